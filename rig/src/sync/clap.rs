//! Clap detection: the loudest sharp onset in an audio track, used to pick the window that
//! GCC-PHAT correlates. Pure signal processing on samples in memory.

/// A detected clap.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Clap {
    /// Sample index where the clap's energy rises.
    pub sample: usize,
    /// Energy of the clap window over the median window energy (≥ 1).
    pub prominence: f64,
}

/// Finds the strongest onset: the 5 ms window whose energy most exceeds the median window
/// energy. Returns `None` when nothing stands out by at least `min_prominence` (a clap is
/// typically 100× louder than the room, ambient sound alone gives below 10).
pub fn detect_clap(samples: &[f32], sample_rate: u32, min_prominence: f64) -> Option<Clap> {
    let win = ((sample_rate as usize) / 200).max(1);
    if samples.len() < 4 * win {
        return None;
    }
    let energies: Vec<f64> = samples
        .chunks(win)
        .map(|c| c.iter().map(|&v| f64::from(v) * f64::from(v)).sum::<f64>() / c.len() as f64)
        .collect();
    let mut sorted = energies.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2].max(1e-20);
    let (best, &peak) = energies
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))?;
    let prominence = peak / median;
    if prominence < min_prominence {
        return None;
    }
    // Walk back from the loudest window to where the energy first rose above 10 % of it.
    let mut first = best;
    while first > 0 && energies[first - 1] > 0.1 * peak {
        first -= 1;
    }
    Some(Clap {
        sample: first * win,
        prominence,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_a_burst_in_quiet_noise() {
        let rate = 48_000;
        let mut s: Vec<f32> = (0..rate)
            .map(|i| 0.001 * ((i as f32) * 0.37).sin())
            .collect();
        for v in &mut s[30_000..30_500] {
            *v += 0.8;
        }
        let c = detect_clap(&s, rate as u32, 20.0).unwrap();
        assert!(c.sample.abs_diff(30_000) <= 240, "{c:?}");
        assert!(detect_clap(&s[..20_000], rate as u32, 20.0).is_none());
    }
}
