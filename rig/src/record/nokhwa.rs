//! The nokhwa camera source (feature `nokhwa`): webcams through the platform's own API —
//! V4L2 on Linux, AVFoundation on macOS, Media Foundation on Windows.
//!
//! Each camera lives on its own capture thread, which opens it, negotiates a mode with the
//! recorder's [`negotiate_among`], and sends the raw buffers with the backend's capture
//! times (Unix time on every platform) to a [`LiveSource`]; pixel conversion, the session
//! clock and the writer are the recorder's, shared with V4L2. The mapping of nokhwa's
//! formats and errors is in plain functions here, tested without a camera.

use std::sync::mpsc;
use std::time::Duration;

use ::nokhwa::utils::{
    ApiBackend, CameraFormat, CameraIndex, FrameFormat, RequestedFormat, RequestedFormatType,
    frame_formats,
};
use ::nokhwa::{Camera, NokhwaError};

use super::live::{DeviceSpec, ListedCamera, LiveSource, RawFrame, resolve_device, unix_now};
use super::pixels::fourcc_text;
use super::{FormatOption, RecordConfig, RecordError, negotiate_among};
use crate::source::{CameraSource, SourceError};

/// Pixel formats nokhwa can deliver that we convert, best first (MJPEG keeps USB bandwidth
/// low for four cameras; grey last).
pub const NOKHWA_FOURCC: [[u8; 4]; 6] =
    [*b"MJPG", *b"YUYV", *b"NV12", *b"RGB3", *b"BGR3", *b"GREY"];

/// How long opening a camera (and the macOS permission prompt) may take.
const OPEN_TIMEOUT: Duration = Duration::from_secs(30);

/// The FourCC of one of nokhwa's frame formats.
pub fn fourcc_of(format: FrameFormat) -> [u8; 4] {
    match format {
        FrameFormat::MJPEG => *b"MJPG",
        FrameFormat::YUYV => *b"YUYV",
        FrameFormat::NV12 => *b"NV12",
        FrameFormat::GRAY => *b"GREY",
        FrameFormat::RAWRGB => *b"RGB3",
        FrameFormat::RAWBGR => *b"BGR3",
    }
}

/// nokhwa's frame format for a FourCC, if it has one.
pub fn frame_format_of(fourcc: &[u8; 4]) -> Option<FrameFormat> {
    frame_formats()
        .iter()
        .copied()
        .find(|f| fourcc_of(*f) == *fourcc)
}

/// The modes a camera lists, as the recorder's [`FormatOption`]s: one per pixel format and
/// size, with its frame rates ascending.
pub fn format_options(formats: &[CameraFormat]) -> Vec<FormatOption> {
    let mut options: Vec<FormatOption> = Vec::new();
    for f in formats {
        let fourcc = fourcc_of(f.format());
        let fps = f64::from(f.frame_rate());
        let existing = options
            .iter_mut()
            .find(|o| o.fourcc == fourcc && (o.width, o.height) == (f.width(), f.height()));
        match existing {
            Some(o) => o.fps.push(fps),
            None => options.push(FormatOption {
                fourcc,
                width: f.width(),
                height: f.height(),
                fps: vec![fps],
            }),
        }
    }
    for o in &mut options {
        o.fps.retain(|f| *f > 0.0);
        o.fps.sort_by(f64::total_cmp);
        o.fps.dedup();
    }
    options
}

/// The nokhwa mode for a negotiated choice (frame rates are whole numbers in nokhwa).
pub fn camera_format_for(choice: &FormatOption, fps: f64) -> Option<CameraFormat> {
    let format = frame_format_of(&choice.fourcc)?;
    let fps = fps.round().clamp(1.0, f64::from(u32::MAX)) as u32;
    Some(CameraFormat::new_from(
        choice.width,
        choice.height,
        format,
        fps,
    ))
}

