// `rasterise_backward` where subgroup operations are missing (or turned off with
// SPLAT4D_GPU_SUBGROUPS=0): per entry, the 256 pixel gradients (10 components) are summed
// in workgroup memory in a fixed order (16 partial sums of 16, then their sum), so the
// result is the same on every adapter. Two workgroup barriers per entry. The pixel's part
// is in `raster_backward_pixel.wgsl`.

// Gradient components per entry, and the groups of 16 pixels summed first.
const COMPONENTS: u32 = 10u;
const SEGMENTS: u32 = 16u;

var<workgroup> pixel_grads: array<array<f32, WG>, COMPONENTS>;
var<workgroup> segment_sums: array<array<f32, SEGMENTS>, COMPONENTS>;

@compute @workgroup_size(16, 16)
fn rasterise_backward(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_id) lid3: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let tile = wid.x + wid.y * view.tiles_x;
    let range = ranges[tile];
    let n = range.y - min(range.x, range.y);
    var p = pixel_at(wid.x * TILE + lid3.x, wid.y * TILE + lid3.y);
    var end = used_entries(p.n_contrib, lid, n);
    loop {
        if end == 0u {
            break;
        }
        let start = end - min(end, BATCH);
        let m = end - start;
        load_batch(range.x, start, m, lid, wid.xy);
        for (var jj = m; jj > 0u; jj--) {
            let j = jj - 1u;
            let g = entry_gradient(&p, batch[j], start + j);
            pixel_grads[0][lid] = g.a.x;
            pixel_grads[1][lid] = g.a.y;
            pixel_grads[2][lid] = g.a.z;
            pixel_grads[3][lid] = g.a.w;
            pixel_grads[4][lid] = g.b.x;
            pixel_grads[5][lid] = g.b.y;
            pixel_grads[6][lid] = g.b.z;
            pixel_grads[7][lid] = g.b.w;
            pixel_grads[8][lid] = g.c.x;
            pixel_grads[9][lid] = g.c.y;
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
                // Colour starts on the slot's third vec4.
                partials[PARTIAL_STRIDE * batch_slot[j] + lid + select(0u, 1u, lid >= 7u)] = acc;
            }
        }
        end = start;
    }
}
