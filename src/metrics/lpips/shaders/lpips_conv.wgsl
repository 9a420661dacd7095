// LPIPS-alex on the GPU (src/metrics/lpips/gpu.rs): one AlexNet convolution with bias and
// ReLU over a batch of same-sized channels-last maps, as the CPU's `Conv2d::forward_relu`
// (src/metrics/lpips/conv.rs) computes it.
//
// Implicit GEMM: the outputs of the batch are a (images·out_h·out_w) × out_channels matrix,
// the product of the receptive fields (one row of size²·in_channels values per output
// pixel, in the kernel's HWIO order, zeros where the padding is) with the HWIO kernel seen
// as a (size²·in_channels) × out_channels matrix. A workgroup computes a 64 × 64 tile of it
// (64 output pixels × 64 channels, 4 × 4 per invocation), stepping through the fields 16
// values at a time: each step gathers the tile's 64 × 16 field values and 16 × 64 kernel
// weights into workgroup memory once. Each output sums its terms in field order.

struct Conv {
    in_width: u32,
    in_height: u32,
    in_channels: u32,
    out_channels: u32,
    out_width: u32,
    out_height: u32,
    size: u32,
    stride: u32,
    padding: u32,
    // Output pixels of the whole batch (matrix rows), values per receptive field.
    rows: u32,
    field: u32,
    // Tiles of 64 rows.
    tiles_m: u32,
}

@group(0) @binding(0) var<uniform> conv: Conv;
@group(0) @binding(1) var<storage, read> conv_in: array<f32>;
@group(0) @binding(2) var<storage, read> weights: array<f32>;
@group(0) @binding(3) var<storage, read> bias: array<f32>;
@group(0) @binding(4) var<storage, read_write> conv_out: array<f32>;

const BM: u32 = 64u;
const BN: u32 = 64u;
const BK: u32 = 16u;
// Row stride of `field_tile`: one more than BM, so that the 16 invocations storing one
// pixel's 16 field values hit 16 different banks.
const BM_PAD: u32 = 65u;
// An input row no pixel has: rows past the batch's end read only zeros.
const NO_ROW: i32 = -1048576;

// [k][m]: field value k of the tile's pixel m.
var<workgroup> field_tile: array<f32, 1040>;
// [k][n]: kernel weight of field value k for the tile's channel n.
var<workgroup> weight_tile: array<f32, 1024>;

@compute @workgroup_size(256)
fn conv_relu(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let tile_m = wid.x + wid.z * nwg.x;
    if tile_m >= conv.tiles_m {
        return;
    }
    let row0 = tile_m * BM;
    let col0 = wid.y * BN;
    let tx = lid % 16u;
    let ty = lid / 16u;

    // What this invocation gathers: field value `load_k` of pixels `load_m + 16 r`.
    let load_k = lid % BK;
    let load_m = lid / BK;
    var image_row: array<u32, 4>;
    var y0: array<i32, 4>;
    var x0: array<i32, 4>;
    for (var r = 0u; r < 4u; r++) {
        let row = row0 + load_m + 16u * r;
        let o = batch_pixel(row, conv.out_width, conv.out_height);
        image_row[r] = o.z * conv.in_height;
        y0[r] = select(NO_ROW, i32(o.y * conv.stride) - i32(conv.padding), row < conv.rows);
        x0[r] = i32(o.x * conv.stride) - i32(conv.padding);
    }
    // And of the kernel: channel `load_n` of field values `load_kb + 4 r`.
    let load_n = lid % BN;
    let load_kb = lid / BN;

    var acc0 = vec4<f32>(0.0);
    var acc1 = vec4<f32>(0.0);
    var acc2 = vec4<f32>(0.0);
    var acc3 = vec4<f32>(0.0);
    for (var k0 = 0u; k0 < conv.field; k0 += BK) {
        let k = k0 + load_k;
        let ci = k % conv.in_channels;
        let kxy = k / conv.in_channels;
        let kx = i32(kxy % conv.size);
        let ky = i32(kxy / conv.size);
        for (var r = 0u; r < 4u; r++) {
            let iy = y0[r] + ky;
            let ix = x0[r] + kx;
            var v = 0.0;
            if k < conv.field && iy >= 0 && iy < i32(conv.in_height) && ix >= 0
                && ix < i32(conv.in_width) {
                v = conv_in[((image_row[r] + u32(iy)) * conv.in_width + u32(ix)) * conv.in_channels + ci];
            }
            field_tile[load_k * BM_PAD + load_m + 16u * r] = v;
        }
        for (var r = 0u; r < 4u; r++) {
            let kb = load_kb + 4u * r;
            let n = col0 + load_n;
            var w = 0.0;
            if k0 + kb < conv.field && n < conv.out_channels {
                w = weights[(k0 + kb) * conv.out_channels + n];
            }
            weight_tile[kb * BN + load_n] = w;
        }
        workgroupBarrier();
        for (var kk = 0u; kk < BK; kk++) {
            let a = kk * BM_PAD + ty;
            let b = kk * BN + tx;
            let w = vec4<f32>(
                weight_tile[b],
                weight_tile[b + 16u],
                weight_tile[b + 32u],
                weight_tile[b + 48u],
            );
            acc0 = fma(vec4<f32>(field_tile[a]), w, acc0);
            acc1 = fma(vec4<f32>(field_tile[a + 16u]), w, acc1);
            acc2 = fma(vec4<f32>(field_tile[a + 32u]), w, acc2);
            acc3 = fma(vec4<f32>(field_tile[a + 48u]), w, acc3);
        }
        workgroupBarrier();
    }
    store_row(row0 + ty, col0 + tx, acc0);
    store_row(row0 + ty + 16u, col0 + tx, acc1);
    store_row(row0 + ty + 32u, col0 + tx, acc2);
    store_row(row0 + ty + 48u, col0 + tx, acc3);
}

// Outputs (row, col + 16 j) = ReLU(sum + bias).
fn store_row(row: u32, col: u32, sums: vec4<f32>) {
    if row >= conv.rows {
        return;
    }
    for (var j = 0u; j < 4u; j++) {
        let c = col + 16u * j;
        if c < conv.out_channels {
            conv_out[row * conv.out_channels + c] = max(sums[j] + bias[c], 0.0);
        }
    }
}
