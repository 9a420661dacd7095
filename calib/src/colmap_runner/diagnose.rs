//! Explaining a COLMAP result the way a user can act on it: per image, how many features
//! and verified matches it has, with which images, whether and in which model it
//! registered; and what to try next.

use std::fmt;
use std::path::PathBuf;

use super::{MatchGraph, Workspace};
use crate::colmap::ColmapModel;

/// Fewer SIFT features than this: the image is blank, dark, blurred or textureless.
pub const FEW_FEATURES: u32 = 200;
/// Fewer verified matches than this with its best partner: the image barely overlaps.
pub const WEAK_MATCHES: u32 = 30;

/// What COLMAP made of one image.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageReport {
    pub colmap_name: String,
    /// The video camera this frame comes from, `None` for a still.
    pub video_camera: Option<String>,
    pub keypoints: u32,
    /// Verified (two-view geometry) matches summed over all partners.
    pub verified_matches: u32,
    /// Up to three best partners: (name, verified matches).
    pub best_partners: Vec<(String, u32)>,
    /// Index into the models (largest first) where this image registered.
    pub model: Option<usize>,
}

/// Per-image facts of a COLMAP run, plus the number of models.
#[derive(Clone, Debug, PartialEq)]
pub struct Diagnosis {
    pub images: Vec<ImageReport>,
    pub num_models: usize,
}

impl Diagnosis {
    pub fn new(ws: &Workspace, graph: &MatchGraph, models: &[(PathBuf, ColmapModel)]) -> Self {
        let images = ws
            .images
            .iter()
            .map(|img| {
                let id = graph.id_of(&img.colmap_name);
                let partners = id.map(|id| graph.partners(id)).unwrap_or_default();
                ImageReport {
                    colmap_name: img.colmap_name.clone(),
                    video_camera: img.video_camera.clone(),
                    keypoints: id
                        .and_then(|id| graph.keypoints.get(&id).copied())
                        .unwrap_or(0),
                    verified_matches: partners.iter().map(|p| p.1).sum(),
                    best_partners: partners
                        .iter()
                        .take(3)
                        .map(|&(pid, n)| {
                            (
                                graph
                                    .names
                                    .get(&pid)
                                    .cloned()
                                    .unwrap_or_else(|| format!("#{pid}")),
                                n,
                            )
                        })
                        .collect(),
                    model: models
                        .iter()
                        .position(|(_, m)| m.image_by_name(&img.colmap_name).is_some()),
                }
            })
            .collect();
        Self {
            images,
            num_models: models.len(),
        }
    }

    /// Images that registered in no model.
    pub fn unregistered(&self) -> impl Iterator<Item = &ImageReport> {
        self.images.iter().filter(|i| i.model.is_none())
    }

    /// What to try, most specific first.
    pub fn advice(&self) -> Vec<String> {
        let mut out = Vec::new();
        let few: Vec<&str> = self
            .images
            .iter()
            .filter(|i| i.keypoints < FEW_FEATURES)
            .map(|i| i.colmap_name.as_str())
            .collect();
        if !few.is_empty() {
            out.push(format!(
                "{} found fewer than {FEW_FEATURES} features: check they are not blank, dark or blurred, \
                 and add texture to the scene (posters, patterned cloth, newspaper on the floor)",
                few.join(", ")
            ));
        }
        let weak: Vec<&str> = self
            .images
            .iter()
            .filter(|i| {
                i.keypoints >= FEW_FEATURES
                    && i.best_partners.first().is_none_or(|p| p.1 < WEAK_MATCHES)
            })
            .map(|i| i.colmap_name.as_str())
            .collect();
        if !weak.is_empty() {
            out.push(format!(
                "{} match no other image well (< {WEAK_MATCHES} verified matches): take stills from \
                 positions between these cameras and their neighbours, each overlapping both",
                weak.join(", ")
            ));
        }
        if self.num_models > 1 {
            out.push(format!(
                "the images fell into {} separate groups (models); take stills that see what two groups \
                 see, to bridge them",
                self.num_models
            ));
        }
        out.push(
            "more stills help most: 8 or more, walking in an arc between the video cameras, \
             60% overlap from one to the next"
                .into(),
        );
        out.push(
            "if the lenses are known (checkerboard calibration), import a calibration file \
             (calibration.json/.yaml/.toml or a COLMAP model) instead of solving"
                .into(),
        );
        out
    }
}

impl fmt::Display for Diagnosis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "  {:<28} {:>9} {:>9} {:>10}  best partners",
            "image", "features", "matches", "registered"
        )?;
        for i in &self.images {
            let reg = i.model.map_or("no".to_string(), |m| format!("model {m}"));
            let partners: Vec<String> = i
                .best_partners
                .iter()
                .map(|(n, c)| format!("{n} ({c})"))
                .collect();
            let partners = if partners.is_empty() {
                "none".to_string()
            } else {
                partners.join(", ")
            };
            writeln!(
                f,
                "  {:<28} {:>9} {:>9} {:>10}  {partners}",
                i.colmap_name, i.keypoints, i.verified_matches, reg
            )?;
        }
        writeln!(f, "What to try:")?;
        for a in self.advice() {
            writeln!(f, "  - {a}")?;
        }
        Ok(())
    }
}
