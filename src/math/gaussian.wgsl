// The per-Gaussian math of this module in WGSL: the constants and guards of numerics.rs
// and the stage modules, and the time slice. Prepended (`math::GAUSSIAN_WGSL`) to the
// kernels that evaluate a Gaussian: the renderer's `preprocess` and its backward, and the
// decay's kernels.

const TEMPORAL_CUTOFF: f32 = 0.05;
const MIN_TIME_VARIANCE: f32 = 1e-30;
const LOG_SCALE_MIN: f32 = -18.0;
const LOG_SCALE_MAX: f32 = 12.0;
const MIN_QUAT_NORM: f32 = 1e-12;
const ALPHA_MIN: f32 = 0.003921569; // 1/255
const LOW_PASS: f32 = 0.3;
const EXTENT_SIGMAS: f32 = 3.0;
const GUARD_BAND: f32 = 0.15;
const PI: f32 = 3.14159265358979;

const SH_C0: f32 = 0.28209479177387814;
const SH_C1: f32 = 0.4886025119029199;
const SH_C2_0: f32 = 1.0925484305920792;
const SH_C2_2: f32 = 0.31539156525252005;
const SH_C2_4: f32 = 0.5462742152960396;
const SH_C3_0: f32 = -0.5900435899266435;
const SH_C3_1: f32 = 2.890611442640554;
const SH_C3_2: f32 = -0.4570457994644658;
const SH_C3_3: f32 = 0.3731763325901154;
const SH_C3_5: f32 = 1.445305721320277;

fn is_nan(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7fffffffu) > 0x7f800000u;
}

fn is_finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

fn unit_quat(q: vec4<f32>) -> vec4<f32> {
    let n = sqrt(dot(q, q));
    if !(n > MIN_QUAT_NORM) || !is_finite(n) {
        return vec4<f32>(1.0, 0.0, 0.0, 0.0);
    }
    return q * (1.0 / n);
}

fn scale_from_log(v: f32) -> f32 {
    if is_nan(v) {
        return 1.0;
    }
    return exp(clamp(v, LOG_SCALE_MIN, LOG_SCALE_MAX));
}

fn sigmoid(x: f32) -> f32 {
    if x >= 0.0 {
        return 1.0 / (1.0 + exp(-x));
    }
    let e = exp(x);
    return e / (1.0 + e);
}

// A Gaussian sliced at time t: its covariance factor L = R·S (rows x, y, z, t; the 4D
// rotation R = Ml(ql)·Mr(qr) reindexed from (1, i, j, k) to (x, y, z, t)), the floored
// temporal variance Σ_tt, t − μ_t, the temporal weight ω and Σ_(xyz)t. Shared by
// `preprocess` and the decay's visibility test, so both slice alike.
struct Slice {
    l0: vec4<f32>,
    l1: vec4<f32>,
    l2: vec4<f32>,
    lt: vec4<f32>,
    s44: f32,
    dt: f32,
    omega: f32,
    v: vec3<f32>,
}

fn slice_at(mean: vec4<f32>, log_scales: vec4<f32>, ql: vec4<f32>, qr: vec4<f32>, t: f32) -> Slice {
    let mr0 = vec4<f32>(qr.x, qr.y, qr.z, qr.w);
    let mr1 = vec4<f32>(-qr.y, qr.x, -qr.w, qr.z);
    let mr2 = vec4<f32>(-qr.z, qr.w, qr.x, -qr.y);
    let mr3 = vec4<f32>(-qr.w, -qr.z, qr.y, qr.x);
    let m0 = ql.x * mr0 - ql.y * mr1 - ql.z * mr2 - ql.w * mr3;
    let m1 = ql.y * mr0 + ql.x * mr1 - ql.w * mr2 + ql.z * mr3;
    let m2 = ql.z * mr0 + ql.w * mr1 + ql.x * mr2 - ql.y * mr3;
    let m3 = ql.w * mr0 - ql.z * mr1 + ql.y * mr2 + ql.x * mr3;
    let scale = vec4<f32>(
        scale_from_log(log_scales.x),
        scale_from_log(log_scales.y),
        scale_from_log(log_scales.z),
        scale_from_log(log_scales.w),
    );
    // L = R·S, rows x, y, z, t.
    let l0 = m1.yzwx * scale;
    let l1 = m2.yzwx * scale;
    let l2 = m3.yzwx * scale;
    let lt = m0.yzwx * scale;
    // Condition on time.
    let raw44 = dot(lt, lt);
    var s44 = MIN_TIME_VARIANCE;
    if raw44 > MIN_TIME_VARIANCE {
        s44 = raw44;
    }
    let dt = t - mean.w;
    let omega = exp(-0.5 * dt * dt / s44);
    let v = vec3<f32>(dot(l0, lt), dot(l1, lt), dot(l2, lt));
    return Slice(l0, l1, l2, lt, s44, dt, omega, v);
}
