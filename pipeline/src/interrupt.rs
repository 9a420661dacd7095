//! Ctrl-C (SIGINT, and SIGTERM and SIGHUP alike: what Slurm sends a job it cancels,
//! requeues or ends at its time limit) during `pipeline run` and `pipeline demo`. A stage
//! that can stop cleanly (the
//! train stage) marks the time it runs with [`Graceful`] and polls [`stop_requested`]:
//! the first Ctrl-C then asks it to stop after its current iteration (it writes a
//! checkpoint and the next run resumes from it). At any other time, or on a second
//! Ctrl-C, the process exits at once; the runner notices the interrupted stage on its
//! next start. This module only holds the two flags; it never touches a capture.

use std::sync::atomic::{AtomicBool, Ordering};

/// Set by the Ctrl-C handler (or [`request_stop`]) while a stage that can stop cleanly runs.
static STOP: AtomicBool = AtomicBool::new(false);
/// Whether a stage that can stop cleanly is running now.
static GRACEFUL: AtomicBool = AtomicBool::new(false);

/// What the Ctrl-C handler of `pipeline run` does: during a [`Graceful`] section, ask the
/// stage to stop at the end of its iteration; at any other time, or on a second Ctrl-C,
/// exit at once.
pub fn on_interrupt() {
    if GRACEFUL.load(Ordering::SeqCst) && !STOP.swap(true, Ordering::SeqCst) {
        eprintln!(
            "\nstopping after this iteration (a checkpoint is written); press Ctrl-C again to quit now"
        );
        return;
    }
    std::process::exit(130);
}

/// Ask the running (or the next) training to stop cleanly after its current iteration,
/// as a first Ctrl-C does.
pub fn request_stop() {
    STOP.store(true, Ordering::SeqCst);
}

/// Whether a clean stop was asked for.
pub fn stop_requested() -> bool {
    STOP.load(Ordering::SeqCst)
}

/// Marks a clean-stop section for [`on_interrupt`]; clears the request when dropped.
pub struct Graceful;

impl Graceful {
    pub fn enter() -> Self {
        GRACEFUL.store(true, Ordering::SeqCst);
        Graceful
    }
}

impl Drop for Graceful {
    fn drop(&mut self) {
        GRACEFUL.store(false, Ordering::SeqCst);
        STOP.store(false, Ordering::SeqCst);
    }
}
