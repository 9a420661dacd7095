//! The allowed range of every numeric setting of `capture.toml`, checked on the file's own
//! values when it is read ([`check`]): an error names the key, the value and the range,
//! so `[frames] long_side = 0` or a learning rate of `nan` stops before any stage runs.
//! The tests hold every numeric setting of the defaults to an entry here.

/// Where a setting's value must lie: `min ≤ v ≤ max`, either bound open.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Range {
    pub min: f64,
    pub min_open: bool,
    pub max: f64,
    pub max_open: bool,
}

/// `v ≥ min`.
const fn at_least(min: f64) -> Range {
    Range {
        min,
        min_open: false,
        max: f64::INFINITY,
        max_open: false,
    }
}

/// `v > min`.
const fn above(min: f64) -> Range {
    Range {
        min,
        min_open: true,
        max: f64::INFINITY,
        max_open: false,
    }
}

/// `min ≤ v ≤ max`.
const fn within(min: f64, max: f64) -> Range {
    Range {
        min,
        min_open: false,
        max,
        max_open: false,
    }
}

/// `0 < v ≤ max`.
const fn positive_to(max: f64) -> Range {
    Range {
        min: 0.0,
        min_open: true,
        max,
        max_open: false,
    }
}

/// A share: `0 ≤ v ≤ 1`.
const FRACTION: Range = within(0.0, 1.0);
/// A count that may be zero (often "off").
const COUNT: Range = at_least(0.0);
/// A count of at least one.
const SOME: Range = at_least(1.0);
/// A learning rate, scale or size: finite and above zero.
const POSITIVE: Range = above(0.0);
/// A rate in frames per second.
const FPS: Range = positive_to(1000.0);

/// Every numeric setting (dotted: section, sub-table, key) and its range; for arrays
/// (`[train] background`, `[render] size`) each element's.
pub const RANGES: &[(&str, Range)] = &[
    ("capture.cameras", SOME),
    ("ingest.image_fps", FPS),
    ("sync.max_offset_s", POSITIVE),
    ("sync.min_audio_confidence", COUNT),
    ("sync.min_flash_confidence", COUNT),
    ("sync.exposure_s", within(0.0, 1.0)),
    ("sync.readout_s", within(0.0, 1.0)),
    ("sync.audio.clap_prominence", COUNT),
    ("sync.audio.clap_window_s", at_least(0.0)),
    ("sync.audio.max_excerpt_s", POSITIVE),
    ("frames.fps", FPS),
    ("frames.long_side", at_least(32.0)),
    ("frames.max_frames", SOME),
    ("frames.start_s", at_least(0.0)),
    ("poses.min_stills", COUNT),
    ("poses.radius", POSITIVE),
    ("poses.colmap.init_min_num_inliers", SOME),
    ("poses.colmap.max_attempts", SOME),
    ("poses.colmap.max_image_size", at_least(32.0)),
    ("poses.colmap.max_num_features", SOME),
    ("poses.colmap.num_threads", at_least(-1.0)),
    ("poses.colmap.random_seed", COUNT),
    ("poses.colmap.video_focal_px", POSITIVE),
    ("init.input_size", at_least(16.0)),
    ("init.min_confidence", at_least(0.0)),
    ("init.voxel_size", at_least(0.0)),
    ("init.max_points", SOME),
    ("init.random_points", COUNT),
    ("init.min_points", COUNT),
    ("init.seed", COUNT),
    ("init.scale_tolerance", POSITIVE),
    ("init.max_residual", POSITIVE),
    ("init.min_sparse_matches", SOME),
    ("init.max_non_finite", FRACTION),
    ("init.moments", COUNT),
    ("init.min_track", at_least(2.0)),
    ("init.static_radius", POSITIVE),
    ("init.sweep_size", at_least(32.0)),
    ("init.sweep_max_planes", at_least(2.0)),
    ("init.sweep_min_score", within(-1.0, 1.0)),
    ("init.sweep_min_views", SOME),
    ("init.min_neighbours", COUNT),
    ("init.plates", COUNT),
    ("init.motion_threshold", within(0.0, 255.0)),
    ("train.iterations", SOME),
    ("train.resolution", positive_to(1.0)),
    ("train.batch_size", SOME),
    ("train.seed", COUNT),
    ("train.lambda_ssim", FRACTION),
    ("train.background", FRACTION),
    ("train.backdrop_size", within(16.0, 8192.0)),
    ("train.colour_degrees.spatial", within(0.0, 3.0)),
    ("train.colour_degrees.temporal", within(0.0, 2.0)),
    ("train.degree_every", SOME),
    ("train.init_opacity", positive_to(1.0)),
    ("train.init_time_scale", POSITIVE),
    ("train.init_flatness", FRACTION),
    ("train.max_anisotropy", COUNT),
    ("train.checkpoint_every", COUNT),
    ("train.keep_checkpoints", SOME),
    ("train.report_every", SOME),
    ("train.lr.position_init", POSITIVE),
    ("train.lr.position_final", POSITIVE),
    ("train.lr.position_decay_steps", COUNT),
    ("train.lr.time", POSITIVE),
    ("train.lr.colour_dc", POSITIVE),
    ("train.lr.colour_rest", POSITIVE),
    ("train.lr.opacity", POSITIVE),
    ("train.lr.scale", POSITIVE),
    ("train.lr.rotation", POSITIVE),
    ("train.densify.from_iteration", COUNT),
    ("train.densify.until_iteration", COUNT),
    ("train.densify.every", SOME),
    ("train.densify.grad_threshold", POSITIVE),
    ("train.densify.percent_dense", POSITIVE),
    ("train.densify.min_opacity", FRACTION),
    ("train.densify.max_screen_radius", POSITIVE),
    ("train.densify.max_world_size", POSITIVE),
    ("train.densify.opacity_reset_every", COUNT),
    ("train.densify.max_gaussians", SOME),
    ("train.densify.min_cameras", COUNT),
    ("train.pseudo_views.weight", at_least(0.0)),
    ("train.pseudo_views.baseline", positive_to(1.0)),
    ("train.pseudo_views.start", FRACTION),
    ("train.pseudo_views.per_step", SOME),
    ("chunks.seconds", at_least(0.0)),
    ("chunks.overlap_seconds", at_least(0.0)),
    ("chunks.static_steps", COUNT),
    ("engine.chunks_at_once", COUNT),
    ("decay.beta", positive_to(1.0)),
    ("decay.constant", positive_to(1.0)),
    ("decay.exp_kappa", POSITIVE),
    ("decay.f_min", positive_to(1.0)),
    ("decay.f_max", positive_to(1.0)),
    ("decay.hidden_layers", SOME),
    ("decay.hidden_width", SOME),
    ("decay.lr", POSITIVE),
    ("decay.near", POSITIVE),
    ("decay.pow_gamma", POSITIVE),
    ("decay.seed", COUNT),
    ("decay.warmup", COUNT),
    ("decay.weight_decay", COUNT),
    ("render.frames", SOME),
    ("render.fps", FPS),
    ("render.size", at_least(16.0)),
    ("eval.heldout_per_camera", COUNT),
    ("eval.train_views", COUNT),
    ("export.steps", SOME),
    ("export.min_opacity", within(0.0, 1.0)),
    ("export.gltf_every", COUNT),
    ("export.segment_seconds", at_least(0.0)),
    ("cluster.cpus", SOME),
    ("cluster.gpus", COUNT),
];

