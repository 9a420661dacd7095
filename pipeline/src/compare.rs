//! The `pipeline metrics A B` command: PSNR, SSIM, DSSIM₁, DSSIM₂ and LPIPS between two
//! images, or between the same-named images of two folders (named alike without their
//! extension, so `0001.png` pairs with `0001.jpg`) — for comparing renders with another
//! tool's. The numbers are the eval stage's (`splat4d::metrics`, the same LPIPS network).
//! Images are read with `image` (PNG, JPEG), converted to RGB in `[0, 1]`; an alpha
//! channel is dropped. Pairs are measured a batch at a time, in parallel.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use shared_types::Progress;
use splat4d::metrics::lpips::{ImagePair, Lpips, LpipsError};
use splat4d::metrics::{ImageMetrics, MetricsError, image_metrics};

/// Why two images or folders cannot be compared.
#[derive(Debug, thiserror::Error)]
pub enum CompareError {
    #[error("{path} does not exist; give two images, or two folders of same-named images")]
    Missing { path: PathBuf },
    #[error(
        "{folder} is a folder but {file} is a file; give two images, or two folders of same-named images"
    )]
    FolderAndFile { folder: PathBuf, file: PathBuf },
    #[error("cannot list {path}: {source}")]
    ListFolder {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path} holds no images (.png, .jpg, .jpeg); give a folder of images")]
    NoImages { path: PathBuf },
    #[error(
        "{folder} has several images named {stem} ({names}); images are paired by name without extension, so keep one"
    )]
    SameStem {
        folder: PathBuf,
        stem: String,
        names: String,
    },
    #[error(
        "{a} and {b} have no image names in common (images are paired by file name without extension; {a} has e.g. {examples_a}, {b} has e.g. {examples_b}); rename one side's images to match the other's"
    )]
    NoCommonNames {
        a: PathBuf,
        b: PathBuf,
        examples_a: String,
        examples_b: String,
    },
    #[error("cannot read image {path}: {source}; give a PNG or JPEG image")]
    ReadImage {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error(
        "{a} is {width_a}×{height_a} but {b} is {width_b}×{height_b}; the metrics compare images of one size: resize one to the other's (e.g. `ffmpeg -i {b} -vf scale={width_a}:{height_a} resized.png`)"
    )]
    SizeMismatch {
        a: PathBuf,
        b: PathBuf,
        width_a: u32,
        height_a: u32,
        width_b: u32,
        height_b: u32,
    },
    #[error("cannot compare {a} with {b}: {source}")]
    Metrics {
        a: PathBuf,
        b: PathBuf,
        source: MetricsError,
    },
    #[error("LPIPS of {a} against {b}: {source}")]
    Lpips {
        a: PathBuf,
        b: PathBuf,
        source: LpipsError,
    },
}

/// The metrics of one pair of images.
#[derive(Clone, Debug, PartialEq)]
pub struct PairMetrics {
    /// The image's name: the file name of the first image.
    pub name: String,
    pub a: PathBuf,
    pub b: PathBuf,
    pub width: u32,
    pub height: u32,
    pub metrics: ImageMetrics,
    /// `None` when LPIPS was not computed (no network).
    pub lpips: Option<f64>,
}

/// Every pair measured, and the names only one folder has (left out).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Comparison {
    pub pairs: Vec<PairMetrics>,
    pub only_in_a: Vec<String>,
    pub only_in_b: Vec<String>,
}

/// Means over the pairs (`None` for none). PSNR is the mean of the per-pair PSNRs, as in
/// eval (`+∞` when a pair is pixel-identical).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MeanMetrics {
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    pub dssim1: Option<f64>,
    pub dssim2: Option<f64>,
    pub lpips: Option<f64>,
}

