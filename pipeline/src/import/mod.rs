//! `pipeline import FORMAT SRC DIR`: a capture directory made from a dataset folder laid
//! out the way another tool lays it out. Each format's reader (one module each) turns its
//! files into [`Dataset`]: calibrated cameras in the engine's convention (OpenCV axes,
//! world-to-camera, pixel centres at +0.5) and each camera's footage. This module chooses
//! the training cameras, then writes `raw/<camera>/` (links to the footage, or copies),
//! `calibration.json` (read back by `poses` like any imported calibration), `capture.toml`
//! and `import.json` (which dataset camera became which capture camera).

pub mod d3dgs;
pub mod easyvolcap;
pub mod n3v;
pub mod nerfstudio;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::DVec3;
use serde::Serialize;
use shared_types::camera::{Camera, Distortion};

/// The dataset layouts `pipeline import` reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// Neural 3D Video: `camNN.mp4` + LLFF `poses_bounds.npy`.
    N3v,
    /// nerfstudio's `transforms.json` beside its images.
    Nerfstudio,
    /// CMU Panoptic as Dynamic 3D Gaussians prepares it: `ims/<cam>/NNNNNN.jpg` +
    /// `train_meta.json` / `test_meta.json`.
    D3dgs,
    /// EasyVolcap / ZJU-style `intri.yml` + `extri.yml` beside `videos/` or `images/<cam>/`.
    Easyvolcap,
}

/// One camera's footage in the dataset.
#[derive(Clone, Debug, PartialEq)]
pub enum Footage {
    /// One video file.
    Video(PathBuf),
    /// Frames as images, in time order.
    Images(Vec<PathBuf>),
}

/// What a reader found: cameras (named as the dataset names them), their footage, and the
/// cameras the dataset's own protocol holds out.
#[derive(Clone, Debug)]
pub struct Dataset {
    pub cameras: Vec<Camera>,
    pub footage: BTreeMap<String, Footage>,
    pub heldout: Vec<String>,
    /// Frame rate of the footage, where the dataset says (images carry none; for videos it
    /// turns `--frames` into a start time).
    pub fps: Option<f64>,
}

/// Which cameras train.
#[derive(Clone, Debug, PartialEq)]
pub enum TrainChoice {
    /// Every camera the dataset's protocol does not hold out.
    Protocol,
    /// These cameras (the dataset's names); every other camera is held out.
    Named(Vec<String>),
    /// The `n` cameras farthest apart (the 4C4D paper's sparse-view protocol); every other
    /// camera is held out.
    Farthest(usize),
}

impl std::str::FromStr for TrainChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if let Some(n) = s.strip_prefix("farthest") {
            let n: usize = n.trim_start_matches(':').parse().map_err(|_| {
                format!("--train {s}: write farthest:N (N cameras farthest apart), e.g. farthest:4")
            })?;
            return Ok(Self::Farthest(n));
        }
        let names: Vec<String> = s.split(',').map(|n| n.trim().to_string()).collect();
        if names.iter().any(String::is_empty) {
            return Err(format!(
                "--train {s}: give camera names separated by commas"
            ));
        }
        Ok(Self::Named(names))
    }
}

/// What to import and how.
#[derive(Clone, Debug)]
pub struct Request {
    pub format: Format,
    pub source: PathBuf,
    pub dest: PathBuf,
    pub train: TrainChoice,
    /// Output frames `first..end` of the footage (in the dataset's frames).
    pub frames: Option<(usize, usize)>,
    /// `[frames] long_side` of the capture.
    pub long_side: Option<u32>,
    /// Copy the footage instead of linking to it.
    pub copy: bool,
}

/// Why an import failed; each names the file (and the key) to look at.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    #[error("cannot read or write {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Bad { path: PathBuf, message: String },
    #[error("{0} exists and is not empty; import into a new folder (nothing there was changed)")]
    DestNotEmpty(PathBuf),
    #[error("--train: {0}")]
    Train(String),
}

