// One pass of a stable least-significant-digit radix sort of (tile, depth, value) entries
// by 4 bits of the tile or depth key. `histogram` counts each block's digits into a
// digit-major table; after an inclusive scan of that table, `scatter` moves every entry
// to its digit's slot, keeping the order of equal digits (ranks come from a workgroup
// scan of packed per-digit flags, two 16-bit counters per word).

struct Pass {
    count: u32,
    shift: u32,
    blocks: u32,
    // 0: digits of the depth key, 1: of the tile key.
    by_tile: u32,
}

@group(0) @binding(0) var<uniform> pass_: Pass;
@group(0) @binding(1) var<storage, read> src_tile: array<u32>;
@group(0) @binding(2) var<storage, read> src_depth: array<u32>;
@group(0) @binding(3) var<storage, read> src_value: array<u32>;
@group(0) @binding(4) var<storage, read_write> dst_tile: array<u32>;
@group(0) @binding(5) var<storage, read_write> dst_depth: array<u32>;
@group(0) @binding(6) var<storage, read_write> dst_value: array<u32>;
@group(0) @binding(7) var<storage, read_write> table: array<u32>;

var<workgroup> digit_count: array<atomic<u32>, 16>;
var<workgroup> packed: array<array<u32, 8>, 256>;

fn digit_of(i: u32) -> u32 {
    var key = src_depth[i];
    if pass_.by_tile != 0u {
        key = src_tile[i];
    }
    return (key >> pass_.shift) & 15u;
}

@compute @workgroup_size(256)
fn histogram(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let block = wid.x + wid.y * nwg.x;
    if lid < 16u {
        atomicStore(&digit_count[lid], 0u);
    }
    workgroupBarrier();
    let i = block * WG + lid;
    if i < pass_.count {
        atomicAdd(&digit_count[digit_of(i)], 1u);
    }
    workgroupBarrier();
    if lid < 16u && block < pass_.blocks {
        table[lid * pass_.blocks + block] = atomicLoad(&digit_count[lid]);
    }
}

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
    let dst = table[d * pass_.blocks + block] - total + rank;
    dst_tile[dst] = src_tile[i];
    dst_depth[dst] = src_depth[i];
    dst_value[dst] = src_value[i];
}
