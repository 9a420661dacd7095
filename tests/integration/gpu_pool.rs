//! Scratch buffers come back to the pool and are reused (`Gpu::scratch`), and reuse leaks
//! nothing: a frame rendered (and differentiated) after other scenes dirtied the pooled
//! buffers is the same to the bit as the first time.

use crate::common::{self, SceneSpec, camera, random_scene};
use splat4d::render::RenderBackend;
use splat4d::{Gradients, ImageGradients, RenderOptions};

#[test]
fn gpu_scratch_buffers_are_reused_by_bucket() {
    let Some(backend) = common::gpu("GPU pool test") else {
        return;
    };
    let gpu = backend.gpu();
    let first = gpu.scratch(1000, "a");
    let size = first.size();
    assert_eq!(size, 1024);
    let before = gpu.pooled();
    drop(first);
    let after = gpu.pooled();
    assert_eq!(after.0, before.0 + 1);
    assert_eq!(after.1, before.1 + 1024);
    // 1010 bytes fall in the same bucket: the idle buffer is handed out again.
    let again = gpu.scratch(1010, "b");
    assert_eq!(again.size(), 1024);
    assert_eq!(gpu.pooled(), before);
    // A different bucket makes a new buffer.
    let other = gpu.scratch(5000, "c");
    assert!(other.size() >= 5000 && other.size() < 5000 * 9 / 8);
}

#[test]
fn gpu_frames_after_reuse_are_the_same_to_the_bit() {
    let Some(gpu) = common::gpu("GPU pool test") else {
        return;
    };
    // Opaque enough that pixels saturate, so that tiles leave entries unused (whose
    // pooled per-tile gradients must not keep an earlier scene's values).
    let scene = |seed, count| {
        random_scene(
            seed,
            SceneSpec {
                count,
                logit: (3.0, 6.0),
                ..SceneSpec::default()
            },
        )
        .cast::<f32>()
    };
    // Scenes of one size: their buffers fall in the same buckets.
    let (small, other) = (scene(3, 1500), scene(4, 1500));
    let cam = camera(64, 48);
    let opts = RenderOptions::default();
    let rgb: Vec<f32> = (0..3 * 64 * 48)
        .map(|i| ((i % 13) as f32 - 6.0) * 0.01)
        .collect();
    let up = ImageGradients {
        rgb: &rgb,
        alpha: None,
        depth: None,
    };
    let run = || {
        let frame = gpu.render(&small, &cam, 0.5, &opts).unwrap();
        let mut g = Gradients::zeros_like(&small, false);
        gpu.backward(&small, &frame, &up, &mut g).unwrap();
        (frame.rgb, frame.alpha, g)
    };
    let first = run();
    // Dirty the pool: another scene, at several times, with its backward.
    for t in [0.2f32, 0.5, 0.8] {
        let frame = gpu.render(&other, &cam, t, &opts).unwrap();
        let mut g = Gradients::zeros_like(&other, false);
        gpu.backward(&other, &frame, &up, &mut g).unwrap();
    }
    assert!(gpu.gpu().pooled().0 > 0, "nothing came back to the pool");
    let second = run();
    assert!(first.0 == second.0, "the image changed after reuse");
    assert!(first.1 == second.1, "the alpha changed after reuse");
    assert!(first.2 == second.2, "the gradients changed after reuse");
}
