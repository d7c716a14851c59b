//! Golden scenes: known geometry rendered from known cameras, the test harness's truth.
//!
//! A golden scene is an analytic SDF ([`prob_grid::Shape`]) or a triangle mesh (OBJ, glTF, GLB)
//! seen by a camera [`rig`](rig::Rig), rendered to RGB, mask, depth and normal maps, with
//! ground-truth surface points sampled uniformly by area. It is deterministic for a seed and
//! needs no files ([`builtin_scene`]) or only the mesh. [`write_idr`] writes it in the IDR layout
//! (the project writes `cameras_sphere.npz` itself), so one loader reads golden and real data.
//!
//! Meshes are normalised into the sphere of radius [`MESH_RADIUS`]; `world_from_normalized`
//! (written as `scale_mat`) maps back to the mesh's own units, in which the ground-truth points
//! and mesh are written.

pub mod backdrop;
pub mod mesh_io;
pub mod render;
pub mod rig;

use crate::error::{Result, io_err};
use crate::io::{PlyData, write_atomic};
use crate::npy::npy_bytes;
use crate::scene::{Format, Scene, SceneSource, View};
pub use backdrop::Backdrop;
use glam::{DMat3, DMat4, DVec3};
use mesh_io::{TexturedMesh, load_mesh};
use prob_grid::ShapeName;
use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
use render::{Geometry, render_view};
use rig::{Rig, RigOptions};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Radius of the sphere (about the origin) that meshes are scaled into.
pub const MESH_RADIUS: f64 = 0.7;

/// What to render.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub enum GeometrySource {
    /// A named analytic shape.
    Shape(ShapeName),
    /// A mesh file (OBJ, glTF, GLB).
    Mesh(PathBuf),
}

/// Everything that defines a golden scene.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GoldenSpec {
    /// The geometry.
    pub geometry: GeometrySource,
    /// The cameras.
    pub rig: RigOptions,
    /// What lies behind the object (black, an environment at infinity, a near floor or wall).
    pub backdrop: Backdrop,
    /// Number of ground-truth surface points (about; CSG shapes lose the hidden parts).
    pub surface_points: usize,
    /// The region of interest's radius in the scene's units (≥ 1): the object is rendered as
    /// always (filling a sphere of radius ≈ 1) and the frame is then shrunk by this factor, so
    /// that the bound (the unit sphere) holds free space around the object, as a capture's bound
    /// does (COLMAP's, DTU's). 1: the object fills the bound.
    pub bound: f64,
    /// Whether a mesh file is y-up (OBJ and glTF convention, the default) or z-up. Golden scenes
    /// are z-up; a y-up mesh is rotated (x, y, z) ↦ (x, −z, y) into them, and the rotation is
    /// part of `world_from_normalized`.
    pub mesh_y_up: bool,
}

impl GoldenSpec {
    /// A spec with defaults: DTU rig, 49 views of 400×300, the checker backdrop, 100 000 surface
    /// points.
    pub fn new(geometry: GeometrySource) -> GoldenSpec {
        GoldenSpec {
            geometry,
            rig: RigOptions { rig: Rig::Dtu, count: 49, width: 400, height: 300, seed: 0 },
            backdrop: Backdrop::Checker,
            surface_points: 100_000,
            bound: 1.0,
            mesh_y_up: true,
        }
    }
}

/// A rendered golden scene and its truth.
#[derive(Debug, Clone)]
pub struct GoldenScene {
    /// The views (normalised frame), as a loader would return them.
    pub scene: Scene,
    /// Per view: depth λ (normalised units), 0 for background; row-major.
    pub depths: Vec<Vec<f32>>,
    /// Per view: unit world normals facing the camera, zero for background; row-major.
    pub normals: Vec<Vec<[f32; 3]>>,
    /// Surface points uniform by area, in the normalised frame.
    pub surface_points: Vec<DVec3>,
    /// The geometry that was rendered (normalised frame).
    pub geometry: Geometry,
    /// The spec it was made from.
    pub spec: GoldenSpec,
}

