//! Interrupt/resume gives a bit-identical model (and learned backdrop); the NaN guard stops
//! with a clear error and keeps the last good checkpoint; bad inputs are typed errors.

use crate::train_scene;

use splat4d::CpuBackend;
use splat4d::Gaussians;
use splat4d::NoProgress;
use splat4d::metrics::{mse, psnr_from_mse};
use splat4d::render::backdrop::{Backdrop, load_backdrop};
use splat4d::train::{NoHooks, TrainConfig, TrainError, TrainHooks, train};
use splat4d::{RenderBackend, RenderOptions, load_model};

fn config(iterations: u64) -> TrainConfig {
    let mut c = TrainConfig {
        iterations,
        checkpoint_every: 10,
        batch_size: 2,
        seed: 7,
        ..Default::default()
    };
    c.degree_every = 8;
    c.densify.from_iteration = 5;
    c.densify.every = 10;
    c.densify.opacity_reset_every = 15;
    c.densify.grad_threshold = 2e-5;
    c.densify.max_world_size = 10.0;
    c
}

#[test]
fn resumed_run_is_bit_identical_to_a_straight_run() {
    let data = train_scene::dataset(32, 24);
    let init = train_scene::points(12, 9, &[0.0, 1.0]);
    let straight = tempfile::tempdir().unwrap();
    train(
        &CpuBackend,
        &config(40),
        &data,
        &init,
        straight.path(),
        false,
        &mut NoHooks,
        &NoProgress,
    )
    .unwrap();

    let a = std::fs::read(straight.path().join("model.bin")).unwrap();
    let log = std::fs::read_to_string(straight.path().join("log.csv")).unwrap();
    let counts: Vec<&str> = log
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(5).unwrap())
        .collect();
    assert_ne!(
        counts[0], counts[39],
        "the run densifies/prunes, so resume must carry that state"
    );

    // Interrupted after 17 iterations (stop request: checkpoint 17), then resumed.
    let resumed = tempfile::tempdir().unwrap();
    let e = train(
        &CpuBackend,
        &config(40),
        &data,
        &init,
        resumed.path(),
        false,
        &mut StopAt(17),
        &NoProgress,
    )
    .unwrap_err();
    assert!(
        matches!(e, TrainError::Interrupted { iteration: 17, .. }),
        "{e}"
    );
    assert!(!resumed.path().join("model.bin").exists());
    let s = train(
        &CpuBackend,
        &config(40),
        &data,
        &init,
        resumed.path(),
        true,
        &mut NoHooks,
        &NoProgress,
    )
    .unwrap();
    assert_eq!(s.started_at, 17);
    let b = std::fs::read(resumed.path().join("model.bin")).unwrap();
    assert_eq!(a, b, "resumed model differs from the straight run");
    let log_b = std::fs::read_to_string(resumed.path().join("log.csv")).unwrap();
    assert_eq!(
        log_b.lines().count(),
        41,
        "one header + one row per iteration"
    );

    // Killed hard after 25 (only the periodic checkpoint 20 survives): same result.
    let killed = tempfile::tempdir().unwrap();
    let e = train(
        &CpuBackend,
        &config(40),
        &data,
        &init,
        killed.path(),
        false,
        &mut StopAt(25),
        &NoProgress,
    )
    .unwrap_err();
    assert!(matches!(e, TrainError::Interrupted { iteration: 25, .. }));
    let ckpt = killed.path().join("ckpt");
    std::fs::remove_file(ckpt.join("000025.bin")).unwrap();
    std::fs::remove_file(ckpt.join("000025.state")).unwrap();
    let s = train(
        &CpuBackend,
        &config(40),
        &data,
        &init,
        killed.path(),
        true,
        &mut NoHooks,
        &NoProgress,
    )
    .unwrap();
    assert_eq!(s.started_at, 20);
    assert_eq!(a, std::fs::read(killed.path().join("model.bin")).unwrap());
}

