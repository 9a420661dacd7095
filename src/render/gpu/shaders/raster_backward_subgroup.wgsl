// `rasterise_backward` with subgroup operations (adapters with the `subgroups` feature and
// subgroups of 8 or more invocations): each subgroup sums its pixels' gradients of an
// entry with `subgroupAdd`, its first invocation writes the sum to workgroup memory, and
// after every CHUNK entries one barrier lets CHUNK invocations add the subgroups' sums in
// subgroup order and write the entries' slots. The sums alternate between two buffers, so
// that a chunk's sums are written while the one before is read. One barrier per CHUNK
// entries instead of two per entry. The pixel's part is in `raster_backward_pixel.wgsl`.
// (wgpu's WGSL takes subgroup operations without an `enable` once the device has them.)

const CHUNK: u32 = 4u;
// A 256-invocation workgroup has at most 32 subgroups of 8 or more.
const MAX_SUBGROUPS: u32 = 32u;
const SUM_SLOTS: u32 = 2u * CHUNK * MAX_SUBGROUPS;

// [buffer][entry of the chunk][subgroup]
var<workgroup> sums_a: array<vec4<f32>, SUM_SLOTS>;
var<workgroup> sums_b: array<vec4<f32>, SUM_SLOTS>;
var<workgroup> sums_c: array<vec2<f32>, SUM_SLOTS>;

// One-dimensional (subgroup builtins need that): pixel (lid mod 16, lid / 16) of the tile.
@compute @workgroup_size(256)
fn rasterise_backward(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
    @builtin(subgroup_invocation_id) lane: u32,
    @builtin(subgroup_id) subgroup: u32,
    @builtin(num_subgroups) subgroups: u32,
) {
    let tile = wid.x + wid.y * view.tiles_x;
    let range = ranges[tile];
    let n = range.y - min(range.x, range.y);
    var p = pixel_at(wid.x * TILE + lid % TILE, wid.y * TILE + lid / TILE);
    var end = used_entries(p.n_contrib, lid, n);
    var buffer = 0u;
    loop {
        if end == 0u {
            break;
        }
        let start = end - min(end, BATCH);
        let m = end - start;
        load_batch(range.x, start, m, lid, wid.xy);
        var jj = m;
        loop {
            if jj == 0u {
                break;
            }
            let count = min(jj, CHUNK);
            let base = buffer * CHUNK * MAX_SUBGROUPS;
            for (var e = 0u; e < count; e++) {
                let g = entry_gradient(&p, batch[jj - 1u - e], start + jj - 1u - e);
                // Most entries reach few of a tile's rows: a subgroup none of whose
                // pixels they reach skips the sums.
                let reached = any(g.a != vec4<f32>(0.0)) || any(g.b != vec4<f32>(0.0)) || any(g.c != vec2<f32>(0.0));
                var a = vec4<f32>(0.0);
                var b = vec4<f32>(0.0);
                var c = vec2<f32>(0.0);
                if subgroupAny(reached) {
                    a = subgroupAdd(g.a);
                    b = subgroupAdd(g.b);
                    c = subgroupAdd(g.c);
                }
                if lane == 0u {
                    let at = base + e * MAX_SUBGROUPS + subgroup;
                    sums_a[at] = a;
                    sums_b[at] = b;
                    sums_c[at] = c;
                }
            }
            workgroupBarrier();
            if lid < count {
                var a = vec4<f32>(0.0);
                var b = vec4<f32>(0.0);
                var c = vec2<f32>(0.0);
                let first = base + lid * MAX_SUBGROUPS;
                for (var r = 0u; r < subgroups; r++) {
                    a += sums_a[first + r];
                    b += sums_b[first + r];
                    c += sums_c[first + r];
                }
                write_partial(jj - 1u - lid, a, b, c);
            }
            buffer = 1u - buffer;
            jj -= count;
        }
        end = start;
    }
}
