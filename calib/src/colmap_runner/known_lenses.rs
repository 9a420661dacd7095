//! Video cameras with a known lens (`[poses] intrinsics`): each is extracted on its own
//! with its model and parameters (`--ImageReader.camera_params`, which COLMAP takes as a
//! trusted prior), the mapper runs as usual (it needs to refine the stills' unknown lenses,
//! and its intrinsics options apply to every camera), and the chosen model is then
//! bundle-adjusted again with the known lenses put back and every intrinsic held fixed
//! (`bundle_adjuster --BundleAdjustment.refine_* 0`): only poses and points move, so the
//! solve keeps the lenses exactly as calibrated.

use std::path::{Path, PathBuf};

use shared_types::Progress;

use super::{ColmapConfig, ColmapError, Workspace, args, io_err};
use crate::colmap::{ColmapModel, ModelFormat};

impl Workspace {
    /// One `feature_extractor` run per known lens, for the video cameras given it (log
    /// `feature_extractor_known_<first camera>`).
    pub(super) fn extract_known_lenses(
        &self,
        binary: &Path,
        threads: &str,
        config: &ColmapConfig,
        progress: &dyn Progress,
    ) -> Result<(), ColmapError> {
        let db = self.database();
        let images = self.image_dir();
        // Cameras given the very same lens (one calibration for identical cameras) share one
        // COLMAP camera: the mapper's refinement of it is then constrained by all their
        // views, not by one image each, and drifts far less from the calibration.
        let mut groups: Vec<(&crate::colmap::ColmapCamera, Vec<&str>)> = Vec::new();
        for (camera, lens) in &self.known_lenses {
            match groups
                .iter_mut()
                .find(|(l, _)| l.model == lens.model && l.params == lens.params)
            {
                Some((_, cameras)) => cameras.push(camera),
                None => groups.push((lens, vec![camera])),
            }
        }
        for (lens, cameras) in groups {
            let names: Vec<&str> = self
                .images
                .iter()
                .filter(|i| {
                    i.video_camera
                        .as_deref()
                        .is_some_and(|c| cameras.contains(&c))
                })
                .map(|i| i.colmap_name.as_str())
                .collect();
            if names.is_empty() {
                continue;
            }
            let camera = cameras[0];
            let list = self.root.join("lists").join(format!("known_{camera}.txt"));
            std::fs::write(&list, names.join("\n") + "\n").map_err(io_err(&list))?;
            let params: Vec<String> = lens.params.iter().map(|p| format!("{p:?}")).collect();
            let params = params.join(",");
            let step_args = args(&[
                ("--database_path", db.as_os_str()),
                ("--image_path", images.as_os_str()),
                ("--image_list_path", list.as_os_str()),
                ("--ImageReader.camera_model", lens.model.name().as_ref()),
                ("--ImageReader.camera_params", params.as_ref()),
                ("--ImageReader.single_camera", "1".as_ref()),
                ("--SiftExtraction.use_gpu", "0".as_ref()),
                ("--SiftExtraction.num_threads", threads.as_ref()),
                (
                    "--SiftExtraction.max_image_size",
                    config.max_image_size.to_string().as_ref(),
                ),
                (
                    "--SiftExtraction.max_num_features",
                    config.max_num_features.to_string().as_ref(),
                ),
            ]);
            self.run_step(
                binary,
                "feature_extractor",
                &format!("feature_extractor_known_{camera}"),
                step_args,
                progress,
            )?;
        }
        Ok(())
    }

    /// `model` with the known lenses put back on the video cameras (`video`: camera name,
    /// COLMAP image name), bundle-adjusted with every intrinsic fixed, into
    /// `known_lenses/adjusted/` (input in `known_lenses/input/`, log
    /// `bundle_adjuster.log`). Returns the adjusted model and its folder.
    pub fn fix_known_lenses(
        &self,
        binary: &Path,
        model: &ColmapModel,
        video: &[(&str, &str)],
        progress: &dyn Progress,
    ) -> Result<(PathBuf, ColmapModel), ColmapError> {
        let mut fixed = model.clone();
        for &(camera, colmap_name) in video {
            let (Some(lens), Some(image)) = (
                self.known_lenses.get(camera),
                model.image_by_name(colmap_name),
            ) else {
                continue;
            };
            let mut lens = lens.clone();
            lens.id = image.camera_id;
            fixed.cameras.insert(image.camera_id, lens);
        }
        let root = self.root.join("known_lenses");
        let (input, output) = (root.join("input"), root.join("adjusted"));
        for dir in [&input, &output] {
            std::fs::create_dir_all(dir).map_err(io_err(dir))?;
        }
        fixed.write(&input, ModelFormat::Binary)?;
        let step_args = args(&[
            ("--input_path", input.as_os_str()),
            ("--output_path", output.as_os_str()),
            ("--BundleAdjustment.refine_focal_length", "0".as_ref()),
            ("--BundleAdjustment.refine_principal_point", "0".as_ref()),
            ("--BundleAdjustment.refine_extra_params", "0".as_ref()),
        ]);
        self.run_step(
            binary,
            "bundle_adjuster",
            "bundle_adjuster",
            step_args,
            progress,
        )?;
        let adjusted = ColmapModel::read(&output)?;
        Ok((output, adjusted))
    }
}
