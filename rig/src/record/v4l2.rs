//! The V4L2 camera source: opens a `/dev/videoN` device, negotiates a capture mode, and
//! yields RGB frames stamped with the kernel's buffer timestamps (CLOCK_MONOTONIC) made
//! relative to the recording session's origin.

use std::path::{Path, PathBuf};

use super::{FormatOption, FrameClock, RecordConfig, RecordError, negotiate};
use crate::source::{CameraSource, Frame, SourceError};

/// The `/dev/video*` device nodes present, sorted.
pub fn list_devices() -> Vec<PathBuf> {
    let mut found: Vec<PathBuf> = std::fs::read_dir("/dev")
        .map(|d| {
            d.filter_map(Result::ok)
                .map(|e| e.path())
                .filter(|p| {
                    p.file_name()
                        .and_then(|n| n.to_str())
                        .is_some_and(|n| n.starts_with("video"))
                })
                .collect()
        })
        .unwrap_or_default();
    found.sort();
    found
}

/// Kernel CLOCK_MONOTONIC now, seconds (the clock of V4L2 buffer timestamps).
pub fn monotonic_now() -> f64 {
    #[cfg(target_os = "linux")]
    {
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: clock_gettime writes into the timespec we own.
        if unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) } == 0 {
            return ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9;
        }
    }
    0.0
}

pub use super::pixels::yuyv_to_rgb;

/// A live V4L2 camera.
pub struct V4l2Source {
    name: String,
    device: String,
    #[cfg(target_os = "linux")]
    stream: v4l::io::mmap::Stream<'static>,
    #[cfg(target_os = "linux")]
    _dev: v4l::Device,
    fourcc: [u8; 4],
    size: (u32, u32),
    fps: f64,
    clock: FrameClock,
    index: usize,
}

fn device_err(device: &Path, e: impl std::fmt::Display) -> RecordError {
    RecordError::Source(SourceError::Device {
        device: device.display().to_string(),
        message: e.to_string(),
    })
}

impl V4l2Source {
    /// Opens `path`, negotiates a mode close to `config`, and starts streaming; frame
    /// timestamps are kernel time minus `origin_s`.
    #[cfg(target_os = "linux")]
    pub fn open(
        name: &str,
        path: &Path,
        config: &RecordConfig,
        origin_s: f64,
    ) -> Result<Self, RecordError> {
        use v4l::video::Capture;
        if !path.exists() {
            return Err(RecordError::NoDevice(format!(
                "{} does not exist",
                path.display()
            )));
        }
        let dev = v4l::Device::with_path(path).map_err(|e| device_err(path, e))?;
        let mut offered = Vec::new();
        for desc in dev.enum_formats().map_err(|e| device_err(path, e))? {
            for size in dev.enum_framesizes(desc.fourcc).unwrap_or_default() {
                for d in size.size.to_discrete() {
                    let fps = dev
                        .enum_frameintervals(desc.fourcc, d.width, d.height)
                        .unwrap_or_default()
                        .into_iter()
                        .filter_map(|i| match i.interval {
                            v4l::frameinterval::FrameIntervalEnum::Discrete(f)
                                if f.numerator > 0 =>
                            {
                                Some(f64::from(f.denominator) / f64::from(f.numerator))
                            }
                            _ => None,
                        })
                        .collect();
                    offered.push(FormatOption {
                        fourcc: desc.fourcc.repr,
                        width: d.width,
                        height: d.height,
                        fps,
                    });
                }
            }
        }
        let Some((choice, fps)) = negotiate(&offered, config) else {
            let list = offered
                .iter()
                .map(|o| {
                    format!(
                        "{} {}x{}",
                        String::from_utf8_lossy(&o.fourcc),
                        o.width,
                        o.height
                    )
                })
                .collect::<Vec<_>>()
                .join(", ");
            return Err(RecordError::NoFormat {
                device: path.display().to_string(),
                offered: list,
            });
        };
        let mut fmt = dev.format().map_err(|e| device_err(path, e))?;
        fmt.width = choice.width;
        fmt.height = choice.height;
        fmt.fourcc = v4l::FourCC::new(&choice.fourcc);
        let fmt = dev.set_format(&fmt).map_err(|e| device_err(path, e))?;
        let params = v4l::video::capture::Parameters::with_fps(fps.round().max(1.0) as u32);
        let _ = dev.set_params(&params);
        let stream = v4l::io::mmap::Stream::with_buffers(&dev, v4l::buffer::Type::VideoCapture, 4)
            .map_err(|e| device_err(path, e))?;
        Ok(V4l2Source {
            name: name.to_string(),
            device: path.display().to_string(),
            stream,
            _dev: dev,
            fourcc: fmt.fourcc.repr,
            size: (fmt.width, fmt.height),
            fps,
            clock: FrameClock::new(origin_s),
            index: 0,
        })
    }

    /// V4L2 is Linux-only.
    #[cfg(not(target_os = "linux"))]
    pub fn open(
        _name: &str,
        path: &Path,
        _config: &RecordConfig,
        _origin_s: f64,
    ) -> Result<Self, RecordError> {
        Err(RecordError::NoDevice(format!(
            "{}: V4L2 needs Linux",
            path.display()
        )))
    }

    /// Frames the driver dropped so far.
    pub fn dropped(&self) -> u64 {
        self.clock.dropped
    }
}

impl CameraSource for V4l2Source {
    fn name(&self) -> &str {
        &self.name
    }

    fn frame_size(&self) -> (u32, u32) {
        self.size
    }

    fn nominal_fps(&self) -> Option<f64> {
        Some(self.fps)
    }

    #[cfg(target_os = "linux")]
    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
        use super::pixels::{PixelError, to_frame_pixels};
        use v4l::io::traits::CaptureStream;
        let dev_err = |m: String| SourceError::Device {
            device: self.device.clone(),
            message: m,
        };
        loop {
            let (buf, meta) = self.stream.next().map_err(|e| dev_err(e.to_string()))?;
            let used = &buf[..(meta.bytesused as usize).min(buf.len())];
            // `time_t` is i64 on 64-bit Linux and i32 on 32-bit: widen either way.
            #[allow(clippy::useless_conversion)]
            let stamped = self.clock.stamp(
                meta.timestamp.sec.into(),
                meta.timestamp.usec.into(),
                Some(meta.sequence),
            );
            let Some(timestamp) = stamped else {
                continue;
            };
            let (w, h) = self.size;
            let (layout, data) = match to_frame_pixels(&self.fourcc, used, w, h) {
                Ok(pixels) => pixels,
                // A corrupt or truncated frame counts as dropped.
                Err(PixelError::Corrupt { .. } | PixelError::Short { .. }) => {
                    self.clock.dropped += 1;
                    continue;
                }
                Err(e) => return Err(dev_err(e.to_string())),
            };
            let index = self.index;
            self.index += 1;
            return Ok(Some(Frame {
                index,
                timestamp,
                width: w,
                height: h,
                layout,
                data,
            }));
        }
    }

    #[cfg(not(target_os = "linux"))]
    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
        Ok(None)
    }
}
