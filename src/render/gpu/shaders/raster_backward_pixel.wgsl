// The backward of `rasterise` for one pixel, shared by its two kernels (src/render/gpu/
// kernels.rs picks one): `raster_backward.wgsl`, which sums the pixels' gradients in
// workgroup memory, and `raster_backward_subgroup.wgsl`, which sums them with subgroup
// operations. As the CPU blend backward does (src/render/cpu/blend/scalar.rs `backward`):
// one 16×16 workgroup per tile, one thread per pixel, the tile's entries visited back to
// front from the last one any pixel used. Each pixel starts from its final transmittance
// and divides by (1 − α) to recover the transmittance in front of each splat, keeping
// `behind = Σ wⱼ (cⱼ·dL/dC + zⱼ·dL/dD)` of the splats behind it.
//
// Each entry's 10 gradient components, summed over the tile's pixels, go without atomics
// to the entry's slot in `partials` — the slot the (tile, Gaussian) key had when `emit`
// wrote it. A Gaussian's slots are contiguous and in tile order, so `preprocess_backward`
// adds them in the order the CPU does. Both kernels sum in an order fixed by the hardware,
// so a result is reproducible run to run; WGSL has no portable float atomics, and
// fixed-point integer atomics would need a per-scene scale, which gradients spanning many
// orders of magnitude (tiny and huge splats) do not allow.

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
const PARTIAL_STRIDE: u32 = 12u;

var<workgroup> batch: array<Splat, BATCH>;
var<workgroup> batch_slot: array<u32, BATCH>;
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

// One pixel walking back through its tile's entries.
struct Pixel {
    fx: f32,
    fy: f32,
    x: i32,
    y: i32,
    // Entries in front of its last contributing one + 1.
    n_contrib: u32,
    d_rgb: vec3<f32>,
    d_depth: f32,
    // T_final (dL/dA − bg·dL/dC): the background's and alpha's share of every dL/dα.
    tail: f32,
    // Transmittance in front of the entry reached, and `behind`.
    trans: f32,
    behind: f32,
}

fn pixel_at(px: u32, py: u32) -> Pixel {
    var p = Pixel(f32(px) + 0.5, f32(py) + 0.5, i32(px), i32(py), 0u, vec3<f32>(0.0), 0.0, 0.0, 1.0, 0.0);
    if px < view.width && py < view.height {
        let i = py * view.width + px;
        let npix = view.width * view.height;
        let st = pixel_state[i];
        p.trans = bitcast<f32>(st.x);
        p.n_contrib = st.y;
        p.d_rgb = vec3<f32>(upstream[3u * i], upstream[3u * i + 1u], upstream[3u * i + 2u]);
        p.d_depth = upstream[4u * npix + i];
        p.tail = p.trans * (upstream[3u * npix + i] - dot(view.background.xyz, p.d_rgb));
    }
    return p;
}

// The entries of the tile any of its pixels used (of `n`): the same for the whole
// workgroup. Every invocation calls it.
fn used_entries(n_contrib: u32, lid: u32, n: u32) -> u32 {
    if lid == 0u {
        atomicStore(&last_atomic, 0u);
    }
    workgroupBarrier();
    atomicMax(&last_atomic, n_contrib);
    workgroupBarrier();
    if lid == 0u {
        last_snapshot = atomicLoad(&last_atomic);
    }
    return min(workgroupUniformLoad(&last_snapshot), n);
}

// Load the tile's entries [start, start + m) into `batch` (m ≤ BATCH). Every invocation
// calls it.
fn load_batch(range_start: u32, start: u32, m: u32, lid: u32, tile: vec2<u32>) {
    workgroupBarrier();
    if lid < m {
        let gid = sorted_value[range_start + start + lid];
        let s = splats[gid];
        batch[lid] = s;
        batch_slot[lid] = slot_of(gid, s, tile.x, tile.y);
    }
    workgroupBarrier();
}

// One pixel's gradient for one entry, in the slot's order: mean (2), opacity, depth |
// conic (3), colour r | colour g, b.
struct EntryGradient {
    a: vec4<f32>,
    b: vec4<f32>,
    c: vec2<f32>,
}

// Pixel `p`'s gradient for entry `k` of its tile (splat `s`), stepping `p` back past it.
fn entry_gradient(p: ptr<function, Pixel>, s: Splat, k: u32) -> EntryGradient {
    var out = EntryGradient(vec4<f32>(0.0), vec4<f32>(0.0), vec2<f32>(0.0));
    let in_rect = (*p).x >= s.rect.x && (*p).x <= s.rect.y && (*p).y >= s.rect.z && (*p).y <= s.rect.w;
    if k >= (*p).n_contrib || !in_rect {
        return out;
    }
    let mdo = s.mean_depth_opacity;
    let q = s.conic_min_power;
    let dx = (*p).fx - mdo.x;
    let dy = (*p).fy - mdo.y;
    let power = -0.5 * (q.x * dx * dx + q.z * dy * dy) - q.y * dx * dy;
    let g = exp(power);
    let a = min(ALPHA_MAX, mdo.w * g);
    if !(power <= 0.0 && power >= max(q.w, MIN_POWER_FLOOR) && a >= ALPHA_MIN) {
        return out;
    }
    let inv_one_minus = 1.0 / (1.0 - a);
    (*p).trans *= inv_one_minus;
    let trans = (*p).trans;
    let w = a * trans;
    let d_rgb = (*p).d_rgb;
    let colour = w * d_rgb;
    let cd = dot(s.colour.xyz, d_rgb) + mdo.z * (*p).d_depth;
    let d_alpha = cd * trans + ((*p).tail - (*p).behind) * inv_one_minus;
    (*p).behind += w * cd;
    var g_mean = vec2<f32>(0.0);
    var g_conic = vec3<f32>(0.0);
    var g_opacity = 0.0;
    if !(mdo.w * g > ALPHA_MAX) {
        // α = opacity · exp(power)
        g_opacity = g * d_alpha;
        let d_power = mdo.w * g * d_alpha;
        g_conic = vec3<f32>(-0.5 * dx * dx, -dx * dy, -0.5 * dy * dy) * d_power;
        g_mean = vec2<f32>(q.x * dx + q.y * dy, q.z * dy + q.y * dx) * d_power;
    }
    out.a = vec4<f32>(g_mean, g_opacity, w * (*p).d_depth);
    out.b = vec4<f32>(g_conic, colour.x);
    out.c = colour.yz;
    return out;
}

// Write entry `j` of the batch's tile sums to its slot.
fn write_partial(j: u32, a: vec4<f32>, b: vec4<f32>, c: vec2<f32>) {
    let at = PARTIAL_STRIDE * batch_slot[j];
    partials[at] = a.x;
    partials[at + 1u] = a.y;
    partials[at + 2u] = a.z;
    partials[at + 3u] = a.w;
    partials[at + 4u] = b.x;
    partials[at + 5u] = b.y;
    partials[at + 6u] = b.z;
    partials[at + 8u] = b.w;
    partials[at + 9u] = c.x;
    partials[at + 10u] = c.y;
}
