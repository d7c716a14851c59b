//! The trainer as a library: a [`Trainer`] built from a configuration and a scene, advanced one
//! [`Trainer::step`] at a time, saved and restored as a checkpoint, and asked for renders, a
//! mesh and metrics. It owns no files and no terminal: the `train` command ([`crate::run`]) adds
//! the run folder, the progress bar and the stop signal around it.
//!
//! ```no_run
//! use trainer::config::{Budget, TrainConfig};
//! use trainer::data::SceneData;
//! use trainer::trainer::Trainer;
//! # fn main() -> trainer::Result<()> {
//! let mut config = TrainConfig { budget: Budget::Steps(5), ..TrainConfig::default() };
//! config.data.builtin.width = 64;
//! config.render.rays = 64;
//! let data = SceneData::builtin(&config)?;
//! let mut trainer = Trainer::new(config, data)?;
//! while !trainer.done() {
//!     let report = trainer.step()?;
//!     println!("step {} loss {:.4} s {:.1}", report.step, report.loss, report.s);
//! }
//! let mesh = trainer.extract_mesh(&|_, _| {})?;
//! println!("{} triangles", mesh.triangles.len());
//! # Ok(()) }
//! ```
//!
//! Each iteration: coarse-to-fine levels and the curvature ramp from the run's progress; a grid
//! update at the start of each of `guide.updates` parts of the run (the estimator's guide and/or
//! occupancy, from the parameters of that moment); the estimator's rays; their loss and gradient
//! (with the surface losses on guided runs); one Adam step with the schedule's rate. A run is
//! bounded by steps (deterministic: the same bits for any thread count, and a resumed run equals
//! an uninterrupted one) or by a time budget (the schedules follow the fraction of time spent).

use crate::bail;
use crate::config::{Budget, MomentStorage, SamplerKind, TrainConfig};
use crate::data::{SceneData, ViewSplit, uses_masks};
use crate::error::{Context, Result};
use crate::rays::{Batch, PixelSource, Sampling, build_batch};
use crate::sizing::GridChoice;
use sdf_backbone::{Adam, Backbone, CheckpointReader, CheckpointWriter, NoSampleLoss, RayOutput, SampleLoss, StepRates};
use std::time::Instant;
use surface_losses::{RaySurface, SurfaceLossConfig};
use view_sampler::{ErrorMap, Estimator, EstimatorConfig, UniformSchedule, UpdateReport};

mod renders;
mod schedules;
pub mod silhouettes;
mod split;
pub use renders::RENDER_BAND_RAYS;
pub(crate) use renders::RENDER_CHUNK;
pub use silhouettes::{Reach, Silhouette, SphereFit, silhouette_reach, sphere_radius};
pub use split::{SplitStats, WALLED_OPACITY};

/// What a checkpoint holds besides the parameters and Adam's moments.
#[derive(Debug, Clone)]
pub struct TrainState {
    /// Iterations done.
    pub step: u64,
    /// Parameters.
    pub params: Vec<f32>,
    /// Optimiser state.
    pub adam: Adam,
    /// Training time spent (what a time budget counts).
    pub train_seconds: f64,
}

/// What one iteration did.
#[derive(Debug, Clone)]
pub struct StepReport {
    /// Iterations done after this one.
    pub step: u64,
    /// Progress after this iteration, in [0, 1].
    pub progress: f64,
    /// The batch loss.
    pub loss: f32,
    /// PSNR of the batch's rendered colours against their targets (foreground rays with masks).
    pub psnr_batch: f64,
    /// The backbone's s before the step.
    pub s: f64,
    /// The learning rate of the MLPs this step.
    pub lr: f64,
    /// Active hash-grid levels (None for positional encoding).
    pub levels: Option<usize>,
    /// Seconds of the iteration (grid update included).
    pub seconds: f64,
    /// Seconds spent drawing and building rays.
    pub ray_seconds: f64,
    /// The grid update made at the start of this iteration, if any.
    pub update: Option<UpdateReport>,
    /// Guided rays in the batch.
    pub guided_rays: usize,
}

/// Time spent by the iterations of this process (not restored from checkpoints).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Timing {
    /// Iterations run.
    pub steps: u64,
    /// Seconds in iterations without grid updates.
    pub step_seconds: f64,
    /// Seconds drawing and building rays.
    pub ray_seconds: f64,
    /// Seconds in grid updates.
    pub grid_seconds: f64,
    /// Grid updates made.
    pub grid_updates: u64,
}

