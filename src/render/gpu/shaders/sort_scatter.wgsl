// `scatter` without subgroup operations: an entry's rank among the block's entries of its
// digit comes from a workgroup scan of packed per-digit flags (two 16-bit counters per
// word), 16 barriers per block. The rest of the sort is in `sort.wgsl`.

var<workgroup> packed: array<array<u32, 8>, 256>;

@compute @workgroup_size(256)
fn scatter(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let block = wid.x + wid.y * nwg.x;
    let i = block * WG + lid;
    let valid = i < pass_.count;
    var d = 0u;
    var mine = array<u32, 8>(0u, 0u, 0u, 0u, 0u, 0u, 0u, 0u);
    if valid {
        d = digit_of(i);
        mine[d >> 1u] = 1u << ((d & 1u) * 16u);
    }
    packed[lid] = mine;
    workgroupBarrier();
    for (var step = 1u; step < WG; step <<= 1u) {
        var add = array<u32, 8>(0u, 0u, 0u, 0u, 0u, 0u, 0u, 0u);
        if lid >= step {
            add = packed[lid - step];
        }
        workgroupBarrier();
        for (var w = 0u; w < 8u; w++) {
            packed[lid][w] += add[w];
        }
        workgroupBarrier();
    }
    if !valid || block >= pass_.blocks {
        return;
    }
    let word = d >> 1u;
    let bit = (d & 1u) * 16u;
    let rank = ((packed[lid][word] >> bit) & 0xffffu) - 1u;
    let total = (packed[WG - 1u][word] >> bit) & 0xffffu;
    move_entry(i, d, block, total, rank);
}