impl GoldenScene {
    /// The radius of a sphere about the origin that holds the geometry (normalised frame).
    pub fn geometry_radius(&self) -> f64 {
        match &self.geometry {
            Geometry::Analytic(shape) => shape.bounding_radius(),
            Geometry::Mesh { mesh, .. } => mesh.mesh.positions.iter().map(|p| f64::from(p.length())).fold(0.0, f64::max),
        }
    }

    /// The mesh in the normalised frame, if the geometry is a mesh.
    pub fn mesh(&self) -> Option<&TexturedMesh> {
        match &self.geometry {
            Geometry::Mesh { mesh, .. } => Some(mesh),
            Geometry::Analytic(_) => None,
        }
    }
}

fn sample_mesh_surface(mesh: &prob_grid::TriangleMesh, count: usize, seed: u64) -> Vec<DVec3> {
    let mut cumulative = Vec::with_capacity(mesh.triangles.len());
    let mut total = 0.0f64;
    for t in 0..mesh.triangles.len() {
        total += 0.5 * mesh.face_normal(t as u32).length() as f64;
        cumulative.push(total);
    }
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    (0..count)
        .map(|_| {
            let pick = rng.random::<f64>() * total;
            let t = cumulative.partition_point(|c| *c < pick).min(cumulative.len() - 1);
            let [a, b, c] = mesh.triangles[t].map(|i| mesh.positions[i as usize].as_dvec3());
            let (u1, u2) = (rng.random::<f64>(), rng.random::<f64>());
            let s = u1.sqrt();
            a * (1.0 - s) + b * (s * (1.0 - u2)) + c * (s * u2)
        })
        .collect()
}

/// Centres a mesh, scales it into the sphere of radius [`MESH_RADIUS`] and turns y-up meshes
/// z-up; returns it with `world_from_normalized`.
fn normalize_mesh(mut mesh: TexturedMesh, y_up: bool) -> (TexturedMesh, DMat4) {
    let (lo, hi) = mesh.mesh.bounds();
    let center = ((lo + hi) / 2.0).as_dvec3();
    let radius = mesh.mesh.positions.iter().map(|p| (p.as_dvec3() - center).length()).fold(0.0, f64::max).max(1e-12);
    let scale = MESH_RADIUS / radius;
    // (x, y, z) ↦ (x, −z, y): a rotation of +90° about x taking +y to +z.
    let z_up_from_y_up = if y_up { DMat3::from_rotation_x(std::f64::consts::FRAC_PI_2) } else { DMat3::IDENTITY };
    let positions = mesh.mesh.positions.iter().map(|p| (z_up_from_y_up * ((p.as_dvec3() - center) * scale)).as_vec3()).collect();
    mesh.mesh = prob_grid::TriangleMesh::new(positions, std::mem::take(&mut mesh.mesh.triangles));
    let world_from_normalized =
        DMat4::from_translation(center) * DMat4::from_scale(DVec3::splat(1.0 / scale)) * DMat4::from_mat3(z_up_from_y_up.transpose());
    (mesh, world_from_normalized)
}

/// Renders a golden scene.
pub fn generate(spec: &GoldenSpec) -> Result<GoldenScene> {
    let (geometry, world_from_normalized, label) = match &spec.geometry {
        GeometrySource::Shape(name) => (Geometry::Analytic(name.shape()), DMat4::IDENTITY, format!("analytic {name}")),
        GeometrySource::Mesh(path) => {
            let (mesh, world_from_normalized) = normalize_mesh(load_mesh(path)?, spec.mesh_y_up);
            (Geometry::from_mesh(mesh), world_from_normalized, format!("mesh {}", path.display()))
        }
    };
    let cameras = rig::cameras(&spec.rig);
    let mut views = Vec::with_capacity(cameras.len());
    let mut depths = Vec::with_capacity(cameras.len());
    let mut normals = Vec::with_capacity(cameras.len());
    for (i, camera) in cameras.iter().enumerate() {
        let r = render_view(&geometry, camera, spec.backdrop);
        views.push(View { name: format!("{i:03}"), camera: *camera, image: r.image, mask: Some(r.mask) });
        depths.push(r.depth);
        normals.push(r.normal);
    }
    let seed = spec.rig.seed ^ 0x005e_ed0f_9017;
    let surface_points = match &geometry {
        Geometry::Analytic(shape) => shape.sample_surface(spec.surface_points as f64 / shape.area(), seed),
        Geometry::Mesh { mesh, .. } => sample_mesh_surface(&mesh.mesh, spec.surface_points, seed),
    };
    let description = format!(
        "golden scene: {label}, {:?} rig, {} views of {}×{}, seed {}, backdrop {}",
        spec.rig.rig,
        spec.rig.count,
        spec.rig.width,
        spec.rig.height,
        spec.rig.seed,
        spec.backdrop.name()
    );
    let golden = GoldenScene {
        scene: Scene { views, world_from_normalized, source: SceneSource { format: Format::Generated, path: None, description } },
        depths,
        normals,
        surface_points,
        geometry,
        spec: spec.clone(),
    };
    shrink(golden, spec.bound)
}

