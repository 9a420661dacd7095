// Per sorted entry: where each tile's run of entries starts and ends (`ranges` is zeroed
// first, so untouched tiles stay empty).
@group(0) @binding(0) var<uniform> range_len: vec4<u32>;
@group(0) @binding(1) var<storage, read> sorted_tile: array<u32>;
@group(0) @binding(2) var<storage, read_write> ranges: array<vec2<u32>>;

@compute @workgroup_size(256)
fn tile_ranges(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let k = flat_index(wid, nwg, lid);
    let m = range_len.x;
    if k >= m {
        return;
    }
    let tile = sorted_tile[k];
    if k == 0u || sorted_tile[k - 1u] != tile {
        ranges[tile].x = k;
    }
    if k + 1u == m || sorted_tile[k + 1u] != tile {
        ranges[tile].y = k + 1u;
    }
}
