//! Camera sources: anything that yields timestamped video frames one after another.
//!
//! [`CameraSource`] is the one interface the recorder and the frame extractor consume.
//! [`FileSource`] decodes a camera's video files (chapters joined in order) with FFmpeg;
//! the V4L2 recorder and the simulator's cameras implement the same trait. This module
//! decodes; it does not decide which files belong to a camera (that is `ingest`).

use std::path::{Path, PathBuf};

use crate::rotation::Rotation;
use ffmpeg::format::Pixel;
use ffmpeg::media::Type;
use ffmpeg::software::scaling;
use ffmpeg_next as ffmpeg;

/// Errors from opening or decoding a camera source.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// FFmpeg could not open or decode a file.
    #[error(
        "cannot decode {path}: {source}. Check that the file plays in a video player (ffprobe {path})"
    )]
    Decode {
        /// The file.
        path: PathBuf,
        /// FFmpeg's error.
        source: ffmpeg::Error,
    },
    /// The file has no stream of the required kind.
    #[error("{path} has no {kind} stream; every camera needs a video file{hint}")]
    NoStream {
        /// The file.
        path: PathBuf,
        /// "video" or "audio".
        kind: &'static str,
        /// Extra advice.
        hint: &'static str,
    },
    /// A live device failed.
    #[error("camera device {device}: {message}")]
    Device {
        /// The device path.
        device: String,
        /// What went wrong and what to do.
        message: String,
    },
}

/// Pixel layout of the frames a source delivers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelLayout {
    /// 8-bit RGB, 3 bytes per pixel, rows packed.
    Rgb8,
    /// 8-bit luma, 1 byte per pixel, rows packed.
    Gray8,
}

impl PixelLayout {
    /// Bytes per pixel.
    pub fn channels(self) -> usize {
        match self {
            PixelLayout::Rgb8 => 3,
            PixelLayout::Gray8 => 1,
        }
    }
}

/// One decoded frame.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Index of the frame in the camera's stream (0-based, presentation order).
    pub index: usize,
    /// Presentation time in seconds on the camera's own clock (see `docs/capture.md`).
    pub timestamp: f64,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Pixel layout of `data`.
    pub layout: PixelLayout,
    /// Packed pixels, `width × height × layout.channels()` bytes.
    pub data: Vec<u8>,
}

/// Something that yields a camera's frames in order: video files, a V4L2 device, a
/// simulated camera.
pub trait CameraSource: Send {
    /// The camera's name (`cam0`, …).
    fn name(&self) -> &str;
    /// Size of the frames this source delivers.
    fn frame_size(&self) -> (u32, u32);
    /// Nominal frame rate (frames per second), if known.
    fn nominal_fps(&self) -> Option<f64>;
    /// The next frame, or `None` at the end of the stream.
    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError>;
}

/// Initialises FFmpeg once and silences its logging below errors.
pub(crate) fn init_ffmpeg() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let _ = ffmpeg::init();
        ffmpeg::util::log::set_level(ffmpeg::util::log::Level::Error);
    });
}

pub(crate) fn decode_err(path: &Path) -> impl FnOnce(ffmpeg::Error) -> SourceError + '_ {
    move |source| SourceError::Decode {
        path: path.to_path_buf(),
        source,
    }
}

/// A scaler owned by one source.
struct Scaler(scaling::Context);

// SAFETY: a swscale context has no thread affinity; it is owned by exactly one
// `FileSource` and only used through `&mut`, so moving it to another thread is sound.
unsafe impl Send for Scaler {}

/// One open chapter: demuxer, decoder and scaler.
struct OpenChapter {
    path: PathBuf,
    input: ffmpeg::format::context::Input,
    stream_index: usize,
    time_base: f64,
    decoder: ffmpeg::decoder::Video,
    scaler: Option<Scaler>,
    /// How the player turns this file's frames; they are delivered turned.
    rotation: Rotation,
    eof_sent: bool,
    offset: f64,
}

/// Decodes a camera's video files (chapters) in order, converted and resized.
pub struct FileSource {
    name: String,
    chapters: Vec<(PathBuf, f64)>,
    next_chapter: usize,
    current: Option<OpenChapter>,
    out_size: Option<(u32, u32)>,
    layout: PixelLayout,
    size: (u32, u32),
    fps: Option<f64>,
    index: usize,
    pending: std::collections::VecDeque<Frame>,
}

impl FileSource {
    /// Opens `chapters` (path, time offset in seconds added to that file's timestamps).
    /// Frames come out as `layout`, resized to `out_size` (or the native size when `None`).
    pub fn open(
        name: &str,
        chapters: &[(PathBuf, f64)],
        layout: PixelLayout,
        out_size: Option<(u32, u32)>,
    ) -> Result<Self, SourceError> {
        init_ffmpeg();
        let mut source = FileSource {
            name: name.to_string(),
            chapters: chapters.to_vec(),
            next_chapter: 0,
            current: None,
            out_size,
            layout,
            size: (0, 0),
            fps: None,
            index: 0,
            pending: Default::default(),
        };
        source.open_next()?;
        if let Some(c) = &source.current {
            let native = c
                .rotation
                .turn_size((c.decoder.width(), c.decoder.height()));
            source.size = out_size.unwrap_or(native);
        }
        Ok(source)
    }