/// The scene in a frame shrunk by `bound` (≥ 1; see [`GoldenSpec::bound`]): the same pixels,
/// cameras, geometry, truth and depths divided by `bound`; `world_from_normalized` keeps the
/// scene's own units.
fn shrink(mut golden: GoldenScene, bound: f64) -> Result<GoldenScene> {
    if !(bound.is_finite() && bound >= 1.0) {
        let message = format!("the region of interest's radius must be ≥ 1, the object's own (got {bound})");
        return Err(crate::DatasetError::InvalidValue { path: "golden scene spec".into(), entry: "bound".into(), message });
    }
    if bound == 1.0 {
        return Ok(golden);
    }
    let s = 1.0 / bound;
    for view in &mut golden.scene.views {
        view.camera.camera_from_world.translation *= s;
    }
    for depth in golden.depths.iter_mut().flatten() {
        *depth *= s as f32;
    }
    for p in &mut golden.surface_points {
        *p *= s;
    }
    golden.geometry = match golden.geometry {
        Geometry::Analytic(shape) => Geometry::Analytic(shape.scaled(s)),
        Geometry::Mesh { mut mesh, vertex_normals } => {
            let positions = mesh.mesh.positions.iter().map(|p| *p * s as f32).collect();
            mesh.mesh = prob_grid::TriangleMesh::new(positions, std::mem::take(&mut mesh.mesh.triangles));
            Geometry::Mesh { mesh, vertex_normals }
        }
    };
    golden.scene.world_from_normalized *= DMat4::from_scale(DVec3::splat(bound));
    golden.scene.source.description += &format!(", bound {bound}");
    Ok(golden)
}

impl GoldenSpec {
    /// The built-in default scene (no files): the analytic composite (a sphere with a bite, a
    /// thin ring, a box foot), DTU rig, 49 views of 200×150, textured backdrop, masks.
    pub fn builtin() -> GoldenSpec {
        let mut spec = GoldenSpec::new(GeometrySource::Shape(ShapeName::Composite));
        spec.rig.width = 200;
        spec.rig.height = 150;
        spec
    }
}

/// Renders [`GoldenSpec::builtin`].
pub fn builtin_scene() -> GoldenScene {
    generate(&GoldenSpec::builtin()).expect("the built-in scene needs no files")
}

