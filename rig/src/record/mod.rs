//! Live recording: capture up to four cameras concurrently into the same layout as video
//! files (`CAPTURE_DIR/raw/camN/capture.mov` + `timestamps.csv`), so ingest treats a live
//! recording like any other.
//!
//! Device-independent parts (format negotiation, the frame clock, the writer, pixel
//! conversion in [`pixels`], the capture-thread source in [`live`]) are plain functions
//! tested with any [`CameraSource`]. Devices come through [`v4l2::V4l2Source`] (kernel
//! buffer timestamps, CLOCK_MONOTONIC) or, with the `nokhwa` feature, `nokhwa` (the
//! backend's capture times on Linux, macOS and Windows); either way the times are made
//! relative to one session origin shared by all cameras, so `sync.method = "timestamps"`
//! works for cameras on one machine. This module does not synchronise or decode files.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use ffmpeg_next as ffmpeg;
use serde::{Deserialize, Serialize};

use crate::source::{CameraSource, Frame, PixelLayout, SourceError, init_ffmpeg};
use shared_types::atomic::{temp_sibling, write_atomic};
use shared_types::progress::Progress;

pub mod live;
#[cfg(feature = "nokhwa")]
pub mod nokhwa;
pub mod pixels;
pub mod v4l2;

/// Errors from live recording.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// No camera device is present.
    #[error(
        "no V4L2 device found ({0}); plug the cameras in, check `ls /dev/video*` and that you are in the `video` group"
    )]
    NoDevice(String),
    /// No camera matches a `--device` through the nokhwa backend.
    #[error(
        "{detail} through nokhwa ({backend}); plug the camera in, close other programs that use it, and see the cameras with `pipeline record --backend nokhwa --list`"
    )]
    NoCamera {
        /// nokhwa's native backend (`Video4Linux`, `AVFoundation`, `MediaFoundation`).
        backend: String,
        /// Which camera was asked for and which are present.
        detail: String,
    },
    /// The nokhwa backend was asked for in a build without it.
    #[error(
        "this build has no nokhwa camera backend; rebuild with `cargo build --release -p pipeline --features nokhwa`{hint}"
    )]
    NokhwaNotBuilt {
        /// What else to do on this platform.
        hint: &'static str,
    },
    /// Too many devices.
    #[error("{0} devices given; record at most 4 cameras at once")]
    TooMany(usize),
    /// The device offers no usable format.
    #[error(
        "{device}: no usable capture format (offered: {offered}); pick another device or resolution"
    )]
    NoFormat {
        /// The device.
        device: String,
        /// What it offers.
        offered: String,
    },
    /// A source failed.
    #[error(transparent)]
    Source(#[from] SourceError),
    /// One camera of a concurrent recording failed (the others were stopped).
    #[error("camera {camera}: {source}; the other cameras were stopped")]
    Camera {
        /// The camera's name.
        camera: String,
        /// What went wrong.
        source: Box<RecordError>,
    },
    /// Encoding or writing failed.
    #[error("writing {path}: {message}")]
    Write {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
}

/// The `[record]` settings: what to ask the cameras for.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RecordConfig {
    /// Wanted width, pixels.
    pub width: u32,
    /// Wanted height, pixels.
    pub height: u32,
    /// Wanted frames per second.
    pub fps: f64,
    /// Stop after this many seconds (otherwise when asked to stop).
    pub duration_s: Option<f64>,
    /// Ask the user to fire a flash (or clap) once every camera is running.
    pub flash_prompt: bool,
}

impl Default for RecordConfig {
    fn default() -> Self {
        RecordConfig {
            width: 1280,
            height: 720,
            fps: 30.0,
            duration_s: None,
            flash_prompt: true,
        }
    }
}

/// One capture mode a device offers.
#[derive(Clone, Debug, PartialEq)]
pub struct FormatOption {
    /// FourCC (`MJPG`, `YUYV`, …).
    pub fourcc: [u8; 4],
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Frame rates offered at this size.
    pub fps: Vec<f64>,
}

/// Pixel formats we can convert, best first (MJPEG keeps USB bandwidth low for 4 cameras).
pub const SUPPORTED_FOURCC: [[u8; 4]; 3] = [*b"MJPG", *b"YUYV", *b"GREY"];