/// A training run in memory (see the module docs).
pub struct Trainer {
    config: TrainConfig,
    data: SceneData,
    split: ViewSplit,
    use_masks: bool,
    backbone: Backbone,
    estimator: Estimator,
    /// The loss-guided samplers' error map (`None` for guided and uniform runs).
    miner: Option<ErrorMap>,
    /// The hash grid sized by the views (`None`: the preset's).
    grid: Option<GridChoice>,
    /// The meshes' marching-cubes resolution (`output.mesh_resolution` resolved).
    mesh_resolution: u32,
    /// The median pixel footprint at the region of interest over the views (`None`: no view
    /// has it in front of its camera).
    footprint: Option<f64>,
    /// The initial sphere's radius (`model.init_radius` resolved).
    init_radius: f64,
    /// The first step sizes the initial sphere from the photos first ([`silhouettes`]).
    sphere_pending: bool,
    /// How it did.
    sphere_fit: Option<SphereFit>,
    /// Seconds of a time budget the first phase spent: the schedules follow the rest of the
    /// budget, from 0 after the phase (kept in the checkpoint).
    first_phase_seconds: f64,
    state: TrainState,
    grads: Vec<f32>,
    timing: Timing,
    last_step_seconds: f64,
    /// The renders' occupancy and the key of the field it was made of ([`renders`]).
    render_occupancy: std::sync::Mutex<Option<(u64, std::sync::Arc<renders::RenderOccupancy>)>>,
}

/// The surface losses as the backbone's per-ray hook.
struct SurfaceHook<'a> {
    config: SurfaceLossConfig,
    rays: &'a [RaySurface],
}

impl SampleLoss for SurfaceHook<'_> {
    fn ray_loss(&self, ray: usize, s: f64, t: &[f64], sdf: &[f64], w: &[f64], d_sdf: &mut [f64], d_w: &mut [f64]) -> f64 {
        surface_losses::ray_loss(&self.config, &self.rays[ray], s, t, sdf, w, d_sdf, d_w).0
    }
}

/// Where a trainer's parameters come from.
#[derive(Debug, Clone)]
pub(crate) enum Parameters {
    /// The preset's initialisation (a sphere of the initial radius; the fit takes ≈ 1 s).
    Initial,
    /// The preset's initialisation made already, for the same model, seed and radius (a fresh
    /// run's, for its first phase's probe): the networks' and the scale's parameters, then
    /// anything after them, which is dropped (the background is made anew).
    Initialised(Vec<f32>),
    /// A checkpoint read over them at once ([`Trainer::from_checkpoint`]): zeros until then.
    Restored,
}

/// The configured backbone with its initial parameters.
fn configured_backbone(config: &TrainConfig, use_masks: bool, grid: Option<&GridChoice>, radius: f64) -> Result<(Backbone, Vec<f32>)> {
    configured(config, use_masks, grid, radius, Parameters::Initial)
}

/// [`configured_backbone`], the parameters from `parameters`.
fn configured(config: &TrainConfig, use_masks: bool, grid: Option<&GridChoice>, radius: f64, parameters: Parameters) -> Result<(Backbone, Vec<f32>)> {
    let (model, seed) = (&config.model, config.seed);
    let variation = crate::sizing::variation(model, grid);
    let (mut backbone, mut params) = if let Parameters::Initial = parameters {
        sdf_backbone::build_varied(model.preset, &variation, radius, seed)?
    } else {
        let backbone = sdf_backbone::architecture_varied(model.preset, &variation)?;
        let n = backbone.layout().variance + 1;
        let params = match parameters {
            Parameters::Initialised(mut params) if params.len() >= n => {
                params.truncate(n);
                params
            }
            // Not this model's: made anew.
            Parameters::Initialised(_) => return configured(config, use_masks, grid, radius, Parameters::Initial),
            _ => vec![0.0; n],
        };
        (backbone, params)
    };
    if config.model.background_model.learned(use_masks) {
        backbone.add_learned_background(&mut params, background_model(config), config.seed + 4);
    }
    if let Some(s) = config.model.init_s {
        params[backbone.layout().variance] = sdf_backbone::variance_from_scale(s) as f32;
    }
    backbone.config.eikonal_weight = config.model.eikonal;
    backbone.config.mask_weight = if use_masks { config.model.mask } else { 0.0 };
    backbone.config.opacity_entropy = if use_masks { 0.0 } else { config.model.opacity_entropy };
    backbone.config.opacity_sparsity = if use_masks { 0.0 } else { config.model.opacity_sparsity };
    backbone.config.opacity_guard = opacity_guard(config, use_masks);
    backbone.config.masked_color = use_masks;
    backbone.config.background = config.model.background;
    backbone.set_normal_scheme(config.model.normal_scheme());
    backbone.set_products(config.model.products.into());
    Ok((backbone, params))
}