    fn open_next(&mut self) -> Result<bool, SourceError> {
        self.current = None;
        let Some((path, offset)) = self.chapters.get(self.next_chapter).cloned() else {
            return Ok(false);
        };
        self.next_chapter += 1;
        let input = ffmpeg::format::input(&path).map_err(decode_err(&path))?;
        let stream = input
            .streams()
            .best(Type::Video)
            .ok_or_else(|| SourceError::NoStream {
                path: path.clone(),
                kind: "video",
                hint: "",
            })?;
        let stream_index = stream.index();
        let time_base = f64::from(stream.time_base());
        let rate = stream.avg_frame_rate();
        if rate.numerator() > 0 && rate.denominator() > 0 {
            self.fps = Some(f64::from(rate));
        }
        let mut ctx = ffmpeg::codec::context::Context::from_parameters(stream.parameters())
            .map_err(decode_err(&path))?;
        // Frame threads on every core (FFmpeg's default is one thread).
        ctx.set_threading(ffmpeg::codec::threading::Config {
            kind: ffmpeg::codec::threading::Type::Frame,
            count: 0,
            ..Default::default()
        });
        let decoder = ctx.decoder().video().map_err(decode_err(&path))?;
        let rotation = Rotation::of_stream(&stream);
        self.current = Some(OpenChapter {
            path,
            input,
            stream_index,
            time_base,
            decoder,
            scaler: None,
            rotation,
            eof_sent: false,
            offset,
        });
        Ok(true)
    }

    fn convert(&mut self, decoded: &ffmpeg::frame::Video) -> Result<(), SourceError> {
        let (layout, out_size) = (self.layout, self.out_size);
        let Some(ch) = self.current.as_mut() else {
            return Ok(());
        };
        // Scaled to the requested (displayed) size as stored, then turned as displayed.
        let stored = (decoded.width(), decoded.height());
        let (w, h) = out_size.unwrap_or(ch.rotation.turn_size(stored));
        let (sw, sh) = ch.rotation.turn_size((w, h));
        let pixel = match layout {
            PixelLayout::Rgb8 => Pixel::RGB24,
            PixelLayout::Gray8 => Pixel::GRAY8,
        };
        let needs_new = match &ch.scaler {
            Some(Scaler(s)) => {
                s.input().width != decoded.width()
                    || s.input().height != decoded.height()
                    || s.input().format != decoded.format()
            }
            None => true,
        };
        if needs_new {
            ch.scaler = Some(Scaler(
                scaling::Context::get(
                    decoded.format(),
                    decoded.width(),
                    decoded.height(),
                    pixel,
                    sw,
                    sh,
                    scaling::Flags::AREA,
                )
                .map_err(decode_err(&ch.path))?,
            ));
        }
        let mut out = ffmpeg::frame::Video::empty();
        if let Some(Scaler(scaler)) = ch.scaler.as_mut() {
            scaler
                .run(decoded, &mut out)
                .map_err(decode_err(&ch.path))?;
        }
        let row = sw as usize * layout.channels();
        let stride = out.stride(0);
        let plane = out.data(0);
        let mut data = Vec::with_capacity(row * sh as usize);
        for y in 0..sh as usize {
            data.extend_from_slice(&plane[y * stride..y * stride + row]);
        }
        if ch.rotation != Rotation::None {
            data = ch.rotation.apply(&data, (sw, sh), layout.channels());
        }
        let pts = decoded.timestamp().or(decoded.pts()).unwrap_or(0);
        let timestamp = ch.offset + pts as f64 * ch.time_base;
        self.pending.push_back(Frame {
            index: self.index,
            timestamp,
            width: w,
            height: h,
            layout,
            data,
        });
        self.index += 1;
        self.size = (w, h);
        Ok(())
    }

    fn receive_all(&mut self) -> Result<bool, SourceError> {
        let mut got = false;
        loop {
            let mut decoded = ffmpeg::frame::Video::empty();
            let Some(ch) = self.current.as_mut() else {
                return Ok(got);
            };
            if ch.decoder.receive_frame(&mut decoded).is_err() {
                return Ok(got);
            }
            self.convert(&decoded)?;
            got = true;
        }
    }
}

impl CameraSource for FileSource {
    fn name(&self) -> &str {
        &self.name
    }

    fn frame_size(&self) -> (u32, u32) {
        self.size
    }

    fn nominal_fps(&self) -> Option<f64> {
        self.fps
    }

    fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
        loop {
            if let Some(f) = self.pending.pop_front() {
                return Ok(Some(f));
            }
            let Some(ch) = self.current.as_mut() else {
                return Ok(None);
            };
            if ch.eof_sent {
                self.receive_all()?;
                if self.pending.is_empty() && !self.open_next()? {
                    return Ok(None);
                }
                continue;
            }
            let mut packet = ffmpeg::Packet::empty();
            match packet.read(&mut ch.input) {
                Ok(()) => {
                    if packet.stream() == ch.stream_index {
                        // A corrupt packet is skipped: the frame counts as dropped.
                        if ch.decoder.send_packet(&packet).is_ok() {
                            self.receive_all()?;
                        }
                    }
                }
                Err(ffmpeg::Error::Eof) => {
                    let _ = ch.decoder.send_eof();
                    ch.eof_sent = true;
                }
                Err(ffmpeg::Error::Other { errno }) if errno == ffmpeg::util::error::EAGAIN => {}
                Err(e) => {
                    return Err(SourceError::Decode {
                        path: ch.path.clone(),
                        source: e,
                    });
                }
            }
        }
    }
}
