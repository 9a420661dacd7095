// Adam on a flat parameter buffer, `src/train/optim.rs` step for step in f32: the host
// passes β₁, β₂, 1 − β₁, 1 − β₂ and ε as it computes them, the bias corrections of this
// step, and one learning rate per position in a stride (position min(i mod stride, 19));
// a negative rate leaves the value and its moments alone (padding), and so does an index
// before `first` (the frozen Gaussians' values).

struct AdamParams {
    count: u32,
    stride: u32,
    first: u32,
    pad1: u32,
    beta1: f32,
    beta2: f32,
    one_minus_beta1: f32,
    one_minus_beta2: f32,
    // 1 − β₁ᵗ and 1 − β₂ᵗ.
    bc1: f32,
    bc2: f32,
    epsilon: f32,
    pad2: f32,
    rates: array<vec4<f32>, 5>,
}

@group(0) @binding(0) var<uniform> A: AdamParams;
@group(0) @binding(1) var<storage, read> gradient: array<f32>;
@group(0) @binding(2) var<storage, read_write> param: array<f32>;
@group(0) @binding(3) var<storage, read_write> moment1: array<f32>;
@group(0) @binding(4) var<storage, read_write> moment2: array<f32>;

@compute @workgroup_size(256)
fn adam_step(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_index(wid, nwg, lid);
    if i >= A.count || i < A.first {
        return;
    }
    let j = min(i % A.stride, 19u);
    let lr = A.rates[j / 4u][j % 4u];
    if lr < 0.0 {
        return;
    }
    let g = gradient[i];
    let m = A.beta1 * moment1[i] + A.one_minus_beta1 * g;
    let v = A.beta2 * moment2[i] + A.one_minus_beta2 * g * g;
    moment1[i] = m;
    moment2[i] = v;
    let mh = m / A.bc1;
    let vh = v / A.bc2;
    param[i] = param[i] - lr * mh / (sqrt(vh) + A.epsilon);
}
