//! A live camera whose buffers arrive from a capture thread: [`LiveSource`] turns each
//! [`RawFrame`] (camera pixels + capture time) into a recorder [`Frame`] on the session's
//! clock. Backends that own the device on their own thread (nokhwa) feed it; so do tests,
//! with the simulator's frames. Also: which device a `--device` argument names. This module
//! opens no device itself.

use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use super::FrameClock;
use super::pixels::{PixelError, fourcc_text, to_frame_pixels};
use crate::source::{CameraSource, Frame, SourceError};

/// One buffer as a camera delivered it.
#[derive(Clone, Debug)]
pub struct RawFrame {
    /// Pixel format (V4L2 FourCC: `MJPG`, `YUYV`, `NV12`, `RGB3`, `BGR3`, `GREY`).
    pub fourcc: [u8; 4],
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// The buffer's bytes.
    pub data: Vec<u8>,
    /// When the camera captured it (Unix time), if the backend says.
    pub captured: Option<Duration>,
    /// When it reached this process (Unix time).
    pub arrived: Duration,
}

/// Now, as a Unix time (the clock of nokhwa's capture timestamps on every platform).
pub fn unix_now() -> Duration {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap_or_default()
}

/// A backend's capture time is trusted unless it lies after arrival (beyond this slack)…
const CAPTURE_AFTER_ARRIVAL_SLACK: Duration = Duration::from_millis(20);
/// …or further before arrival than any camera buffers frames.
const MAX_CAPTURE_LATENCY: Duration = Duration::from_secs(2);

/// Seconds from the session's `origin` (Unix time) to a frame's capture: the backend's
/// capture time when it has a plausible one, else its arrival time.
pub fn session_seconds(captured: Option<Duration>, arrived: Duration, origin: Duration) -> f64 {
    let t = match captured {
        Some(c)
            if c <= arrived + CAPTURE_AFTER_ARRIVAL_SLACK
                && arrived.saturating_sub(c) <= MAX_CAPTURE_LATENCY =>
        {
            c
        }
        _ => arrived,
    };
    // Nanoseconds in i128: exact, and negative for a frame captured before the origin.
    (t.as_nanos() as i128 - origin.as_nanos() as i128) as f64 * 1e-9
}

/// Frames missing in a gap of `interval_s` at `fps` (0 unless the gap exceeds 1.5 frames).
pub fn missed_frames(interval_s: f64, fps: f64) -> u64 {
    let frames = interval_s * fps;
    if fps > 0.0 && frames > 1.5 {
        (frames.round() as u64).saturating_sub(1)
    } else {
        0
    }
}

/// How long a camera may deliver nothing before recording stops with an error.
pub const FRAME_TIMEOUT: Duration = Duration::from_secs(10);

/// A live camera fed by a capture thread through a channel; the channel closing ends the
/// stream.
pub struct LiveSource {
    name: String,
    device: String,
    size: (u32, u32),
    fps: f64,
    frames: Receiver<Result<RawFrame, SourceError>>,
    origin: Duration,
    clock: FrameClock,
    last: Option<f64>,
    index: usize,
    dropped: u64,
    timeout: Duration,
}

impl LiveSource {
    /// A source named `name` for `device`, delivering `size` frames at about `fps`, whose
    /// timestamps are seconds since `origin` (Unix time, shared by the session's cameras).
    pub fn new(
        name: &str,
        device: &str,
        size: (u32, u32),
        fps: f64,
        origin: Duration,
        frames: Receiver<Result<RawFrame, SourceError>>,
    ) -> Self {
        LiveSource {
            name: name.to_string(),
            device: device.to_string(),
            size,
            fps,
            frames,
            origin,
            clock: FrameClock::new(0.0),
            last: None,
            index: 0,
            dropped: 0,
            timeout: FRAME_TIMEOUT,
        }
    }

    /// Waits at most `timeout` for each frame (default [`FRAME_TIMEOUT`]).
    pub fn with_timeout(mut self, timeout: Duration) -> Self {
        self.timeout = timeout;
        self
    }

    /// The device this source reads.
    pub fn device(&self) -> &str {
        &self.device
    }

    /// Frames lost so far: gaps in the capture times and corrupt buffers.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    fn error(&self, message: String) -> SourceError {
        SourceError::Device {
            device: self.device.clone(),
            message,
        }
    }
}

impl CameraSource for LiveSource {
    fn name(&self) -> &str {
        &self.name
    }

    fn frame_size(&self) -> (u32, u32) {
        self.size
    }

    fn nominal_fps(&self) -> Option<f64> {
        Some(self.fps)
    }

    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
        loop {
            let raw = match self.frames.recv_timeout(self.timeout) {
                Ok(raw) => raw?,
                Err(RecvTimeoutError::Disconnected) => return Ok(None),
                Err(RecvTimeoutError::Timeout) => {
                    return Err(self.error(format!(
                        "no frame for {} s; check that the camera is still connected and that no other program uses it",
                        self.timeout.as_secs_f64()
                    )));
                }
            };
            if (raw.width, raw.height) != self.size {
                return Err(self.error(format!(
                    "the camera switched from {}x{} to {}x{} while recording; close other programs that configure it",
                    self.size.0, self.size.1, raw.width, raw.height
                )));
            }
            let t = session_seconds(raw.captured, raw.arrived, self.origin);
            let Some(timestamp) = self.clock.stamp_seconds(t, None) else {
                continue; // a repeated buffer
            };
            if let Some(last) = self.last.replace(timestamp) {
                self.dropped += missed_frames(timestamp - last, self.fps);
            }
            let (layout, data) =
                match to_frame_pixels(&raw.fourcc, &raw.data, raw.width, raw.height) {
                    Ok(pixels) => pixels,
                    Err(PixelError::Corrupt { .. } | PixelError::Short { .. }) => {
                        self.dropped += 1;
                        continue;
                    }
                    Err(e) => {
                        return Err(self.error(format!(
                            "{e}; the camera delivers {}, pick another mode",
                            fourcc_text(&raw.fourcc)
                        )));
                    }
                };
            let index = self.index;
            self.index += 1;
            return Ok(Some(Frame {
                index,
                timestamp,
                width: raw.width,
                height: raw.height,
                layout,
                data,
            }));
        }
    }
}

