//! The data of a run: the scene (built-in golden scene or a dataset folder), its ground truth
//! when it has one, and the split into training and held-out views.

use crate::bail;
use crate::config::TrainConfig;
use crate::error::{Context, Result};
use datasets::golden::{self, GeometrySource, GoldenSpec};
use datasets::io::PlyData;
use datasets::{LoadOptions, Scene, load_scene};
use glam::{DVec3, Vec3};
use std::path::{Path, PathBuf};

/// The options the loaders get from a configuration.
fn load_options(config: &TrainConfig) -> LoadOptions {
    let bound_sphere = config.data.bound.map(|[x, y, z, r]| (glam::DVec3::new(x, y, z), r));
    LoadOptions { downscale: config.data.downscale, background: config.model.background.map(|c| c as f32), bound_sphere, ..Default::default() }
}

/// The golden scene `config.data.builtin` describes.
fn builtin_spec(config: &TrainConfig) -> GoldenSpec {
    let b = &config.data.builtin;
    let mut spec = GoldenSpec::builtin();
    spec.geometry = GeometrySource::Shape(b.shape);
    spec.rig.width = b.width;
    spec.rig.height = b.width * 3 / 4;
    spec.rig.count = b.views;
    spec.backdrop = b.backdrop;
    spec.rig.rig = b.rig;
    spec.bound = b.bound;
    spec
}

/// Ground-truth points (normalised frame) and, where the truth has them, their unit normals
/// ([`SceneData::oriented_ground_truth`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Truth {
    /// The points.
    pub points: Vec<[f32; 3]>,
    /// One unit normal per point (`None`: a point cloud, such as DTU's, has none).
    pub normals: Option<Vec<[f32; 3]>>,
}

/// An analytic surface's truth points at a protocol's `spacing`: `1 / spacing²` points per unit
/// of area, as a truth mesh is sampled (`eval_metrics::sample_mesh`); deterministic.
pub fn analytic_truth(shape: &prob_grid::Shape, spacing: f64) -> Vec<[f32; 3]> {
    shape.sample_surface(1.0 / (spacing * spacing), crate::evaluation::GT_SAMPLING_SEED).iter().map(|p| p.as_vec3().to_array()).collect()
}

/// The unit normals of an analytic surface at its `points` (the SDF's gradient; zero where it
/// vanishes).
pub fn analytic_normals(shape: &prob_grid::Shape, points: &[[f32; 3]]) -> Vec<[f32; 3]> {
    points.iter().map(|p| shape.gradient(Vec3::from_array(*p).as_dvec3()).normalize_or_zero().as_vec3().to_array()).collect()
}

/// What the memory model needs of a scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneSize {
    /// Views.
    pub views: usize,
    /// Bytes of all images and masks as loaded.
    pub pixel_bytes: usize,
    /// Pixels of the largest view.
    pub largest_view_pixels: usize,
    /// The widest view's width in pixels.
    pub widest_view: u32,
    /// Whether every view has a mask.
    pub masks: bool,
    /// The views' median pixel footprint at the region of interest ([`crate::sizing`]).
    pub footprint: Option<f64>,
}

impl SceneSize {
    /// The views of `cameras`, `pixels` pixels each (masked or not).
    fn new(cameras: &[camera_geom::PinholeCamera], pixels: usize, masks: bool) -> SceneSize {
        let mask_bytes = if masks { pixels.div_ceil(8) } else { 0 };
        let views = cameras.len();
        let footprint = crate::sizing::median_footprint(cameras);
        let widest_view = cameras.iter().map(|c| c.width).max().unwrap_or(0);
        SceneSize { views, pixel_bytes: views * (3 * pixels + mask_bytes), largest_view_pixels: pixels, widest_view, masks, footprint }
    }

