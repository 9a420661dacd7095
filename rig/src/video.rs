//! Writing MP4 files with FFmpeg: H.264 video (libx264, yuv420p, no B-frames so that
//! pts = dts) with exact per-frame pts in units of 1/fps, and optionally AAC audio
//! (FFmpeg's native encoder, mono, fltp). The one encoder of the project: the simulator's
//! cameras and the renderer's videos both use it. The file is written under a temporary
//! sibling name ([`shared_types::atomic::temp_sibling`]: hidden, same extension) and renamed
//! by [`Mp4Writer::finish`], so a reader never sees a half-written video.

use std::path::{Path, PathBuf};

use ffmpeg::{
    ChannelLayout, Dictionary, Packet, Rational, codec, encoder, format, frame, software,
};
use ffmpeg_next as ffmpeg;
use shared_types::atomic::temp_sibling;

/// What can go wrong writing a video; every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum VideoError {
    #[error("cannot encode {path}: {what}: {source}")]
    Encode {
        path: PathBuf,
        what: String,
        source: ffmpeg::Error,
    },
    #[error(
        "FFmpeg lacks {what} needed to write {path}; install an FFmpeg build with it (Debian: libavcodec59)"
    )]
    MissingCodec { path: PathBuf, what: String },
    #[error("cannot write {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write {path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

/// Frame rate as an exact rational (integer rates, or NTSC `N·1000/1001`).
pub fn fps_rational(fps: f64) -> Rational {
    if (fps - fps.round()).abs() < 1e-9 {
        Rational::new(fps.round() as i32, 1)
    } else {
        Rational::new((fps * 1001.0).round() as i32, 1001)
    }
}

/// Initialise FFmpeg once (quiet logging).
pub fn init() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let _ = ffmpeg::init();
        ffmpeg::log::set_level(ffmpeg::log::Level::Error);
    });
}

/// How to encode.
#[derive(Clone, Debug, PartialEq)]
pub struct VideoOptions {
    /// Frames per second (integer or NTSC rates are kept exact).
    pub fps: f64,
    /// libx264 constant rate factor, 0 (lossless) ..= 51; 18 looks visually lossless.
    pub crf: u32,
    /// libx264 preset (`ultrafast` … `veryslow`).
    pub preset: String,
    /// Mono audio at this sample rate in Hz, or none.
    pub audio_rate: Option<u32>,
}

impl VideoOptions {
    /// Video only at `fps`, crf 18, preset `medium`.
    pub fn new(fps: f64) -> Self {
        Self {
            fps,
            crf: 18,
            preset: "medium".into(),
            audio_rate: None,
        }
    }
}

struct AudioOut {
    encoder: encoder::Audio,
    stream: usize,
    time_base: Rational,
    frame_size: usize,
    /// Samples sent so far (= pts of the next audio frame).
    sent: usize,
}

/// An MP4 being written.
pub struct Mp4Writer {
    path: PathBuf,
    tmp: PathBuf,
    octx: format::context::Output,
    video: encoder::Video,
    video_stream: usize,
    video_tb: Rational,
    scaler: software::scaling::Context,
    rgb: frame::Video,
    yuv: frame::Video,
    audio: Option<AudioOut>,
    /// Audio samples waiting for a whole encoder frame.
    pending: Vec<f32>,
    /// pts of the next frame given to [`Mp4Writer::push`].
    next: i64,
}

