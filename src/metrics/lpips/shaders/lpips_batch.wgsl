// Prepended to the LPIPS kernels that walk a batch of same-sized channels-last maps.

// (x, y, image) of pixel `index` of a batch of `width` × `height` maps, pixels in row-major
// order image after image.
fn batch_pixel(index: u32, width: u32, height: u32) -> vec3<u32> {
    let rest = index / width;
    return vec3<u32>(index % width, rest % height, rest / height);
}