/// Chooses a capture mode: a supported pixel format, the size closest to the wanted one
/// (larger preferred on ties), the frame rate closest to the wanted one, MJPEG first.
pub fn negotiate(offered: &[FormatOption], want: &RecordConfig) -> Option<(FormatOption, f64)> {
    negotiate_among(offered, want, &SUPPORTED_FOURCC)
}

/// [`negotiate`] among the pixel formats `supported`, best first.
pub fn negotiate_among(
    offered: &[FormatOption],
    want: &RecordConfig,
    supported: &[[u8; 4]],
) -> Option<(FormatOption, f64)> {
    let size_cost = |o: &FormatOption| {
        let dw = (f64::from(o.width) - f64::from(want.width)).abs();
        let dh = (f64::from(o.height) - f64::from(want.height)).abs();
        let smaller = if o.width < want.width || o.height < want.height {
            0.5
        } else {
            0.0
        };
        dw + dh + smaller
    };
    let fps_of = |o: &FormatOption| {
        o.fps
            .iter()
            .copied()
            .min_by(|a, b| (a - want.fps).abs().total_cmp(&(b - want.fps).abs()))
            .unwrap_or(want.fps)
    };
    offered
        .iter()
        .filter_map(|o| {
            supported
                .iter()
                .position(|f| *f == o.fourcc)
                .map(|rank| (rank, o))
        })
        .min_by(|(ra, a), (rb, b)| {
            let ka = (size_cost(a), (fps_of(a) - want.fps).abs(), *ra);
            let kb = (size_cost(b), (fps_of(b) - want.fps).abs(), *rb);
            ka.partial_cmp(&kb).unwrap_or(std::cmp::Ordering::Equal)
        })
        .map(|(_, o)| (o.clone(), fps_of(o)))
}

/// Turns kernel buffer timestamps into session seconds and counts dropped frames from the
/// driver's sequence numbers.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameClock {
    /// Kernel time (seconds) that becomes 0 on the recording's timeline.
    pub origin_s: f64,
    last_sequence: Option<u32>,
    last_time: Option<f64>,
    /// Frames the driver skipped (sequence gaps).
    pub dropped: u64,
}

impl FrameClock {
    /// A clock whose zero is kernel time `origin_s` (shared by all cameras of a session).
    pub fn new(origin_s: f64) -> Self {
        FrameClock {
            origin_s,
            last_sequence: None,
            last_time: None,
            dropped: 0,
        }
    }

    /// Session time of a frame with kernel timestamp `(sec, usec)` and driver `sequence`.
    /// Returns `None` for a frame that does not advance time (a repeated buffer).
    pub fn stamp(&mut self, sec: i64, usec: i64, sequence: Option<u32>) -> Option<f64> {
        self.stamp_seconds(sec as f64 + usec as f64 * 1e-6, sequence)
    }

    /// Session time of a frame taken at `time_s` on the clock of `origin_s` (see
    /// [`FrameClock::stamp`]).
    pub fn stamp_seconds(&mut self, time_s: f64, sequence: Option<u32>) -> Option<f64> {
        let t = time_s - self.origin_s;
        if self.last_time.is_some_and(|last| t <= last) {
            return None;
        }
        if let (Some(prev), Some(seq)) = (self.last_sequence, sequence) {
            self.dropped += u64::from(seq.wrapping_sub(prev).saturating_sub(1));
        }
        self.last_sequence = sequence.or(self.last_sequence);
        self.last_time = Some(t);
        Some(t)
    }
}

/// Encodes frames with exact timestamps into `capture.mov` (Motion JPEG, microsecond
/// timestamps) and lists them in `timestamps.csv`; both appear only when complete. While
/// recording, the video grows under a temporary sibling name
/// ([`shared_types::atomic::temp_sibling`]) that [`CaptureWriter::finish`] renames.
pub struct CaptureWriter {
    dir: PathBuf,
    /// The recording while it is written: the temporary sibling of `capture.mov`.
    tmp: PathBuf,
    output: ffmpeg::format::context::Output,
    encoder: ffmpeg::encoder::Video,
    scaler: Option<(PixelLayout, ffmpeg::software::scaling::Context)>,
    stream_time_base: ffmpeg::Rational,
    size: (u32, u32),
    csv: String,
    frames: usize,
    /// Pts (µs) of the last frame written, and the interval before it: the last packet's
    /// duration, which the muxer needs to keep the final frame inside the edit list.
    last_pts: Option<i64>,
    interval: i64,
}