impl Mp4Writer {
    /// Open `path` for `width × height` video (both even: yuv420p) with `options`.
    pub fn create(
        path: &Path,
        width: u32,
        height: u32,
        options: &VideoOptions,
    ) -> Result<Self, VideoError> {
        init();
        let invalid = |message: String| VideoError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        if width == 0 || height == 0 || width % 2 == 1 || height % 2 == 1 {
            return Err(invalid(format!(
                "H.264 (yuv420p) needs a positive, even width and height, not {width}×{height}; choose an even size"
            )));
        }
        if !(options.fps.is_finite() && options.fps > 0.0) {
            return Err(invalid(format!(
                "frame rate {} is not positive",
                options.fps
            )));
        }
        if options.crf > 51 {
            return Err(invalid(format!("crf {} is outside 0..=51", options.crf)));
        }
        let err = |what: &str| {
            let path = path.to_path_buf();
            let what = what.to_string();
            move |source| VideoError::Encode { path, what, source }
        };
        let tmp = temp_sibling(path);
        let mut octx = format::output_as(&tmp, "mp4").map_err(err("opening the MP4 muxer"))?;
        let global = octx.format().flags().contains(format::Flags::GLOBAL_HEADER);

        let h264 = encoder::find_by_name("libx264").ok_or_else(|| VideoError::MissingCodec {
            path: path.to_path_buf(),
            what: "the libx264 encoder".into(),
        })?;
        let rate = fps_rational(options.fps);
        let video_tb = rate.invert();
        let mut enc = codec::context::Context::new_with_codec(h264)
            .encoder()
            .video()
            .map_err(err("video encoder"))?;
        enc.set_width(width);
        enc.set_height(height);
        enc.set_format(format::Pixel::YUV420P);
        enc.set_time_base(video_tb);
        enc.set_frame_rate(Some(rate));
        enc.set_max_b_frames(0);
        if global {
            enc.set_flags(codec::Flags::GLOBAL_HEADER);
        }
        let mut opts = Dictionary::new();
        opts.set("preset", &options.preset);
        opts.set("crf", &options.crf.to_string());
        // One thread per file: identical bytes on every machine (files run in parallel).
        opts.set("threads", "1");
        let video = enc.open_with(opts).map_err(err("opening libx264"))?;
        let video_stream = {
            let mut st = octx
                .add_stream(h264)
                .map_err(err("adding the video stream"))?;
            st.set_parameters(&video);
            st.set_time_base(video_tb);
            st.set_avg_frame_rate(rate);
            st.index()
        };

        let audio = match options.audio_rate {
            None => None,
            Some(sr) => {
                let aac =
                    encoder::find(codec::Id::AAC).ok_or_else(|| VideoError::MissingCodec {
                        path: path.to_path_buf(),
                        what: "an AAC encoder".into(),
                    })?;
                let mut enc = codec::context::Context::new_with_codec(aac)
                    .encoder()
                    .audio()
                    .map_err(err("audio encoder"))?;
                enc.set_rate(sr as i32);
                enc.set_channel_layout(ChannelLayout::MONO);
                enc.set_format(format::Sample::F32(format::sample::Type::Planar));
                enc.set_bit_rate(128_000);
                enc.set_time_base(Rational::new(1, sr as i32));
                if global {
                    enc.set_flags(codec::Flags::GLOBAL_HEADER);
                }
                let enc = enc.open_as(aac).map_err(err("opening the AAC encoder"))?;
                let mut st = octx
                    .add_stream(aac)
                    .map_err(err("adding the audio stream"))?;
                st.set_parameters(&enc);
                st.set_time_base(Rational::new(1, sr as i32));
                let frame_size = (enc.frame_size() as usize).max(1);
                Some(AudioOut {
                    encoder: enc,
                    stream: st.index(),
                    time_base: Rational::new(1, sr as i32),
                    frame_size,
                    sent: 0,
                })
            }
        };

        octx.write_header().map_err(err("writing the MP4 header"))?;
        let scaler = software::scaling::Context::get(
            format::Pixel::RGB24,
            width,
            height,
            format::Pixel::YUV420P,
            width,
            height,
            software::scaling::Flags::BILINEAR
                | software::scaling::Flags::ACCURATE_RND
                | software::scaling::Flags::BITEXACT,
        )
        .map_err(err("creating the RGB→YUV converter"))?;
        Ok(Mp4Writer {
            path: path.to_path_buf(),
            tmp,
            octx,
            video,
            video_stream,
            video_tb,
            scaler,
            rgb: frame::Video::new(format::Pixel::RGB24, width, height),
            yuv: frame::Video::new(format::Pixel::YUV420P, width, height),
            audio,
            pending: Vec::new(),
            next: 0,
        })
    }

    fn err(&self, what: &str) -> impl FnOnce(ffmpeg::Error) -> VideoError + use<> {
        let path = self.path.clone();
        let what = what.to_string();
        move |source| VideoError::Encode { path, what, source }
    }

    /// The final path of the file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Add the next video frame (pts = frames pushed so far); `rgb` is tightly packed
    /// 8-bit RGB of the writer's size.
    pub fn push(&mut self, rgb: &[u8]) -> Result<(), VideoError> {
        let index = self.next;
        self.push_video(index, rgb)?;
        self.next = index + 1;
        Ok(())
    }

