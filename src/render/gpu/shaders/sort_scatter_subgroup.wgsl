// `scatter` with subgroup operations, for adapters whose subgroups have one fixed size of
// 8 to 128 invocations (so a 256-invocation workgroup is whole subgroups): the block's
// entries are taken in (subgroup, lane) order; per digit, one ballot gives each entry its
// rank inside its subgroup and each subgroup its count; one barrier, a scan of the counts
// over the subgroups, another barrier. The rest of the sort is in `sort.wgsl`.

// A 256-invocation workgroup has at most 32 subgroups of 8 or more.
const MAX_SUBGROUPS: u32 = 32u;

// [subgroup][digit]: the subgroup's entries of the digit, then the entries of that digit
// in the subgroups before it.
var<workgroup> before: array<array<u32, 16>, MAX_SUBGROUPS>;
// [digit]: the block's entries of the digit.
var<workgroup> in_block: array<u32, 16>;

// Set bits of `b` (a ballot) for the lanes below `lane`.
fn bits_below(b: vec4<u32>, lane: u32) -> u32 {
    var n = 0u;
    for (var w = 0u; w < 4u; w++) {
        let first = 32u * w;
        if lane >= first + 32u {
            n += countOneBits(b[w]);
        } else if lane > first {
            n += countOneBits(b[w] & ((1u << (lane - first)) - 1u));
        }
    }
    return n;
}

@compute @workgroup_size(256)
fn scatter(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
    @builtin(subgroup_invocation_id) lane: u32,
    @builtin(subgroup_size) size: u32,
    @builtin(subgroup_id) subgroup: u32,
    @builtin(num_subgroups) subgroups: u32,
) {
    let block = wid.x + wid.y * nwg.x;
    let i = block * WG + subgroup * size + lane;
    let valid = i < pass_.count;
    // 16: no digit (past the end).
    var d = 16u;
    if valid {
        d = digit_of(i);
    }
    var rank = 0u;
    for (var v = 0u; v < 16u; v++) {
        let b = subgroupBallot(d == v);
        if d == v {
            rank = bits_below(b, lane);
        }
        if lane == 0u {
            before[subgroup][v] = countOneBits(b.x) + countOneBits(b.y) + countOneBits(b.z) + countOneBits(b.w);
        }
    }
    workgroupBarrier();
    if lid < 16u {
        var sum = 0u;
        for (var s = 0u; s < subgroups; s++) {
            let count = before[s][lid];
            before[s][lid] = sum;
            sum += count;
        }
        in_block[lid] = sum;
    }
    workgroupBarrier();
    if !valid || block >= pass_.blocks {
        return;
    }
    move_entry(i, d, block, in_block[d], before[subgroup][d] + rank);
}
