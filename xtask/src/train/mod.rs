//! `cargo xtask train`: backbone + probability-guided sampler + surface losses, with progress,
//! pictures, checkpoints, a mesh and metrics. See `config` for every knob.

pub mod config;
pub mod outputs;
pub mod rays;

use anyhow::{Context, Result, bail};
use config::{SamplerKind, TrainConfig};
use datasets::golden::{self, GoldenSpec};
use datasets::io::write_atomic;
use datasets::{LoadOptions, Scene, load_scene};
use prob_grid::{CameraGridConfig, SceneGridConfig, ViewDependency};
use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
use rays::{DrawnRay, build_batch, stream_seed};
use sdf_backbone::{Adam, Backbone, Checkpoint, NoSampleLoss, NormalScheme, Preset, SampleLoss, WarmupCosine, WarmupStep, adam_step, build};
use serde_json::json;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;
use surface_losses::{RaySurface, SurfaceLossConfig};
use view_sampler::{Interpolation, SamplerConfig, UniformSchedule, ViewSampler};

/// Options of `cargo xtask train`.
#[derive(clap::Args, Debug, Clone)]
pub struct TrainArgs {
    /// Dataset folder (IDR/NeuS/DTU, NeRF-synthetic, instant-ngp). Default: the built-in scene.
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// TOML configuration (unknown keys are errors).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// guided (the paper) or uniform (the plain backbone, same rays and samples).
    #[arg(long)]
    pub sampler: Option<String>,
    /// Run folder (config, log, pictures, checkpoints, mesh, metrics).
    #[arg(long, default_value = "out/train")]
    pub out: PathBuf,
    /// Continue the run in this folder from its checkpoint (same result as an uninterrupted run
    /// at the same thread count).
    #[arg(long, conflicts_with_all = ["data", "config", "sampler", "seed"])]
    pub resume: Option<PathBuf>,
    /// Seed of every random stream.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Stop after this many iterations as if interrupted (checkpoint written), for testing resume.
    #[arg(long, hide = true)]
    pub stop_at: Option<u64>,
    /// Print one JSON summary line at the end.
    #[arg(long)]
    pub json: bool,
    /// Configuration overrides `key=value` (e.g. `steps=500 guide.partition=1`).
    pub overrides: Vec<String>,
}

/// What a run reports at the end.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RunSummary {
    /// Run folder.
    pub out: String,
    /// Mesh files written.
    pub meshes: Vec<String>,
    /// Metrics (also in metrics.json).
    pub metrics: serde_json::Value,
    /// Periodic metrics (`output.metrics_every`), also in log.jsonl.
    pub history: Vec<serde_json::Value>,
}

/// The data of a run and its ground truth.
struct RunData {
    scene: Scene,
    builtin_truth: Option<Vec<glam::DVec3>>,
    path: Option<PathBuf>,
}

fn load_data(config: &TrainConfig, data: Option<&Path>) -> Result<RunData> {
    match data {
        None => {
            let mut spec = GoldenSpec::builtin();
            spec.rig.width = config.data.builtin_width;
            spec.rig.height = config.data.builtin_width * 3 / 4;
            spec.rig.count = config.data.builtin_views;
            spec.backdrop = false; // black background: the fixed background colour
            let g = golden::generate(&spec).context("rendering the built-in scene")?;
            Ok(RunData { scene: g.scene, builtin_truth: Some(g.surface_points), path: None })
        }
        Some(dir) => {
            let options =
                LoadOptions { downscale: config.data.downscale, background: config.model.background.map(|c| c as f32), ..Default::default() };
            let scene = load_scene(dir, &options).with_context(|| format!("cannot load the data folder {}", dir.display()))?;
            if scene.views.is_empty() {
                bail!("the data folder {} has no views", dir.display());
            }
            Ok(RunData { scene, builtin_truth: None, path: Some(dir.to_path_buf()) })
        }
    }
}

/// Training and held-out views: every `holdout_every`-th view is held out (a single view is
/// always trained on).
fn split_views(config: &TrainConfig, scene: &Scene) -> (Vec<usize>, Vec<usize>) {
    let every = config.data.holdout_every;
    let n = scene.views.len();
    let held = |i: usize| every > 0 && i % every == every - 1 && n > 1;
    ((0..n).filter(|&i| !held(i)).collect(), (0..n).filter(|&i| held(i)).collect())
}

