//! How every stage reports to the user, so all stages look alike: one line per stage
//! event and an indicatif progress bar for long work (human mode), nothing but errors
//! (`--quiet`), or one JSON object per line on stdout (`--json`).

use std::io::Write;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};
use serde::Serialize;

/// How output is shown.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputMode {
    Human,
    Quiet,
    Json,
}

/// Something that happened during a run.
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Event<'a> {
    StageStarted {
        stage: &'a str,
        reasons: &'a [String],
    },
    StageSkipped {
        stage: &'a str,
        reason: &'a str,
    },
    StageFinished {
        stage: &'a str,
        duration_s: f64,
        outputs: usize,
    },
    StageFailed {
        stage: &'a str,
        error: &'a str,
    },
    StageNotImplemented {
        stage: &'a str,
    },
    StageBlocked {
        stage: &'a str,
        upstream: &'a str,
    },
    Progress {
        stage: &'a str,
        done: u64,
        total: u64,
        unit: &'a str,
        message: &'a str,
    },
    Message {
        stage: &'a str,
        message: &'a str,
    },
}

/// Prints events and makes progress bars.
pub struct Reporter {
    mode: OutputMode,
    multi: MultiProgress,
}

impl Reporter {
    pub fn new(mode: OutputMode) -> Self {
        let multi = MultiProgress::new();
        if mode != OutputMode::Human {
            multi.set_draw_target(ProgressDrawTarget::hidden());
        }
        Self { mode, multi }
    }

    pub fn mode(&self) -> OutputMode {
        self.mode
    }

    /// The bars' container, so log output can be printed without tearing them.
    pub fn multi(&self) -> &MultiProgress {
        &self.multi
    }

    /// Print a line for a human (stderr), above any progress bars.
    pub fn say(&self, line: &str) {
        if self.mode == OutputMode::Human {
            self.multi.suspend(|| eprintln!("{line}"));
        }
    }

    /// Print a JSON object on its own line (JSON mode only).
    pub fn json(&self, value: &impl Serialize) {
        if self.mode == OutputMode::Json
            && let Ok(text) = serde_json::to_string(value)
        {
            let mut out = std::io::stdout().lock();
            let _ = writeln!(out, "{text}");
            let _ = out.flush();
        }
    }

    pub fn event(&self, event: &Event) {
        match self.mode {
            OutputMode::Json => self.json(event),
            OutputMode::Quiet => {
                if let Event::StageFailed { stage, error } = event {
                    eprintln!("✗ {stage} failed: {error}");
                }
            }
            OutputMode::Human => self.say(&human_line(event)),
        }
    }

    /// A progress sink for one stage.
    pub fn progress(&self, stage: &str) -> StageProgress<'_> {
        let bar = (self.mode == OutputMode::Human).then(|| {
            let bar = self.multi.add(ProgressBar::new_spinner());
            bar.set_prefix(stage.to_string());
            bar.enable_steady_tick(Duration::from_millis(200));
            bar
        });
        StageProgress {
            reporter: self,
            stage: stage.to_string(),
            bar,
            done: AtomicU64::new(0),
            total: AtomicU64::new(0),
            unit: Mutex::new(String::new()),
            message: Mutex::new(String::new()),
            last_json: Mutex::new(None),
        }
    }
}

/// Reasons shown on a console line: the first [`SHOWN_REASONS`], then how many more (a
/// folder of inputs replaced at once gives one reason per file; `--json` has them all).
fn reasons_text(reasons: &[String]) -> String {
    let mut text = reasons
        .iter()
        .take(SHOWN_REASONS)
        .cloned()
        .collect::<Vec<_>>()
        .join("; ");
    if reasons.len() > SHOWN_REASONS {
        text += &format!("; and {} more", reasons.len() - SHOWN_REASONS);
    }
    text
}

/// Reasons a console line names before counting the rest.
const SHOWN_REASONS: usize = 4;

