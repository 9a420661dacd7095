//! Flash detection: time a sudden brightness step seen by a camera, below one frame.
//!
//! Input is a per-frame brightness profile (mean luma of each image row, top to bottom).
//! The flash is the largest frame-to-frame rise in mean brightness.
//!
//! Camera model: row `r` of a frame stamped `t` collects light during the `exposure`
//! seconds that end at `t + r / rows · readout` (readout 0: global shutter; exposure 0:
//! instantaneous). Then:
//! - rolling shutter: the row where the step lies in the first lit frame times the flash to
//!   a fraction of a millisecond (half-lit row = flash at that row's exposure midpoint);
//! - a partly lit frame (the flash came during the exposure): lit fraction `f` puts the
//!   flash at `t − f · exposure`;
//! - otherwise the flash lies between the previous frame's last row and this frame's
//!   exposure start, and the midpoint is used (error < ½ frame per camera).

/// Brightness of one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameBrightness {
    /// Frame timestamp, seconds on the camera's clock (the time row 0 is read).
    pub timestamp: f64,
    /// Mean luma of each image row, top to bottom, in [0, 255].
    pub rows: Vec<f32>,
}

impl FrameBrightness {
    /// Mean over all rows.
    pub fn mean(&self) -> f64 {
        if self.rows.is_empty() {
            return 0.0;
        }
        self.rows.iter().map(|&v| f64::from(v)).sum::<f64>() / self.rows.len() as f64
    }
}

/// A detected flash onset.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlashEvent {
    /// Onset time, seconds on the camera's clock.
    pub time: f64,
    /// Index of the first frame that sees the flash.
    pub frame: usize,
    /// Row (fraction of the height, 0 = top) where the step starts in that frame; 0 when the
    /// whole frame is lit (or with a global shutter).
    pub row_fraction: f64,
    /// Brightness rise over the frame-to-frame noise (robust z-score).
    pub confidence: f64,
}

/// Detects the flash in `frames`. `readout_s` is the rolling-shutter readout time (top row
/// to bottom row; 0 for a global shutter) and `exposure_s` the exposure time (0 when
/// unknown). Returns `None` when there is no rise at all or it happens on the first frame
/// (no dark frame before it).
pub fn detect_flash(
    frames: &[FrameBrightness],
    readout_s: f64,
    exposure_s: f64,
) -> Option<FlashEvent> {
    if frames.len() < 3 {
        return None;
    }
    let means: Vec<f64> = frames.iter().map(FrameBrightness::mean).collect();
    let rises: Vec<f64> = means.windows(2).map(|w| w[1] - w[0]).collect();
    let (i, _) = rises.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1))?;
    let k_max = i + 1;
    // Noise: median absolute frame-to-frame change (the flash itself is one outlier).
    let mut abs: Vec<f64> = rises.iter().map(|r| r.abs()).collect();
    abs.sort_by(f64::total_cmp);
    let noise = (1.4826 * abs[abs.len() / 2]).max(0.25);
    let before = &means[k_max.saturating_sub(6)..k_max - 1];
    let base = if before.is_empty() {
        means[k_max - 1]
    } else {
        median(before)
    };
    let full = means[k_max..(k_max + 4).min(means.len())]
        .iter()
        .copied()
        .fold(f64::MIN, f64::max);
    let contrast = full - base;
    if contrast <= 0.0 {
        return None;
    }
    // A step in the last rows of a rolling-shutter frame lifts that frame only a little.
    let partial = means[k_max - 1] - base > (4.0 * noise).max(0.01 * contrast);
    let k_on = if partial && k_max >= 2 {
        k_max - 1
    } else {
        k_max
    };
    if k_on == 0 {
        return None;
    }
    let confidence = contrast / noise;
    let t_on = frames[k_on].timestamp;
    let t_prev = frames[k_on - 1].timestamp;
    let row_fraction = if readout_s > 0.0 {
        step_row(frames, k_on, contrast)
    } else {
        0.0
    };
    let lit_fraction = ((means[k_on] - base) / contrast).clamp(0.0, 1.0);
    let time = if row_fraction > 0.0 {
        t_on + row_fraction * readout_s - 0.5 * exposure_s
    } else if exposure_s > 0.0 && lit_fraction < 0.97 {
        // The flash came during the first row's exposure.
        t_on - lit_fraction * exposure_s
    } else {
        // Fully lit: after the previous frame's last row, before this exposure started.
        let prev_end = t_prev + readout_s;
        let this_start = (t_on - exposure_s).max(prev_end);
        0.5 * (prev_end + this_start)
    };
    Some(FlashEvent {
        time,
        frame: k_on,
        row_fraction,
        confidence,
    })
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[s.len() / 2]
}

