// Per Gaussian with tiles: one (tile, depth) key and its Gaussian index per touched tile,
// at the offset the inclusive scan of `tiles_touched` gives. Keys are written in Gaussian
// order, so a stable sort keeps ties of depth in index order, as on the CPU.

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read> splats: array<Splat>;
@group(0) @binding(2) var<storage, read> counts: array<u32>;
@group(0) @binding(3) var<storage, read> ends: array<u32>;
@group(0) @binding(4) var<storage, read_write> key_tile: array<u32>;
@group(0) @binding(5) var<storage, read_write> key_depth: array<u32>;
@group(0) @binding(6) var<storage, read_write> key_value: array<u32>;

@compute @workgroup_size(256)
fn emit(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_index(wid, nwg, lid);
    if i >= view.count {
        return;
    }
    let n = counts[i];
    if n == 0u {
        return;
    }
    let s = splats[i];
    let depth_bits = bitcast<u32>(max(s.mean_depth_opacity.z, 0.0));
    let tx0 = u32(s.rect.x) / TILE;
    let tx1 = u32(s.rect.y) / TILE;
    let ty0 = u32(s.rect.z) / TILE;
    let ty1 = u32(s.rect.w) / TILE;
    var at = ends[i] - n;
    for (var ty = ty0; ty <= ty1; ty++) {
        for (var tx = tx0; tx <= tx1; tx++) {
            key_tile[at] = ty * view.tiles_x + tx;
            key_depth[at] = depth_bits;
            key_value[at] = i;
            at++;
        }
    }
}
