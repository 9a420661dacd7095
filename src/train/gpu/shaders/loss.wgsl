// The training loss (1 − λ)·L1 + λ·(1 − SSIM) of a rendered image against its target and
// its gradient w.r.t. the rendered image: `src/train/loss.rs` and `src/metrics/ssim.rs`
// step for step in f32 (11×11 separable Gaussian window, zero padding, "same" size).
// Images are interleaved RGB, one thread per value k = 3·pixel + channel.
//
// ssim_blur_h → ssim_pixel (+ per-workgroup sums) → ssim_grad, and reduce_sums adds the
// per-workgroup sums in one workgroup.

struct LossParams {
    width: u32,
    height: u32,
    // Values of an image: 3 · width · height.
    count: u32,
    // Workgroups of the per-value passes (= per-workgroup sums).
    groups: u32,
    c1: f32,
    c2: f32,
    // 1 / count.
    inv_count: f32,
    // (1 − λ) / count: the L1 term's weight.
    wl: f32,
    // −λ: the SSIM gradient's weight.
    ws: f32,
    // Multiplies the whole gradient (1 / batch size in training).
    scale: f32,
    pad0: f32,
    pad1: f32,
    // The normalised 11-tap window, four per vec4.
    window: array<vec4<f32>, 3>,
}

const RADIUS: i32 = 5;

@group(0) @binding(0) var<uniform> P: LossParams;
@group(0) @binding(1) var<storage, read> rendered: array<f32>;
@group(0) @binding(2) var<storage, read> target_image: array<f32>;
// 2 · count: x and y blurred horizontally.
@group(0) @binding(3) var<storage, read_write> tmp: array<f32>;
// 5 · count: ∂S/∂(µx, σxx, σxy) / count, then µx and µy, per value.
@group(0) @binding(4) var<storage, read_write> partial: array<f32>;
// groups + 1 entries: (Σ 1 − SSIM, Σ |r − t|, Σ (r − t)², Σ SSIM) per workgroup, the total
// last.
@group(0) @binding(5) var<storage, read_write> sums: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> grad: array<f32>;

var<workgroup> shared_sums: array<vec4<f32>, WG>;

fn tap(k: i32) -> f32 {
    let j = u32(k + RADIUS);
    return P.window[j / 4u][j % 4u];
}

// The value's pixel (x, y) and channel c.
fn coords(k: u32) -> vec3<i32> {
    let i = k / 3u;
    return vec3<i32>(i32(i % P.width), i32(i / P.width), i32(k % 3u));
}

fn at(x: i32, y: i32, c: i32) -> u32 {
    return 3u * (u32(y) * P.width + u32(x)) + u32(c);
}

// Sum of the window's taps that fall outside [0, size) around `x`.
fn outside(x: i32, size: i32) -> f32 {
    var o = 0.0;
    for (var d = -RADIUS; d <= RADIUS; d++) {
        if x + d < 0 || x + d >= size {
            o += tap(d);
        }
    }
    return o;
}

// Horizontal blur of x and y.
@compute @workgroup_size(256)
fn ssim_blur_h(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let k = flat_index(wid, nwg, lid);
    if k >= P.count {
        return;
    }
    let p = coords(k);
    let lo = max(p.x - RADIUS, 0);
    let hi = min(p.x + RADIUS, i32(P.width) - 1);
    var acc = vec2<f32>(0.0);
    for (var xx = lo; xx <= hi; xx++) {
        let j = at(xx, p.y, p.z);
        acc += tap(xx - p.x) * vec2<f32>(rendered[j], target_image[j]);
    }
    tmp[k] = acc.x;
    tmp[P.count + k] = acc.y;
}

// Sum `v` over the workgroup into sums[group] (every thread must call it).
fn reduce_group(v: vec4<f32>, lid: u32, group: u32) {
    shared_sums[lid] = v;
    workgroupBarrier();
    for (var s = WG / 2u; s > 0u; s >>= 1u) {
        if lid < s {
            shared_sums[lid] += shared_sums[lid + s];
        }
        workgroupBarrier();
    }
    if lid == 0u {
        sums[group] = shared_sums[0];
    }
}

