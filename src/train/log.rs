//! `log.csv`: one row per iteration. On resume the rows after the checkpoint are dropped,
//! so the file reads as one uninterrupted run.

use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::Path;

pub const HEADER: &str = "iteration,loss,l1,ssim,psnr,gaussians,elapsed_s";

/// One log row.
#[derive(Clone, Copy, Debug)]
pub struct LogRow {
    pub iteration: u64,
    pub loss: f64,
    pub l1: f64,
    pub ssim: f64,
    pub psnr: f64,
    pub gaussians: usize,
    pub elapsed_s: f64,
}

/// An open log file.
pub struct TrainLog {
    out: BufWriter<File>,
}

impl TrainLog {
    /// Start a new log (truncating), or reopen one keeping rows with iteration ≤ `keep_until`.
    pub fn open(path: &Path, keep_until: Option<u64>) -> std::io::Result<Self> {
        let mut kept = String::new();
        if let Some(limit) = keep_until
            && let Ok(text) = std::fs::read_to_string(path)
        {
            for line in text.lines().skip(1) {
                let it = line.split(',').next().and_then(|s| s.parse::<u64>().ok());
                if it.is_some_and(|it| it <= limit) {
                    kept.push_str(line);
                    kept.push('\n');
                }
            }
        }
        crate::atomic::write_atomic(path, format!("{HEADER}\n{kept}").as_bytes())?;
        let out = BufWriter::new(OpenOptions::new().append(true).open(path)?);
        Ok(Self { out })
    }

    pub fn write(&mut self, r: &LogRow) -> std::io::Result<()> {
        writeln!(
            self.out,
            "{},{:.6},{:.6},{:.6},{:.3},{},{:.3}",
            r.iteration, r.loss, r.l1, r.ssim, r.psnr, r.gaussians, r.elapsed_s
        )
    }

    pub fn flush(&mut self) -> std::io::Result<()> {
        self.out.flush()
    }
}