/// Pseudo views change the trained model, and a run with them resumes bit-identically (the
/// virtual camera's direction comes from the seed, the iteration and the view).
#[test]
fn pseudo_views_train_and_resume_bit_identically() {
    let data = train_scene::dataset(32, 24);
    let init = train_scene::points(12, 9, &[0.0, 1.0]);
    let mut with = config(30);
    with.pseudo_views.weight = 0.3;
    with.pseudo_views.start = 0.2;
    let run = |c: &TrainConfig, hooks: &mut dyn TrainHooks, dir: &std::path::Path, resume| {
        train(
            &CpuBackend,
            c,
            &data,
            &init,
            dir,
            resume,
            hooks,
            &NoProgress,
        )
    };
    let (off, straight, resumed) = (
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
    );
    let mut without = config(30);
    without.pseudo_views.weight = 0.0;
    run(&without, &mut NoHooks, off.path(), false).unwrap();
    run(&with, &mut NoHooks, straight.path(), false).unwrap();
    let e = run(&with, &mut StopAt(17), resumed.path(), false).unwrap_err();
    assert!(
        matches!(e, TrainError::Interrupted { iteration: 17, .. }),
        "{e}"
    );
    assert_eq!(
        run(&with, &mut NoHooks, resumed.path(), true)
            .unwrap()
            .started_at,
        17
    );
    let model = |d: &tempfile::TempDir| std::fs::read(d.path().join("model.bin")).unwrap();
    assert_ne!(
        model(&off),
        model(&straight),
        "pseudo views changed nothing"
    );
    assert_eq!(model(&straight), model(&resumed), "resumed model differs");
}

/// Damaged checkpoints (a truncated model, a zeroed state, a bit flip, another format
/// version, another capture's) are each named, set aside as `*.damaged`, and the run resumes
/// from the newest good one, or starts over when none is left: the same model either way.
#[test]
fn damaged_checkpoints_are_named_set_aside_and_resumed_past() {
    let data = train_scene::dataset(32, 24);
    let init = train_scene::points(12, 9, &[0.0, 1.0]);
    let cfg = TrainConfig {
        checkpoint_every: 5,
        keep_checkpoints: 10,
        ..config(40)
    };
    let run = |dir: &std::path::Path, hooks: &mut dyn TrainHooks, resume: bool| {
        train(
            &CpuBackend,
            &cfg,
            &data,
            &init,
            dir,
            resume,
            hooks,
            &NoProgress,
        )
    };
    let straight = tempfile::tempdir().unwrap();
    run(straight.path(), &mut NoHooks, false).unwrap();
    let want = std::fs::read(straight.path().join("model.bin")).unwrap();

    // Another capture's checkpoint 30: the same settings on other cameras.
    let other = tempfile::tempdir().unwrap();
    let other_data = train_scene::dataset(40, 30);
    train(
        &CpuBackend,
        &cfg,
        &other_data,
        &init,
        other.path(),
        false,
        &mut StopAt(30),
        &NoProgress,
    )
    .unwrap_err();

    let dir = tempfile::tempdir().unwrap();
    run(dir.path(), &mut StopAt(37), false).unwrap_err();
    let ckpt = dir.path().join("ckpt");
    let file = |it: u64, ext: &str| ckpt.join(format!("{it:06}.{ext}"));
    let len = |p: &std::path::Path| std::fs::metadata(p).unwrap().len();
    // 37: the model cut short. 35: the state zeroed. 30: another capture's pair.
    // 25: one bit flipped in the middle of the state. 20: an older format version.
    std::fs::File::options()
        .write(true)
        .open(file(37, "bin"))
        .unwrap()
        .set_len(len(&file(37, "bin")) / 2)
        .unwrap();
    std::fs::write(
        file(35, "state"),
        vec![0u8; len(&file(35, "state")) as usize],
    )
    .unwrap();
    for ext in ["bin", "state"] {
        let theirs = other.path().join(format!("ckpt/000030.{ext}"));
        std::fs::copy(theirs, file(30, ext)).unwrap();
    }
    let mut bytes = std::fs::read(file(25, "state")).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x10;
    std::fs::write(file(25, "state"), &bytes).unwrap();
    let mut bytes = std::fs::read(file(20, "state")).unwrap();
    bytes[8..12].copy_from_slice(&1u32.to_le_bytes());
    std::fs::write(file(20, "state"), &bytes).unwrap();

    let s = run(dir.path(), &mut NoHooks, true).unwrap();
    assert_eq!(s.started_at, 15, "15 is the newest good checkpoint");
    assert_eq!(want, std::fs::read(dir.path().join("model.bin")).unwrap());
    let said: Vec<String> = s
        .skipped_checkpoints
        .iter()
        .map(|k| k.to_string())
        .collect();
    let expect = [
        (37, "bin", "not the model its state file"),
        (35, "state", "not a training state"),
        (30, "state", "made for other views"),
        (25, "state", "checksum does not match"),
        (20, "state", "another version of the program (format 1"),
    ];
    assert_eq!(said.len(), expect.len(), "{said:#?}");
    for ((it, ext, why), text) in expect.iter().zip(&said) {
        let name = file(*it, ext).display().to_string();
        assert!(text.contains(&name) && text.contains(why), "{text}");
        for e in ["bin", "state"] {
            let aside = ckpt.join(format!("{it:06}.{e}.damaged"));
            assert!(
                aside.exists() && text.contains(&aside.display().to_string()),
                "{text}"
            );
        }
    }

    // Nothing good left: every pair damaged, the run starts over and still ends the same.
    for it in splat4d::train::checkpoint::list(&ckpt) {
        std::fs::write(file(it, "bin"), b"").unwrap();
    }
    std::fs::remove_file(dir.path().join("model.bin")).unwrap();
    let s = run(dir.path(), &mut NoHooks, true).unwrap();
    assert_eq!(s.started_at, 0);
    assert_eq!(
        s.skipped_checkpoints.len(),
        8,
        "{:#?}",
        s.skipped_checkpoints
    );
    assert_eq!(want, std::fs::read(dir.path().join("model.bin")).unwrap());
}