/// Whether the mask loss applies: masks asked for and present on every view.
fn uses_masks(config: &TrainConfig, scene: &Scene) -> bool {
    config.data.masks && scene.views.iter().all(|v| v.mask.is_some())
}

/// The configured backbone with its initial parameters (preset, learned background, loss
/// weights, background colour, normal scheme).
fn backbone_for(config: &TrainConfig, use_masks: bool) -> Result<(Backbone, Vec<f32>)> {
    let (mut backbone, mut params) = build(Preset::from_name(&config.model.preset)?, config.model.init_radius, config.seed);
    if config.model.learned_background {
        backbone.add_learned_background(&mut params, config.seed + 4);
    }
    backbone.config.eikonal_weight = config.model.eikonal;
    backbone.config.mask_weight = if use_masks { config.model.mask } else { 0.0 };
    backbone.config.background = config.model.background;
    backbone.config.normals = if config.model.normals == "central" { NormalScheme::Central } else { NormalScheme::Tetrahedral };
    Ok((backbone, params))
}

/// A run folder's configuration (with `overrides`), data path and checkpoint.
fn read_run_folder(dir: &Path, overrides: &[String]) -> Result<(TrainConfig, Option<PathBuf>, Checkpoint)> {
    let config = TrainConfig::load(Some(&dir.join("config.toml")), overrides)?;
    let data: serde_json::Value = serde_json::from_slice(
        &std::fs::read(dir.join("data.json")).with_context(|| format!("{} is not a run folder (no data.json)", dir.display()))?,
    )?;
    let data_path = data["path"].as_str().map(PathBuf::from);
    let ckpt = Checkpoint::from_bytes(&std::fs::read(checkpoint_path(dir)).with_context(|| format!("no checkpoint in {}", dir.display()))?)?;
    Ok((config, data_path, ckpt))
}

/// The surface losses as the backbone's per-ray hook.
struct SurfaceHook<'a> {
    config: SurfaceLossConfig,
    rays: &'a [RaySurface],
    s: f64,
}

impl SampleLoss for SurfaceHook<'_> {
    fn ray_loss(&self, ray: usize, t: &[f64], sdf: &[f64], w: &[f64], d_sdf: &mut [f64], d_w: &mut [f64]) -> f64 {
        surface_losses::ray_loss(&self.config, &self.rays[ray], self.s, t, sdf, w, d_sdf, d_w).0
    }
}

/// Everything one iteration needs besides the parameters.
pub struct StepInputs<'a> {
    /// The configuration.
    pub config: &'a TrainConfig,
    /// The backbone.
    pub backbone: &'a Backbone,
    /// The scene.
    pub scene: &'a Scene,
    /// Indices of the training views.
    pub train_views: &'a [usize],
    /// Their cameras.
    pub train_cameras: &'a [camera_geom::PinholeCamera],
    /// Whether the mask loss is used.
    pub use_masks: bool,
}

