//! What the decay did to a trained model, as evidence for whether it earns its place: how
//! far f_θ moved from its initial weights, how much of τ's allowed range it uses, what τ
//! follows (opacity, size, time), and the model's opacity distribution. The train stage
//! writes it as `work/train/decay.json`.

use serde::Serialize;

use super::mlp::Mlp;
use super::{DecayHooks, DecayVariant};
use crate::math::numerics::sigmoid;
use crate::model::Gaussians;

/// Bins of the histograms.
const BINS: usize = 20;

/// Distribution of one per-Gaussian quantity.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Distribution {
    pub min: f64,
    pub max: f64,
    pub mean: f64,
    pub std: f64,
    /// Quantiles 1, 10, 50, 90 and 99 %.
    pub quantiles: [f64; 5],
    /// Counts of `BINS` equal bins over `range` (values outside go to the end bins).
    pub range: [f64; 2],
    pub histogram: Vec<usize>,
}

impl Distribution {
    /// `None` for no values.
    pub fn of(values: &[f64], range: [f64; 2]) -> Option<Self> {
        let finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
        if finite.is_empty() {
            return None;
        }
        let mut sorted = finite.clone();
        sorted.sort_by(f64::total_cmp);
        let n = sorted.len() as f64;
        let mean = sorted.iter().sum::<f64>() / n;
        let var = sorted.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
        let q = |p: f64| sorted[((p * (n - 1.0)).round() as usize).min(sorted.len() - 1)];
        let width = (range[1] - range[0]).max(f64::MIN_POSITIVE);
        let mut histogram = vec![0; BINS];
        for v in &finite {
            let bin = (((v - range[0]) / width) * BINS as f64).floor();
            histogram[(bin.max(0.0) as usize).min(BINS - 1)] += 1;
        }
        Some(Self {
            min: sorted[0],
            max: sorted[sorted.len() - 1],
            mean,
            std: var.sqrt(),
            quantiles: [q(0.01), q(0.1), q(0.5), q(0.9), q(0.99)],
            range,
            histogram,
        })
    }
}

/// What τ follows: Pearson correlations of τ with Gaussian properties.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TauCorrelations {
    /// With the opacity `sigmoid(o)`.
    pub opacity: f64,
    /// With the largest spatial log-scale.
    pub log_size: f64,
    /// With the temporal log-scale (how long the Gaussian lives).
    pub log_lifetime: f64,
    /// With `|μ_t − middle of the clip|`.
    pub time_from_middle: f64,
}

/// The neural decay's side of the report.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NeuralReport {
    /// τ of every Gaussian under the final f_θ.
    pub tau: Distribution,
    /// Share of `[f_min, f_max]` that τ's 1–99 % quantiles span (0: f_θ is a constant).
    pub range_used: f64,
    /// `‖θ − θ₀‖ / ‖θ₀‖`: how far training moved f_θ from its seeded start.
    pub weights_moved: f64,
    pub correlations: TauCorrelations,
    /// f_θ updates skipped for a non-finite gradient.
    pub skipped_updates: u64,
}

/// The report of one trained model.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DecayReport {
    pub variant: DecayVariant,
    pub gaussians: usize,
    /// `sigmoid(o)` of every Gaussian.
    pub opacity: Option<Distribution>,
    /// Gaussians with opacity under 0.05 (nearly transparent).
    pub faint: usize,
    /// Only for the neural decay.
    pub neural: Option<NeuralReport>,
}

fn pearson(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len()) as f64;
    if n < 2.0 {
        return 0.0;
    }
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma).powi(2);
        sbb += (y - mb).powi(2);
    }
    if saa <= 0.0 || sbb <= 0.0 {
        0.0
    } else {
        sab / (saa * sbb).sqrt()
    }
}

