//! The estimator (nerfacc's shape): one object a training loop holds, with two verbs —
//! [`Estimator::update_due`] (the update when its schedule says so, from any [`SdfField`], with
//! the Lipschitz bound it carries from one update to the next) and [`Estimator::draw_rays`]
//! (a batch of rays with their coarse samples and guided depths) — and, below them,
//! [`Estimator::update`], [`Estimator::draw`] and [`Estimator::march`] for callers that
//! schedule themselves. `examples/toy_sdf.rs` trains an SDF of its own with the two verbs alone.
//!
//! - **Guided** (`config.guided`): the update evaluates p(x) = φ_s(S(x)) on the scene grid,
//!   reprojects it into every camera and builds the samplers; draws mix guided and uniform rays
//!   by the schedule, each with its λ̃.
//! - **Uniform** (guide off): the same object draws uniform pixels (no λ̃). It still updates when
//!   empty-space skipping is on, for the occupancy.
//! - **Empty-space skipping** (`config.skip_empty`): the update keeps an occupancy bitfield of
//!   the scene grid's cells that hold mass ([`Occupancy`], dilated by `config.dilation` cells);
//!   [`Estimator::march`] then places a ray's coarse samples only in its occupied intervals, so
//!   the samples freed from empty space land where the surface can be. The evaluation checks the
//!   field's Lipschitz claim against its own values ([`prob_grid::LipschitzCheck`]): a wrong bound
//!   is detected and the evaluation redone, not trusted.
//!
//!   The trainer skips empty space by default (`render.skip_empty`, 16 coarse + 16 fine samples
//!   per ray): why, and what it buys at equal wall time, is in the repository's
//!   docs/DECISIONS.md §24.
//!
//! Sampling is outside any gradient graph: everything here returns numbers.

use crate::{CameraDistribution, DepthSample, Interpolation, RaySample, SamplerConfig, UniformSchedule, ViewSampler, draw_batch, uniform_pixel};
use camera_geom::PinholeCamera;
use glam::DVec3;
use prob_grid::{CameraGrid, CameraGridConfig, GridError, LipschitzCheck, Occupancy, SceneGridConfig, SdfField, evaluate, reproject};
use rayon::prelude::*;
use std::time::Instant;

/// What an [`Estimator`] does and with which grids.
#[derive(Debug, Clone, PartialEq)]
pub struct EstimatorConfig {
    /// Guided rays (the paper) or uniform pixels only.
    pub guided: bool,
    /// The scene grid (evaluation of p(x)).
    pub scene: SceneGridConfig,
    /// The camera grids.
    pub camera: CameraGridConfig,
    /// Interpolation of the conditionals.
    pub interpolation: Interpolation,
    /// Uniform/guided mix over the run.
    pub schedule: UniformSchedule,
    /// FS ablation: the update evaluates p(x) at this fixed s instead of the backbone's.
    pub fixed_s: Option<f32>,
    /// Empty-space skipping for [`Estimator::march`].
    pub skip_empty: bool,
    /// Dilation of the occupancy, in scene-grid cells (covers a surface that moves between
    /// updates).
    pub dilation: u32,
    /// Updates per run for [`Estimator::update_due`]: one at the start of each of `updates`
    /// equal parts of the run's progress (≥ 1).
    pub updates: u32,
}

impl Default for EstimatorConfig {
    fn default() -> Self {
        EstimatorConfig {
            guided: true,
            scene: SceneGridConfig::default(),
            camera: CameraGridConfig::default(),
            interpolation: Interpolation::Linear,
            schedule: UniformSchedule::default(),
            fixed_s: None,
            skip_empty: true,
            dilation: 1,
            updates: 6,
        }
    }
}

/// The margin over the slope an update measured that the next update claims for the field
/// ([`Estimator::update_due`]): a learnt SDF steepens between updates; a claim found broken
/// redoes the evaluation ([`LipschitzCheck`]).
pub const CARRIED_LIPSCHITZ_MARGIN: f32 = 1.25;

