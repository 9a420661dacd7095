//! Motion at init. Moving points come from point maps at a few moments of the clip, each
//! seen once; between two moments such a point fades while the object moves on. Here each
//! moving point gets a velocity from its nearest moving points at the previous and next
//! moment, and starts as a 4D Gaussian that moves with it: `Σ_xt = σ_t²·v`, which leaves
//! the sliced 3D covariance as given and moves the sliced mean as `μ + v·(t − μ_t)`.

use crate::math::rotation4d::{Mat4, rotation};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix3, Matrix4, SymmetricEigen};
use std::num::NonZero;

/// Neighbours at the same moment whose raw velocities are combined (component-wise
/// median) into a point's velocity: one nearest-neighbour match is noisy.
const SMOOTHING: usize = 8;
/// A match farther than this many times the median match distance between the two moments
/// is taken as no match (the object left the view, or another appeared).
const MATCH_GATE: f32 = 3.0;

/// The moments of a cloud's moving points (`span` 0), each the indices of its points in
/// time order: their times form clusters (one per point-map or swept moment, each spread by
/// the cameras' sub-frame offsets); a gap over a third of the largest one, and over
/// `min_gap`, starts the next.
pub fn moments(time: &[f32], span: &[f32], min_gap: f32) -> Vec<Vec<usize>> {
    let mut moving: Vec<usize> = (0..time.len().min(span.len()))
        .filter(|&i| span[i] == 0.0)
        .collect();
    moving.sort_by(|&a, &b| time[a].total_cmp(&time[b]));
    let largest_gap = moving
        .windows(2)
        .map(|w| time[w[1]] - time[w[0]])
        .fold(0.0f32, f32::max);
    let mut moments: Vec<Vec<usize>> = Vec::new();
    let mut last = f32::NEG_INFINITY;
    for i in moving {
        match moments.last_mut() {
            Some(ids) if time[i] - last <= (largest_gap / 3.0).max(min_gap) => ids.push(i),
            _ => moments.push(vec![i]),
        }
        last = time[i];
    }
    moments
}

/// The median time between consecutive [`moments`] (by their points' mean times); `None`
/// with fewer than two moments.
pub fn moment_spacing(time: &[f32], span: &[f32], min_gap: f32) -> Option<f32> {
    let centres: Vec<f32> = moments(time, span, min_gap)
        .iter()
        .map(|ids| ids.iter().map(|&i| time[i]).sum::<f32>() / ids.len() as f32)
        .collect();
    let mut gaps: Vec<f32> = centres.windows(2).map(|w| w[1] - w[0]).collect();
    if gaps.is_empty() {
        return None;
    }
    gaps.sort_by(f32::total_cmp);
    Some(gaps[gaps.len() / 2])
}

