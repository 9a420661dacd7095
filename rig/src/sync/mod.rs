//! Sync: put every camera on one timeline.
//!
//! Each camera gets an offset (seconds) with `t_common = t_camera + offset`; the reference
//! camera's clock is the common timeline (offset 0). Methods: audio (GCC-PHAT against the
//! reference, [`audio`]), flash (a brightness step timed below one frame, [`flash`]),
//! timestamps (the cameras already share a clock) and manual offsets. `auto` takes audio
//! when every camera has a confident peak, else flash, else fails and says why.
//! This module reads streams and decodes what it needs; it writes no images.

pub mod audio;
pub mod clap;
pub mod flash;
pub mod gcc_phat;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

#[cfg(feature = "ffmpeg")]
use crate::ingest::{CameraStream, IngestError, SourceKind, Streams, decode_audio};
#[cfg(feature = "ffmpeg")]
use crate::source::{CameraSource, PixelLayout, SourceError};
#[cfg(feature = "ffmpeg")]
use audio::audio_offsets;
use audio::{AcousticConfig, AudioSyncConfig};
#[cfg(feature = "ffmpeg")]
use flash::{FrameBrightness, detect_flash};
use shared_types::progress::Progress;

/// How cameras are synchronised.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum SyncMethod {
    /// Audio when every camera has a confident peak, else flash, else an error.
    #[default]
    Auto,
    /// GCC-PHAT of the audio tracks.
    Audio,
    /// A flash (brightness step) seen by every camera.
    Flash,
    /// The streams' timestamps already share a clock (offsets 0).
    Timestamps,
    /// Offsets given in `manual_offsets`.
    Manual,
}

/// The `[sync]` section of `capture.toml`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct SyncConfig {
    /// Which method to use.
    pub method: SyncMethod,
    /// Reference camera (its clock is the common timeline); the first camera by default.
    pub reference: Option<String>,
    /// Largest offset searched between any camera and the reference, seconds.
    pub max_offset_s: f64,
    /// Minimum GCC-PHAT peak-to-sidelobe ratio for `auto` to trust audio.
    pub min_audio_confidence: f64,
    /// Minimum flash rise over frame noise for a flash to count.
    pub min_flash_confidence: f64,
    /// Rolling-shutter readout time (first to last row), seconds; 0 = global shutter.
    pub readout_s: f64,
    /// Exposure time, seconds (0 = unknown); lets a partly lit frame time the flash.
    pub exposure_s: f64,
    /// Audio correlation settings.
    pub audio: AudioSyncConfig,
    /// Known clap and microphone positions: removes the sound's travel time.
    pub acoustic: Option<AcousticConfig>,
    /// Offsets for `method = "manual"`, seconds, by camera name (missing ones are 0).
    pub manual_offsets: BTreeMap<String, f64>,
}

impl Default for SyncConfig {
    fn default() -> Self {
        SyncConfig {
            method: SyncMethod::Auto,
            reference: None,
            max_offset_s: 10.0,
            min_audio_confidence: 10.0,
            min_flash_confidence: 8.0,
            readout_s: 0.0,
            exposure_s: 0.0,
            audio: AudioSyncConfig::default(),
            acoustic: None,
            manual_offsets: BTreeMap::new(),
        }
    }
}

/// The result of sync (`work/sync/sync.json`).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SyncResult {
    /// The method that produced the offsets (never `auto`).
    pub method: SyncMethod,
    /// The reference camera.
    pub reference: String,
    /// One entry per camera, in stream order.
    pub cameras: Vec<CameraSync>,
    /// What was tried and why (fallbacks, corrections).
    pub notes: Vec<String>,
}

/// One camera on the common timeline.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CameraSync {
    /// Camera name.
    pub name: String,
    /// `t_common = t_camera + offset_s`.
    pub offset_s: f64,
    /// Confidence of the estimate (audio: peak-to-sidelobe ratio; flash: rise over noise);
    /// `None` for the reference, timestamps and manual offsets.
    pub confidence: Option<f64>,
    /// Every frame's timestamp on the common timeline, seconds.
    pub timestamps: Vec<f64>,
}

impl SyncResult {
    /// Looks a camera up by name.
    pub fn camera(&self, name: &str) -> Option<&CameraSync> {
        self.cameras.iter().find(|c| c.name == name)
    }

    /// Writes `sync.json` atomically.
    pub fn write_json(&self, path: &Path) -> Result<(), SyncError> {
        shared_types::atomic::write_json(path, self).map_err(|source| SyncError::Io {
            path: path.into(),
            source,
        })
    }

    /// Reads a `sync.json`.
    pub fn read_json(path: &Path) -> Result<Self, SyncError> {
        let text = std::fs::read_to_string(path).map_err(|source| SyncError::Io {
            path: path.into(),
            source,
        })?;
        serde_json::from_str(&text).map_err(|e| SyncError::Io {
            path: path.into(),
            source: std::io::Error::other(e),
        })
    }
}

