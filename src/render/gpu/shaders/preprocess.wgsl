// Per Gaussian: slice in time → opacity → EWA projection → colour → support box, as the
// CPU path does (src/math/{slice,project,sh}.rs, src/render/cpu/blend/mod.rs `Splat::new`).
// Writes the splat, its tile count (0 when culled) and its screen radius.

@group(0) @binding(0) var<uniform> view: View;
// Five vec4 per Gaussian: mean (x, y, z, t), log scales, left and right quaternions,
// (opacity logit, 0, 0, 0).
@group(0) @binding(1) var<storage, read> params: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> colours: array<f32>;
// Per-Gaussian multiplier on opacity (the neural decay τ; ones when there is none).
@group(0) @binding(3) var<storage, read> factor: array<f32>;
@group(0) @binding(4) var<storage, read_write> splats: array<Splat>;
@group(0) @binding(5) var<storage, read_write> tiles_touched: array<u32>;
@group(0) @binding(6) var<storage, read_write> radii: array<f32>;

fn culled(i: u32) {
    tiles_touched[i] = 0u;
    radii[i] = 0.0;
}

// Row `s` of the SH basis sum Σ_s coeff_s · Y_s(dir) for one temporal row starting at `base`.
fn sh_row(base: u32, ns: u32, d: vec3<f32>) -> vec3<f32> {
    var c = SH_C0 * coeff(base, 0u);
    if ns > 1u {
        c += -SH_C1 * d.y * coeff(base, 1u) + SH_C1 * d.z * coeff(base, 2u) - SH_C1 * d.x * coeff(base, 3u);
    }
    if ns > 4u {
        let xx = d.x * d.x;
        let yy = d.y * d.y;
        let zz = d.z * d.z;
        c += SH_C2_0 * d.x * d.y * coeff(base, 4u)
            - SH_C2_0 * d.y * d.z * coeff(base, 5u)
            + SH_C2_2 * (2.0 * zz - xx - yy) * coeff(base, 6u)
            - SH_C2_0 * d.x * d.z * coeff(base, 7u)
            + SH_C2_4 * (xx - yy) * coeff(base, 8u);
        if ns > 9u {
            c += SH_C3_0 * d.y * (3.0 * xx - yy) * coeff(base, 9u)
                + SH_C3_1 * d.x * d.y * d.z * coeff(base, 10u)
                + SH_C3_2 * d.y * (4.0 * zz - xx - yy) * coeff(base, 11u)
                + SH_C3_3 * d.z * (2.0 * zz - 3.0 * xx - 3.0 * yy) * coeff(base, 12u)
                + SH_C3_2 * d.x * (4.0 * zz - xx - yy) * coeff(base, 13u)
                + SH_C3_5 * d.z * (xx - yy) * coeff(base, 14u)
                + SH_C3_0 * d.x * (xx - 3.0 * yy) * coeff(base, 15u);
        }
    }
    return c;
}

fn coeff(base: u32, s: u32) -> vec3<f32> {
    let k = base + 3u * s;
    return vec3<f32>(colours[k], colours[k + 1u], colours[k + 2u]);
}

