//! Audio offsets: GCC-PHAT of every camera's track against the reference camera's, around
//! a detected clap (or over the first minute of overlap), with optional correction for
//! the sound's travel time from a known clap position to each camera.

#[cfg(feature = "ffmpeg")]
use crate::ingest::AudioTrack;
use crate::sync::clap::detect_clap;
use crate::sync::gcc_phat::gcc_phat;
use serde::{Deserialize, Serialize};

/// How the audio is correlated.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct AudioSyncConfig {
    /// Correlate around the loudest clap of the reference track when one stands out.
    pub use_clap: bool,
    /// Energy ratio over the median that makes an onset a clap.
    pub clap_prominence: f64,
    /// Seconds of reference audio kept before / after the clap.
    pub clap_window_s: [f64; 2],
    /// Without a clap: seconds of reference audio correlated (from its start).
    pub max_excerpt_s: f64,
}

impl Default for AudioSyncConfig {
    fn default() -> Self {
        AudioSyncConfig {
            use_clap: true,
            clap_prominence: 30.0,
            clap_window_s: [0.5, 1.5],
            max_excerpt_s: 60.0,
        }
    }
}

/// Where the clap was made and where the cameras' microphones are, to remove each
/// camera's acoustic path delay (`distance / speed_of_sound`).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct AcousticConfig {
    /// Clap position, metres, in the same frame as the camera positions.
    pub clap_position: [f64; 3],
    /// Microphone (camera) position of every camera, by name.
    pub camera_positions: std::collections::BTreeMap<String, [f64; 3]>,
    /// Speed of sound in m/s (343 at 20 °C).
    #[serde(default = "default_speed_of_sound")]
    pub speed_of_sound: f64,
}

fn default_speed_of_sound() -> f64 {
    343.0
}

impl AcousticConfig {
    /// Travel time of the clap's sound to camera `name`, if its position is known.
    pub fn delay_s(&self, name: &str) -> Option<f64> {
        let p = self.camera_positions.get(name)?;
        let d = (0..3)
            .map(|i| (p[i] - self.clap_position[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        Some(d / self.speed_of_sound)
    }
}

/// One camera's audio offset estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AudioOffset {
    /// Seconds added to this camera's clock to reach the reference camera's clock.
    pub offset_s: f64,
    /// GCC-PHAT peak-to-sidelobe ratio.
    pub confidence: f64,
}

#[cfg(feature = "ffmpeg")]
/// Linear-interpolation resampling to `rate` (only used when cameras record at different
/// rates; the correlation peak is still sub-sample at the reference rate).
fn resample(track: &AudioTrack, rate: u32) -> AudioTrack {
    if track.sample_rate == rate || track.samples.is_empty() {
        return track.clone();
    }
    let ratio = f64::from(track.sample_rate) / f64::from(rate);
    let n = ((track.samples.len() - 1) as f64 / ratio).floor() as usize + 1;
    let samples = (0..n)
        .map(|i| {
            let x = i as f64 * ratio;
            let j = x.floor() as usize;
            let f = (x - j as f64) as f32;
            let a = track.samples[j];
            let b = *track.samples.get(j + 1).unwrap_or(&a);
            a + (b - a) * f
        })
        .collect();
    AudioTrack {
        sample_rate: rate,
        start_s: track.start_s,
        samples,
    }
}

#[cfg(feature = "ffmpeg")]
/// The samples of `track` covering camera-clock times `[from, to)`, with the time of the
/// first one.
fn excerpt(track: &AudioTrack, from: f64, to: f64) -> (f64, &[f32]) {
    let rate = f64::from(track.sample_rate);
    let n = track.samples.len();
    let a = (((from - track.start_s) * rate).floor().max(0.0) as usize).min(n);
    let b = (((to - track.start_s) * rate).ceil().max(0.0) as usize).clamp(a, n);
    (track.start_s + a as f64 / rate, &track.samples[a..b])
}

#[cfg(feature = "ffmpeg")]
/// Offsets of every track relative to `tracks[reference]` (whose offset is 0).
///
/// `None` for a track that is missing or silent (all `None` when the reference is).
/// `max_offset_s` bounds the search.
/// Offsets are on the reference clock: `t_reference = t_camera + offset_s`.
pub fn audio_offsets(
    tracks: &[Option<AudioTrack>],
    reference: usize,
    max_offset_s: f64,
    config: &AudioSyncConfig,
) -> Vec<Option<AudioOffset>> {
    let Some(Some(ref_track)) = tracks.get(reference) else {
        return vec![None; tracks.len()];
    };
    if ref_track.samples.iter().all(|&v| v == 0.0) {
        return vec![None; tracks.len()];
    }
    let rate = ref_track.sample_rate;
    let fs = f64::from(rate);
    let ref_end = ref_track.start_s + ref_track.samples.len() as f64 / fs;
    let clap = if config.use_clap {
        detect_clap(&ref_track.samples, rate, config.clap_prominence)
    } else {
        None
    };
    let (ref_from, ref_to) = match clap {
        Some(c) => {
            let t = ref_track.start_s + c.sample as f64 / fs;
            (t - config.clap_window_s[0], t + config.clap_window_s[1])
        }
        None => (
            ref_track.start_s,
            (ref_track.start_s + config.max_excerpt_s).min(ref_end),
        ),
    };
    let (ref_start, ref_samples) = excerpt(ref_track, ref_from, ref_to);
    tracks
        .iter()
        .enumerate()
        .map(|(i, track)| {
            if i == reference {
                return Some(AudioOffset {
                    offset_s: 0.0,
                    confidence: f64::INFINITY,
                });
            }
            let track = resample(track.as_ref()?, rate);
            // t_ref = t_cam + offset, |offset| ≤ max: the camera window is the reference
            // window shifted by up to ±max.
            let (cam_start, cam_samples) =
                excerpt(&track, ref_from - max_offset_s, ref_to + max_offset_s);
            // ref[n] = cam[n − D] ⇒ offset = ref_start − cam_start + D / fs.
            let base = ref_start - cam_start;
            let lo = ((-max_offset_s - base) * fs).floor() as i64;
            let hi = ((max_offset_s - base) * fs).ceil() as i64;
            let d = gcc_phat(ref_samples, cam_samples, lo..=hi)?;
            Some(AudioOffset {
                offset_s: base + d.samples / fs,
                confidence: d.confidence,
            })
        })
        .collect()
}
