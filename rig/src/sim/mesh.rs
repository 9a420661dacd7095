//! Scene geometry: the primitives (box, sphere, plane, cylinder, inline meshes, a room or
//! dome background) as textured triangle meshes, and their pose and non-rigid deformation
//! at a scene time.
//!
//! Texture coordinates are in metres along the surface divided by the texture's tile size,
//! so texture detail has the same physical scale everywhere.

use glam::{DQuat, DVec3, Vec3};

use super::animation::object_pose;
use super::schema::{DeformKind, DeformSpec, ObjectSection, SceneFile};
use super::texture::Texture;

/// Object id of the background in masks; objects are numbered from 2.
pub const BACKGROUND_ID: u16 = 1;

/// A triangle mesh in its own (object) coordinates.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub positions: Vec<DVec3>,
    /// Texture coordinates in tile units.
    pub uvs: Vec<[f32; 2]>,
    pub triangles: Vec<[u32; 3]>,
    /// Grids added so far (offsets their texture coordinates).
    grids: u32,
}

impl Mesh {
    fn push(&mut self, p: DVec3, uv: [f64; 2]) -> u32 {
        self.positions.push(p);
        self.uvs.push([uv[0] as f32, uv[1] as f32]);
        (self.positions.len() - 1) as u32
    }

    /// A grid of `nu × nv` quads spanning `origin + a·u + b·v`, `a, b ∈ [0, 1]`.
    /// Each grid's texture coordinates start at a different place, so faces of a box differ.
    fn grid(&mut self, origin: DVec3, u: DVec3, v: DVec3, nu: u32, nv: u32) {
        let (lu, lv) = (u.length(), v.length());
        let base = self.positions.len() as u32;
        let k = self.grids as f64;
        self.grids += 1;
        let (ou, ov) = (k * 7.31, k * 3.17);
        for j in 0..=nv {
            for i in 0..=nu {
                let (a, b) = (i as f64 / nu as f64, j as f64 / nv as f64);
                self.push(origin + u * a + v * b, [ou + a * lu, ov + b * lv]);
            }
        }
        self.quads(base, nu, nv);
    }

    /// Two triangles per quad of a `(cols + 1) × (rows + 1)` vertex lattice pushed row by
    /// row from vertex `base`.
    fn quads(&mut self, base: u32, cols: u32, rows: u32) {
        let row = cols + 1;
        for j in 0..rows {
            for i in 0..cols {
                let k = base + j * row + i;
                self.triangles.push([k, k + 1, k + row + 1]);
                self.triangles.push([k, k + row + 1, k + row]);
            }
        }
    }

    pub fn plane(sx: f64, sy: f64, seg: u32) -> Mesh {
        let mut m = Mesh::default();
        m.grid(
            DVec3::new(-sx / 2.0, -sy / 2.0, 0.0),
            DVec3::X * sx,
            DVec3::Y * sy,
            seg,
            seg,
        );
        m
    }

    /// An axis-aligned box centred on the origin.
    pub fn cuboid(size: DVec3, seg: u32) -> Mesh {
        let mut m = Mesh::default();
        let h = size / 2.0;
        let (x, y, z) = (DVec3::X * size.x, DVec3::Y * size.y, DVec3::Z * size.z);
        m.grid(DVec3::new(-h.x, -h.y, -h.z), x, y, seg, seg); // bottom
        m.grid(DVec3::new(-h.x, -h.y, h.z), x, y, seg, seg); // top
        m.grid(DVec3::new(-h.x, -h.y, -h.z), x, z, seg, seg); // front (−y)
        m.grid(DVec3::new(-h.x, h.y, -h.z), x, z, seg, seg); // back
        m.grid(DVec3::new(-h.x, -h.y, -h.z), y, z, seg, seg); // left (−x)
        m.grid(DVec3::new(h.x, -h.y, -h.z), y, z, seg, seg); // right
        m
    }

    /// A UV sphere centred on the origin, `seg` latitude bands and `2·seg` longitudes.
    pub fn sphere(r: f64, seg: u32) -> Mesh {
        let mut m = Mesh::default();
        let (nlat, nlon) = (seg.max(3), 2 * seg.max(3));
        for j in 0..=nlat {
            let lat = std::f64::consts::PI * (j as f64 / nlat as f64 - 0.5);
            for i in 0..=nlon {
                let lon = std::f64::consts::TAU * i as f64 / nlon as f64;
                let p = DVec3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin()) * r;
                m.push(p, [lon * r, (lat + std::f64::consts::FRAC_PI_2) * r]);
            }
        }
        m.quads(0, nlon, nlat);
        m
    }

    /// A closed cylinder standing on the origin (z from 0 to `h`).
    pub fn cylinder(r: f64, h: f64, seg: u32) -> Mesh {
        let mut m = Mesh::default();
        let (n, rings) = (2 * seg.max(3), (seg / 2).max(1));
        for j in 0..=rings {
            let z = h * j as f64 / rings as f64;
            for i in 0..=n {
                let a = std::f64::consts::TAU * i as f64 / n as f64;
                m.push(DVec3::new(r * a.cos(), r * a.sin(), z), [a * r, z]);
            }
        }
        m.quads(0, n, rings);
        for z in [0.0, h] {
            let c = m.push(DVec3::new(0.0, 0.0, z), [0.0, 0.0]);
            let first = m.positions.len() as u32;
            for i in 0..=n {
                let a = std::f64::consts::TAU * i as f64 / n as f64;
                m.push(
                    DVec3::new(r * a.cos(), r * a.sin(), z),
                    [r * a.cos(), r * a.sin()],
                );
            }
            for i in 0..n {
                m.triangles.push([c, first + i, first + i + 1]);
            }
        }
        m
    }

    fn scale_uvs(mut self, tile: f64) -> Mesh {
        let s = 1.0 / tile as f32;
        for uv in &mut self.uvs {
            uv[0] *= s;
            uv[1] *= s;
        }
        self
    }
}

