// Densification statistics of one view, added on the device as `DensifyStats::record`
// adds them on the host: for every Gaussian the view drew (radius > 0), its view-space
// gradient norm (`preprocess_backward` stores it in the .z of its fifth gradient vec4)
// times `to_ndc` into the sum, one more view seen, and the largest screen radius.

struct StatsParams {
    count: u32,
    pad0: u32,
    pad1: u32,
    // d/d(ndc) = d/d(pixel) · max(width, height) / 2, times the batch size.
    to_ndc: f32,
}

@group(0) @binding(0) var<uniform> S: StatsParams;
@group(0) @binding(1) var<storage, read> view_grads: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> radii: array<f32>;
@group(0) @binding(3) var<storage, read_write> grad_sum: array<f32>;
@group(0) @binding(4) var<storage, read_write> seen: array<u32>;
@group(0) @binding(5) var<storage, read_write> max_radius: array<f32>;

@compute @workgroup_size(256)
fn record_stats(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_index(wid, nwg, lid);
    if i >= S.count {
        return;
    }
    let r = radii[i];
    if r > 0.0 {
        grad_sum[i] = grad_sum[i] + view_grads[5u * i + 4u].z * S.to_ndc;
        seen[i] = seen[i] + 1u;
        max_radius[i] = max(max_radius[i], r);
    }
}
