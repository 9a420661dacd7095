//! A small CPU rasteriser of textured triangles for the simulator: near-plane clipping,
//! z-buffer, perspective-correct texture coordinates, flat Lambert + ambient shading.
//! Renders an ideal pinhole image; lens distortion is applied afterwards by `lens`.
//!
//! Pixel convention: pixel `(i, j)` covers `[i, i+1) × [j, j+1)` and is sampled at its
//! centre `(i + 0.5, j + 0.5)`, matching `shared_types::Intrinsics`.
//! It must stay independent of the Gaussian engine: the model is never tested on data
//! made by itself.

use glam::{Mat3, Vec3};
use rayon::prelude::*;

use super::mesh::SceneMesh;

/// Nearest depth a surface can have in front of the camera, metres.
const NEAR: f32 = 0.01;
/// Rows per parallel band.
const BAND: usize = 8;

/// A pinhole view: world-to-camera rotation and translation, intrinsics in pixels.
#[derive(Clone, Copy, Debug)]
pub struct View {
    pub rotation: Mat3,
    pub translation: Vec3,
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    pub width: usize,
    pub height: usize,
}

impl View {
    fn centre(&self) -> Vec3 {
        -(self.rotation.transpose() * self.translation)
    }
}

/// Lighting of the whole scene.
#[derive(Clone, Copy, Debug)]
pub struct Light {
    /// Unit direction towards the light.
    pub direction: Vec3,
    pub ambient: f32,
    pub diffuse: f32,
    pub clear: [f32; 3],
}

/// The rendered image with its depth and object ids.
#[derive(Clone, Debug)]
pub struct Rendered {
    pub width: usize,
    pub height: usize,
    pub color: Vec<[f32; 3]>,
    /// Camera z of the visible surface, `f32::INFINITY` where nothing is hit.
    pub depth: Vec<f32>,
    /// Mesh id of the visible surface (0 where nothing is hit).
    pub id: Vec<u16>,
}

#[derive(Clone, Copy, Debug)]
struct ScreenTri {
    xy: [[f32; 2]; 3],
    inv_z: [f32; 3],
    u_z: [f32; 3],
    v_z: [f32; 3],
    shade: f32,
    mesh: u16,
    ymin: f32,
    ymax: f32,
}

#[derive(Clone, Copy)]
struct ClipVertex {
    p: Vec3,
    uv: [f32; 2],
}

fn lerp_vertex(a: ClipVertex, b: ClipVertex, s: f32) -> ClipVertex {
    ClipVertex {
        p: a.p + (b.p - a.p) * s,
        uv: [
            a.uv[0] + (b.uv[0] - a.uv[0]) * s,
            a.uv[1] + (b.uv[1] - a.uv[1]) * s,
        ],
    }
}

/// Clip a camera-space polygon against `z ≥ NEAR` (Sutherland–Hodgman).
fn clip_near(poly: &[ClipVertex]) -> Vec<ClipVertex> {
    let mut out = Vec::with_capacity(4);
    for i in 0..poly.len() {
        let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
        let (ina, inb) = (a.p.z >= NEAR, b.p.z >= NEAR);
        if ina {
            out.push(a);
        }
        if ina != inb {
            out.push(lerp_vertex(a, b, (NEAR - a.p.z) / (b.p.z - a.p.z)));
        }
    }
    out
}

