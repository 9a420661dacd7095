//! How library code reports progress on long work without knowing who displays it.
//! The `pipeline` binary implements [`Progress`] with progress bars or JSON events;
//! tests and scripts use [`NoProgress`].

/// A sink for progress of one long task (a stage, a training run, a render).
pub trait Progress: Send + Sync {
    /// Total amount of work, in units of `unit` (frames, iterations, …).
    fn start(&self, total: u64, unit: &str);
    /// `n` more units done.
    fn advance(&self, n: u64);
    /// A short status message (loss, PSNR, …) shown beside the bar.
    fn message(&self, msg: &str);
    /// The task is complete.
    fn finish(&self);
}

/// Discards all progress.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoProgress;

impl Progress for NoProgress {
    fn start(&self, _total: u64, _unit: &str) {}
    fn advance(&self, _n: u64) {}
    fn message(&self, _msg: &str) {}
    fn finish(&self) {}
}