struct StopAt(u64);
impl TrainHooks for StopAt {
    fn stop_requested(&mut self, iteration: u64) -> bool {
        iteration == self.0
    }
}

/// Poisons the model at one iteration, as a diverging run would.
struct Poison(u64);
impl TrainHooks for Poison {
    fn after_step(&mut self, iteration: u64, model: &mut Gaussians<f32>) {
        if iteration == self.0 {
            model.means[3][0] = f32::NAN;
        }
    }
}

#[test]
fn nan_guard_stops_and_keeps_the_last_good_checkpoint() {
    let data = train_scene::dataset(32, 24);
    let init = train_scene::points(12, 9, &[0.0, 1.0]);
    let dir = tempfile::tempdir().unwrap();
    let err = train(
        &CpuBackend,
        &config(30),
        &data,
        &init,
        dir.path(),
        false,
        &mut Poison(13),
        &NoProgress,
    )
    .unwrap_err();
    let msg = err.to_string();
    match err {
        TrainError::NonFinite {
            iteration,
            last_checkpoint,
            ..
        } => {
            assert_eq!(iteration, 13);
            let ckpt = last_checkpoint.expect("checkpoint 10 was written");
            assert!(ckpt.ends_with("000010.bin"));
            let good = splat4d::load_model(&ckpt).unwrap();
            assert!(good.means.iter().flatten().all(|v| v.is_finite()));
        }
        other => panic!("expected NonFinite, got {other}"),
    }
    assert!(
        msg.contains("iteration 13") && msg.contains("learning rate"),
        "{msg}"
    );
    assert!(
        !dir.path().join("model.bin").exists(),
        "no model may be written after divergence"
    );
}

#[test]
fn mismatched_image_and_bad_config_are_errors() {
    let mut data = train_scene::dataset(32, 24);
    let init = train_scene::points(4, 3, &[0.0]);
    let dir = tempfile::tempdir().unwrap();
    let bad = TrainConfig {
        batch_size: 0,
        ..config(5)
    };
    assert!(matches!(
        train(
            &CpuBackend,
            &bad,
            &data,
            &init,
            dir.path(),
            false,
            &mut NoHooks,
            &NoProgress
        ),
        Err(TrainError::Config(_))
    ));
    data.views[3].image.width = 16;
    let e = train(
        &CpuBackend,
        &config(5),
        &data,
        &init,
        dir.path(),
        false,
        &mut NoHooks,
        &NoProgress,
    )
    .unwrap_err();
    assert!(matches!(e, TrainError::ImageSize { index: 3, .. }), "{e}");
}

