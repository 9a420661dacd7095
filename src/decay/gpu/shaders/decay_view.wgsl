// Per view of a training batch with the neural decay (src/decay/visibility.rs): which
// Gaussians are visible (Z_T: ω(t) > 0.05; Z_V: the time-sliced centre in front of the
// near plane and, in frustum mode, inside the image), their render-opacity factor (τ when
// visible, 1 otherwise), "visible in some view of the batch", and after the view's
// backward its dL/dτ added into the batch's for the visible Gaussians.

struct DecayView {
    rot0: vec4<f32>,
    rot1: vec4<f32>,
    rot2: vec4<f32>,
    trans: vec4<f32>,
    // fx, fy, cx, cy.
    focal: vec4<f32>,
    width: u32,
    height: u32,
    count: u32,
    // 0: off (all visible), 1: near plane, 2: frustum.
    mode: u32,
    t: f32,
    near: f32,
    pad0: f32,
    pad1: f32,
}

@group(0) @binding(0) var<uniform> V: DecayView;
@group(0) @binding(1) var<storage, read> model: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> tau: array<f32>;
@group(0) @binding(3) var<storage, read_write> factor: array<f32>;
@group(0) @binding(4) var<storage, read_write> vis: array<u32>;
@group(0) @binding(5) var<storage, read_write> seen: array<u32>;
@group(0) @binding(6) var<storage, read_write> d_tau: array<f32>;
// The view's gradients, five vec4 per Gaussian (dL/dfactor at 20·i + 17).
@group(0) @binding(7) var<storage, read> view_grads: array<f32>;

// `visibility::visible` for Gaussian i (the slice as `preprocess` computes it).
fn visible(i: u32) -> bool {
    if V.mode == 0u {
        return true;
    }
    let mean = model[5u * i];
    let log_scales = model[5u * i + 1u];
    let ql = unit_quat(model[5u * i + 2u]);
    let qr = unit_quat(model[5u * i + 3u]);
    let sl = slice_at(mean, log_scales, ql, qr, V.t);
    if !(sl.omega > TEMPORAL_CUTOFF) {
        return false;
    }
    let mean3 = mean.xyz + sl.v * (sl.dt / sl.s44);
    let p = vec3<f32>(dot(V.rot0.xyz, mean3), dot(V.rot1.xyz, mean3), dot(V.rot2.xyz, mean3))
        + V.trans.xyz;
    if !(p.z > V.near) {
        return false;
    }
    if V.mode == 1u {
        return true;
    }
    let iz = 1.0 / p.z;
    let u = V.focal.x * p.x * iz + V.focal.z;
    let w = V.focal.y * p.y * iz + V.focal.w;
    return u >= 0.0 && u < f32(V.width) && w >= 0.0 && w < f32(V.height);
}

@compute @workgroup_size(256)
fn decay_visibility(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_index(wid, nwg, lid);
    if i >= V.count {
        return;
    }
    let v = visible(i);
    vis[i] = select(0u, 1u, v);
    factor[i] = select(1.0, tau[i], v);
    if v {
        seen[i] = 1u;
    }
}

@compute @workgroup_size(256)
fn decay_gather(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_index(wid, nwg, lid);
    if i >= V.count {
        return;
    }
    if vis[i] != 0u {
        d_tau[i] = d_tau[i] + view_grads[20u * i + 17u];
    }
}