/// What a `--device` argument names: a camera index (`0`, or `/dev/video0` on Linux) or
/// (part of) a camera's name as the backend lists it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DeviceSpec {
    /// The backend's camera index.
    Index(u32),
    /// A camera's name, or a unique part of it (case-insensitive).
    Name(String),
}

impl DeviceSpec {
    /// Reads a `--device` argument.
    pub fn parse(arg: &str) -> Self {
        let arg = arg.trim();
        let digits = arg.strip_prefix("/dev/video").unwrap_or(arg);
        match digits.parse::<u32>() {
            Ok(i) => DeviceSpec::Index(i),
            Err(_) => DeviceSpec::Name(arg.to_string()),
        }
    }
}

impl std::fmt::Display for DeviceSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DeviceSpec::Index(i) => write!(f, "#{i}"),
            DeviceSpec::Name(n) => write!(f, "\"{n}\""),
        }
    }
}

/// A camera a backend lists.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ListedCamera {
    /// Its index for the backend.
    pub index: u32,
    /// Its human-readable name.
    pub name: String,
}

impl std::fmt::Display for ListedCamera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "#{} {}", self.index, self.name)
    }
}

/// The listed camera `spec` names: by index, by exact name, or by the one name that
/// contains it (case-insensitive). The error says what is present.
pub fn resolve_device(spec: &DeviceSpec, listed: &[ListedCamera]) -> Result<ListedCamera, String> {
    let present = || {
        if listed.is_empty() {
            "no camera is present".to_string()
        } else {
            let names: Vec<String> = listed.iter().map(ToString::to_string).collect();
            format!("present: {}", names.join(", "))
        }
    };
    let found: Vec<&ListedCamera> = match spec {
        DeviceSpec::Index(i) => listed.iter().filter(|c| c.index == *i).collect(),
        DeviceSpec::Name(n) => {
            let n = n.to_lowercase();
            let exact: Vec<_> = listed
                .iter()
                .filter(|c| c.name.to_lowercase() == n)
                .collect();
            if exact.is_empty() {
                listed
                    .iter()
                    .filter(|c| c.name.to_lowercase().contains(&n))
                    .collect()
            } else {
                exact
            }
        }
    };
    match found.as_slice() {
        [one] => Ok((*one).clone()),
        [] => Err(format!("no camera {spec} ({})", present())),
        many => Err(format!(
            "{} cameras match {spec} ({}); give an index instead",
            many.len(),
            many.iter()
                .map(|c| c.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn capture_times_are_trusted_only_when_plausible() {
        let origin = Duration::from_secs(1_700_000_000);
        let arrived = origin + Duration::from_millis(1500);
        let captured = origin + Duration::from_micros(1_466_667);
        assert!((session_seconds(Some(captured), arrived, origin) - 1.466667).abs() < 1e-12);
        assert_eq!(session_seconds(None, arrived, origin), 1.5);
        let future = arrived + Duration::from_secs(1);
        assert_eq!(session_seconds(Some(future), arrived, origin), 1.5);
        let stale = arrived - Duration::from_secs(30);
        assert_eq!(session_seconds(Some(stale), arrived, origin), 1.5);
        let before = origin - Duration::from_millis(10);
        assert!((session_seconds(Some(before), before, origin) + 0.01).abs() < 1e-12);
    }

    #[test]
    fn gaps_count_missing_frames() {
        assert_eq!(missed_frames(1.0 / 30.0, 30.0), 0);
        assert_eq!(missed_frames(1.4 / 30.0, 30.0), 0);
        assert_eq!(missed_frames(2.0 / 30.0, 30.0), 1);
        assert_eq!(missed_frames(4.1 / 30.0, 30.0), 3);
        assert_eq!(missed_frames(1.0, 0.0), 0);
    }

    #[test]
    fn devices_are_named_by_index_path_or_name() {
        assert_eq!(DeviceSpec::parse("2"), DeviceSpec::Index(2));
        assert_eq!(DeviceSpec::parse("/dev/video4"), DeviceSpec::Index(4));
        assert_eq!(
            DeviceSpec::parse("FaceTime HD"),
            DeviceSpec::Name("FaceTime HD".into())
        );
        let listed = vec![
            ListedCamera {
                index: 0,
                name: "FaceTime HD Camera".into(),
            },
            ListedCamera {
                index: 1,
                name: "Logitech C920".into(),
            },
            ListedCamera {
                index: 2,
                name: "Logitech C920 #2".into(),
            },
        ];
        let pick = |s: &str| resolve_device(&DeviceSpec::parse(s), &listed);
        assert_eq!(pick("1").unwrap().index, 1);
        assert_eq!(pick("facetime").unwrap().index, 0);
        assert_eq!(
            pick("logitech c920").unwrap().index,
            1,
            "an exact name wins"
        );
        let err = pick("logitech").unwrap_err();
        assert!(err.starts_with("2 cameras match"), "{err}");
        let err = pick("7").unwrap_err();
        assert!(
            err.contains("no camera #7") && err.contains("#1 Logitech C920"),
            "{err}"
        );
        let err = resolve_device(&DeviceSpec::Index(0), &[]).unwrap_err();
        assert_eq!(err, "no camera #0 (no camera is present)");
    }
}
