// The Neural Decaying Function f_θ on the device (src/decay/mlp.rs, src/decay/inputs.rs):
// the inputs' z-scoring statistics over all Gaussians, the forward
// τ = f_min + (f_max − f_min)·sigmoid(f_θ(x)) per Gaussian, the weight gradient dL/dθ
// from dL/dτ (inputs detached) and f_θ's Adam with L2 weight decay.
//
// Every reduction has a fixed order (workgroup trees or rows in order, then the
// workgroups' partials in index order), and no float atomics: the results are the same on
// every run.

const MAX_W: u32 = 32u;        // widest layer (inputs included)
const ADAM_SLOTS: u32 = 12u;   // parameters per thread of mlp_outer and mlp_adam (≤ 3072)
const COLS: u32 = 8u;          // z-scored columns: mean (x, y, z, t), log-scales
const MIN_STD: f32 = 1e-6;
const BIAS: u32 = 0xffffffffu;

struct MlpParams {
    count: u32,
    in_width: u32,
    // Linear layers (hidden layers + 1).
    layers: u32,
    // 0: official inputs, 1: paper inputs.
    inputs: u32,
    // input_moments / input_stats: 0 sums, 1 squared deviations; mlp_adam: 0 gradient
    // only, 1 gradient and Adam step.
    pass_kind: u32,
    n_params: u32,
    // Workgroups of one pass over the Gaussians (256 rows each).
    groups: u32,
    // mlp_rows / mlp_outer: the first Gaussian of this chunk of rows.
    row_offset: u32,
    f_min: f32,
    f_max: f32,
    lr: f32,
    weight_decay: f32,
    beta1: f32,
    beta2: f32,
    one_minus_beta1: f32,
    one_minus_beta2: f32,
    bc1: f32,
    bc2: f32,
    epsilon: f32,
    pad1: f32,
    // Per row of `rows`: the layers' inputs (act_stride floats), then the deltas of their
    // outputs (del_stride floats); rows in this chunk.
    act_stride: u32,
    del_stride: u32,
    chunk_rows: u32,
    pad2: u32,
    // Layer widths, inputs first, 1 last.
    dims: array<vec4<u32>, 2>,
}

@group(0) @binding(0) var<uniform> M: MlpParams;
// The model as uploaded: five vec4 per Gaussian.
@group(0) @binding(1) var<storage, read> model: array<vec4<f32>>;
// f_θ's parameters, laid out as `Mlp::params`.
@group(0) @binding(2) var<storage, read_write> weights: array<f32>;
// Adam's first moments, then its second moments.
@group(0) @binding(3) var<storage, read_write> moments: array<f32>;
// Column means [0, 8), standard deviations [8, 16), then the reduced gradient, then
// (as bits) 1 when the last Adam step was skipped (a non-finite gradient).
@group(0) @binding(4) var<storage, read_write> stats: array<f32>;
// Per workgroup: column sums (8) or parameter gradients (n_params).
@group(0) @binding(5) var<storage, read_write> partials: array<f32>;
@group(0) @binding(6) var<storage, read_write> tau: array<f32>;
@group(0) @binding(7) var<storage, read_write> d_tau: array<f32>;
// One chunk of rows' layer inputs and output deltas (mlp_rows → mlp_outer).
@group(0) @binding(8) var<storage, read_write> rows: array<f32>;

var<workgroup> red: array<f32, 256>;
var<workgroup> bad: atomic<u32>;

fn dim(l: u32) -> u32 {
    return M.dims[l / 4u][l % 4u];
}

fn column(i: u32, k: u32) -> f32 {
    if k < 4u {
        return model[5u * i][k];
    }
    return model[5u * i + 1u][k - 4u];
}

fn zscore(i: u32, k: u32) -> f32 {
    return (column(i, k) - stats[k]) / stats[COLS + k];
}

// Relu that maps NaN to 0, like `f32::max(s, 0.0)` on the host.
fn relu(s: f32) -> f32 {
    return select(0.0, s, s > 0.0);
}

// Sum `red` over the workgroup (256 threads) into red[0].
fn tree_sum(lid: u32) {
    workgroupBarrier();
    for (var s = 128u; s > 0u; s = s >> 1u) {
        if lid < s {
            red[lid] = red[lid] + red[lid + s];
        }
        workgroupBarrier();
    }
}

// Column sums (pass 0) or squared deviations from the means (pass 1) of one workgroup's
// 256 Gaussians.
@compute @workgroup_size(256)
fn input_moments(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let g = wid.x + wid.y * nwg.x;
    let i = g * WG + lid;
    for (var k = 0u; k < COLS; k++) {
        var v = 0.0;
        if i < M.count {
            v = column(i, k);
            if M.pass_kind == 1u {
                let d = v - stats[k];
                v = d * d;
            }
        }
        red[lid] = v;
        tree_sum(lid);
        if lid == 0u && g < M.groups {
            partials[g * COLS + k] = red[0];
        }
        workgroupBarrier();
    }
}

