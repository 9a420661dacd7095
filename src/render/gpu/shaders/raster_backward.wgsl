// Backward of `rasterise`, as the CPU blend backward does (src/render/cpu/blend/scalar.rs
// `backward`): one 16×16 workgroup per tile, one thread per pixel, the tile's entries
// visited back to front from the last one any pixel used. Each pixel starts from its final
// transmittance and divides by (1 − α) to recover the transmittance in front of each
// splat, keeping `behind = Σ wⱼ (cⱼ·dL/dC + zⱼ·dL/dD)` of the splats behind it.
//
// Accumulation: per entry, the 256 pixel contributions (10 gradient components) are summed
// in workgroup memory in a fixed order (16 partial sums of 16, then their sum), and the
// tile's total is written, without atomics, to the entry's slot in `partials` — the slot
// the (tile, Gaussian) key had when `emit` wrote it. A Gaussian's slots are contiguous and
// in tile order, so `preprocess_backward` adds them in the order the CPU does. The result
// is bit-reproducible and needs no float atomics (WGSL has none portably); fixed-point
// integer atomics would be as deterministic but need a per-scene scale, which gradients
// spanning many orders of magnitude (tiny and huge splats) do not allow.

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read> splats: array<Splat>;
@group(0) @binding(2) var<storage, read> sorted_value: array<u32>;
@group(0) @binding(3) var<storage, read> ranges: array<vec2<u32>>;
// Per pixel: (bits of the final transmittance, last contributing entry + 1), from `rasterise`.
@group(0) @binding(4) var<storage, read> pixel_state: array<vec2<u32>>;
// dL/d(output) in planes: RGB (3 per pixel), then alpha, then depth.
@group(0) @binding(5) var<storage, read> upstream: array<f32>;
// Inclusive scan of the tile counts: Gaussian i's slots end at ends[i].
@group(0) @binding(6) var<storage, read> ends: array<u32>;
// PARTIAL_STRIDE floats per slot: mean (2), opacity, depth | conic (3), 0 | colour (3), 0.
@group(0) @binding(7) var<storage, read_write> partials: array<f32>;

const ALPHA_MAX: f32 = 0.99;
const ALPHA_MIN: f32 = 0.003921569; // 1/255
const MIN_POWER_FLOOR: f32 = -4.5; // -½·3²
// Splats loaded into workgroup memory at a time.
const BATCH: u32 = 64u;
// Gradient components per entry, and the groups of 16 pixels summed first.
const COMPONENTS: u32 = 10u;
const SEGMENTS: u32 = 16u;
const PARTIAL_STRIDE: u32 = 12u;

var<workgroup> batch: array<Splat, BATCH>;
var<workgroup> batch_slot: array<u32, BATCH>;
var<workgroup> pixel_grads: array<array<f32, WG>, COMPONENTS>;
var<workgroup> segment_sums: array<array<f32, SEGMENTS>, COMPONENTS>;
var<workgroup> last_atomic: atomic<u32>;
var<workgroup> last_snapshot: u32;

// Where `emit` put the key of Gaussian `gid` (splat `s`) for tile (tx, ty).
fn slot_of(gid: u32, s: Splat, tx: u32, ty: u32) -> u32 {
    let tx0 = u32(s.rect.x) / TILE;
    let tx1 = u32(s.rect.y) / TILE;
    let ty0 = u32(s.rect.z) / TILE;
    let ty1 = u32(s.rect.w) / TILE;
    let wx = tx1 - tx0 + 1u;
    return ends[gid] - wx * (ty1 - ty0 + 1u) + (ty - ty0) * wx + (tx - tx0);
}

// Component c's offset inside a slot (colour starts on the third vec4).
fn component_offset(c: u32) -> u32 {
    return c + select(0u, 1u, c >= 7u);
}