fn setup(view: &View, meshes: &[SceneMesh], world: &[Vec<Vec3>], light: &Light) -> Vec<ScreenTri> {
    let eye = view.centre();
    let (w, h) = (view.width as f32, view.height as f32);
    let mut tris = Vec::new();
    for (mi, (m, pos)) in meshes.iter().zip(world).enumerate() {
        let cam: Vec<Vec3> = pos
            .iter()
            .map(|&p| view.rotation * p + view.translation)
            .collect();
        for t in &m.mesh.triangles {
            let [a, b, c] = t.map(|i| i as usize);
            if cam[a].z < NEAR && cam[b].z < NEAR && cam[c].z < NEAR {
                continue;
            }
            let mut n = (pos[b] - pos[a]).cross(pos[c] - pos[a]).normalize_or_zero();
            if n.dot(eye - pos[a]) < 0.0 {
                n = -n;
            }
            let shade = light.ambient + light.diffuse * n.dot(light.direction).max(0.0);
            let poly = [a, b, c].map(|i| ClipVertex {
                p: cam[i],
                uv: m.mesh.uvs[i],
            });
            let clipped;
            let verts: &[ClipVertex] = if poly.iter().all(|v| v.p.z >= NEAR) {
                &poly
            } else {
                clipped = clip_near(&poly);
                &clipped
            };
            for k in 1..verts.len().saturating_sub(1) {
                let tri = [verts[0], verts[k], verts[k + 1]];
                let xy = tri.map(|v| {
                    [
                        view.fx * v.p.x / v.p.z + view.cx,
                        view.fy * v.p.y / v.p.z + view.cy,
                    ]
                });
                let xs = xy.map(|p| p[0]);
                let ys = xy.map(|p| p[1]);
                let (xmin, xmax) = (xs[0].min(xs[1]).min(xs[2]), xs[0].max(xs[1]).max(xs[2]));
                let (ymin, ymax) = (ys[0].min(ys[1]).min(ys[2]), ys[0].max(ys[1]).max(ys[2]));
                if xmax < 0.0 || ymax < 0.0 || xmin > w || ymin > h {
                    continue;
                }
                let area = (xy[1][0] - xy[0][0]) * (xy[2][1] - xy[0][1])
                    - (xy[1][1] - xy[0][1]) * (xy[2][0] - xy[0][0]);
                if area.abs() < 1e-12 {
                    continue;
                }
                tris.push(ScreenTri {
                    xy,
                    inv_z: tri.map(|v| 1.0 / v.p.z),
                    u_z: tri.map(|v| v.uv[0] / v.p.z),
                    v_z: tri.map(|v| v.uv[1] / v.p.z),
                    shade,
                    mesh: mi as u16,
                    ymin,
                    ymax,
                });
            }
        }
    }
    tris
}

/// Render the meshes (at their world positions `world`, one `Vec` per mesh) into `view`.
pub fn render(view: &View, meshes: &[SceneMesh], world: &[Vec<Vec3>], light: &Light) -> Rendered {
    let tris = setup(view, meshes, world, light);
    let (w, h) = (view.width, view.height);
    let mut color = vec![light.clear; w * h];
    let mut depth = vec![f32::INFINITY; w * h];
    let mut id = vec![0u16; w * h];
    color
        .par_chunks_mut(w * BAND)
        .zip(depth.par_chunks_mut(w * BAND))
        .zip(id.par_chunks_mut(w * BAND))
        .enumerate()
        .for_each(|(band, ((color, depth), id))| {
            let y0 = band * BAND;
            let rows = depth.len() / w;
            // Deferred: keep the nearest surface's mesh, uv and shade, texture once at the end.
            let mut hit: Vec<(u16, f32, f32, f32)> = vec![(u16::MAX, 0.0, 0.0, 0.0); w * rows];
            let (band_top, band_bottom) = (y0 as f32, (y0 + rows) as f32);
            for t in &tris {
                if t.ymax < band_top || t.ymin > band_bottom {
                    continue;
                }
                rasterise(t, w, y0, rows, depth, &mut hit);
            }
            for (k, &(mesh, u, v, shade)) in hit.iter().enumerate() {
                if mesh != u16::MAX {
                    let m = &meshes[mesh as usize];
                    let c = m.texture.sample(u, v);
                    color[k] = c.map(|x| x * shade);
                    id[k] = m.id;
                }
            }
        });
    Rendered {
        width: w,
        height: h,
        color,
        depth,
        id,
    }
}