/// The Lipschitz bound an estimator claims for a field before its first update.
pub const INITIAL_LIPSCHITZ: f32 = 1.5;

/// A field with the Lipschitz bound the estimator carries instead of its own claim.
struct Claimed<'a> {
    field: &'a dyn SdfField,
    bound: f32,
}

impl SdfField for Claimed<'_> {
    fn sdf_batch(&self, points: &[glam::Vec3], out: &mut [f32]) {
        self.field.sdf_batch(points, out)
    }
    fn lipschitz_bound(&self) -> f32 {
        self.bound
    }
}

/// A ray with its coarse sample depths, as a renderer takes it (f32, unit direction).
#[derive(Debug, Clone, PartialEq)]
pub struct CoarseRay {
    /// Origin, normalised frame.
    pub origin: [f32; 3],
    /// Unit direction, normalised frame.
    pub direction: [f32; 3],
    /// The `coarse + 1` coarse sample depths ([`Estimator::march`]).
    pub depths: Vec<f32>,
}

/// One ray of [`Estimator::draw_rays`]: what was drawn, the ray with its coarse samples, and
/// (guided rays) λ̃ along it.
#[derive(Debug, Clone, PartialEq)]
pub struct DrawnRay {
    /// The drawn pixel (camera, pixel, pdf, guided or not).
    pub sample: RaySample,
    /// The ray through it with its coarse samples.
    pub ray: CoarseRay,
    /// λ̃ as a distance along the ray (`None`: a ray without one).
    pub surface: Option<SurfaceDistance>,
}

/// What one update did and cost.
#[derive(Debug, Clone, PartialEq)]
pub struct UpdateReport {
    /// Wall time of the update (evaluation, reprojection, CDFs).
    pub seconds: f64,
    /// The s the field was evaluated at.
    pub s: f32,
    /// Field queries made.
    pub field_queries: usize,
    /// Scene mass Σ p(x)·volume.
    pub scene_mass: f64,
    /// Fraction of the scene grid occupied (1 without empty-space skipping).
    pub occupied_fraction: f64,
    /// Cameras whose grid holds no mass (sampled uniformly).
    pub empty_cameras: Vec<usize>,
    /// The field's Lipschitz claim against its values.
    pub lipschitz: LipschitzCheck,
}

/// Guided (or uniform) rays and their coarse samples, updated from an SDF (see the module docs).
#[derive(Debug, Clone)]
pub struct Estimator {
    cameras: Vec<PinholeCamera>,
    config: EstimatorConfig,
    sampler: Option<ViewSampler>,
    /// The camera grids' values of the last update (guided), for [`Estimator::state`].
    grids: Vec<Vec<f32>>,
    occupancy: Option<Occupancy>,
    /// The part of the run whose update is in use ([`Estimator::update_due`]).
    part: Option<u32>,
    /// The Lipschitz bound claimed for the field at the next scheduled update.
    lipschitz: f32,
}

/// λ̃ of a drawn ray along the ray ([`Estimator::surface_distance`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceDistance {
    /// λ̃ as a distance along the ray's unit direction.
    pub distance: f64,
    /// One λ bin of the ray's camera grid as a distance along the ray: how far λ̃ can be from
    /// the surface the grid holds (0 without a guide).
    pub bin: f64,
    /// A *background* ray for the surface losses: no λ̃ from the grid (its column held no
    /// mass), or λ̃ outside the unit bound sphere.
    pub background: bool,
}

/// What an estimator's last update built, to save and restore exactly (a resumed run draws the
/// same rays as an uninterrupted one): the camera grids' values and the occupancy.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EstimatorState {
    /// Per camera, its grid's values (guided; empty otherwise).
    pub grids: Vec<Vec<f32>>,
    /// The occupancy, one value per scene-grid cell ([`Occupancy::to_values`]), if skipping.
    pub occupancy: Option<Vec<f32>>,
    /// The part of the run of the last scheduled update (`None`: none yet).
    pub part: Option<u32>,
    /// The Lipschitz bound the next scheduled update claims.
    pub lipschitz: f32,
}

