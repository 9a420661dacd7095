//! `model.4dgs`: the whole 4D model in one compact file for the browser viewer, which
//! slices each Gaussian at the playback time on the GPU (no per-frame baking).
//!
//! A 4D Gaussian sliced at time `t` is exactly a 3D Gaussian moving on a line
//! (REFERENCE.md §1): mean `μ + v·(t − μt)` with `v = Σ12/Σ44`, a covariance
//! `Σ11 − Σ12Σ12ᵀ/Σ44` that does not depend on `t`, and opacity `σ(o)·ω(t)`,
//! `ω(t) = exp(−½(t − μt)²/Σ44)`. The file stores that form, computed in `f64` from the
//! model, and the spherindrical colour coefficients at the model's active degrees, so the
//! page evaluates the engine's own colour (view direction from the camera to `μ`,
//! temporal cosines over the period `T`).
//!
//! Layout (little-endian):
//!
//! - 8 bytes magic `4DGSWEB1`, `u32` length `J`, `J` bytes of JSON ([`WebHeader`]), zero
//!   padding to a multiple of 16 bytes from the start of the file;
//! - `count` records of `texels × 16` bytes, one per Gaussian, most important first (so a
//!   page that draws while the file streams in shows the big opaque splats first). As
//!   `u32` words (`half2(a, b)`: `a` in the low 16 bits):
//!   - `0..3` position `f32 × 3`, `3` time centre `μt` as `f32`;
//!   - `4` half2(vx, vy), `5` half2(vz, σt) with `σt = √Σ44`;
//!   - `6` half2(sx, sy), `7` half2(sz, opacity): the covariance's standard deviations
//!     along its axes and `σ(o)`;
//!   - `8` half2(qw, qx), `9` half2(qy, qz): the axes' rotation, a unit quaternion;
//!   - `10` half2(dc_r, dc_g), `11` half2(dc_b, 0): the DC colour coefficients;
//!   - `12..`: the other colour coefficients as `i8`, four per word, coefficient
//!     `k = j·(spatial+1)² + s` (temporal `j` outer, spatial SH `s` inner; `k = 0` is the
//!     DC) from `k = 1` up, channel innermost; value `i8 · sh_scales[k − 1]`.
//!
//! At degrees (3, 2) a record is 192 bytes: 200 000 Gaussians take 38 MB whatever the
//! clip's length.

use super::bake::{colour_period, covariance_to_scale_rotation, linear_motion};
use super::splatv::{half2, unhalf2};
use super::{ExportError, write_atomic};
use crate::math::numerics::sigmoid;
use crate::math::slice::TEMPORAL_CUTOFF;
use crate::model::{ColourDegrees, Gaussians, TimeMapping};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The first 8 bytes of every file.
pub const MAGIC: &[u8; 8] = b"4DGSWEB1";
/// Words of a record before the packed colour coefficients.
pub const BASE_WORDS: usize = 12;
/// Largest header accepted by [`decode`].
const MAX_HEADER: usize = 1 << 20;
/// The quantisation scale of a coefficient covers this quantile of its magnitudes
/// (rarer, larger values are clamped): a few outliers do not coarsen every other value.
const SCALE_QUANTILE: f64 = 0.999;
/// Records sampled (evenly) for the quantiles.
const SCALE_SAMPLE: usize = 50_000;
/// Largest finite half float.
const HALF_MAX: f64 = 65504.0;
/// Smallest standard deviation stored (a normal-range half float keeps 3 digits).
const MIN_WIDTH: f64 = 1e-6;

/// The JSON header.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WebHeader {
    /// Number of records.
    pub count: usize,
    /// 16-byte texels per record.
    pub texels: usize,
    /// Colour degrees of the records (the model's active degrees).
    pub degrees: ColourDegrees,
    /// Period `T` of the temporal colour basis (model time).
    pub period: f64,
    /// Seconds ↔ model time.
    pub time: TimeMapping,
    /// Model times the file was made for; Gaussians invisible throughout are left out.
    pub span: [f64; 2],
    /// Dequantisation scale of colour coefficient `k = 1, 2, …` (index `k − 1`).
    pub sh_scales: Vec<f32>,
}

