//! The tradeoff bench's plot: held-out PSNR against training time (log scale), one colour
//! per training resolution, each point labelled, the Pareto front drawn as a red line
//! through ringed points. Drawn with `plotters` into an RGB buffer and written as PNG by `image`.

use std::path::Path;
use std::sync::OnceLock;

use anyhow::{Context, bail};
use plotters::prelude::*;
use plotters::style::FontStyle;
use plotters::style::text_anchor::{HPos, Pos, VPos};

const SIZE: (u32, u32) = (1000, 640);

/// Fonts tried in order (`PIPELINE_PLOT_FONT` first): Debian's `fonts-dejavu-core`, other
/// Linux layouts, macOS and Windows.
const FONT_CANDIDATES: [&str; 5] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/System/Library/Fonts/Supplemental/Arial.ttf",
    "C:\\Windows\\Fonts\\arial.ttf",
];

/// Register a sans-serif font for plot text once per process.
fn register_font() -> anyhow::Result<()> {
    static REGISTERED: OnceLock<Result<(), String>> = OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            let env = std::env::var("PIPELINE_PLOT_FONT").ok();
            let paths = env.iter().map(String::as_str).chain(FONT_CANDIDATES);
            for path in paths {
                if let Ok(bytes) = std::fs::read(path) {
                    // plotters keeps fonts for the life of the process.
                    let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                    if plotters::style::register_font("sans-serif", FontStyle::Normal, bytes)
                        .is_ok()
                    {
                        return Ok(());
                    }
                }
            }
            Err(format!(
                "no font for the plot's text: install DejaVu (`apt-get install fonts-dejavu-core`) or set PIPELINE_PLOT_FONT to a .ttf file (tried {})",
                FONT_CANDIDATES.join(", ")
            ))
        })
        .clone()
        .map_err(anyhow::Error::msg)
}

const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(23, 190, 207),
    RGBColor(140, 86, 75),
];

/// One measured setting on the plot.
#[derive(Clone, Debug, PartialEq)]
pub struct PlotPoint {
    /// Training wall time.
    pub seconds: f64,
    /// Held-out PSNR (dB).
    pub psnr: f64,
    /// Training resolution: one colour each.
    pub resolution: f64,
    /// The text beside the point ("1000 it none").
    pub label: String,
    /// On the Pareto front: ringed and joined by the red line.
    pub on_front: bool,
}

/// Draw `points` into a PNG at `path` (written atomically).
pub fn plot(points: &[PlotPoint], path: &Path) -> anyhow::Result<()> {
    register_font()?;
    if points.is_empty() {
        bail!("no setting has a held-out PSNR to plot");
    }
    let x = |p: &PlotPoint| p.seconds.max(1e-3).log10();
    let (mut t0, mut t1, mut p0, mut p1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in points {
        (t0, t1) = (t0.min(x(p)), t1.max(x(p)));
        (p0, p1) = (p0.min(p.psnr), p1.max(p.psnr));
    }
    // x is log10(seconds) on a linear axis, so that every range gets labelled ticks.
    let x_range = (t0 - 0.15)..(t1 + 0.15);
    let y_range = (p0 - 0.6)..(p1 + 0.6);
    let mut resolutions: Vec<f64> = points.iter().map(|p| p.resolution).collect();
    resolutions.sort_by(f64::total_cmp);
    resolutions.dedup();

    let mut buffer = vec![0u8; (SIZE.0 * SIZE.1 * 3) as usize];
    {
        let draw_err = |e: &dyn std::fmt::Display| anyhow::anyhow!("drawing the plot: {e}");
        let root = BitMapBackend::with_buffer(&mut buffer, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(|e| draw_err(&e))?;
        let mut chart = ChartBuilder::on(&root)
            .caption("Held-out PSNR against training time", ("sans-serif", 26))
            .margin(20)
            .x_label_area_size(50)
            .y_label_area_size(60)
            .build_cartesian_2d(x_range.clone(), y_range.clone())
            .map_err(|e| draw_err(&e))?;
        chart
            .configure_mesh()
            .x_desc("training wall time (log scale)")
            // The time ticks are drawn below at round durations.
            .x_labels(0)
            .light_line_style(RGBColor(238, 238, 238))
            .y_desc("held-out PSNR (dB)")
            .axis_desc_style(("sans-serif", 18))
            .label_style(("sans-serif", 15))
            .draw()
            .map_err(|e| draw_err(&e))?;
        let grid = RGBColor(215, 215, 215);
        for tick in time_ticks(x_range.start, x_range.end) {
            chart
                .draw_series(LineSeries::new(
                    [(tick, y_range.start), (tick, y_range.end)],
                    grid.stroke_width(1),
                ))
                .map_err(|e| draw_err(&e))?;
            let (px, py) = chart.backend_coord(&(tick, y_range.start));
            let style = TextStyle::from(("sans-serif", 15).into_font())
                .pos(Pos::new(HPos::Center, VPos::Top));
            root.draw(&Text::new(
                tick_label(10f64.powf(tick)),
                (px, py + 8),
                style,
            ))
            .map_err(|e| draw_err(&e))?;
        }
        // The Pareto front, fastest first.
        let mut line: Vec<(f64, f64)> = points
            .iter()
            .filter(|p| p.on_front)
            .map(|p| (x(p), p.psnr))
            .collect();
        line.sort_by(|a, b| a.0.total_cmp(&b.0));
        chart
            .draw_series(LineSeries::new(line.clone(), RED.stroke_width(2)))
            .map_err(|e| draw_err(&e))?
            .label("Pareto front")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED.stroke_width(2)));
        chart
            .draw_series(
                line.iter()
                    .map(|&(t, p)| Circle::new((t, p), 10, RED.stroke_width(2))),
            )
            .map_err(|e| draw_err(&e))?;
        for (k, &res) in resolutions.iter().enumerate() {
            let colour = PALETTE[k % PALETTE.len()];
            let series: Vec<(f64, f64, String)> = points
                .iter()
                .filter(|p| p.resolution == res)
                .map(|p| (x(p), p.psnr, p.label.clone()))
                .collect();
            chart
                .draw_series(
                    series
                        .iter()
                        .map(|(t, p, _)| Circle::new((*t, *p), 6, colour.filled())),
                )
                .map_err(|e| draw_err(&e))?
                .label(format!("resolution {res}"))
                .legend(move |(x, y)| Circle::new((x + 10, y), 6, colour.filled()));
            chart
                .draw_series(series.iter().map(|(t, p, text)| {
                    EmptyElement::at((*t, *p))
                        + Text::new(text.clone(), (10, -18), ("sans-serif", 14).into_font())
                }))
                .map_err(|e| draw_err(&e))?;
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 15))
            .draw()
            .map_err(|e| draw_err(&e))?;
        root.present().map_err(|e| draw_err(&e))?;
    }
    let image = image::RgbImage::from_raw(SIZE.0, SIZE.1, buffer)
        .context("the plot buffer has the wrong size")?;
    let mut png = Vec::new();
    image
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .context("encoding the plot as PNG")?;
    shared_types::atomic::write_atomic(path, &png)?;
    Ok(())
}

