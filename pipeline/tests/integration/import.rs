//! `pipeline import`: each dataset layout written the way its tool writes it, from known
//! cameras; after import, `calibration.json` read back by the pose stage's own reader
//! reprojects known 3D points to the pixels the known cameras see them at. Bad files give
//! errors naming the file and the key.

use std::path::{Path, PathBuf};
use std::process::Command;

use glam::{DMat3, DQuat, DVec3};
use pipeline::import::{Format, Request, TrainChoice, import};
use shared_types::camera::{Camera, Distortion, Intrinsics, WorldToCamera};

const W: u32 = 64;
const H: u32 = 36;

/// Five cameras on an arc around the origin, looking at it; lens per `lens`.
fn truth(lens: impl Fn(usize) -> (Intrinsics, Distortion)) -> Vec<Camera> {
    (0..5)
        .map(|i| {
            let a = -0.9 + 0.45 * i as f64;
            let eye = DVec3::new(3.0 * a.sin(), -1.2 + 0.1 * i as f64, -3.0 * a.cos());
            let up = DVec3::new(0.0, -1.0, 0.0);
            let (intrinsics, distortion) = lens(i);
            Camera {
                name: format!("truth{i}"),
                intrinsics,
                distortion,
                world_to_camera: WorldToCamera::look_at(eye, DVec3::new(0.1, 0.2, 0.0), up)
                    .unwrap(),
            }
        })
        .collect()
}

fn centred(f: f64) -> Intrinsics {
    Intrinsics {
        width: W,
        height: H,
        fx: f,
        fy: f,
        cx: W as f64 / 2.0,
        cy: H as f64 / 2.0,
    }
}

fn general(i: usize) -> Intrinsics {
    Intrinsics {
        width: W,
        height: H,
        fx: 50.0 + i as f64,
        fy: 51.5 + i as f64,
        cx: 31.3 + 0.2 * i as f64,
        cy: 18.6 - 0.1 * i as f64,
    }
}

const POINTS: [[f64; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [0.3, -0.2, 0.1],
    [-0.25, 0.3, -0.2],
    [0.1, 0.4, 0.3],
];

/// A request with the defaults: footage linked, every frame, the dataset's size.
fn plain(
    format: Format,
    source: impl Into<PathBuf>,
    dest: impl Into<PathBuf>,
    train: TrainChoice,
) -> Request {
    Request {
        format,
        source: source.into(),
        dest: dest.into(),
        train,
        frames: None,
        long_side: None,
        copy: false,
    }
}

/// The error of importing `source` as `format` with the dataset's protocol.
fn import_error(format: Format, source: &Path, dest: &Path) -> String {
    import(&plain(format, source, dest, TrainChoice::Protocol))
        .unwrap_err()
        .to_string()
}

/// Import `source` as `format` into a new folder; every camera of the capture, read back
/// from its calibration.json, projects the known points where the known camera does.
fn import_and_reproject(
    format: Format,
    source: &Path,
    truth: &[Camera],
    dataset_name: impl Fn(usize) -> String,
    train: TrainChoice,
    tolerance: f64,
) -> (PathBuf, pipeline::import::Summary) {
    let dest = source.parent().unwrap().join("capture");
    let summary = import(&plain(format, source, &dest, train)).unwrap();
    let set = calib::import::import_calibration(&dest.join("calibration.json")).unwrap();
    assert_eq!(set.cameras.len(), truth.len());
    for (capture, dataset) in &summary.cameras {
        let i = (0..truth.len())
            .find(|&i| dataset_name(i) == *dataset)
            .unwrap();
        let got = set.get(capture).unwrap();
        assert_eq!(
            (got.intrinsics.width, got.intrinsics.height),
            (W, H),
            "{capture}"
        );
        for p in POINTS {
            let p = DVec3::from_array(p);
            let (want, _) = truth[i].project(p).unwrap();
            let (seen, _) = got.project(p).unwrap();
            assert!(
                want.distance(seen) < tolerance,
                "{format:?} {capture} ({dataset}): {p} at {seen}, expected {want}"
            );
        }
        assert!(
            dest.join("raw")
                .join(capture)
                .read_dir()
                .unwrap()
                .next()
                .is_some()
        );
    }
    (dest, summary)
}

fn blank_image(path: &Path) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    image::RgbImage::new(W, H).save(path).unwrap();
}