const TIME_BASE: ffmpeg::Rational = ffmpeg::Rational(1, 1_000_000);

impl CaptureWriter {
    /// Starts `dir/capture.mov` for frames of `size`.
    pub fn create(dir: &Path, size: (u32, u32)) -> Result<Self, RecordError> {
        init_ffmpeg();
        let tmp = temp_sibling(&dir.join("capture.mov"));
        let err = |e: ffmpeg::Error| RecordError::Write {
            path: tmp.clone(),
            message: e.to_string(),
        };
        std::fs::create_dir_all(dir).map_err(|e| RecordError::Write {
            path: dir.into(),
            message: e.to_string(),
        })?;
        let mut output = ffmpeg::format::output_as(&tmp, "mov").map_err(err)?;
        let codec =
            ffmpeg::encoder::find(ffmpeg::codec::Id::MJPEG).ok_or_else(|| RecordError::Write {
                path: tmp.clone(),
                message: "FFmpeg has no MJPEG encoder".into(),
            })?;
        let global = output
            .format()
            .flags()
            .contains(ffmpeg::format::Flags::GLOBAL_HEADER);
        let mut ost = output.add_stream(codec).map_err(err)?;
        let mut enc = ffmpeg::codec::context::Context::new_with_codec(codec)
            .encoder()
            .video()
            .map_err(err)?;
        enc.set_width(size.0);
        enc.set_height(size.1);
        enc.set_format(ffmpeg::format::Pixel::YUVJ420P);
        enc.set_time_base(TIME_BASE);
        if global {
            enc.set_flags(ffmpeg::codec::Flags::GLOBAL_HEADER);
        }
        let mut opts = ffmpeg::Dictionary::new();
        opts.set("q:v", "3");
        let encoder = enc.open_with(opts).map_err(err)?;
        ost.set_parameters(&encoder);
        ost.set_time_base(TIME_BASE);
        let mut header_opts = ffmpeg::Dictionary::new();
        header_opts.set("video_track_timescale", "1000000");
        // The edit list that carries a non-zero first timestamp is in the movie timescale
        // (1/1000 s by default, which would round the start by up to 0.5 ms).
        header_opts.set("movie_timescale", "1000000");
        output.write_header_with(header_opts).map_err(err)?;
        let stream_time_base = output.stream(0).map(|s| s.time_base()).unwrap_or(TIME_BASE);
        Ok(CaptureWriter {
            dir: dir.to_path_buf(),
            tmp,
            output,
            encoder,
            scaler: None,
            stream_time_base,
            size,
            csv: String::from("frame,timestamp_s\n"),
            frames: 0,
            last_pts: None,
            interval: 33_333,
        })
    }

    /// Appends one frame; `frame.timestamp` (seconds, ≥ 0, increasing) becomes its pts.
    pub fn write(&mut self, frame: &Frame) -> Result<(), RecordError> {
        let path = self.tmp.clone();
        let err = |e: ffmpeg::Error| RecordError::Write {
            path: path.clone(),
            message: e.to_string(),
        };
        let (w, h) = self.size;
        if (frame.width, frame.height) != (w, h) {
            return Err(RecordError::Write {
                path: path.clone(),
                message: format!(
                    "frame {}x{} in a {w}x{h} recording",
                    frame.width, frame.height
                ),
            });
        }
        let pixel = match frame.layout {
            PixelLayout::Rgb8 => ffmpeg::format::Pixel::RGB24,
            PixelLayout::Gray8 => ffmpeg::format::Pixel::GRAY8,
        };
        if self.scaler.as_ref().is_none_or(|(l, _)| *l != frame.layout) {
            let s = ffmpeg::software::scaling::Context::get(
                pixel,
                w,
                h,
                ffmpeg::format::Pixel::YUVJ420P,
                w,
                h,
                ffmpeg::software::scaling::Flags::BILINEAR,
            )
            .map_err(err)?;
            self.scaler = Some((frame.layout, s));
        }
        let mut src = ffmpeg::frame::Video::new(pixel, w, h);
        let row = w as usize * frame.layout.channels();
        let stride = src.stride(0);
        for y in 0..h as usize {
            src.data_mut(0)[y * stride..y * stride + row]
                .copy_from_slice(&frame.data[y * row..(y + 1) * row]);
        }
        let mut yuv = ffmpeg::frame::Video::empty();
        if let Some((_, s)) = self.scaler.as_mut() {
            s.run(&src, &mut yuv).map_err(err)?;
        }
        let pts = (frame.timestamp * 1e6).round() as i64;
        if let Some(last) = self.last_pts {
            self.interval = (pts - last).max(1);
        }
        self.last_pts = Some(pts);
        yuv.set_pts(Some(pts));
        self.encoder.send_frame(&yuv).map_err(err)?;
        self.drain()?;
        self.csv
            .push_str(&format!("{},{:.6}\n", self.frames, frame.timestamp));
        self.frames += 1;
        Ok(())
    }