impl WebHeader {
    /// Texels per record at colour degrees `degrees`.
    pub fn texels_for(degrees: ColourDegrees) -> usize {
        let bytes = (degrees.coeff_count() - 1) * 3;
        (BASE_WORDS * 4 + bytes).div_ceil(16)
    }
}

/// One record, decoded (values after half-float and `i8` rounding).
#[derive(Clone, Debug, PartialEq)]
pub struct WebGaussian {
    pub position: [f32; 3],
    pub t_mean: f32,
    pub velocity: [f32; 3],
    /// `√Σ44`.
    pub t_sigma: f32,
    /// Standard deviations along the covariance's axes.
    pub scale: [f32; 3],
    /// `σ(o)`.
    pub opacity: f32,
    /// `(w, x, y, z)`; its rotation matrix has the axes as columns.
    pub rotation: [f32; 4],
    /// `coeffs[k][c]`, `k` as in the module docs.
    pub coeffs: Vec<[f32; 3]>,
}

/// What [`encode`] made: the file's bytes and its header.
pub struct Encoded {
    pub bytes: Vec<u8>,
    pub header: WebHeader,
}

/// Whether a Gaussian with time centre `mu` and `σt` has `ω > cutoff` anywhere in `span`.
fn alive_in(mu: f64, sigma: f64, span: [f64; 2]) -> bool {
    let nearest = mu.clamp(span[0], span[1]);
    let reach = sigma * (-2.0 * TEMPORAL_CUTOFF.ln()).sqrt();
    (nearest - mu).abs() < reach
}

/// The linear-motion form of one Gaussian, before quantisation.
struct Row {
    position: [f64; 3],
    t_mean: f64,
    velocity: [f64; 3],
    t_sigma: f64,
    scale: [f64; 3],
    opacity: f64,
    rotation: [f64; 4],
    importance: f64,
    index: usize,
}

/// Encode `model` for times in `span` (model time): Gaussians with `σ(o) < min_opacity`
/// or culled in time throughout `span` are left out.
pub fn encode(model: &Gaussians<f32>, span: [f64; 2], min_opacity: f64) -> Encoded {
    let rows = rows_of(model, span, min_opacity);
    let header = header_for(model, &rows, span);
    encode_rows(model, header, &rows)
}

/// One file of a model encoded in time segments ([`encode_segments`]).
pub struct Segment {
    /// The model times at which a Gaussian of this file can be drawn: the union of its
    /// Gaussians' reaches in time (`[start, end]` of the clip for the always-drawn file).
    pub reach: [f64; 2],
    pub encoded: Encoded,
}

/// Encode `model` for `span` as [`encode`] does, split into files a page can load as the
/// playhead moves: first the Gaussians drawn for longer than `segment` (model time; the
/// static scene), then one file per segment of about `segment` holding the Gaussians
/// whose time centre lies in it. Each Gaussian is in exactly one file, and every file
/// shares the first's header (colour scales included) but for `count` and `span`
/// (its `reach`). A span up to 1.5 segments long, or `segment <= 0`, gives one file.
pub fn encode_segments(
    model: &Gaussians<f32>,
    span: [f64; 2],
    min_opacity: f64,
    segment: f64,
) -> Vec<Segment> {
    let rows = rows_of(model, span, min_opacity);
    let header = header_for(model, &rows, span);
    let length = span[1] - span[0];
    let n = if segment > 0.0 && length > 1.5 * segment {
        (length / segment).round() as usize
    } else {
        1
    };
    if n == 1 {
        let encoded = encode_rows(model, header, &rows);
        return vec![Segment {
            reach: span,
            encoded,
        }];
    }
    let width = length / n as f64;
    let reach_of = |r: &Row| {
        let half = r.t_sigma * (-2.0 * TEMPORAL_CUTOFF.ln()).sqrt();
        [
            (r.t_mean - half).max(span[0]),
            (r.t_mean + half).min(span[1]),
        ]
    };
    // Part 0: Gaussians that reach over more than a segment; part 1 + k: segment k.
    let mut parts: Vec<Vec<Row>> = (0..=n).map(|_| Vec::new()).collect();
    for r in rows {
        let [a, b] = reach_of(&r);
        let k = if b - a > width {
            0
        } else {
            1 + (((r.t_mean - span[0]) / width).floor().max(0.0) as usize).min(n - 1)
        };
        parts[k].push(r);
    }
    parts
        .into_iter()
        .enumerate()
        .map(|(k, part)| {
            let reach = if k == 0 {
                span
            } else {
                let own = [span[0] + width * (k - 1) as f64, span[0] + width * k as f64];
                part.iter()
                    .map(reach_of)
                    .fold(own, |acc, [a, b]| [acc[0].min(a), acc[1].max(b)])
            };
            let header = WebHeader {
                count: part.len(),
                span: reach,
                ..header.clone()
            };
            Segment {
                reach,
                encoded: encode_rows(model, header, &part),
            }
        })
        .collect()
}