/// One textured mesh of the scene with its motion.
#[derive(Clone, Debug)]
pub struct SceneMesh {
    pub mesh: Mesh,
    pub texture: Texture,
    /// Id written to masks (1 = background, objects from 2).
    pub id: u16,
    /// Index into `SceneFile::objects`, `None` for the background.
    pub object: Option<usize>,
    pub deform: Option<DeformSpec>,
    /// Whether the mesh moves or deforms (its pixels go into the moving-object masks).
    pub moving: bool,
}

/// Build every mesh of the scene (background first) with textures baked at `tex` texels.
pub(crate) fn build_meshes(file: &SceneFile, tex: u32) -> Vec<SceneMesh> {
    let seed = file.scene.seed;
    let mut out = Vec::new();
    let bg = &file.background;
    let c = DVec3::from_array(bg.center);
    let bg_mesh = match bg.kind.as_str() {
        "room" => {
            let s = DVec3::from_array(bg.size);
            let mut m = Mesh::cuboid(s, bg.segments.max(1));
            for p in &mut m.positions {
                *p += c + DVec3::Z * (s.z / 2.0);
            }
            Some(m)
        }
        "dome" => {
            let mut m = Mesh::sphere(bg.radius, bg.segments.max(8));
            let mut floor = Mesh::plane(2.0 * bg.radius, 2.0 * bg.radius, bg.segments.max(1));
            let base = m.positions.len() as u32;
            m.positions.append(&mut floor.positions);
            m.uvs.append(&mut floor.uvs);
            m.triangles
                .extend(floor.triangles.iter().map(|t| t.map(|i| i + base)));
            for p in &mut m.positions {
                *p += c;
            }
            Some(m)
        }
        _ => None,
    };
    if let Some(m) = bg_mesh {
        out.push(SceneMesh {
            mesh: m.scale_uvs(bg.texture.tile),
            texture: Texture::bake(&bg.texture, tex, seed, 1),
            id: BACKGROUND_ID,
            object: None,
            deform: None,
            moving: false,
        });
    }
    for (i, o) in file.objects.iter().enumerate() {
        out.push(SceneMesh {
            mesh: object_mesh(o).scale_uvs(o.texture.tile),
            texture: Texture::bake(&o.texture, tex, seed, 100 + i as u64),
            id: 2 + i as u16,
            object: Some(i),
            deform: o.deform.filter(|d| d.amplitude != 0.0),
            moving: o.deform.is_some_and(|d| d.amplitude != 0.0) || keyframes_move(o),
        });
    }
    out
}

fn keyframes_move(o: &ObjectSection) -> bool {
    o.keyframes
        .windows(2)
        .any(|w| w[0].position != w[1].position || w[0].rotation != w[1].rotation)
}

fn object_mesh(o: &ObjectSection) -> Mesh {
    let seg = o.segments;
    match o.shape.as_str() {
        "box" => Mesh::cuboid(DVec3::from_array(o.size), seg.min(16)),
        "sphere" => Mesh::sphere(o.radius, seg),
        "plane" => Mesh::plane(o.size[0], o.size[1], seg),
        "cylinder" => Mesh::cylinder(o.radius, o.height, seg),
        _ => {
            let mut m = Mesh::default();
            for (k, v) in o.vertices.iter().enumerate() {
                let p = DVec3::from_array(*v);
                let uv = o.uvs.get(k).copied().unwrap_or([p.x, p.y + p.z]);
                m.push(p, uv);
            }
            m.triangles = o.triangles.clone();
            m
        }
    }
}

/// Non-rigid displacement of an object-space point at scene time `t`.
pub fn deform(d: &DeformSpec, p: DVec3, t: f64) -> DVec3 {
    let phase = std::f64::consts::TAU * d.frequency * t;
    match d.kind {
        DeformKind::Wave => {
            // A travelling wave along local x, displacing local z (a flag in the xy plane).
            let k = std::f64::consts::TAU / d.wavelength;
            p + DVec3::Z * (d.amplitude * (k * p.x - phase).sin())
        }
        DeformKind::Bend => {
            let s = p.z / d.wavelength;
            p + DVec3::X * (d.amplitude * s * s * phase.sin())
        }
    }
}

/// World-space vertex positions of every mesh at scene time `t` (f32 for the rasteriser).
pub(crate) fn world_positions(file: &SceneFile, meshes: &[SceneMesh], t: f64) -> Vec<Vec<Vec3>> {
    meshes
        .iter()
        .map(|m| {
            let (rot, pos): (DQuat, DVec3) = match m.object {
                Some(i) => object_pose(&file.objects[i], t),
                None => (DQuat::IDENTITY, DVec3::ZERO),
            };
            m.mesh
                .positions
                .iter()
                .map(|&p| {
                    let local = match &m.deform {
                        Some(d) => deform(d, p, t),
                        None => p,
                    };
                    (rot * local + pos).as_vec3()
                })
                .collect()
        })
        .collect()
}
