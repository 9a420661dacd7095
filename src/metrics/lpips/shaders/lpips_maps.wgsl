// LPIPS-alex on the GPU (src/metrics/lpips/gpu.rs): the element-wise passes between the
// convolutions, on channels-last maps of a batch of same-sized images.
// - `scale_input`: interleaved RGB in [0, 1] to the network's input,
//   ((2v − 1) − shift) / scale per channel (the CPU's `AlexLpips` input, alex.rs);
// - `max_pool`: 3×3 stride-2 unpadded max-pool (the CPU's `max_pool_3x3_s2`, conv.rs).

struct Maps {
    // Output values of the whole batch.
    count: u32,
    in_width: u32,
    in_height: u32,
    channels: u32,
    out_width: u32,
    out_height: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var<uniform> maps: Maps;
@group(0) @binding(1) var<storage, read> src: array<f32>;
@group(0) @binding(2) var<storage, read_write> dst: array<f32>;

@compute @workgroup_size(256)
fn scale_input(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_index(wid, nwg, lid);
    if i >= maps.count {
        return;
    }
    // LPIPS's shift and scale (alex.rs: SHIFT, SCALE).
    var shift = array<f32, 3>(-0.030, -0.088, -0.188);
    var scale = array<f32, 3>(0.458, 0.448, 0.450);
    let c = i % 3u;
    dst[i] = ((2.0 * src[i] - 1.0) - shift[c]) / scale[c];
}

@compute @workgroup_size(256)
fn max_pool(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_index(wid, nwg, lid);
    if i >= maps.count {
        return;
    }
    let c = i % maps.channels;
    let pixel = i / maps.channels;
    let o = batch_pixel(pixel, maps.out_width, maps.out_height);
    let corner = ((o.z * maps.in_height + 2u * o.y) * maps.in_width + 2u * o.x) * maps.channels + c;
    var m = src[corner];
    for (var dy = 0u; dy < 3u; dy++) {
        for (var dx = 0u; dx < 3u; dx++) {
            m = max(m, src[corner + (dy * maps.in_width + dx) * maps.channels]);
        }
    }
    dst[i] = m;
}
