// The decay's write-back after the Gaussians' Adam step (`DecayHooks::after_step`,
// `variants::decayed_logit`): o ← o·d for Gaussians visible in some view of the batch, with
// d the variant's factor (τ of f_θ, the constant, or `pow`/`exp` of the current opacity),
// o ← o·β for the rest, in logit space; and the step's statistics (visible count, smallest,
// largest and summed factor), reduced per workgroup and then in a fixed order.

struct Apply {
    count: u32,
    groups: u32,
    // 0: neural (τ), 1: constant, 2: pow, 3: exp.
    variant: u32,
    pad0: u32,
    beta: f32,
    one_minus_beta: f32,
    ln_beta: f32,
    constant: f32,
    f_min: f32,
    f_max: f32,
    pow_gamma: f32,
    exp_kappa: f32,
}

const LOGIT_FLOOR: f32 = -30.0;
const BIG: f32 = 3.0e38;

@group(0) @binding(0) var<uniform> A: Apply;
// The trained parameters, 20 floats per Gaussian (opacity logit at 20·i + 16).
@group(0) @binding(1) var<storage, read_write> params: array<f32>;
@group(0) @binding(2) var<storage, read> tau: array<f32>;
@group(0) @binding(3) var<storage, read> seen: array<u32>;
// Four words per workgroup: visible count, min, max, sum (floats as bits).
@group(0) @binding(4) var<storage, read_write> partials: array<u32>;
@group(0) @binding(5) var<storage, read_write> summary: array<u32>;

var<workgroup> r_count: array<u32, 256>;
var<workgroup> r_min: array<f32, 256>;
var<workgroup> r_max: array<f32, 256>;
var<workgroup> r_sum: array<f32, 256>;

// log(1 + u), accurate for small u.
fn log1p_(u: f32) -> f32 {
    let w = 1.0 + u;
    if w == 1.0 {
        return u;
    }
    return log(w) * u / (w - 1.0);
}

// logit(sigmoid(x)·d) = x + ln d − ln(1 + (1 − d)·eˣ), never above x, never below the floor
// (unless x already is), non-finite x and d ≥ 1 unchanged.
fn decayed_logit(x: f32, d: f32, one_minus_d: f32, ln_d: f32) -> f32 {
    if !is_finite(x) || !(d < 1.0) {
        return x;
    }
    var y: f32;
    if x > 0.0 {
        y = ln_d - log(exp(-x) + one_minus_d);
    } else {
        y = x + ln_d - log1p_(one_minus_d * exp(x));
    }
    y = max(y, min(LOGIT_FLOOR, x));
    return min(y, x);
}

// The opacity of logit x in [0, 1] (0 for NaN, as the sign says for ±∞).
fn opacity(x: f32) -> f32 {
    if !is_finite(x) {
        return select(0.0, 1.0, x > 0.0);
    }
    if x >= 0.0 {
        return 1.0 / (1.0 + exp(-x));
    }
    let e = exp(x);
    return e / (1.0 + e);
}

// The factor of a Gaussian seen in the batch (`DecayHooks::variant_factor`).
fn seen_factor(i: u32, x: f32) -> f32 {
    switch A.variant {
        case 1u: {
            return A.constant;
        }
        case 2u: {
            return A.f_min + (A.f_max - A.f_min) * pow(max(opacity(x), 1e-30), A.pow_gamma);
        }
        case 3u: {
            return A.f_max - (A.f_max - A.f_min) * exp(-opacity(x) / A.exp_kappa);
        }
        default: {
            return tau[i];
        }
    }
}

fn reduce(lid: u32) {
    workgroupBarrier();
    for (var s = 128u; s > 0u; s = s >> 1u) {
        if lid < s {
            r_count[lid] = r_count[lid] + r_count[lid + s];
            r_min[lid] = min(r_min[lid], r_min[lid + s]);
            r_max[lid] = max(r_max[lid], r_max[lid + s]);
            r_sum[lid] = r_sum[lid] + r_sum[lid + s];
        }
        workgroupBarrier();
    }
}

@compute @workgroup_size(256)
fn decay_apply(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let g = wid.x + wid.y * nwg.x;
    let i = g * WG + lid;
    var count = 0u;
    var lo = BIG;
    var hi = 0.0;
    var sum = 0.0;
    if i < A.count {
        var d = A.beta;
        var omd = A.one_minus_beta;
        var ln_d = A.ln_beta;
        let at = 20u * i + 16u;
        if seen[i] != 0u {
            d = seen_factor(i, params[at]);
            omd = 1.0 - d;
            ln_d = log1p_(-omd);
            count = 1u;
        }
        lo = d;
        hi = d;
        sum = d;
        params[at] = decayed_logit(params[at], d, omd, ln_d);
    }
    r_count[lid] = count;
    r_min[lid] = lo;
    r_max[lid] = hi;
    r_sum[lid] = sum;
    reduce(lid);
    if lid == 0u && g < A.groups {
        partials[4u * g] = r_count[0];
        partials[4u * g + 1u] = bitcast<u32>(r_min[0]);
        partials[4u * g + 2u] = bitcast<u32>(r_max[0]);
        partials[4u * g + 3u] = bitcast<u32>(r_sum[0]);
    }
}

// One workgroup: the partials in a fixed order into summary[0..4].
@compute @workgroup_size(256)
fn decay_summary(@builtin(local_invocation_index) lid: u32) {
    var count = 0u;
    var lo = BIG;
    var hi = 0.0;
    var sum = 0.0;
    for (var g = lid; g < A.groups; g += WG) {
        count += partials[4u * g];
        lo = min(lo, bitcast<f32>(partials[4u * g + 1u]));
        hi = max(hi, bitcast<f32>(partials[4u * g + 2u]));
        sum += bitcast<f32>(partials[4u * g + 3u]);
    }
    r_count[lid] = count;
    r_min[lid] = lo;
    r_max[lid] = hi;
    r_sum[lid] = sum;
    reduce(lid);
    if lid == 0u {
        summary[0] = r_count[0];
        summary[1] = bitcast<u32>(r_min[0]);
        summary[2] = bitcast<u32>(r_max[0]);
        summary[3] = bitcast<u32>(r_sum[0]);
    }
}
