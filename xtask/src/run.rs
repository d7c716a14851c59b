//! `cargo xtask train`: a [`Trainer`] with a run folder around it — the resolved configuration,
//! a JSONL log, validation pictures, atomic checkpoints, resume, a stop signal (Ctrl-C), progress
//! in every phase (training, meshing, evaluation), and at the end the mesh, its picture and the
//! metrics.
//!
//! Every file goes through a [`Sink`] (atomic writes by default): a failed write names the file
//! and its cause, leaves the previous checkpoint as it was, and ends the run with an error. A run
//! that fails before its first checkpoint removes the run folder it created.

use crate::config::{SamplerKind, TrainConfig, parse_duration};
use crate::data::SceneData;
use crate::memory::{self, MemoryEstimate};
use crate::outputs::{geometry_metrics, mesh_files, mesh_picture};
use crate::plot::{Panel, Series, render};
use crate::progress::Progress;
use crate::trainer::{StepReport, Trainer};
use anyhow::{Context, Result, bail};
use sdf_backbone::CheckpointReader;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Options of `cargo xtask train`.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct TrainArgs {
    /// Dataset folder (IDR/NeuS/DTU, NeRF-synthetic, instant-ngp, COLMAP). Default: the
    /// built-in scene.
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// TOML configuration (unknown keys are errors).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// guided (the paper) or uniform (the plain backbone, same rays and samples).
    #[arg(long)]
    pub sampler: Option<String>,
    /// Train for this long instead of a number of steps: `90s`, `10m`, `1.5h` (sets
    /// `time_budget_s`; the schedules follow the fraction of the budget spent).
    #[arg(long)]
    pub budget: Option<String>,
    /// Run folder (config, log, pictures, checkpoints, mesh, metrics).
    #[arg(long, default_value = "out/train")]
    pub out: PathBuf,
    /// Continue the run in this folder from its checkpoint, with its own configuration (same
    /// result as an uninterrupted run for step budgets; the rest of the budget for time budgets).
    #[arg(long, conflicts_with_all = ["data", "config", "sampler", "seed", "budget"])]
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
    /// The memory limit (e.g. `8G`); by default the memory the system has available. A run whose
    /// estimated peak exceeds it is refused before it starts, with what to change.
    #[arg(long)]
    pub max_memory: Option<String>,
    /// Configuration overrides `key=value` (e.g. `steps=500 guide.scene.partition=1`).
    pub overrides: Vec<String>,
}

/// What a finished run reports.
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

/// How a run ended.
#[derive(Debug, Clone)]
pub enum Outcome {
    /// The budget was spent; mesh and metrics written.
    Finished(Box<RunSummary>),
    /// Stopped by the stop signal or `--stop-at`: a checkpoint was written.
    Stopped {
        /// Iterations done.
        step: u64,
        /// The run folder.
        out: PathBuf,
    },
}

/// Where a run's files go. The default writes atomically (temporary file + rename); tests inject
/// failures.
pub trait Sink: Send + Sync {
    /// Writes `bytes` to `path` whole, or not at all.
    fn write(&self, path: &Path, bytes: &[u8]) -> std::io::Result<()>;

    /// Writes what `fill` streams to `path` whole, or not at all. Default: collected in memory,
    /// then [`Sink::write`].
    fn write_with(&self, path: &Path, fill: &mut dyn FnMut(&mut dyn std::io::Write) -> std::io::Result<()>) -> std::io::Result<()> {
        let mut bytes = Vec::new();
        fill(&mut bytes)?;
        self.write(path, &bytes)
    }
}

/// Atomic writes to the file system (`datasets::io::write_atomic`).
#[derive(Debug, Clone, Copy, Default)]
pub struct AtomicFiles;

impl Sink for AtomicFiles {
    fn write(&self, path: &Path, bytes: &[u8]) -> std::io::Result<()> {
        self.write_with(path, &mut |w| w.write_all(bytes))
    }
    fn write_with(&self, path: &Path, fill: &mut dyn FnMut(&mut dyn std::io::Write) -> std::io::Result<()>) -> std::io::Result<()> {
        datasets::io::write_atomic_with(path, fill).map_err(|e| match e {
            datasets::DatasetError::Io { source, .. } => source,
            other => std::io::Error::other(other.to_string()),
        })
    }
}

