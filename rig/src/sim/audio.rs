//! The audio each camera records: background noise of its own plus one clap, a sharp
//! broadband burst with a fast decay, heard at `clap_time + distance / 343 m/s` and recorded
//! on the camera's own timeline (file time 0 = the camera's first frame).
//!
//! The clap is a continuous-time signal, so every camera hears the same sound, shifted by
//! a fraction of a sample where the offsets call for it.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::texture::hash;

/// Speed of sound used for the acoustic delay, m/s.
pub const SPEED_OF_SOUND: f64 = 343.0;
/// Seconds of clap signal after its onset (beyond that it is below the noise).
pub const CLAP_LENGTH: f64 = 0.08;
const PARTIALS: usize = 48;
/// Attack of the clap, seconds.
const ATTACK: f64 = 0.0002;
/// Decay constant of the clap envelope, seconds.
const DECAY: f64 = 0.008;

/// The clap sound: `partials` random sinusoids between 300 Hz and 8 kHz under a fast
/// attack / exponential decay envelope; unit peak order of magnitude.
#[derive(Clone, Debug)]
pub struct Clap {
    partials: Vec<(f64, f64)>,
}

impl Clap {
    /// The clap of a scene with this seed.
    pub fn new(seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(hash(seed, 0xC1A9, 0));
        let partials = (0..PARTIALS)
            .map(|_| {
                let f = 300.0 * (8000.0f64 / 300.0).powf(rng.random::<f64>());
                (f, std::f64::consts::TAU * rng.random::<f64>())
            })
            .collect();
        Clap { partials }
    }

    /// Signal `s` seconds after the onset (0 before it).
    pub fn at(&self, s: f64) -> f64 {
        if !(0.0..CLAP_LENGTH).contains(&s) {
            return 0.0;
        }
        let envelope = (s / ATTACK).min(1.0) * (-s / DECAY).exp();
        let sum: f64 = self
            .partials
            .iter()
            .map(|&(f, ph)| (std::f64::consts::TAU * f * s + ph).sin())
            .sum();
        envelope * sum * (2.0 / PARTIALS as f64).sqrt()
    }
}

/// What one camera's audio track holds.
#[derive(Clone, Debug)]
pub struct Track {
    pub samples: Vec<f32>,
    /// Seconds from the clap to its arrival at the camera (0 when the delay is off).
    pub acoustic_delay: f64,
    /// File time (seconds from the file's first sample) at which the clap begins.
    pub clap_file_time: f64,
}

/// Synthesize `n` samples at `rate` for a camera whose first frame is at scene time
/// `start_time`, at `distance` metres from the clap.
#[allow(clippy::too_many_arguments)]
pub fn camera_track(
    clap: &Clap,
    seed: u64,
    camera_index: u64,
    rate: u32,
    n: usize,
    start_time: f64,
    clap_time: f64,
    distance: f64,
    acoustic_delay: bool,
    noise: f64,
    clap_gain: f64,
) -> Track {
    let mut rng = ChaCha8Rng::seed_from_u64(hash(seed, 0xA0D1_0000, camera_index));
    let delay = if acoustic_delay {
        distance / SPEED_OF_SOUND
    } else {
        0.0
    };
    let onset = clap_time + delay - start_time;
    let gain = clap_gain / distance.max(1.0);
    let mut samples = Vec::with_capacity(n);
    for j in 0..n {
        // Gaussian noise by Box–Muller.
        let (u1, u2): (f64, f64) = (rng.random::<f64>().max(1e-300), rng.random::<f64>());
        let g = (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos();
        let t = j as f64 / rate as f64;
        let v = noise * g + gain * clap.at(t - onset);
        samples.push(v.clamp(-1.0, 1.0) as f32);
    }
    Track {
        samples,
        acoustic_delay: delay,
        clap_file_time: onset,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_clap_starts_where_declared_and_stands_out_of_the_noise() {
        let clap = Clap::new(3);
        let track = camera_track(
            &clap, 3, 0, 48_000, 48_000, 0.25, 0.5, 3.43, true, 0.01, 0.8,
        );
        assert!((track.acoustic_delay - 0.01).abs() < 1e-12);
        assert!((track.clap_file_time - 0.26).abs() < 1e-12);
        let onset = (0.26 * 48_000.0) as usize;
        let before: f32 = track.samples[..onset]
            .iter()
            .map(|v| v.abs())
            .fold(0.0, f32::max);
        let after: f32 = track.samples[onset..onset + 480]
            .iter()
            .map(|v| v.abs())
            .fold(0.0, f32::max);
        assert!(
            before < 0.06 && after > 0.1,
            "before {before} after {after}"
        );
    }
}
