// sum[i] += part[i]: one view's gradients added into the batch's.

@group(0) @binding(0) var<uniform> add_len: vec4<u32>;
@group(0) @binding(1) var<storage, read> part: array<f32>;
@group(0) @binding(2) var<storage, read_write> sum: array<f32>;

@compute @workgroup_size(256)
fn add_into(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_index(wid, nwg, lid);
    if i >= add_len.x {
        return;
    }
    sum[i] = sum[i] + part[i];
}