/// NeuS's near/far: the sphere of radius 1 around the origin, measured from the ray's closest
/// approach (`mid = −o·d`, `[mid − 1, mid + 1]`), near clamped to 0.05 so that cameras inside the
/// bound still get samples in front of them. `direction` is a unit vector.
pub fn near_far(origin: DVec3, direction: DVec3) -> (f64, f64) {
    let mid = -origin.dot(direction);
    let near = (mid - 1.0).max(0.05);
    (near, (mid + 1.0).max(near + 1e-3))
}

impl Estimator {
    /// An estimator over `cameras` (the training views); checks the configuration.
    pub fn new(cameras: Vec<PinholeCamera>, config: EstimatorConfig) -> Result<Estimator, GridError> {
        config.scene.validate()?;
        config.camera.validate()?;
        if cameras.is_empty() {
            return Err(GridError::InvalidConfig { what: "estimator", message: "no cameras".into() });
        }
        if let Some(s) = config.fixed_s.filter(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(GridError::InvalidConfig { what: "fixed s", message: format!("{s} (must be finite and > 0)") });
        }
        if config.updates == 0 {
            return Err(GridError::InvalidConfig { what: "estimator", message: "updates per run must be ≥ 1".into() });
        }
        Ok(Estimator { cameras, config, sampler: None, grids: Vec::new(), occupancy: None, part: None, lipschitz: INITIAL_LIPSCHITZ })
    }

    /// The scheduled update: when `progress` ∈ [0, 1] enters a new one of the run's
    /// `config.updates` parts, rebuilds the grids from `field` at scale `s` and returns the
    /// report; otherwise (or with nothing to update) `None`. The field's own Lipschitz claim is
    /// replaced by the bound the estimator carries: the slope the last update measured ×
    /// [`CARRIED_LIPSCHITZ_MARGIN`] (at least 1).
    pub fn update_due(&mut self, progress: f64, field: &dyn SdfField, s: f32) -> Result<Option<UpdateReport>, GridError> {
        if !self.needs_updates() || self.part == Some(self.part_at(progress)) {
            return Ok(None);
        }
        self.update_at(progress, field, s).map(Some)
    }

    /// [`Self::update_due`] now, whatever the schedule (the grids then belong to the part of
    /// `progress`): for a caller whose field changed outside training.
    pub fn update_at(&mut self, progress: f64, field: &dyn SdfField, s: f32) -> Result<UpdateReport, GridError> {
        self.part = Some(self.part_at(progress));
        let report = self.update(&Claimed { field, bound: self.lipschitz }, s)?;
        self.lipschitz = (report.lipschitz.measured * CARRIED_LIPSCHITZ_MARGIN).max(1.0);
        Ok(report)
    }

    /// The part of the run at `progress`.
    fn part_at(&self, progress: f64) -> u32 {
        let updates = self.config.updates;
        ((progress * f64::from(updates)).floor() as u32).min(updates - 1)
    }

    /// The Lipschitz bound the estimator carries for the field (what the next scheduled update
    /// claims; a mesh extraction of the same field may use it).
    pub fn lipschitz_bound(&self) -> f32 {
        self.lipschitz
    }

    /// `n` rays at training `progress` ([`Self::draw`]), each with its `coarse + 1` coarse
    /// samples ([`Self::march`] with the explicit uniform `jitter(i)` ∈ [0, 1) of ray `i`) and
    /// its λ̃ ([`Self::surface_distance`]). Deterministic in (seed, step, jitter).
    pub fn draw_rays(&self, n: usize, progress: f64, seed: u64, step: u64, coarse: usize, jitter: &(dyn Fn(usize) -> f64 + Sync)) -> Vec<DrawnRay> {
        self.rays_of(self.draw(n, progress, seed, step), coarse, jitter)
    }