/// Velocity (model units per model time) of each point of `xyz` seen at one moment:
/// points with `span` 0 at `time`; `None` for static points (span > 0) and where no moment
/// before or after it has a match. Moments less than `min_gap` apart are one. Needs at
/// least two moments.
pub fn moment_velocities(
    xyz: &[[f32; 3]],
    time: &[f32],
    span: &[f32],
    min_gap: f32,
) -> Vec<Option<[f32; 3]>> {
    let n = xyz.len();
    let mut out = vec![None; n];
    let moments = moments(time, span, min_gap);
    if moments.len() < 2 {
        return out;
    }
    let trees: Vec<ImmutableKdTree<f32, 3>> = moments
        .iter()
        .map(|ids| {
            let pts: Vec<[f32; 3]> = ids.iter().map(|&i| xyz[i]).collect();
            ImmutableKdTree::new_from_slice(&pts)
        })
        .collect();
    // Nearest point of moment `m` to `p`: its index and distance.
    let nearest = |m: usize, p: &[f32; 3]| {
        let nn = trees[m].nearest_one::<SquaredEuclidean>(p);
        (moments[m][nn.item as usize], nn.distance.sqrt())
    };
    for m in 0..moments.len() {
        let ids = &moments[m];
        // Matches in the previous and next moment, gated by their median distance.
        let side = |other: Option<usize>| -> Vec<Option<usize>> {
            let Some(o) = other else {
                return vec![None; ids.len()];
            };
            let found: Vec<(usize, f32)> = ids.iter().map(|&i| nearest(o, &xyz[i])).collect();
            let mut d: Vec<f32> = found.iter().map(|f| f.1).collect();
            d.sort_by(f32::total_cmp);
            let gate = MATCH_GATE * d[d.len() / 2];
            found
                .into_iter()
                .map(|(j, dist)| (dist <= gate).then_some(j))
                .collect()
        };
        let before = side(m.checked_sub(1));
        let after = side((m + 1 < moments.len()).then_some(m + 1));
        let raw: Vec<Option<[f32; 3]>> = ids
            .iter()
            .enumerate()
            .map(|(k, &i)| {
                let (from, to) = match (before[k], after[k]) {
                    (Some(a), Some(b)) => (a, b),
                    (Some(a), None) => (a, i),
                    (None, Some(b)) => (i, b),
                    (None, None) => return None,
                };
                let dt = time[to] - time[from];
                let d: [f32; 3] = std::array::from_fn(|c| xyz[to][c] - xyz[from][c]);
                (dt > 0.0).then(|| d.map(|c| c / dt))
            })
            .collect();
        // Component-wise median over the nearest points of the same moment.
        let want = NonZero::new(SMOOTHING.min(ids.len())).unwrap_or(NonZero::<usize>::MIN);
        for (k, &i) in ids.iter().enumerate() {
            if raw[k].is_none() {
                continue;
            }
            let near: Vec<[f32; 3]> = trees[m]
                .nearest_n::<SquaredEuclidean>(&xyz[i], want)
                .iter()
                .filter_map(|nn| raw[nn.item as usize])
                .collect();
            out[i] = Some(std::array::from_fn(|c| {
                let mut v: Vec<f32> = near.iter().map(|r| r[c]).collect();
                v.sort_by(f32::total_cmp);
                v[v.len() / 2]
            }));
        }
    }
    out
}

/// The 4D Gaussian (log-scales, left and right rotation quaternions) whose slice at any
/// time has the 3D covariance `R(q3)·diag(exp(2·log_s3))·R(q3)ᵀ`, whose temporal standard
/// deviation is `exp(log_sigma_t)`, and whose sliced mean moves with `velocity`.
pub fn moving_gaussian(
    log_s3: [f32; 3],
    q3: [f32; 4],
    log_sigma_t: f32,
    velocity: [f32; 3],
) -> ([f32; 4], [f32; 4], [f32; 4]) {
    let q = q3.map(f64::from);
    let (r, _) = rotation(q, q);
    let r3 = Matrix3::from_fn(|i, j| r[i][j]);
    let s2 = Matrix3::from_diagonal(&nalgebra::Vector3::from_fn(|i, _| {
        (2.0 * log_s3[i] as f64).exp()
    }));
    let a = r3 * s2 * r3.transpose();
    let var_t = (2.0 * log_sigma_t as f64).exp();
    let v = nalgebra::Vector3::from_fn(|i, _| velocity[i] as f64);
    let mut cov = Matrix4::zeros();
    cov.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(a + v * v.transpose() * var_t));
    for i in 0..3 {
        cov[(i, 3)] = var_t * v[i];
        cov[(3, i)] = var_t * v[i];
    }
    cov[(3, 3)] = var_t;
    let eig = SymmetricEigen::new(cov);
    // The axis closest to time last (densification reads log_scales[3] as the temporal
    // scale), the others in order; a proper rotation (det +1).
    let t_axis = (0..4)
        .max_by(|&a, &b| {
            eig.eigenvectors[(3, a)]
                .abs()
                .total_cmp(&eig.eigenvectors[(3, b)].abs())
        })
        .unwrap_or(3);
    let order: Vec<usize> = (0..4).filter(|&c| c != t_axis).chain([t_axis]).collect();
    let mut rot: Mat4<f64> = [[0.0; 4]; 4];
    for (col, &c) in order.iter().enumerate() {
        for (row, r) in rot.iter_mut().enumerate() {
            r[col] = eig.eigenvectors[(row, c)];
        }
    }
    if Matrix4::from_fn(|i, j| rot[i][j]).determinant() < 0.0 {
        for r in rot.iter_mut() {
            r[0] = -r[0];
        }
    }
    let log_scales: [f32; 4] =
        std::array::from_fn(|k| (0.5 * eig.eigenvalues[order[k]].max(1e-30).ln()) as f32);
    let (ql, qr) = quaternions_of(&rot);
    (log_scales, ql.map(|x| x as f32), qr.map(|x| x as f32))
}