/// A run folder and the sink its files go through.
pub struct RunFolder {
    dir: PathBuf,
    sink: Arc<dyn Sink>,
}

impl RunFolder {
    /// Creates `dir` and `dir/pictures`; returns the folder and whether `dir` was created now.
    pub fn create(dir: &Path, sink: Arc<dyn Sink>) -> Result<(RunFolder, bool)> {
        let existed = dir.exists();
        std::fs::create_dir_all(dir.join("pictures")).with_context(|| format!("cannot create the run folder {}", dir.display()))?;
        Ok((RunFolder { dir: dir.to_path_buf(), sink }, !existed))
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Writes `name` (relative to the folder) whole; the error names the file and the cause.
    pub fn write(&self, name: &str, bytes: &[u8]) -> Result<()> {
        let path = self.dir.join(name);
        self.sink.write(&path, bytes).with_context(|| format!("cannot write {}", path.display()))
    }

    /// Writes `name` from what `fill` streams, whole; the error names the file and the cause.
    pub fn write_with(&self, name: &str, fill: &mut dyn FnMut(&mut dyn std::io::Write) -> std::io::Result<()>) -> Result<()> {
        let path = self.dir.join(name);
        self.sink.write_with(&path, fill).with_context(|| format!("cannot write {}", path.display()))
    }

    /// Writes the trainer's checkpoint (streamed).
    pub fn write_checkpoint(&self, trainer: &Trainer) -> Result<()> {
        self.write_with("checkpoint.safetensors", &mut |w| trainer.write_checkpoint(w))
    }

    /// Writes a PNG.
    pub fn write_png(&self, name: &str, image: &datasets::RgbImage) -> Result<()> {
        self.write(name, &image.png_bytes().with_context(|| format!("encoding {name}"))?)
    }

    /// Appends one line to `log.jsonl` (a log is appended, not replaced).
    pub fn log(&self, record: &serde_json::Value) -> Result<()> {
        use std::io::Write;
        let path = self.dir.join("log.jsonl");
        let mut f = std::fs::OpenOptions::new().create(true).append(true).open(&path).with_context(|| format!("cannot open {}", path.display()))?;
        writeln!(f, "{record}").with_context(|| format!("cannot write {}", path.display()))
    }
}

/// The checkpoint file of a run folder.
pub fn checkpoint_path(dir: &Path) -> PathBuf {
    dir.join("checkpoint.safetensors")
}

/// A run folder's configuration and data path; errors name the file at fault.
pub fn read_run_config(dir: &Path) -> Result<(TrainConfig, Option<PathBuf>)> {
    let config_path = dir.join("config.toml");
    let text = std::fs::read_to_string(&config_path).with_context(|| format!("{} is not a run folder (no config.toml)", dir.display()))?;
    let config = TrainConfig::from_toml(&text).with_context(|| format!("{}", config_path.display()))?;
    let data_path = dir.join("data.json");
    let data: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&data_path).with_context(|| format!("{} is not a run folder (no data.json)", dir.display()))?)
            .with_context(|| format!("{} is not valid JSON", data_path.display()))?;
    Ok((config, data["path"].as_str().map(PathBuf::from)))
}

/// A run folder's trainer at its checkpoint (for `eval --run`, the benches, `--resume`).
pub fn open_run(dir: &Path) -> Result<Trainer> {
    let (config, data_path) = read_run_config(dir)?;
    let data = SceneData::load(&config, data_path.as_deref())?;
    restore_run(dir, config, data)
}

/// The trainer of `config` on `data` at the checkpoint of run folder `dir`.
fn restore_run(dir: &Path, config: TrainConfig, data: SceneData) -> Result<Trainer> {
    let ckpt_path = checkpoint_path(dir);
    let file = std::fs::File::open(&ckpt_path).with_context(|| format!("no checkpoint in {}", dir.display()))?;
    let len = file.metadata().with_context(|| format!("{}", ckpt_path.display()))?.len();
    let mut input = std::io::BufReader::new(file);
    let reader = CheckpointReader::open(&mut input, len).with_context(|| format!("{} is truncated or corrupt", ckpt_path.display()))?;
    let mut trainer = Trainer::new(config, data)?;
    trainer.restore(&reader, &mut input).with_context(|| format!("restoring {}", ckpt_path.display()))?;
    Ok(trainer)
}