// One workgroup: the partials in a fixed order → means (pass 0) or deviations (pass 1).
@compute @workgroup_size(256)
fn input_stats(@builtin(local_invocation_index) lid: u32) {
    for (var k = 0u; k < COLS; k++) {
        var s = 0.0;
        for (var g = lid; g < M.groups; g += WG) {
            s += partials[g * COLS + k];
        }
        red[lid] = s;
        tree_sum(lid);
        if lid == 0u {
            let n = f32(M.count);
            if M.pass_kind == 0u {
                stats[k] = select(0.0, red[0] / n, M.count > 0u);
            } else {
                stats[COLS + k] = select(1.0, max(sqrt(red[0] / n), MIN_STD), M.count > 0u);
            }
        }
        workgroupBarrier();
    }
}

// f_θ's input row of Gaussian i (`inputs::input_rows`).
fn input_row(i: u32) -> array<f32, 12> {
    var x: array<f32, 12>;
    let o = 2.0 * sigmoid(model[5u * i + 4u].x) - 1.0;
    if M.inputs == 0u {
        x[0] = o;
        for (var k = 0u; k < COLS; k++) {
            x[k + 1u] = zscore(i, k);
        }
    } else {
        for (var k = 0u; k < 3u; k++) {
            x[k] = zscore(i, k);
        }
        x[3] = o;
        let ql = unit_quat(model[5u * i + 2u]);
        let qr = unit_quat(model[5u * i + 3u]);
        for (var k = 0u; k < 4u; k++) {
            x[4u + k] = ql[k];
            x[8u + k] = qr[k];
        }
    }
    return x;
}

fn tau_of(z: f32) -> f32 {
    if is_nan(z) {
        return 0.5 * (M.f_min + M.f_max);
    }
    return M.f_min + (M.f_max - M.f_min) * sigmoid(z);
}

// No row of `rows` to store activations in (`forward_z`).
const NO_STORE: u32 = 0xffffffffu;

// f_θ's output before the sigmoid for Gaussian i. Unless `ab` is NO_STORE, each layer's
// input is kept at rows[ab + (sum of the earlier layers' widths)] for the backward.
fn forward_z(i: u32, ab: u32) -> f32 {
    let store = ab != NO_STORE;
    let x = input_row(i);
    var a: array<f32, MAX_W>;
    var b: array<f32, MAX_W>;
    for (var k = 0u; k < M.in_width; k++) {
        a[k] = x[k];
        if store {
            rows[ab + k] = x[k];
        }
    }
    var off = 0u;
    var aoff = 0u;
    var z = 0.0;
    for (var l = 0u; l < M.layers; l++) {
        let n_in = dim(l);
        let n_out = dim(l + 1u);
        let bo = off + n_out * n_in;
        for (var j = 0u; j < n_out; j++) {
            var s = weights[bo + j];
            for (var k = 0u; k < n_in; k++) {
                s += weights[off + j * n_in + k] * a[k];
            }
            if l + 1u == M.layers {
                z = s;
            } else {
                b[j] = relu(s);
                if store {
                    rows[ab + aoff + n_in + j] = b[j];
                }
            }
        }
        a = b;
        off = bo + n_out;
        aoff += n_in;
    }
    return z;
}

// τ of every Gaussian.
@compute @workgroup_size(256)
fn mlp_forward(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_index(wid, nwg, lid);
    if i >= M.count {
        return;
    }
    tau[i] = tau_of(forward_z(i, NO_STORE));
}

