//! Flash detection: time a sudden brightness step seen by a camera, below one frame.
//!
//! Input is a per-frame brightness profile (mean luma of each image row, top to bottom).
//! The flash is the largest frame-to-frame rise in mean brightness.
//!
//! Camera model: row `r` of a frame stamped `t` collects light during the `exposure`
//! seconds that end at `t + r / rows · readout` (readout 0: global shutter; exposure 0:
//! instantaneous). Then:
//! - rolling shutter: where the lit rows begin in the first lit frame times the flash to a
//!   fraction of a millisecond, for a lasting step (a lamp switched on) or a pulse shorter
//!   than a frame (a flash) alike — see [`step_row`];
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
        step_row(frames, k_on)
    } else {
        0.0
    };
    let lit_fraction = ((means[k_on] - base) / contrast).clamp(0.0, 1.0);
    let time = if row_fraction > 0.0 {
        t_on + row_fraction * readout_s
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

/// Where the flash's leading edge lies in frame `k` (rolling shutter), as a fraction of the
/// height (0 = top); 0 when the frame is lit from its first row.
///
/// The flash lights each surface in proportion to its brightness, so each row's lift over
/// the dark frame `k − 1` is taken relative to that row's dark level. Going down the frame,
/// rows are exposed later, so the relative lift ramps up from 0 where a row's exposure
/// first overlaps the flash, over `min(exposure, flash duration)` worth of rows, to its
/// peak. The peak is read from frames `k` and `k + 1` (a step stays lit; a pulse shorter
/// than a frame lights only a band of rows), the half-peak crossing is found with
/// sub-row interpolation, and the ramp's width (from its 10 % and 90 % crossings) moves it
/// back to where the ramp starts: the row whose exposure ends as the flash begins.
fn step_row(frames: &[FrameBrightness], k: usize) -> f64 {
    let dark = &frames[k - 1].rows;
    let lifts = |rows: &[f32]| -> Vec<(usize, f64)> {
        (0..rows.len().min(dark.len()))
            .filter(|&r| dark[r] >= 8.0)
            .map(|r| (r, f64::from(rows[r] - dark[r]) / f64::from(dark[r])))
            .collect()
    };
    let now = lifts(&frames[k].rows);
    if now.len() < 3 {
        return 0.0;
    }
    // Peak: the largest 3-row median (one noisy row cannot set it).
    let median3 = |v: &[(usize, f64)]| {
        v.windows(3)
            .map(|w| median(&[w[0].1, w[1].1, w[2].1]))
            .fold(f64::MIN, f64::max)
    };
    let mut peak = median3(&now);
    if let Some(next) = frames.get(k + 1) {
        peak = peak.max(median3(&lifts(&next.rows)));
    }
    if peak <= 0.0 {
        return 0.0;
    }
    // First crossing of `level · peak` going down, in (fractional) row units.
    let crossing = |level: f64| -> Option<f64> {
        let target = level * peak;
        let i = now.iter().position(|&(_, v)| v >= target)?;
        if i == 0 {
            return Some(now[0].0 as f64);
        }
        let ((r0, v0), (r1, v1)) = (now[i - 1], now[i]);
        let f = ((target - v0) / (v1 - v0)).clamp(0.0, 1.0);
        Some(r0 as f64 + f * (r1 - r0) as f64)
    };
    let (Some(x10), Some(x50), Some(x90)) = (crossing(0.1), crossing(0.5), crossing(0.9)) else {
        return 0.0;
    };
    if x10 <= now[0].0 as f64 {
        return 0.0;
    }
    let ramp = ((x90 - x10) / 0.8).max(0.0);
    (x50 - 0.5 * ramp).max(0.0) / frames[k].rows.len() as f64
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

    /// A rolling-shutter camera filming a textured scene lit by a flash pulse: row r of
    /// frame k integrates over `[t_k + r/h·readout − exposure, t_k + r/h·readout]`, and
    /// its brightness is the row's albedo × (1 + 1.5 × lit fraction of the exposure).
    fn pulse(
        phase: f64,
        readout: f64,
        exposure: f64,
        flash: f64,
        duration: f64,
    ) -> Vec<FrameBrightness> {
        let h = 120;
        (0..30)
            .map(|k| {
                let t = phase + k as f64 / 30.0;
                let rows = (0..h)
                    .map(|r| {
                        let end = t + r as f64 / h as f64 * readout;
                        let overlap =
                            (end.min(flash + duration) - (end - exposure).max(flash)).max(0.0);
                        let albedo = 60.0 + 50.0 * ((r * 7919) % 13) as f64 / 13.0;
                        (albedo * (1.0 + 1.5 * overlap / exposure)) as f32
                    })
                    .collect();
                FrameBrightness { timestamp: t, rows }
            })
            .collect()
    }

    #[test]
    fn rolling_shutter_times_a_flash_pulse_on_a_textured_scene() {
        for &duration in &[0.001, 0.004, 0.010, 1.0] {
            for &flash in &[0.3012, 0.3171, 0.3290] {
                let f = pulse(0.0, 0.0266, 0.004, flash, duration);
                let e = detect_flash(&f, 0.0266, 0.004).unwrap();
                // When the flash starts between two frames' readouts, no row shows its
                // leading edge and only the exposure bounds it.
                let tolerance = if e.row_fraction > 0.0 {
                    3e-4
                } else {
                    0.004 + duration.min(0.004)
                };
                assert!(
                    (e.time - flash).abs() < tolerance,
                    "pulse {duration} s at {flash}: {e:?}"
                );
            }
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
