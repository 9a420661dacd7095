// Backward of `preprocess`, one thread per Gaussian, as the CPU's per-Gaussian backward
// (src/render/cpu/backward.rs): add the Gaussian's per-tile blend gradients (its slots of
// `partials`, in tile order), then chain them through colour (`colour_backward_masked`),
// EWA projection (`project_backward`) and slicing (`slice_backward`, `rotation_backward`,
// `normalise_quat_backward`) of src/math, recomputing the forward intermediates.
// Writes every output entry: zeros for Gaussians that were not drawn.

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read> params: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> colours: array<f32>;
@group(0) @binding(3) var<storage, read> factor: array<f32>;
@group(0) @binding(4) var<storage, read> counts: array<u32>;
@group(0) @binding(5) var<storage, read> ends: array<u32>;
// Three vec4 per slot: (mean (2), opacity, depth), (conic, 0), (colour, 0).
@group(0) @binding(6) var<storage, read> partials: array<vec4<f32>>;
// Five vec4 per Gaussian, like `params`: mean, log scales, left and right quaternions,
// (opacity logit, opacity factor, |dL/d(2D mean)|, 0).
@group(0) @binding(7) var<storage, read_write> out_params: array<vec4<f32>>;
@group(0) @binding(8) var<storage, read_write> out_colours: array<f32>;

// Rows of Ml(q) (`rotation4d::ML`), stored as the columns of a WGSL matrix.
fn left_rows(q: vec4<f32>) -> mat4x4<f32> {
    return mat4x4<f32>(
        vec4<f32>(q.x, -q.y, -q.z, -q.w),
        vec4<f32>(q.y, q.x, -q.w, q.z),
        vec4<f32>(q.z, q.w, q.x, -q.y),
        vec4<f32>(q.w, -q.z, q.y, q.x),
    );
}

// Rows of Mr(q) (`rotation4d::MR`), stored as the columns of a WGSL matrix.
fn right_rows(q: vec4<f32>) -> mat4x4<f32> {
    return mat4x4<f32>(
        vec4<f32>(q.x, q.y, q.z, q.w),
        vec4<f32>(-q.y, q.x, -q.w, q.z),
        vec4<f32>(-q.z, q.w, q.x, -q.y),
        vec4<f32>(-q.w, -q.z, q.y, q.x),
    );
}

// Σ_ij a_ij b_ij of two matrices stored alike.
fn frobenius(a: mat4x4<f32>, b: mat4x4<f32>) -> f32 {
    return dot(a[0], b[0]) + dot(a[1], b[1]) + dot(a[2], b[2]) + dot(a[3], b[3]);
}

const E0: vec4<f32> = vec4<f32>(1.0, 0.0, 0.0, 0.0);
const E1: vec4<f32> = vec4<f32>(0.0, 1.0, 0.0, 0.0);
const E2: vec4<f32> = vec4<f32>(0.0, 0.0, 1.0, 0.0);
const E3: vec4<f32> = vec4<f32>(0.0, 0.0, 0.0, 1.0);

// `normalise_quat_backward`: norm 0 marks a quaternion that became the identity.
fn unit_quat_backward(unit: vec4<f32>, norm: f32, d_unit: vec4<f32>) -> vec4<f32> {
    if norm == 0.0 {
        return vec4<f32>(0.0);
    }
    return (d_unit - unit * dot(unit, d_unit)) / norm;
}

// The quaternion's norm, 0 where `unit_quat` falls back to the identity.
fn quat_norm(q: vec4<f32>) -> f32 {
    let n = sqrt(dot(q, q));
    if !(n > MIN_QUAT_NORM) || !is_finite(n) {
        return 0.0;
    }
    return n;
}

// Whether `scale_from_log` passes the gradient (the clamp is inactive).
fn scale_ok(v: f32) -> bool {
    return !is_nan(v) && v >= LOG_SCALE_MIN && v <= LOG_SCALE_MAX;
}

