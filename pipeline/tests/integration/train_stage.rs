//! The train and export stages on a small simulated capture (sync-audio, 160×120) with an
//! imported calibration: exact timestamps, the trained model, a clean stop with a
//! checkpoint that the next run continues bit-identically, cameras of unequal exposure
//! equalised, and the exports.
//! One test in its own binary: it uses the process-wide stop request.

use crate::common;

use common::fixture;
use std::fs;
use std::path::Path;

use pipeline::report::{OutputMode, Reporter};
use pipeline::runner::{RunSummary, Selection};
use pipeline::{engine_inputs, interrupt, simulate};

fn run(root: &Path, sel: Selection) -> RunSummary {
    common::run_stages(root, sel)
}

#[test]
fn train_stops_cleanly_resumes_identically_and_exports() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("capture");
    let mut scene = rig::sim::Scene::from_file(&fixture("sync-audio.toml")).unwrap();
    // Two cameras film brighter and darker than the others (geometric mean 1): training
    // sees their frames equalised.
    let exposures = [1.0, 1.25, 0.8, 1.0];
    let video: Vec<&mut rig::sim::SimCamera> = scene
        .cameras
        .iter_mut()
        .filter(|c| c.role == rig::sim::CameraRole::Video)
        .collect();
    assert_eq!(video.len(), exposures.len());
    for (cam, e) in video.into_iter().zip(exposures) {
        cam.exposure = e;
    }
    simulate::simulate_into(&scene, &root, &Reporter::new(OutputMode::Quiet)).unwrap();
    simulate::write_truth_calibration(&root).unwrap();
    fs::write(
        root.join("capture.toml"),
        "[train]\niterations = 24\nbatch_size = 2\ncheckpoint_every = 8\ndegree_every = 4\n\
         [train.densify]\nfrom_iteration = 4\nuntil_iteration = 16\nevery = 6\nopacity_reset_every = 0\n\
         [export]\nsteps = 3\nviewer = false\nframes = true\nsplatv = true\n",
    )
    .unwrap();
    let summary = run(
        &root,
        Selection {
            to: Some("init".into()),
            ..Default::default()
        },
    );
    assert!(summary.failed.is_none(), "{summary:?}");

    // The views: every camera of every aligned frame, at its exact timestamp.
    let dataset = engine_inputs::load_dataset(
        &root.join("work/frames"),
        &root.join("work/poses/cameras.json"),
        &shared_types::NoProgress,
    )
    .unwrap();
    let index = rig::frames::FramesIndex::read_json(&root.join("work/frames/frames.json")).unwrap();
    assert_eq!(dataset.views.len(), 4 * index.frames.len());
    let mapping = engine_inputs::time_mapping(&index);
    for (view, source) in dataset
        .views
        .iter()
        .zip(index.frames.iter().flat_map(|f| &f.views))
    {
        let expected = mapping.model_time(source.timestamp_s) as f32;
        assert_eq!(view.time, expected);
        assert!(view.camera.distortion.is_none());
        assert_eq!(view.image.width, view.camera.intrinsics.width);
    }

    // A stop request: the stage stops after its first iteration with a checkpoint and
    // reports how to continue; the model is not written.
    interrupt::request_stop();
    let stopped = run(&root, common::only("train", false));
    let (stage, error) = stopped.failed.expect("stopped");
    assert_eq!(stage, "train");
    assert!(
        error.contains("run the same `pipeline run` again"),
        "{error}"
    );
    assert!(!root.join("work/train/model.bin").exists());
    assert!(root.join("work/.train.partial/ckpt").is_dir());

    // The next run continues from that checkpoint …
    let resumed = run(&root, common::only("train", false));
    assert_eq!(resumed.ran, ["train"], "{resumed:?}");
    let resumed_model = fs::read(root.join("work/train/model.bin")).unwrap();
    let log = fs::read_to_string(root.join("work/train/log.csv")).unwrap();
    assert_eq!(
        log.lines().count(),
        1 + 24,
        "one header and one row per iteration"
    );

    // … to exactly the model of an uninterrupted run.
    let fresh = run(&root, common::only("train", true));
    assert_eq!(fresh.ran, ["train"]);
    assert_eq!(
        fs::read(root.join("work/train/model.bin")).unwrap(),
        resumed_model
    );
    let model = splat4d::load_model(&root.join("work/train/model.bin")).unwrap();
    assert!(!model.is_empty());
    // The exposure gains the frames were divided by, measured on the init's static points.
    let record: engine_inputs::TrainRecord =
        serde_json::from_str(&fs::read_to_string(root.join("work/train/train.json")).unwrap())
            .unwrap();
    assert_eq!(record.exposure.len(), exposures.len());
    for (g, e) in record.exposure.iter().zip(exposures) {
        for v in g.gain {
            assert!(
                (v as f64 / e - 1.0).abs() < 0.03,
                "{}: {:?} against {e}",
                g.camera,
                g.gain
            );
        }
    }
    assert_eq!(model.time, mapping);
    // What the decay did: the default constant decay (no f_θ to report); the opacity
    // histogram counts every Gaussian.
    let decay: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(root.join("work/train/decay.json")).unwrap())
            .unwrap();
    assert_eq!(decay["variant"], "constant");
    assert_eq!(decay["gaussians"], model.len());
    let histogram = decay["opacity"]["histogram"].as_array().unwrap();
    let counted: u64 = histogram.iter().map(|c| c.as_u64().unwrap()).sum();
    assert_eq!(counted as usize, model.len());
    assert!(decay["neural"].is_null(), "{decay}");

    // Export: three time steps as 3DGS PLY, the 4D PLY, the .splatv.
    let exported = run(&root, common::only("export", false));
    assert_eq!(exported.ran, ["export"], "{exported:?}");
    let report: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(root.join("work/export/export.json")).unwrap())
            .unwrap();
    assert_eq!(report["frames"].as_array().unwrap().len(), 3);
    // The paths it records are the final ones, relative to work/export/ (the stage writes
    // into work/.export.partial/, renamed when complete).
    let mut paths: Vec<&str> = report["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["path"].as_str().unwrap())
        .collect();
    paths.extend(["model4d", "splatv"].map(|k| report[k].as_str().unwrap()));
    paths.push(report["gltf"][0][0].as_str().unwrap());
    assert_eq!(
        paths,
        [
            "frames/0000.ply",
            "frames/0001.ply",
            "frames/0002.ply",
            "model4d.ply",
            "scene.splatv",
            "scene.glb"
        ]
    );
    for p in paths {
        assert!(root.join("work/export").join(p).is_file(), "{p}");
    }
    assert!(root.join("work/export/model4d.ply").is_file());
    assert!(root.join("work/export/scene.splatv").is_file());
    let reloaded = splat4d::export::read_model_ply(&root.join("work/export/model4d.ply")).unwrap();
    assert_eq!(reloaded.len(), model.len());
    // The cameras for nerfstudio: every camera, each frame's image found from work/export/.
    let back = pipeline::import::nerfstudio::read(&root.join("work/export")).unwrap();
    let frames: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(root.join("work/frames/frames.json")).unwrap())
            .unwrap();
    assert_eq!(
        back.cameras.len(),
        frames["cameras"].as_array().unwrap().len()
    );
    for images in back.footage.values() {
        let pipeline::import::Footage::Images(list) = images else {
            panic!("images")
        };
        assert_eq!(list.len(), frames["frames"].as_array().unwrap().len());
    }
}