impl Comparison {
    /// Means of every metric over the pairs.
    pub fn mean(&self) -> MeanMetrics {
        let mean = |f: &dyn Fn(&PairMetrics) -> Option<f64>| {
            let values: Vec<f64> = self.pairs.iter().filter_map(f).collect();
            (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
        };
        MeanMetrics {
            psnr: mean(&|p| Some(p.metrics.psnr)),
            ssim: mean(&|p| Some(p.metrics.ssim)),
            dssim1: mean(&|p| Some(p.metrics.dssim1)),
            dssim2: mean(&|p| Some(p.metrics.dssim2)),
            lpips: mean(&|p| p.lpips),
        }
    }
}

/// One pair to measure, before reading.
#[derive(Clone, Debug)]
struct Job {
    name: String,
    a: PathBuf,
    b: PathBuf,
}

/// Measure `a` against `b`: two image files, or two folders (every image name they share).
/// LPIPS is computed when `lpips` is given. Pairs are read and measured in batches of a
/// few per core, so a large folder never sits in memory at once.
pub fn compare(
    a: &Path,
    b: &Path,
    lpips: Option<&Lpips>,
    progress: &dyn Progress,
) -> Result<Comparison, CompareError> {
    for path in [a, b] {
        if !path.exists() {
            return Err(CompareError::Missing {
                path: path.to_path_buf(),
            });
        }
    }
    let mut comparison = Comparison::default();
    let jobs = match (a.is_dir(), b.is_dir()) {
        (false, false) => vec![Job {
            name: file_name(a),
            a: a.to_path_buf(),
            b: b.to_path_buf(),
        }],
        (true, true) => {
            let (in_a, in_b) = (images_by_stem(a)?, images_by_stem(b)?);
            comparison.only_in_a = only_in(&in_a, &in_b);
            comparison.only_in_b = only_in(&in_b, &in_a);
            let jobs: Vec<Job> = in_a
                .iter()
                .filter_map(|(stem, name_a)| {
                    in_b.get(stem).map(|name_b| Job {
                        name: name_a.clone(),
                        a: a.join(name_a),
                        b: b.join(name_b),
                    })
                })
                .collect();
            if jobs.is_empty() {
                let examples = |m: &BTreeMap<String, String>| {
                    m.values().take(3).cloned().collect::<Vec<_>>().join(", ")
                };
                return Err(CompareError::NoCommonNames {
                    a: a.to_path_buf(),
                    b: b.to_path_buf(),
                    examples_a: examples(&in_a),
                    examples_b: examples(&in_b),
                });
            }
            jobs
        }
        (true, false) => {
            return Err(CompareError::FolderAndFile {
                folder: a.to_path_buf(),
                file: b.to_path_buf(),
            });
        }
        (false, true) => {
            return Err(CompareError::FolderAndFile {
                folder: b.to_path_buf(),
                file: a.to_path_buf(),
            });
        }
    };
    progress.start(jobs.len() as u64, "images");
    let batch = 2 * rayon::current_num_threads().max(1);
    for chunk in jobs.chunks(batch) {
        comparison.pairs.extend(measure_batch(chunk, lpips)?);
        progress.advance(chunk.len() as u64);
    }
    progress.finish();
    Ok(comparison)
}

/// Read and measure a batch of pairs in parallel.
fn measure_batch(jobs: &[Job], lpips: Option<&Lpips>) -> Result<Vec<PairMetrics>, CompareError> {
    type Loaded = (Vec<f32>, Vec<f32>, u32, u32);
    let loaded: Vec<Loaded> = jobs
        .par_iter()
        .map(|job| {
            let ((a, wa, ha), (b, wb, hb)) = (read_rgb(&job.a)?, read_rgb(&job.b)?);
            if (wa, ha) != (wb, hb) {
                return Err(CompareError::SizeMismatch {
                    a: job.a.clone(),
                    b: job.b.clone(),
                    width_a: wa,
                    height_a: ha,
                    width_b: wb,
                    height_b: hb,
                });
            }
            Ok((a, b, wa, ha))
        })
        .collect::<Result<_, _>>()?;
    let metrics: Vec<ImageMetrics> = jobs
        .par_iter()
        .zip(&loaded)
        .map(|(job, (a, b, w, h))| {
            image_metrics(a, b, *w as usize, *h as usize).map_err(|source| CompareError::Metrics {
                a: job.a.clone(),
                b: job.b.clone(),
                source,
            })
        })
        .collect::<Result<_, _>>()?;
    let lpips_values: Vec<Option<f64>> = match lpips {
        Some(net) => {
            let pairs: Vec<ImagePair> = loaded
                .iter()
                .map(|(a, b, w, h)| ImagePair {
                    a,
                    b,
                    width: *w as usize,
                    height: *h as usize,
                })
                .collect();
            net.distances(&pairs)
                .into_iter()
                .zip(jobs)
                .map(|(d, job)| {
                    d.map(Some).map_err(|source| CompareError::Lpips {
                        a: job.a.clone(),
                        b: job.b.clone(),
                        source,
                    })
                })
                .collect::<Result<_, _>>()?
        }
        None => vec![None; jobs.len()],
    };
    Ok(jobs
        .iter()
        .zip(loaded)
        .zip(metrics.into_iter().zip(lpips_values))
        .map(
            |((job, (_, _, width, height)), (metrics, lpips))| PairMetrics {
                name: job.name.clone(),
                a: job.a.clone(),
                b: job.b.clone(),
                width,
                height,
                metrics,
                lpips,
            },
        )
        .collect())
}

/// An image as interleaved RGB in `[0, 1]`, with its width and height.
fn read_rgb(path: &Path) -> Result<(Vec<f32>, u32, u32), CompareError> {
    let img = image::open(path).map_err(|source| CompareError::ReadImage {
        path: path.to_path_buf(),
        source,
    })?;
    let (w, h) = (img.width(), img.height());
    let rgb = match img {
        image::DynamicImage::ImageRgb8(_)
        | image::DynamicImage::ImageRgba8(_)
        | image::DynamicImage::ImageLuma8(_)
        | image::DynamicImage::ImageLumaA8(_) => img
            .to_rgb8()
            .into_raw()
            .into_iter()
            .map(|v| v as f32 / 255.0)
            .collect(),
        _ => img.to_rgb32f().into_raw(),
    };
    Ok((rgb, w, h))
}

fn file_name(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| path.display().to_string())
}