fn npy_f64(path: &Path, rows: usize, cols: usize, data: &[f64]) {
    let dict = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({rows}, {cols}), }}");
    let mut header = dict.into_bytes();
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(b' ');
    }
    header.push(b'\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(&header);
    data.iter()
        .for_each(|v| bytes.extend_from_slice(&v.to_le_bytes()));
    std::fs::write(path, bytes).unwrap();
}

/// Neural 3D Video: `poses_bounds.npy` in LLFF's `[down, right, back]` axes.
fn write_n3v(dir: &Path, cams: &[Camera], nan: bool) {
    std::fs::create_dir_all(dir).unwrap();
    let mut data = Vec::new();
    for (i, c) in cams.iter().enumerate() {
        let c2w = c.world_to_camera.rotation().transpose();
        let centre = c.world_to_camera.centre();
        let cols = [c2w.y_axis, c2w.x_axis, -c2w.z_axis, centre];
        let hwf = [H as f64, W as f64, c.intrinsics.fx];
        for r in 0..3 {
            for col in cols {
                data.push(col[r]);
            }
            data.push(hwf[r]);
        }
        data.extend([0.5, 9.0]);
        std::fs::write(dir.join(format!("cam{i:02}.mp4")), b"linked, not read").unwrap();
    }
    if nan {
        data[3] = f64::NAN;
    }
    npy_f64(&dir.join("poses_bounds.npy"), cams.len(), 17, &data);
}

#[test]
fn n3v_poses_bounds_reproject_and_its_protocols_choose_the_cameras() {
    let tmp = tempfile::tempdir().unwrap();
    let cams = truth(|i| (centred(48.0 + 2.0 * i as f64), Distortion::None));
    let src = tmp.path().join("coffee_martini");
    write_n3v(&src, &cams, false);
    let (dest, summary) = import_and_reproject(
        Format::N3v,
        &src,
        &cams,
        |i| format!("cam{i:02}"),
        TrainChoice::Protocol,
        1e-3,
    );
    // The dataset's protocol holds out cam00; the training cameras come first.
    assert_eq!(summary.training, 4);
    assert_eq!(
        summary.cameras[4],
        ("cam4".to_string(), "cam00".to_string())
    );
    let toml = std::fs::read_to_string(dest.join("capture.toml")).unwrap();
    assert!(
        toml.contains("cameras = 4\nheldout = [\"cam4\"]")
            && toml.contains("method = \"timestamps\""),
        "{toml}"
    );
    let link = std::fs::read_link(dest.join("raw/cam4/cam00.mp4")).unwrap();
    assert_eq!(link, std::path::absolute(src.join("cam00.mp4")).unwrap());

    // The paper's protocol: the four cameras farthest apart train, the rest are held out;
    // a frame range becomes the frames stage's start and length.
    let centres: Vec<DVec3> = cams.iter().map(|c| c.world_to_camera.centre()).collect();
    assert_eq!(
        pipeline::import::farthest(&centres, 2),
        [0, 4],
        "the ends of the arc"
    );
    let far = tmp.path().join("far");
    let summary = import(&Request {
        format: Format::N3v,
        source: src.clone(),
        dest: far.clone(),
        train: "farthest:4".parse().unwrap(),
        frames: Some((30, 330)),
        long_side: Some(1352),
        copy: true,
    })
    .unwrap();
    let train: Vec<&str> = summary.cameras[..4]
        .iter()
        .map(|(_, d)| d.as_str())
        .collect();
    let expected: Vec<String> = pipeline::import::farthest(&centres, 4)
        .iter()
        .map(|i| format!("cam{i:02}"))
        .collect();
    assert_eq!(train, expected);
    let toml = std::fs::read_to_string(far.join("capture.toml")).unwrap();
    assert!(
        toml.contains("long_side = 1352")
            && toml.contains("max_frames = 300")
            && toml.contains("start_s = 1"),
        "{toml}"
    );
    assert!(
        !std::fs::symlink_metadata(
            far.join("raw/cam0")
                .read_dir()
                .unwrap()
                .next()
                .unwrap()
                .unwrap()
                .path()
        )
        .unwrap()
        .is_symlink()
    );

    // Bad datasets: a video without a row, a NaN, a non-empty destination, an unknown camera.
    let err = |src: &Path, dest: &Path, train: TrainChoice| {
        import(&plain(Format::N3v, src, dest, train))
            .unwrap_err()
            .to_string()
    };
    let extra = tmp.path().join("extra");
    write_n3v(&extra, &cams, false);
    std::fs::write(extra.join("cam05.mp4"), b"").unwrap();
    let e = err(&extra, &tmp.path().join("x1"), TrainChoice::Protocol);
    assert!(
        e.contains("poses_bounds.npy") && e.contains("5 cameras") && e.contains("6 videos"),
        "{e}"
    );
    let nan = tmp.path().join("nan");
    write_n3v(&nan, &cams, true);
    let e = err(&nan, &tmp.path().join("x2"), TrainChoice::Protocol);
    assert!(
        e.contains("poses_bounds.npy") && e.contains("camera cam00") && e.contains("NaN"),
        "{e}"
    );
    let e = err(&src, &dest, TrainChoice::Protocol);
    assert!(
        e.contains("not empty") && e.contains("nothing there was changed"),
        "{e}"
    );
    let e = err(&src, &tmp.path().join("x3"), "cam01,cam99".parse().unwrap());
    assert!(
        e.contains("no camera cam99") && e.contains("cam00, cam01"),
        "{e}"
    );
    assert!(
        !tmp.path().join("x3").exists(),
        "nothing written on an error"
    );
}