impl ImportError {
    pub fn bad(path: &Path, message: impl Into<String>) -> Self {
        Self::Bad {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }
    pub fn io(path: &Path) -> impl FnOnce(std::io::Error) -> Self + '_ {
        move |source| Self::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// What an import wrote.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    /// Capture camera name → dataset camera name, training cameras first.
    pub cameras: Vec<(String, String)>,
    pub training: usize,
    pub heldout: Vec<String>,
}

/// Read `request.source` as `request.format` and write the capture directory.
pub fn import(request: &Request) -> Result<Summary, ImportError> {
    let dest = &request.dest;
    if dest.exists()
        && std::fs::read_dir(dest)
            .map_err(ImportError::io(dest))?
            .next()
            .is_some()
    {
        return Err(ImportError::DestNotEmpty(dest.clone()));
    }
    let dataset = read(request.format, &request.source)?;
    check(&dataset, &request.source)?;
    let (train, heldout) = choose(&dataset, &request.train)?;
    write(request, &dataset, &train, &heldout)
}

/// Read a dataset folder in `format`.
pub fn read(format: Format, source: &Path) -> Result<Dataset, ImportError> {
    if !source.is_dir() {
        return Err(ImportError::bad(
            source,
            "not a folder: give the dataset's folder",
        ));
    }
    match format {
        Format::N3v => n3v::read(source),
        Format::Nerfstudio => nerfstudio::read(source),
        Format::D3dgs => d3dgs::read(source),
        Format::Easyvolcap => easyvolcap::read(source),
    }
}

/// Every camera finite, with footage; nothing held out that is not there.
fn check(dataset: &Dataset, source: &Path) -> Result<(), ImportError> {
    if dataset.cameras.is_empty() {
        return Err(ImportError::bad(source, "no cameras found"));
    }
    for c in &dataset.cameras {
        let i = &c.intrinsics;
        let w = &c.world_to_camera;
        let finite = [i.fx, i.fy, i.cx, i.cy]
            .iter()
            .chain(w.rotation.iter().flatten())
            .chain(&w.translation)
            .chain(&c.distortion.coefficients())
            .all(|v| v.is_finite());
        if !finite {
            return Err(ImportError::bad(
                source,
                format!(
                    "camera {}: its calibration holds NaN or infinite values",
                    c.name
                ),
            ));
        }
        if i.fx <= 0.0 || i.fy <= 0.0 || i.width == 0 || i.height == 0 {
            return Err(ImportError::bad(
                source,
                format!(
                    "camera {}: focal length and image size must be positive",
                    c.name
                ),
            ));
        }
        if !dataset.footage.contains_key(&c.name) {
            return Err(ImportError::bad(
                source,
                format!("camera {} is calibrated but has no video or images", c.name),
            ));
        }
    }
    Ok(())
}

/// Training and held-out cameras (dataset names), training in the dataset's order.
fn choose(
    dataset: &Dataset,
    choice: &TrainChoice,
) -> Result<(Vec<String>, Vec<String>), ImportError> {
    let names: Vec<String> = dataset.cameras.iter().map(|c| c.name.clone()).collect();
    let train: Vec<String> = match choice {
        TrainChoice::Protocol => names
            .iter()
            .filter(|n| !dataset.heldout.contains(n))
            .cloned()
            .collect(),
        TrainChoice::Named(list) => {
            if let Some(unknown) = list.iter().find(|n| !names.contains(n)) {
                return Err(ImportError::Train(format!(
                    "the dataset has no camera {unknown}; its cameras: {}",
                    names.join(", ")
                )));
            }
            names.iter().filter(|n| list.contains(n)).cloned().collect()
        }
        TrainChoice::Farthest(n) => {
            let centres: Vec<DVec3> = dataset
                .cameras
                .iter()
                .map(|c| c.world_to_camera.centre())
                .collect();
            if *n == 0 || *n > centres.len() {
                return Err(ImportError::Train(format!(
                    "farthest:{n} asks for {n} of the dataset's {} cameras",
                    centres.len()
                )));
            }
            let picked = farthest(&centres, *n);
            names
                .iter()
                .enumerate()
                .filter(|(i, _)| picked.contains(i))
                .map(|(_, n)| n.clone())
                .collect()
        }
    };
    if train.is_empty() {
        return Err(ImportError::Train("no camera left to train on".into()));
    }
    let heldout = names.into_iter().filter(|n| !train.contains(n)).collect();
    Ok((train, heldout))
}

/// Indices of `n` points spread farthest apart: the two farthest, then each time the
/// point whose nearest chosen point is farthest (ties: the lower index).
pub fn farthest(points: &[DVec3], n: usize) -> Vec<usize> {
    let mut best = (0, 0, -1.0);
    for i in 0..points.len() {
        for j in i + 1..points.len() {
            let d = points[i].distance(points[j]);
            if d > best.2 {
                best = (i, j, d);
            }
        }
    }
    let mut picked = vec![best.0];
    if n > 1 && points.len() > 1 {
        picked.push(best.1);
    }
    while picked.len() < n.min(points.len()) {
        let next = (0..points.len())
            .filter(|i| !picked.contains(i))
            .map(|i| {
                let near = picked
                    .iter()
                    .map(|&p| points[i].distance(points[p]))
                    .fold(f64::INFINITY, f64::min);
                (i, near)
            })
            .fold((usize::MAX, -1.0), |b, c| if c.1 > b.1 { c } else { b });
        picked.push(next.0);
    }
    picked.sort_unstable();
    picked
}

/// Write the capture: training cameras become `cam0..`, held-out ones follow.
fn write(
    request: &Request,
    dataset: &Dataset,
    train: &[String],
    heldout: &[String],
) -> Result<Summary, ImportError> {
    let dest = &request.dest;
    let order: Vec<&String> = train.iter().chain(heldout).collect();
    let capture_name = |i: usize| format!("cam{i}");
    let mut cameras = Vec::new();
    let mut pairs = Vec::new();
    for (i, name) in order.iter().enumerate() {
        let camera = dataset
            .cameras
            .iter()
            .find(|c| &c.name == *name)
            .expect("chosen from the dataset's cameras");
        let folder = dest.join("raw").join(capture_name(i));
        std::fs::create_dir_all(&folder).map_err(ImportError::io(&folder))?;
        match &dataset.footage[*name] {
            Footage::Video(path) => place(path, &folder, request.copy)?,
            Footage::Images(images) => {
                let (first, end) = request.frames.unwrap_or((0, images.len()));
                let chosen = images.get(first..end.min(images.len())).unwrap_or(&[]);
                if chosen.is_empty() {
                    return Err(ImportError::bad(
                        &request.source,
                        format!(
                            "--frames {first}..{end}: camera {name} has {} images",
                            images.len()
                        ),
                    ));
                }
                for image in chosen {
                    place(image, &folder, request.copy)?;
                }
            }
        }
        cameras.push(calibration_entry(camera, &capture_name(i)));
        pairs.push((capture_name(i), (*name).clone()));
    }
    let calibration = serde_json::json!({
        "units": "m",
        "pixel_centre": "half",
        "cameras": cameras,
    });
    write_file(
        &dest.join("calibration.json"),
        &serde_json::to_string_pretty(&calibration).unwrap_or_default(),
    )?;
    let heldout_names: Vec<String> = (train.len()..order.len()).map(capture_name).collect();
    write_file(
        &dest.join("capture.toml"),
        &capture_toml(request, dataset, train.len(), &heldout_names),
    )?;
    let summary = Summary {
        cameras: pairs,
        training: train.len(),
        heldout: heldout_names,
    };
    write_file(
        &dest.join("import.json"),
        &serde_json::to_string_pretty(&serde_json::json!({
            "format": format!("{:?}", request.format).to_lowercase(),
            "source": request.source,
            "cameras": summary.cameras.iter().map(|(c, d)| serde_json::json!({"camera": c, "dataset": d})).collect::<Vec<_>>(),
        }))
        .unwrap_or_default(),
    )?;
    Ok(summary)
}

/// A calibration.json entry in the engine's convention (`pixel_centre = "half"`).
fn calibration_entry(camera: &Camera, name: &str) -> serde_json::Value {
    let i = &camera.intrinsics;
    let mut entry = serde_json::json!({
        "name": name,
        "K": [[i.fx, 0.0, i.cx], [0.0, i.fy, i.cy], [0.0, 0.0, 1.0]],
        "dist": camera.distortion.coefficients(),
        "R": camera.world_to_camera.rotation,
        "t": camera.world_to_camera.translation,
        "size": [i.width, i.height],
    });
    if matches!(camera.distortion, Distortion::Fisheye { .. }) {
        entry["model"] = "fisheye".into();
    }
    if camera.distortion.is_none() {
        entry["dist"] = serde_json::json!([0.0, 0.0, 0.0, 0.0, 0.0]);
    }
    entry
}

fn capture_toml(
    request: &Request,
    dataset: &Dataset,
    training: usize,
    heldout: &[String],
) -> String {
    let quoted: Vec<String> = heldout.iter().map(|h| format!("{h:?}")).collect();
    let mut text = format!(
        "# Imported from {} ({:?}); import.json maps the cameras to the dataset's names.\n\
         [capture]\ncameras = {training}\nheldout = [{}]\n\n\
         # The dataset's cameras share a clock.\n[sync]\nmethod = \"timestamps\"\n",
        request.source.display(),
        request.format,
        quoted.join(", ")
    );
    let videos = dataset
        .footage
        .values()
        .any(|f| matches!(f, Footage::Video(_)));
    if let (Some(fps), false) = (dataset.fps, videos) {
        text += &format!("\n[ingest]\nimage_fps = {fps}\n");
    }
    let mut frames = Vec::new();
    if let Some(side) = request.long_side {
        frames.push(format!("long_side = {side}"));
    }
    if let Some((first, end)) = request.frames {
        // Videos are cut by the frames stage (images were linked from `first` on).
        frames.push(format!("max_frames = {}", end.saturating_sub(first)));
        if let (true, Some(fps)) = (videos && first > 0, dataset.fps) {
            frames.push(format!("start_s = {}", first as f64 / fps));
        }
    }
    if !frames.is_empty() {
        text += &format!("\n[frames]\n{}\n", frames.join("\n"));
    }
    text
}

/// Link (or copy) `file` into `folder` under its own name.
fn place(file: &Path, folder: &Path, copy: bool) -> Result<(), ImportError> {
    let name = file
        .file_name()
        .ok_or_else(|| ImportError::bad(file, "not a file name"))?;
    let to = folder.join(name);
    if copy {
        std::fs::copy(file, &to)
            .map(|_| ())
            .map_err(ImportError::io(&to))
    } else {
        let from = std::path::absolute(file).map_err(ImportError::io(file))?;
        std::os::unix::fs::symlink(&from, &to).map_err(ImportError::io(&to))
    }
}

fn write_file(path: &Path, text: &str) -> Result<(), ImportError> {
    shared_types::atomic::write_atomic(path, text.as_bytes()).map_err(ImportError::io(path))
}

/// Read a file as text, the error naming it.
pub(crate) fn read_text(path: &Path) -> Result<String, ImportError> {
    std::fs::read_to_string(path).map_err(ImportError::io(path))
}

/// Image files of a folder in natural name order.
pub(crate) fn images_in(folder: &Path) -> Result<Vec<PathBuf>, ImportError> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(folder)
        .map_err(ImportError::io(folder))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| rig::media::is_image(p))
        .collect();
    files.sort_by_key(|p| {
        rig::media::natural_key(&p.file_name().unwrap_or_default().to_string_lossy())
    });
    Ok(files)
}

/// The size of an image file (its header only).
pub(crate) fn image_size(path: &Path) -> Result<(u32, u32), ImportError> {
    image::image_dimensions(path)
        .map_err(|e| ImportError::bad(path, format!("cannot read its size: {e}")))
}
