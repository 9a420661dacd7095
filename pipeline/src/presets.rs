//! Training presets: `--preset preview|balanced|best|full` on `run` and `demo`, or
//! `[train] preset` in `capture.toml`. The first three are points on the Pareto front of
//! held-out PSNR against training time that `pipeline bench tradeoff` measured on the demo
//! scene on 2 CPU cores (docs/bench/tradeoff.md); `full` is the most accurate point
//! measured there, with room for more Gaussians, meant for a GPU
//! (docs/bench/tradeoff-full.md). A preset sets the iterations (every schedule that counts iterations
//! scales with them, as [`schedule_for`] does), the training resolution and the Gaussian
//! budget; every other setting, the decay variant included, stays as configured. Half
//! and quarter resolution were measured too and left off the presets: with the time in the
//! Gaussians rather than the pixels they saved 10–45 % for 0.7–4 dB.

use serde::{Deserialize, Serialize};
use splat4d::decay::DecayConfig;
use splat4d::train::TrainConfig;

/// A named speed/quality point.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Preset {
    /// A quick look: 300 steps (the demo: under a minute of training on 2 cores).
    Preview,
    /// 1000 steps (the demo: 1–2.5 min).
    Balanced,
    /// The demo's schedule, the most accurate point measured on 2 CPU cores: 2000 steps
    /// (the demo: 2–5 min).
    Best,
    /// The most accurate point measured, for a GPU: 4000 steps with room for 200k
    /// Gaussians (`pipeline demo` takes it when it trains on a hardware GPU; the demo: 5 min
    /// on 2 cores). Longer overfits four views: the paper's 30 000 steps are the file's
    /// `iterations` without a preset.
    Full,
}

/// What a preset sets.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PresetValues {
    pub iterations: u64,
    /// `[train] resolution`.
    pub resolution: f64,
    /// `[train.densify] max_gaussians`.
    pub max_gaussians: usize,
}

/// The `[train]` keys a preset sets: giving one of them beside `preset` is an error.
pub const PRESET_KEYS: [&str; 3] = ["iterations", "resolution", "densify.max_gaussians"];

impl Preset {
    pub fn values(self) -> PresetValues {
        match self {
            Self::Preview => PresetValues {
                iterations: 300,
                resolution: 1.0,
                max_gaussians: 80_000,
            },
            Self::Balanced => PresetValues {
                iterations: 1000,
                resolution: 1.0,
                max_gaussians: 80_000,
            },
            Self::Best => PresetValues {
                iterations: 2000,
                resolution: 1.0,
                max_gaussians: 80_000,
            },
            Self::Full => PresetValues {
                iterations: 4000,
                resolution: 1.0,
                max_gaussians: 200_000,
            },
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::Preview => "preview",
            Self::Balanced => "balanced",
            Self::Best => "best",
            Self::Full => "full",
        }
    }

    /// The training and decay settings with this preset applied (checkpoints keep their
    /// interval, but come at most twenty times a run and at least once).
    pub fn apply(self, train: &TrainConfig, decay: &DecayConfig) -> (TrainConfig, DecayConfig) {
        let v = self.values();
        let (mut t, d) = schedule_for(train, decay, v.iterations);
        t.resolution = v.resolution;
        t.densify.max_gaussians = v.max_gaussians;
        t.checkpoint_every = train
            .checkpoint_every
            .max(v.iterations / 20)
            .min(v.iterations);
        (t, d)
    }

    /// "1000 iterations at resolution 1, at most 80000 Gaussians".
    pub fn describe(self) -> String {
        let v = self.values();
        format!(
            "{} iterations at resolution {}, at most {} Gaussians",
            v.iterations, v.resolution, v.max_gaussians
        )
    }
}

/// The preset `pipeline demo` trains with when neither `--preset` nor `[train] preset`
/// chose one: `full` on a hardware GPU, else none (the demo's own CPU schedule).
pub fn demo_preset(chosen: Option<Preset>, hardware_gpu: bool) -> Option<Preset> {
    chosen.or(hardware_gpu.then_some(Preset::Full))
}