impl Range {
    /// Whether `v` lies in the range (never for NaN or an infinite value).
    pub fn contains(&self, v: f64) -> bool {
        let above_min = v > self.min || (!self.min_open && v == self.min);
        let below_max = v < self.max || (!self.max_open && v == self.max);
        v.is_finite() && above_min && below_max
    }

    /// "at least 1", "above 0", "from 0 to 1", "above 0 and at most 1".
    pub fn describe(&self) -> String {
        let low = if self.min_open {
            format!("above {}", self.min)
        } else {
            format!("at least {}", self.min)
        };
        if self.max.is_infinite() {
            return format!("a finite number {low}");
        }
        match (self.min_open, self.max_open) {
            (false, false) => format!("from {} to {}", self.min, self.max),
            (_, max_open) => format!(
                "{low} and {} {}",
                if max_open { "below" } else { "at most" },
                self.max
            ),
        }
    }
}

/// The range of the setting at dotted `key`, if it is numeric. A per-stage cluster key
/// (`cluster.stages.train.cpus`) has the range of its `[cluster]` key.
pub fn range_of(key: &str) -> Option<Range> {
    let key = match key.strip_prefix("cluster.stages.") {
        Some(rest) => format!("cluster.{}", rest.split_once('.').map_or(rest, |(_, k)| k)),
        None => key.to_string(),
    };
    RANGES.iter().find(|(k, _)| *k == key).map(|(_, r)| *r)
}

/// The first numeric value of `table` (a parsed `capture.toml`) outside its range, as a
/// message naming the key, the value and the range.
pub fn check(table: &toml::Table) -> Result<(), String> {
    check_table(table, "")
}

fn check_table(table: &toml::Table, prefix: &str) -> Result<(), String> {
    for (key, value) in table {
        let path = if prefix.is_empty() {
            key.clone()
        } else {
            format!("{prefix}.{key}")
        };
        match value {
            toml::Value::Table(t) => check_table(t, &path)?,
            toml::Value::Array(items) => {
                for item in items {
                    check_value(&path, item)?;
                }
            }
            other => check_value(&path, other)?,
        }
    }
    Ok(())
}