    /// [`Self::draw_rays`] with the uniform share given instead of the schedule's
    /// ([`Self::draw_mixed`]).
    pub fn draw_rays_mixed(
        &self,
        n: usize,
        uniform_fraction: f64,
        seed: u64,
        step: u64,
        coarse: usize,
        jitter: &(dyn Fn(usize) -> f64 + Sync),
    ) -> Vec<DrawnRay> {
        self.rays_of(self.draw_mixed(n, uniform_fraction, seed, step), coarse, jitter)
    }

    /// The rays of drawn pixels (from this estimator or any other pixel sampler, e.g. an
    /// [`crate::ErrorMap`]) with their coarse samples ([`Self::march`] at `jitter(i)`) and λ̃.
    pub fn rays_of(&self, samples: Vec<RaySample>, coarse: usize, jitter: &(dyn Fn(usize) -> f64 + Sync)) -> Vec<DrawnRay> {
        samples
            .into_par_iter()
            .enumerate()
            .map(|(i, sample)| {
                let [col, row] = sample.pixel;
                let ray = self.coarse_ray(&self.cameras[sample.camera as usize], col, row, coarse, jitter(i));
                let origin = DVec3::from_array(ray.origin.map(f64::from));
                let direction = DVec3::from_array(ray.direction.map(f64::from));
                let surface = self.surface_distance(&sample, origin, direction);
                DrawnRay { sample, ray, surface }
            })
            .collect()
    }

    /// The ray through pixel (col, row) of any `camera` (e.g. a training view at another
    /// resolution) with its `coarse + 1` coarse samples at `jitter` ∈ [0, 1).
    pub fn coarse_ray(&self, camera: &PinholeCamera, col: u32, row: u32, coarse: usize, jitter: f64) -> CoarseRay {
        let ray = camera.ray_through_pixel_index(col, row);
        let mut depths = Vec::with_capacity(coarse + 1);
        self.march(ray.origin, ray.direction, coarse, jitter, &mut depths);
        CoarseRay { origin: ray.origin.as_vec3().to_array(), direction: ray.direction.as_vec3().to_array(), depths }
    }

    /// The configuration.
    pub fn config(&self) -> &EstimatorConfig {
        &self.config
    }

    /// The cameras.
    pub fn cameras(&self) -> &[PinholeCamera] {
        &self.cameras
    }

    /// Whether [`Self::update`] does anything (a guide, or empty-space skipping).
    pub fn needs_updates(&self) -> bool {
        self.config.guided || self.config.skip_empty
    }

    /// The guided sampler of the last update (`None` before it, or without a guide).
    pub fn sampler(&self) -> Option<&ViewSampler> {
        self.sampler.as_ref()
    }

    /// The per-camera distributions of the last update (empty without a guide).
    pub fn distributions(&self) -> &[CameraDistribution] {
        self.sampler.as_ref().map_or(&[], ViewSampler::cameras)
    }

    /// The occupancy of the last update (`None` before it, or without skipping).
    pub fn occupancy(&self) -> Option<&Occupancy> {
        self.occupancy.as_ref()
    }

    /// Rebuilds the grids from `field` at scale `s` (or the fixed s): the occupancy (with
    /// skipping) and the guide (guided). A no-op that reports zeros when neither is on.
    pub fn update(&mut self, field: &dyn SdfField, s: f32) -> Result<UpdateReport, GridError> {
        let t = Instant::now();
        let s = self.config.fixed_s.unwrap_or(s);
        let mut report = UpdateReport {
            seconds: 0.0,
            s,
            field_queries: 0,
            scene_mass: 0.0,
            occupied_fraction: 1.0,
            empty_cameras: Vec::new(),
            lipschitz: LipschitzCheck::default(),
        };
        if !self.needs_updates() {
            return Ok(report);
        }
        let active = evaluate(field, s, &self.config.scene)?;
        report.field_queries = active.field_queries;
        report.scene_mass = active.total_mass;
        report.lipschitz = active.lipschitz;
        if self.config.skip_empty {
            let occupancy = Occupancy::from_active(&active, &self.config.scene, self.config.dilation);
            report.occupied_fraction = occupancy.occupied_fraction();
            self.occupancy = Some(occupancy);
        }
        if self.config.guided {
            let grids: Vec<CameraGrid> = self.cameras.par_iter().map(|c| reproject(&active, c, &self.config.camera)).collect();
            report.empty_cameras = grids.iter().enumerate().filter(|(_, g)| !(g.total() > 0.0)).map(|(i, _)| i).collect();
            self.grids = grids.iter().map(|g| g.values.clone()).collect();
            self.build_sampler(grids);
        }
        report.seconds = t.elapsed().as_secs_f64();
        Ok(report)
    }