    /// The sizes of a loaded scene.
    pub fn of(scene: &Scene) -> SceneSize {
        SceneSize {
            views: scene.views.len(),
            pixel_bytes: scene.pixel_bytes(),
            largest_view_pixels: scene.views.iter().map(|v| v.image.width as usize * v.image.height as usize).max().unwrap_or(0),
            widest_view: scene.views.iter().map(|v| v.image.width).max().unwrap_or(0),
            masks: scene.views.iter().all(|v| v.mask.is_some()),
            footprint: crate::sizing::median_footprint(scene.views.iter().map(|v| &v.camera)),
        }
    }
}

/// A scene with what a run needs to know about where it came from.
#[derive(Debug, Clone)]
pub struct SceneData {
    /// The views (normalised frame).
    pub scene: Scene,
    /// Surface points of the built-in scene (normalised frame), its ground truth.
    pub builtin_truth: Option<Vec<DVec3>>,
    /// The built-in scene's analytic shape (normalised frame): the truth's exact SDF.
    pub builtin_shape: Option<prob_grid::Shape>,
    /// The dataset folder (`None` for the built-in scene).
    pub path: Option<PathBuf>,
}

impl SceneData {
    /// The same scene's frame and source without its views, truth or path: a stand-in while the
    /// views are lent to another trainer.
    pub fn without_views(&self) -> SceneData {
        let scene = Scene { views: Vec::new(), world_from_normalized: self.scene.world_from_normalized, source: self.scene.source.clone() };
        SceneData { scene, builtin_truth: None, builtin_shape: None, path: None }
    }

    /// The built-in golden scene as `config.data.builtin` describes it (no files).
    pub fn builtin(config: &TrainConfig) -> Result<SceneData> {
        if config.data.bound.is_some() {
            bail!(
                Config,
                "data.bound applies to dataset folders (COLMAP, instant-ngp, NeRF-synthetic); the built-in scene's bound is the unit sphere"
            );
        }
        let g = golden::generate(&builtin_spec(config)).context("rendering the built-in scene")?;
        let builtin_shape = match g.geometry {
            golden::render::Geometry::Analytic(shape) => Some(shape),
            golden::render::Geometry::Mesh { .. } => None,
        };
        Ok(SceneData { scene: g.scene, builtin_truth: Some(g.surface_points), builtin_shape, path: None })
    }

    /// A dataset folder (any layout `datasets` reads).
    pub fn folder(config: &TrainConfig, dir: &Path) -> Result<SceneData> {
        let scene = load_scene(dir, &load_options(config)).with_context(|| format!("cannot load the data folder {}", dir.display()))?;
        if scene.views.is_empty() {
            bail!(Input, "the data folder {} has no views", dir.display());
        }
        Ok(SceneData { scene, builtin_truth: None, builtin_shape: None, path: Some(dir.to_path_buf()) })
    }

    /// The sizes of the scene `load` would make, from the configuration (the built-in scene) or
    /// the cameras and image headers (a folder): no pixel is decoded or rendered.
    pub fn size_before_loading(config: &TrainConfig, dir: Option<&Path>) -> Result<SceneSize> {
        let Some(dir) = dir else {
            let spec = builtin_spec(config);
            let (w, h) = (spec.rig.width as usize, spec.rig.height as usize);
            return Ok(SceneSize::new(&golden::rig::cameras(&spec.rig), w * h, true));
        };
        let cameras = datasets::read_cameras(dir, &load_options(config)).with_context(|| format!("cannot load the data folder {}", dir.display()))?;
        let pixels: Vec<usize> = cameras.records.iter().map(|r| r.camera.width as usize * r.camera.height as usize).collect();
        // NeRF-synthetic's masks are the images' alpha: they have no file of their own.
        let masks = cameras.records.iter().all(|r| r.mask_path.is_some()) || datasets::detect_format(dir)? == datasets::Format::NerfSynthetic;
        Ok(SceneSize {
            views: pixels.len(),
            pixel_bytes: pixels.iter().map(|p| 3 * p + p.div_ceil(8)).sum(),
            largest_view_pixels: pixels.iter().copied().max().unwrap_or(0),
            widest_view: cameras.records.iter().map(|r| r.camera.width).max().unwrap_or(0),
            masks,
            footprint: crate::sizing::median_footprint(cameras.records.iter().map(|r| &r.camera)),
        })
    }

