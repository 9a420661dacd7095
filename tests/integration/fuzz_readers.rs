//! Fuzzed readers of the engine's files: the model file (`model.bin`), the 4D model PLY,
//! the per-time-step 3DGS PLY and glTF time step, the viewer's `model.4dgs`. Damaged copies of valid files (`shared_types::fuzz`)
//! must give an error or a model, never a panic, an abort or an allocation a damaged
//! count asked for. `PROPTEST_CASES` sets the number of cases.

use crate::common::{SceneSpec, random_scene};

use proptest::prelude::*;
use shared_types::fuzz::{self, damaged, within_budget};
use splat4d::export::bake::bake_frame;
use splat4d::export::gltf::{encode_glb, read_glb};
use splat4d::export::ply3d::{read_frame_ply, write_frame_ply};
use splat4d::export::ply4d::{read_model_ply, write_model_ply};
use splat4d::export::web4d;
use splat4d::model::Gaussians;
use splat4d::model::file::{parse_model, save_model};

fn model() -> Gaussians<f32> {
    random_scene(
        5,
        SceneSpec {
            count: 6,
            ..SceneSpec::default()
        },
    )
    .cast()
}

/// The bytes `write` puts in a file.
fn written(write: impl FnOnce(&std::path::Path)) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("file");
    write(&path);
    std::fs::read(&path).unwrap()
}

/// `bytes` as a file named `name`, read back by `read`.
fn read_as<T>(
    name: &str,
    bytes: &[u8],
    read: impl FnOnce(&std::path::Path) -> T,
) -> Result<(), TestCaseError> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    within_budget(|| read(&path))
}

proptest! {
    #![proptest_config(fuzz::config(1))]

    #[test]
    fn model_file(bytes in damaged(written(|p| save_model(&model(), p).unwrap()))) {
        within_budget(|| parse_model(&bytes, std::path::Path::new("model.bin")))?;
    }

    #[test]
    fn model_ply(bytes in damaged(written(|p| write_model_ply(&model(), p).unwrap()))) {
        read_as("model.ply", &bytes, read_model_ply)?;
    }

    #[test]
    fn frame_ply(bytes in damaged(written(|p| {
        write_frame_ply(&bake_frame(&model(), 0.5, 0.0), p).unwrap()
    }))) {
        read_as("frame.ply", &bytes, read_frame_ply)?;
    }

    #[test]
    fn gltf_time_step(bytes in damaged(encode_glb(&bake_frame(&model(), 0.5, 0.0)))) {
        within_budget(|| read_glb(&bytes, std::path::Path::new("step.glb")))?;
    }

    #[test]
    fn viewer_model(bytes in damaged(web4d::encode(&model(), [0.0, 1.0], 0.0).bytes)) {
        within_budget(|| web4d::decode(&bytes))?;
    }
}