// Forward and backward of one row of the chunk (one thread each): the layers' inputs
// and the deltas of their outputs into `rows` (the deltas all zero when dL/dτ = 0).
@compute @workgroup_size(256)
fn mlp_rows(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let lr = flat_index(wid, nwg, lid);
    if lr >= M.chunk_rows {
        return;
    }
    let row = M.row_offset + lr;
    let ab = lr * (M.act_stride + M.del_stride);
    let db = ab + M.act_stride;
    let z = forward_z(row, ab);
    // The ends of the weights (`off`) and of the stored inputs (`aoff`).
    var off = 0u;
    var aoff = 0u;
    for (var l = 0u; l < M.layers; l++) {
        off += dim(l + 1u) * dim(l) + dim(l + 1u);
        aoff += dim(l);
    }
    let sg = sigmoid(z);
    let dz = d_tau[row] * ((M.f_max - M.f_min) * sg * (1.0 - sg));
    // Backward, last layer first: `off`, `aoff` and `doff` walk back.
    var delta: array<f32, MAX_W>;
    var next: array<f32, MAX_W>;
    delta[0] = dz;
    var doff = M.del_stride;
    for (var li = 0u; li < M.layers; li++) {
        let l = M.layers - 1u - li;
        let n_in = dim(l);
        let n_out = dim(l + 1u);
        off -= n_out * n_in + n_out;
        aoff -= n_in;
        doff -= n_out;
        for (var j = 0u; j < n_out; j++) {
            rows[db + doff + j] = delta[j];
        }
        if l == 0u {
            break;
        }
        for (var k = 0u; k < n_in; k++) {
            next[k] = 0.0;
        }
        for (var j = 0u; j < n_out; j++) {
            let dj = delta[j];
            if dj == 0.0 {
                continue;
            }
            for (var k = 0u; k < n_in; k++) {
                next[k] += dj * weights[off + j * n_in + k];
            }
        }
        for (var k = 0u; k < n_in; k++) {
            delta[k] = select(0.0, next[k], rows[ab + aoff + k] > 0.0);
        }
    }
}

// Where parameter p reads its row values: (offset among the inputs or BIAS, offset among
// the deltas).
fn locate(p: u32) -> vec2<u32> {
    var off = 0u;
    var aoff = 0u;
    var doff = 0u;
    for (var l = 0u; l < M.layers; l++) {
        let n_in = dim(l);
        let n_out = dim(l + 1u);
        let w = n_in * n_out;
        if p < off + w {
            let q = p - off;
            return vec2<u32>(aoff + q % n_in, doff + q / n_in);
        }
        if p < off + w + n_out {
            return vec2<u32>(BIAS, doff + (p - off - w));
        }
        off += w + n_out;
        aoff += n_in;
        doff += n_out;
    }
    return vec2<u32>(BIAS, 0u);
}

// dL/dθ of 256 rows of the chunk (one workgroup, one thread per parameter), rows added
// in order, into partials[g] (g: the rows' global workgroup index).
@compute @workgroup_size(256)
fn mlp_outer(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let lg = wid.x + wid.y * nwg.x;
    let g = M.row_offset / WG + lg;
    if lg * WG >= M.chunk_rows || g >= M.groups {
        return;
    }
    let end = min(WG, M.chunk_rows - lg * WG);
    let stride = M.act_stride + M.del_stride;
    for (var s = 0u; s < ADAM_SLOTS; s++) {
        let p = lid + s * WG;
        if p >= M.n_params {
            break;
        }
        let at = locate(p);
        var sum = 0.0;
        for (var r = 0u; r < end; r++) {
            let base = (lg * WG + r) * stride;
            let d = rows[base + M.act_stride + at.y];
            if d != 0.0 {
                if at.x == BIAS {
                    sum += d;
                } else {
                    sum += d * rows[base + at.x];
                }
            }
        }
        partials[g * M.n_params + p] = sum;
    }
}

// One workgroup: the workgroups' gradients added in order into stats[16 + p]; then (pass 1)
// Adam with L2 weight decay (`MlpAdam::step`), skipped when any gradient is not finite.
@compute @workgroup_size(256)
fn mlp_adam(@builtin(local_invocation_index) lid: u32) {
    if lid == 0u {
        atomicStore(&bad, 0u);
    }
    workgroupBarrier();
    var grad: array<f32, ADAM_SLOTS>;
    for (var s = 0u; s < ADAM_SLOTS; s++) {
        let p = lid + s * WG;
        if p < M.n_params {
            var sum = 0.0;
            for (var g = 0u; g < M.groups; g++) {
                sum += partials[g * M.n_params + p];
            }
            grad[s] = sum;
            stats[2u * COLS + p] = sum;
            if !is_finite(sum) {
                atomicOr(&bad, 1u);
            }
        }
    }
    workgroupBarrier();
    let skip = atomicLoad(&bad) != 0u;
    if lid == 0u {
        stats[2u * COLS + M.n_params] = bitcast<f32>(select(0u, 1u, skip));
    }
    if skip || M.pass_kind == 0u {
        return;
    }
    let n = M.n_params;
    for (var s = 0u; s < ADAM_SLOTS; s++) {
        let p = lid + s * WG;
        if p < n {
            let g = grad[s] + M.weight_decay * weights[p];
            let m = M.beta1 * moments[p] + M.one_minus_beta1 * g;
            let v = M.beta2 * moments[n + p] + M.one_minus_beta2 * g * g;
            moments[p] = m;
            moments[n + p] = v;
            let mh = m / M.bc1;
            let vh = v / M.bc2;
            weights[p] = weights[p] - M.lr * mh / (sqrt(vh) + M.epsilon);
        }
    }
}