// The real SH basis (3DGS ordering and signs) at unit `d`, the first `ns` functions.
fn sh_basis(d: vec3<f32>, ns: u32) -> array<f32, 16> {
    var y: array<f32, 16>;
    y[0] = SH_C0;
    if ns > 1u {
        y[1] = -SH_C1 * d.y;
        y[2] = SH_C1 * d.z;
        y[3] = -SH_C1 * d.x;
    }
    if ns > 4u {
        let xx = d.x * d.x;
        let yy = d.y * d.y;
        let zz = d.z * d.z;
        y[4] = SH_C2_0 * d.x * d.y;
        y[5] = -SH_C2_0 * d.y * d.z;
        y[6] = SH_C2_2 * (2.0 * zz - xx - yy);
        y[7] = -SH_C2_0 * d.x * d.z;
        y[8] = SH_C2_4 * (xx - yy);
        if ns > 9u {
            y[9] = SH_C3_0 * d.y * (3.0 * xx - yy);
            y[10] = SH_C3_1 * d.x * d.y * d.z;
            y[11] = SH_C3_2 * d.y * (4.0 * zz - xx - yy);
            y[12] = SH_C3_3 * d.z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
            y[13] = SH_C3_2 * d.x * (4.0 * zz - xx - yy);
            y[14] = SH_C3_5 * d.z * (xx - yy);
            y[15] = SH_C3_0 * d.x * (xx - 3.0 * yy);
        }
    }
    return y;
}

// `sh::basis_grad`: Σ_s dy[s] ∇Y_s(d) over the basis functions 1..ns.
fn sh_basis_grad(d: vec3<f32>, ns: u32, dy: array<f32, 16>) -> vec3<f32> {
    var g = vec3<f32>(0.0);
    if ns > 1u {
        g += SH_C1 * vec3<f32>(-dy[3], -dy[1], dy[2]);
    }
    if ns > 4u {
        let x = d.x;
        let y = d.y;
        let z = d.z;
        let xx = x * x;
        let yy = y * y;
        let zz = z * z;
        g += dy[4] * SH_C2_0 * vec3<f32>(y, x, 0.0);
        g -= dy[5] * SH_C2_0 * vec3<f32>(0.0, z, y);
        g += dy[6] * SH_C2_2 * vec3<f32>(-2.0 * x, -2.0 * y, 4.0 * z);
        g -= dy[7] * SH_C2_0 * vec3<f32>(z, 0.0, x);
        g += dy[8] * SH_C2_4 * vec3<f32>(2.0 * x, -2.0 * y, 0.0);
        if ns > 9u {
            g += dy[9] * SH_C3_0 * vec3<f32>(6.0 * x * y, 3.0 * (xx - yy), 0.0);
            g += dy[10] * SH_C3_1 * vec3<f32>(y * z, x * z, x * y);
            g += dy[11] * SH_C3_2 * vec3<f32>(-2.0 * x * y, 4.0 * zz - xx - 3.0 * yy, 8.0 * y * z);
            g += dy[12] * SH_C3_3 * vec3<f32>(-6.0 * x * z, -6.0 * y * z, 6.0 * zz - 3.0 * (xx + yy));
            g += dy[13] * SH_C3_2 * vec3<f32>(4.0 * zz - 3.0 * xx - yy, -2.0 * x * y, 8.0 * x * z);
            g += dy[14] * SH_C3_5 * vec3<f32>(2.0 * x * z, -2.0 * y * z, xx - yy);
            g += dy[15] * SH_C3_0 * vec3<f32>(3.0 * (xx - yy), -6.0 * x * y, 0.0);
        }
    }
    return g;
}

fn write_zeros(i: u32) {
    for (var k = 0u; k < 5u; k++) {
        out_params[5u * i + k] = vec4<f32>(0.0);
    }
    let base = i * view.colour_stride;
    for (var k = 0u; k < view.colour_stride; k++) {
        out_colours[base + k] = 0.0;
    }
}