/// The records of `model` for `span`, most important first (see [`encode`]).
fn rows_of(model: &Gaussians<f32>, span: [f64; 2], min_opacity: f64) -> Vec<Row> {
    let mut rows: Vec<Row> = (0..model.len())
        .into_par_iter()
        .with_min_len(512)
        .filter_map(|i| {
            let opacity = sigmoid(model.opacity_logits[i] as f64);
            if !(opacity >= min_opacity) {
                return None;
            }
            let (position, velocity, s44, cov) = linear_motion(model, i);
            let t_mean = model.means[i][3] as f64;
            let t_sigma = s44.sqrt();
            let finite = position.iter().chain(&velocity).all(|v| v.is_finite());
            if !finite || !t_mean.is_finite() || !alive_in(t_mean, t_sigma, span) {
                return None;
            }
            let (log_scale, rotation) = covariance_to_scale_rotation(cov);
            let scale = log_scale.map(f64::exp);
            let importance = opacity * (scale[0] * scale[1] * scale[2]).cbrt().powi(2);
            Some(Row {
                position,
                t_mean,
                velocity,
                t_sigma,
                scale,
                opacity,
                rotation,
                importance,
                index: i,
            })
        })
        .collect();
    rows.sort_by(|a, b| {
        b.importance
            .total_cmp(&a.importance)
            .then(a.index.cmp(&b.index))
    });
    rows
}

/// Colour coefficient `k` (file order, active degrees) of Gaussian `i`, channel `c`.
fn coeff(model: &Gaussians<f32>, i: usize, k: usize, c: usize) -> f32 {
    let degrees = model.active.min(model.capacity);
    let ns = degrees.spatial_count();
    let (j, s) = (k / ns, k % ns);
    model.colour_of(i)[(j * model.capacity.spatial_count() + s) * 3 + c]
}

/// The header of a file of `rows`: the colour coefficients' quantisation scales from an
/// even sample of them.
fn header_for(model: &Gaussians<f32>, rows: &[Row], span: [f64; 2]) -> WebHeader {
    let degrees = model.active.min(model.capacity);
    let nk = degrees.coeff_count();
    // Each coefficient's magnitudes over an even sample of the records, gathered in one
    // pass over the sample (each Gaussian's coefficients are contiguous).
    let step = rows.len().div_ceil(SCALE_SAMPLE).max(1);
    let mut mags: Vec<Vec<f32>> = vec![Vec::new(); nk.saturating_sub(1)];
    for r in rows.iter().step_by(step) {
        for (k, m) in (1..nk).zip(&mut mags) {
            m.extend(
                (0..3)
                    .map(|c| coeff(model, r.index, k, c).abs())
                    .filter(|v| v.is_finite()),
            );
        }
    }
    let sh_scales: Vec<f32> = mags
        .into_par_iter()
        .map(|mut m| {
            if m.is_empty() {
                return 1.0;
            }
            let at = ((m.len() - 1) as f64 * SCALE_QUANTILE).round() as usize;
            let (_, q, _) = m.select_nth_unstable_by(at, f32::total_cmp);
            if *q > 0.0 { *q / 127.0 } else { 1.0 }
        })
        .collect();
    WebHeader {
        count: rows.len(),
        texels: WebHeader::texels_for(degrees),
        degrees,
        period: colour_period(model),
        time: model.time,
        span,
        sh_scales,
    }
}