    fn drain(&mut self) -> Result<(), RecordError> {
        let path = self.tmp.clone();
        let mut packet = ffmpeg::Packet::empty();
        while self.encoder.receive_packet(&mut packet).is_ok() {
            packet.set_stream(0);
            packet.set_duration(self.interval);
            packet.rescale_ts(TIME_BASE, self.stream_time_base);
            packet
                .write_interleaved(&mut self.output)
                .map_err(|e| RecordError::Write {
                    path: path.clone(),
                    message: e.to_string(),
                })?;
        }
        Ok(())
    }

    /// Flushes, closes and renames the files; returns the video's path.
    pub fn finish(mut self) -> Result<PathBuf, RecordError> {
        let path = self.tmp.clone();
        let err = |e: ffmpeg::Error| RecordError::Write {
            path: path.clone(),
            message: e.to_string(),
        };
        self.encoder.send_eof().map_err(err)?;
        self.drain()?;
        self.output.write_trailer().map_err(err)?;
        let io = |p: &Path, e: std::io::Error| RecordError::Write {
            path: p.into(),
            message: e.to_string(),
        };
        let csv = self.dir.join("timestamps.csv");
        write_atomic(&csv, self.csv.as_bytes()).map_err(|e| io(&csv, e))?;
        let video = self.dir.join("capture.mov");
        std::fs::rename(&path, &video).map_err(|e| io(&video, e))?;
        Ok(video)
    }
}

/// What one camera recorded.
#[derive(Clone, Debug, PartialEq)]
pub struct RecordedCamera {
    /// Camera name.
    pub name: String,
    /// Its folder (`raw/camN`).
    pub dir: PathBuf,
    /// Frames written.
    pub frames: usize,
}

/// Records `source` into `dir` until it ends, `stop` is set, or `max_duration_s` of its
/// own time has passed.
pub fn record_source(
    source: &mut dyn CameraSource,
    dir: &Path,
    stop: &AtomicBool,
    max_duration_s: Option<f64>,
    progress: &dyn Progress,
) -> Result<RecordedCamera, RecordError> {
    let mut writer = CaptureWriter::create(dir, source.frame_size())?;
    let mut first: Option<f64> = None;
    while !stop.load(Ordering::Relaxed) {
        let Some(frame) = source.next_frame()? else {
            break;
        };
        let t0 = *first.get_or_insert(frame.timestamp);
        if max_duration_s.is_some_and(|d| frame.timestamp - t0 > d) {
            break;
        }
        writer.write(&frame)?;
        progress.advance(1);
    }
    let frames = writer.frames;
    writer.finish()?;
    Ok(RecordedCamera {
        name: source.name().to_string(),
        dir: dir.to_path_buf(),
        frames,
    })
}

/// The library that talks to the cameras.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CaptureBackend {
    /// V4L2 directly (Linux): kernel buffer timestamps and driver sequence numbers.
    V4l2,
    /// nokhwa (feature `nokhwa`): V4L2 on Linux, AVFoundation on macOS, Media Foundation on
    /// Windows; the backend's capture timestamps.
    Nokhwa,
}

impl CaptureBackend {
    /// The default here: V4L2 on Linux, nokhwa elsewhere.
    pub fn native() -> Self {
        if cfg!(target_os = "linux") {
            CaptureBackend::V4l2
        } else {
            CaptureBackend::Nokhwa
        }
    }
}