    fn build_sampler(&mut self, grids: Vec<CameraGrid>) {
        let config = SamplerConfig { interpolation: self.config.interpolation, schedule: self.config.schedule.clone() };
        self.sampler = Some(ViewSampler::new(grids, config));
    }

    /// What the last update built ([`EstimatorState`]).
    pub fn state(&self) -> EstimatorState {
        EstimatorState {
            grids: self.grids.clone(),
            occupancy: self.occupancy.as_ref().map(Occupancy::to_values),
            part: self.part,
            lipschitz: self.lipschitz,
        }
    }

    /// Restores what [`Self::state`] saved (same cameras and configuration).
    pub fn restore(&mut self, state: &EstimatorState) -> Result<(), GridError> {
        let bad = |message: String| GridError::InvalidConfig { what: "estimator state", message };
        if !(state.lipschitz.is_finite() && state.lipschitz > 0.0) {
            return Err(bad(format!("a Lipschitz bound of {}", state.lipschitz)));
        }
        (self.part, self.lipschitz) = (state.part, state.lipschitz);
        if state.part.is_none() {
            // No update was made yet: nothing else to restore.
            return Ok(());
        }
        if self.config.guided {
            if state.grids.len() != self.cameras.len() {
                return Err(bad(format!("{} camera grids for {} cameras", state.grids.len(), self.cameras.len())));
            }
            let grids: Vec<CameraGrid> = self
                .cameras
                .iter()
                .zip(&state.grids)
                .map(|(c, values)| {
                    let mut g = CameraGrid::empty(c, &self.config.camera);
                    if values.len() != g.values.len() {
                        return Err(bad(format!("a camera grid of {} values, expected {}", values.len(), g.values.len())));
                    }
                    g.values.copy_from_slice(values);
                    Ok(g)
                })
                .collect::<Result<_, _>>()?;
            self.grids = state.grids.clone();
            self.build_sampler(grids);
        }
        if self.config.skip_empty {
            let values = state.occupancy.as_deref().ok_or_else(|| bad("no occupancy".into()))?;
            self.occupancy = Some(Occupancy::from_values(&self.config.scene, values).ok_or_else(|| bad("an occupancy of another size".into()))?);
        }
        Ok(())
    }

    /// Draws `n` rays at training `progress` ∈ [0, 1]: guided and uniform by the schedule with
    /// their λ̃ (guided, after an update), else uniform pixels without λ̃. Deterministic in
    /// (seed, step) whatever the thread count.
    pub fn draw(&self, n: usize, progress: f64, seed: u64, step: u64) -> Vec<RaySample> {
        self.draw_mixed(n, self.config.schedule.fraction(progress), seed, step)
    }

    /// [`Self::draw`] with the uniform share given instead of the schedule's: the first
    /// `round(uniform_fraction · n)` rays are uniform, the rest guided (all uniform without a
    /// guide or before the first update).
    pub fn draw_mixed(&self, n: usize, uniform_fraction: f64, seed: u64, step: u64) -> Vec<RaySample> {
        match (&self.sampler, self.config.guided) {
            (Some(sampler), true) => sampler.sample_batch_mixed(n, uniform_fraction, seed, step),
            _ => draw_batch(n, self.cameras.len(), seed, step, |_, camera, u| {
                let (pixel, pixel_coords, pdf) = uniform_pixel(&self.cameras[camera], [u[0], u[1]]);
                RaySample { camera: camera as u32, pixel, pixel_coords, pdf_pixel: pdf as f32, guided: false, depth: None }
            }),
        }
    }