/// `MJPG 1280x720 @ 30/60 fps, …`, what a camera offers, for error messages.
pub fn describe_options(options: &[FormatOption]) -> String {
    if options.is_empty() {
        return "nothing".into();
    }
    options
        .iter()
        .map(|o| {
            let fps: Vec<String> = o.fps.iter().map(|f| format!("{f}")).collect();
            format!(
                "{} {}x{} @ {} fps",
                fourcc_text(&o.fourcc),
                o.width,
                o.height,
                fps.join("/")
            )
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// What went wrong with `device`, from nokhwa's error, and what to do about it.
pub fn device_message(e: &NokhwaError) -> String {
    let fix = match e {
        NokhwaError::OpenDeviceError(..) | NokhwaError::InitializeError { .. } => {
            "check that the camera is plugged in, that no other program (a video call, a browser tab) uses it, and that you may use cameras (Linux: the `video` group; macOS: System Settings › Privacy & Security › Camera; Windows: Settings › Privacy › Camera)"
        }
        NokhwaError::OpenStreamError(_) => {
            "close other programs that use the camera, or ask for less with --width/--height/--fps (cameras sharing a USB controller can exceed its bandwidth)"
        }
        NokhwaError::ReadFrameError(_) => {
            "check the cable and the USB bandwidth (spread the cameras over USB controllers)"
        }
        NokhwaError::SetPropertyError { .. }
        | NokhwaError::GetPropertyError { .. }
        | NokhwaError::StructureError { .. } => {
            "ask for another --width/--height/--fps; `pipeline record --backend nokhwa --list` shows the cameras"
        }
        NokhwaError::UnsupportedOperationError(_) | NokhwaError::NotImplementedError(_) => {
            "this platform's camera API cannot do this; on Linux try --backend v4l2"
        }
        _ => "unplug and replug the camera, then try again",
    };
    format!("{e}; {fix}")
}

/// nokhwa's error for `device` as a recorder error naming the device and the fix.
pub fn error_for(device: &str, e: &NokhwaError) -> RecordError {
    RecordError::Source(SourceError::Device {
        device: device.to_string(),
        message: device_message(e),
    })
}

/// This platform's camera API as nokhwa names it.
pub fn native_backend() -> ApiBackend {
    ::nokhwa::native_api_backend().unwrap_or(ApiBackend::Auto)
}

fn no_camera(detail: String) -> RecordError {
    RecordError::NoCamera {
        backend: native_backend().to_string(),
        detail,
    }
}

/// The cameras nokhwa finds, by index.
pub fn list_cameras() -> Result<Vec<ListedCamera>, RecordError> {
    ensure_permission()?;
    let cameras = ::nokhwa::query(native_backend())
        .map_err(|e| no_camera(format!("cannot list cameras: {e}")))?;
    let mut listed: Vec<ListedCamera> = cameras
        .iter()
        .filter_map(|c| match c.index() {
            CameraIndex::Index(i) => Some(ListedCamera {
                index: *i,
                name: c.human_name(),
            }),
            CameraIndex::String(_) => None,
        })
        .collect();
    listed.sort_by_key(|c| c.index);
    Ok(listed)
}

/// Asks for camera access where the platform requires it (macOS); a no-op elsewhere.
fn ensure_permission() -> Result<(), RecordError> {
    if ::nokhwa::nokhwa_check() {
        return Ok(());
    }
    let (tx, rx) = mpsc::channel();
    ::nokhwa::nokhwa_initialize(move |granted| {
        // The receiver may have timed out; then nobody needs the answer.
        let _ = tx.send(granted);
    });
    match rx.recv_timeout(OPEN_TIMEOUT) {
        Ok(true) => Ok(()),
        _ => Err(no_camera(
            "camera access was not granted (macOS: allow this terminal in System Settings › Privacy & Security › Camera)".into(),
        )),
    }
}

/// Opens every camera `devices` names (index, `/dev/videoN` or name; see [`DeviceSpec`]) as
/// `cam0`, `cam1`, …, on one session clock.
pub fn open_all(
    devices: &[String],
    config: &RecordConfig,
) -> Result<Vec<Box<dyn CameraSource>>, RecordError> {
    let listed = list_cameras()?;
    if devices.is_empty() {
        let detail = if listed.is_empty() {
            "no camera is present".to_string()
        } else {
            let names: Vec<String> = listed.iter().map(ToString::to_string).collect();
            format!("none given with --device; present: {}", names.join(", "))
        };
        return Err(no_camera(detail));
    }
    let origin = unix_now();
    let mut sources: Vec<Box<dyn CameraSource>> = Vec::new();
    for (i, arg) in devices.iter().enumerate() {
        let camera = resolve_device(&DeviceSpec::parse(arg), &listed).map_err(no_camera)?;
        sources.push(Box::new(open(&format!("cam{i}"), &camera, config, origin)?));
    }
    Ok(sources)
}

/// The mode a camera streams in.
struct Opened {
    size: (u32, u32),
    fps: f64,
}

/// Opens `camera` on its own capture thread and returns the source fed by it; frame
/// timestamps are seconds since `origin` (Unix time).
pub fn open(
    name: &str,
    camera: &ListedCamera,
    config: &RecordConfig,
    origin: Duration,
) -> Result<LiveSource, RecordError> {
    let device = format!("{camera} ({})", native_backend());
    let (ready_tx, ready_rx) = mpsc::sync_channel(1);
    // A few buffers of slack; when the recorder falls behind, the camera drops frames,
    // which show as gaps in the capture times.
    let (frames_tx, frames_rx) = mpsc::sync_channel(4);
    let index = camera.index;
    let (thread_device, thread_config) = (device.clone(), config.clone());
    std::thread::Builder::new()
        .name(format!("nokhwa-{name}"))
        .spawn(move || capture(index, &thread_device, &thread_config, ready_tx, frames_tx))
        .map_err(|e| {
            RecordError::Source(SourceError::Device {
                device: device.clone(),
                message: format!("cannot start its capture thread: {e}"),
            })
        })?;
    let opened = match ready_rx.recv_timeout(OPEN_TIMEOUT) {
        Ok(result) => result?,
        Err(_) => {
            return Err(RecordError::Source(SourceError::Device {
                device,
                message: format!(
                    "did not start streaming within {} s; unplug and replug it, then try again",
                    OPEN_TIMEOUT.as_secs()
                ),
            }));
        }
    };
    Ok(LiveSource::new(
        name,
        &device,
        opened.size,
        opened.fps,
        origin,
        frames_rx,
    ))
}

/// Opens the camera and negotiates its mode (on the capture thread).
fn open_camera(index: u32, device: &str, config: &RecordConfig) -> Result<Camera, RecordError> {
    let err = |e: NokhwaError| error_for(device, &e);
    let any = RequestedFormat::with_formats(
        RequestedFormatType::AbsoluteHighestFrameRate,
        frame_formats(),
    );
    let mut camera =
        Camera::with_backend(CameraIndex::Index(index), any, native_backend()).map_err(err)?;
    let offered = match camera.compatible_camera_formats() {
        Ok(formats) if !formats.is_empty() => formats,
        // Some backends cannot list modes: negotiate with the current one.
        _ => vec![camera.camera_format()],
    };
    let options = format_options(&offered);
    let choice = negotiate_among(&options, config, &NOKHWA_FOURCC)
        .and_then(|(choice, fps)| camera_format_for(&choice, fps));
    let Some(format) = choice else {
        return Err(RecordError::NoFormat {
            device: device.to_string(),
            offered: describe_options(&options),
        });
    };
    if format != camera.camera_format() {
        camera
            .set_camera_requset(RequestedFormat::with_formats(
                RequestedFormatType::Exact(format),
                &[format.format()],
            ))
            .map_err(err)?;
    }
    camera.open_stream().map_err(err)?;
    Ok(camera)
}

/// The capture thread: opens the camera, reports its mode on `ready`, then sends every
/// buffer until the source is dropped or the camera fails.
fn capture(
    index: u32,
    device: &str,
    config: &RecordConfig,
    ready: mpsc::SyncSender<Result<Opened, RecordError>>,
    frames: mpsc::SyncSender<Result<RawFrame, SourceError>>,
) {
    let mut camera = match open_camera(index, device, config) {
        Ok(camera) => camera,
        Err(e) => {
            // If nobody waits any more, the error has nowhere to go.
            let _ = ready.send(Err(e));
            return;
        }
    };
    let format = camera.camera_format();
    let opened = Opened {
        size: (format.width(), format.height()),
        fps: f64::from(format.frame_rate()),
    };
    if ready.send(Ok(opened)).is_ok() {
        loop {
            let result = camera.frame();
            let arrived = unix_now();
            let message = result
                .map(|buffer| RawFrame {
                    fourcc: fourcc_of(buffer.source_frame_format()),
                    width: buffer.resolution().width(),
                    height: buffer.resolution().height(),
                    data: buffer.buffer().to_vec(),
                    captured: buffer.capture_timestamp(),
                    arrived,
                })
                .map_err(|e| SourceError::Device {
                    device: device.to_string(),
                    message: device_message(&e),
                });
            let failed = message.is_err();
            if frames.send(message).is_err() || failed {
                break;
            }
        }
    }
    // The recording is over either way; a camera that will not stop cleanly is released
    // when it is dropped.
    let _ = camera.stop_stream();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_nokhwa_format_has_a_fourcc_we_convert() {
        for f in frame_formats() {
            let fourcc = fourcc_of(*f);
            assert!(NOKHWA_FOURCC.contains(&fourcc), "{f}");
            assert_eq!(frame_format_of(&fourcc), Some(*f));
        }
        assert_eq!(frame_format_of(b"H264"), None);
    }

    #[test]
    fn modes_group_by_format_and_size_and_negotiate_like_v4l2() {
        let modes = [
            CameraFormat::new_from(1280, 720, FrameFormat::YUYV, 10),
            CameraFormat::new_from(1280, 720, FrameFormat::MJPEG, 60),
            CameraFormat::new_from(1280, 720, FrameFormat::MJPEG, 30),
            CameraFormat::new_from(1280, 720, FrameFormat::MJPEG, 30),
            CameraFormat::new_from(640, 480, FrameFormat::NV12, 30),
        ];
        let options = format_options(&modes);
        assert_eq!(options.len(), 3);
        assert_eq!(options[1].fps, vec![30.0, 60.0]);
        let want = RecordConfig::default(); // 1280×720 at 30 fps
        let (choice, fps) = negotiate_among(&options, &want, &NOKHWA_FOURCC).unwrap();
        assert_eq!(
            camera_format_for(&choice, fps),
            Some(CameraFormat::new_from(1280, 720, FrameFormat::MJPEG, 30))
        );
        let small = RecordConfig {
            width: 640,
            height: 480,
            ..Default::default()
        };
        let (choice, _) = negotiate_among(&options, &small, &NOKHWA_FOURCC).unwrap();
        assert_eq!(&choice.fourcc, b"NV12", "NV12 is usable through nokhwa");
        assert_eq!(
            describe_options(&options[1..2]),
            "MJPG 1280x720 @ 30/60 fps"
        );
    }

    #[test]
    fn errors_name_the_device_and_the_fix() {
        let e = error_for(
            "#0 Logitech C920 (Video4Linux)",
            &NokhwaError::OpenDeviceError("0".into(), "Permission denied".into()),
        );
        let text = e.to_string();
        assert!(text.starts_with("camera device #0 Logitech C920"), "{text}");
        assert!(
            text.contains("Permission denied") && text.contains("`video` group"),
            "{text}"
        );
        let text = device_message(&NokhwaError::OpenStreamError("busy".into()));
        assert!(text.contains("--width/--height/--fps"), "{text}");
        let text = device_message(&NokhwaError::ReadFrameError("timeout".into()));
        assert!(text.contains("USB"), "{text}");
    }

    #[test]
    fn without_a_camera_listing_is_empty_and_opening_fails_cleanly() {
        let listed = list_cameras().unwrap_or_default();
        if !listed.is_empty() {
            return; // a machine with a camera: the ignored test below covers it
        }
        let Err(err) = open_all(&["0".into()], &RecordConfig::default()) else {
            panic!("opened a camera that is not listed");
        };
        let text = err.to_string();
        assert!(matches!(err, RecordError::NoCamera { .. }), "{text}");
        assert!(
            text.contains("no camera #0 (no camera is present)") && text.contains("--list"),
            "{text}"
        );
        let Err(err) = open_all(&[], &RecordConfig::default()) else {
            panic!("opened no camera");
        };
        assert!(err.to_string().contains("no camera is present"), "{err}");
    }
}