/// The guard on the foreground of a run of `config` (`model.opacity_guard`): only without masks.
fn opacity_guard(config: &TrainConfig, use_masks: bool) -> Option<sdf_backbone::OpacityGuard> {
    let m = &config.model;
    let weight = m.opacity_guard.filter(|_| !use_masks)?;
    Some(sdf_backbone::OpacityGuard { weight, tolerance: m.opacity_guard_tolerance })
}

/// Adam's state at the start of a run of `config` with `n` parameters.
fn fresh_adam(config: &TrainConfig, backbone: &Backbone, n: usize) -> Adam {
    let mut adam = match config.optim.table_moments {
        MomentStorage::F32 => Adam::new(n),
        MomentStorage::Bf16 => Adam::with_compact_prefix(n, backbone.layout().encoding.len()),
    };
    adam.epsilon = 1e-15;
    adam
}

/// The learned background of a run without masks ([`sdf_backbone::BackgroundModel::cpu`]).
pub fn background_model(config: &TrainConfig) -> sdf_backbone::BackgroundModel {
    let mut model = sdf_backbone::BackgroundModel::cpu(config.model.background_frequencies, config.model.background_view);
    model.near = config.model.background_near;
    if config.model.background_grid.used(config.sampler) {
        model = model.with_grid(sdf_backbone::BackgroundModel::cpu_grid());
    }
    model
}

/// The estimator's configuration from the trainer's.
pub fn estimator_config(config: &TrainConfig) -> EstimatorConfig {
    EstimatorConfig {
        guided: config.sampler == SamplerKind::Guided,
        scene: config.guide.scene.clone(),
        camera: config.guide.camera.clone(),
        interpolation: config.guide.interpolation,
        schedule: UniformSchedule { fractions: config.guide.uniform_fractions.clone() },
        fixed_s: config.guide.fixed_s.map(|s| s as f32),
        skip_empty: config.render.skip_empty,
        dilation: config.render.occupancy_dilation,
        updates: config.guide.updates,
    }
}

impl Trainer {
    /// A fresh run: the configured backbone at its initial parameters, no grids yet.
    pub fn new(config: TrainConfig, data: SceneData) -> Result<Trainer> {
        Trainer::with_parameters(config, data, Parameters::Initial)
    }

    /// The run of `config` on `data` at the checkpoint `reader` reads from `input` (see
    /// [`Trainer::restore`]): [`Trainer::new`] then [`Trainer::restore`], the same state to the
    /// bit, without initialising the parameters that the checkpoint overwrites (the preset's
    /// sphere fit: ≈ 1 s of every `eval --run` and resumed run).
    pub fn from_checkpoint(
        config: TrainConfig,
        data: SceneData,
        reader: &CheckpointReader,
        input: &mut (impl std::io::Read + std::io::Seek),
    ) -> Result<Trainer> {
        let mut trainer = Trainer::with_parameters(config, data, Parameters::Restored)?;
        trainer.restore(reader, input)?;
        Ok(trainer)
    }