/// The report for `model` trained with `hooks`.
pub fn report(hooks: &DecayHooks, model: &Gaussians<f32>) -> DecayReport {
    let config = hooks.config();
    let opacity: Vec<f64> = model
        .opacity_logits
        .iter()
        .map(|&o| sigmoid(o as f64))
        .collect();
    let neural = (config.variant == DecayVariant::Neural && !model.is_empty()).then(|| {
        let tau: Vec<f64> = hooks.tau(model).iter().map(|&t| t as f64).collect();
        let range = [config.f_min, config.f_max];
        let distribution = Distribution::of(&tau, range);
        let start = Mlp::<f32>::new(&config.mlp_dims(), config.seed);
        let norm = |v: &mut dyn Iterator<Item = f64>| v.map(|x| x * x).sum::<f64>().sqrt();
        let moved = norm(
            &mut hooks
                .mlp()
                .params
                .iter()
                .zip(&start.params)
                .map(|(a, b)| (a - b) as f64),
        );
        let initial = norm(&mut start.params.iter().map(|&p| p as f64));
        let log_size: Vec<f64> = model
            .log_scales
            .iter()
            .map(|s| s[0].max(s[1]).max(s[2]) as f64)
            .collect();
        let log_lifetime: Vec<f64> = model.log_scales.iter().map(|s| s[3] as f64).collect();
        let times: Vec<f64> = model.means.iter().map(|m| m[3] as f64).collect();
        let (lo, hi) = times
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &t| {
                (a.min(t), b.max(t))
            });
        let from_middle: Vec<f64> = times.iter().map(|t| (t - 0.5 * (lo + hi)).abs()).collect();
        (
            distribution,
            range,
            moved / initial.max(f64::MIN_POSITIVE),
            {
                TauCorrelations {
                    opacity: pearson(&tau, &opacity),
                    log_size: pearson(&tau, &log_size),
                    log_lifetime: pearson(&tau, &log_lifetime),
                    time_from_middle: pearson(&tau, &from_middle),
                }
            },
        )
    });
    let neural = neural.and_then(|(tau, range, weights_moved, correlations)| {
        let tau = tau?;
        Some(NeuralReport {
            range_used: (tau.quantiles[4] - tau.quantiles[0])
                / (range[1] - range[0]).max(f64::MIN_POSITIVE),
            tau,
            weights_moved,
            correlations,
            skipped_updates: hooks.skipped_updates(),
        })
    });
    DecayReport {
        variant: config.variant,
        gaussians: model.len(),
        faint: opacity.iter().filter(|&&o| o < 0.05).count(),
        opacity: Distribution::of(&opacity, [0.0, 1.0]),
        neural,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decay::DecayConfig;

    #[test]
    fn distributions_count_every_value_and_clamp_to_the_end_bins() {
        let values: Vec<f64> = (0..100)
            .map(|i| i as f64 / 99.0)
            .chain([-1.0, 2.0])
            .collect();
        let d = Distribution::of(&values, [0.0, 1.0]).unwrap();
        assert_eq!(d.histogram.iter().sum::<usize>(), 102);
        assert_eq!(d.histogram[0], 6);
        assert_eq!(d.histogram[BINS - 1], 6);
        assert_eq!((d.min, d.max), (-1.0, 2.0));
        assert!((d.quantiles[2] - 0.5).abs() < 0.02, "{:?}", d.quantiles);
        assert!(Distribution::of(&[f64::NAN], [0.0, 1.0]).is_none());
    }

    #[test]
    fn correlations_are_pearson() {
        let a = [1.0, 2.0, 3.0, 4.0];
        assert!((pearson(&a, &[2.0, 4.0, 6.0, 8.0]) - 1.0).abs() < 1e-12);
        assert!((pearson(&a, &[8.0, 6.0, 4.0, 2.0]) + 1.0).abs() < 1e-12);
        assert_eq!(pearson(&a, &[1.0; 4]), 0.0);
    }

    #[test]
    fn an_untrained_neural_decay_has_not_moved_and_uses_little_range() {
        use crate::model::{ColourDegrees, Gaussians};
        let mut model = Gaussians::new(ColourDegrees::FULL, Default::default());
        for i in 0..500 {
            let x = i as f32 / 500.0;
            model.push(
                [x, 1.0 - x, 2.0 * x, x],
                [-3.0 + x, -3.0, -2.5, -1.0],
                -5.0,
                [x; 3],
            );
        }
        let hooks = DecayHooks::new(&DecayConfig::neural()).unwrap();
        let r = report(&hooks, &model);
        assert_eq!(r.gaussians, 500);
        assert_eq!(r.faint, 500);
        let neural = r.neural.unwrap();
        assert_eq!(neural.weights_moved, 0.0);
        assert_eq!(neural.tau.histogram.iter().sum::<usize>(), 500);
        assert!(neural.tau.min >= 0.996 - 1e-6 && neural.tau.max <= 0.998 + 1e-6);
        assert!((0.0..=1.0).contains(&neural.range_used));
        let none = report(&DecayHooks::new(&DecayConfig::none()).unwrap(), &model);
        assert!(none.neural.is_none());
    }
}