#[test]
fn config_section_rejects_unknown_keys_and_fills_defaults() {
    let c: TrainConfig =
        serde_json::from_str(r#"{"iterations": 5, "densify": {"every": 50}}"#).unwrap();
    assert_eq!(c.iterations, 5);
    assert_eq!(c.densify.every, 50);
    assert_eq!(c.batch_size, TrainConfig::default().batch_size);
    assert!(serde_json::from_str::<TrainConfig>(r#"{"iteratons": 5}"#).is_err());
}

#[test]
fn a_learned_backdrop_is_fitted_after_training_and_draws_what_no_gaussian_covers() {
    use splat4d::train::{BACKDROP_FILE, Background};
    let data = train_scene::dataset(32, 24);
    // Gaussians on the left half of the textured plane only: the right half of every
    // view is whatever is behind them.
    let init = train_scene::left_half(&train_scene::points(12, 9, &[0.0, 1.0]));
    let learned = |iterations| TrainConfig {
        background: Background::Learned,
        backdrop_size: 32,
        ..config(iterations)
    };
    let run = |config: &TrainConfig, dir: &std::path::Path, resume, hooks: &mut dyn TrainHooks| {
        train(
            &CpuBackend,
            config,
            &data,
            &init,
            dir,
            resume,
            hooks,
            &NoProgress,
        )
    };
    let straight = tempfile::tempdir().unwrap();
    let s = run(&learned(40), straight.path(), false, &mut NoHooks).unwrap();
    assert_eq!(s.backdrop, Some(straight.path().join(BACKDROP_FILE)));
    let flat = tempfile::tempdir().unwrap();
    let mean = TrainConfig {
        background: Background::Mean,
        ..config(40)
    };
    let f = run(&mean, flat.path(), false, &mut NoHooks).unwrap();
    assert!(f.backdrop.is_none() && !flat.path().join(BACKDROP_FILE).exists());
    // The Gaussians train on the mean colour either way; the backdrop is fitted after.
    assert_eq!(s.background, f.background);
    assert!(
        std::fs::read(straight.path().join("model.bin")).unwrap()
            == std::fs::read(flat.path().join("model.bin")).unwrap(),
        "the Gaussians trained differently with a learned backdrop"
    );

    // What render and eval draw: the saved backdrop (baked into one level) behind the
    // model, well above the mean colour where no Gaussian covers the view.
    let backdrop = load_backdrop(&straight.path().join(BACKDROP_FILE)).unwrap();
    assert_eq!(backdrop.levels.len(), 1);
    let view_psnr = |dir: &std::path::Path, backdrop: Option<&Backdrop>| {
        let model = load_model(&dir.join("model.bin")).unwrap();
        let mean: f64 = data
            .views
            .iter()
            .map(|v| {
                let options = RenderOptions {
                    background: if backdrop.is_some() {
                        [0.0; 3]
                    } else {
                        f.background
                    },
                    ..Default::default()
                };
                let mut r = CpuBackend
                    .render(&model, &v.camera, v.time, &options)
                    .unwrap();
                if let Some(b) = backdrop {
                    b.draw(&v.camera, &mut r);
                }
                let mut truth = Vec::new();
                v.image.to_f32_into(&mut truth);
                psnr_from_mse(mse(&r.rgb, &truth))
            })
            .sum();
        mean / data.views.len() as f64
    };
    let (drawn, plain) = (
        view_psnr(straight.path(), Some(&backdrop)),
        view_psnr(flat.path(), None),
    );
    eprintln!("saved model: on its backdrop {drawn:.2} dB, on the mean colour {plain:.2} dB");
    assert!(drawn > plain + 1.0, "{drawn:.2} against {plain:.2} dB");

    let resumed = tempfile::tempdir().unwrap();
    let e = run(&learned(40), resumed.path(), false, &mut StopAt(17)).unwrap_err();
    assert!(
        matches!(e, TrainError::Interrupted { iteration: 17, .. }),
        "{e}"
    );
    let r = run(&learned(40), resumed.path(), true, &mut NoHooks).unwrap();
    assert_eq!(r.started_at, 17);
    for file in ["model.bin", BACKDROP_FILE] {
        assert!(
            std::fs::read(straight.path().join(file)).unwrap()
                == std::fs::read(resumed.path().join(file)).unwrap(),
            "resumed {file} differs from the straight run"
        );
    }
}