impl StepInputs<'_> {
    /// Draws the rays of iteration `step` (guided from `sampler`, else uniform), builds their
    /// depths and adds the batch loss's gradient into `grads`. Returns the loss, the per-ray
    /// outputs, the batch, and the seconds spent drawing and building rays.
    pub fn gradient(
        &self,
        params: &[f32],
        step: u64,
        sampler: Option<&ViewSampler>,
        grads: &mut [f32],
    ) -> (f32, Vec<sdf_backbone::RayOutput<f32>>, rays::Batch, f64) {
        let t = Instant::now();
        let config = self.config;
        let s_now = self.backbone.scale(params);
        let progress = step as f64 / config.steps as f64;
        let drawn: Vec<DrawnRay> = match sampler {
            Some(sampler) => sampler
                .sample_batch(config.render.rays, progress, config.seed, step)
                .iter()
                .map(|r| DrawnRay { view: r.camera as usize, col: r.pixel[0], row: r.pixel[1], depth: Some((r.depth, r.depth_from_grid)) })
                .collect(),
            None => {
                let mut rng = Xoshiro256PlusPlus::seed_from_u64(stream_seed(config.seed ^ 0x756e_6966, step, 0));
                (0..config.render.rays)
                    .map(|_| {
                        let view = rng.random_range(0..self.train_views.len());
                        let cam = &self.train_cameras[view];
                        DrawnRay { view, col: rng.random_range(0..cam.width), row: rng.random_range(0..cam.height), depth: None }
                    })
                    .collect()
            }
        };
        let cams: Vec<&camera_geom::PinholeCamera> = self.train_cameras.iter().collect();
        let target = |v: usize, c: u32, r: u32| {
            let view = &self.scene.views[self.train_views[v]];
            let m = if self.use_masks { view.mask.as_ref().map(|m| if m.get(c, r) { 1.0 } else { 0.0 }) } else { None };
            (view.image.get_f32(c, r), m)
        };
        let batch = build_batch(config, self.backbone, params, &cams, target, &drawn, step, s_now);
        let rays_time = t.elapsed().as_secs_f64();
        let surface_config = config.surface_losses();
        let hook = SurfaceHook { config: surface_config, rays: &batch.surfaces, s: s_now };
        let extra: &dyn SampleLoss = if sampler.is_some() && surface_config.weight > 0.0 { &hook } else { &NoSampleLoss };
        let (loss, outputs) = self.backbone.loss_parallel(params, &batch.rays, grads, config.render.chunk, extra);
        (loss, outputs, batch, rays_time)
    }
}

/// The mutable state a checkpoint holds.
struct State {
    step: u64,
    params: Vec<f32>,
    adam: Adam,
    /// Parameters at the last grid update (guided), so a resumed run rebuilds the same grids.
    grid_params: Vec<f32>,
}

fn checkpoint_path(out: &Path) -> PathBuf {
    out.join("checkpoint.safetensors")
}

fn save_checkpoint(out: &Path, state: &State, config: &TrainConfig) -> Result<()> {
    let mut c = Checkpoint::from_state(&state.params, &state.adam);
    c.tensors.insert("grid_params".into(), state.grid_params.clone());
    c.metadata.insert("step".into(), state.step.to_string());
    c.metadata.insert("config".into(), config.to_toml());
    write_atomic(&checkpoint_path(out), &c.to_bytes()?).context("writing the checkpoint")?;
    Ok(())
}

/// Grids and sampler from the parameters of the last update.
pub(crate) fn guide(
    config: &TrainConfig,
    backbone: &Backbone,
    grid_params: &[f32],
    cameras: &[camera_geom::PinholeCamera],
) -> Result<(ViewSampler, f64)> {
    let s = if config.guide.fixed_s > 0.0 { config.guide.fixed_s } else { backbone.scale(grid_params) };
    let scene_cfg = SceneGridConfig { resolution: config.guide.scene_resolution, partition: config.guide.partition, ..Default::default() };
    let cam_cfg = CameraGridConfig {
        ru: config.guide.camera_uv,
        rv: config.guide.camera_uv,
        rl: config.guide.camera_depth,
        view_dependency: match config.guide.view_dependency.as_str() {
            "off" => ViewDependency::Off,
            "paper" => ViewDependency::PaperSum,
            "quadrature" => ViewDependency::Quadrature,
            _ => ViewDependency::Opaque,
        },
        ..Default::default()
    };
    let t = Instant::now();
    let grids = prob_grid::update(&backbone.field(grid_params), s as f32, cameras, &scene_cfg, &cam_cfg)?;
    let sampler = ViewSampler::new(
        grids.cameras,
        SamplerConfig { interpolation: Interpolation::Linear, schedule: UniformSchedule { fractions: config.guide.uniform_fractions.clone() } },
    );
    Ok((sampler, t.elapsed().as_secs_f64()))
}

/// Active hash-grid levels at `step` (coarse-to-fine).
fn active_levels(config: &TrainConfig, levels: usize, step: u64) -> usize {
    let progress = step as f64 / config.steps as f64;
    let ramp = if config.model.all_levels_at > 0.0 { (progress / config.model.all_levels_at).min(1.0) } else { 1.0 };
    let start = config.model.initial_levels.min(levels);
    start + ((levels - start) as f64 * ramp).floor() as usize
}