/// Errors from synchronisation.
#[derive(Debug, thiserror::Error)]
pub enum SyncError {
    /// No usable method: the message lists what each method found per camera.
    #[error("cannot synchronise the cameras: {0}")]
    NoMethod(String),
    /// The configured reference camera does not exist.
    #[error("sync.reference = {0:?} is not one of the cameras ({1})")]
    UnknownReference(String, String),
    /// A manual offset names an unknown camera.
    #[error("sync.manual_offsets names {0:?}, which is not one of the cameras ({1})")]
    UnknownCamera(String, String),
    /// Decoding audio or video failed.
    #[cfg(feature = "ffmpeg")]
    #[error(transparent)]
    Ingest(#[from] IngestError),
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
}

/// Per-camera outcome of one method: the offset or why there is none.
type Attempt = Vec<Result<(f64, f64), String>>;

#[cfg(feature = "ffmpeg")]
/// Synchronises all cameras of `streams` with `config.method`.
pub fn synchronise(
    streams: &Streams,
    config: &SyncConfig,
    progress: &dyn Progress,
) -> Result<SyncResult, SyncError> {
    let names: Vec<&str> = streams.cameras.iter().map(|c| c.name.as_str()).collect();
    let all = names.join(", ");
    if names.is_empty() {
        return Err(SyncError::NoMethod(
            "no cameras in streams.json; rerun ingest".into(),
        ));
    }
    let reference = match &config.reference {
        Some(r) => names
            .iter()
            .position(|n| n == r)
            .ok_or_else(|| SyncError::UnknownReference(r.clone(), all.clone()))?,
        None => 0,
    };
    let mut notes = Vec::new();
    let (method, offsets): (SyncMethod, Vec<(f64, Option<f64>)>) = match config.method {
        SyncMethod::Timestamps => (SyncMethod::Timestamps, vec![(0.0, None); names.len()]),
        SyncMethod::Manual => {
            if let Some(unknown) = config
                .manual_offsets
                .keys()
                .find(|k| !names.contains(&k.as_str()))
            {
                return Err(SyncError::UnknownCamera(unknown.clone(), all));
            }
            let offsets = names
                .iter()
                .map(|n| (config.manual_offsets.get(*n).copied().unwrap_or(0.0), None))
                .collect();
            (SyncMethod::Manual, offsets)
        }
        SyncMethod::Audio => {
            let a = audio_attempt(streams, reference, config, &mut notes, progress)?;
            (
                SyncMethod::Audio,
                accept(&a, &names, reference, "audio", None).map_err(SyncError::NoMethod)?,
            )
        }
        SyncMethod::Flash => {
            let f = flash_attempt(streams, reference, config, progress)?;
            (
                SyncMethod::Flash,
                accept(&f, &names, reference, "flash", None).map_err(SyncError::NoMethod)?,
            )
        }
        SyncMethod::Auto if streams.cameras.iter().all(|c| c.kind == SourceKind::Images) => {
            notes.push(
                "auto: every camera is an image sequence (no sound, no clock): image k of every camera is taken \
                 as the same moment (method timestamps)"
                    .into(),
            );
            (SyncMethod::Timestamps, vec![(0.0, None); names.len()])
        }
        SyncMethod::Auto => {
            let a = audio_attempt(streams, reference, config, &mut notes, progress)?;
            match accept(
                &a,
                &names,
                reference,
                "audio",
                Some(config.min_audio_confidence),
            ) {
                Ok(o) => (SyncMethod::Audio, o),
                Err(audio_why) => {
                    notes.push(format!("auto: audio not used ({audio_why}); trying flash"));
                    let f = flash_attempt(streams, reference, config, progress)?;
                    match accept(
                        &f,
                        &names,
                        reference,
                        "flash",
                        Some(config.min_flash_confidence),
                    ) {
                        Ok(o) => (SyncMethod::Flash, o),
                        Err(flash_why) => {
                            return Err(SyncError::NoMethod(format!(
                                "{audio_why}; {flash_why}. Record a sharp clap heard by every camera, or fire a \
                                 flash seen by every camera, or set sync.method = \"timestamps\" (shared clock) or \
                                 \"manual\" with sync.manual_offsets"
                            )));
                        }
                    }
                }
            }
        }
    };
    let cameras = streams
        .cameras
        .iter()
        .zip(&offsets)
        .map(|(c, &(offset_s, confidence))| CameraSync {
            name: c.name.clone(),
            offset_s,
            confidence,
            timestamps: c.timestamps.iter().map(|t| t + offset_s).collect(),
        })
        .collect();
    Ok(SyncResult {
        method,
        reference: names[reference].to_string(),
        cameras,
        notes,
    })
}

#[cfg(feature = "ffmpeg")]
/// Turns per-camera attempts into offsets, or explains which cameras failed.
fn accept(
    attempt: &Attempt,
    names: &[&str],
    reference: usize,
    what: &str,
    min_confidence: Option<f64>,
) -> Result<Vec<(f64, Option<f64>)>, String> {
    let mut problems = Vec::new();
    let mut out = Vec::new();
    for (i, r) in attempt.iter().enumerate() {
        match r {
            Ok((offset, conf)) => {
                if let Some(min) = min_confidence
                    && conf.is_finite()
                    && *conf < min
                {
                    problems.push(format!("{} peak confidence {conf:.1} < {min}", names[i]));
                }
                out.push((*offset, if i == reference { None } else { Some(*conf) }));
            }
            Err(why) => problems.push(format!("{}: {why}", names[i])),
        }
    }
    if problems.is_empty() {
        Ok(out)
    } else {
        Err(format!("{what}: {}", problems.join(", ")))
    }
}

#[cfg(feature = "ffmpeg")]
fn audio_attempt(
    streams: &Streams,
    reference: usize,
    config: &SyncConfig,
    notes: &mut Vec<String>,
    progress: &dyn Progress,
) -> Result<Attempt, SyncError> {
    progress.start(streams.cameras.len() as u64, "audio tracks");
    let mut tracks = Vec::new();
    for c in &streams.cameras {
        progress.message(&format!("decoding audio of {}", c.name));
        tracks.push(decode_audio(c)?);
        progress.advance(1);
    }
    progress.finish();
    let offsets = audio_offsets(&tracks, reference, config.max_offset_s, &config.audio);
    if let Some(track) = &tracks[reference] {
        let clap = config
            .audio
            .use_clap
            .then(|| {
                clap::detect_clap(
                    &track.samples,
                    track.sample_rate,
                    config.audio.clap_prominence,
                )
            })
            .flatten();
        notes.push(match clap {
            Some(c) => format!(
                "audio: correlated around the clap at {:.3} s of {}",
                track.start_s + c.sample as f64 / f64::from(track.sample_rate),
                streams.cameras[reference].name
            ),
            None => format!(
                "audio: no clap found; correlated the first {} s of {}",
                config.audio.max_excerpt_s, streams.cameras[reference].name
            ),
        });
    }
    let ref_delay = config
        .acoustic
        .as_ref()
        .and_then(|a| a.delay_s(&streams.cameras[reference].name));
    let attempt = streams
        .cameras
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let Some(o) = offsets[i] else {
                return Err(match &tracks[i] {
                    None => "no audio track".to_string(),
                    Some(_) if i != reference && offsets[reference].is_none() => {
                        format!(
                            "reference camera {} has no usable audio",
                            streams.cameras[reference].name
                        )
                    }
                    Some(_) => "silent audio track".to_string(),
                });
            };
            let mut offset = o.offset_s;
            if let (Some(acoustic), Some(rd)) = (&config.acoustic, ref_delay)
                && let Some(d) = acoustic.delay_s(&c.name)
            {
                offset += d - rd;
                if i != reference {
                    notes.push(format!(
                        "{}: acoustic path correction {:+.3} ms",
                        c.name,
                        (d - rd) * 1e3
                    ));
                }
            }
            Ok((offset, o.confidence))
        })
        .collect();
    Ok(attempt)
}

