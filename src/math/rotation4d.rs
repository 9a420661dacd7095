//! 4D rotation from two quaternions, `R = Ml(ql) · Mr(qr)`, forward and
//! backward. Inputs are raw (unnormalised) quaternions; normalisation is part of the stage.
//!
//! Convention: `Ml·Mr` acts on quaternion coordinates `(1, i, j, k)`, which we identify
//! with `(t, x, y, z)`; so `R[a][b] = (Ml·Mr)[(a+1)%4][(b+1)%4]` in our `(x, y, z, t)` order.
//! With it, `ql = qr = q` is exactly the 3D rotation of unit quaternion `q = (w, x, y, z)`
//! (as in 3DGS PLY files), leaving time alone; `(1,0,0,0)` twice is the identity.

use crate::math::numerics::{Real, normalise_quat, normalise_quat_backward};

/// A 4×4 matrix, row-major.
pub type Mat4<F> = [[F; 4]; 4];

// (component index, sign) of each entry of Ml and Mr.
const ML: [[(usize, i8); 4]; 4] = [
    [(0, 1), (1, -1), (2, -1), (3, -1)],
    [(1, 1), (0, 1), (3, -1), (2, 1)],
    [(2, 1), (3, 1), (0, 1), (1, -1)],
    [(3, 1), (2, -1), (1, 1), (0, 1)],
];
const MR: [[(usize, i8); 4]; 4] = [
    [(0, 1), (1, 1), (2, 1), (3, 1)],
    [(1, -1), (0, 1), (3, -1), (2, 1)],
    [(2, -1), (3, 1), (0, 1), (1, -1)],
    [(3, -1), (2, -1), (1, 1), (0, 1)],
];

fn build<F: Real>(table: &[[(usize, i8); 4]; 4], q: [F; 4]) -> Mat4<F> {
    let mut m = [[F::zero(); 4]; 4];
    for i in 0..4 {
        for j in 0..4 {
            let (k, s) = table[i][j];
            m[i][j] = if s > 0 { q[k] } else { -q[k] };
        }
    }
    m
}

fn unbuild<F: Real>(table: &[[(usize, i8); 4]; 4], dm: &Mat4<F>) -> [F; 4] {
    let mut dq = [F::zero(); 4];
    for i in 0..4 {
        for j in 0..4 {
            let (k, s) = table[i][j];
            if s > 0 {
                dq[k] += dm[i][j];
            } else {
                dq[k] -= dm[i][j];
            }
        }
    }
    dq
}

/// `a · b` for 4×4 matrices.
#[inline]
pub fn mat4_mul<F: Real>(a: &Mat4<F>, b: &Mat4<F>) -> Mat4<F> {
    let mut m = [[F::zero(); 4]; 4];
    for i in 0..4 {
        for j in 0..4 {
            m[i][j] = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j] + a[i][3] * b[3][j];
        }
    }
    m
}

fn transpose<F: Real>(a: &Mat4<F>) -> Mat4<F> {
    let mut m = [[F::zero(); 4]; 4];
    for i in 0..4 {
        for j in 0..4 {
            m[i][j] = a[j][i];
        }
    }
    m
}

/// Intermediate values of [`rotation`] needed by its backward.
#[derive(Clone, Copy, Debug)]
pub struct RotationAux<F> {
    pub left: [F; 4],
    pub left_norm: F,
    pub right: [F; 4],
    pub right_norm: F,
}

/// The 4D rotation `Ml(ql/|ql|) · Mr(qr/|qr|)`. Zero quaternions act as the identity.
#[inline]
pub fn rotation<F: Real>(ql: [F; 4], qr: [F; 4]) -> (Mat4<F>, RotationAux<F>) {
    let (left, left_norm) = normalise_quat(ql);
    let (right, right_norm) = normalise_quat(qr);
    let m = mat4_mul(&build(&ML, left), &build(&MR, right));
    let mut r = [[F::zero(); 4]; 4];
    for a in 0..4 {
        for b in 0..4 {
            r[a][b] = m[(a + 1) % 4][(b + 1) % 4];
        }
    }
    (
        r,
        RotationAux {
            left,
            left_norm,
            right,
            right_norm,
        },
    )
}