/// Runs `cargo xtask train`.
pub fn run(args: &TrainArgs) -> Result<RunSummary> {
    let out = args.resume.clone().unwrap_or_else(|| args.out.clone());
    // Configuration: fresh, or the run folder's own when resuming.
    let (config, data_path, resumed) = if let Some(dir) = &args.resume {
        let (config, data_path, ckpt) = read_run_folder(dir, &args.overrides)?;
        (config, data_path, Some(ckpt))
    } else {
        let mut overrides = args.overrides.clone();
        if let Some(s) = &args.sampler {
            overrides.push(format!("sampler={s}"));
        }
        if let Some(seed) = args.seed {
            overrides.push(format!("seed={seed}"));
        }
        (TrainConfig::load(args.config.as_deref(), &overrides)?, args.data.clone(), None)
    };
    std::fs::create_dir_all(out.join("pictures")).with_context(|| format!("cannot create the run folder {}", out.display()))?;
    // Fail early on an unwritable folder, before any work.
    write_atomic(&out.join(".write_test"), b"ok").with_context(|| format!("the run folder {} is not writable", out.display()))?;
    let _ = std::fs::remove_file(out.join(".write_test"));

    let data = load_data(&config, data_path.as_deref())?;
    if resumed.is_none() {
        write_atomic(&out.join("config.toml"), config.to_toml().as_bytes())?;
        let data_json = json!({"path": data.path.as_ref().map(|p| p.display().to_string()), "description": data.scene.source.description});
        write_atomic(&out.join("data.json"), serde_json::to_string_pretty(&data_json)?.as_bytes())?;
    }
    let scene = &data.scene;
    let (train_views, test_views) = split_views(&config, scene);
    let train_cameras: Vec<camera_geom::PinholeCamera> = train_views.iter().map(|&i| scene.views[i].camera).collect();
    let use_masks = uses_masks(&config, scene);
    let (mut backbone, init_params) = backbone_for(&config, use_masks)?;
    let layout = backbone.layout();
    let n = init_params.len();
    let mut adam = Adam::new(n);
    adam.epsilon = 1e-15;
    let mut state = State { step: 0, grid_params: init_params.clone(), params: init_params, adam };
    if let Some(ckpt) = &resumed {
        ckpt.restore(&mut state.params, &mut state.adam)?;
        state.grid_params.copy_from_slice(ckpt.tensor("grid_params", n)?);
        state.step = ckpt.metadata.get("step").and_then(|s| s.parse().ok()).context("checkpoint without a step")?;
    }
    let cosine = WarmupCosine { base: 1.0, warmup: config.optim.warmup, total: config.steps, final_factor: config.optim.final_factor as f32 };
    let stepped = WarmupStep {
        base: 1.0,
        warmup: config.optim.warmup,
        milestones: config.optim.milestones.iter().map(|m| (m * config.steps as f64) as u64).collect(),
        factor: config.optim.step_factor as f32,
    };
    let lr_factor = |step: u64| if config.optim.schedule == "step" { stepped.at(step) } else { cosine.at(step) };
    let guided = config.sampler == SamplerKind::Guided;

    let interrupted = Arc::new(AtomicBool::new(false));
    {
        let flag = interrupted.clone();
        // Only the first call can install a handler (a second run in the same process keeps it).
        let _ = ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst));
    }

    let mut sampler = None;
    let mut grid_seconds = 0.0;
    let mut grid_updates = 0;
    if guided {
        let (s, secs) = guide(&config, &backbone, &state.grid_params, &train_cameras)?;
        sampler = Some(s);
        grid_seconds += secs;
        grid_updates += 1;
    }
    let mut log = std::fs::OpenOptions::new().create(true).append(true).open(out.join("log.jsonl")).context("opening log.jsonl")?;
    let progress = if std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        let bar = indicatif::ProgressBar::new(config.steps);
        bar.set_style(indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} {percent}% {per_sec} ETA {eta} {msg}").expect("template"));
        bar.set_position(state.step);
        Some(bar)
    } else {
        None
    };
    eprintln!(
        "train: {} · {} · {} views ({} held out) · {} parameters · {} rays × {} samples · {} steps → {}",
        scene.source.description,
        if guided { "guided sampler" } else { "uniform sampler" },
        scene.views.len(),
        test_views.len(),
        n,
        config.render.rays,
        config.render.coarse + config.render.fine,
        config.steps,
        out.display()
    );
    let start = Instant::now();
    let first_step = state.step;
    let mut grads = vec![0.0f32; n];
    let mut step_seconds = 0.0;
    let mut ray_seconds = 0.0;
    let mut history = Vec::new();
    while state.step < config.steps {
        let step = state.step;
        if let Some(levels) = backbone.levels() {
            backbone.set_active_levels(active_levels(&config, levels, step));
        }
        backbone.config.curvature_weight = config.model.curvature * ((step + 1) as f64 / config.optim.warmup.max(1) as f64).min(1.0);
        if guided && step > 0 && step.is_multiple_of(config.guide.update_every) {
            state.grid_params.copy_from_slice(&state.params);
            let (s, secs) = guide(&config, &backbone, &state.grid_params, &train_cameras)?;
            sampler = Some(s);
            grid_seconds += secs;
            grid_updates += 1;
        }
        let t_step = Instant::now();
        let s_now = backbone.scale(&state.params);
        grads.fill(0.0);
        let inputs = StepInputs { config: &config, backbone: &backbone, scene, train_views: &train_views, train_cameras: &train_cameras, use_masks };
        let (loss, outputs, batch, rays_time) = inputs.gradient(&state.params, step, sampler.as_ref(), &mut grads);
        ray_seconds += rays_time;
        let f = lr_factor(step);
        let groups = [(layout.encoding.clone(), config.optim.lr_grid as f32 * f), (layout.encoding.end..n, config.optim.lr as f32 * f)];
        let clip = (config.optim.clip_norm > 0.0).then_some(config.optim.clip_norm as f32);
        adam_step(&mut state.adam, &mut state.params, &mut grads, &groups, clip);
        state.step += 1;
        step_seconds += t_step.elapsed().as_secs_f64();
        if !loss.is_finite() {
            save_checkpoint(&out, &state, &config)?;
            bail!("the loss became {loss} at step {step}; checkpoint written to {}", checkpoint_path(&out).display());
        }

        let mse =
            batch.rays.iter().zip(&outputs).map(|(r, o)| (0..3).map(|k| f64::from(o.color[k] - r.target[k]).powi(2)).sum::<f64>() / 3.0).sum::<f64>()
                / outputs.len() as f64;
        let psnr = -10.0 * mse.log10();
        if state.step.is_multiple_of(config.output.log_every) || state.step == config.steps {
            let elapsed = start.elapsed().as_secs_f64();
            let record = json!({
                "step": state.step, "loss": loss, "psnr_batch": psnr, "s": s_now, "lr": config.optim.lr * f64::from(f),
                "elapsed_s": elapsed, "step_s": step_seconds / (state.step - first_step) as f64,
                "rays_s": ray_seconds / (state.step - first_step) as f64,
                "levels": backbone.levels().map(|l| active_levels(&config, l, step)), "grid_updates": grid_updates, "grid_s": grid_seconds,
            });
            writeln!(log, "{record}").context("writing log.jsonl")?;
            let msg = format!("loss {loss:.4} PSNR {psnr:.2} s {s_now:.0}");
            match &progress {
                Some(bar) => {
                    bar.set_position(state.step);
                    bar.set_message(msg);
                }
                None => {
                    let rate = (state.step - first_step) as f64 / elapsed.max(1e-9);
                    let eta = (config.steps - state.step) as f64 / rate.max(1e-9);
                    eprintln!(
                        "step {}/{} ({:.0}%) {rate:.2} it/s ETA {eta:.0} s {msg}",
                        state.step,
                        config.steps,
                        100.0 * state.step as f64 / config.steps as f64
                    );
                }
            }
        }
        let stop = interrupted.load(Ordering::SeqCst) || args.stop_at == Some(state.step);
        let periodic = |every: u64| every > 0 && state.step.is_multiple_of(every) && state.step < config.steps;
        if periodic(config.output.checkpoint_every) || stop {
            save_checkpoint(&out, &state, &config)?;
        }
        if periodic(config.output.validate_every) {
            validation_pictures(&config, &backbone, &state.params, scene, &test_views, sampler.as_ref(), &train_views, &out, state.step)?;
        }
        if periodic(config.output.metrics_every) {
            let record = interim_metrics(&config, &backbone, &state.params, &data, &test_views, state.step, step_seconds + grid_seconds)?;
            writeln!(log, "{record}").context("writing log.jsonl")?;
            history.push(record);
        }
        if stop {
            if let Some(bar) = &progress {
                bar.abandon();
            }
            eprintln!("stopped at step {}: checkpoint written; continue with `cargo xtask train --resume {}`", state.step, out.display());
            std::process::exit(130);
        }
    }
    if let Some(bar) = &progress {
        bar.finish();
    }
    save_checkpoint(&out, &state, &config)?;
    let train_seconds = start.elapsed().as_secs_f64();
    let per_step = |t: f64| t / (config.steps - first_step).max(1) as f64;
    let timing = Timing { train_seconds, step_seconds: per_step(step_seconds), ray_seconds: per_step(ray_seconds), grid_seconds, grid_updates };
    let mut summary = finish(&config, &backbone, &state.params, &data, &test_views, &train_views, sampler.as_ref(), &out, &timing)?;
    history.push(json!({"step": config.steps, "chamfer": summary.metrics["chamfer"], "f_score": summary.metrics["f_score"], "psnr": summary.metrics["psnr"], "psnr_masked": summary.metrics["psnr_masked"], "time_s": step_seconds + grid_seconds}));
    summary.history = history;
    if args.json {
        println!("{}", serde_json::to_string(&summary)?);
    }
    Ok(summary)
}

