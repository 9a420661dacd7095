//! The `export` stage: the trained model as per-timestep 3DGS PLY frames, the native 4D
//! PLY, a `.splatv` and the browser viewer (`splat4d::export`, docs/export.md), listed
//! in `export.json` (paths relative to `work/export/`).

use anyhow::Context;
use calib::poses::PosesFile;
use rig::frames::FramesIndex;
use shared_types::CameraSet;
use shared_types::atomic::write_json;
use splat4d::export::ExportOptions;

use crate::engine_inputs::{load_trained_model, pinhole_cameras};
use crate::stage_context::StageContext;

/// `[export]` settings: the exporter's own (time steps, which files, viewer options).
pub type ExportSettings = ExportOptions;

/// The `export` stage; `trained` is what the model was trained on (the viewer draws its
/// background or learned backdrop behind the splats).
pub fn run(
    ctx: &StageContext,
    options: &ExportSettings,
    trained: &crate::engine_inputs::TrainRecord,
) -> anyhow::Result<()> {
    let model = load_trained_model(&ctx.capture.work_dir())?;
    let options = &ExportOptions {
        background: trained.background,
        backdrop: trained.load_backdrop(&ctx.capture.work_dir())?,
        ..options.clone()
    };
    let cameras_file = ctx.stage_dir("poses").join("cameras.json");
    let poses = PosesFile::read(&cameras_file)?;
    let index = FramesIndex::read_json(&ctx.stage_dir("frames").join("frames.json"))?;
    // The cameras the engine renders with (undistorted, at the frames' size): the viewer
    // opens at the first and shows exactly what the render and eval stages draw there.
    let cameras = CameraSet::new(
        pinhole_cameras(&index, &poses.set, &cameras_file)?
            .into_iter()
            .map(|(camera, _)| camera)
            .collect(),
    );
    write_transforms(ctx, &index, &poses.set, &cameras_file)?;
    let times = options.times(&model, index.frames.len());
    let report = splat4d::export::export_all(
        &model,
        &cameras,
        &times,
        &ctx.out_dir,
        options,
        ctx.progress,
    )?;
    tracing::info!(
        "exported {} time steps of {} Gaussians in {:.1} s{}",
        report.frames.len(),
        report.gaussians,
        report.seconds,
        match &report.viewer_index {
            Some(_) => format!(
                "; `pipeline view {}` shows it in a browser",
                ctx.capture.root.display()
            ),
            None => String::new(),
        }
    );
    write_json(
        &ctx.output("export.json"),
        &report.relative_to(&ctx.out_dir),
    )
    .context("cannot write export.json")?;
    Ok(())
}

/// `transforms.json`: the capture's cameras (at the frames' size, with their lenses) and
/// every frame in `work/frames/`, as nerfstudio and tools that read its format open them.
fn write_transforms(
    ctx: &StageContext,
    index: &FramesIndex,
    set: &CameraSet,
    cameras_file: &std::path::Path,
) -> anyhow::Result<()> {
    let cameras = index
        .cameras
        .iter()
        .map(|c| {
            let camera = set
                .get(&c.name)
                .with_context(|| format!("{} has no camera {}", cameras_file.display(), c.name))?;
            Ok(shared_types::camera::Camera {
                intrinsics: camera.intrinsics.scaled_to(c.width, c.height),
                ..camera.clone()
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    match crate::import::nerfstudio::transforms(&cameras, index, "../frames") {
        Ok(value) => {
            write_json(&ctx.output(TRANSFORMS_FILE), &value).context("cannot write transforms.json")
        }
        Err(why) => {
            tracing::warn!("no transforms.json: {why}");
            Ok(())
        }
    }
}

/// The cameras and frames for nerfstudio, in `work/export/`.
pub const TRANSFORMS_FILE: &str = "transforms.json";
