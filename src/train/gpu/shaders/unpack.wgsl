// A target image uploaded as bytes (four per word, little-endian) to floats in [0, 1],
// `byte · (1 / 255)` in f32 as on the host (`ImageU8::to_f32_into` in `src/train/dataset.rs`).

@group(0) @binding(0) var<uniform> unpack_len: vec4<u32>;
@group(0) @binding(1) var<storage, read> packed: array<u32>;
@group(0) @binding(2) var<storage, read_write> unpacked: array<f32>;

@compute @workgroup_size(256)
fn unpack_bytes(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let k = flat_index(wid, nwg, lid);
    if k >= unpack_len.x {
        return;
    }
    let byte = (packed[k / 4u] >> (8u * (k % 4u))) & 0xffu;
    unpacked[k] = f32(byte) * (1.0 / 255.0);
}