#[inline]
fn rasterise(
    t: &ScreenTri,
    w: usize,
    y0: usize,
    rows: usize,
    depth: &mut [f32],
    hit: &mut [(u16, f32, f32, f32)],
) {
    let [p0, p1, p2] = t.xy;
    let area = (p1[0] - p0[0]) * (p2[1] - p0[1]) - (p1[1] - p0[1]) * (p2[0] - p0[0]);
    let inv_area = 1.0 / area;
    let xmin = p0[0].min(p1[0]).min(p2[0]);
    let xmax = p0[0].max(p1[0]).max(p2[0]);
    // Pixel centres inside the bounding box.
    let i0 = ((xmin - 0.5).ceil().max(0.0)) as usize;
    let i1 = ((xmax - 0.5).floor().min(w as f32 - 1.0)) as isize;
    let j0 = ((t.ymin - 0.5).ceil().max(y0 as f32)) as usize;
    let j1 = ((t.ymax - 0.5).floor().min((y0 + rows) as f32 - 1.0)) as isize;
    if i1 < i0 as isize || j1 < j0 as isize {
        return;
    }
    let edge = |a: [f32; 2], b: [f32; 2], x: f32, y: f32| {
        (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])
    };
    for j in j0..=j1 as usize {
        let y = j as f32 + 0.5;
        let row = (j - y0) * w;
        for i in i0..=i1 as usize {
            let x = i as f32 + 0.5;
            let w0 = edge(p1, p2, x, y) * inv_area;
            let w1 = edge(p2, p0, x, y) * inv_area;
            let w2 = edge(p0, p1, x, y) * inv_area;
            if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                continue;
            }
            let inv_z = w0 * t.inv_z[0] + w1 * t.inv_z[1] + w2 * t.inv_z[2];
            let z = 1.0 / inv_z;
            let k = row + i;
            if z < depth[k] {
                depth[k] = z;
                let u = (w0 * t.u_z[0] + w1 * t.u_z[1] + w2 * t.u_z[2]) * z;
                let v = (w0 * t.v_z[0] + w1 * t.v_z[1] + w2 * t.v_z[2]) * z;
                hit[k] = (t.mesh, u, v, t.shade);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::mesh::{Mesh, SceneMesh};
    use crate::sim::schema::TextureSpec;
    use crate::sim::texture::Texture;

    #[test]
    fn a_square_in_front_of_the_camera_covers_its_projection_at_its_depth() {
        let spec = TextureSpec {
            kind: "solid".into(),
            colors: [[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]],
            ..Default::default()
        };
        let mut mesh = Mesh::plane(1.0, 1.0, 1);
        for p in &mut mesh.positions {
            *p += glam::DVec3::new(0.0, 0.0, 2.0);
        }
        let meshes = vec![SceneMesh {
            mesh,
            texture: Texture::bake(&spec, 16, 0, 0),
            id: 2,
            object: None,
            deform: None,
            moving: false,
        }];
        let world = vec![
            meshes[0]
                .mesh
                .positions
                .iter()
                .map(|p| p.as_vec3())
                .collect(),
        ];
        let view = View {
            rotation: Mat3::IDENTITY,
            translation: Vec3::ZERO,
            fx: 100.0,
            fy: 100.0,
            cx: 50.0,
            cy: 50.0,
            width: 100,
            height: 100,
        };
        let light = Light {
            direction: Vec3::Z,
            ambient: 1.0,
            diffuse: 0.0,
            clear: [0.0; 3],
        };
        let r = render(&view, &meshes, &world, &light);
        // The square spans x, y ∈ [-0.5, 0.5] at z = 2 → pixels [25, 75).
        let covered = r.id.iter().filter(|&&i| i == 2).count();
        assert_eq!(covered, 50 * 50);
        assert_eq!(r.id[25 * 100 + 25], 2);
        assert_eq!(r.id[24 * 100 + 25], 0);
        assert!((r.depth[50 * 100 + 50] - 2.0).abs() < 1e-5);
        assert!((r.color[50 * 100 + 50][0] - 1.0).abs() < 1e-5);
    }
}
