//! EWA projection of a sliced 3D Gaussian through a pinhole camera:
//! 2D mean, inverse 2D covariance (conic) with the 0.3 px² low-pass, depth, and the 3σ
//! extent; forward and backward. Cameras come in as [`PinholeCamera`] (no distortion).

use crate::math::numerics::Real;

/// Low-pass added to the 2D covariance diagonal (px²).
pub const LOW_PASS: f64 = 0.3;
/// The footprint is truncated at this many standard deviations.
pub const EXTENT_SIGMAS: f64 = 3.0;
/// `x/z` and `y/z` are clamped to the image extended by this fraction on each side
/// before building the projection Jacobian (as in 3DGS), which keeps Gaussians near the
/// near plane or far off-screen from exploding.
pub const JACOBIAN_GUARD_BAND: f64 = 0.15;

/// A pinhole camera in the renderer's float type: `x_cam = W·x + tr`, pixels
/// `(fx x/z + cx, fy y/z + cy)`, pixel centres at integer + 0.5.
#[derive(Clone, Copy, Debug)]
pub struct PinholeCamera<F> {
    pub rotation: [[F; 3]; 3],
    pub translation: [F; 3],
    pub centre: [F; 3],
    pub fx: F,
    pub fy: F,
    pub cx: F,
    pub cy: F,
    pub width: u32,
    pub height: u32,
    /// Gaussians whose sliced mean has camera depth below this are culled.
    pub near: F,
}

impl<F: Real> PinholeCamera<F> {
    /// From the shared camera type (its distortion is ignored here; `render` rejects
    /// distorted cameras before calling this).
    pub fn from_camera(camera: &crate::Camera, near: F) -> Self {
        let w = &camera.world_to_camera;
        let c = w.centre();
        let i = &camera.intrinsics;
        Self {
            rotation: w.rotation.map(|r| r.map(F::c)),
            translation: w.translation.map(F::c),
            centre: [F::c(c.x), F::c(c.y), F::c(c.z)],
            fx: F::c(i.fx),
            fy: F::c(i.fy),
            cx: F::c(i.cx),
            cy: F::c(i.cy),
            width: i.width,
            height: i.height,
            near,
        }
    }

    /// World point to camera coordinates.
    #[inline]
    pub fn to_camera(&self, p: [F; 3]) -> [F; 3] {
        let w = &self.rotation;
        let mut out = self.translation;
        for i in 0..3 {
            out[i] += w[i][0] * p[0] + w[i][1] * p[1] + w[i][2] * p[2];
        }
        out
    }

    /// Pixel position of a camera-space point in front of the camera (pinhole projection,
    /// pixel centres at integer + 0.5).
    #[inline]
    pub fn to_pixel(&self, p: [F; 3]) -> [F; 2] {
        let iz = F::one() / p[2];
        [self.fx * p[0] * iz + self.cx, self.fy * p[1] * iz + self.cy]
    }
}

/// A projected Gaussian.
#[derive(Clone, Copy, Debug, Default)]
pub struct Projected<F> {
    /// Pixel coordinates of the mean.
    pub mean: [F; 2],
    /// Inverse 2D covariance `(a, b, c)`: `power = −½(a dx² + c dy²) − b dx dy`.
    pub conic: [F; 3],
    /// Camera-space depth of the mean.
    pub depth: F,
    /// Half-widths of the 3σ box in pixels.
    pub extent: [F; 2],
}

/// Forward intermediates for [`project_backward`].
#[derive(Clone, Copy, Debug)]
pub struct ProjectAux<F> {
    p: [F; 3],
    u_free: [bool; 2],
    m: [[F; 3]; 2],
    k: [[F; 4]; 2],
    conic: [F; 3],
}