    /// [`Trainer::new`] with its parameters from `parameters`.
    pub(crate) fn with_parameters(config: TrainConfig, data: SceneData, parameters: Parameters) -> Result<Trainer> {
        config.validate()?;
        // Every render the run will make must have pixels: fail now, not after the budget.
        let smallest = data.scene.views.iter().map(|v| v.camera.width.min(v.camera.height)).min().unwrap_or(0);
        for (key, downscale) in
            [("output.validate_downscale", config.output.validate_downscale), ("output.eval_downscale", config.output.eval_downscale)]
        {
            if smallest < downscale {
                bail!(Config, "{key} = {downscale} leaves no pixel of the smallest view ({smallest} pixels on its short side): lower it");
            }
        }
        let split = ViewSplit::new(&config, &data.scene);
        let use_masks = uses_masks(&config, &data.scene);
        let footprint = crate::sizing::median_footprint(data.scene.views.iter().map(|v| &v.camera));
        let grid = crate::sizing::grid_choice(&config.model, footprint)?;
        let mesh_resolution = crate::sizing::mesh_resolution(config.output.mesh_resolution, &config.model, footprint)?;
        let init_radius = config.model.init_radius.resolve(data.scene.views.iter().map(|v| &v.camera), use_masks);
        let (backbone, params) = configured(&config, use_masks, grid.as_ref(), init_radius, parameters)?;
        let cameras: Vec<_> = split.train.iter().map(|&i| data.scene.views[i].camera).collect();
        let miner = crate::mining::error_map(&config, &cameras);
        let estimator = Estimator::new(cameras, estimator_config(&config)).context("the guide's configuration")?;
        let adam = fresh_adam(&config, &backbone, params.len());
        let state = TrainState { step: 0, params, adam, train_seconds: 0.0 };
        let config_asks_photos = config.model.init_radius == crate::config::InitRadius::Photos && !use_masks;
        Ok(Trainer {
            config,
            data,
            split,
            use_masks,
            backbone,
            estimator,
            miner,
            grid,
            mesh_resolution,
            footprint,
            init_radius,
            sphere_pending: config_asks_photos,
            sphere_fit: None,
            first_phase_seconds: 0.0,
            state,
            grads: Vec::new(),
            timing: Timing::default(),
            last_step_seconds: 0.0,
            render_occupancy: std::sync::Mutex::new(None),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &TrainConfig {
        &self.config
    }

    /// The hash grid sized by the views (`model.grid = "footprint"`; `None`: the preset's).
    pub fn grid_choice(&self) -> Option<&GridChoice> {
        self.grid.as_ref()
    }

    /// The median pixel footprint at the region of interest over the views, in the normalised
    /// frame (`None`: no view has the region's centre in front of its camera).
    pub fn pixel_footprint(&self) -> Option<f64> {
        self.footprint
    }

    /// The initial sphere's radius (`model.init_radius`, `auto` resolved).
    pub fn init_radius(&self) -> f64 {
        self.init_radius
    }

    /// The meshes' marching-cubes resolution: cells per side of the bound's cube
    /// (`output.mesh_resolution`, `"model"` resolved).
    pub fn mesh_resolution(&self) -> u32 {
        self.mesh_resolution
    }

    /// The data.
    pub fn data(&self) -> &SceneData {
        &self.data
    }

    /// Training and held-out views.
    pub fn split(&self) -> &ViewSplit {
        &self.split
    }

    /// The training views' cameras (normalised frame).
    pub fn train_cameras(&self) -> Vec<camera_geom::PinholeCamera> {
        self.split.train_cameras(&self.data.scene)
    }

    /// Whether the masks are used.
    pub fn uses_masks(&self) -> bool {
        self.use_masks
    }

    /// The backbone.
    pub fn backbone(&self) -> &Backbone {
        &self.backbone
    }

    /// The state (parameters, optimiser, step, …).
    pub fn state(&self) -> &TrainState {
        &self.state
    }

    /// The estimator (guide and occupancy of the last update).
    pub fn estimator(&self) -> &Estimator {
        &self.estimator
    }

    /// Time spent by this process's iterations.
    pub fn timing(&self) -> Timing {
        self.timing
    }

    /// The backbone's current logistic scale s.
    pub fn s(&self) -> f64 {
        self.backbone.scale(&self.state.params)
    }

    /// Fraction of the run done, in [0, 1]: steps done / steps, or training time / budget.
    pub fn progress(&self) -> f64 {
        self.progress_at(self.state.step, self.state.train_seconds)
    }

    fn progress_at(&self, step: u64, seconds: f64) -> f64 {
        match self.config.budget {
            Budget::Time(budget) => {
                // A first phase's seconds count towards the budget but not the schedules.
                let start = self.first_phase_seconds;
                ((seconds - start) / (budget.as_secs_f64() - start).max(f64::MIN_POSITIVE)).clamp(0.0, 1.0)
            }
            Budget::Steps(steps) => (step as f64 / steps as f64).min(1.0),
        }
    }

    /// Whether the run is over (its steps done or its time budget spent).
    pub fn done(&self) -> bool {
        match self.config.budget {
            Budget::Time(budget) => self.state.train_seconds >= budget.as_secs_f64(),
            Budget::Steps(steps) => self.state.step >= steps,
        }
    }

    /// Seconds of the budget left (time budgets), or an estimate from the mean iteration time.
    pub fn seconds_left(&self) -> f64 {
        match self.config.budget {
            Budget::Time(budget) => (budget.as_secs_f64() - self.state.train_seconds).max(0.0),
            Budget::Steps(steps) => {
                let per_step =
                    if self.timing.steps > 0 { (self.timing.step_seconds + self.timing.grid_seconds) / self.timing.steps as f64 } else { 0.0 };
                steps.saturating_sub(self.state.step) as f64 * per_step
            }
        }
    }

    /// The estimator's update from the current parameters when its schedule says so.
    fn update_grids_due(&mut self, progress: f64) -> Result<Option<UpdateReport>> {
        let s = self.backbone.scale(&self.state.params) as f32;
        let field = self.backbone.field(&self.state.params);
        self.estimator.update_due(progress, &field, s).context("the grid update")
    }

    /// The estimator's update from the current parameters now (its grids then belong to the
    /// part of the run at the current progress).
    fn update_grids_now(&mut self) -> Result<UpdateReport> {
        let (progress, s) = (self.progress(), self.backbone.scale(&self.state.params) as f32);
        let field = self.backbone.field(&self.state.params);
        self.estimator.update_at(progress, &field, s).context("the grid update")
    }

    /// One iteration (see the module docs).
    pub fn step(&mut self) -> Result<StepReport> {
        if self.sphere_pending {
            self.fit_sphere_to_photos()?;
        }
        let start = Instant::now();
        let step = self.state.step;
        let progress = self.progress();
        self.set_progress_schedules(progress);
        (self.backbone.config.curvature_weight, self.backbone.config.normal_smoothness) = self.smoothing_weights(progress);

        // Grid update at the start of each part of the run (the estimator's schedule).
        let update = self.update_grids_due(progress)?;
        if let Some(report) = &update {
            self.timing.grid_seconds += report.seconds;
            self.timing.grid_updates += 1;
        }
        let t_step = Instant::now();
        let s = self.s();
        let batch = self.batch(step, progress, s);
        let ray_seconds = t_step.elapsed().as_secs_f64();
        // The schedule's factor for a step that ends at the next progress point.
        let progress_end = if self.config.timed() {
            self.progress_at(step + 1, self.state.train_seconds + self.last_step_seconds)
        } else {
            self.progress_at(step + 1, 0.0)
        };
        let factor = self.config.optim.schedule.factor(progress_end);
        let rates = StepRates {
            tables: self.config.optim.lr_grid as f32 * factor,
            rest: self.config.optim.lr as f32 * factor,
            clip_norm: self.config.optim.clip_norm.map(|c| c as f32),
            geometry: self.geometry_rate(progress),
        };
        let hook = SurfaceHook { config: self.config.surface, rays: &batch.surfaces };
        let extra: &dyn SampleLoss = if self.surface_losses_on() { &hook } else { &NoSampleLoss };
        let (loss, outputs) =
            self.backbone.train_step(&mut self.state.params, &mut self.state.adam, &batch.rays, self.config.render.chunk, extra, rates);
        if !loss.is_finite() {
            return Err(crate::Error::Diverged { loss: f64::from(loss), step });
        }
        if let Some([from, to]) = self.config.model.s_floor {
            // s = exp(10 v) ≥ from · (to / from)^progress.
            let floor = from * (to / from).powf(progress_end);
            let v = &mut self.state.params[self.backbone.layout().variance];
            *v = v.max(sdf_backbone::variance_from_scale(floor) as f32);
        }
        if let Some(map) = &mut self.miner {
            crate::mining::record(map, &batch.drawn, &batch.rays, &outputs);
        }
        self.state.step += 1;
        let step_seconds = t_step.elapsed().as_secs_f64();
        let seconds = start.elapsed().as_secs_f64();
        self.state.train_seconds += seconds;
        self.last_step_seconds = seconds;
        self.timing.steps += 1;
        self.timing.step_seconds += step_seconds;
        self.timing.ray_seconds += ray_seconds;
        // Over the foreground rays when masks are used (the backdrop is not learnt then).
        let (sum, count) = batch
            .rays
            .iter()
            .zip(&outputs)
            .filter(|(r, _)| r.mask.is_none_or(|m| m >= 0.5))
            .map(|(r, o)| (0..3).map(|k| f64::from(o.color[k] - r.target[k]).powi(2)).sum::<f64>() / 3.0)
            .fold((0.0, 0usize), |(s, n), e| (s + e, n + 1));
        let mse = sum / count.max(1) as f64;
        Ok(StepReport {
            step: self.state.step,
            progress: self.progress(),
            loss,
            psnr_batch: -10.0 * mse.log10(),
            s,
            lr: self.config.optim.lr * f64::from(factor),
            levels: self.backbone.levels().map(|l| self.active_levels(l, progress)),
            seconds,
            ray_seconds,
            update,
            guided_rays: batch.drawn.iter().filter(|d| d.guided).count(),
        })
    }

    /// The loss of `batch` and its gradient (into the trainer's gradient buffer), with the
    /// surface losses on guided runs; the parameters are not changed.
    pub fn gradient(&mut self, batch: &Batch) -> (f32, Vec<RayOutput<f32>>) {
        self.grads.clear();
        self.grads.resize(self.state.params.len(), 0.0);
        let hook = SurfaceHook { config: self.config.surface, rays: &batch.surfaces };
        let extra: &dyn SampleLoss = if self.surface_losses_on() { &hook } else { &NoSampleLoss };
        self.backbone.loss_and_gradient(&self.state.params, &batch.rays, &mut self.grads, self.config.render.chunk, extra)
    }

    /// Whether the surface losses apply: guided runs with a positive weight.
    fn surface_losses_on(&self) -> bool {
        self.config.sampler == SamplerKind::Guided && self.config.surface.weight > 0.0
    }

    /// The gradient of the last [`Self::gradient`] (steps do not keep one: the hash tables'
    /// gradient is applied level by level).
    pub fn gradients(&self) -> &[f32] {
        &self.grads
    }

    /// Replaces the parameters (e.g. another run's, to compare samplers on one model) and
    /// rebuilds the grids from them.
    pub fn set_parameters(&mut self, params: &[f32]) -> Result<()> {
        if params.len() != self.state.params.len() {
            bail!(Input, "{} parameters given, the model has {}", params.len(), self.state.params.len());
        }
        self.state.params.copy_from_slice(params);
        if self.estimator.needs_updates() {
            self.update_grids_now()?;
        }
        Ok(())
    }

    /// Rebuilds the grids from another field at scale `s` (a known SDF, e.g. to check the guide
    /// or to start from a prior); the next scheduled update returns to the backbone's SDF.
    pub fn guide_from(&mut self, field: &dyn prob_grid::SdfField, s: f32) -> Result<UpdateReport> {
        self.estimator.update(field, s).context("the grid update")
    }

    /// Rebuilds the grids from the current parameters now; returns the update's report.
    pub fn update_grids(&mut self) -> Result<UpdateReport> {
        self.update_grids_now()
    }

    /// The rays of iteration `step` at `progress` and scale `s` (what [`Self::step`] trains on).
    pub fn batch(&self, step: u64, progress: f64, s: f64) -> Batch {
        let views: Vec<&datasets::View> = self.split.train.iter().map(|&i| &self.data.scene.views[i]).collect();
        let n = self.config.render.rays;
        build_batch(
            &self.estimator,
            &views,
            self.use_masks,
            &self.backbone,
            &self.state.params,
            &self.sampling(),
            match &self.miner {
                Some(map) => PixelSource::Mined { map, alpha: crate::mining::alpha_at(&self.config, progress) },
                None => PixelSource::Estimator,
            },
            (n, progress),
            self.config.seed,
            step,
            s,
        )
    }

    fn sampling(&self) -> Sampling {
        let r = &self.config.render;
        let guided = self.config.sampler == SamplerKind::Guided;
        Sampling {
            coarse: r.coarse,
            fine: r.fine,
            rounds: r.upsample_rounds,
            upsample_s: r.upsample_s,
            extra_points: if guided { self.config.guide.extra_points } else { 0 },
            extra: self.config.guide.extra,
            extra_bin_spread: self.config.guide.extra_bin_spread,
        }
    }

    /// Writes the state as a checkpoint (streamed: no copy of the parameters): parameters,
    /// Adam's moments, the estimator's grids of the last update, and metadata (step, the part of
    /// the grids, the Lipschitz claim, training time, the configuration).
    pub fn write_checkpoint(&self, out: &mut dyn std::io::Write) -> std::io::Result<()> {
        let guide = self.estimator.state();
        let mut w = CheckpointWriter::with_state(&self.state.params, &self.state.adam);
        let names: Vec<String> = (0..guide.grids.len()).map(|i| format!("guide.grid.{i}")).collect();
        for (name, grid) in names.iter().zip(&guide.grids) {
            w.tensor(name, grid);
        }
        if let Some(occupancy) = &guide.occupancy {
            w.tensor("guide.occupancy", occupancy);
        }
        let errors = self.miner.as_ref().map(ErrorMap::state);
        if let Some(errors) = &errors {
            w.tensor("sampler.error_map", errors);
        }
        w.meta("step", self.state.step.to_string())
            .meta("update_part", guide.part.map_or("none".into(), |p| p.to_string()))
            .meta("lipschitz", guide.lipschitz.to_string())
            .meta("train_seconds", self.state.train_seconds.to_string())
            .meta("first_phase_seconds", self.first_phase_seconds.to_string())
            .meta("config", self.config.to_toml());
        w.write_to(out)
    }

    /// Continues from a checkpoint (`reader` over `input`): it must come from a run of this very
    /// configuration (the error names the keys that differ); the grids come back as they were.
    pub fn restore(&mut self, reader: &CheckpointReader, input: &mut (impl std::io::Read + std::io::Seek)) -> Result<()> {
        let meta = |key: &str| reader.meta(key).with_context(|| format!("the checkpoint has no {key:?} entry"));
        let saved = TrainConfig::from_toml(meta("config")?).context("the checkpoint's configuration")?;
        let changed = saved.differences(&self.config);
        if !changed.is_empty() {
            bail!(Input, "the configuration differs from the checkpoint's in: {} (a run resumes with its own configuration)", changed.join(", "));
        }
        // Parse everything small before touching the state, then read the tensors in place.
        let step = meta("step")?.parse().context("the checkpoint's step")?;
        let update_part = match meta("update_part")? {
            "none" => None,
            p => Some(p.parse().context("the checkpoint's update_part")?),
        };
        let lipschitz = meta("lipschitz")?.parse().context("the checkpoint's lipschitz")?;
        let train_seconds = meta("train_seconds")?.parse().context("the checkpoint's train_seconds")?;
        // Absent from checkpoints written before the first phase existed: none.
        let first_phase_seconds = match reader.meta("first_phase_seconds") {
            Ok(text) => text.parse().context("the checkpoint's first_phase_seconds")?,
            Err(_) => 0.0,
        };
        let (mut grids, mut occupancy) = (Vec::new(), None);
        if update_part.is_some() {
            while let Some(n) = reader.len(&format!("guide.grid.{}", grids.len())) {
                let mut g = vec![0.0f32; n];
                reader.read_into(input, &format!("guide.grid.{}", grids.len()), &mut g)?;
                grids.push(g);
            }
            occupancy = reader.len("guide.occupancy").map(|_| reader.read_vec(input, "guide.occupancy")).transpose()?;
        }
        let guide = view_sampler::EstimatorState { grids, occupancy, part: update_part, lipschitz };
        let errors = match &self.miner {
            Some(_) => Some(reader.read_vec(input, "sampler.error_map").context("the checkpoint's error map")?),
            None => None,
        };
        reader
            .restore_state(input, &mut self.state.params, &mut self.state.adam)
            .map_err(|e| crate::sizing::explain_size_mismatch(&self.config.model, e))?;
        self.state.step = step;
        self.state.train_seconds = train_seconds;
        self.first_phase_seconds = first_phase_seconds;
        // The first phase's sphere is in the parameters restored.
        self.sphere_pending = false;
        // The levels and the background of the last iteration done.
        let last = self.progress_at(self.state.step.saturating_sub(1), self.state.train_seconds);
        self.set_progress_schedules(last);
        self.estimator.restore(&guide).context("the checkpoint's grids")?;
        if let (Some(map), Some(errors)) = (&mut self.miner, errors) {
            map.restore(&errors).context("the checkpoint's error map")?;
        }
        Ok(())
    }
}