/// The file of `rows` under `header` (whose `count` is `rows.len()`).
fn encode_rows(model: &Gaussians<f32>, header: WebHeader, rows: &[Row]) -> Encoded {
    let nk = header.degrees.coeff_count();
    let coeff = |i: usize, k: usize, c: usize| coeff(model, i, k, c);
    let texels = header.texels;
    let json = serde_json::to_vec(&header).expect("the header serialises");
    let start = (12 + json.len()).div_ceil(16) * 16;
    let record = texels * 16;
    let mut bytes = vec![0u8; start + rows.len() * record];
    bytes[..8].copy_from_slice(MAGIC);
    bytes[8..12].copy_from_slice(&(json.len() as u32).to_le_bytes());
    bytes[12..12 + json.len()].copy_from_slice(&json);
    bytes[start..]
        .par_chunks_mut(record)
        .zip(rows)
        .for_each(|(out, r)| {
            let f = |v: f64| v as f32;
            // Within half-float range: no infinities, no zero widths (the page divides).
            let big = |v: f64| v.clamp(-HALF_MAX, HALF_MAX) as f32;
            let width = |v: f64| v.clamp(MIN_WIDTH, HALF_MAX) as f32;
            let words = [
                f(r.position[0]).to_bits(),
                f(r.position[1]).to_bits(),
                f(r.position[2]).to_bits(),
                f(r.t_mean).to_bits(),
                half2(big(r.velocity[0]), big(r.velocity[1])),
                half2(big(r.velocity[2]), width(r.t_sigma)),
                half2(width(r.scale[0]), width(r.scale[1])),
                half2(width(r.scale[2]), f(r.opacity)),
                half2(f(r.rotation[0]), f(r.rotation[1])),
                half2(f(r.rotation[2]), f(r.rotation[3])),
                half2(coeff(r.index, 0, 0), coeff(r.index, 0, 1)),
                half2(coeff(r.index, 0, 2), 0.0),
            ];
            for (w, o) in words.iter().zip(out.chunks_exact_mut(4)) {
                o.copy_from_slice(&w.to_le_bytes());
            }
            let packed = &mut out[BASE_WORDS * 4..];
            for k in 1..nk {
                let s = header.sh_scales[k - 1];
                for c in 0..3 {
                    let q = (coeff(r.index, k, c) / s).round();
                    let q = if q.is_finite() {
                        q.clamp(-127.0, 127.0)
                    } else {
                        0.0
                    };
                    packed[(k - 1) * 3 + c] = q as i8 as u8;
                }
            }
        });
    Encoded { bytes, header }
}

/// Write `model.4dgs` atomically; returns the header written.
pub fn write_web_model(
    model: &Gaussians<f32>,
    span: [f64; 2],
    min_opacity: f64,
    path: &Path,
) -> Result<WebHeader, ExportError> {
    let Encoded { bytes, header } = encode(model, span, min_opacity);
    write_atomic(path, &bytes)?;
    Ok(header)
}