@compute @workgroup_size(16, 16)
fn rasterise_backward(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_id) lid3: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let tile = wid.x + wid.y * view.tiles_x;
    let px = wid.x * TILE + lid3.x;
    let py = wid.y * TILE + lid3.y;
    let inside = px < view.width && py < view.height;
    let range = ranges[tile];
    let n = range.y - min(range.x, range.y);
    let fx = f32(px) + 0.5;
    let fy = f32(py) + 0.5;
    let ipx = i32(px);
    let ipy = i32(py);

    var final_t = 1.0;
    var n_contrib = 0u;
    var d_rgb = vec3<f32>(0.0);
    var d_alpha_px = 0.0;
    var d_depth_px = 0.0;
    if inside {
        let p = py * view.width + px;
        let npix = view.width * view.height;
        let st = pixel_state[p];
        final_t = bitcast<f32>(st.x);
        n_contrib = st.y;
        d_rgb = vec3<f32>(upstream[3u * p], upstream[3u * p + 1u], upstream[3u * p + 2u]);
        d_alpha_px = upstream[3u * npix + p];
        d_depth_px = upstream[4u * npix + p];
    }
    // T_final (dL/dA − bg·dL/dC): the background's and alpha's share of every dL/dα.
    let tail = final_t * (d_alpha_px - dot(view.background.xyz, d_rgb));
    var trans = final_t;
    var behind = 0.0;

    if lid == 0u {
        atomicStore(&last_atomic, 0u);
    }
    workgroupBarrier();
    atomicMax(&last_atomic, n_contrib);
    workgroupBarrier();
    if lid == 0u {
        last_snapshot = atomicLoad(&last_atomic);
    }
    let k_max = min(workgroupUniformLoad(&last_snapshot), n);

    var end = k_max;
    loop {
        if end == 0u {
            break;
        }
        let start = end - min(end, BATCH);
        let m = end - start;
        workgroupBarrier();
        if lid < m {
            let gid = sorted_value[range.x + start + lid];
            let s = splats[gid];
            batch[lid] = s;
            batch_slot[lid] = slot_of(gid, s, wid.x, wid.y);
        }
        workgroupBarrier();
        for (var jj = m; jj > 0u; jj--) {
            let j = jj - 1u;
            let s = batch[j];
            var g_mean = vec2<f32>(0.0);
            var g_conic = vec3<f32>(0.0);
            var g_opacity = 0.0;
            var g_colour = vec3<f32>(0.0);
            var g_depth = 0.0;
            let in_rect = ipx >= s.rect.x && ipx <= s.rect.y && ipy >= s.rect.z && ipy <= s.rect.w;
            if start + j < n_contrib && in_rect {
                let mdo = s.mean_depth_opacity;
                let q = s.conic_min_power;
                let dx = fx - mdo.x;
                let dy = fy - mdo.y;
                let power = -0.5 * (q.x * dx * dx + q.z * dy * dy) - q.y * dx * dy;
                let g = exp(power);
                let a = min(ALPHA_MAX, mdo.w * g);
                if power <= 0.0 && power >= max(q.w, MIN_POWER_FLOOR) && a >= ALPHA_MIN {
                    let inv_one_minus = 1.0 / (1.0 - a);
                    trans *= inv_one_minus;
                    let w = a * trans;
                    g_colour = w * d_rgb;
                    g_depth = w * d_depth_px;
                    let cd = dot(s.colour.xyz, d_rgb) + mdo.z * d_depth_px;
                    let d_alpha = cd * trans + (tail - behind) * inv_one_minus;
                    behind += w * cd;
                    if !(mdo.w * g > ALPHA_MAX) {
                        // α = opacity · exp(power)
                        g_opacity = g * d_alpha;
                        let d_power = mdo.w * g * d_alpha;
                        g_conic = vec3<f32>(-0.5 * dx * dx, -dx * dy, -0.5 * dy * dy) * d_power;
                        g_mean = vec2<f32>(q.x * dx + q.y * dy, q.z * dy + q.y * dx) * d_power;
                    }
                }
            }
            pixel_grads[0][lid] = g_mean.x;
            pixel_grads[1][lid] = g_mean.y;
            pixel_grads[2][lid] = g_opacity;
            pixel_grads[3][lid] = g_depth;
            pixel_grads[4][lid] = g_conic.x;
            pixel_grads[5][lid] = g_conic.y;
            pixel_grads[6][lid] = g_conic.z;
            pixel_grads[7][lid] = g_colour.x;
            pixel_grads[8][lid] = g_colour.y;
            pixel_grads[9][lid] = g_colour.z;
            workgroupBarrier();
            if lid < COMPONENTS * SEGMENTS {
                let c = lid / SEGMENTS;
                let first = (lid % SEGMENTS) * SEGMENTS;
                var acc = 0.0;
                for (var r = 0u; r < SEGMENTS; r++) {
                    acc += pixel_grads[c][first + r];
                }
                segment_sums[c][lid % SEGMENTS] = acc;
            }
            workgroupBarrier();
            if lid < COMPONENTS {
                var acc = 0.0;
                for (var r = 0u; r < SEGMENTS; r++) {
                    acc += segment_sums[lid][r];
                }
                partials[PARTIAL_STRIDE * batch_slot[j] + component_offset(lid)] = acc;
            }
        }
        end = start;
    }
}