/// Wall time of a run.
#[derive(Clone, Copy)]
struct Timing {
    train_seconds: f64,
    /// Per iteration, without grid updates.
    step_seconds: f64,
    /// Per iteration: drawing pixels and building rays (up-sampling, extra points).
    ray_seconds: f64,
    grid_seconds: f64,
    grid_updates: usize,
}

/// Chamfer of the current mesh and PSNR of the first held-out view.
fn interim_metrics(
    config: &TrainConfig,
    backbone: &Backbone,
    params: &[f32],
    data: &RunData,
    test_views: &[usize],
    step: u64,
    time: f64,
) -> Result<serde_json::Value> {
    let scene = &data.scene;
    let view = test_views.first().copied().unwrap_or(0);
    let (psnr, masked) = outputs::render_view(config, backbone, params, &scene.views[view], config.output.validate_downscale).psnr();
    let mesh = outputs::extract_mesh(config, backbone, params)?;
    let gt = outputs::ground_truth(data.path.as_deref(), scene, data.builtin_truth.as_deref(), config.output.chamfer_spacing)?;
    let geometry = match gt {
        Some(gt) if !mesh.triangles.is_empty() => Some(outputs::geometry_metrics(config, &mesh, &gt)?),
        _ => None,
    };
    Ok(
        json!({"eval": true, "step": step, "psnr": psnr, "psnr_masked": masked, "chamfer": geometry.map(|g| g.chamfer), "f_score": geometry.map(|g| g.f_score), "time_s": time}),
    )
}