/// nerfstudio: OpenGL camera-to-world, `applied_transform`, shared and per-frame
/// intrinsics, an OpenCV lens.
fn write_nerfstudio(dir: &Path, cams: &[Camera], nan: bool) {
    // nerfstudio's COLMAP conversion: swap y and z, negate the new z.
    let applied = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0, 0.0],
    ];
    let a = DMat3::from_cols_array_2d(&[[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]);
    let mut frames = Vec::new();
    for (i, c) in cams.iter().enumerate() {
        let c2w = c.world_to_camera.rotation().transpose();
        let gl = a * DMat3::from_cols(c2w.x_axis, -c2w.y_axis, -c2w.z_axis);
        let centre = a * c.world_to_camera.centre();
        let m = |r: usize| vec![gl.x_axis[r], gl.y_axis[r], gl.z_axis[r], centre[r]];
        let Distortion::Opencv { k1, k2, p1, p2, .. } = c.distortion else {
            panic!("an OpenCV lens")
        };
        for t in 0..2 {
            let file = format!("images/cam_{i}/frame_{t:05}.png");
            blank_image(&dir.join(&file));
            let mut frame = serde_json::json!({
                "file_path": file,
                "transform_matrix": [m(0), m(1), m(2), [0.0, 0.0, 0.0, 1.0]],
            });
            // Camera 0 carries its own intrinsics; the others use the shared ones.
            if i == 0 {
                let k = &c.intrinsics;
                for (key, v) in [
                    ("fl_x", k.fx),
                    ("fl_y", k.fy),
                    ("cx", k.cx),
                    ("cy", k.cy),
                    ("k1", k1),
                    ("k2", k2),
                    ("p1", p1),
                    ("p2", p2),
                ] {
                    frame[key] = v.into();
                }
            }
            frames.push(frame);
        }
    }
    let k = &cams[1].intrinsics;
    let Distortion::Opencv { k1, k2, p1, p2, .. } = cams[1].distortion else {
        panic!("an OpenCV lens")
    };
    let file = serde_json::json!({
        "camera_model": "OPENCV",
        "fl_x": k.fx, "fl_y": k.fy, "cx": k.cx, "cy": k.cy, "w": W, "h": H,
        "k1": k1, "k2": k2, "p1": p1, "p2": p2,
        "applied_transform": applied,
        "frames": frames,
    });
    let mut text = serde_json::to_string_pretty(&file).unwrap();
    if nan {
        // Python's json writes a NaN as a bare `NaN`.
        text = text.replacen("\"fl_x\": 50.0", "\"fl_x\": NaN", 1);
    }
    std::fs::write(dir.join("transforms.json"), text).unwrap();
}

