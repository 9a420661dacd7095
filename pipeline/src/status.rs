//! The `pipeline status` table.

use crate::report::format_duration;
use crate::runner::{StageStatus, State};

fn state_word(state: State) -> &'static str {
    match state {
        State::Done => "done",
        State::Stale => "stale",
        State::Missing => "missing",
        State::Failed => "failed",
        State::Running => "running",
        State::Queued => "queued",
        State::Cancelled => "cancelled",
    }
}

/// Render rows as an aligned text table: stage, state, when, how long, details.
pub fn format_table(rows: &[StageStatus]) -> String {
    let header = ["STAGE", "STATE", "WHEN", "TOOK", "DETAILS"];
    let cells: Vec<[String; 5]> = rows
        .iter()
        .map(|r| {
            [
                r.stage.clone(),
                state_word(r.state).to_string(),
                r.when
                    .map(|t| {
                        t.with_timezone(&chrono::Local)
                            .format("%Y-%m-%d %H:%M:%S")
                            .to_string()
                    })
                    .unwrap_or_else(|| "-".into()),
                r.duration_s
                    .map(format_duration)
                    .unwrap_or_else(|| "-".into()),
                if r.details.is_empty() {
                    String::new()
                } else {
                    r.details.join("; ")
                },
            ]
        })
        .collect();
    let mut widths = header.map(|h| h.chars().count());
    for row in &cells {
        for (w, cell) in widths.iter_mut().zip(row.iter()) {
            *w = (*w).max(cell.chars().count());
        }
    }
    let mut out = String::new();
    let mut push_row = |row: [&str; 5]| {
        let mut line = String::new();
        for (i, cell) in row.iter().enumerate() {
            if i == 4 {
                line.push_str(cell);
            } else {
                line.push_str(&format!("{cell:<width$}  ", width = widths[i]));
            }
        }
        out.push_str(line.trim_end());
        out.push('\n');
    };
    push_row(header);
    for row in &cells {
        push_row([&row[0], &row[1], &row[2], &row[3], &row[4]]);
    }
    out
}