/// The memory model of `config` on `data`, printed beside the memory available; an error naming
/// what to change when the peak exceeds `max_memory` (default: the memory available).
pub fn check_memory(config: &TrainConfig, data: &SceneData, max_memory: Option<f64>) -> Result<MemoryEstimate> {
    let mut backbone = sdf_backbone::architecture(config.model.preset);
    backbone.config.normals = config.model.normals;
    if config.model.background_model.learned(crate::data::uses_masks(config, &data.scene)) {
        backbone.add_learned_background(&mut Vec::new(), 0);
    }
    let n_params = backbone.n_params::<f32>();
    let view_pixels = data.scene.views.iter().map(|v| v.image.width as usize * v.image.height as usize).max().unwrap_or(0);
    let estimate =
        memory::estimate(config, &backbone, n_params, data.scene.views.len(), data.scene.pixel_bytes(), view_pixels, rayon::current_num_threads());
    let available = memory::available_bytes();
    let limit = max_memory.or(available);
    eprintln!(
        "memory: {}; {}",
        estimate.describe(),
        match (available, max_memory) {
            (_, Some(m)) => format!("limit {:.2} GB (--max-memory)", m / 1e9),
            (Some(a), None) => format!("{:.2} GB available", a / 1e9),
            (None, None) => "available memory unknown".into(),
        }
    );
    if let Some(limit) = limit.filter(|l| estimate.peak() > *l) {
        bail!(
            "this run needs about {:.2} GB and {:.2} GB is the limit: lower {} (or raise the limit with --max-memory)",
            estimate.peak() / 1e9,
            limit / 1e9,
            estimate.advice(config)
        );
    }
    Ok(estimate)
}

/// The configuration of a fresh run from the command line.
fn fresh_config(args: &TrainArgs) -> Result<TrainConfig> {
    let mut overrides = args.overrides.clone();
    if let Some(s) = &args.sampler {
        overrides.push(format!("sampler={s}"));
    }
    if let Some(seed) = args.seed {
        overrides.push(format!("seed={seed}"));
    }
    if let Some(b) = &args.budget {
        overrides.push(format!("time_budget_s={}", parse_duration(b)?));
    }
    TrainConfig::load(args.config.as_deref(), &overrides)
}

/// Runs `cargo xtask train` with atomic file writes; `stop` ends the run early with a checkpoint.
pub fn train(args: &TrainArgs, stop: &AtomicBool) -> Result<Outcome> {
    train_with(args, stop, Arc::new(AtomicFiles))
}

/// [`train`] with the files going through `sink`.
pub fn train_with(args: &TrainArgs, stop: &AtomicBool, sink: Arc<dyn Sink>) -> Result<Outcome> {
    // Everything that can fail on input fails before the run folder exists, and the memory is
    // checked before anything large is allocated.
    let max_memory = args.max_memory.as_deref().map(memory::parse_size).transpose()?;
    let (trainer, dir, estimate) = if let Some(dir) = &args.resume {
        if !args.overrides.is_empty() {
            bail!("--resume continues a run with its own configuration; overrides ({}) are not allowed", args.overrides.join(" "));
        }
        let (config, data_path) = read_run_config(dir)?;
        let data = SceneData::load(&config, data_path.as_deref())?;
        let estimate = check_memory(&config, &data, max_memory)?;
        (restore_run(dir, config, data)?, dir.clone(), estimate)
    } else {
        let config = fresh_config(args)?;
        let data = SceneData::load(&config, args.data.as_deref())?;
        let estimate = check_memory(&config, &data, max_memory)?;
        (Trainer::new(config, data)?, args.out.clone(), estimate)
    };
    let (folder, created) = RunFolder::create(&dir, sink)?;
    let result = run_folder(trainer, &folder, args, stop, &estimate);
    if result.is_err() && created && !checkpoint_path(&dir).exists() {
        // Nothing worth keeping was made: leave no stray folder.
        let _ = std::fs::remove_dir_all(&dir);
    }
    result
}