#[test]
fn nerfstudio_transforms_reproject_through_opengl_axes_and_the_applied_transform() {
    let tmp = tempfile::tempdir().unwrap();
    let lens = Distortion::radial_tangential(0.04, -0.01, 0.001, -0.0005, 0.0);
    // Cameras 1..4 share camera 1's lens (the file's top level); camera 0 has its own.
    let cams = truth(|i| (general(i.min(1)), lens));
    let src = tmp.path().join("ns");
    write_nerfstudio(&src, &cams, false);
    let (dest, summary) = import_and_reproject(
        Format::Nerfstudio,
        &src,
        &cams,
        |i| format!("cam_{i}"),
        "cam_0,cam_2,cam_3,cam_4".parse().unwrap(),
        1e-6,
    );
    assert_eq!(summary.heldout, ["cam4"]);
    assert_eq!(summary.cameras[4].1, "cam_1");
    assert_eq!(
        std::fs::read_dir(dest.join("raw/cam0")).unwrap().count(),
        2,
        "two frames"
    );

    let bad = tmp.path().join("bad");
    write_nerfstudio(&bad, &cams, true);
    let e = import_error(Format::Nerfstudio, &bad, &tmp.path().join("x"));
    assert!(
        e.contains("transforms.json") && e.contains("NaN") && e.contains("fl_x"),
        "{e}"
    );
}

/// D3DGS's Panoptic: `train_meta.json` / `test_meta.json`, per time step per camera.
fn write_d3dgs(dir: &Path, cams: &[Camera], wrong_size: bool) {
    for (file, ids) in [("train_meta.json", 0..4), ("test_meta.json", 4..5)] {
        let mut k = Vec::new();
        let mut w2c = Vec::new();
        let mut fns = Vec::new();
        let mut cam_ids = Vec::new();
        for t in 0..3 {
            let (mut ks, mut ws, mut fs, mut is) = (vec![], vec![], vec![], vec![]);
            for i in ids.clone() {
                let c = &cams[i];
                let n = &c.intrinsics;
                ks.push(serde_json::json!([
                    [n.fx, 0.0, n.cx],
                    [0.0, n.fy, n.cy],
                    [0.0, 0.0, 1.0]
                ]));
                let r = c.world_to_camera.rotation;
                let tr = c.world_to_camera.translation;
                ws.push(serde_json::json!([
                    [r[0][0], r[0][1], r[0][2], tr[0]],
                    [r[1][0], r[1][1], r[1][2], tr[1]],
                    [r[2][0], r[2][1], r[2][2], tr[2]],
                    [0.0, 0.0, 0.0, 1.0]
                ]));
                let f = format!("{i}/{t:06}.jpg");
                if wrong_size && i == 2 {
                    std::fs::create_dir_all(dir.join("ims").join(i.to_string())).unwrap();
                    image::RgbImage::new(W / 2, H / 2)
                        .save(dir.join("ims").join(&f))
                        .unwrap();
                } else {
                    blank_image(&dir.join("ims").join(&f));
                }
                fs.push(f);
                is.push(i);
            }
            k.push(ks);
            w2c.push(ws);
            fns.push(fs);
            cam_ids.push(is);
        }
        let meta =
            serde_json::json!({"w": W, "h": H, "k": k, "w2c": w2c, "fn": fns, "cam_id": cam_ids});
        std::fs::write(dir.join(file), meta.to_string()).unwrap();
    }
}

#[test]
fn d3dgs_panoptic_meta_reprojects_and_holds_out_its_test_cameras() {
    let tmp = tempfile::tempdir().unwrap();
    let cams = truth(|i| (general(i), Distortion::None));
    let src = tmp.path().join("basketball");
    write_d3dgs(&src, &cams, false);
    let (dest, summary) = import_and_reproject(
        Format::D3dgs,
        &src,
        &cams,
        |i| i.to_string(),
        TrainChoice::Protocol,
        1e-6,
    );
    assert_eq!(
        (summary.training, summary.heldout.clone()),
        (4, vec!["cam4".to_string()])
    );
    assert_eq!(std::fs::read_dir(dest.join("raw/cam4")).unwrap().count(), 3);
    let toml = std::fs::read_to_string(dest.join("capture.toml")).unwrap();
    assert!(toml.contains("image_fps = 30"), "{toml}");

    let bad = tmp.path().join("bad");
    write_d3dgs(&bad, &cams, true);
    let e = import_error(Format::D3dgs, &bad, &tmp.path().join("x"));
    assert!(
        e.contains("train_meta.json")
            && e.contains("camera 2")
            && e.contains("32 × 18")
            && e.contains("64 × 36"),
        "{e}"
    );
}