    /// λ̃ of a drawn ray as a distance along its (unit) `direction`, with its resolution and
    /// whether it is a background ray for the surface losses. `None` for rays without λ̃.
    pub fn surface_distance(&self, ray: &RaySample, origin: DVec3, direction: DVec3) -> Option<SurfaceDistance> {
        let DepthSample { depth, from_grid, .. } = ray.depth?;
        let camera = &self.cameras[ray.camera as usize];
        let per_distance = camera.depth_per_distance(direction).max(1e-9);
        let distance = f64::from(depth) / per_distance;
        let bin = self.distributions().get(ray.camera as usize).map_or(0.0, |d| d.depth_bin() / per_distance);
        Some(SurfaceDistance { distance, bin, background: !from_grid || (origin + distance * direction).length() > 1.0 })
    }

    /// The `n + 1` coarse sample depths of the ray `origin + t·direction` (unit direction) within
    /// [`near_far`]: stratified with one `jitter` ∈ [0, 1) over the ray's occupied intervals when
    /// skipping is on and the ray crosses any (the last depth ends the last interval), else over
    /// the whole [near, far] (the last depth is far). `depths` is cleared first.
    pub fn march(&self, origin: DVec3, direction: DVec3, n: usize, jitter: f64, depths: &mut Vec<f32>) {
        march_through(self.occupancy.as_ref(), origin, direction, n, jitter, depths);
    }
}

/// [`Estimator::march`] through any `occupancy` (e.g. one a renderer built for its own field):
/// returns whether the ray crosses occupied space (always true without an occupancy); a ray
/// that does not gets stratified depths over the whole [near, far].
pub fn march_through(occupancy: Option<&Occupancy>, origin: DVec3, direction: DVec3, n: usize, jitter: f64, depths: &mut Vec<f32>) -> bool {
    march_through_with(occupancy, origin, direction, n, jitter, &mut Vec::new(), depths)
}