/// Decode a file made by [`encode`]; `Err` says what is wrong with it.
pub fn decode(bytes: &[u8]) -> Result<(WebHeader, Vec<WebGaussian>), String> {
    if bytes.get(..8) != Some(MAGIC.as_slice()) {
        return Err("does not start with 4DGSWEB1: not a splat4d web model".into());
    }
    let len = bytes
        .get(8..12)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
        .ok_or("truncated before the header length")?;
    if len > MAX_HEADER {
        return Err(format!("header length {len} is implausible"));
    }
    let json = bytes.get(12..12 + len).ok_or("truncated header")?;
    let header: WebHeader = serde_json::from_slice(json).map_err(|e| format!("header: {e}"))?;
    let d = header.degrees;
    if !d.is_valid() {
        return Err(format!("header: colour degrees {d:?} out of range"));
    }
    if header.texels != WebHeader::texels_for(d) {
        return Err(format!(
            "header: {} texels per record, degrees {d:?} need {}",
            header.texels,
            WebHeader::texels_for(d)
        ));
    }
    let nk = d.coeff_count();
    if header.sh_scales.len() != nk - 1 {
        return Err(format!(
            "header: {} colour scales, degrees {d:?} need {}",
            header.sh_scales.len(),
            nk - 1
        ));
    }
    let start = (12 + len).div_ceil(16) * 16;
    let record = header.texels * 16;
    let body = bytes.get(start..).unwrap_or_default();
    if body.len() / record < header.count {
        return Err(format!(
            "truncated: the header lists {} Gaussians, the file holds {}",
            header.count,
            body.len() / record
        ));
    }
    let gaussians = body
        .chunks_exact(record)
        .take(header.count)
        .map(|r| {
            let w =
                |k: usize| u32::from_le_bytes([r[4 * k], r[4 * k + 1], r[4 * k + 2], r[4 * k + 3]]);
            let (vx, vy) = unhalf2(w(4));
            let (vz, t_sigma) = unhalf2(w(5));
            let (sx, sy) = unhalf2(w(6));
            let (sz, opacity) = unhalf2(w(7));
            let (qw, qx) = unhalf2(w(8));
            let (qy, qz) = unhalf2(w(9));
            let (r0, g0) = unhalf2(w(10));
            let (b0, _) = unhalf2(w(11));
            let mut coeffs = vec![[r0, g0, b0]];
            let packed = &r[BASE_WORDS * 4..];
            for k in 1..nk {
                let s = header.sh_scales[k - 1];
                coeffs.push(std::array::from_fn(|c| {
                    packed[(k - 1) * 3 + c] as i8 as f32 * s
                }));
            }
            WebGaussian {
                position: [w(0), w(1), w(2)].map(f32::from_bits),
                t_mean: f32::from_bits(w(3)),
                velocity: [vx, vy, vz],
                t_sigma,
                scale: [sx, sy, sz],
                opacity,
                rotation: [qw, qx, qy, qz],
                coeffs,
            }
        })
        .collect();
    Ok((header, gaussians))
}