/// Whether a due validation picture is taken: while the pictures so far took at most `share` of
/// the training time so far (the time a budget counts; `share` = 0: always).
fn pictures_due(picture_seconds: f64, trainer: &Trainer, share: f64) -> bool {
    share == 0.0 || picture_seconds <= share * trainer.state().train_seconds
}

fn run_folder(mut trainer: Trainer, folder: &RunFolder, args: &TrainArgs, stop: &AtomicBool, estimate: &MemoryEstimate) -> Result<Outcome> {
    let config = trainer.config().clone();
    if args.resume.is_none() {
        folder.write("config.toml", config.to_toml().as_bytes())?;
        let data = trainer.data();
        let data_json = json!({"path": data.path.as_ref().map(|p| p.display().to_string()), "description": data.description()});
        folder.write("data.json", serde_json::to_string_pretty(&data_json)?.as_bytes())?;
    }
    let guided = config.sampler == SamplerKind::Guided;
    let split = trainer.split().clone();
    eprintln!(
        "train: {} · {} · {} views ({} held out) · {} parameters · {} rays × {} samples · {} → {}",
        trainer.data().description(),
        if guided { "guided sampler" } else { "uniform sampler" },
        trainer.data().scene.views.len(),
        split.held_out.len(),
        trainer.state().params.len(),
        config.render.rays,
        config.render.coarse + config.render.fine,
        if config.timed() { format!("{:.0} s budget", config.time_budget_s) } else { format!("{} steps", config.steps) },
        folder.dir().display()
    );
    let progress = Progress::new(&config);
    progress.set(trainer.state().step, trainer.progress(), trainer.seconds_left(), "");
    let mut history = Vec::new();
    let start = Instant::now();
    let mut measured_seconds = 0.0;
    let mut picture_seconds = 0.0;
    while !trainer.done() {
        let report = trainer.step()?;
        log_step(folder, &progress, &trainer, &report)?;
        let step = report.step;
        let stopping = stop.load(Ordering::SeqCst) || args.stop_at == Some(step);
        let periodic = |every: u64| every > 0 && step.is_multiple_of(every) && !trainer.done();
        if periodic(config.output.checkpoint_every) || stopping {
            folder.write_checkpoint(&trainer)?;
        }
        if periodic(config.output.validate_every) && pictures_due(picture_seconds, &trainer, config.output.validate_share) {
            let t = Instant::now();
            validation_pictures(&trainer, folder, step)?;
            picture_seconds += t.elapsed().as_secs_f64();
        }
        if periodic(config.output.metrics_every) {
            let t = Instant::now();
            let record = interim_metrics(&trainer)?;
            measured_seconds += t.elapsed().as_secs_f64();
            folder.log(&record)?;
            history.push(record);
        }
        if stopping {
            progress.abandon();
            eprintln!("stopped at step {step}: checkpoint written; continue with `cargo xtask train --resume {}`", folder.dir().display());
            return Ok(Outcome::Stopped { step, out: folder.dir().to_path_buf() });
        }
    }
    progress.finish_phase();
    let t = Instant::now();
    progress.phase("checkpoint", 0, 1);
    folder.write_checkpoint(&trainer)?;
    progress.phase("checkpoint", 1, 1);
    let checkpoint_seconds = t.elapsed().as_secs_f64();
    let wall = start.elapsed().as_secs_f64() - measured_seconds;
    curves(folder)?;
    let mut summary = finish(&trainer, folder, &progress, wall, estimate)?;
    summary.metrics["checkpoint_s"] = json!(checkpoint_seconds);
    summary.metrics["validation_s"] = json!(picture_seconds);
    folder.write("metrics.json", serde_json::to_string_pretty(&summary.metrics)?.as_bytes())?;
    let t = trainer.timing();
    history.push(json!({"step": trainer.state().step, "chamfer": summary.metrics["chamfer"], "f_score": summary.metrics["f_score"], "psnr": summary.metrics["psnr"], "psnr_masked": summary.metrics["psnr_masked"], "time_s": t.step_seconds + t.grid_seconds}));
    summary.history = history;
    if args.json {
        println!("{}", serde_json::to_string(&summary)?);
    }
    Ok(Outcome::Finished(Box::new(summary)))
}