/// An `!!opencv-matrix` entry as OpenCV's FileStorage writes it.
fn opencv_matrix(rows: usize, cols: usize, data: &[f64]) -> String {
    let values: Vec<String> = data.iter().map(|v| format!("{v:.16e}")).collect();
    format!(
        "!!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {} ]\n",
        values.join(", ")
    )
}

/// EasyVolcap: OpenCV FileStorage YAML, Rodrigues `R_` for some cameras and `Rot_` for
/// others, OpenCV's pixel convention.
fn write_easyvolcap(dir: &Path, cams: &[Camera], drop_k: bool) {
    let matrix = opencv_matrix;
    let mut intri = String::from("%YAML:1.0\n---\nnames:\n");
    let mut extri = String::from("%YAML:1.0\n---\n");
    for i in 0..cams.len() {
        intri += &format!("   - \"{i:02}\"\n");
    }
    for (i, c) in cams.iter().enumerate() {
        let n = &c.intrinsics;
        let k = [n.fx, 0.0, n.cx - 0.5, 0.0, n.fy, n.cy - 0.5, 0.0, 0.0, 1.0];
        if !(drop_k && i == 1) {
            intri += &format!("K_{i:02}: {}", matrix(3, 3, &k));
        }
        intri += &format!(
            "dist_{i:02}: {}",
            matrix(1, 5, &c.distortion.coefficients())
        );
        let r = c.world_to_camera.rotation();
        if i % 2 == 0 {
            let (axis, angle) = DQuat::from_mat3(&r).to_axis_angle();
            extri += &format!("R_{i:02}: {}", matrix(3, 1, &(axis * angle).to_array()));
        } else {
            extri += &format!(
                "Rot_{i:02}: {}",
                matrix(3, 3, c.world_to_camera.rotation.as_flattened())
            );
        }
        extri += &format!("T_{i:02}: {}", matrix(3, 1, &c.world_to_camera.translation));
        blank_image(&dir.join(format!("images/{i:02}/000000.jpg")));
        blank_image(&dir.join(format!("images/{i:02}/000001.jpg")));
    }
    std::fs::write(dir.join("intri.yml"), intri).unwrap();
    std::fs::write(dir.join("extri.yml"), extri).unwrap();
}

#[test]
fn easyvolcap_yaml_reprojects_with_rodrigues_or_matrix_rotations() {
    let tmp = tempfile::tempdir().unwrap();
    let cams = truth(|i| {
        (
            general(i),
            Distortion::radial_tangential(0.02 * i as f64, 0.0, 0.0005, 0.0, 0.001),
        )
    });
    let src = tmp.path().join("zju");
    write_easyvolcap(&src, &cams, false);
    import_and_reproject(
        Format::Easyvolcap,
        &src,
        &cams,
        |i| format!("{i:02}"),
        TrainChoice::Farthest(4),
        1e-6,
    );
    let bad = tmp.path().join("bad");
    write_easyvolcap(&bad, &cams, true);
    let e = import_error(Format::Easyvolcap, &bad, &tmp.path().join("x"));
    assert!(
        e.contains("intri.yml") && e.contains("`K_01` is missing"),
        "{e}"
    );
}

/// The command line: a summary of the cameras, and the next command.
#[test]
fn the_import_command_names_the_cameras_and_the_next_step() {
    let tmp = tempfile::tempdir().unwrap();
    let cams = truth(|i| (centred(48.0 + i as f64), Distortion::None));
    let src = tmp.path().join("n3v");
    write_n3v(&src, &cams, false);
    let dest = tmp.path().join("cap");
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .args(["import", "n3v"])
        .arg(&src)
        .arg(&dest)
        .args(["--train", "farthest:4"])
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{said}");
    assert!(
        said.contains("training cameras: cam0 (cam00)") && said.contains("next: pipeline run"),
        "{said}"
    );
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .args(["import", "n3v"])
        .arg(&src)
        .arg(tmp.path().join("cap2"))
        .args(["--frames", "10..5"])
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&out.stderr).contains("END must be after FIRST"));
}