/// [`march_through`] with the ray's occupied intervals gathered in `segments` (cleared first):
/// a caller that marches many rays keeps one buffer for them all, no allocation per ray.
pub fn march_through_with(
    occupancy: Option<&Occupancy>,
    origin: DVec3,
    direction: DVec3,
    n: usize,
    jitter: f64,
    segments: &mut Vec<[f32; 2]>,
    depths: &mut Vec<f32>,
) -> bool {
    depths.clear();
    segments.clear();
    let (near, far) = near_far(origin, direction);
    if let Some(occupancy) = occupancy {
        occupancy.segments(origin.as_vec3(), direction.as_vec3(), near as f32, far as f32, segments);
    }
    let total: f64 = segments.iter().map(|s| f64::from(s[1] - s[0])).sum();
    if segments.is_empty() || !(total > 1e-6) {
        let step = (far - near) / n as f64;
        depths.extend((0..n).map(|i| (near + (i as f64 + jitter) * step) as f32));
        depths.push(far as f32);
        return occupancy.is_none();
    }
    // Stratified positions along the concatenated occupied length.
    let mut k = 0;
    let mut start = 0.0f64;
    for i in 0..n {
        let x = (i as f64 + jitter) / n as f64 * total;
        while k + 1 < segments.len() && x > start + f64::from(segments[k][1] - segments[k][0]) {
            start += f64::from(segments[k][1] - segments[k][0]);
            k += 1;
        }
        let t = f64::from(segments[k][0]) + (x - start);
        depths.push((t as f32).min(segments[k][1]));
    }
    let end = segments.last().expect("segments")[1];
    depths.push(end.max(*depths.last().expect("n ≥ 1")));
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use camera_geom::{Intrinsics, PixelCenters};
    use prob_grid::Shape;

    fn cameras() -> Vec<PinholeCamera> {
        let k = Intrinsics { fx: 300.0, fy: 300.0, cx: 99.5, cy: 74.5, skew: 0.0 };
        [DVec3::new(0.0, -3.0, 0.5), DVec3::new(3.0, 0.0, 0.5)]
            .map(|eye| PinholeCamera::look_at(eye, DVec3::ZERO, DVec3::Z, k, 200, 150, PixelCenters::Integer).unwrap())
            .to_vec()
    }

    fn config(guided: bool) -> EstimatorConfig {
        EstimatorConfig {
            guided,
            scene: SceneGridConfig { resolution: 32, ..Default::default() },
            camera: CameraGridConfig { ru: 16, rv: 16, rl: 32, ..Default::default() },
            ..Default::default()
        }
    }

    #[test]
    fn near_far_brackets_the_unit_sphere_and_stays_in_front_of_the_camera() {
        let (n, f) = near_far(DVec3::new(0.0, 0.0, -3.0), DVec3::Z);
        assert!((n - 2.0).abs() < 1e-12 && (f - 4.0).abs() < 1e-12);
        let (n, f) = near_far(DVec3::new(0.0, 0.0, 0.5), DVec3::Z);
        assert!(n >= 0.05 && f > n);
    }

    #[test]
    fn uniform_estimator_draws_pixels_without_depth_and_guided_ones_with() {
        let sphere = Shape::Sphere { center: DVec3::ZERO, radius: 0.5 };
        let mut uniform = Estimator::new(cameras(), EstimatorConfig { skip_empty: false, ..config(false) }).unwrap();
        assert!(!uniform.needs_updates());
        uniform.update(&sphere, 100.0).unwrap();
        let rays = uniform.draw(600, 0.0, 1, 0);
        assert!(rays.iter().all(|r| r.depth.is_none() && !r.guided && r.pixel[0] < 200 && r.pixel[1] < 150));
        assert!(rays.iter().any(|r| r.camera == 1) && rays.iter().any(|r| r.camera == 0));
        let mut guided = Estimator::new(cameras(), config(true)).unwrap();
        let report = guided.update(&sphere, 100.0).unwrap();
        assert!(report.empty_cameras.is_empty() && report.occupied_fraction < 0.5, "{report:?}");
        let rays = guided.draw(600, 0.0, 1, 0);
        assert_eq!(rays.iter().filter(|r| r.guided).count(), 480, "20 % uniform at the start");
        assert!(rays.iter().all(|r| r.depth.is_some()));
    }

    /// Why the extra points' spread includes one λ bin (docs/DECISIONS.md §18): at a large s the
    /// logistic's σ is a small fraction of a bin, but λ̃ is off the true surface by about a bin.
    #[test]
    fn sampled_depth_is_within_a_few_bins_of_the_surface_whatever_s() {
        let sphere = Shape::Sphere { center: DVec3::ZERO, radius: 0.5 };
        let mut e = Estimator::new(cameras(), config(true)).unwrap();
        e.update(&sphere, 1000.0).unwrap();
        let mut errors = Vec::new();
        for d in e.draw(2000, 1.0, 3, 0) {
            let camera = &e.cameras()[d.camera as usize];
            let ray = camera.ray_through_pixel_index(d.pixel[0], d.pixel[1]);
            let surface = e.surface_distance(&d, ray.origin, ray.direction).expect("guided rays have λ̃");
            let bin = e.distributions()[d.camera as usize].depth_bin() / camera.depth_per_distance(ray.direction);
            assert!(surface.bin > 0.0 && (surface.bin - bin).abs() <= 1e-12 * bin);
            // The sphere's first intersection, if the ray meets it.
            let b = ray.origin.dot(ray.direction);
            let disc = b * b - (ray.origin.length_squared() - 0.25);
            if disc > 0.0 && !surface.background {
                errors.push(((surface.distance - (-b - disc.sqrt())).abs(), surface.bin));
            }
        }
        errors.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (median, bin) = errors[errors.len() / 2];
        let sigma = std::f64::consts::PI / (3.0f64.sqrt() * 1000.0);
        assert!(errors.len() > 500 && median > 3.0 * sigma && median < 1.5 * bin, "median {median}, σ {sigma}, bin {bin}, {} rays", errors.len());
    }

    #[test]
    fn march_puts_the_coarse_samples_where_the_surface_can_be() {
        let sphere = Shape::Sphere { center: DVec3::ZERO, radius: 0.5 };
        let mut e = Estimator::new(cameras(), config(false)).unwrap();
        e.update(&sphere, 200.0).unwrap();
        let (o, d) = (DVec3::new(0.0, 0.0, -3.0), DVec3::Z);
        let mut depths = Vec::new();
        e.march(o, d, 32, 0.5, &mut depths);
        assert_eq!(depths.len(), 33);
        assert!(depths.windows(2).all(|w| w[0] <= w[1]));
        // Every sample within the occupied shell around t = 2.5 or 3.5.
        assert!(depths.iter().all(|&t| (t - 2.5).abs() < 0.2 || (t - 3.5).abs() < 0.2), "{depths:?}");
        // A ray that misses everything keeps NeuS's stratified [near, far].
        e.march(DVec3::new(0.95, 0.95, -3.0), d, 8, 0.0, &mut depths);
        let (near, far) = near_far(DVec3::new(0.95, 0.95, -3.0), d);
        assert_eq!(depths.len(), 9);
        assert!((f64::from(depths[0]) - near).abs() < 1e-5 && (f64::from(depths[8]) - far).abs() < 1e-5);
        // Without skipping: stratified over [near, far].
        let plain = Estimator::new(cameras(), EstimatorConfig { skip_empty: false, ..config(false) }).unwrap();
        plain.march(o, d, 4, 0.5, &mut depths);
        assert_eq!(depths, vec![2.25, 2.75, 3.25, 3.75, 4.0]);
    }

    /// `march_through` (a renderer's own occupancy) says which rays cross occupied space: the
    /// miss is reported, not hidden behind the stratified fallback.
    #[test]
    fn march_through_reports_the_rays_that_cross_no_occupied_cell() {
        let sphere = Shape::Sphere { center: DVec3::ZERO, radius: 0.5 };
        let mut e = Estimator::new(cameras(), config(false)).unwrap();
        e.update(&sphere, 200.0).unwrap();
        let occupancy = e.occupancy().expect("skipping keeps an occupancy");
        let mut depths = Vec::new();
        assert!(march_through(Some(occupancy), DVec3::new(0.0, 0.0, -3.0), DVec3::Z, 8, 0.5, &mut depths));
        assert!(!march_through(Some(occupancy), DVec3::new(0.95, 0.95, -3.0), DVec3::Z, 8, 0.5, &mut depths));
        assert_eq!(depths.len(), 9, "a miss still gets its stratified depths");
        assert!(march_through(None, DVec3::new(0.95, 0.95, -3.0), DVec3::Z, 8, 0.5, &mut depths), "no occupancy: every ray may hold the surface");
    }

    /// `draw_mixed` takes the uniform share it is given, whatever the schedule says.
    #[test]
    fn draw_mixed_takes_the_given_uniform_share() {
        let sphere = Shape::Sphere { center: DVec3::ZERO, radius: 0.5 };
        let mut e = Estimator::new(cameras(), config(true)).unwrap();
        e.update(&sphere, 100.0).unwrap();
        for (fraction, guided) in [(0.0, 500), (0.3, 350), (1.0, 0), (f64::NAN, 500)] {
            assert_eq!(e.draw_mixed(500, fraction, 2, 0).iter().filter(|r| r.guided).count(), guided, "uniform share {fraction}");
        }
        assert_eq!(e.draw(500, 0.0, 2, 0), e.draw_mixed(500, 0.2, 2, 0), "the schedule's share at the start is 0.2");
    }
}
