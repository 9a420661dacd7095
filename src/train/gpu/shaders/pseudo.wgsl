// The pseudo-view consistency term of one training view (`consistency` in
// `src/train/pseudo_view.rs`, whose rules and formulas these follow): each training pixel
// with alpha > 0.5 is lifted to its expected depth, landed in the virtual view (the
// training camera moved by `shift` in its own x/y), the virtual render is sampled there
// bilinearly and compared with the training image (L1).
//
// `pseudo_land` (one thread per training pixel) writes the training render's alpha and
// depth gradients into its upstream planes and scatters the virtual image's gradient as
// fixed-point integers (`sign · w · 2^16` per bilinear corner, in units of the term's
// per-value weight): integer atomics add in any order to the same sum, so the step stays
// deterministic. `pseudo_resolve` turns those sums into the virtual view's upstream RGB.

struct Pseudo {
    // width, height, pixels, 0
    size: vec4<u32>,
    // fx, fy, cx, cy
    focal: vec4<f32>,
    // shift x, shift y, weight per value (weight / (3 · pixels)), 0
    shift: vec4<f32>,
}

@group(0) @binding(0) var<uniform> pv: Pseudo;
// Interleaved RGB of the training image.
@group(0) @binding(1) var<storage, read> pv_target: array<f32>;
@group(0) @binding(2) var<storage, read> pv_alpha: array<f32>;
@group(0) @binding(3) var<storage, read> pv_depth: array<f32>;
@group(0) @binding(4) var<storage, read> pv_virtual_rgb: array<f32>;
@group(0) @binding(5) var<storage, read> pv_virtual_alpha: array<f32>;
@group(0) @binding(6) var<storage, read> pv_virtual_depth: array<f32>;
// The training view's upstream gradient planes (RGB, alpha, depth): alpha and depth are
// written here.
@group(0) @binding(7) var<storage, read_write> pv_upstream: array<f32>;
// Per virtual value, the fixed-point sum of its gradient.
@group(0) @binding(8) var<storage, read_write> pv_sums: array<atomic<i32>>;

// Fixed-point scale of a bilinear weight: 2^16 leaves room for 32768 whole weights on
// one value.
const PV_FIXED: f32 = 65536.0;
// How far the virtual depth at a landing point may lie from the lifted point's.
const PV_AGREEMENT: f32 = 0.95;

@compute @workgroup_size(256)
fn pseudo_land(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let p = flat_index(wid, nwg, lid);
    let w = pv.size.x;
    let h = pv.size.y;
    let npix = pv.size.z;
    if p >= npix {
        return;
    }
    let a = pv_alpha[p];
    if a <= 0.5 {
        return;
    }
    let z = pv_depth[p] / a;
    if z <= 1e-6 {
        return;
    }
    let f = pv.focal;
    let x = f32(p % w);
    let y = f32(p / w);
    let u = (x + 0.5 - f.z) / f.x;
    let v = (y + 0.5 - f.w) / f.y;
    // Landing point in pixel-index space (pixel centres at integers).
    let sx = f.x * (u - pv.shift.x / z) + f.z - 0.5;
    let sy = f.y * (v - pv.shift.y / z) + f.w - 0.5;
    if !(sx >= 0.0 && sy >= 0.0 && sx < f32(w - 1u) && sy < f32(h - 1u)) {
        return;
    }
    let x0 = u32(floor(sx));
    let y0 = u32(floor(sy));
    let fa = sx - f32(x0);
    let fb = sy - f32(y0);
    let q00 = y0 * w + x0;
    var idx = array<u32, 4>(q00, q00 + 1u, q00 + w, q00 + w + 1u);
    // The virtual view must see the same surface there, or none.
    let qn = idx[select(0u, 1u, fa >= 0.5) + select(0u, 2u, fb >= 0.5)];
    let av = pv_virtual_alpha[qn];
    if av > 0.5 {
        let zv = pv_virtual_depth[qn] / av;
        if !(zv >= PV_AGREEMENT * z && zv <= z / PV_AGREEMENT) {
            return;
        }
    }
    var wt = array<f32, 4>((1.0 - fa) * (1.0 - fb), fa * (1.0 - fb), (1.0 - fa) * fb, fa * fb);
    let norm = pv.shift.z;
    var dz = 0.0;
    for (var c = 0u; c < 3u; c++) {
        let s0 = pv_virtual_rgb[3u * idx[0] + c];
        let s1 = pv_virtual_rgb[3u * idx[1] + c];
        let s2 = pv_virtual_rgb[3u * idx[2] + c];
        let s3 = pv_virtual_rgb[3u * idx[3] + c];
        let warped = wt[0] * s0 + wt[1] * s1 + wt[2] * s2 + wt[3] * s3;
        // The host's `signum`: +1 at an exact match.
        let g = select(-1.0, 1.0, warped - pv_target[3u * p + c] >= 0.0);
        for (var i = 0u; i < 4u; i++) {
            atomicAdd(&pv_sums[3u * idx[i] + c], i32(round(g * wt[i] * PV_FIXED)));
        }
        let d_sx = (1.0 - fb) * (s1 - s0) + fb * (s3 - s2);
        let d_sy = (1.0 - fa) * (s2 - s0) + fa * (s3 - s1);
        dz += g * (d_sx * f.x * pv.shift.x + d_sy * f.y * pv.shift.y);
    }
    dz *= norm / (z * z);
    // z = D / A.
    pv_upstream[3u * npix + p] = -dz * pv_depth[p] / (a * a);
    pv_upstream[4u * npix + p] = dz / a;
}

// The virtual view's upstream RGB from the fixed-point sums (its alpha and depth planes
// stay zero).
@compute @workgroup_size(256)
fn pseudo_resolve(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_index(wid, nwg, lid);
    if i >= 3u * pv.size.z {
        return;
    }
    pv_upstream[i] = f32(atomicLoad(&pv_sums[i])) * (pv.shift.z / PV_FIXED);
}