    /// Add video frame number `index` (its pts is `index / fps`; frames may be skipped,
    /// e.g. dropped frames of a simulated camera); `rgb` is tightly packed 8-bit RGB.
    pub fn push_video(&mut self, index: i64, rgb: &[u8]) -> Result<(), VideoError> {
        let w = self.rgb.width() as usize * 3;
        let expected = w * self.rgb.height() as usize;
        if rgb.len() != expected {
            return Err(VideoError::Invalid {
                path: self.path.clone(),
                message: format!(
                    "frame {index} has {} bytes, expected {expected} ({}×{} RGB)",
                    rgb.len(),
                    self.rgb.width(),
                    self.rgb.height()
                ),
            });
        }
        let stride = self.rgb.stride(0);
        let data = self.rgb.data_mut(0);
        for (row, src) in rgb.chunks_exact(w).enumerate() {
            data[row * stride..row * stride + w].copy_from_slice(src);
        }
        self.scaler
            .run(&self.rgb, &mut self.yuv)
            .map_err(self.err("converting RGB to YUV"))?;
        self.yuv.set_pts(Some(index));
        self.video
            .send_frame(&self.yuv)
            .map_err(self.err("encoding a video frame"))?;
        self.next = index + 1;
        self.drain_video()
    }

    fn drain_video(&mut self) -> Result<(), VideoError> {
        let mut pkt = Packet::empty();
        let stream_tb = self
            .octx
            .stream(self.video_stream)
            .map(|s| s.time_base())
            .unwrap_or(self.video_tb);
        while self.video.receive_packet(&mut pkt).is_ok() {
            pkt.set_stream(self.video_stream);
            pkt.rescale_ts(self.video_tb, stream_tb);
            pkt.write_interleaved(&mut self.octx)
                .map_err(self.err("writing a video packet"))?;
        }
        Ok(())
    }

    /// Add audio samples (mono, [-1, 1]) following those already added. Only whole encoder
    /// frames are sent; the rest waits for more samples or for [`Mp4Writer::finish`].
    pub fn push_audio(&mut self, samples: &[f32]) -> Result<(), VideoError> {
        self.pending.extend_from_slice(samples);
        let Some(fs) = self.audio.as_ref().map(|a| a.frame_size) else {
            self.pending.clear();
            return Ok(());
        };
        let whole = self.pending.len() / fs * fs;
        let chunk: Vec<f32> = self.pending.drain(..whole).collect();
        for c in chunk.chunks(fs) {
            self.send_audio(c)?;
        }
        Ok(())
    }

    fn send_audio(&mut self, chunk: &[f32]) -> Result<(), VideoError> {
        let err_send = self.err("encoding audio");
        let err_write = self.err("writing an audio packet");
        let Some(a) = self.audio.as_mut() else {
            return Ok(());
        };
        let mut f = frame::Audio::new(
            format::Sample::F32(format::sample::Type::Planar),
            chunk.len(),
            ChannelLayout::MONO,
        );
        f.set_rate(a.encoder.rate());
        f.plane_mut::<f32>(0)[..chunk.len()].copy_from_slice(chunk);
        f.set_pts(Some(a.sent as i64));
        a.sent += chunk.len();
        a.encoder.send_frame(&f).map_err(err_send)?;
        drain_audio(a, &mut self.octx).map_err(err_write)
    }

    /// Flush both encoders (the last audio frame may be short), write the trailer and
    /// move the file to its final name.
    pub fn finish(mut self) -> Result<PathBuf, VideoError> {
        let pending = std::mem::take(&mut self.pending);
        if !pending.is_empty() {
            self.send_audio(&pending)?;
        }
        self.video
            .send_eof()
            .map_err(self.err("flushing the video encoder"))?;
        self.drain_video()?;
        let err_flush = self.err("flushing the audio encoder");
        let err_write = self.err("writing an audio packet");
        if let Some(a) = self.audio.as_mut() {
            a.encoder.send_eof().map_err(err_flush)?;
            drain_audio(a, &mut self.octx).map_err(err_write)?;
        }
        self.octx
            .write_trailer()
            .map_err(self.err("writing the MP4 trailer"))?;
        drop(self.octx);
        std::fs::rename(&self.tmp, &self.path).map_err(|source| VideoError::Write {
            path: self.path.clone(),
            source,
        })?;
        Ok(self.path)
    }
}

fn drain_audio(a: &mut AudioOut, octx: &mut format::context::Output) -> Result<(), ffmpeg::Error> {
    let mut pkt = Packet::empty();
    let stream_tb = octx
        .stream(a.stream)
        .map(|s| s.time_base())
        .unwrap_or(a.time_base);
    while a.encoder.receive_packet(&mut pkt).is_ok() {
        pkt.set_stream(a.stream);
        pkt.rescale_ts(a.time_base, stream_tb);
        pkt.write_interleaved(octx)?;
    }
    Ok(())
}