#[cfg(feature = "ffmpeg")]
/// Mean luma of every row of every frame of a camera (decoded as narrow grey images).
pub fn brightness_profile(stream: &CameraStream) -> Result<Vec<FrameBrightness>, SyncError> {
    let width = stream.video.width.clamp(1, 64);
    let height = stream.video.height.max(1);
    let src = |source: SourceError| IngestError::Source {
        camera: stream.name.clone(),
        source,
    };
    let mut source = stream
        .open(PixelLayout::Gray8, Some((width, height)))
        .map_err(src)?;
    let mut out = Vec::with_capacity(stream.timestamps.len());
    while let Some(frame) = source.next_frame().map_err(src)? {
        let w = frame.width as usize;
        let rows = frame
            .data
            .chunks_exact(w)
            .map(|row| row.iter().map(|&v| f32::from(v)).sum::<f32>() / w as f32)
            .collect();
        out.push(FrameBrightness {
            timestamp: frame.timestamp,
            rows,
        });
    }
    Ok(out)
}

#[cfg(feature = "ffmpeg")]
fn flash_attempt(
    streams: &Streams,
    reference: usize,
    config: &SyncConfig,
    progress: &dyn Progress,
) -> Result<Attempt, SyncError> {
    progress.start(streams.cameras.len() as u64, "cameras");
    let mut events = Vec::new();
    for c in &streams.cameras {
        progress.message(&format!("measuring brightness of {}", c.name));
        let profile = brightness_profile(c)?;
        events.push(detect_flash(&profile, config.readout_s, config.exposure_s));
        progress.advance(1);
    }
    progress.finish();
    let Some(ref_event) = events[reference] else {
        let why = |i| {
            if i == reference {
                "no brightness step found"
            } else {
                "reference camera saw no flash"
            }
        };
        return Ok((0..events.len()).map(|i| Err(why(i).to_string())).collect());
    };
    Ok(events
        .iter()
        .map(|e| match e {
            Some(e) => Ok((ref_event.time - e.time, e.confidence)),
            None => Err("no brightness step found".to_string()),
        })
        .collect())
}