/// Writes a golden scene in the IDR layout, plus its truth:
/// `image/NNN.png`, `mask/NNN.png`, `cameras_sphere.npz` (`world_mat_i`, `scale_mat_i`),
/// `depth/NNN.npy` (H×W f32, normalised units, 0 = background), `normal/NNN.npy` (H×W×3 f32),
/// `gt_points.ply` (input world units), `gt_mesh.ply` (meshes only, input world units) and
/// `golden.json` (the spec). Every file is written atomically.
pub fn write_idr(golden: &GoldenScene, out: &Path) -> Result<()> {
    for sub in ["image", "mask", "depth", "normal"] {
        std::fs::create_dir_all(out.join(sub)).map_err(io_err(out.join(sub)))?;
    }
    let scene = &golden.scene;
    let scale_mat = scene.world_from_normalized;
    for (i, view) in scene.views.iter().enumerate() {
        let name = format!("{i:03}");
        view.image.save_png(&out.join("image").join(format!("{name}.png")))?;
        if let Some(mask) = &view.mask {
            mask.save_png(&out.join("mask").join(format!("{name}.png")))?;
        }
        let (w, h) = (view.camera.width as usize, view.camera.height as usize);
        write_atomic(&out.join("depth").join(format!("{name}.npy")), &npy_bytes(&[h, w], &golden.depths[i]))?;
        let flat: Vec<f32> = golden.normals[i].iter().flatten().copied().collect();
        write_atomic(&out.join("normal").join(format!("{name}.npy")), &npy_bytes(&[h, w, 3], &flat))?;
    }
    let cameras: Vec<_> = scene.views.iter().map(|v| v.camera).collect();
    crate::idr::write_cameras(out, &cameras, &scale_mat)?;

    let to_world = |p: DVec3| scale_mat.transform_point3(p).as_vec3();
    PlyData { positions: golden.surface_points.iter().map(|p| to_world(*p)).collect(), ..Default::default() }.write(&out.join("gt_points.ply"))?;
    if let Some(mesh) = golden.mesh() {
        PlyData {
            positions: mesh.mesh.positions.iter().map(|p| to_world(p.as_dvec3())).collect(),
            faces: mesh.mesh.triangles.clone(),
            ..Default::default()
        }
        .write(&out.join("gt_mesh.ply"))?;
    }
    let meta = serde_json::json!({
        "spec": golden.spec,
        "description": scene.source.description,
        "views": scene.views.len(),
        "surface_points": golden.surface_points.len(),
        "depth_units": "normalised frame (apply scale_mat for world units)",
        "points_units": "input world units (scale_mat applied)",
        "pixel_centers": "integer (IDR/NeuS convention)",
    });
    write_atomic(&out.join("golden.json"), serde_json::to_string_pretty(&meta).expect("json").as_bytes())
}

