//! What the training benches (`pipeline bench ablation`, `pipeline bench tradeoff`) train
//! and measure: a capture brought up to its `init` stage (a simulated scene is simulated
//! first, with its true video cameras as the calibration, so pose errors do not blur the
//! comparison), its training dataset, initial points and held-out views.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use calib::poses::PosesFile;
use rig::frames::FramesIndex;
use splat4d::eval::EvalView;
use splat4d::train::Dataset;
use splat4d::train::PointCloud;

use crate::config::CaptureConfig;
use crate::layout::Capture;
use crate::report::Reporter;
use crate::runner::Selection;
use crate::{open_capture, simulate, stages};

/// A capture ready to train and measure.
pub struct BenchInputs {
    pub capture: Capture,
    pub config: CaptureConfig,
    pub dataset: Dataset,
    pub points: PointCloud,
    pub heldout: Vec<EvalView>,
    /// The LPIPS network: `[eval] lpips` when the capture sets one, else the installed
    /// LPIPS-alex weights; `None` when there are none.
    pub lpips: Option<splat4d::metrics::lpips::Lpips>,
    /// `work/bench/` of the capture: where the benches write.
    pub bench_dir: PathBuf,
}

impl BenchInputs {
    /// The start of a bench table's header: the source and its training and held-out views.
    pub fn describe(&self, source: &BenchSource) -> String {
        let first = &self.dataset.views[0].image;
        format!(
            "{}, {} training views of {}×{}, {} held-out views",
            source.describe(),
            self.dataset.views.len(),
            first.width,
            first.height,
            self.heldout.len()
        )
    }
}

/// Where a bench's inputs come from.
#[derive(Clone, Debug)]
pub enum BenchSource {
    /// A scene file, simulated into the capture directory (reused when it exists).
    Scene {
        scene: PathBuf,
        capture_dir: PathBuf,
    },
    /// An existing capture directory (simulated or real) with held-out cameras.
    Capture(PathBuf),
    /// An existing capture directory used as its stages left it, up to `init`, without
    /// bringing them up to date: a capture prepared elsewhere, whose trimmed copy (no COLMAP
    /// workspace, no point maps) the engine-only build on a GPU node cannot rerun.
    Prepared(PathBuf),
}

impl BenchSource {
    /// `SOURCE [CAPTURE_DIR]` of the command line: a `.toml` scene needs a capture
    /// directory to simulate into; a capture directory needs none.
    pub fn from_args(source: &Path, capture_dir: Option<&Path>) -> anyhow::Result<Self> {
        if source.is_dir() {
            if let Some(extra) = capture_dir {
                bail!(
                    "{} is a capture directory, so the bench writes into it; remove the second path {}",
                    source.display(),
                    extra.display()
                );
            }
            return Ok(Self::Capture(source.to_path_buf()));
        }
        if !source.is_file() {
            bail!(
                "{} is neither a scene file nor a capture directory",
                source.display()
            );
        }
        match capture_dir {
            Some(dir) => Ok(Self::Scene {
                scene: source.to_path_buf(),
                capture_dir: dir.to_path_buf(),
            }),
            None => bail!(
                "{} is a scene file: give a capture directory to simulate it into, e.g. `{} /tmp/bench`",
                source.display(),
                source.display()
            ),
        }
    }

    /// This capture directory used as prepared ([`Self::Prepared`]); a scene file stays
    /// one (it is simulated and prepared here).
    pub fn as_prepared(self) -> Self {
        match self {
            Self::Capture(dir) => Self::Prepared(dir),
            other => other,
        }
    }

    /// The capture directory the bench works in.
    pub fn capture_dir(&self) -> &Path {
        match self {
            Self::Scene { capture_dir, .. } => capture_dir,
            Self::Capture(dir) | Self::Prepared(dir) => dir,
        }
    }

    /// A short name for table headers.
    pub fn describe(&self) -> String {
        match self {
            Self::Scene { scene, .. } => format!("scene {}", scene.display()),
            Self::Capture(dir) => format!("capture {}", dir.display()),
            Self::Prepared(dir) => format!("capture {} (as prepared)", dir.display()),
        }
    }
}

/// Simulate (for a scene), run the stages up to `init` (not for [`BenchSource::Prepared`]),
/// and load what training needs.
pub fn prepare(source: &BenchSource, reporter: &Reporter) -> anyhow::Result<BenchInputs> {
    let capture_dir = source.capture_dir();
    if let BenchSource::Scene { scene, .. } = source
        && !capture_dir.join("raw").exists()
    {
        let parsed = rig::sim::Scene::from_file(scene)?;
        simulate::simulate_into(&parsed, capture_dir, reporter)?;
        simulate::write_truth_calibration(capture_dir)?;
    }
    let (capture, config) = open_capture(capture_dir)?;
    let work = capture.work_dir();
    if let BenchSource::Prepared(_) = source {
        if !work.join("init/stage.json").is_file() {
            bail!(
                "{} has not been prepared up to `init`; run `pipeline run {} --to init` first, or leave out --as-prepared",
                capture_dir.display(),
                capture_dir.display()
            );
        }
    } else {
        let summary = stages::pipeline().run(
            &capture,
            &config,
            &Selection {
                to: Some("init".into()),
                ..Default::default()
            },
            reporter,
        )?;
        if let Some((stage, error)) = summary.failed {
            bail!("the {stage} stage failed: {error}");
        }
    }
    let cameras_file = work.join("poses/cameras.json");
    let progress = reporter.progress("load");
    let mut dataset =
        crate::engine_inputs::load_dataset(&work.join("frames"), &cameras_file, &progress)?;
    let points_file = work.join("init/points.ply");
    let points = shared_types::points::read_points_ply(&points_file)
        .with_context(|| format!("cannot read the initial points {}", points_file.display()))?;
    // As the train stage does: every setting trains on the cameras' matched exposure.
    if config.train.match_exposure {
        stages::train::match_exposure(&mut dataset, &points, &progress);
    }
    shared_types::Progress::finish(&progress);
    let index = FramesIndex::read_json(&work.join("frames/frames.json"))?;
    let poses = PosesFile::read(&cameras_file)?;
    let bench_dir = work.join("bench");
    let masks = stages::eval::moving_masks(
        &capture,
        &config.eval,
        &config.capture.heldout,
        config.plate_masks(),
        &bench_dir.join("plate_masks"),
    )?;
    let heldout = stages::eval::any_heldout_views(
        &capture,
        &config.eval,
        &config.capture.heldout,
        &poses.set,
        &crate::engine_inputs::time_mapping(&index),
        &bench_dir.join("heldout-groundtruth"),
        masks.as_ref(),
    )?;
    if heldout.is_empty() {
        bail!(
            "{} has no held-out cameras: add `[capture] heldout` cameras (real captures) or `[[cameras.heldout]]` to the scene (simulated ones); a bench measures novel views",
            capture_dir.display()
        );
    }
    let lpips = stages::eval::load_lpips(&capture, &config.eval)?;
    Ok(BenchInputs {
        lpips,
        capture,
        config,
        dataset,
        points,
        heldout,
        bench_dir,
    })
}

/// The sentence a bench table's header says about LPIPS: which network measured it, or
/// that it was skipped and how to get the weights.
pub fn lpips_note(lpips: Option<&splat4d::metrics::lpips::Lpips>) -> String {
    match lpips {
        Some(net) => format!("LPIPS: {} ({}).", net.kind(), net.path().display()),
        None => "LPIPS skipped: no weights installed (run scripts/setup.sh, or set LPIPS_WEIGHTS)."
            .into(),
    }
}