// `colour_backward_masked`: writes dL/d(coefficients) of Gaussian i (zeros for the
// inactive ones) and returns dL/d(canonical mean) through the view direction and Δt.
fn colour_backward(i: u32, mean: vec4<f32>, d_rgb_in: vec3<f32>) -> vec4<f32> {
    let ns = view.ns_active;
    let nt = view.nt_active;
    let ns_cap = view.ns_capacity;
    let base = i * view.colour_stride;
    let to_mean = mean.xyz - view.centre.xyz;
    let norm = sqrt(dot(to_mean, to_mean));
    var dir = vec3<f32>(0.0, 0.0, 1.0);
    var dir_norm = 0.0;
    if norm > 1e-20 {
        dir = to_mean * (1.0 / norm);
        dir_norm = norm;
    }
    let y = sh_basis(dir, ns);
    let delta_t = mean.w - view.t;
    var psi = array<f32, 3>(1.0, 0.0, 0.0);
    var d_psi_dt = array<f32, 3>(0.0, 0.0, 0.0);
    for (var j = 1u; j < nt; j++) {
        let w = 2.0 * PI * f32(j) / view.period;
        psi[j] = cos(w * delta_t);
        d_psi_dt[j] = -sin(w * delta_t) * w;
    }
    // The clamp at 0: only channels that were positive pass the gradient.
    var raw = vec3<f32>(0.5);
    for (var j = 0u; j < nt; j++) {
        let row = base + 3u * j * ns_cap;
        for (var s = 0u; s < ns; s++) {
            let k = row + 3u * s;
            raw += vec3<f32>(colours[k], colours[k + 1u], colours[k + 2u]) * (y[s] * psi[j]);
        }
    }
    let d_raw = select(vec3<f32>(0.0), d_rgb_in, raw > vec3<f32>(0.0));

    var d_y: array<f32, 16>;
    var d_mean = vec4<f32>(0.0);
    let nt_cap = view.colour_stride / (3u * ns_cap);
    for (var j = 0u; j < nt_cap; j++) {
        let row = base + 3u * j * ns_cap;
        var dp = 0.0;
        for (var s = 0u; s < ns_cap; s++) {
            let k = row + 3u * s;
            var d_coeff = vec3<f32>(0.0);
            if j < nt && s < ns {
                let c = vec3<f32>(colours[k], colours[k + 1u], colours[k + 2u]);
                d_coeff = d_raw * (y[s] * psi[j]);
                let cd = dot(d_raw, c);
                d_y[s] += cd * psi[j];
                dp += cd * y[s];
            }
            out_colours[k] = d_coeff.x;
            out_colours[k + 1u] = d_coeff.y;
            out_colours[k + 2u] = d_coeff.z;
        }
        if j >= 1u && j < nt {
            d_mean.w += dp * d_psi_dt[j];
        }
    }
    if ns > 1u && dir_norm != 0.0 {
        let d_dir = sh_basis_grad(dir, ns, d_y);
        d_mean = vec4<f32>((d_dir - dir * dot(dir, d_dir)) / dir_norm, d_mean.w);
    }
    return d_mean;
}

