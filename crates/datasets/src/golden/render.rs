//! Ray casting golden geometry into RGB, mask, depth and normal maps.
//!
//! Shading is Lambertian under one fixed directional light plus ambient light, with no shadows
//! and no view dependence, so that colour is a function of the surface point only (what NeuS's
//! colour network can represent exactly). Albedo comes from the mesh texture or from a
//! procedural pattern of stripes in 3D. Behind the object lies a [`Backdrop`]: black (as DTU with
//! masks), an environment at infinity, or a near floor or wall; masks, depths and normals are the
//! object's alone.

use super::backdrop::Backdrop;
use super::mesh_io::TexturedMesh;
use crate::images::{Mask, RgbImage};
use camera_geom::{PinholeCamera, ray_sphere};
use glam::{DVec3, Vec2, Vec3};
use prob_grid::Shape;
use rayon::prelude::*;

/// What a golden scene renders, in the normalised frame.
#[derive(Debug, Clone)]
pub enum Geometry {
    /// An analytic SDF.
    Analytic(Shape),
    /// A triangle mesh (with smooth vertex normals for shading).
    Mesh {
        /// The mesh.
        mesh: TexturedMesh,
        /// Area-weighted vertex normals.
        vertex_normals: Vec<Vec3>,
    },
}

impl Geometry {
    /// Wraps a mesh and computes its vertex normals.
    pub fn from_mesh(mesh: TexturedMesh) -> Geometry {
        let vertex_normals = prob_grid::vertex_normals(&mesh.mesh.positions, &mesh.mesh.triangles);
        Geometry::Mesh { mesh, vertex_normals }
    }
}

/// A surface hit: distance along the ray, unit normal facing the viewer, albedo.
struct Hit {
    t: f64,
    normal: DVec3,
    albedo: [f32; 3],
}

/// A 3D stripe pattern, smooth at large scale: enough texture for photometric training.
pub fn procedural_albedo(p: DVec3) -> [f32; 3] {
    let stripes = (11.0 * p.x + 5.0 * p.y).sin() * (13.0 * p.z + 3.0 * p.x).sin();
    let a = [0.85, 0.55, 0.30];
    let b = [0.30, 0.55, 0.75];
    let base = if stripes > 0.0 { a } else { b };
    let shade = 0.8 + 0.2 * (3.0 * p.y + 1.0).sin();
    base.map(|c| (c * shade) as f32)
}

fn sample_texture(tex: &RgbImage, uv: Vec2) -> [f32; 3] {
    let x = (uv.x - uv.x.floor()) * tex.width as f32 - 0.5;
    let y = (1.0 - (uv.y - uv.y.floor())) * tex.height as f32 - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let wrap = |v: f32, n: u32| (v as i64).rem_euclid(n as i64) as u32;
    let mut out = [0.0f32; 3];
    for (dy, wy) in [(0.0, 1.0 - fy), (1.0, fy)] {
        for (dx, wx) in [(0.0, 1.0 - fx), (1.0, fx)] {
            let c = tex.get_f32(wrap(x0 + dx, tex.width), wrap(y0 + dy, tex.height));
            for k in 0..3 {
                out[k] += wx * wy * c[k];
            }
        }
    }
    out
}

