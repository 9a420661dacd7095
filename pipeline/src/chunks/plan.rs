//! Which aligned frames each chunk trains on, and which part of the clip it owns.

use std::ops::Range;

use rig::frames::FramesIndex;
use serde::{Deserialize, Serialize};

use super::ChunkSettings;

/// One chunk of the clip.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Chunk {
    pub index: usize,
    /// The aligned frames (positions in `frames.json`) this chunk owns.
    pub core: Range<usize>,
    /// The aligned frames it trains on: its core and the overlap on both sides.
    pub window: Range<usize>,
    /// The model times it owns, `[from, until)`: from midway between its first frame and
    /// the one before, to midway between its last frame and the one after (`None`: no
    /// bound, for the first chunk's start and the last one's end). The merged model keeps
    /// this chunk's moving Gaussians whose time centre lies here.
    pub from: Option<f64>,
    pub until: Option<f64>,
}

impl Chunk {
    /// Whether model time `t` is this chunk's.
    pub fn owns_time(&self, t: f64) -> bool {
        self.from.is_none_or(|from| t >= from) && self.until.is_none_or(|until| t < until)
    }

    /// Folder of the chunk's training under `work/train/`.
    pub fn dir_name(&self) -> String {
        format!("chunks/{:03}", self.index)
    }
}

/// The chunks of a clip, in time order; one chunk when the clip is not cut.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChunkPlan {
    pub chunks: Vec<Chunk>,
}

impl ChunkPlan {
    /// The plan of a clip whose aligned frames are at model times `times` (ascending),
    /// filmed at `fps`.
    pub fn new(times: &[f64], fps: f64, settings: &ChunkSettings) -> Self {
        let frames = times.len();
        let per_chunk = settings.seconds * fps;
        let count = if per_chunk > 0.0 && frames > 0 {
            ((frames as f64 / per_chunk).round() as usize).clamp(1, frames)
        } else {
            1
        };
        let overlap = (settings.overlap_seconds * fps).round() as usize;
        let bound = |k: usize| k * frames / count;
        let midway = |f: usize| 0.5 * (times[f - 1] + times[f]);
        let chunks = (0..count)
            .map(|k| {
                let core = bound(k)..bound(k + 1);
                let window = core.start.saturating_sub(overlap)..(core.end + overlap).min(frames);
                let from = (k > 0).then(|| midway(core.start));
                let until = (k + 1 < count).then(|| midway(core.end));
                Chunk {
                    index: k,
                    core,
                    window,
                    from,
                    until,
                }
            })
            .collect();
        Self { chunks }
    }

    /// The plan of the frames stage's clip.
    pub fn of_index(index: &FramesIndex, settings: &ChunkSettings) -> Self {
        let mapping = crate::engine_inputs::time_mapping(index);
        let times: Vec<f64> = index
            .frames
            .iter()
            .map(|f| mapping.model_time(f.time_s))
            .collect();
        Self::new(&times, index.fps, settings)
    }

    /// The plan of the clip under `work/` (its `frames/frames.json`), when the frames
    /// stage has run.
    pub fn read(work: &std::path::Path, settings: &ChunkSettings) -> Option<Self> {
        let index = FramesIndex::read_json(&work.join("frames").join("frames.json")).ok()?;
        Some(Self::of_index(&index, settings))
    }

    /// Aligned frames of the clip.
    pub fn frames(&self) -> usize {
        self.chunks.last().map_or(0, |c| c.core.end)
    }

    /// Frames of the largest window: what one chunk holds in memory.
    pub fn largest_window(&self) -> usize {
        self.chunks
            .iter()
            .map(|c| c.window.len())
            .max()
            .unwrap_or(0)
    }

    /// Whether the clip is cut into more than one chunk.
    pub fn is_chunked(&self) -> bool {
        self.chunks.len() > 1
    }