@compute @workgroup_size(256)
fn preprocess(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_index(wid, nwg, lid);
    if i >= view.count {
        return;
    }
    let mean = params[5u * i];
    let log_scales = params[5u * i + 1u];
    let ql = unit_quat(params[5u * i + 2u]);
    let qr = unit_quat(params[5u * i + 3u]);
    let extra = params[5u * i + 4u];

    let sl = slice_at(mean, log_scales, ql, qr, view.t);
    let l0 = sl.l0;
    let l1 = sl.l1;
    let l2 = sl.l2;
    let lt = sl.lt;
    let s44 = sl.s44;
    let dt = sl.dt;
    let omega = sl.omega;
    if !(omega > TEMPORAL_CUTOFF) {
        culled(i);
        return;
    }
    let v = sl.v;
    let shift = dt / s44;
    let inv44 = 1.0 / s44;
    let mean3 = mean.xyz + v * shift;
    let b0 = l0 - v.x * lt * inv44;
    let b1 = l1 - v.y * lt * inv44;
    let b2 = l2 - v.z * lt * inv44;

    let opacity = sigmoid(extra.x) * omega * factor[i];
    if !(opacity >= ALPHA_MIN) {
        culled(i);
        return;
    }

    // EWA projection with the Jacobian's guard band and a low-pass filter.
    let r0 = view.rot0.xyz;
    let r1 = view.rot1.xyz;
    let r2 = view.rot2.xyz;
    let p = vec3<f32>(dot(r0, mean3), dot(r1, mean3), dot(r2, mean3)) + view.trans.xyz;
    let z = p.z;
    if !(z >= view.near) || !is_finite(p.x) || !is_finite(p.y) || !is_finite(z) {
        culled(i);
        return;
    }
    let fx = view.focal.x;
    let fy = view.focal.y;
    let cx = view.focal.z;
    let cy = view.focal.w;
    let w = f32(view.width);
    let h = f32(view.height);
    let ux = clamp(p.x / z, (-GUARD_BAND * w - cx) / fx, ((1.0 + GUARD_BAND) * w - cx) / fx);
    let uy = clamp(p.y / z, (-GUARD_BAND * h - cy) / fy, ((1.0 + GUARD_BAND) * h - cy) / fy);
    let iz = 1.0 / z;
    let ja = fx * iz * (r0 - ux * r2);
    let jb = fy * iz * (r1 - uy * r2);
    let k0 = ja.x * b0 + ja.y * b1 + ja.z * b2;
    let k1 = jb.x * b0 + jb.y * b1 + jb.z * b2;
    let ca = dot(k0, k0) + LOW_PASS;
    let cb = dot(k0, k1);
    let cc = dot(k1, k1) + LOW_PASS;
    let det = ca * cc - cb * cb;
    if !(det > 0.0) || !is_finite(det) {
        culled(i);
        return;
    }
    let inv_det = 1.0 / det;
    let conic = vec3<f32>(cc * inv_det, -cb * inv_det, ca * inv_det);
    let mean2 = vec2<f32>(fx * p.x * iz + cx, fy * p.y * iz + cy);
    let radius = EXTENT_SIGMAS * max(sqrt(ca), sqrt(cc));

    // Spherindrical colour: SH of the view direction to the canonical mean × temporal cosines.
    let to_mean = mean.xyz - view.centre.xyz;
    let norm = sqrt(dot(to_mean, to_mean));
    var dir = vec3<f32>(0.0, 0.0, 1.0);
    if norm > 1e-20 {
        dir = to_mean * (1.0 / norm);
    }
    let delta_t = mean.w - view.t;
    var rgb = vec3<f32>(0.5);
    let base = i * view.colour_stride;
    for (var j = 0u; j < view.nt_active; j++) {
        var psi = 1.0;
        if j > 0u {
            psi = cos(2.0 * PI * f32(j) / view.period * delta_t);
        }
        rgb += psi * sh_row(base + 3u * j * view.ns_capacity, view.ns_active, dir);
    }
    rgb = max(rgb, vec3<f32>(0.0));

    // Support: the 3σ ellipse shrunk to where opacity·exp(power) ≥ 1/255.
    let op = min(opacity, 1.0);
    var d2 = 0.0;
    if op > ALPHA_MIN {
        d2 = min(2.0 * log(op / ALPHA_MIN), EXTENT_SIGMAS * EXTENT_SIGMAS);
    }
    let cdet = conic.x * conic.z - conic.y * conic.y;
    var sxx = 0.0;
    var syy = 0.0;
    if cdet > 0.0 {
        sxx = conic.z / cdet;
        syy = conic.x / cdet;
    }
    let ex = sqrt(d2 * sxx);
    let ey = sqrt(d2 * syy);
    if !(d2 > 0.0) || !is_finite(ex) || !is_finite(ey) || !is_finite(mean2.x) || !is_finite(mean2.y) {
        culled(i);
        return;
    }
    let lim = 1e9;
    let bx0 = i32(clamp(ceil(mean2.x - ex - 0.5), -lim, lim));
    let bx1 = i32(clamp(floor(mean2.x + ex - 0.5), -lim, lim));
    let by0 = i32(clamp(ceil(mean2.y - ey - 0.5), -lim, lim));
    let by1 = i32(clamp(floor(mean2.y + ey - 0.5), -lim, lim));
    let x0 = max(bx0, 0);
    let x1 = min(bx1, i32(view.width) - 1);
    let y0 = max(by0, 0);
    let y1 = min(by1, i32(view.height) - 1);
    if x0 > x1 || y0 > y1 {
        culled(i);
        return;
    }
    let min_power = -0.5 * d2 * (1.0 + 1e-6) - 1e-9;
    splats[i] = Splat(
        vec4<f32>(mean2, z, opacity),
        vec4<f32>(conic, min_power),
        vec4<f32>(rgb, 0.0),
        vec4<i32>(x0, x1, y0, y1),
    );
    let tx0 = u32(x0) / TILE;
    let tx1 = u32(x1) / TILE;
    let ty0 = u32(y0) / TILE;
    let ty1 = u32(y1) / TILE;
    tiles_touched[i] = (tx1 - tx0 + 1u) * (ty1 - ty0 + 1u);
    radii[i] = radius;
}