/// Read a `model.4dgs` file.
pub fn read_web_model(path: &Path) -> Result<(WebHeader, Vec<WebGaussian>), ExportError> {
    let bytes = std::fs::read(path).map_err(|source| ExportError::Io {
        path: path.into(),
        source,
    })?;
    decode(&bytes).map_err(|reason| ExportError::Format {
        path: path.into(),
        reason,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::slice::slice;

    /// A model of Gaussians tilted in time (moving), with colour at degrees (3, 2).
    fn moving_model() -> Gaussians<f32> {
        let mut g = Gaussians::<f32>::new(ColourDegrees::FULL, TimeMapping::default());
        g.active = ColourDegrees::FULL;
        let mut seed = 11u64;
        let mut r = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 33) as f64 / (1u64 << 31) as f64) as f32 * 2.0 - 1.0
        };
        for _ in 0..200 {
            let mean = [r() * 2.0, r() * 2.0, 3.0 + r(), 0.5 + 0.4 * r()];
            let ls = [-3.0 + r(), -3.0 + r(), -3.5 + r(), -1.5 + r()];
            let i = g.push(mean, ls, 2.0 * r(), [0.5, 0.4, 0.3]);
            g.rot_left[i] = [1.0, 0.3 * r(), 0.3 * r(), 0.3 * r()];
            g.rot_right[i] = [1.0, 0.3 * r(), 0.3 * r(), 0.3 * r()];
            let k = 3 * g.coeffs_per_channel();
            for c in 3..k {
                g.colours[i * k + c] = 0.3 * r();
            }
        }
        g
    }

    #[test]
    fn records_slice_as_the_engine_does() {
        let model = moving_model();
        let Encoded { bytes, header } = encode(&model, [0.0, 1.0], 0.0);
        let (back, rows) = decode(&bytes).unwrap();
        assert_eq!(back, header);
        assert_eq!(rows.len(), model.len());
        assert_eq!(bytes.len() % 16, 0);
        assert_eq!(header.texels, 12, "192 bytes per record at degrees (3, 2)");
        let mut matched = 0;
        for i in 0..model.len() {
            // Records are reordered; find this Gaussian's by its exact time centre.
            let w = rows
                .iter()
                .find(|w| w.t_mean == model.means[i][3] && w.position[0] == model.means[i][0])
                .expect("every Gaussian has a record");
            let f = |a: [f32; 4]| a.map(|x| x as f64);
            for t in [0.1, 0.5, 0.9] {
                let engine = slice::<f64>(
                    f(model.means[i]),
                    f(model.log_scales[i]),
                    f(model.rot_left[i]),
                    f(model.rot_right[i]),
                    t,
                );
                let dt = t - w.t_mean as f64;
                let sig = w.t_sigma as f64;
                let omega = (-0.5 * dt * dt / (sig * sig)).exp();
                let Some((sl, _)) = engine else {
                    assert!(
                        omega <= 0.051,
                        "the engine culls, the record gives ω = {omega}"
                    );
                    continue;
                };
                matched += 1;
                assert!(
                    (omega - sl.omega).abs() < 2e-3 * sl.omega.max(0.05),
                    "ω {omega} vs {}",
                    sl.omega
                );
                let radius = (0..3).map(|a| w.scale[a] as f64).fold(0.0, f64::max);
                for a in 0..3 {
                    let shift = w.velocity[a] as f64 * dt;
                    let m = w.position[a] as f64 + shift;
                    // Half-float velocity: ~5e-4 of the shift.
                    assert!(
                        (m - sl.mean[a]).abs() < 1e-3 * shift.abs() + 2e-3 * radius + 1e-6,
                        "mean {m} vs {} (σmax {radius})",
                        sl.mean[a]
                    );
                }
                // Covariance R·diag(s²)·Rᵀ against the engine's B·Bᵀ.
                let [qw, qx, qy, qz] = w.rotation.map(|v| v as f64);
                let rot =
                    glam::DMat3::from_quat(glam::DQuat::from_xyzw(qx, qy, qz, qw).normalize());
                let s2 = glam::DVec3::from_array(w.scale.map(|v| (v as f64).powi(2)));
                let cov = rot * glam::DMat3::from_diagonal(s2) * rot.transpose();
                let b = sl.factor;
                let scale2 = s2.max_element();
                for r in 0..3 {
                    for c in 0..3 {
                        let e: f64 = (0..4).map(|k| b[r][k] * b[c][k]).sum();
                        assert!(
                            (cov.col(c)[r] - e).abs() < 4e-3 * scale2,
                            "cov[{r}][{c}] {} vs {e}",
                            cov.col(c)[r]
                        );
                    }
                }
            }
            // Colours within half a quantisation step (DC: half-float rounding).
            let coeffs = model.colour_of(i);
            for (k, got) in w.coeffs.iter().enumerate() {
                for c in 0..3 {
                    let want = coeffs[k * 3 + c];
                    // Beyond the scale's quantile a value is clamped to ±127 steps.
                    let tol = match k {
                        0 => 1e-3,
                        _ => {
                            let s = header.sh_scales[k - 1];
                            0.51 * s + (want.abs() - 127.0 * s).max(0.0)
                        }
                    };
                    assert!(
                        (got[c] - want).abs() <= tol,
                        "coefficient {k}/{c}: {} vs {want}",
                        got[c]
                    );
                }
            }
        }
        assert!(matched > 300, "only {matched} slices compared");
    }

    #[test]
    fn gaussians_invisible_in_the_span_or_transparent_are_left_out() {
        let mut model = moving_model();
        let n = model.len();
        // One far outside the span in time, one nearly transparent.
        model.push(
            [0.0, 0.0, 3.0, 9.0],
            [-3.0, -3.0, -3.0, -3.0],
            1.0,
            [0.5; 3],
        );
        model.push(
            [0.0, 0.0, 3.0, 0.5],
            [-3.0, -3.0, -3.0, -1.0],
            -9.0,
            [0.5; 3],
        );
        let e = encode(&model, [0.0, 1.0], 1.0 / 255.0);
        let kept = e.header.count;
        assert!(kept <= n && kept > n / 2, "{kept} of {n} kept");
        let (_, rows) = decode(&e.bytes).unwrap();
        assert!(
            rows.iter()
                .all(|w| w.t_mean != 9.0 && w.opacity > 1.0 / 255.0 - 1e-4)
        );
        // Most important first.
        let imp = |w: &WebGaussian| {
            w.opacity as f64
                * ((w.scale[0] * w.scale[1] * w.scale[2]) as f64)
                    .cbrt()
                    .powi(2)
        };
        assert!(imp(&rows[0]) >= imp(&rows[rows.len() - 1]));
    }

    #[test]
    fn segments_hold_every_record_once_each_within_its_files_reach() {
        // The moving model's Gaussians spread over a clip of 6 (model time), plus a still
        // wall drawn throughout.
        let mut model = moving_model();
        for m in &mut model.means {
            m[3] = 6.0 * (m[3] - 0.1) / 0.8;
        }
        for k in 0..20 {
            model.push(
                [k as f32 * 0.1, 0.0, 4.0, 3.0],
                [-3.0, -3.0, -3.0, 11.0],
                2.0,
                [0.5; 3],
            );
        }
        let span = [0.0, 6.0];
        let whole = encode(&model, span, 1.0 / 255.0);
        let (_, all) = decode(&whole.bytes).unwrap();
        let parts = encode_segments(&model, span, 1.0 / 255.0, 1.5);
        assert_eq!(parts.len(), 5, "the wall's file and four segments");
        assert_eq!(parts[0].reach, span);
        let mut seen = Vec::new();
        for (k, p) in parts.iter().enumerate() {
            let (h, rows) = decode(&p.encoded.bytes).unwrap();
            assert_eq!(
                h.sh_scales, whole.header.sh_scales,
                "one header for every file"
            );
            assert_eq!(h.span, p.reach);
            if k > 0 {
                assert!(!rows.is_empty(), "segment {k} is empty");
                let own = [1.5 * (k - 1) as f64, 1.5 * k as f64];
                assert!(p.reach[0] <= own[0] && p.reach[1] >= own[1]);
                assert!(p.reach[0] >= own[0] - 1.5 && p.reach[1] <= own[1] + 1.5);
            }
            for w in rows {
                let half = w.t_sigma as f64 * (-2.0 * TEMPORAL_CUTOFF.ln()).sqrt();
                let t = w.t_mean as f64;
                if k == 0 {
                    assert!(
                        2.0 * half > 1.5,
                        "a short-lived Gaussian among the always-drawn"
                    );
                } else {
                    // σt went through a half float (3 digits).
                    let tol = 2e-3 * half + 1e-9;
                    assert!(p.reach[0] <= (t - half).max(0.0) + tol);
                    assert!(p.reach[1] >= (t + half).min(6.0) - tol);
                }
                seen.push(w);
            }
        }
        assert_eq!(seen.len(), all.len());
        for w in &all {
            assert!(seen.contains(w), "a record is missing from the segments");
        }
        // Short clips and `segment <= 0`: one file, the whole model's.
        for segment in [0.0, 4.5] {
            let one = encode_segments(&model, span, 1.0 / 255.0, segment);
            assert_eq!(one.len(), 1);
            assert_eq!(one[0].encoded.bytes, whole.bytes);
        }
    }

    #[test]
    fn a_full_colour_model_of_200k_gaussians_fits_in_40_mb() {
        let record = WebHeader::texels_for(ColourDegrees::FULL) * 16;
        assert_eq!(record, 192);
        assert!(200_000 * record <= 40_000_000);
        // Degree 1 without temporal colour, as short trainings end: a third of that.
        let small = ColourDegrees {
            spatial: 1,
            temporal: 0,
        };
        assert_eq!(WebHeader::texels_for(small) * 16, 64);
    }

    #[test]
    fn damaged_headers_are_errors_not_panics() {
        let model = moving_model();
        let bytes = encode(&model, [0.0, 1.0], 0.0).bytes;
        assert!(
            decode(&bytes[..bytes.len() - 100])
                .unwrap_err()
                .contains("truncated")
        );
        assert!(decode(b"4DGSWEB0").unwrap_err().contains("4DGSWEB1"));
        let mut huge = bytes.clone();
        huge[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(decode(&huge).unwrap_err().contains("implausible"));
    }
}
