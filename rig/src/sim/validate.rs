//! Validation of a scene file: every value is checked (finite, in range, consistent with
//! the others) and each camera spec is resolved into a [`SimCamera`] (intrinsics, pose,
//! distortion that can be inverted over the whole image, timing). Errors name the table
//! and key to fix.
// `!(x > 0.0)` is deliberate below: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::nonminimal_bool)]

use glam::{DVec2, DVec3};
use shared_types::{Camera, Distortion, Intrinsics, WorldToCamera};

use super::error::SimError;
use super::lens::border_pixels;
use super::schema::{
    CameraRole, CameraSpec, ObjectSection, SceneFile, SimCamera, TextureSpec, VIDEO_CAMERAS,
};

/// The frame rate as the exact value the video files carry: an integer, or an NTSC rate
/// `N·1000/1001` (29.97 → 30000/1001).
pub(crate) fn exact_fps(fps: f64, origin: &str) -> Result<f64, SimError> {
    if !(fps.is_finite() && fps > 0.0 && fps <= 1000.0) {
        return Err(SimError::invalid(
            origin,
            format!("[scene] fps = {fps} is not a frame rate; give a positive number such as 30"),
        ));
    }
    if (fps - fps.round()).abs() < 1e-9 {
        return Ok(fps.round());
    }
    let ntsc = (fps * 1.001).round();
    if (fps * 1.001 - ntsc).abs() < 2e-3 {
        return Ok(ntsc * 1000.0 / 1001.0);
    }
    Err(SimError::invalid(
        origin,
        format!("[scene] fps = {fps} must be an integer or an NTSC rate (e.g. 29.97 = 30000/1001)"),
    ))
}

fn finite(origin: &str, what: &str, values: &[f64]) -> Result<(), SimError> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(SimError::invalid(
            origin,
            format!("{what} must be finite numbers, got {values:?}"),
        ))
    }
}