/// `pictures/curves.png` from the run's log: loss, batch PSNR and s against iterations and
/// against training time, and, when the run logged metrics (`output.metrics_every`), Chamfer and
/// held-out PSNR.
fn curves(folder: &RunFolder) -> Result<()> {
    let text = std::fs::read_to_string(folder.dir().join("log.jsonl")).unwrap_or_default();
    let records: Vec<serde_json::Value> = text.lines().filter_map(|l| serde_json::from_str(l).ok()).collect();
    let steps: Vec<&serde_json::Value> = records.iter().filter(|r| r["loss"].is_number()).collect();
    let evals: Vec<&serde_json::Value> = records.iter().filter(|r| r["eval"] == true).collect();
    if steps.len() < 2 {
        return Ok(());
    }
    let series = |rows: &[&serde_json::Value], x: &str, y: &str, label: &str, color: [f32; 3]| Series {
        label: label.into(),
        color,
        points: rows.iter().filter_map(|r| Some((r[x].as_f64()?, r[y].as_f64()?, None))).collect(),
    };
    let mut panels = Vec::new();
    for (key, label, color) in [
        ("loss", "training loss", [0.2, 0.35, 0.85]),
        ("psnr_batch", "batch PSNR (dB)", [0.85, 0.15, 0.15]),
        ("s", "logistic scale s (1 / length)", [0.15, 0.6, 0.25]),
    ] {
        for (x, x_label) in [("step", "iteration"), ("train_s", "training time (s)")] {
            panels.push(Panel {
                title: format!("{label} against {}", if x == "step" { "iterations" } else { "time" }),
                x_label: x_label.into(),
                y_label: label.into(),
                series: vec![series(&steps, x, key, label, color)],
                markers: Vec::new(),
            });
        }
    }
    if !evals.is_empty() {
        for (key, label) in [("chamfer", "Chamfer (normalised units)"), ("psnr", "held-out PSNR (dB)")] {
            panels.push(Panel {
                title: format!("{label} against iterations"),
                x_label: "iteration".into(),
                y_label: label.into(),
                series: vec![series(&evals, "step", key, label, [0.6, 0.3, 0.7])],
                markers: Vec::new(),
            });
        }
    }
    folder.write_png("pictures/curves.png", &render(&panels, 2, (420, 300))?)
}

fn log_step(folder: &RunFolder, progress: &Progress, trainer: &Trainer, report: &StepReport) -> Result<()> {
    let config = trainer.config();
    let last = trainer.done();
    if report.step.is_multiple_of(config.output.log_every) || last || report.update.is_some() {
        let t = trainer.timing();
        let per = |x: f64| x / t.steps.max(1) as f64;
        let record = json!({
            "step": report.step, "progress": report.progress, "loss": report.loss, "psnr_batch": report.psnr_batch, "s": report.s, "lr": report.lr,
            "train_s": trainer.state().train_seconds, "step_s": per(t.step_seconds), "rays_s": per(t.ray_seconds), "levels": report.levels,
            "grid_updates": t.grid_updates, "grid_s": t.grid_seconds, "guided_rays": report.guided_rays,
            "rss_bytes": crate::memory::rss_bytes(),
            "update": report.update.as_ref().map(|u| json!({"seconds": u.seconds, "s": u.s, "occupied": u.occupied_fraction,
                "lipschitz_measured": u.lipschitz.measured, "lipschitz_used": u.lipschitz.used, "lipschitz_retries": u.lipschitz.retries})),
        });
        folder.log(&record)?;
    }
    progress.set(
        report.step,
        report.progress,
        trainer.seconds_left(),
        &format!("loss {:.4} PSNR {:.2} s {:.0}", report.loss, report.psnr_batch, report.s),
    );
    Ok(())
}

/// The validation panel of the first held-out view (or view 0) and the guide's pdf heat map.
fn validation_pictures(trainer: &Trainer, folder: &RunFolder, step: u64) -> Result<()> {
    let view = trainer.split().evaluation_views()[0];
    let render = trainer.render_view(view, trainer.config().output.validate_downscale);
    folder.write_png(&format!("pictures/val_{step:06}.png"), &render.panel())?;
    if let Some(map) = trainer.pdf_heat_map(view) {
        folder.write_png(&format!("pictures/pdf_{step:06}.png"), &map)?;
    }
    Ok(())
}

