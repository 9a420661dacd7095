// One pass of a stable least-significant-digit radix sort of (tile, depth, value) entries
// by 4 bits of the tile or depth key. `histogram` counts each block's digits into a
// digit-major table; after an inclusive scan of that table, `scatter` moves every entry
// to its digit's slot, keeping the order of equal digits. Two `scatter`s rank the entries
// of a block (src/render/gpu/kernels.rs picks one): `sort_scatter.wgsl` with a workgroup
// scan, `sort_scatter_subgroup.wgsl` with subgroup ballots.

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

// Move entry i, of digit d, to its slot: the digit's end in this block (the scanned
// table) less the block's entries of that digit, plus the entry's rank among them.
fn move_entry(i: u32, d: u32, block: u32, in_block: u32, rank: u32) {
    let dst = table[d * pass_.blocks + block] - in_block + rank;
    dst_tile[dst] = src_tile[i];
    dst_depth[dst] = src_depth[i];
    dst_value[dst] = src_value[i];
}
