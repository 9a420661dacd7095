// The renderer's per-view constants and its projected splat record, prepended to the
// renderer's kernels that read a view or a splat (`render::gpu::kernels`).

const TILE: u32 = 16u;

struct View {
    // Rows of the world-to-camera rotation (xyz) and the translation.
    rot0: vec4<f32>,
    rot1: vec4<f32>,
    rot2: vec4<f32>,
    trans: vec4<f32>,
    // Camera centre in world coordinates.
    centre: vec4<f32>,
    // fx, fy, cx, cy.
    focal: vec4<f32>,
    background: vec4<f32>,
    width: u32,
    height: u32,
    tiles_x: u32,
    tiles_y: u32,
    count: u32,
    // Active spatial / temporal colour basis sizes, and the per-Gaussian colour stride.
    ns_active: u32,
    nt_active: u32,
    ns_capacity: u32,
    t: f32,
    period: f32,
    near: f32,
    colour_stride: u32,
}

// A projected, coloured splat ready for blending (the CPU `Splat` plus its tile box).
struct Splat {
    // Pixel mean, camera depth, opacity.
    mean_depth_opacity: vec4<f32>,
    // Conic (a, b, c) and the smallest `power` inside the support.
    conic_min_power: vec4<f32>,
    colour: vec4<f32>,
    // Inclusive support box in pixels: x0, x1, y0, y1 (clipped to the image).
    rect: vec4<i32>,
}