/// Chamfer of the current mesh and PSNR of the first held-out view (not counted as training).
fn interim_metrics(trainer: &Trainer) -> Result<serde_json::Value> {
    let config = trainer.config();
    let view = trainer.split().evaluation_views()[0];
    let (psnr, masked) = trainer.render_view(view, config.output.eval_downscale).psnr();
    let mesh = trainer.extract_mesh(&|_, _| {})?;
    let geometry = match trainer.data().ground_truth(config.output.chamfer_spacing)? {
        Some(gt) if !mesh.triangles.is_empty() => {
            Some(geometry_metrics(&mesh, &gt, config.output.chamfer_spacing, config.output.chamfer_max_dist, config.output.fscore_tau)?)
        }
        _ => None,
    };
    let t = trainer.timing();
    Ok(json!({"eval": true, "step": trainer.state().step, "psnr": psnr, "psnr_masked": masked, "chamfer": geometry.map(|g| g.chamfer),
        "f_score": geometry.map(|g| g.f_score), "time_s": t.step_seconds + t.grid_seconds}))
}

/// Image metrics of a trainer on the views of `views` at `downscale`: per view (whole, masked)
/// PSNR and SSIM; `progress(done, total)`.
pub fn image_metrics(trainer: &Trainer, views: &[usize], downscale: u32, progress: &dyn Fn(usize, usize)) -> Vec<(f64, Option<f64>, Option<f64>)> {
    views
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            let r = trainer.render_view(v, downscale);
            progress(i + 1, views.len());
            let (whole, masked) = r.psnr();
            (whole, masked, r.ssim())
        })
        .collect()
}

