//! Audio sync on synthetic tracks: a scene sound (ambient tones + a band-limited clap)
//! evaluated analytically at each camera's sample times, so offsets are exact to far below
//! one sample. Checks GCC-PHAT's sub-sample accuracy, the confidence of silent or
//! unrelated tracks, and the acoustic path correction.

use crate::sync_support;

use std::collections::BTreeMap;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rig::ingest::AudioTrack;
use rig::sync::audio::{AcousticConfig, AudioSyncConfig, audio_offsets};
use sync_support::SceneSound;

const RATE: u32 = 48_000;
const CLAP_T: f64 = 2.0;

/// A camera whose clock reads `t − offset` at scene time `t`, recording 4 s, hearing the
/// scene `delay` seconds late, with its own microphone noise.
fn record(scene: &SceneSound, offset: f64, delay: f64, seed: u64) -> AudioTrack {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let samples = (0..4 * RATE as usize)
        .map(|n| {
            let t = n as f64 / f64::from(RATE) + offset; // scene time of sample n
            (scene.at(t - delay) + 0.002 * (rng.random::<f64>() - 0.5)) as f32
        })
        .collect();
    AudioTrack {
        sample_rate: RATE,
        start_s: 0.0,
        samples,
    }
}

const OFFSETS: [f64; 4] = [0.0, 0.012_345_6, -0.350_123_4, 0.800_037_1];

#[test]
fn gcc_phat_offsets_are_sub_sample() {
    let scene = SceneSound::with_tones(7, 30, 60, CLAP_T);
    let tracks: Vec<_> = OFFSETS
        .iter()
        .enumerate()
        .map(|(i, &o)| Some(record(&scene, o, 0.0, i as u64)))
        .collect();
    for use_clap in [true, false] {
        let config = AudioSyncConfig {
            use_clap,
            ..Default::default()
        };
        let found = audio_offsets(&tracks, 0, 2.0, &config);
        for (i, f) in found.iter().enumerate() {
            let f = f.expect("every camera has audio");
            let err = f.offset_s - OFFSETS[i];
            println!(
                "clap window {use_clap}: cam{i} offset {:.7} s, error {:.2} µs, confidence {:.1}",
                f.offset_s,
                err * 1e6,
                f.confidence
            );
            assert!(err.abs() < 1e-4, "cam{i}: error {err} s");
            assert!(f.confidence > 20.0, "cam{i}: confidence {}", f.confidence);
        }
    }
}

#[test]
fn silent_and_unrelated_tracks_are_not_trusted() {
    let scene = SceneSound::with_tones(7, 30, 60, CLAP_T);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let hiss: Vec<f32> = (0..4 * RATE as usize)
        .map(|_| 0.002 * (rng.random::<f32>() - 0.5))
        .collect();
    let silent = AudioTrack {
        sample_rate: RATE,
        start_s: 0.0,
        samples: vec![0.0; 4 * RATE as usize],
    };
    let tracks = vec![
        Some(record(&scene, 0.0, 0.0, 1)),
        Some(silent),
        Some(AudioTrack {
            sample_rate: RATE,
            start_s: 0.0,
            samples: hiss,
        }),
        None,
    ];
    let found = audio_offsets(&tracks, 0, 2.0, &AudioSyncConfig::default());
    assert!(found[1].is_none(), "digital silence gives no peak");
    let unrelated = found[2].expect("microphone hiss still correlates");
    println!("hiss-only track confidence {:.1}", unrelated.confidence);
    assert!(unrelated.confidence < 10.0, "{unrelated:?}");
    assert!(found[3].is_none());
}

#[test]
fn acoustic_path_delay_is_measured_and_corrected() {
    let scene = SceneSound::with_tones(3, 30, 60, CLAP_T);
    let clap_position = [0.0, 0.0, 0.0];
    let positions = [
        [3.0, 0.0, 0.0],
        [0.0, 1.0, 0.5],
        [-2.0, -4.0, 0.0],
        [1.0, 1.0, 6.0],
    ];
    let c = 343.0;
    let dist = |p: &[f64; 3]| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    let tracks: Vec<_> = OFFSETS
        .iter()
        .zip(&positions)
        .enumerate()
        .map(|(i, (&o, p))| Some(record(&scene, o, dist(p) / c, 10 + i as u64)))
        .collect();
    let raw = audio_offsets(&tracks, 0, 2.0, &AudioSyncConfig::default());
    let acoustic = AcousticConfig {
        clap_position,
        camera_positions: positions
            .iter()
            .enumerate()
            .map(|(i, p)| (format!("cam{i}"), *p))
            .collect::<BTreeMap<_, _>>(),
        speed_of_sound: c,
    };
    let ref_delay = acoustic.delay_s("cam0").unwrap();
    for i in 1..4 {
        let raw = raw[i].unwrap().offset_s;
        let uncorrected = raw - OFFSETS[i];
        let corrected =
            raw + acoustic.delay_s(&format!("cam{i}")).unwrap() - ref_delay - OFFSETS[i];
        println!(
            "cam{i}: path-delay error {:.3} ms uncorrected, {:.2} µs corrected",
            uncorrected * 1e3,
            corrected * 1e6
        );
        let expected = (dist(&positions[0]) - dist(&positions[i])) / c;
        assert!(
            (uncorrected - expected).abs() < 1e-4,
            "the uncorrected error is the path difference"
        );
        assert!(
            corrected.abs() < 1e-4,
            "cam{i}: corrected error {corrected}"
        );
    }
}
