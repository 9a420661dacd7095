// Front-to-back α-blending, one 16×16 workgroup per tile and one thread per pixel, as the
// CPU blend does (src/render/cpu/blend): `α = min(0.99, opacity·exp(power))`, splats with
// `α < 1/255` or outside their support are skipped, and a pixel stops before its
// transmittance would fall below 1e-4. The tile's splats are loaded 256 at a time into
// workgroup memory; the workgroup stops as soon as every pixel has stopped. For the
// backward pass it also keeps, per pixel, the final transmittance and how many list
// entries were visited up to the last contributing one (the CPU's `final_t`, `n_contrib`).

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read> splats: array<Splat>;
@group(0) @binding(2) var<storage, read> sorted_value: array<u32>;
@group(0) @binding(3) var<storage, read> ranges: array<vec2<u32>>;
@group(0) @binding(4) var<storage, read_write> out_rgb: array<f32>;
@group(0) @binding(5) var<storage, read_write> out_alpha: array<f32>;
@group(0) @binding(6) var<storage, read_write> out_depth: array<f32>;
// Per pixel: (bits of the final transmittance, last contributing entry + 1).
@group(0) @binding(7) var<storage, read_write> out_state: array<vec2<u32>>;

const ALPHA_MAX: f32 = 0.99;
const ALPHA_MIN: f32 = 0.003921569; // 1/255
const TRANSMITTANCE_MIN: f32 = 1e-4;
const MIN_POWER_FLOOR: f32 = -4.5; // -½·3²

var<workgroup> batch: array<Splat, 256>;
var<workgroup> done_count: atomic<u32>;
var<workgroup> done_snapshot: u32;

@compute @workgroup_size(16, 16)
fn rasterise(
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

    var trans = 1.0;
    var colour = vec3<f32>(0.0);
    var depth = 0.0;
    var last = 0u;
    var done = !inside;
    if lid == 0u {
        atomicStore(&done_count, 0u);
    }
    workgroupBarrier();
    if done {
        atomicAdd(&done_count, 1u);
    }
    for (var start = 0u; start < n; start += WG) {
        workgroupBarrier();
        if lid == 0u {
            done_snapshot = atomicLoad(&done_count);
        }
        if workgroupUniformLoad(&done_snapshot) == WG {
            break;
        }
        if start + lid < n {
            batch[lid] = splats[sorted_value[range.x + start + lid]];
        }
        workgroupBarrier();
        let m = min(WG, n - start);
        for (var j = 0u; j < m && !done; j++) {
            let s = batch[j];
            if ipx < s.rect.x || ipx > s.rect.y || ipy < s.rect.z || ipy > s.rect.w {
                continue;
            }
            let dx = fx - s.mean_depth_opacity.x;
            let dy = fy - s.mean_depth_opacity.y;
            let q = s.conic_min_power;
            let power = -0.5 * (q.x * dx * dx + q.z * dy * dy) - q.y * dx * dy;
            if power > 0.0 || power < max(q.w, MIN_POWER_FLOOR) {
                continue;
            }
            let a = min(ALPHA_MAX, s.mean_depth_opacity.w * exp(power));
            if a < ALPHA_MIN {
                continue;
            }
            let next = trans * (1.0 - a);
            if next < TRANSMITTANCE_MIN {
                done = true;
                atomicAdd(&done_count, 1u);
                break;
            }
            let w = a * trans;
            colour += s.colour.xyz * w;
            depth += s.mean_depth_opacity.z * w;
            trans = next;
            last = start + j + 1u;
        }
    }
    if inside {
        let p = py * view.width + px;
        let c = colour + trans * view.background.xyz;
        out_rgb[3u * p] = c.x;
        out_rgb[3u * p + 1u] = c.y;
        out_rgb[3u * p + 2u] = c.z;
        out_alpha[p] = 1.0 - trans;
        out_depth[p] = depth;
        out_state[p] = vec2<u32>(bitcast<u32>(trans), last);
    }
}