fn mean(values: impl Iterator<Item = f64>) -> Option<f64> {
    let v: Vec<f64> = values.collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// Final pictures, mesh, metrics and summary.
fn finish(trainer: &Trainer, folder: &RunFolder, progress: &Progress, train_wall: f64, estimate: &MemoryEstimate) -> Result<RunSummary> {
    let config = trainer.config();
    let scene = &trainer.data().scene;
    let split = trainer.split();
    let step = trainer.state().step;
    // Each phase's scratch buffers differ in size: the resident size is the largest phase's.
    sdf_backbone::scratch::release_all();
    validation_pictures(trainer, folder, step)?;
    // Image metrics on the held-out views (all views when none are held out).
    let candidates = split.evaluation_views();
    let every = candidates.len().div_ceil(config.output.eval_views.max(1));
    let eval_views: Vec<usize> = candidates.iter().copied().step_by(every.max(1)).collect();
    let fit_every = split.train.len().div_ceil(config.output.eval_train_views.max(1));
    let fit_views: Vec<usize> =
        if config.output.eval_train_views == 0 { Vec::new() } else { split.train.iter().copied().step_by(fit_every.max(1)).collect() };
    let t = Instant::now();
    let n_renders = eval_views.len() + fit_views.len();
    let held = image_metrics(trainer, &eval_views, config.output.eval_downscale, &|i, _| progress.phase("eval", i, n_renders));
    let fit = image_metrics(trainer, &fit_views, config.output.eval_downscale, &|i, _| progress.phase("eval", eval_views.len() + i, n_renders));
    let eval_seconds = t.elapsed().as_secs_f64();
    sdf_backbone::scratch::release_all();
    let psnr = mean(held.iter().map(|p| p.0)).unwrap_or(f64::NAN);
    let psnr_masked = mean(held.iter().filter_map(|p| p.1));
    let ssim = mean(held.iter().filter_map(|p| p.2));
    let psnr_train = mean(fit.iter().map(|p| p.0));
    let psnr_train_masked = mean(fit.iter().filter_map(|p| p.1));

    let t = Instant::now();
    let (mesh, components, kept) = trainer.extract_mesh_with_stats(&|done, total| progress.phase("mesh", done, total))?;
    let colors = config.output.vertex_colors.then(|| trainer.vertex_colors(&mesh));
    let mut meshes = Vec::new();
    for (format, bytes) in mesh_files(&mesh, &scene.world_from_normalized, colors.as_deref(), &config.output.mesh_formats) {
        let name = format!("mesh.{}", format.extension());
        folder.write(&name, &bytes)?;
        meshes.push(folder.dir().join(name).display().to_string());
    }
    if !mesh.triangles.is_empty() {
        let views = [eval_views[0], split.train[split.train.len() / 2]];
        let cams: Vec<camera_geom::PinholeCamera> = views.iter().map(|&v| scene.views[v].camera).collect();
        folder.write_png("pictures/mesh.png", &mesh_picture(&mesh, &cams))?;
    }
    let mesh_seconds = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let world_scale = scene.world_from_normalized.determinant().abs().cbrt();
    let gt = trainer.data().ground_truth(config.output.chamfer_spacing)?;
    let geometry = match (&gt, mesh.triangles.is_empty()) {
        (Some(gt), false) => {
            Some(geometry_metrics(&mesh, gt, config.output.chamfer_spacing, config.output.chamfer_max_dist, config.output.fscore_tau)?)
        }
        _ => None,
    };
    let geometry_seconds = t.elapsed().as_secs_f64();
    progress.finish_phase();
    let timing = trainer.timing();
    let per_step = |x: f64| x / timing.steps.max(1) as f64;
    let metrics = json!({
        "sampler": config.sampler,
        "steps": step,
        "time_budget_s": config.time_budget_s,
        "psnr": psnr,
        "psnr_masked": psnr_masked,
        "ssim": ssim,
        "psnr_views": eval_views,
        "psnr_train": psnr_train,
        "psnr_train_masked": psnr_train_masked,
        "psnr_train_views": fit_views,
        "psnr_per_view": held.iter().map(|p| json!({"whole": p.0, "masked": p.1})).collect::<Vec<_>>(),
        "chamfer": geometry.map(|g| g.chamfer),
        "chamfer_world": geometry.map(|g| g.chamfer * world_scale),
        "accuracy": geometry.map(|g| g.accuracy),
        "completeness": geometry.map(|g| g.completeness),
        "f_score": geometry.map(|g| g.f_score),
        "f_score_tau": config.output.fscore_tau,
        "world_scale": world_scale,
        "mesh_vertices": mesh.vertices.len(),
        "mesh_triangles": mesh.triangles.len(),
        "mesh_components": components,
        "mesh_components_kept": kept,
        "train_s": trainer.state().train_seconds,
        "train_wall_s": train_wall,
        "step_s": per_step(timing.step_seconds),
        "iteration_s": per_step(timing.step_seconds + timing.grid_seconds),
        "rays_s": per_step(timing.ray_seconds),
        "grid_s": timing.grid_seconds,
        "grid_updates": timing.grid_updates,
        "eval_s": eval_seconds,
        "mesh_s": mesh_seconds,
        "geometry_s": geometry_seconds,
        "threads": rayon::current_num_threads(),
        "memory_estimate_bytes": estimate.peak(),
        "peak_rss_bytes": memory::peak_rss_bytes(),
    });
    folder.write("metrics.json", serde_json::to_string_pretty(&metrics)?.as_bytes())?;
    eprintln!(
        "done in {:.0} s ({:.3} s/iteration, {step} iterations). mesh: {} ({} triangles, {kept} of {components} components)",
        trainer.state().train_seconds,
        per_step(timing.step_seconds + timing.grid_seconds),
        meshes.first().map_or("-", String::as_str),
        mesh.triangles.len()
    );
    eprintln!(
        "PSNR {psnr:.2} dB{} on {} held-out view(s){}; {}",
        psnr_masked.map_or(String::new(), |m| format!(" (masked {m:.2} dB)")),
        eval_views.len(),
        psnr_train.map_or(String::new(), |p| format!(", {p:.2} dB on {} training view(s)", fit_views.len())),
        match geometry {
            Some(g) => format!("Chamfer {:.4} ({:.4} in world units), F-score {:.3} at τ = {}", g.chamfer, g.chamfer * world_scale, g.f_score, g.tau),
            None if gt.is_none() => "no ground truth for Chamfer".into(),
            None => "the mesh is empty: no Chamfer".into(),
        }
    );
    Ok(RunSummary { out: folder.dir().display().to_string(), meshes, metrics, history: Vec::new() })
}