/// A folder's images by file stem → file name; two images with one stem are an error.
fn images_by_stem(dir: &Path) -> Result<BTreeMap<String, String>, CompareError> {
    let list_err = |source| CompareError::ListFolder {
        path: dir.to_path_buf(),
        source,
    };
    let mut by_stem: BTreeMap<String, String> = BTreeMap::new();
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(list_err)?
        .map(|e| e.map(|e| e.path()))
        .collect::<Result<_, _>>()
        .map_err(list_err)?;
    entries.sort();
    for path in entries {
        let is_image = path.is_file() && rig::media::is_photo(&path);
        let Some(stem) = path.file_stem().map(|s| s.to_string_lossy().into_owned()) else {
            continue;
        };
        if !is_image {
            continue;
        }
        let name = file_name(&path);
        if let Some(other) = by_stem.get(&stem) {
            return Err(CompareError::SameStem {
                folder: dir.to_path_buf(),
                stem,
                names: format!("{other}, {name}"),
            });
        }
        by_stem.insert(stem, name);
    }
    if by_stem.is_empty() {
        return Err(CompareError::NoImages {
            path: dir.to_path_buf(),
        });
    }
    Ok(by_stem)
}

/// File names of `this` whose stem `other` lacks.
fn only_in(this: &BTreeMap<String, String>, other: &BTreeMap<String, String>) -> Vec<String> {
    this.iter()
        .filter(|(stem, _)| !other.contains_key(*stem))
        .map(|(_, name)| name.clone())
        .collect()
}