@compute @workgroup_size(256)
fn preprocess_backward(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_index(wid, nwg, lid);
    if i >= view.count {
        return;
    }
    let count = counts[i];
    if count == 0u {
        write_zeros(i);
        return;
    }
    // The blend gradients of this Gaussian, summed over its tiles in tile order.
    var g_a = vec4<f32>(0.0);
    var g_b = vec4<f32>(0.0);
    var g_c = vec4<f32>(0.0);
    for (var s = ends[i] - count; s < ends[i]; s++) {
        g_a += partials[3u * s];
        g_b += partials[3u * s + 1u];
        g_c += partials[3u * s + 2u];
    }
    let d_mean2d = g_a.xy;
    let d_opacity = g_a.z;
    let d_depth = g_a.w;
    let d_conic = g_b.xyz;

    // Forward again: rotation, scales, L = R·S (rows x, y, z, t).
    let mean = params[5u * i];
    let log_scales = params[5u * i + 1u];
    let raw_l = params[5u * i + 2u];
    let raw_r = params[5u * i + 3u];
    let logit = params[5u * i + 4u].x;
    let ql = unit_quat(raw_l);
    let qr = unit_quat(raw_r);
    let wml = left_rows(ql);
    let wmr = right_rows(qr);
    // Rows of M = Ml·Mr (column k of the WGSL matrix is row k).
    let m = wmr * wml;
    let scale = vec4<f32>(
        scale_from_log(log_scales.x),
        scale_from_log(log_scales.y),
        scale_from_log(log_scales.z),
        scale_from_log(log_scales.w),
    );
    let r0 = m[1].yzwx;
    let r1 = m[2].yzwx;
    let r2 = m[3].yzwx;
    let rt = m[0].yzwx;
    let l0 = r0 * scale;
    let l1 = r1 * scale;
    let l2 = r2 * scale;
    let lt = rt * scale;
    let raw44 = dot(lt, lt);
    let s44_ok = raw44 > MIN_TIME_VARIANCE;
    var s44 = MIN_TIME_VARIANCE;
    if s44_ok {
        s44 = raw44;
    }
    let dt = view.t - mean.w;
    let omega = exp(-0.5 * dt * dt / s44);
    let v = vec3<f32>(dot(l0, lt), dot(l1, lt), dot(l2, lt));
    let inv44 = 1.0 / s44;
    let mean3 = mean.xyz + v * (dt / s44);
    let b0 = l0 - v.x * lt * inv44;
    let b1 = l1 - v.y * lt * inv44;
    let b2 = l2 - v.z * lt * inv44;

    // Opacity = sigmoid(logit) · ω · factor.
    let sig = sigmoid(logit);
    let f = factor[i];
    let g_logit = d_opacity * omega * f * sig * (1.0 - sig);
    let g_factor = d_opacity * sig * omega;
    let d_omega = d_opacity * sig * f;

    let d_mean_colour = colour_backward(i, mean, g_c.xyz);

    // Projection forward intermediates.
    let w0 = view.rot0.xyz;
    let w1 = view.rot1.xyz;
    let w2 = view.rot2.xyz;
    let p = vec3<f32>(dot(w0, mean3), dot(w1, mean3), dot(w2, mean3)) + view.trans.xyz;
    let z = p.z;
    let fx = view.focal.x;
    let fy = view.focal.y;
    let cx = view.focal.z;
    let cy = view.focal.w;
    let w = f32(view.width);
    let h = f32(view.height);
    let lo = vec2<f32>((-GUARD_BAND * w - cx) / fx, (-GUARD_BAND * h - cy) / fy);
    let hi = vec2<f32>(((1.0 + GUARD_BAND) * w - cx) / fx, ((1.0 + GUARD_BAND) * h - cy) / fy);
    let u_raw = p.xy / z;
    let u_free = !(u_raw < lo) & !(u_raw > hi);
    let u = clamp(u_raw, lo, hi);
    let iz = 1.0 / z;
    let ja = fx * iz * (w0 - u.x * w2);
    let jb = fy * iz * (w1 - u.y * w2);
    let k0 = ja.x * b0 + ja.y * b1 + ja.z * b2;
    let k1 = jb.x * b0 + jb.y * b1 + jb.z * b2;
    let ca = dot(k0, k0) + LOW_PASS;
    let cb = dot(k0, k1);
    let cc = dot(k1, k1) + LOW_PASS;
    let inv_det = 1.0 / (ca * cc - cb * cb);
    let qa = cc * inv_det;
    let qb = -cb * inv_det;
    let qc = ca * inv_det;

    // project_backward: dΣ2 = −Q dQ Q, dK = (G + Gᵀ) K, dB = Mᵀ dK, dM = dK Bᵀ.
    let dq00 = d_conic.x;
    let dq01 = 0.5 * d_conic.y;
    let dq11 = d_conic.z;
    let t00 = qa * dq00 + qb * dq01;
    let t01 = qa * dq01 + qb * dq11;
    let t10 = qb * dq00 + qc * dq01;
    let t11 = qb * dq01 + qc * dq11;
    let g00 = -(t00 * qa + t01 * qb);
    let g01 = -(t00 * qb + t01 * qc);
    let g10 = -(t10 * qa + t11 * qb);
    let g11 = -(t10 * qb + t11 * qc);
    let dk0 = (g00 + g00) * k0 + (g01 + g10) * k1;
    let dk1 = (g10 + g01) * k0 + (g11 + g11) * k1;
    let db0 = ja.x * dk0 + jb.x * dk1;
    let db1 = ja.y * dk0 + jb.y * dk1;
    let db2 = ja.z * dk0 + jb.z * dk1;
    let dm0 = vec3<f32>(dot(dk0, b0), dot(dk0, b1), dot(dk0, b2));
    let dm1 = vec3<f32>(dot(dk1, b0), dot(dk1, b1), dot(dk1, b2));
    var dp = vec3<f32>(0.0, 0.0, d_depth);
    dp.z -= (dot(dm0, ja) + dot(dm1, jb)) * iz;
    let du = vec2<f32>(-fx * iz * dot(dm0, w2), -fy * iz * dot(dm1, w2));
    if u_free.x {
        dp.x += du.x * iz;
        dp.z -= du.x * p.x * iz * iz;
    }
    if u_free.y {
        dp.y += du.y * iz;
        dp.z -= du.y * p.y * iz * iz;
    }
    dp.x += fx * iz * d_mean2d.x;
    dp.z -= fx * p.x * iz * iz * d_mean2d.x;
    dp.y += fy * iz * d_mean2d.y;
    dp.z -= fy * p.y * iz * iz * d_mean2d.y;
    let d_mean3 = w0 * dp.x + w1 * dp.y + w2 * dp.z;

    // slice_backward: B = A − v lᵀ / s44, μ(t) = μ + v dt / s44, ω = exp(−½ dt² / s44).
    var dl0 = db0;
    var dl1 = db1;
    var dl2 = db2;
    var dlt = -(db0 * v.x + db1 * v.y + db2 * v.z) * inv44;
    var d_v = -vec3<f32>(dot(db0, lt), dot(db1, lt), dot(db2, lt)) * inv44;
    var d_s44 = -dot(d_v, v) * inv44;
    d_v += d_mean3 * dt * inv44;
    let dmv = dot(d_mean3, v);
    var d_dt = dmv * inv44;
    d_s44 -= dmv * dt * inv44 * inv44;
    d_dt -= d_omega * omega * dt * inv44;
    d_s44 += d_omega * omega * 0.5 * dt * dt * inv44 * inv44;
    // v = A l
    dl0 += d_v.x * lt;
    dl1 += d_v.y * lt;
    dl2 += d_v.z * lt;
    dlt += d_v.x * l0 + d_v.y * l1 + d_v.z * l2;
    if s44_ok {
        dlt += 2.0 * d_s44 * lt;
    }
    // L = R diag(scale)
    let ok = vec4<bool>(
        scale_ok(log_scales.x),
        scale_ok(log_scales.y),
        scale_ok(log_scales.z),
        scale_ok(log_scales.w),
    );
    let ds = (dl0 * r0 + dl1 * r1 + dl2 * r2 + dlt * rt) * scale;
    let g_log_scales = select(vec4<f32>(0.0), ds, ok);
    // dM rows from dR rows: R[a][b] = M[(a+1)%4][(b+1)%4].
    let d_m = mat4x4<f32>(
        (dlt * scale).wxyz,
        (dl0 * scale).wxyz,
        (dl1 * scale).wxyz,
        (dl2 * scale).wxyz,
    );
    // rotation_backward: dMl = dM Mrᵀ, dMr = Mlᵀ dM (stored transposed, as above).
    let d_ml = transpose(wmr) * d_m;
    let d_mr = d_m * transpose(wml);
    let d_left = vec4<f32>(
        frobenius(d_ml, left_rows(E0)),
        frobenius(d_ml, left_rows(E1)),
        frobenius(d_ml, left_rows(E2)),
        frobenius(d_ml, left_rows(E3)),
    );
    let d_right = vec4<f32>(
        frobenius(d_mr, right_rows(E0)),
        frobenius(d_mr, right_rows(E1)),
        frobenius(d_mr, right_rows(E2)),
        frobenius(d_mr, right_rows(E3)),
    );
    let g_left = unit_quat_backward(ql, quat_norm(raw_l), d_left);
    let g_right = unit_quat_backward(qr, quat_norm(raw_r), d_right);

    let g_mean = vec4<f32>(d_mean3 + d_mean_colour.xyz, -d_dt + d_mean_colour.w);
    out_params[5u * i] = g_mean;
    out_params[5u * i + 1u] = g_log_scales;
    out_params[5u * i + 2u] = g_left;
    out_params[5u * i + 3u] = g_right;
    out_params[5u * i + 4u] = vec4<f32>(g_logit, g_factor, length(d_mean2d), 0.0);
}