/// Fraction of the height above the brightness step in frame `k` (rolling shutter).
///
/// Each row's lift is normalised by the lift it gets once fully lit; the step is placed
/// where a 0→1 step fits the normalised lifts best (rows the flash barely reaches are
/// ignored). Returns 0 when the whole frame is lit.
fn step_row(frames: &[FrameBrightness], k: usize, contrast: f64) -> f64 {
    let dark = &frames[k - 1].rows;
    let now = &frames[k].rows;
    let lit_frame = (k + 1..(k + 4).min(frames.len()))
        .max_by(|&a, &b| frames[a].mean().total_cmp(&frames[b].mean()))
        .unwrap_or(k);
    let lit = &frames[lit_frame].rows;
    let h = now.len().min(dark.len()).min(lit.len());
    if h == 0 {
        return 0.0;
    }
    let mut lifts: Vec<(usize, f64)> = Vec::with_capacity(h);
    for r in 0..h {
        let den = f64::from(lit[r]) - f64::from(dark[r]);
        if den > 0.25 * contrast {
            let n = (f64::from(now[r]) - f64::from(dark[r])) / den;
            lifts.push((r, n.clamp(0.0, 1.0)));
        }
    }
    if lifts.is_empty() {
        return 0.0;
    }
    // Best step position s (index into lifts): maximise Σ_{j ≥ s} (2 n_j − 1).
    let mut suffix = 0.0;
    let (mut best, mut best_s) = (f64::MIN, lifts.len());
    for s in (0..=lifts.len()).rev() {
        if s < lifts.len() {
            suffix += 2.0 * lifts[s].1 - 1.0;
        }
        if suffix >= best {
            best = suffix;
            best_s = s;
        }
    }
    if best_s == 0 {
        return 0.0;
    }
    // Sub-row: the row just above the step may be partly lit.
    let (row, _) = lifts[best_s.min(lifts.len() - 1)];
    let above = lifts[best_s - 1];
    let row = if best_s < lifts.len() {
        row as f64 - above.1
    } else {
        above.0 as f64 + 1.0 - above.1
    };
    row.max(0.0) / h as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rolling-shutter camera: row r of frame k is sampled at t_k + r/h·readout and sees
    /// brightness 200 after `flash`, 20 before.
    fn rolling(fps: f64, phase: f64, readout: f64, flash: f64, h: usize) -> Vec<FrameBrightness> {
        (0..30)
            .map(|k| {
                let t = phase + k as f64 / fps;
                let rows = (0..h)
                    .map(|r| {
                        if t + r as f64 / h as f64 * readout >= flash {
                            200.0
                        } else {
                            20.0
                        }
                    })
                    .collect();
                FrameBrightness { timestamp: t, rows }
            })
            .collect()
    }

    #[test]
    fn rolling_shutter_times_the_flash_to_a_row() {
        for &flash in &[0.3012, 0.3171, 0.3290, 0.345] {
            let f = rolling(30.0, 0.0, 0.030, flash, 540);
            let e = detect_flash(&f, 0.030, 0.0).unwrap();
            assert!((e.time - flash).abs() < 1e-3, "flash {flash}: {e:?}");
        }
    }

    #[test]
    fn global_shutter_is_within_half_a_frame() {
        for &flash in &[0.3012, 0.3171, 0.3299] {
            let f = rolling(30.0, 0.01, 0.0, flash, 10);
            let e = detect_flash(&f, 0.0, 0.0).unwrap();
            assert!((e.time - flash).abs() <= 0.5 / 30.0, "{e:?}");
        }
    }
}
