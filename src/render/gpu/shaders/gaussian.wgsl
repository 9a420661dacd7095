// Per-Gaussian constants and guards shared by `preprocess` and `preprocess_backward`, as
// in src/math/numerics.rs and the stage modules of src/math.

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
