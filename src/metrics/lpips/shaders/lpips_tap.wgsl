// LPIPS-alex on the GPU (src/metrics/lpips/gpu.rs): one tap's term of each pair's distance,
// as the CPU's `tap_distance` (alex.rs). The batch's maps are [a₀, b₀, a₁, b₁, …].
// - `tap_pixels`: per pair and pixel, Σ_c w_c (â_c − b̂_c)² with â, b̂ the channel vectors
//   divided by their length plus 1e-10;
// - `tap_mean`: per pair (one workgroup), the mean of those over the pixels, added to the
//   pair's distance. Each invocation sums a strided run of pixels in order, then a fixed
//   tree adds the 256 sums: the result does not depend on scheduling.

struct Tap {
    pixels: u32,
    channels: u32,
    pairs: u32,
    pad: u32,
}

@group(0) @binding(0) var<uniform> tap: Tap;
@group(0) @binding(1) var<storage, read> features: array<f32>;
@group(0) @binding(2) var<storage, read> lin_weights: array<f32>;
@group(0) @binding(3) var<storage, read_write> terms: array<f32>;
@group(0) @binding(4) var<storage, read_write> totals: array<f32>;

const NORM_EPS: f32 = 1e-10;

@compute @workgroup_size(256)
fn tap_pixels(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_index(wid, nwg, lid);
    if i >= tap.pairs * tap.pixels {
        return;
    }
    let pair = i / tap.pixels;
    let p = i % tap.pixels;
    let a = ((2u * pair) * tap.pixels + p) * tap.channels;
    let b = ((2u * pair + 1u) * tap.pixels + p) * tap.channels;
    var sa = 0.0;
    var sb = 0.0;
    for (var c = 0u; c < tap.channels; c++) {
        sa += features[a + c] * features[a + c];
        sb += features[b + c] * features[b + c];
    }
    let na = 1.0 / (sqrt(sa) + NORM_EPS);
    let nb = 1.0 / (sqrt(sb) + NORM_EPS);
    var sum = 0.0;
    for (var c = 0u; c < tap.channels; c++) {
        let d = features[a + c] * na - features[b + c] * nb;
        sum += lin_weights[c] * d * d;
    }
    terms[i] = sum;
}

var<workgroup> partial: array<f32, 256>;

@compute @workgroup_size(256)
fn tap_mean(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let pair = wid.x + wid.y * nwg.x;
    if pair >= tap.pairs {
        return;
    }
    var sum = 0.0;
    for (var p = lid; p < tap.pixels; p += WG) {
        sum += terms[pair * tap.pixels + p];
    }
    partial[lid] = sum;
    workgroupBarrier();
    for (var width = WG / 2u; width > 0u; width /= 2u) {
        if lid < width {
            partial[lid] += partial[lid + width];
        }
        workgroupBarrier();
    }
    if lid == 0u {
        totals[pair] += partial[0] / f32(tap.pixels);
    }
}