    /// The folder if given, else the built-in scene.
    pub fn load(config: &TrainConfig, dir: Option<&Path>) -> Result<SceneData> {
        match dir {
            Some(dir) => SceneData::folder(config, dir),
            None => SceneData::builtin(config),
        }
    }

    /// Ground-truth points in the normalised frame, if the data has them: the built-in scene's
    /// surface samples, or `gt_mesh.ply` (sampled every `spacing`) / `gt_points.ply` (input world
    /// units) in the data folder.
    pub fn ground_truth(&self, spacing: f64) -> Result<Option<Vec<[f32; 3]>>> {
        Ok(self.truth(spacing, false)?.map(|t| t.points))
    }

    /// [`Self::ground_truth`] with the truth's unit normals where it has them: the analytic
    /// shape's gradient, or the triangle of `gt_mesh.ply` each point lies on (none for
    /// `gt_points.ply`).
    pub fn oriented_ground_truth(&self, spacing: f64) -> Result<Option<Truth>> {
        self.truth(spacing, true)
    }

    /// The truth's points, with its normals when `oriented` asks for them (the same points).
    fn truth(&self, spacing: f64, oriented: bool) -> Result<Option<Truth>> {
        if let Some(points) = &self.builtin_truth {
            // A protocol finer than the default samples the analytic surface at its own density,
            // as a truth mesh is sampled; the default keeps the stored points (every table so far).
            let points = match &self.builtin_shape {
                Some(shape) if spacing < crate::config::DEFAULT_CHAMFER_SPACING => analytic_truth(shape, spacing),
                _ => points.iter().map(|p| p.as_vec3().to_array()).collect(),
            };
            let normals = self.builtin_shape.as_ref().filter(|_| oriented).map(|shape| analytic_normals(shape, &points));
            return Ok(Some(Truth { points, normals }));
        }
        let Some(dir) = &self.path else { return Ok(None) };
        let normalized_from_world = self.scene.world_from_normalized.inverse();
        let to_normalized = |p: &Vec3| normalized_from_world.transform_point3(p.as_dvec3()).as_vec3().to_array();
        let mesh_path = dir.join("gt_mesh.ply");
        if mesh_path.exists() {
            let ply = PlyData::read(&mesh_path).with_context(|| format!("ground-truth mesh {}", mesh_path.display()))?;
            let v: Vec<[f32; 3]> = ply.positions.iter().map(to_normalized).collect();
            let context = || format!("ground-truth mesh {}", mesh_path.display());
            let seed = crate::evaluation::GT_SAMPLING_SEED;
            let truth = if oriented {
                let sampled = eval_metrics::sample_mesh_oriented(&v, &ply.faces, spacing, seed).with_context(context)?;
                Truth { points: sampled.points, normals: Some(sampled.normals) }
            } else {
                Truth { points: eval_metrics::sample_mesh(&v, &ply.faces, spacing, seed).with_context(context)?, normals: None }
            };
            return Ok(Some(truth));
        }
        let points_path = dir.join("gt_points.ply");
        if points_path.exists() {
            let ply = PlyData::read(&points_path).with_context(|| format!("ground-truth points {}", points_path.display()))?;
            return Ok(Some(Truth { points: ply.positions.iter().map(to_normalized).collect(), normals: None }));
        }
        Ok(None)
    }

    /// One line describing the data.
    pub fn description(&self) -> &str {
        &self.scene.source.description
    }
}

/// Training and held-out views.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ViewSplit {
    /// Indices of the training views.
    pub train: Vec<usize>,
    /// Indices of the held-out views (may be empty).
    pub held_out: Vec<usize>,
}

impl ViewSplit {
    /// Every `holdout_every`-th view is held out (a single view is always trained on).
    pub fn new(config: &TrainConfig, scene: &Scene) -> ViewSplit {
        let n = scene.views.len();
        let held = |i: usize| config.data.holdout_every.is_some_and(|every| i % every == every - 1) && n > 1;
        ViewSplit { train: (0..n).filter(|&i| !held(i)).collect(), held_out: (0..n).filter(|&i| held(i)).collect() }
    }