/// The cameras `backend` finds, one line each (`/dev/video0`; `#0 Logitech C920`).
pub fn list_cameras(backend: CaptureBackend) -> Result<Vec<String>, RecordError> {
    match backend {
        CaptureBackend::V4l2 => Ok(v4l2::list_devices()
            .iter()
            .map(|p| p.display().to_string())
            .collect()),
        #[cfg(feature = "nokhwa")]
        CaptureBackend::Nokhwa => Ok(nokhwa::list_cameras()?
            .iter()
            .map(ToString::to_string)
            .collect()),
        #[cfg(not(feature = "nokhwa"))]
        CaptureBackend::Nokhwa => Err(nokhwa_not_built()),
    }
}

#[cfg(not(feature = "nokhwa"))]
fn nokhwa_not_built() -> RecordError {
    RecordError::NokhwaNotBuilt {
        hint: if cfg!(target_os = "linux") {
            ", or record with --backend v4l2"
        } else {
            ""
        },
    }
}

/// Records `devices` through `backend` (see [`record`] and [`record_nokhwa`]); a device is
/// a path (`/dev/video0`) for V4L2, an index, `/dev/videoN` or a camera's name for nokhwa.
pub fn record_with(
    backend: CaptureBackend,
    devices: &[String],
    capture_dir: &Path,
    config: &RecordConfig,
    stop: &AtomicBool,
    progress: &dyn Progress,
) -> Result<Vec<RecordedCamera>, RecordError> {
    match backend {
        CaptureBackend::V4l2 => {
            let paths: Vec<PathBuf> = devices.iter().map(PathBuf::from).collect();
            record(&paths, capture_dir, config, stop, progress)
        }
        CaptureBackend::Nokhwa => record_nokhwa(devices, capture_dir, config, stop, progress),
    }
}

/// Records cameras through nokhwa concurrently into `capture_dir/raw/camN/`, stamped with
/// the backend's capture times relative to one session origin. Fails cleanly with
/// [`RecordError::NoCamera`] when a camera is missing, and with
/// [`RecordError::NokhwaNotBuilt`] in a build without the `nokhwa` feature.
pub fn record_nokhwa(
    devices: &[String],
    capture_dir: &Path,
    config: &RecordConfig,
    stop: &AtomicBool,
    progress: &dyn Progress,
) -> Result<Vec<RecordedCamera>, RecordError> {
    #[cfg(feature = "nokhwa")]
    {
        if devices.len() > 4 {
            return Err(RecordError::TooMany(devices.len()));
        }
        let sources = nokhwa::open_all(devices, config)?;
        record_opened(sources, capture_dir, config, stop, progress)
    }
    #[cfg(not(feature = "nokhwa"))]
    {
        let _ = (devices, capture_dir, config, stop, progress);
        Err(nokhwa_not_built())
    }
}