    /// The aligned frames of the init's moments. One chunk: `spread(frames, per_chunk)`
    /// over the clip (offsets into it, its ends included). Several: each chunk's core cut
    /// into `per_chunk` equal parts, a moment at each part's middle, so that the moments are
    /// evenly spaced over the whole clip and no two chunks' moments sit side by side at a
    /// boundary (the ends of neighbouring cores are adjacent frames).
    pub fn moments(
        &self,
        per_chunk: usize,
        spread: impl Fn(usize, usize) -> Vec<usize>,
    ) -> Vec<usize> {
        if let [only] = self.chunks.as_slice() {
            let start = only.core.start;
            return spread(only.core.len(), per_chunk)
                .into_iter()
                .map(|i| start + i)
                .collect();
        }
        self.chunks
            .iter()
            .flat_map(|c| {
                let (start, len) = (c.core.start, c.core.len());
                let count = per_chunk.min(len);
                (0..count).map(move |k| start + (2 * k + 1) * len / (2 * count))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn times(frames: usize, fps: f64) -> Vec<f64> {
        (0..frames).map(|f| f as f64 / fps).collect()
    }

    fn settings(seconds: f64, overlap_seconds: f64) -> ChunkSettings {
        ChunkSettings {
            seconds,
            overlap_seconds,
            ..ChunkSettings::default()
        }
    }

    #[test]
    fn a_minute_at_30_fps_is_twelve_chunks_of_five_seconds_with_overlaps() {
        let plan = ChunkPlan::new(&times(1800, 30.0), 30.0, &settings(5.0, 0.5));
        assert_eq!(plan.chunks.len(), 12);
        assert!(plan.is_chunked());
        assert_eq!(plan.chunks[0].core, 0..150);
        assert_eq!(plan.chunks[0].window, 0..165);
        assert_eq!(plan.chunks[1].core, 150..300);
        assert_eq!(plan.chunks[1].window, 135..315);
        assert_eq!(plan.chunks[11].window, 1635..1800);
        // The cores tile the clip; the owned times tile the line.
        for pair in plan.chunks.windows(2) {
            assert_eq!(pair[0].core.end, pair[1].core.start);
            assert_eq!(pair[0].until, pair[1].from);
        }
        assert_eq!(plan.chunks[0].from, None);
        assert_eq!(plan.chunks[11].until, None);
        // Frame 149 (t = 4.967) is chunk 0's, frame 150 (t = 5.0) chunk 1's.
        let boundary = plan.chunks[0].until.unwrap();
        assert!((boundary - 149.5 / 30.0).abs() < 1e-12, "{boundary}");
        assert!(plan.chunks[0].owns_time(149.0 / 30.0));
        assert!(plan.chunks[1].owns_time(150.0 / 30.0));
        assert_eq!(plan.chunks[3].dir_name(), "chunks/003");
    }

    #[test]
    fn short_clips_and_zero_seconds_stay_one_model() {
        for (frames, s) in [(72, 5.0), (75, 5.0), (220, 5.0), (1800, 0.0), (1, 1.0)] {
            let plan = ChunkPlan::new(&times(frames, 30.0), 30.0, &settings(s, 0.5));
            assert_eq!(plan.chunks.len(), 1, "{frames} frames, {s} s");
            assert_eq!(plan.chunks[0].core, 0..frames);
            assert_eq!(plan.chunks[0].window, 0..frames);
            assert!(plan.chunks[0].owns_time(1e9) && plan.chunks[0].owns_time(-1e9));
        }
        // 7.5 s at 5 s per chunk: two chunks of 3.75 s; uneven frame counts still tile.
        let plan = ChunkPlan::new(&times(225, 30.0), 30.0, &settings(5.0, 0.0));
        assert_eq!(plan.chunks.len(), 2);
        assert_eq!(plan.chunks[0].core, 0..112);
        assert_eq!(plan.chunks[1].core, 112..225);
        assert_eq!(plan.chunks[1].window, 112..225);
        // No more chunks than frames.
        let plan = ChunkPlan::new(&times(3, 30.0), 30.0, &settings(0.01, 0.0));
        assert_eq!(plan.chunks.len(), 3);
        assert!(
            ChunkPlan::new(&[], 30.0, &settings(5.0, 0.5)).chunks[0]
                .core
                .is_empty()
        );
    }

    #[test]
    fn moments_are_evenly_spaced_over_the_chunks_and_the_clip_ends_without_chunks() {
        let spread = |frames: usize, count: usize| -> Vec<usize> {
            (0..count).map(|k| k * (frames - 1) / (count - 1)).collect()
        };
        // Two chunks of 30 frames: parts of 10 frames, a moment in each part's middle,
        // 10 frames apart across the boundary too.
        let plan = ChunkPlan::new(&times(60, 30.0), 30.0, &settings(1.0, 0.2));
        assert_eq!(plan.moments(3, spread), [5, 15, 25, 35, 45, 55]);
        // More moments than a chunk has frames: one per frame.
        let plan = ChunkPlan::new(&times(4, 30.0), 30.0, &settings(1.0 / 15.0, 0.0));
        assert_eq!(plan.chunks.len(), 2);
        assert_eq!(plan.moments(6, spread), [0, 1, 2, 3]);
        // One model: the spread over the whole clip, its ends included.
        let plan = ChunkPlan::new(&times(60, 30.0), 30.0, &settings(0.0, 0.2));
        assert_eq!(plan.moments(3, spread), [0, 29, 59]);
    }
}