/// `train` and `decay` shortened (or lengthened) to `iterations`: every schedule counted
/// in iterations (colour degree, densification window, position decay, the decay's
/// warm-up) scales by the same factor; checkpoints only at the end.
pub fn schedule_for(
    train: &TrainConfig,
    decay: &DecayConfig,
    iterations: u64,
) -> (TrainConfig, DecayConfig) {
    let scale = iterations as f64 / train.iterations.max(1) as f64;
    let mut d = decay.clone();
    d.warmup = (decay.warmup as f64 * scale).round() as u64;
    (train.with_iterations(iterations), d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_demo_takes_the_full_schedule_only_on_a_gpu_and_when_nothing_was_chosen() {
        assert_eq!(demo_preset(None, true), Some(Preset::Full));
        assert_eq!(demo_preset(None, false), None);
        assert_eq!(
            demo_preset(Some(Preset::Preview), true),
            Some(Preset::Preview)
        );
        assert_eq!(demo_preset(Some(Preset::Best), false), Some(Preset::Best));
    }

    #[test]
    fn presets_scale_the_schedules_and_set_their_values() {
        let train = TrainConfig::default();
        let decay = DecayConfig::default();
        for preset in [
            Preset::Preview,
            Preset::Balanced,
            Preset::Best,
            Preset::Full,
        ] {
            let v = preset.values();
            let (t, d) = preset.apply(&train, &decay);
            assert_eq!(t.iterations, v.iterations);
            assert_eq!(t.resolution, v.resolution);
            assert_eq!(t.densify.max_gaussians, v.max_gaussians);
            let scale = v.iterations as f64 / train.iterations as f64;
            let close = |a: u64, b: u64| (a as f64 - b as f64 * scale).abs() <= 1.0;
            assert!(close(
                t.densify.until_iteration,
                train.densify.until_iteration
            ));
            assert!(close(d.warmup, decay.warmup));
            assert!(t.checkpoint_every >= 1 && t.checkpoint_every <= v.iterations);
            assert!(v.iterations / t.checkpoint_every <= 20, "{preset:?}");
            assert_eq!(t.batch_size, train.batch_size);
        }
        // Cheaper to better.
        let it = |p: Preset| p.values().iterations as f64 * p.values().resolution.powi(2);
        assert!(
            it(Preset::Preview) < it(Preset::Balanced)
                && it(Preset::Balanced) < it(Preset::Best)
                && it(Preset::Best) < it(Preset::Full)
        );
    }

    /// Densification steps of a run, step by step as the trainer decides them (checked
    /// against the closed form `DensifyConfig::count`).
    fn densifications(t: &TrainConfig) -> u64 {
        let n = (1..=t.iterations)
            .filter(|&done| t.densify.densifies_at(done, t.iterations))
            .count() as u64;
        assert_eq!(n, t.densify.count(), "{:?}", t.densify);
        n
    }

    #[test]
    fn every_preset_densifies_at_least_five_times_and_long_ones_keep_the_interval() {
        // The demo's own schedule (fixtures/demo-capture.toml).
        let mut demo = TrainConfig {
            iterations: 2000,
            ..TrainConfig::default()
        };
        demo.densify.from_iteration = 80;
        demo.densify.until_iteration = 1000;
        demo.densify.every = 200;
        let decay = DecayConfig::default();
        for train in [&demo, &TrainConfig::default()] {
            for preset in [
                Preset::Preview,
                Preset::Balanced,
                Preset::Best,
                Preset::Full,
            ] {
                let (t, _) = preset.apply(train, &decay);
                let n = densifications(&t);
                assert!(n >= splat4d::train::MIN_DENSIFICATIONS, "{preset:?}: {n}");
                assert!(t.densify.every <= train.densify.every);
                if t.iterations >= train.iterations {
                    assert_eq!(t.densify.every, train.densify.every, "{preset:?}");
                }
            }
        }
        // 300 steps of the demo: every 27 steps in (12, 150], five times (none before).
        let (t, _) = Preset::Preview.apply(&demo, &decay);
        assert_eq!(
            (
                t.densify.from_iteration,
                t.densify.until_iteration,
                t.densify.every
            ),
            (12, 150, 27)
        );
        assert_eq!(densifications(&t), 5);
    }
}