/// Check every section of `file` and resolve its cameras: video, then held-out, then stills.
pub(crate) fn validate(file: &SceneFile, origin: &str) -> Result<Vec<SimCamera>, SimError> {
    let s = &file.scene;
    if !(s.fps.is_finite() && s.fps > 0.0 && s.fps <= 1000.0) {
        return Err(SimError::invalid(
            origin,
            format!(
                "[scene] fps = {} is not a frame rate; give a positive number such as 30",
                s.fps
            ),
        ));
    }
    if !(s.duration.is_finite() && s.duration > 0.0 && s.duration <= 600.0) {
        return Err(SimError::invalid(
            origin,
            format!(
                "[scene] duration = {} s must be positive (at most 600 s)",
                s.duration
            ),
        ));
    }
    let r = &file.render;
    if !(1..=4).contains(&r.supersample) {
        return Err(SimError::invalid(
            origin,
            "[render] supersample must be 1, 2, 3 or 4",
        ));
    }
    if !(16..=4096).contains(&r.texture_size) {
        return Err(SimError::invalid(
            origin,
            "[render] texture_size must be between 16 and 4096",
        ));
    }
    finite(origin, "[render] light_direction", &r.light_direction)?;
    if DVec3::from_array(r.light_direction).length() < 1e-9 {
        return Err(SimError::invalid(
            origin,
            "[render] light_direction must not be zero",
        ));
    }
    if file.encode.crf > 51 {
        return Err(SimError::invalid(origin, "[encode] crf must be in 0..=51"));
    }
    const PRESETS: [&str; 10] = [
        "ultrafast",
        "superfast",
        "veryfast",
        "faster",
        "fast",
        "medium",
        "slow",
        "slower",
        "veryslow",
        "placebo",
    ];
    if !PRESETS.contains(&file.encode.preset.as_str()) {
        return Err(SimError::invalid(
            origin,
            format!(
                "[encode] preset = {:?} is not an x264 preset; use one of {PRESETS:?}",
                file.encode.preset
            ),
        ));
    }
    let bg = &file.background;
    match bg.kind.as_str() {
        "room" => {
            if bg.size.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(SimError::invalid(
                    origin,
                    "[background] size must be three positive lengths",
                ));
            }
        }
        "dome" => {
            if !(bg.radius.is_finite() && bg.radius > 0.0) {
                return Err(SimError::invalid(
                    origin,
                    "[background] radius must be positive",
                ));
            }
        }
        "none" => {}
        other => {
            return Err(SimError::invalid(
                origin,
                format!("[background] kind = {other:?}; use \"room\", \"dome\" or \"none\""),
            ));
        }
    }
    validate_texture(origin, "[background] texture", &bg.texture)?;
    for (i, o) in file.objects.iter().enumerate() {
        let what = format!(
            "[[objects]] #{i} ({})",
            if o.name.is_empty() { &o.shape } else { &o.name }
        );
        validate_object(origin, &what, o)?;
    }

    let cams = &file.cameras;
    if cams.video.len() != VIDEO_CAMERAS {
        return Err(SimError::invalid(
            origin,
            format!(
                "the rig has {} video cameras ([[cameras.video]]); a capture needs exactly {VIDEO_CAMERAS}",
                cams.video.len()
            ),
        ));
    }
    let mut out = Vec::new();
    for (i, spec) in cams.video.iter().enumerate() {
        out.push(resolve_camera(
            file,
            origin,
            spec,
            format!("cam{i}"),
            CameraRole::Video,
        )?);
    }
    for (i, spec) in cams.heldout.iter().enumerate() {
        out.push(resolve_camera(
            file,
            origin,
            spec,
            format!("heldout{i}"),
            CameraRole::Heldout,
        )?);
    }
    let st = &file.stills;
    if st.count > 0 {
        finite(
            origin,
            "[stills]",
            &[
                st.radius,
                st.heights[0],
                st.heights[1],
                st.hfov,
                st.time,
                st.start_angle,
            ],
        )?;
        if !(st.radius > 0.0) {
            return Err(SimError::invalid(
                origin,
                "[stills] radius must be positive",
            ));
        }
        if !(1..=100).contains(&st.jpeg_quality) {
            return Err(SimError::invalid(
                origin,
                "[stills] jpeg_quality must be in 1..=100",
            ));
        }
    }
    for i in 0..st.count {
        let a = (st.start_angle + 360.0 * i as f64 / st.count as f64).to_radians();
        let c = DVec3::from_array(st.center);
        let pos = c + DVec3::new(
            st.radius * a.cos(),
            st.radius * a.sin(),
            st.heights[(i % 2) as usize],
        );
        let spec = CameraSpec {
            position: pos.to_array(),
            look_at: st.look_at,
            width: Some(st.width),
            height: Some(st.height),
            hfov: Some(st.hfov),
            exposure: 1.0,
            ..Default::default()
        };
        out.push(resolve_camera(
            file,
            origin,
            &spec,
            format!("still_{i:02}"),
            CameraRole::Still,
        )?);
    }
    if let Some(a) = &file.audio {
        finite(origin, "[audio]", &[a.noise, a.clap_time, a.clap_gain])?;
        finite(origin, "[audio] clap_position", &a.clap_position)?;
        if !(8000..=192_000).contains(&a.sample_rate) {
            return Err(SimError::invalid(
                origin,
                "[audio] sample_rate must be in 8000..=192000 Hz",
            ));
        }
        if a.noise < 0.0 || a.clap_gain < 0.0 {
            return Err(SimError::invalid(
                origin,
                "[audio] noise and clap_gain must not be negative",
            ));
        }
    }
    if let Some(f) = &file.flash {
        finite(
            origin,
            "[flash]",
            &[
                f.time,
                f.duration,
                f.strength,
                f.readout,
                f.shutter.unwrap_or(0.01),
            ],
        )?;
        if f.duration <= 0.0 || f.readout < 0.0 || f.shutter.is_some_and(|s| s <= 0.0) {
            return Err(SimError::invalid(
                origin,
                "[flash] duration and shutter must be positive, readout not negative",
            ));
        }
        if f.readout + f.shutter.unwrap_or(0.5 / s.fps) > 1.0 / s.fps + 1e-12 {
            return Err(SimError::invalid(
                origin,
                "[flash] readout + shutter must fit in one frame interval (1 / fps)",
            ));
        }
    }
    if let Some(n) = &file.noise
        && !(n.sigma.is_finite() && n.sigma >= 0.0)
    {
        return Err(SimError::invalid(
            origin,
            "[noise] sigma must be a non-negative number",
        ));
    }
    Ok(out)
}

fn validate_texture(origin: &str, what: &str, t: &TextureSpec) -> Result<(), SimError> {
    if !["mix", "noise", "checker", "glyphs", "solid"].contains(&t.kind.as_str()) {
        return Err(SimError::invalid(
            origin,
            format!(
                "{what}: kind = {:?}; use mix, noise, checker, glyphs or solid",
                t.kind
            ),
        ));
    }
    if !(t.tile.is_finite() && t.tile > 0.0) {
        return Err(SimError::invalid(
            origin,
            format!("{what}: tile must be a positive length in metres"),
        ));
    }
    if !(1..=64).contains(&t.cells) {
        return Err(SimError::invalid(
            origin,
            format!("{what}: cells must be in 1..=64"),
        ));
    }
    finite(origin, what, t.colors.as_flattened())
}