fn check_value(path: &str, value: &toml::Value) -> Result<(), String> {
    let v = match value {
        toml::Value::Integer(i) => *i as f64,
        toml::Value::Float(f) => *f,
        _ => return Ok(()),
    };
    let Some(range) = range_of(path) else {
        return Ok(());
    };
    if range.contains(v) {
        return Ok(());
    }
    let (section, key) = path.rsplit_once('.').unwrap_or(("", path));
    Err(format!(
        "[{section}] {key} = {value} is out of range: it must be {}",
        range.describe()
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::CaptureConfig;
    use std::path::Path;

    /// Dotted paths of the numeric values of `value` (array elements under their array).
    fn numeric_keys(value: &serde_json::Value, prefix: &str, out: &mut Vec<String>) {
        match value {
            serde_json::Value::Object(map) => {
                for (k, v) in map {
                    let path = if prefix.is_empty() {
                        k.clone()
                    } else {
                        format!("{prefix}.{k}")
                    };
                    numeric_keys(v, &path, out);
                }
            }
            serde_json::Value::Array(items) if items.iter().any(|i| i.is_number()) => {
                out.push(prefix.to_string())
            }
            serde_json::Value::Number(_) => out.push(prefix.to_string()),
            _ => {}
        }
    }

    #[test]
    fn every_numeric_setting_has_a_range_that_holds_its_default() {
        let config = CaptureConfig::default();
        let json = serde_json::to_value(&config).unwrap();
        let mut keys = Vec::new();
        numeric_keys(&json, "", &mut keys);
        assert!(keys.len() > 80, "{keys:?}");
        let mut missing = Vec::new();
        for key in &keys {
            match range_of(key) {
                None => missing.push(key.clone()),
                Some(range) => {
                    let mut values = Vec::new();
                    let mut at = &json;
                    for part in key.split('.') {
                        at = &at[part];
                    }
                    match at {
                        serde_json::Value::Array(items) => values.extend(items.clone()),
                        v => values.push(v.clone()),
                    }
                    for v in values {
                        let v = v.as_f64().unwrap();
                        assert!(range.contains(v), "{key}: default {v} outside {range:?}");
                    }
                }
            }
        }
        assert!(
            missing.is_empty(),
            "numeric settings without a range: {missing:?}"
        );
    }

    /// `[section.sub] key = value` as TOML.
    fn setting(key: &str, value: &str) -> String {
        let (section, key) = key.rsplit_once('.').unwrap();
        format!("[{section}]\n{key} = {value}\n")
    }

    #[test]
    fn a_value_outside_its_range_names_the_key_the_value_and_the_range() {
        let path = Path::new("capture.toml");
        let e = CaptureConfig::parse("[frames]\nlong_side = 0\n", path)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("capture.toml")
                && e.contains("[frames] long_side = 0 is out of range")
                && e.contains("at least 32"),
            "{e}"
        );
        for (key, bad) in [
            ("train.lr.opacity", "nan"),
            ("train.lr.opacity", "-0.01"),
            ("train.densify.min_opacity", "1.5"),
            ("init.max_non_finite", "inf"),
            ("decay.beta", "0"),
            ("train.background", "[0.5, 1.2, 0.5]"),
            ("render.size", "[0, 360]"),
            ("capture.cameras", "0"),
            ("init.sweep_min_score", "-2.0"),
            ("cluster.cpus", "0"),
            ("cluster.stages.train.cpus", "0"),
            ("cluster.gpus", "-1"),
        ] {
            let e = CaptureConfig::parse(&setting(key, bad), path)
                .unwrap_err()
                .to_string();
            let short = key.rsplit_once('.').unwrap().1;
            assert!(e.contains(&format!("{short} = ")), "{key} = {bad}: {e}");
            assert!(e.contains("out of range") || e.contains("at least"), "{e}");
        }
        // In range, at the bounds.
        for (key, good) in [
            ("frames.long_side", "32"),
            ("train.densify.min_opacity", "1.0"),
            ("init.plates", "0"),
            ("poses.colmap.num_threads", "-1"),
            ("train.background", "[0.0, 1.0, 0.5]"),
            ("decay.beta", "1.0"),
        ] {
            CaptureConfig::parse(&setting(key, good), path)
                .unwrap_or_else(|e| panic!("{key} = {good}: {e}"));
        }
    }

    #[test]
    fn the_shipped_capture_settings_are_in_range() {
        let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures");
        for name in ["demo-capture.toml", "panoptic-capture.toml"] {
            let path = fixtures.join(name);
            let text = std::fs::read_to_string(&path).unwrap();
            CaptureConfig::parse(&text, &path).unwrap_or_else(|e| panic!("{e}"));
        }
    }

    #[test]
    fn ranges_describe_themselves() {
        assert_eq!(SOME.describe(), "a finite number at least 1");
        assert_eq!(POSITIVE.describe(), "a finite number above 0");
        assert_eq!(FRACTION.describe(), "from 0 to 1");
        assert_eq!(positive_to(1.0).describe(), "above 0 and at most 1");
        assert!(!POSITIVE.contains(f64::NAN) && !COUNT.contains(f64::INFINITY));
    }
}