/// The unit quaternions `(ql, qr)` with `rotation(ql, qr) = r` for a 4D rotation `r`.
/// `r` is bilinear in the two quaternions over the 16 basis rotations `B_kl = rotation(e_k,
/// e_l)`, which are orthogonal with `⟨B_kl, B_mn⟩ = 4·δ_km·δ_ln`; so the coefficients
/// `M_kl = ⟨r, B_kl⟩ / 4` are `ql_k·qr_l`, a rank-one matrix read off its largest column.
pub fn quaternions_of(r: &Mat4<f64>) -> ([f64; 4], [f64; 4]) {
    let e = |k: usize| std::array::from_fn::<f64, 4, _>(|i| if i == k { 1.0 } else { 0.0 });
    let mut m = [[0.0; 4]; 4];
    for (k, row) in m.iter_mut().enumerate() {
        for (l, v) in row.iter_mut().enumerate() {
            let (b, _) = rotation(e(k), e(l));
            *v = (0..4)
                .flat_map(|i| (0..4).map(move |j| (i, j)))
                .map(|(i, j)| r[i][j] * b[i][j])
                .sum::<f64>()
                / 4.0;
        }
    }
    let norm = |c: usize| (0..4).map(|k| m[k][c] * m[k][c]).sum::<f64>().sqrt();
    let col = (0..4)
        .max_by(|&a, &b| norm(a).total_cmp(&norm(b)))
        .unwrap_or(0);
    let n = norm(col).max(1e-300);
    let ql: [f64; 4] = std::array::from_fn(|k| m[k][col] / n);
    let qr: [f64; 4] = std::array::from_fn(|l| (0..4).map(|k| ql[k] * m[k][l]).sum());
    let nr = qr.iter().map(|x| x * x).sum::<f64>().sqrt().max(1e-300);
    (ql, qr.map(|x| x / nr))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moment_spacing_is_the_median_gap_between_moment_centres() {
        // Three moments, each spread by sub-frame offsets, and a static point.
        let time = [0.0, 0.01, 0.5, 0.51, 1.0, 1.02, 0.7];
        let span = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
        let moments = moments(&time, &span, 0.02);
        assert_eq!(moments, vec![vec![0, 1], vec![2, 3], vec![4, 5]]);
        let gap = moment_spacing(&time, &span, 0.02).unwrap();
        assert!((gap - 0.505).abs() < 1e-6, "{gap}");
        // One moment: no spacing.
        assert_eq!(moment_spacing(&time[..2], &span[..2], 0.02), None);
    }
    use crate::math::slice::slice;

    fn unit(q: [f64; 4]) -> [f64; 4] {
        let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
        q.map(|x| x / n)
    }

    #[test]
    fn a_rotation_gives_back_its_quaternions() {
        for (ql, qr) in [
            ([1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]),
            ([0.3, -0.5, 0.7, 0.2], [0.9, 0.1, -0.3, 0.4]),
            ([0.0, 0.0, 0.0, 1.0], [0.1, 0.8, 0.2, -0.5]),
            ([-0.6, 0.2, 0.2, 0.7], [0.6, 0.2, 0.2, 0.7]),
        ] {
            let (r, _) = rotation(unit(ql), unit(qr));
            let (a, b) = quaternions_of(&r);
            let (back, _) = rotation(a, b);
            for i in 0..4 {
                for j in 0..4 {
                    assert!((back[i][j] - r[i][j]).abs() < 1e-12, "{back:?} vs {r:?}");
                }
            }
        }
    }

    #[test]
    fn a_moving_gaussian_keeps_its_slice_and_moves_its_mean() {
        let q3 = unit([0.9, 0.2, -0.3, 0.1]).map(|x| x as f32);
        let log_s3 = [0.02f32.ln(), 0.01f32.ln(), 0.002f32.ln()];
        let log_t = 0.05f32.ln();
        for v in [[0.0f32; 3], [0.8, -0.3, 0.1], [0.0, 0.0, 3.0]] {
            let (ls, ql, qr) = moving_gaussian(log_s3, q3, log_t, v);
            let mean = [0.5f32, -0.2, 1.0, 0.3];
            let (still, _) = {
                let q = q3.map(f64::from);
                let (ls, lt) = (log_s3.map(f64::from), log_t as f64);
                slice([0.0, 0.0, 0.0, 0.3], [ls[0], ls[1], ls[2], lt], q, q, 0.3).unwrap()
            };
            let cov = |b: &[[f64; 4]; 3]| -> [[f64; 3]; 3] {
                std::array::from_fn(|i| {
                    std::array::from_fn(|j| (0..4).map(|k| b[i][k] * b[j][k]).sum())
                })
            };
            let want = cov(&still.factor);
            for t in [0.3f32, 0.33, 0.25, 0.4] {
                let (s, _) = slice(
                    mean.map(f64::from),
                    ls.map(f64::from),
                    ql.map(f64::from),
                    qr.map(f64::from),
                    t as f64,
                )
                .unwrap();
                let dt = (t - mean[3]) as f64;
                for i in 0..3 {
                    let moved = mean[i] as f64 + v[i] as f64 * dt;
                    assert!((s.mean[i] - moved).abs() < 1e-5, "{:?} at {t}", s.mean);
                }
                let got = cov(&s.factor);
                for i in 0..3 {
                    for j in 0..3 {
                        assert!(
                            (got[i][j] - want[i][j]).abs() < 1e-6 * want[0][0].max(1e-12),
                            "{got:?} vs {want:?}"
                        );
                    }
                }
                // The temporal weight is that of σ_t = 0.05.
                let omega = (-0.5 * dt * dt / 0.0025).exp();
                assert!((s.omega - omega).abs() < 1e-5, "{} vs {omega}", s.omega);
            }
            assert!(ls.iter().all(|x| x.is_finite()));
        }
    }

    #[test]
    fn a_patch_moving_along_its_normal_gets_its_velocity_and_static_points_none() {
        // A jittered square patch in a plane, at moments 0, 0.2, 0.4 (each point up to 0.008
        // off its moment, as cameras' frames are), moving along its normal
        // at 0.5 (nearest points see the motion across a surface, not along it), and a
        // static wall seen over the whole clip.
        let n = glam::Vec3::new(0.3, -0.2, 1.0).normalize();
        let (u, w) = (n.any_orthonormal_pair().0, n.any_orthonormal_pair().1);
        let v = n * 0.5;
        let (mut xyz, mut time, mut span) = (Vec::new(), Vec::new(), Vec::new());
        for (m, t) in [0.0f32, 0.2, 0.4].into_iter().enumerate() {
            for i in 0..20 {
                for j in 0..20 {
                    let jitter = 0.004 * ((i * 7 + j * 3 + m * 5) % 5) as f32;
                    // Each camera's frames are a little off the moment.
                    let t = t + 0.004 * ((i + j) % 3) as f32;
                    let p = u * (i as f32 * 0.02 + jitter) + w * (j as f32 * 0.02) + v * t;
                    xyz.push(p.to_array());
                    time.push(t);
                    span.push(0.0);
                }
            }
        }
        for i in 0..100 {
            xyz.push([i as f32 * 0.01, 2.0, 0.0]);
            time.push(0.2);
            span.push(0.4);
        }
        let got = moment_velocities(&xyz, &time, &span, 0.02);
        assert!(got[1200..].iter().all(Option::is_none));
        for g in &got[..1200] {
            let g = glam::Vec3::from(g.expect("a moving point"));
            assert!((g - v).length() < 0.05, "{g} vs {v}");
        }
        // One moment only: nothing to match.
        assert!(
            moment_velocities(&xyz[..400], &time[..400], &span[..400], 0.02)
                .iter()
                .all(Option::is_none)
        );
    }
}