fn validate_object(origin: &str, what: &str, o: &ObjectSection) -> Result<(), SimError> {
    finite(
        origin,
        &format!("{what} size/radius/height"),
        &[o.size[0], o.size[1], o.size[2], o.radius, o.height],
    )?;
    finite(origin, &format!("{what} position"), &o.position)?;
    finite(origin, &format!("{what} rotation"), &o.rotation)?;
    if !(1..=256).contains(&o.segments) {
        return Err(SimError::invalid(
            origin,
            format!("{what}: segments must be in 1..=256"),
        ));
    }
    match o.shape.as_str() {
        "box" | "plane" => {
            let n = if o.shape == "box" { 3 } else { 2 };
            if o.size[..n].iter().any(|v| *v <= 0.0) {
                return Err(SimError::invalid(
                    origin,
                    format!("{what}: size must be positive"),
                ));
            }
        }
        "sphere" | "cylinder" => {
            if o.radius <= 0.0 || (o.shape == "cylinder" && o.height <= 0.0) {
                return Err(SimError::invalid(
                    origin,
                    format!("{what}: radius and height must be positive"),
                ));
            }
        }
        "mesh" => {
            if o.vertices.is_empty() || o.triangles.is_empty() {
                return Err(SimError::invalid(
                    origin,
                    format!("{what}: a mesh needs vertices and triangles"),
                ));
            }
            if let Some(bad) = o
                .triangles
                .iter()
                .flatten()
                .find(|&&i| i as usize >= o.vertices.len())
            {
                return Err(SimError::invalid(
                    origin,
                    format!(
                        "{what}: triangle index {bad} but only {} vertices",
                        o.vertices.len()
                    ),
                ));
            }
            if !o.uvs.is_empty() && o.uvs.len() != o.vertices.len() {
                return Err(SimError::invalid(
                    origin,
                    format!("{what}: give one uv per vertex or none"),
                ));
            }
            finite(
                origin,
                &format!("{what} vertices"),
                o.vertices.as_flattened(),
            )?;
        }
        other => {
            return Err(SimError::invalid(
                origin,
                format!("{what}: shape = {other:?}; use box, sphere, plane, cylinder or mesh"),
            ));
        }
    }
    validate_texture(origin, &format!("{what} texture"), &o.texture)?;
    let mut last = f64::NEG_INFINITY;
    for k in &o.keyframes {
        finite(
            origin,
            &format!("{what} keyframe"),
            &[k.t, k.position[0], k.position[1], k.position[2]],
        )?;
        finite(origin, &format!("{what} keyframe rotation"), &k.rotation)?;
        if k.t <= last {
            return Err(SimError::invalid(
                origin,
                format!("{what}: keyframe times must increase"),
            ));
        }
        last = k.t;
    }
    if let Some(d) = &o.deform {
        finite(
            origin,
            &format!("{what} deform"),
            &[d.amplitude, d.wavelength, d.frequency],
        )?;
        if d.wavelength <= 0.0 {
            return Err(SimError::invalid(
                origin,
                format!("{what}: deform wavelength must be positive"),
            ));
        }
    }
    Ok(())
}