// Per value: the local means (vertical blur), the local (co)variances from centred
// values, SSIM and its partials. With zero padding, E[x²] − µx² equals
// Σ g·(x − µx)² + µx²·(1 − Σ g) over the taps inside the image: the same value as the
// CPU's blurred moments, without their cancellation in f32 on flat images.
@compute @workgroup_size(256)
fn ssim_pixel(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let k = flat_index(wid, nwg, lid);
    var contribution = vec4<f32>(0.0);
    if k < P.count {
        let p = coords(k);
        let ylo = max(p.y - RADIUS, 0);
        let yhi = min(p.y + RADIUS, i32(P.height) - 1);
        let xlo = max(p.x - RADIUS, 0);
        let xhi = min(p.x + RADIUS, i32(P.width) - 1);
        var mu = vec2<f32>(0.0);
        for (var yy = ylo; yy <= yhi; yy++) {
            let j = at(p.x, yy, p.z);
            mu += tap(yy - p.y) * vec2<f32>(tmp[j], tmp[P.count + j]);
        }
        let mx = mu.x;
        let my = mu.y;
        var c = vec3<f32>(0.0);
        for (var yy = ylo; yy <= yhi; yy++) {
            let gy = tap(yy - p.y);
            for (var xx = xlo; xx <= xhi; xx++) {
                let j = at(xx, yy, p.z);
                let dx = rendered[j] - mx;
                let dy = target_image[j] - my;
                c += (gy * tap(xx - p.x)) * vec3<f32>(dx * dx, dy * dy, dx * dy);
            }
        }
        let ox = outside(p.x, i32(P.width));
        let oy = outside(p.y, i32(P.height));
        let out = ox + oy - ox * oy;
        let sxx = c.x + mx * mx * out;
        let syy = c.y + my * my * out;
        let sxy = c.z + mx * my * out;
        let a1 = 2.0 * mx * my + P.c1;
        let a2 = 2.0 * sxy + P.c2;
        let b1 = mx * mx + my * my + P.c1;
        let b2 = sxx + syy + P.c2;
        let s = a1 * a2 / (b1 * b2);
        let ds_dmx = 2.0 * my * a2 / (b1 * b2) - s * 2.0 * mx / b1;
        let ds_dsxx = -s / b2;
        let ds_dsxy = 2.0 * a1 / (b1 * b2);
        partial[k] = ds_dmx * P.inv_count;
        partial[P.count + k] = ds_dsxx * P.inv_count;
        partial[2u * P.count + k] = ds_dsxy * P.inv_count;
        partial[3u * P.count + k] = mx;
        partial[4u * P.count + k] = my;
        let d = rendered[k] - target_image[k];
        // 1 − S and S: each sum keeps its digits near zero.
        contribution = vec4<f32>(1.0 - s, abs(d), d * d, s);
    }
    reduce_group(contribution, lid, wid.x + wid.y * nwg.x);
}

fn sign_of(x: f32) -> f32 {
    if x > 0.0 {
        return 1.0;
    }
    if x < 0.0 {
        return -1.0;
    }
    return 0.0;
}

// Per value x_j: d(mean SSIM)/d(x_j) = Σ_i g(i − j)·(∂S_i/∂µx + 2(x_j − µx_i)·∂S_i/∂σxx
// + (y_j − µy_i)·∂S_i/∂σxy) / count over the window's pixels i inside the image (the
// blurred-moment chain rule of the CPU, with centred terms), then the loss weights.
@compute @workgroup_size(256)
fn ssim_grad(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let k = flat_index(wid, nwg, lid);
    if k >= P.count {
        return;
    }
    let p = coords(k);
    let r = rendered[k];
    let t = target_image[k];
    let ylo = max(p.y - RADIUS, 0);
    let yhi = min(p.y + RADIUS, i32(P.height) - 1);
    let xlo = max(p.x - RADIUS, 0);
    let xhi = min(p.x + RADIUS, i32(P.width) - 1);
    var acc = 0.0;
    for (var yy = ylo; yy <= yhi; yy++) {
        let gy = tap(yy - p.y);
        for (var xx = xlo; xx <= xhi; xx++) {
            let i = at(xx, yy, p.z);
            let term = partial[i] + 2.0 * (r - partial[3u * P.count + i]) * partial[P.count + i]
                + (t - partial[4u * P.count + i]) * partial[2u * P.count + i];
            acc += (gy * tap(xx - p.x)) * term;
        }
    }
    grad[k] = (acc * P.ws + P.wl * sign_of(r - t)) * P.scale;
}

// One workgroup: add the per-workgroup sums into sums[groups].
@compute @workgroup_size(256)
fn reduce_sums(@builtin(local_invocation_index) lid: u32) {
    var acc = vec4<f32>(0.0);
    for (var g = lid; g < P.groups; g += WG) {
        acc += sums[g];
    }
    shared_sums[lid] = acc;
    workgroupBarrier();
    for (var s = WG / 2u; s > 0u; s >>= 1u) {
        if lid < s {
            shared_sums[lid] += shared_sums[lid + s];
        }
        workgroupBarrier();
    }
    if lid == 0u {
        sums[P.groups] = shared_sums[0];
    }
}