/// The one file of a folder (a camera's video).
fn first_file(folder: &Path) -> PathBuf {
    std::fs::read_dir(folder)
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path()
}

/// A Neural 3D Video dataset made of the tiny simulated capture (its four videos, its true
/// cameras as LLFF poses) imports and runs through `pipeline run` to a trained model.
#[test]
fn an_imported_n3v_dataset_runs_through_the_pipeline_to_a_model() {
    let tmp = tempfile::tempdir().unwrap();
    let tiny = crate::common::tiny_capture(&tmp.path().join("tiny"), "");
    let set = calib::import::import_calibration(&tiny.join("calibration.json")).unwrap();
    let src = tmp.path().join("n3v");
    std::fs::create_dir_all(&src).unwrap();
    let mut data = Vec::new();
    for i in 0..4 {
        let c = set.get(&format!("cam{i}")).unwrap();
        let k = &c.intrinsics;
        assert!(
            k.fx == k.fy && k.cx == k.width as f64 / 2.0 && k.cy == k.height as f64 / 2.0,
            "LLFF holds one focal length and a centred principal point: {k:?}"
        );
        let c2w = c.world_to_camera.rotation().transpose();
        let cols = [
            c2w.y_axis,
            c2w.x_axis,
            -c2w.z_axis,
            c.world_to_camera.centre(),
        ];
        let hwf = [k.height as f64, k.width as f64, k.fx];
        for r in 0..3 {
            cols.iter().for_each(|col| data.push(col[r]));
            data.push(hwf[r]);
        }
        data.extend([0.5, 20.0]);
        let video = first_file(&tiny.join(format!("raw/cam{i}")));
        std::fs::copy(video, src.join(format!("cam{i:02}.mp4"))).unwrap();
    }
    npy_f64(&src.join("poses_bounds.npy"), 4, 17, &data);
    let dest = tmp.path().join("capture");
    let summary = import(&Request {
        format: Format::N3v,
        source: src,
        dest: dest.clone(),
        train: "cam00,cam01,cam02,cam03".parse().unwrap(),
        frames: Some((0, 10)),
        long_side: Some(160),
        copy: false,
    })
    .unwrap();
    assert_eq!(summary.training, 4);
    // The test's short schedule (everything but `[sync]`, which the import wrote).
    let cheap = crate::common::CHEAP.replace("[sync]\nmethod = \"timestamps\"\n", "");
    let mut toml = std::fs::read_to_string(dest.join("capture.toml")).unwrap();
    toml = toml.replace("[frames]\n", &format!("{cheap}[frames]\n"));
    std::fs::write(dest.join("capture.toml"), toml).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
        .args(["--quiet", "run"])
        .arg(&dest)
        .args(["--to", "train"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let frames: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dest.join("work/frames/frames.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(
        frames["frames"].as_array().unwrap().len(),
        10,
        "--frames 0..10"
    );
    assert!(dest.join("work/train/model.bin").is_file());
    let poses = std::fs::read_to_string(dest.join("work/poses/cameras.json")).unwrap();
    assert!(poses.contains("cam3"), "{poses}");
}

/// `transforms.json` is ours to write too (the export stage writes one): written for known
/// cameras over a frames index and read back by the importer, it gives the same cameras.
#[test]
fn transforms_json_written_for_a_capture_reads_back_as_the_same_cameras() {
    let tmp = tempfile::tempdir().unwrap();
    let lens = Distortion::radial_tangential(0.03, -0.02, 0.0004, 0.0002, 0.001);
    let mut cams = truth(|i| (general(i), if i == 3 { Distortion::None } else { lens }));
    cams[4].distortion = Distortion::Fisheye {
        k1: 0.1,
        k2: -0.02,
        k3: 0.003,
        k4: 0.0,
    };
    let names: Vec<String> = (0..5).map(|i| format!("cam{i}")).collect();
    for (c, n) in cams.iter_mut().zip(&names) {
        c.name = n.clone();
    }
    let frames: Vec<rig::frames::AlignedFrame> = (0..2)
        .map(|k| rig::frames::AlignedFrame {
            index: k,
            time_s: k as f64 / 30.0,
            views: names
                .iter()
                .map(|n| rig::frames::View {
                    source_frame: k,
                    timestamp_s: k as f64 / 30.0,
                    residual_s: 0.0,
                    file: format!("{n}/{k:06}.png"),
                })
                .collect(),
        })
        .collect();
    let index = rig::frames::FramesIndex {
        fps: 30.0,
        start_s: 0.0,
        cameras: names
            .iter()
            .map(|n| rig::frames::CameraImages {
                name: n.clone(),
                width: W,
                height: H,
            })
            .collect(),
        frames,
        warnings: Vec::new(),
    };
    let work = tmp.path().join("work");
    for n in &names {
        for k in 0..2 {
            blank_image(&work.join(format!("frames/{n}/{k:06}.png")));
        }
    }
    let value = pipeline::import::nerfstudio::transforms(&cams, &index, "../frames").unwrap();
    std::fs::create_dir_all(work.join("export")).unwrap();
    std::fs::write(work.join("export/transforms.json"), value.to_string()).unwrap();
    let back = pipeline::import::nerfstudio::read(&work.join("export")).unwrap();
    for c in &cams {
        let got = back.cameras.iter().find(|b| b.name == c.name).unwrap();
        assert_eq!(
            (got.intrinsics, got.distortion),
            (c.intrinsics, c.distortion)
        );
        for p in POINTS {
            let p = DVec3::from_array(p);
            let (a, b) = (c.project(p).unwrap().0, got.project(p).unwrap().0);
            assert!(a.distance(b) < 1e-9, "{}: {a} vs {b}", c.name);
        }
        let pipeline::import::Footage::Images(list) = &back.footage[&c.name] else {
            panic!("images")
        };
        assert_eq!(list.len(), 2);
    }
    // A lens transforms.json cannot hold is refused, naming the camera.
    cams[1].distortion =
        Distortion::from_opencv_coefficients(&[0.1, 0.0, 0.0, 0.0, 0.0, 0.2, 0.0, 0.0]).unwrap();
    let e = pipeline::import::nerfstudio::transforms(&cams, &index, "../frames").unwrap_err();
    assert!(e.contains("camera cam1") && e.contains("rational"), "{e}");
}

/// The tiny simulated capture's frames as images (ffmpeg, as a dataset's tool extracts
/// them) under D3DGS's, nerfstudio's and EasyVolcap's layouts: each imports and trains.
#[test]
fn image_datasets_of_every_layout_import_and_train() {
    let tmp = tempfile::tempdir().unwrap();
    let tiny = crate::common::tiny_capture(&tmp.path().join("tiny"), "");
    let set = calib::import::import_calibration(&tiny.join("calibration.json")).unwrap();
    let cams: Vec<Camera> = (0..4)
        .map(|i| set.get(&format!("cam{i}")).unwrap().clone())
        .collect();
    let frames = tmp.path().join("frames");
    for i in 0..4 {
        let video = first_file(&tiny.join(format!("raw/cam{i}")));
        let out = frames.join(i.to_string());
        std::fs::create_dir_all(&out).unwrap();
        let status = Command::new("ffmpeg")
            .args(["-v", "error", "-i"])
            .arg(&video)
            .args(["-frames:v", "8", "-start_number", "0"])
            .arg(out.join("%06d.png"))
            .status()
            .unwrap();
        assert!(status.success());
    }
    let image = |i: usize, t: usize| frames.join(format!("{i}/{t:06}.png"));
    let copy = |from: &Path, to: &Path| {
        std::fs::create_dir_all(to.parent().unwrap()).unwrap();
        std::fs::copy(from, to).unwrap();
    };
    let (w, h) = (cams[0].intrinsics.width, cams[0].intrinsics.height);

    // D3DGS: every camera in train_meta.json.
    let d3dgs = tmp.path().join("d3dgs");
    let per_step = |f: &dyn Fn(usize, &Camera) -> serde_json::Value| {
        (0..8)
            .map(|t| {
                (cams.iter().enumerate())
                    .map(|(i, c)| f(i * 100 + t, c))
                    .collect::<Vec<_>>()
            })
            .collect::<Vec<_>>()
    };
    let meta = serde_json::json!({
        "w": w, "h": h,
        "k": per_step(&|_, c| {
            let k = &c.intrinsics;
            serde_json::json!([[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]])
        }),
        "w2c": per_step(&|_, c| {
            let (r, t) = (c.world_to_camera.rotation, c.world_to_camera.translation);
            serde_json::json!([
                [r[0][0], r[0][1], r[0][2], t[0]],
                [r[1][0], r[1][1], r[1][2], t[1]],
                [r[2][0], r[2][1], r[2][2], t[2]],
                [0.0, 0.0, 0.0, 1.0]
            ])
        }),
        "fn": per_step(&|it, _| format!("{}/{:06}.png", it / 100, it % 100).into()),
        "cam_id": per_step(&|it, _| (it / 100).into()),
    });
    for i in 0..4 {
        for t in 0..8 {
            copy(&image(i, t), &d3dgs.join(format!("ims/{i}/{t:06}.png")));
        }
    }
    std::fs::write(d3dgs.join("train_meta.json"), meta.to_string()).unwrap();

    // nerfstudio: a folder per camera.
    let ns = tmp.path().join("ns");
    let mut ns_frames = Vec::new();
    for (i, c) in cams.iter().enumerate() {
        let c2w = c.world_to_camera.rotation().transpose();
        let (x, y, z, o) = (
            c2w.x_axis,
            -c2w.y_axis,
            -c2w.z_axis,
            c.world_to_camera.centre(),
        );
        let row = |r: usize| [x[r], y[r], z[r], o[r]];
        for t in 0..8 {
            let file = format!("images/cam_{i}/{t:06}.png");
            copy(&image(i, t), &ns.join(&file));
            let k = &c.intrinsics;
            ns_frames.push(serde_json::json!({
                "file_path": file,
                "transform_matrix": [row(0), row(1), row(2), [0.0, 0.0, 0.0, 1.0]],
                "fl_x": k.fx, "fl_y": k.fy, "cx": k.cx, "cy": k.cy, "w": w, "h": h,
            }));
        }
    }
    std::fs::write(
        ns.join("transforms.json"),
        serde_json::json!({"frames": ns_frames}).to_string(),
    )
    .unwrap();

    // EasyVolcap: rotation matrices, OpenCV's pixel convention.
    let ev = tmp.path().join("ev");
    let m = opencv_matrix;
    let mut intri = String::from("%YAML:1.0\n---\nnames: [ \"a\", \"b\", \"c\", \"d\" ]\n");
    let mut extri = String::from("%YAML:1.0\n---\n");
    for (i, (c, n)) in cams.iter().zip(["a", "b", "c", "d"]).enumerate() {
        let k = &c.intrinsics;
        intri += &format!(
            "K_{n}: {}",
            m(
                3,
                3,
                &[k.fx, 0.0, k.cx - 0.5, 0.0, k.fy, k.cy - 0.5, 0.0, 0.0, 1.0]
            )
        );
        extri += &format!(
            "Rot_{n}: {}",
            m(3, 3, c.world_to_camera.rotation.as_flattened())
        );
        extri += &format!("T_{n}: {}", m(3, 1, &c.world_to_camera.translation));
        for t in 0..8 {
            copy(&image(i, t), &ev.join(format!("images/{n}/{t:06}.png")));
        }
    }
    std::fs::write(ev.join("intri.yml"), intri).unwrap();
    std::fs::write(ev.join("extri.yml"), extri).unwrap();

    let cheap = crate::common::CHEAP.replace("[sync]\nmethod = \"timestamps\"\n", "");
    for (format, src) in [
        (Format::D3dgs, d3dgs),
        (Format::Nerfstudio, ns),
        (Format::Easyvolcap, ev),
    ] {
        let dest = tmp.path().join(format!("{format:?}-capture"));
        let summary = import(&plain(format, src, dest.clone(), TrainChoice::Protocol)).unwrap();
        assert_eq!(summary.training, 4, "{format:?}");
        let toml = std::fs::read_to_string(dest.join("capture.toml")).unwrap() + &cheap;
        std::fs::write(dest.join("capture.toml"), toml).unwrap();
        let out = Command::new(env!("CARGO_BIN_EXE_pipeline"))
            .args(["--quiet", "run"])
            .arg(&dest)
            .args(["--to", "train"])
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{format:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(dest.join("work/train/model.bin").is_file(), "{format:?}");
    }
}