/// The comparison as a text table: one row per pair, then the means when there are
/// several. `lpips_computed` false: the LPIPS column says `skipped`.
pub fn format_table(comparison: &Comparison, lpips_computed: bool) -> String {
    use std::fmt::Write as _;
    let num = |v: Option<f64>, digits: usize| match v {
        Some(v) if v.is_infinite() => "inf".to_string(),
        Some(v) => format!("{v:.digits$}"),
        None => "–".to_string(),
    };
    let lp = |v: Option<f64>| {
        if lpips_computed {
            num(v, 4)
        } else {
            "skipped".into()
        }
    };
    let mean_label = format!("mean of {}", comparison.pairs.len());
    let width = comparison
        .pairs
        .iter()
        .map(|p| p.name.chars().count())
        .chain([mean_label.chars().count()])
        .max()
        .unwrap_or(0);
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{:<width$}  {:>11}  {:>8}  {:>6}  {:>6}  {:>6}  {:>7}",
        "image", "size", "PSNR dB", "SSIM", "DSSIM1", "DSSIM2", "LPIPS"
    );
    for p in &comparison.pairs {
        let m = &p.metrics;
        let _ = writeln!(
            s,
            "{:<width$}  {:>11}  {:>8}  {:>6.4}  {:>6.4}  {:>6.4}  {:>7}",
            p.name,
            format!("{}×{}", p.width, p.height),
            num(Some(m.psnr), 2),
            m.ssim,
            m.dssim1,
            m.dssim2,
            lp(p.lpips)
        );
    }
    if comparison.pairs.len() > 1 {
        let mean = comparison.mean();
        let _ = writeln!(
            s,
            "{:<width$}  {:>11}  {:>8}  {:>6}  {:>6}  {:>6}  {:>7}",
            mean_label,
            "",
            num(mean.psnr, 2),
            num(mean.ssim, 4),
            num(mean.dssim1, 4),
            num(mean.dssim2, 4),
            lp(mean.lpips)
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_png(path: &Path, w: u32, h: u32, seed: u32) {
        let img = image::RgbImage::from_fn(w, h, |x, y| {
            let v = ((x * 31 + y * 17 + seed * 101) % 256) as u8;
            image::Rgb([v, v.wrapping_add(40), v.wrapping_mul(3)])
        });
        img.save(path).unwrap();
    }

    #[test]
    fn folders_pair_images_by_name_without_extension() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a"), dir.path().join("b"));
        std::fs::create_dir_all(&a).unwrap();
        std::fs::create_dir_all(&b).unwrap();
        write_png(&a.join("0001.png"), 40, 32, 1);
        write_png(&a.join("0002.png"), 40, 32, 2);
        write_png(&a.join("extra.png"), 40, 32, 3);
        std::fs::write(a.join("notes.txt"), "not an image").unwrap();
        write_png(&b.join("0001.png"), 40, 32, 1);
        write_png(&b.join("0002.PNG"), 40, 32, 5);
        write_png(&b.join("other.png"), 40, 32, 3);
        let c = compare(&a, &b, None, &shared_types::NoProgress).unwrap();
        let names: Vec<&str> = c.pairs.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(names, ["0001.png", "0002.png"]);
        assert_eq!(c.only_in_a, ["extra.png"]);
        assert_eq!(c.only_in_b, ["other.png"]);
        assert!(c.pairs[0].metrics.psnr.is_infinite());
        assert_eq!(c.pairs[0].metrics.dssim1, 0.0);
        assert!(c.pairs[1].metrics.psnr.is_finite());
        assert!(c.pairs.iter().all(|p| p.lpips.is_none()));
        let table = format_table(&c, false);
        assert!(table.contains("mean of 2"), "{table}");
        assert!(table.contains("skipped"), "{table}");
        assert!(table.contains("inf"), "{table}");

        // Same stem twice in one folder: ambiguous.
        write_png(&b.join("0001.jpg"), 40, 32, 1);
        let e = compare(&a, &b, None, &shared_types::NoProgress).unwrap_err();
        assert!(
            matches!(&e, CompareError::SameStem { stem, .. } if stem == "0001"),
            "{e}"
        );
    }

    #[test]
    fn mistakes_are_errors_naming_the_path_and_the_fix() {
        let dir = tempfile::tempdir().unwrap();
        let p = |n: &str| dir.path().join(n);
        write_png(&p("a.png"), 40, 32, 1);
        write_png(&p("small.png"), 20, 32, 1);
        let none = &shared_types::NoProgress;
        let e = compare(&p("a.png"), &p("absent.png"), None, none).unwrap_err();
        assert!(matches!(&e, CompareError::Missing { path } if path == &p("absent.png")));
        let e = compare(&p("a.png"), &p("small.png"), None, none).unwrap_err();
        let text = e.to_string();
        assert!(
            text.contains("40×32") && text.contains("20×32") && text.contains("scale=40:32"),
            "{text}"
        );
        std::fs::write(p("fake.png"), "not a png").unwrap();
        let e = compare(&p("a.png"), &p("fake.png"), None, none).unwrap_err();
        assert!(matches!(&e, CompareError::ReadImage { path, .. } if path == &p("fake.png")));

        std::fs::create_dir_all(p("x")).unwrap();
        std::fs::create_dir_all(p("y")).unwrap();
        std::fs::create_dir_all(p("empty")).unwrap();
        write_png(&p("x/frame_1.png"), 40, 32, 1);
        write_png(&p("y/000001.png"), 40, 32, 1);
        let e = compare(&p("x"), &p("y"), None, none).unwrap_err();
        let text = e.to_string();
        assert!(
            matches!(e, CompareError::NoCommonNames { .. })
                && text.contains("frame_1.png")
                && text.contains("000001.png"),
            "{text}"
        );
        let e = compare(&p("x"), &p("a.png"), None, none).unwrap_err();
        assert!(matches!(e, CompareError::FolderAndFile { .. }), "{e}");
        let e = compare(&p("x"), &p("empty"), None, none).unwrap_err();
        assert!(matches!(&e, CompareError::NoImages { path } if path == &p("empty")));
    }
}