fn resolve_camera(
    file: &SceneFile,
    origin: &str,
    spec: &CameraSpec,
    name: String,
    role: CameraRole,
) -> Result<SimCamera, SimError> {
    let defaults = &file.cameras;
    let fps = file.scene.fps;
    finite(origin, &format!("camera {name} position"), &spec.position)?;
    finite(origin, &format!("camera {name} look_at"), &spec.look_at)?;
    finite(
        origin,
        &format!("camera {name}"),
        &[spec.offset, spec.phase, spec.exposure],
    )?;
    let width = spec.width.unwrap_or(defaults.width);
    let height = spec.height.unwrap_or(defaults.height);
    if width < 16
        || height < 16
        || width > 8192
        || height > 8192
        || !width.is_multiple_of(2)
        || !height.is_multiple_of(2)
    {
        return Err(SimError::invalid(
            origin,
            format!(
                "camera {name}: resolution {width}×{height} must be even and between 16 and 8192 pixels"
            ),
        ));
    }
    let intrinsics = match (spec.focal, spec.hfov) {
        (Some(_), Some(_)) => {
            return Err(SimError::invalid(
                origin,
                format!("camera {name}: give either focal or hfov, not both"),
            ));
        }
        (Some(f), None) => {
            if !(f.is_finite() && f > 0.0) {
                return Err(SimError::invalid(
                    origin,
                    format!("camera {name}: focal must be positive pixels"),
                ));
            }
            Intrinsics {
                width,
                height,
                fx: f,
                fy: f,
                cx: 0.5 * width as f64,
                cy: 0.5 * height as f64,
            }
        }
        (None, hfov) => {
            let h = hfov.unwrap_or(defaults.hfov);
            if !(h.is_finite() && h > 1.0 && h < 170.0) {
                return Err(SimError::invalid(
                    origin,
                    format!("camera {name}: hfov = {h} must be in (1, 170) degrees"),
                ));
            }
            Intrinsics::from_hfov(width, height, h)
        }
    };
    let eye = DVec3::from_array(spec.position);
    let target = DVec3::from_array(spec.look_at);
    if (target - eye).length() < 1e-9 {
        return Err(SimError::invalid(
            origin,
            format!(
                "camera {name} looks at nothing: look_at equals its position {:?}",
                spec.position
            ),
        ));
    }
    let world_to_camera = WorldToCamera::look_at(eye, target, DVec3::Z).ok_or_else(|| {
        SimError::invalid(
            origin,
            format!(
                "camera {name} looks straight up or down (world z is up); tilt its look_at a little"
            ),
        )
    })?;
    validate_distortion(origin, &name, &spec.distortion, &intrinsics)?;
    if !(0.0..1.0).contains(&spec.phase) {
        return Err(SimError::invalid(
            origin,
            format!("camera {name}: phase must be in [0, 1) frames"),
        ));
    }
    if !(spec.exposure > 0.0) {
        return Err(SimError::invalid(
            origin,
            format!("camera {name}: exposure must be positive"),
        ));
    }
    let frames = (file.scene.duration * fps).round().max(1.0) as u32;
    if role != CameraRole::Video
        && (spec.offset != 0.0
            || spec.phase != 0.0
            || !spec.dropped.is_empty()
            || spec.chapter_frames.is_some())
    {
        return Err(SimError::invalid(
            origin,
            format!(
                "camera {name}: offset, phase, dropped and chapter_frames apply to video cameras only"
            ),
        ));
    }
    let mut dropped = spec.dropped.clone();
    dropped.sort_unstable();
    dropped.dedup();
    if let Some(&bad) = dropped.iter().find(|&&d| d == 0 || d >= frames) {
        return Err(SimError::invalid(
            origin,
            format!(
                "camera {name}: dropped frame {bad} must be in 1..{frames} (frame 0 starts the file)"
            ),
        ));
    }
    if let Some(c) = spec.chapter_frames
        && (c == 0 || frames.div_ceil(c) > 99)
    {
        return Err(SimError::invalid(
            origin,
            format!("camera {name}: chapter_frames must give 1..=99 chapters"),
        ));
    }
    let start_time = spec.offset + spec.phase / fps;
    Ok(SimCamera {
        camera: Camera {
            name,
            intrinsics,
            distortion: spec.distortion,
            world_to_camera,
        },
        role,
        start_time,
        offset: spec.offset,
        phase: spec.phase,
        exposure: spec.exposure,
        dropped,
        chapter_frames: spec.chapter_frames,
    })
}

/// The distortion must be finite and invertible over the whole image: undistorting each
/// border pixel and distorting it again must come back within 1e-3 px.
fn validate_distortion(
    origin: &str,
    name: &str,
    d: &Distortion,
    k: &Intrinsics,
) -> Result<(), SimError> {
    if d.is_none() {
        return Ok(());
    }
    let values = d.coefficients();
    finite(origin, &format!("camera {name} distortion"), &values)?;
    for p in border_pixels(k.width, k.height, 8) {
        let n = d.undistort(k.to_normalised(p));
        let back = k.to_pixels(d.distort(n));
        if !(n.is_finite() && (back - p).length() < 1e-3) || !radially_monotonic(d, n) {
            return Err(SimError::invalid(
                origin,
                format!(
                    "camera {name}: distortion {d:?} cannot be inverted at pixel ({:.0}, {:.0}); \
                     use smaller coefficients",
                    p.x, p.y
                ),
            ));
        }
    }
    Ok(())
}

/// Whether distortion keeps growing outwards up to `n` (no fold-back inside the image).
fn radially_monotonic(d: &Distortion, n: DVec2) -> bool {
    let mut last = 0.0;
    for i in 1..=32 {
        let r = d.distort(n * (i as f64 / 32.0)).length();
        if r <= last {
            return false;
        }
        last = r;
    }
    true
}