/// Tick positions (log10 seconds) at round durations inside `[lo, hi]` (log10 seconds),
/// at most 9.
fn time_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let mut seconds: Vec<f64> = (-3..=6)
        .flat_map(|k| [1.0, 1.5, 2.0, 3.0, 5.0, 7.0].map(|m| m * 10f64.powi(k)))
        .filter(|s| *s < 60.0)
        .chain([1.0, 1.5, 2.0, 3.0, 5.0, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0].map(|m| m * 60.0))
        .chain([1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 24.0, 48.0].map(|h| h * 3600.0))
        .filter(|s| (lo..=hi).contains(&s.log10()))
        .collect();
    seconds.sort_by(f64::total_cmp);
    let step = seconds.len().div_ceil(9).max(1);
    seconds.into_iter().step_by(step).map(f64::log10).collect()
}

/// "0.15 s", "2 s", "45 s", "5 min", "1 h 30 min".
fn tick_label(seconds: f64) -> String {
    let round = |v: f64, d: usize| {
        format!("{v:.d$}")
            .trim_end_matches('0')
            .trim_end_matches('.')
            .to_string()
    };
    if seconds < 1.0 {
        format!("{} s", round(seconds, 2))
    } else if seconds < 60.0 {
        format!("{} s", round(seconds, 1))
    } else if seconds < 3600.0 {
        format!("{} min", round(seconds / 60.0, 1))
    } else {
        let (h, m) = (
            (seconds / 3600.0) as u64,
            ((seconds % 3600.0) / 60.0).round() as u64,
        );
        if m == 0 {
            format!("{h} h")
        } else {
            format!("{h} h {m} min")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_durations_inside_the_range() {
        let ticks: Vec<String> = time_ticks(60f64.log10(), 3000f64.log10())
            .into_iter()
            .map(|t| tick_label(10f64.powf(t)))
            .collect();
        assert!(ticks.len() >= 4 && ticks.len() <= 9, "{ticks:?}");
        assert_eq!(ticks[0], "1 min");
        assert!(ticks.contains(&"30 min".to_string()), "{ticks:?}");
        let narrow = time_ticks(0.2f64.log10(), 0.6f64.log10());
        assert!(narrow.len() >= 2, "{narrow:?}");
        assert_eq!(tick_label(0.15), "0.15 s");
        assert_eq!(tick_label(5400.0), "1 h 30 min");
    }
}