/// The validation panel of the first held-out view (or view 0) and the guided pdf heat map.
#[allow(clippy::too_many_arguments)]
fn validation_pictures(
    config: &TrainConfig,
    backbone: &Backbone,
    params: &[f32],
    scene: &Scene,
    test_views: &[usize],
    sampler: Option<&ViewSampler>,
    train_views: &[usize],
    out: &Path,
    step: u64,
) -> Result<()> {
    let view = test_views.first().copied().unwrap_or(0);
    let r = outputs::render_view(config, backbone, params, &scene.views[view], config.output.validate_downscale);
    r.panel().save_png(&out.join("pictures").join(format!("val_{step:06}.png")))?;
    if let Some(sampler) = sampler {
        let cam = &sampler.cameras()[train_views.iter().position(|&v| v >= view).unwrap_or(0).min(sampler.cameras().len() - 1)];
        let (ru, rv, _) = cam.resolution();
        outputs::heat_map(&cam.pixel_marginal(), ru, rv, 4).save_png(&out.join("pictures").join(format!("pdf_{step:06}.png")))?;
    }
    Ok(())
}

/// Final pictures, mesh, metrics and summary.
#[allow(clippy::too_many_arguments)]
fn finish(
    config: &TrainConfig,
    backbone: &Backbone,
    params: &[f32],
    data: &RunData,
    test_views: &[usize],
    train_views: &[usize],
    sampler: Option<&ViewSampler>,
    out: &Path,
    timing: &Timing,
) -> Result<RunSummary> {
    let scene = &data.scene;
    let Timing { train_seconds, step_seconds, ray_seconds, grid_seconds, grid_updates } = *timing;
    validation_pictures(config, backbone, params, scene, test_views, sampler, train_views, out, config.steps)?;
    // Image metrics on the held-out views (all views when none are held out).
    let candidates: Vec<usize> = if test_views.is_empty() { (0..scene.views.len()).collect() } else { test_views.to_vec() };
    let every = candidates.len().div_ceil(config.output.eval_views.max(1));
    let eval_views: Vec<usize> = candidates.iter().copied().step_by(every.max(1)).collect();
    let t = Instant::now();
    let renders: Vec<outputs::ViewRender> =
        eval_views.iter().map(|&v| outputs::render_view(config, backbone, params, &scene.views[v], config.output.validate_downscale)).collect();
    let psnrs: Vec<(f64, Option<f64>)> = renders.iter().map(|r| r.psnr()).collect();
    let ssims: Vec<f64> = renders.iter().filter_map(|r| r.ssim()).collect();
    let mean = |v: &[f64]| if v.is_empty() { f64::NAN } else { v.iter().sum::<f64>() / v.len() as f64 };
    let psnr_whole = mean(&psnrs.iter().map(|p| p.0).collect::<Vec<_>>());
    let masked: Vec<f64> = psnrs.iter().filter_map(|p| p.1).collect();
    let psnr_masked = (!masked.is_empty()).then(|| mean(&masked));
    // Training views (the render-fit figure).
    let every = train_views.len().div_ceil(config.output.eval_train_views.max(1));
    let fit_views: Vec<usize> =
        if config.output.eval_train_views == 0 { Vec::new() } else { train_views.iter().copied().step_by(every.max(1)).collect() };
    let fit: Vec<(f64, Option<f64>)> =
        fit_views.iter().map(|&v| outputs::render_view(config, backbone, params, &scene.views[v], config.output.validate_downscale).psnr()).collect();
    let psnr_train = (!fit.is_empty()).then(|| mean(&fit.iter().map(|p| p.0).collect::<Vec<_>>()));
    let eval_seconds = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let mesh = outputs::extract_mesh(config, backbone, params)?;
    let colors = config.output.vertex_colors.then(|| outputs::vertex_colors(backbone, params, &mesh));
    let meshes = outputs::write_mesh(out, &mesh, &scene.world_from_normalized, colors.as_deref(), &config.output.mesh_formats)?;
    if !mesh.triangles.is_empty() {
        let views = [eval_views[0], train_views[train_views.len() / 2]];
        let cams: Vec<camera_geom::PinholeCamera> = views.iter().map(|&v| scene.views[v].camera).collect();
        outputs::mesh_picture(&mesh, &cams).save_png(&out.join("pictures").join("mesh.png"))?;
    }
    let mesh_seconds = t.elapsed().as_secs_f64();
    let world_scale = scene.world_from_normalized.determinant().abs().cbrt();
    let gt = outputs::ground_truth(data.path.as_deref(), scene, data.builtin_truth.as_deref(), config.output.chamfer_spacing)?;
    let geometry = match (&gt, mesh.triangles.is_empty()) {
        (Some(gt), false) => Some(outputs::geometry_metrics(config, &mesh, gt)?),
        _ => None,
    };
    let metrics = json!({
        "sampler": config.sampler,
        "steps": config.steps,
        "psnr": psnr_whole,
        "psnr_masked": psnr_masked,
        "ssim": mean(&ssims),
        "psnr_views": eval_views,
        "psnr_train": psnr_train,
        "psnr_train_views": fit_views,
        "psnr_per_view": psnrs.iter().map(|p| json!({"whole": p.0, "masked": p.1})).collect::<Vec<_>>(),
        "chamfer": geometry.map(|g| g.chamfer),
        "chamfer_world": geometry.map(|g| g.chamfer * world_scale),
        "accuracy": geometry.map(|g| g.accuracy),
        "completeness": geometry.map(|g| g.completeness),
        "f_score": geometry.map(|g| g.f_score),
        "f_score_tau": config.output.fscore_tau,
        "world_scale": world_scale,
        "mesh_vertices": mesh.vertices.len(),
        "mesh_triangles": mesh.triangles.len(),
        "train_s": train_seconds,
        "step_s": step_seconds,
        "iteration_s": step_seconds + grid_seconds / config.steps as f64,
        "rays_s": ray_seconds,
        "grid_s": grid_seconds,
        "grid_updates": grid_updates,
        "eval_s": eval_seconds,
        "mesh_s": mesh_seconds,
        "threads": rayon::current_num_threads(),
    });
    write_atomic(&out.join("metrics.json"), serde_json::to_string_pretty(&metrics)?.as_bytes())?;
    eprintln!(
        "done in {train_seconds:.0} s ({step_seconds:.3} s/step). mesh: {} ({} triangles)",
        meshes.first().map_or("-", String::as_str),
        mesh.triangles.len()
    );
    eprintln!(
        "PSNR {psnr_whole:.2} dB{} on {} held-out view(s){}; {}",
        psnr_masked.map_or(String::new(), |m| format!(" (masked {m:.2} dB)")),
        eval_views.len(),
        psnr_train.map_or(String::new(), |p| format!(", {p:.2} dB on {} training view(s)", fit_views.len())),
        match geometry {
            Some(g) => format!("Chamfer {:.4} ({:.4} in world units), F-score {:.3} at τ = {}", g.chamfer, g.chamfer * world_scale, g.f_score, g.tau),
            None if gt.is_none() => "no ground truth for Chamfer".into(),
            None => "the mesh is empty: no Chamfer".into(),
        }
    );
    Ok(RunSummary { out: out.display().to_string(), meshes, metrics, history: Vec::new() })
}