/// Backward of [`rotation`]: dL/dR → (dL/dql, dL/dqr).
pub fn rotation_backward<F: Real>(aux: &RotationAux<F>, d_r: &Mat4<F>) -> ([F; 4], [F; 4]) {
    let ml = build(&ML, aux.left);
    let mr = build(&MR, aux.right);
    let mut d_m = [[F::zero(); 4]; 4];
    for a in 0..4 {
        for b in 0..4 {
            d_m[(a + 1) % 4][(b + 1) % 4] = d_r[a][b];
        }
    }
    let d_ml = mat4_mul(&d_m, &transpose(&mr));
    let d_mr = mat4_mul(&transpose(&ml), &d_m);
    let d_left = unbuild(&ML, &d_ml);
    let d_right = unbuild(&MR, &d_mr);
    (
        normalise_quat_backward(aux.left, aux.left_norm, d_left),
        normalise_quat_backward(aux.right, aux.right_norm, d_right),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_is_orthonormal_and_identity_at_identity() {
        let (r, _) = rotation([0.3, -0.5, 0.2, 0.9f64], [1.1, 0.4, -0.3, 0.2]);
        let rrt = mat4_mul(&r, &transpose(&r));
        for i in 0..4 {
            for j in 0..4 {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((rrt[i][j] - want).abs() < 1e-12);
            }
        }
        let (id, _) = rotation([1.0f64, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]);
        assert_eq!(id[1][1], 1.0);
        assert_eq!(id[0][1], 0.0);
    }

    #[test]
    fn equal_quaternions_give_the_3d_rotation_and_keep_time() {
        let q = [0.9f64, 0.2, -0.3, 0.25];
        let n = (q.iter().map(|x| x * x).sum::<f64>()).sqrt();
        let [w, x, y, z] = q.map(|v| v / n);
        let r3 = [
            [
                1.0 - 2.0 * (y * y + z * z),
                2.0 * (x * y - w * z),
                2.0 * (x * z + w * y),
            ],
            [
                2.0 * (x * y + w * z),
                1.0 - 2.0 * (x * x + z * z),
                2.0 * (y * z - w * x),
            ],
            [
                2.0 * (x * z - w * y),
                2.0 * (y * z + w * x),
                1.0 - 2.0 * (x * x + y * y),
            ],
        ];
        let (r, _) = rotation(q, q);
        for a in 0..3 {
            for b in 0..3 {
                assert!(
                    (r[a][b] - r3[a][b]).abs() < 1e-12,
                    "{a}{b}: {} vs {}",
                    r[a][b],
                    r3[a][b]
                );
            }
            assert!(r[a][3].abs() < 1e-12 && r[3][a].abs() < 1e-12);
        }
        assert!((r[3][3] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn rotation_gradient_matches_finite_differences() {
        let ql = [0.3, -0.5, 0.2, 0.9f64];
        let qr = [1.1, 0.4, -0.3, 0.2];
        let w: Mat4<f64> = [
            [0.1, -0.2, 0.3, 0.4],
            [0.5, 0.6, -0.7, 0.8],
            [0.9, -1.0, 1.1, 0.2],
            [-0.3, 0.4, 0.5, 0.6],
        ];
        let f = |ql, qr| {
            let (r, _) = rotation(ql, qr);
            (0..16)
                .map(|k| r[k / 4][k % 4] * w[k / 4][k % 4])
                .sum::<f64>()
        };
        let (_, aux) = rotation(ql, qr);
        let (gl, gr) = rotation_backward(&aux, &w);
        for i in 0..4 {
            let h = 1e-6;
            let (mut a, mut b) = (ql, ql);
            a[i] += h;
            b[i] -= h;
            assert!(((f(a, qr) - f(b, qr)) / (2.0 * h) - gl[i]).abs() < 1e-8);
            let (mut a, mut b) = (qr, qr);
            a[i] += h;
            b[i] -= h;
            assert!(((f(ql, a) - f(ql, b)) / (2.0 * h) - gr[i]).abs() < 1e-8);
        }
    }
}