/// A small thumbnail grid of a scene's first views (RGB), `columns` across, each `thumb_width` wide.
pub fn thumbnail_grid(scene: &Scene, columns: usize, rows: usize, thumb_width: u32) -> crate::images::RgbImage {
    let first = &scene.views[0].camera;
    let thumb_height = (thumb_width as f64 * first.height as f64 / first.width as f64).round() as u32;
    let mut out = crate::images::RgbImage::new(thumb_width * columns as u32, thumb_height * rows as u32);
    let n = scene.views.len();
    for k in 0..(columns * rows).min(n) {
        let view = &scene.views[k * n / (columns * rows).min(n)];
        let (ox, oy) = ((k % columns) as u32 * thumb_width, (k / columns) as u32 * thumb_height);
        for y in 0..thumb_height {
            for x in 0..thumb_width {
                let sx = (x as u64 * view.image.width as u64 / thumb_width as u64) as u32;
                let sy = (y as u64 * view.image.height as u64 / thumb_height as u64) as u32;
                out.set_f32(ox + x, oy + y, view.image.get_f32(sx, sy));
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    #[test]
    fn builtin_scene_depths_and_normals_agree_with_the_sdf() {
        let g = builtin_scene();
        assert_eq!(g.scene.views.len(), 49);
        let Geometry::Analytic(shape) = &g.geometry else { panic!("the built-in scene is analytic") };
        let mut checked = 0;
        for (v, view) in g.scene.views.iter().enumerate().step_by(7) {
            let cam = &view.camera;
            let mask = view.mask.as_ref().unwrap();
            let fg = mask.count() as f64 / (cam.width * cam.height) as f64;
            assert!(fg > 0.1 && fg < 0.9, "view {v}: foreground {fg}");
            for row in (0..cam.height).step_by(5) {
                for col in (0..cam.width).step_by(5) {
                    let i = (row * cam.width + col) as usize;
                    let depth = g.depths[v][i] as f64;
                    assert_eq!(mask.get(col, row), depth > 0.0);
                    if depth > 0.0 {
                        let p = cam.world_from_pixel_space(cam.pixel_center(col, row).extend(depth));
                        assert!(shape.sdf(p).abs() < 1e-5, "view {v} ({col},{row}): S = {}", shape.sdf(p));
                        let n = DVec3::from_array(g.normals[v][i].map(f64::from));
                        assert!((n.length() - 1.0).abs() < 1e-5);
                        checked += 1;
                    }
                }
            }
        }
        assert!(checked > 500, "{checked}");
    }

    #[test]
    fn golden_scenes_are_deterministic_for_a_seed() {
        let mut spec = GoldenSpec::new(GeometrySource::Shape(ShapeName::Torus));
        spec.rig = RigOptions { rig: Rig::Random, count: 3, width: 32, height: 24, seed: 9 };
        spec.surface_points = 500;
        let (a, b) = (generate(&spec).unwrap(), generate(&spec).unwrap());
        assert_eq!(a.scene, b.scene);
        assert_eq!(a.surface_points, b.surface_points);
        spec.rig.seed = 10;
        assert_ne!(generate(&spec).unwrap().scene.views[0].camera, a.scene.views[0].camera);
    }

    #[test]
    fn a_looser_bound_shrinks_the_frame_and_keeps_every_pixel() {
        let mut spec = GoldenSpec::new(GeometrySource::Shape(ShapeName::Composite));
        spec.rig = RigOptions { rig: Rig::Dtu, count: 4, width: 48, height: 36, seed: 2 };
        spec.surface_points = 2000;
        let tight = generate(&spec).unwrap();
        spec.bound = 1.6;
        let loose = generate(&spec).unwrap();
        let Geometry::Analytic(shape) = &loose.geometry else { panic!("analytic") };
        assert!((shape.bounding_radius() - tight.geometry_radius() / 1.6).abs() < 1e-12);
        for (v, (a, b)) in tight.scene.views.iter().zip(&loose.scene.views).enumerate() {
            assert_eq!(a.image, b.image, "view {v}: the same pixels");
            assert_eq!(a.mask, b.mask);
            // The truth projects to the same pixel at a depth shrunk by the bound.
            for p in tight.surface_points.iter().step_by(97) {
                let (pa, pb) = (a.camera.pixel_space_from_world(*p), b.camera.pixel_space_from_world(*p / 1.6));
                assert!((pa.truncate() - pb.truncate()).length() < 1e-9 && (pa.z / 1.6 - pb.z).abs() < 1e-9);
            }
            for (da, db) in tight.depths[v].iter().zip(&loose.depths[v]) {
                assert!((da / 1.6 - db).abs() <= 1e-6 * da);
            }
        }
        // World units are the object's own: the truth maps back to the tight scene's.
        let back = loose.scene.world_from_normalized.transform_point3(loose.surface_points[5]);
        assert!((back - tight.surface_points[5]).length() < 1e-12);
        spec.bound = 0.8;
        assert!(generate(&spec).unwrap_err().to_string().contains("≥ 1"));
    }

    #[test]
    fn a_near_backdrop_is_pixels_but_not_object() {
        let mut spec = GoldenSpec::new(GeometrySource::Shape(ShapeName::Sphere));
        spec.rig = RigOptions { rig: Rig::Dtu, count: 3, width: 40, height: 30, seed: 0 };
        spec.surface_points = 100;
        spec.backdrop = Backdrop::None;
        let black = generate(&spec).unwrap();
        spec.backdrop = Backdrop::Wall;
        let wall = generate(&spec).unwrap();
        for (a, b) in black.scene.views.iter().zip(&wall.scene.views) {
            assert_eq!(a.mask, b.mask, "the mask is the object's alone");
            let mask = a.mask.as_ref().unwrap();
            let backdrop_pixels = (0..a.camera.height).flat_map(|r| (0..a.camera.width).map(move |c| (c, r))).filter(|&(c, r)| !mask.get(c, r));
            assert!(backdrop_pixels.into_iter().all(|(c, r)| a.image.get_f32(c, r) == [0.0; 3] && b.image.get_f32(c, r) != [0.0; 3]));
        }
        assert_eq!(black.depths, wall.depths);
    }
}