impl Geometry {
    fn hit(&self, origin: DVec3, direction: DVec3) -> Option<Hit> {
        match self {
            Geometry::Analytic(shape) => {
                let (t0, t1) = ray_sphere(&camera_geom::Ray { origin, direction }, DVec3::ZERO, shape.bounding_radius() + 1e-3)?;
                let t = shape.ray_hit(origin, direction, t0.max(0.0), t1, 1e-8)?;
                let p = origin + t * direction;
                let mut normal = shape.gradient(p).normalize_or_zero();
                if normal.dot(direction) > 0.0 {
                    normal = -normal;
                }
                Some(Hit { t, normal, albedo: procedural_albedo(p) })
            }
            Geometry::Mesh { mesh, vertex_normals } => {
                let h = mesh.mesh.ray_hit(origin.as_vec3(), direction.as_vec3(), 0.0, f32::INFINITY)?;
                let tri = mesh.mesh.triangles[h.triangle as usize];
                let [b1, b2] = h.barycentric;
                let w = [1.0 - b1 - b2, b1, b2];
                let interp = |v: &[Vec3]| w[0] * v[tri[0] as usize] + w[1] * v[tri[1] as usize] + w[2] * v[tri[2] as usize];
                let mut normal = interp(vertex_normals).normalize_or_zero().as_dvec3();
                if normal == DVec3::ZERO {
                    normal = mesh.mesh.face_normal(h.triangle).normalize_or_zero().as_dvec3();
                }
                if normal.dot(direction) > 0.0 {
                    normal = -normal;
                }
                let t = h.t as f64;
                let tex = mesh.triangle_texture[h.triangle as usize];
                let albedo = match (&mesh.uvs, mesh.textures.get(tex as usize)) {
                    (Some(uvs), Some(texture)) => {
                        let uv = w[0] * uvs[tri[0] as usize] + w[1] * uvs[tri[1] as usize] + w[2] * uvs[tri[2] as usize];
                        sample_texture(texture, uv)
                    }
                    _ => procedural_albedo(origin + t * direction),
                };
                Some(Hit { t, normal, albedo })
            }
        }
    }
}

/// One rendered view.
#[derive(Debug, Clone)]
pub struct Render {
    /// Shaded colour.
    pub image: RgbImage,
    /// Foreground = a surface was hit.
    pub mask: Mask,
    /// Depth λ along the optical axis (normalised-frame units), 0 where nothing was hit; row-major.
    pub depth: Vec<f32>,
    /// Unit world normal facing the camera, zero where nothing was hit; row-major.
    pub normal: Vec<[f32; 3]>,
}

/// Bytes a pixel of [`render_view`] holds at its peak: each row's hits with their rays until
/// the view is shaded, and the [`Render`] itself (colour, depth, normal; the mask's bit rounded
/// up). For memory models of callers that render large views.
pub const RENDER_BYTES_PER_PIXEL: usize = std::mem::size_of::<(Option<Hit>, DVec3, DVec3)>() + 3 + 4 + 12 + 1;

/// The fixed light direction (towards the light).
pub const LIGHT_DIRECTION: DVec3 = DVec3::new(0.36, -0.48, 0.8);

/// Renders one camera, one ray through each pixel centre.
pub fn render_view(geometry: &Geometry, camera: &PinholeCamera, backdrop: Backdrop) -> Render {
    let (w, h) = (camera.width, camera.height);
    let light = LIGHT_DIRECTION.normalize();
    let rows: Vec<Vec<(Option<Hit>, DVec3, DVec3)>> = (0..h)
        .into_par_iter()
        .map(|row| {
            (0..w)
                .map(|col| {
                    let ray = camera.ray_through_pixel_index(col, row);
                    let behind = backdrop.distance(ray.origin, ray.direction);
                    let hit = geometry.hit(ray.origin, ray.direction).filter(|h| h.t < behind);
                    (hit, ray.origin, ray.direction)
                })
                .collect()
        })
        .collect();
    let mut out =
        Render { image: RgbImage::new(w, h), mask: Mask::new(w, h), depth: vec![0.0; (w * h) as usize], normal: vec![[0.0; 3]; (w * h) as usize] };
    for (row, line) in rows.into_iter().enumerate() {
        for (col, (hit, origin, direction)) in line.into_iter().enumerate() {
            let i = row * w as usize + col;
            let (col, row) = (col as u32, row as u32);
            let Some(hit) = hit else {
                out.image.set_f32(col, row, backdrop.color(origin, direction));
                continue;
            };
            let diffuse = hit.normal.dot(light).max(0.0) as f32;
            let rgb = hit.albedo.map(|a| a * (0.35 + 0.65 * diffuse));
            out.image.set_f32(col, row, rgb);
            out.mask.set(col, row, true);
            out.depth[i] = (hit.t * camera.depth_per_distance(direction)) as f32;
            out.normal[i] = hit.normal.as_vec3().to_array();
        }
    }
    out
}
