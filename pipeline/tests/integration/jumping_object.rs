//! An object that jumps between two places in a green dome (`fixtures/jumping.toml`, four
//! training cameras, three held out between them; docs/experiments/jumping-object.md):
//! where the training cameras disagree, the held-out views must not darken the object.
//! With the defaults (the Gaussians no training camera sees pruned, pseudo views for every
//! view of the batch whose pixels in front of a farther surface take no part) the darkest
//! held-out view keeps 0.87 of the box's brightness at preset `balanced` (0.84–0.87 over
//! seeds 0–2; 0.81–0.84 with a pseudo view for the batch's first view alone). Without
//! the pruning it kept 0.78, and its mean 0.88 against 0.92; with those pseudo-view
//! pixels taking part, 0.64 under a haze over a whole view. No whole held-out view may
//! sink under a dark cloud either (`darkest_view`).

use crate::common;

use std::fs;

use common::fixture;
use pipeline::report::{OutputMode, Reporter};
use pipeline::runner::Selection;
use pipeline::simulate;

#[test]
fn held_out_views_keep_the_jumping_object_bright() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("capture");
    let scene = rig::sim::Scene::from_file(&fixture("jumping.toml")).unwrap();
    simulate::simulate_into(&scene, &root, &Reporter::new(OutputMode::Quiet)).unwrap();
    simulate::write_truth_calibration(&root).unwrap();
    fs::write(
        root.join("capture.toml"),
        "[sync]\nmethod = \"timestamps\"\n[train]\npreset = \"balanced\"\n",
    )
    .unwrap();
    let summary = common::run_stages(
        &root,
        Selection {
            to: Some("eval".into()),
            ..Default::default()
        },
    );
    assert!(summary.failed.is_none(), "{summary:?}");
    let json: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(root.join("work/eval/metrics.json")).unwrap())
            .unwrap();
    let moving = &json["heldout"]["moving"];
    eprintln!("held-out moving region: {moving}");
    assert_eq!(moving["frames"].as_u64(), Some(45), "{moving}");
    let mean = moving["mean"]["brightness"].as_f64().unwrap();
    let darkest = moving["darkest"].as_f64().unwrap();
    assert!(
        mean >= 0.9,
        "the held-out box keeps {mean:.3} of its brightness"
    );
    assert!(
        darkest >= 0.8,
        "the darkest held-out view keeps {darkest:.3}"
    );
    let psnr = moving["mean"]["psnr"].as_f64().unwrap();
    assert!(psnr > 14.5, "held-out moving region {psnr:.2} dB");
    // No held-out view under a dark cloud: the darkest whole view keeps 0.93 of the
    // truth's brightness (0.92–0.95 over seeds 0–2; a 12-s clip of the scene kept 0.59 at
    // one seed of two, before pseudo views).
    let view = &json["heldout"]["darkest_view"];
    let whole = view["brightness"].as_f64().unwrap();
    assert!(whole >= 0.8, "the darkest held-out view: {view}");
}