/// Project a Gaussian with mean `mean` and covariance `B Bᵀ`; `None` if it is behind the
/// near plane or numerically degenerate.
#[inline]
pub fn project<F: Real>(
    cam: &PinholeCamera<F>,
    mean: [F; 3],
    factor: &[[F; 4]; 3],
) -> Option<(Projected<F>, ProjectAux<F>)> {
    let p = cam.to_camera(mean);
    let z = p[2];
    if !(z >= cam.near) || !p[0].is_finite() || !p[1].is_finite() || !z.is_finite() {
        return None;
    }
    let gb = F::c(JACOBIAN_GUARD_BAND);
    let (w, h) = (F::c(cam.width as f64), F::c(cam.height as f64));
    let lim = [
        (
            (-gb * w - cam.cx) / cam.fx,
            ((F::one() + gb) * w - cam.cx) / cam.fx,
        ),
        (
            (-gb * h - cam.cy) / cam.fy,
            ((F::one() + gb) * h - cam.cy) / cam.fy,
        ),
    ];
    let mut u = [p[0] / z, p[1] / z];
    let mut u_free = [true; 2];
    for a in 0..2 {
        if u[a] < lim[a].0 {
            u[a] = lim[a].0;
            u_free[a] = false;
        } else if u[a] > lim[a].1 {
            u[a] = lim[a].1;
            u_free[a] = false;
        }
    }
    let iz = F::one() / z;
    let f = [cam.fx, cam.fy];
    let wr = &cam.rotation;
    let mut m = [[F::zero(); 3]; 2];
    for a in 0..2 {
        // Row a of J is (fa/z) e_a − (fa u_a / z) e_z.
        for c in 0..3 {
            m[a][c] = f[a] * iz * (wr[a][c] - u[a] * wr[2][c]);
        }
    }
    let mut k = [[F::zero(); 4]; 2];
    for a in 0..2 {
        for q in 0..4 {
            k[a][q] = m[a][0] * factor[0][q] + m[a][1] * factor[1][q] + m[a][2] * factor[2][q];
        }
    }
    let dot = |x: &[F; 4], y: &[F; 4]| x[0] * y[0] + x[1] * y[1] + x[2] * y[2] + x[3] * y[3];
    let lp = F::c(LOW_PASS);
    let ca = dot(&k[0], &k[0]) + lp;
    let cb = dot(&k[0], &k[1]);
    let cc = dot(&k[1], &k[1]) + lp;
    let det = ca * cc - cb * cb;
    if !(det > F::zero()) || !det.is_finite() {
        return None;
    }
    let inv = F::one() / det;
    let conic = [cc * inv, -cb * inv, ca * inv];
    let s = F::c(EXTENT_SIGMAS);
    let out = Projected {
        mean: cam.to_pixel(p),
        conic,
        depth: z,
        extent: [s * ca.sqrt(), s * cc.sqrt()],
    };
    Some((
        out,
        ProjectAux {
            p,
            u_free,
            m,
            k,
            conic,
        },
    ))
}

/// Backward of [`project`]: from dL/d(mean2d, conic, depth) to dL/d(mean3, B), where
/// `factor` is the `B` that was projected.
pub fn project_backward<F: Real>(
    cam: &PinholeCamera<F>,
    aux: &ProjectAux<F>,
    factor: &[[F; 4]; 3],
    d_mean2d: [F; 2],
    d_conic: [F; 3],
    d_depth: F,
) -> ([F; 3], [[F; 4]; 3]) {
    let half = F::c(0.5);
    // dΣ2 = −Q dQ Q with dQ = [[da, db/2], [db/2, dc]].
    let [qa, qb, qc] = aux.conic;
    let dq = [
        [d_conic[0], half * d_conic[1]],
        [half * d_conic[1], d_conic[2]],
    ];
    let q = [[qa, qb], [qb, qc]];
    let mut t = [[F::zero(); 2]; 2];
    for i in 0..2 {
        for j in 0..2 {
            t[i][j] = q[i][0] * dq[0][j] + q[i][1] * dq[1][j];
        }
    }
    let mut g = [[F::zero(); 2]; 2];
    for i in 0..2 {
        for j in 0..2 {
            g[i][j] = -(t[i][0] * q[0][j] + t[i][1] * q[1][j]);
        }
    }
    // Σ2 = K Kᵀ (+ low-pass): dK = (G + Gᵀ) K.
    let mut dk = [[F::zero(); 4]; 2];
    for a in 0..2 {
        for c in 0..4 {
            dk[a][c] = (g[a][0] + g[0][a]) * aux.k[0][c] + (g[a][1] + g[1][a]) * aux.k[1][c];
        }
    }
    // K = M B: dB = Mᵀ dK, dM = dK Bᵀ.
    let mut d_b = [[F::zero(); 4]; 3];
    let mut dm = [[F::zero(); 3]; 2];
    for r in 0..3 {
        for c in 0..4 {
            d_b[r][c] = aux.m[0][r] * dk[0][c] + aux.m[1][r] * dk[1][c];
        }
        for a in 0..2 {
            dm[a][r] = dk[a][0] * factor[r][0]
                + dk[a][1] * factor[r][1]
                + dk[a][2] * factor[r][2]
                + dk[a][3] * factor[r][3];
        }
    }
    // M[a][c] = f_a/z (W[a][c] − u_a W[2][c]).
    let p = aux.p;
    let z = p[2];
    let iz = F::one() / z;
    let f = [cam.fx, cam.fy];
    let wr = &cam.rotation;
    let mut dp = [F::zero(); 3];
    for a in 0..2 {
        let mut du = F::zero();
        for c in 0..3 {
            dp[2] -= dm[a][c] * aux.m[a][c] * iz;
            du -= dm[a][c] * f[a] * iz * wr[2][c];
        }
        if aux.u_free[a] {
            dp[a] += du * iz;
            dp[2] -= du * p[a] * iz * iz;
        }
        // 2D mean.
        dp[a] += f[a] * iz * d_mean2d[a];
        dp[2] -= f[a] * p[a] * iz * iz * d_mean2d[a];
    }
    dp[2] += d_depth;
    let mut d_mean = [F::zero(); 3];
    for c in 0..3 {
        d_mean[c] = wr[0][c] * dp[0] + wr[1][c] * dp[1] + wr[2][c] * dp[2];
    }
    (d_mean, d_b)
}