fn human_line(event: &Event) -> String {
    match event {
        Event::StageStarted { stage, reasons } => {
            let why = if reasons.is_empty() {
                String::new()
            } else {
                format!(" ({})", reasons_text(reasons))
            };
            format!("▶ {stage}: running{why}")
        }
        Event::StageSkipped { stage, reason } => format!("· {stage}: {reason}, skipped"),
        Event::StageFinished {
            stage,
            duration_s,
            outputs,
        } => {
            format!(
                "✓ {stage}: done in {} ({outputs} output files)",
                format_duration(*duration_s)
            )
        }
        Event::StageFailed { stage, error } => format!("✗ {stage}: FAILED: {error}"),
        Event::StageNotImplemented { stage } => {
            format!("… {stage}: not implemented yet in this version of pipeline")
        }
        Event::StageBlocked { stage, upstream } => {
            format!("… {stage}: not run (needs `{upstream}`, which did not run)")
        }
        Event::Progress {
            stage,
            done,
            total,
            unit,
            message,
        } => format!("  {stage}: {done}/{total} {unit} {message}"),
        Event::Message { stage, message } => format!("  {stage}: {message}"),
    }
}

/// `1.2 s`, `3 min 05 s`, `2 h 03 min`.
pub fn format_duration(seconds: f64) -> String {
    if seconds < 60.0 {
        format!("{seconds:.1} s")
    } else if seconds < 3600.0 {
        format!(
            "{} min {:02} s",
            (seconds / 60.0) as u64,
            (seconds % 60.0) as u64
        )
    } else {
        format!(
            "{} h {:02} min",
            (seconds / 3600.0) as u64,
            ((seconds % 3600.0) / 60.0) as u64
        )
    }
}

/// Progress of one stage: a bar (human), throttled JSON events (`--json`), or nothing.
pub struct StageProgress<'a> {
    reporter: &'a Reporter,
    stage: String,
    bar: Option<ProgressBar>,
    done: AtomicU64,
    total: AtomicU64,
    unit: Mutex<String>,
    message: Mutex<String>,
    last_json: Mutex<Option<Instant>>,
}

impl StageProgress<'_> {
    fn emit_json(&self, force: bool) {
        if self.reporter.mode != OutputMode::Json {
            return;
        }
        let Ok(mut last) = self.last_json.lock() else {
            return;
        };
        if !force && last.is_some_and(|t| t.elapsed() < Duration::from_millis(500)) {
            return;
        }
        *last = Some(Instant::now());
        let unit = self.unit.lock().map(|u| u.clone()).unwrap_or_default();
        let message = self.message.lock().map(|m| m.clone()).unwrap_or_default();
        self.reporter.event(&Event::Progress {
            stage: &self.stage,
            done: self.done.load(Ordering::Relaxed),
            total: self.total.load(Ordering::Relaxed),
            unit: &unit,
            message: &message,
        });
    }
}

impl shared_types::Progress for StageProgress<'_> {
    fn start(&self, total: u64, unit: &str) {
        self.total.store(total, Ordering::Relaxed);
        self.done.store(0, Ordering::Relaxed);
        if let Ok(mut u) = self.unit.lock() {
            *u = unit.to_string();
        }
        if let Some(bar) = &self.bar {
            bar.set_length(total);
            bar.set_position(0);
            bar.reset_eta();
            let template = format!(
                "{{prefix:>8}} [{{bar:30.cyan/blue}}] {{pos}}/{{len}} {unit} ({{per_sec}}, ETA {{eta}}) {{msg}}"
            );
            if let Ok(style) = ProgressStyle::with_template(&template) {
                bar.set_style(style.progress_chars("=> "));
            }
        }
        self.emit_json(true);
    }

    fn advance(&self, n: u64) {
        self.done.fetch_add(n, Ordering::Relaxed);
        if let Some(bar) = &self.bar {
            bar.inc(n);
        }
        self.emit_json(false);
    }

    fn message(&self, msg: &str) {
        if let Some(bar) = &self.bar {
            bar.set_message(msg.to_string());
        }
        if let Ok(mut m) = self.message.lock() {
            *m = msg.to_string();
        }
    }

    fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
        if self.total.load(Ordering::Relaxed) > 0 {
            self.emit_json(true);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_long_list_of_reasons_is_cut_to_a_count() {
        let reasons: Vec<String> = (0..7)
            .map(|i| format!("input masks/{i}.png removed"))
            .collect();
        let line = human_line(&Event::StageStarted {
            stage: "eval",
            reasons: &reasons,
        });
        assert_eq!(
            line,
            "▶ eval: running (input masks/0.png removed; input masks/1.png removed; input masks/2.png removed; input masks/3.png removed; and 3 more)"
        );
        assert_eq!(reasons_text(&reasons[..4]), reasons[..4].join("; "));
    }
}
