// Prepended to every WGSL kernel module (`gpu::compute::shader`): the workgroup width and
// the 1D index of a (possibly 2D) dispatch of `WG`-wide workgroups.

const WG: u32 = 256u;

fn flat_index(wid: vec3<u32>, nwg: vec3<u32>, lid: u32) -> u32 {
    return (wid.x + wid.y * nwg.x) * WG + lid;
}