    /// The training views' cameras in `scene` (normalised frame): what observed the scene
    /// ([`crate::observation`]).
    pub fn train_cameras(&self, scene: &Scene) -> Vec<camera_geom::PinholeCamera> {
        self.train.iter().map(|&v| scene.views[v].camera).collect()
    }

    /// The views evaluation renders: the held-out ones, or all views when none are held out.
    pub fn evaluation_views(&self) -> Vec<usize> {
        if self.held_out.is_empty() {
            let mut all: Vec<usize> = self.train.clone();
            all.sort_unstable();
            all
        } else {
            self.held_out.clone()
        }
    }
}

/// Whether the masks are used: asked for and present on every view.
pub fn uses_masks(config: &TrainConfig, scene: &Scene) -> bool {
    config.data.masks && scene.views.iter().all(|v| v.mask.is_some())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The analytic truth's normals are its surface's: radial on a sphere, the faces' on a box,
    /// unit length on the composite; a truth mesh's are its triangles' (`eval_metrics`' test).
    #[test]
    fn the_built_in_truth_is_oriented_by_its_shapes_gradient() {
        use prob_grid::ShapeName;
        let config = TrainConfig::load(None, &["data.builtin.width=40".into(), "data.builtin.views=4".into()]).unwrap();
        let truth = SceneData::builtin(&config).unwrap().oriented_ground_truth(crate::config::DEFAULT_CHAMFER_SPACING).unwrap().unwrap();
        let normals = truth.normals.expect("an analytic truth has normals");
        assert_eq!(normals.len(), truth.points.len());
        assert!(normals.iter().all(|n| (Vec3::from_array(*n).length() - 1.0).abs() < 1e-3));
        let sphere = ShapeName::Sphere.shape();
        let points = analytic_truth(&sphere, 0.05);
        for (p, n) in points.iter().zip(analytic_normals(&sphere, &points)) {
            assert!(Vec3::from_array(*p).normalize().dot(Vec3::from_array(n)) > 0.9999, "{p:?}: {n:?}");
        }
        let cube = ShapeName::Box.shape();
        let points = analytic_truth(&cube, 0.05);
        for (p, n) in points.iter().zip(analytic_normals(&cube, &points)) {
            // The face a point lies on: its largest coordinate; corners and edges aside.
            let q = Vec3::from_array(*p);
            let axis = q.abs().max_position();
            if q.abs().to_array().iter().filter(|c| **c > 0.34).count() == 1 {
                assert!((n[axis].abs() - 1.0).abs() < 1e-4 && n[axis].signum() == q[axis].signum(), "{p:?}: {n:?}");
            }
        }
    }

    /// The built-in truth keeps its stored points at the default protocol (every table so far)
    /// and follows a finer protocol's density, as a truth mesh would: about four times the points
    /// at half the spacing.
    #[test]
    fn a_finer_protocol_samples_the_built_in_truth_at_its_own_density() {
        let config = TrainConfig::load(None, &["data.builtin.width=40".into(), "data.builtin.views=4".into()]).unwrap();
        let data = SceneData::builtin(&config).unwrap();
        let stored = data.builtin_truth.as_ref().unwrap().len();
        let at = |spacing: f64| data.ground_truth(spacing).unwrap().unwrap().len() as f64;
        assert_eq!(at(crate::config::DEFAULT_CHAMFER_SPACING) as usize, stored);
        let (fine, finer) = (at(0.003), at(0.0015));
        assert!((finer / fine - 4.0).abs() < 0.1, "{fine} → {finer}");
        // The CSG area is an upper bound (the sum over the primitives, hidden parts included).
        let area = data.builtin_shape.as_ref().unwrap().area();
        assert!((0.5..=1.0).contains(&(fine * 0.003 * 0.003 / area)), "{fine} points on at most {area}");
    }
}