/// Records every device concurrently into `capture_dir/raw/camN/` (see [`record_sources`]).
/// Fails cleanly with [`RecordError::NoDevice`] when a device is missing.
pub fn record(
    devices: &[PathBuf],
    capture_dir: &Path,
    config: &RecordConfig,
    stop: &AtomicBool,
    progress: &dyn Progress,
) -> Result<Vec<RecordedCamera>, RecordError> {
    if devices.is_empty() {
        let found = v4l2::list_devices();
        if found.is_empty() {
            return Err(RecordError::NoDevice("no /dev/video* present".into()));
        }
        return Err(RecordError::NoDevice(format!(
            "none given; present: {}",
            found
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    if devices.len() > 4 {
        return Err(RecordError::TooMany(devices.len()));
    }
    let origin = v4l2::monotonic_now();
    let mut sources: Vec<Box<dyn CameraSource>> = Vec::new();
    for (i, d) in devices.iter().enumerate() {
        sources.push(Box::new(v4l2::V4l2Source::open(
            &format!("cam{i}"),
            d,
            config,
            origin,
        )?));
    }
    record_opened(sources, capture_dir, config, stop, progress)
}

/// Records opened `sources` for `config.duration_s`, prompting for the flash when asked.
fn record_opened(
    sources: Vec<Box<dyn CameraSource>>,
    capture_dir: &Path,
    config: &RecordConfig,
    stop: &AtomicBool,
    progress: &dyn Progress,
) -> Result<Vec<RecordedCamera>, RecordError> {
    let camera_count = sources.len();
    let prompt = config.flash_prompt;
    record_sources(
        sources,
        capture_dir,
        config.duration_s,
        stop,
        progress,
        &mut || {
            if prompt {
                tracing::info!(
                    "all {camera_count} cameras are delivering frames: fire the flash (or clap) now"
                );
            }
        },
    )
}

/// What a camera task tells the coordinator.
enum Event {
    /// `n` more frames written by camera `camera`.
    Frames { camera: usize, n: u64 },
}

/// Forwards a camera task's progress to the coordinator.
struct ChannelProgress {
    camera: usize,
    events: tokio::sync::mpsc::UnboundedSender<Event>,
}

impl Progress for ChannelProgress {
    fn start(&self, _total: u64, _unit: &str) {}
    fn advance(&self, n: u64) {
        // The coordinator outlives every camera task; a closed channel only means it has
        // already given up, and the frames are on disk either way.
        let _ = self.events.send(Event::Frames {
            camera: self.camera,
            n,
        });
    }
    fn message(&self, _msg: &str) {}
    fn finish(&self) {}
}

/// Records `sources` concurrently, one tokio task per camera, into
/// `capture_dir/raw/<source name>/`, each for at most `max_duration_s` of its own time.
///
/// Capture is blocking work (V4L2 dequeues are blocking ioctls), so each camera task runs
/// on tokio's blocking pool; the coordinator, on the calling thread, counts frames into
/// `progress`, calls `on_all_running` once every camera has written its first frame (the
/// moment to fire the sync flash), forwards `stop`, and stops every camera as soon as one
/// fails. Returns the cameras in the order given, or the first failure, naming the camera.
pub fn record_sources(
    sources: Vec<Box<dyn CameraSource>>,
    capture_dir: &Path,
    max_duration_s: Option<f64>,
    stop: &AtomicBool,
    progress: &dyn Progress,
    on_all_running: &mut dyn FnMut(),
) -> Result<Vec<RecordedCamera>, RecordError> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .map_err(|e| RecordError::Write {
            path: capture_dir.into(),
            message: format!("cannot start the recording runtime: {e}"),
        })?;
    let names: Vec<String> = sources.iter().map(|s| s.name().to_string()).collect();
    let halt = Arc::new(AtomicBool::new(false));
    let (tx, mut events) = tokio::sync::mpsc::unbounded_channel();
    progress.start(0, "frames");
    let result = runtime.block_on(async {
        let mut tasks = tokio::task::JoinSet::new();
        for (camera, mut source) in sources.into_iter().enumerate() {
            let dir = capture_dir.join("raw").join(source.name());
            let halt = halt.clone();
            let sink = ChannelProgress {
                camera,
                events: tx.clone(),
            };
            tasks.spawn_blocking(move || {
                let r = record_source(source.as_mut(), &dir, &halt, max_duration_s, &sink);
                (camera, r)
            });
        }
        drop(tx);
        let mut running = vec![false; names.len()];
        let mut prompted = false;
        let mut done: Vec<Option<RecordedCamera>> = vec![None; names.len()];
        let mut failure: Option<RecordError> = None;
        let mut poll = tokio::time::interval(std::time::Duration::from_millis(20));
        loop {
            tokio::select! {
                Some(Event::Frames { camera, n }) = events.recv() => {
                    progress.advance(n);
                    running[camera] = true;
                    if !prompted && running.iter().all(|&r| r) {
                        prompted = true;
                        on_all_running();
                    }
                }
                joined = tasks.join_next() => {
                    let Some(joined) = joined else { break };
                    match joined {
                        Ok((camera, Ok(rec))) => done[camera] = Some(rec),
                        Ok((camera, Err(e))) => {
                            halt.store(true, Ordering::Relaxed);
                            failure.get_or_insert(RecordError::Camera {
                                camera: names[camera].clone(),
                                source: Box::new(e),
                            });
                        }
                        Err(e) => {
                            halt.store(true, Ordering::Relaxed);
                            failure.get_or_insert(RecordError::Write {
                                path: capture_dir.into(),
                                message: format!("a camera task failed: {e}"),
                            });
                        }
                    }
                }
                _ = poll.tick() => {
                    if stop.load(Ordering::Relaxed) {
                        halt.store(true, Ordering::Relaxed);
                    }
                }
            }
        }
        // Frames counted after the last task ended.
        while let Ok(Event::Frames { n, .. }) = events.try_recv() {
            progress.advance(n);
        }
        match failure {
            Some(e) => Err(e),
            None => Ok(done.into_iter().flatten().collect()),
        }
    });
    progress.finish();
    result
}