/// A finished (or checkpointed) run, ready to evaluate: its configuration, data, backbone and
/// parameters.
pub struct RestoredRun {
    /// The run's configuration.
    pub config: TrainConfig,
    scene_data: RunData,
    /// The backbone with the final coarse-to-fine state.
    pub backbone: Backbone,
    /// The parameters of the checkpoint.
    pub params: Vec<f32>,
    /// The checkpoint's step.
    pub step: u64,
}

impl RestoredRun {
    /// Loads `dir` (config.toml, data.json, checkpoint.safetensors).
    pub fn load(dir: &Path) -> Result<RestoredRun> {
        let (config, data_path, ckpt) = read_run_folder(dir, &[])?;
        let scene_data = load_data(&config, data_path.as_deref())?;
        let (mut backbone, mut params) = backbone_for(&config, uses_masks(&config, &scene_data.scene))?;
        let mut adam = Adam::new(params.len());
        ckpt.restore(&mut params, &mut adam)?;
        let step: u64 = ckpt.metadata.get("step").and_then(|s| s.parse().ok()).context("checkpoint without a step")?;
        if let Some(levels) = backbone.levels() {
            backbone.set_active_levels(active_levels(&config, levels, step.saturating_sub(1)));
        }
        Ok(RestoredRun { config, scene_data, backbone, params, step })
    }

    /// The run's scene.
    pub fn scene(&self) -> &Scene {
        &self.scene_data.scene
    }

    /// Indices of the training views and their cameras, and whether masks are used.
    pub fn training_views(&self) -> (Vec<usize>, Vec<camera_geom::PinholeCamera>, bool) {
        let scene = self.scene();
        let (views, _) = split_views(&self.config, scene);
        let cameras = views.iter().map(|&i| scene.views[i].camera).collect();
        let use_masks = uses_masks(&self.config, scene);
        (views, cameras, use_masks)
    }

    /// Indices of the held-out views (all views when none are held out).
    pub fn held_out_views(&self) -> Vec<usize> {
        let (train, held) = split_views(&self.config, self.scene());
        if held.is_empty() { train } else { held }
    }
}
