// Inclusive prefix sum of u32, in place, in blocks of 256: `scan_blocks` scans each block
// and writes its total to `block_sums`; after `block_sums` is scanned the same way,
// `add_block_offsets` adds each block's predecessor total to its elements.

@group(0) @binding(0) var<uniform> len: vec4<u32>;
@group(0) @binding(1) var<storage, read_write> data: array<u32>;
@group(0) @binding(2) var<storage, read_write> block_sums: array<u32>;

var<workgroup> buf: array<u32, 256>;

@compute @workgroup_size(256)
fn scan_blocks(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let block = wid.x + wid.y * nwg.x;
    let i = block * WG + lid;
    var v = 0u;
    if i < len.x {
        v = data[i];
    }
    buf[lid] = v;
    workgroupBarrier();
    for (var step = 1u; step < WG; step <<= 1u) {
        var add = 0u;
        if lid >= step {
            add = buf[lid - step];
        }
        workgroupBarrier();
        buf[lid] += add;
        workgroupBarrier();
    }
    if i < len.x {
        data[i] = buf[lid];
    }
    if lid == WG - 1u {
        block_sums[block] = buf[lid];
    }
}

@compute @workgroup_size(256)
fn add_block_offsets(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let block = wid.x + wid.y * nwg.x;
    let i = block * WG + lid;
    if block > 0u && i < len.x {
        data[i] += block_sums[block - 1u];
    }
}
