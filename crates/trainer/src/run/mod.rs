//! `cargo xtask train`: a [`Trainer`] with a run folder around it — the resolved configuration,
//! a JSONL log, validation pictures, atomic checkpoints, resume, a stop signal (Ctrl-C), progress
//! in every phase (training, meshing, evaluation), and at the end the mesh, its picture and the
//! metrics.
//!
//! Every file goes through a [`Sink`] (atomic writes by default): a failed write names the file
//! and its cause, leaves the previous checkpoint as it was, and ends the run with an error. A run
//! that fails before its first checkpoint removes the run folder it created.

use crate::bail;
use crate::config::TrainConfig;
use crate::data::{SceneData, SceneSize};
use crate::error::{Context, Result};
pub use crate::folder::{AtomicFiles, RunFolder, Sink, checkpoint_path, read_run_config};
use crate::folder::{DataRecord, is_run_folder};
use crate::memory::{self, MemoryEstimate};
use crate::metrics::RunMetrics;
use crate::outputs::run_geometry;
use crate::plot::{Panel, Series, render};
use crate::progress::Progress;
use crate::snapshot::{Snapshots, write_snapshot};
use crate::trainer::{StepReport, Trainer};
use sdf_backbone::CheckpointReader;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::time::Instant;

mod finish;
mod remesh;
pub use crate::snapshot::RunModel;
use finish::{FinishTiming, final_eval_views, finish};
pub use remesh::{Remeshed, RemeshedGeometry, remesh};

/// What to run.
#[derive(Debug, Clone)]
pub enum RunRequest {
    /// A new run of `config` on `data` (none: the built-in scene) into the folder `out`.
    Fresh {
        /// The configuration.
        config: Box<TrainConfig>,
        /// The dataset folder.
        data: Option<PathBuf>,
        /// The run folder (must not exist, be empty, or, with `overwrite`, be a run folder).
        out: PathBuf,
        /// Replace an earlier run in `out`.
        overwrite: bool,
    },
    /// The continuation of the run in `dir`, on its own data (or on `data`, the same data at a
    /// new place: checked against the run's fingerprint).
    Resume {
        /// The run folder.
        dir: PathBuf,
        /// The run's data at a new place.
        data: Option<PathBuf>,
    },
}

/// How to run it.
#[derive(Debug, Clone, Copy, Default)]
pub struct RunOptions {
    /// The memory limit in bytes (default: the memory available).
    pub max_memory: Option<f64>,
    /// Stop after this iteration as if interrupted.
    pub stop_at: Option<u64>,
    /// Print one JSON summary line at the end.
    pub json: bool,
}

/// The default run folder.
pub const DEFAULT_OUT: &str = "out/train";

/// `out/train`, or the first of `out/train-2`, `-3`, … that does not hold a run yet.
pub fn free_default_out() -> PathBuf {
    let taken = |p: &Path| p.exists() && (is_run_folder(p) || std::fs::read_dir(p).map_or(true, |mut d| d.next().is_some()));
    let first = PathBuf::from(DEFAULT_OUT);
    if !taken(&first) {
        return first;
    }
    (2..).map(|i| PathBuf::from(format!("{DEFAULT_OUT}-{i}"))).find(|p| !taken(p)).expect("a free name")
}

/// What a finished run reports.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RunSummary {
    /// Run folder.
    pub out: String,
    /// Mesh files written.
    pub meshes: Vec<String>,
    /// Metrics (also in metrics.json).
    pub metrics: RunMetrics,
    /// Periodic metrics (`output.metrics_every`), also in log.jsonl.
    pub history: Vec<serde_json::Value>,
}

/// How a run ended.
#[derive(Debug, Clone)]
pub enum Outcome {
    /// The budget was spent; mesh and metrics written.
    Finished(Box<RunSummary>),
    /// Stopped by the stop signal or `--stop-at`: a checkpoint was written (and kept, when the
    /// stop came during meshing or evaluation).
    Stopped {
        /// Iterations done.
        step: u64,
        /// The run folder.
        out: PathBuf,
    },
}

/// The phase a run is in, for what the first Ctrl-C says it will do ([`stop_message`]).
static PHASE: AtomicU8 = AtomicU8::new(0);
const PHASE_TRAINING: u8 = 0;
const PHASE_FINISHING: u8 = 1;

/// What asked a run to stop (the stop signal's source, for the message).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopSource {
    /// Ctrl-C in the terminal (SIGINT).
    CtrlC,
    /// SIGTERM: a batch scheduler, `timeout`, `docker stop`, systemd, `kill`.
    Terminate,
    /// SIGHUP: the terminal went away.
    HangUp,
}

/// What a stop request does now, said when it comes (the first signal).
pub fn stop_message(source: StopSource) -> String {
    let (what, again) = match source {
        StopSource::CtrlC => ("Ctrl-C", "Ctrl-C again to quit now"),
        StopSource::Terminate => ("SIGTERM", "a second SIGTERM quits now"),
        StopSource::HangUp => ("SIGHUP", "a second SIGHUP quits now"),
    };
    let doing = match PHASE.load(Ordering::SeqCst) {
        PHASE_FINISHING => {
            "stopping after this part of meshing and evaluation: the checkpoint is kept, no mesh or metrics are written; `--resume` finishes them"
        }
        _ => "stopping after this iteration (a checkpoint will be written)",
    };
    format!("{what}: {doing}; {again}")
}

/// The memory model of `config` on `data`, printed beside the memory available; an error naming
/// what to change when the peak exceeds `max_memory` (default: the memory available).
pub fn check_memory(config: &TrainConfig, size: &SceneSize, max_memory: Option<f64>) -> Result<MemoryEstimate> {
    let mut backbone = crate::sizing::architecture(&config.model, size.footprint)?;
    backbone.set_normal_scheme(config.model.normal_scheme());
    if config.model.background_model.learned(config.data.masks && size.masks) {
        backbone.add_learned_background(&mut Vec::new(), crate::trainer::background_model(config), 0);
    }
    let n_params = backbone.n_params::<f32>();
    let mesh_resolution = crate::sizing::mesh_resolution(config.output.mesh_resolution, &config.model, size.footprint)?;
    let estimate = memory::estimate(config, &backbone, n_params, size, mesh_resolution, rayon::current_num_threads());
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
            Config,
            "this run needs about {:.2} GB and {:.2} GB is the limit: lower {} (or raise the limit with --max-memory)",
            estimate.peak() / 1e9,
            limit / 1e9,
            estimate.advice(config)
        );
    }
    Ok(estimate)
}

/// A run folder's trainer at its checkpoint, on the run's own data (checked against its
/// fingerprint; `data`: the same data at a new place), for `eval --run`, the benches, `--resume`.
pub fn open_run(dir: &Path, data: Option<&Path>) -> Result<Trainer> {
    open_run_model(dir, data, RunModel::Last)
}

/// [`open_run`] at `model`: the run's last checkpoint or one a snapshot kept (checked to exist
/// before the data is loaded).
pub fn open_run_model(dir: &Path, data: Option<&Path>, model: RunModel) -> Result<Trainer> {
    let (config, record) = read_run_config(dir)?;
    let checkpoint = model.checkpoint(dir)?;
    let data = load_run_data(dir, &config, &record, data)?;
    restore_checkpoint(&checkpoint, config, data)
}

/// `", 0.65 px"`: a distance in pixels of the photos at the region of interest (`footprint`,
/// [`crate::trainer::Trainer::pixel_footprint`]); empty without a footprint or a finite distance.
pub fn in_pixels(distance: f64, footprint: Option<f64>) -> String {
    match footprint.filter(|f| *f > 0.0) {
        Some(f) if distance.is_finite() => format!(", {:.2} px", distance / f),
        _ => String::new(),
    }
}

/// `", normal consistency 0.985"`: the mesh's normals against the truth's
/// ([`crate::metrics::RunMetrics::normal_consistency`]); empty without.
pub fn normals_part(normal_consistency: Option<f64>) -> String {
    normal_consistency.map_or(String::new(), |nc| format!(", normal consistency {nc:.4}"))
}

/// One line for the figures over what the training views observe; with the views' pixel
/// footprint, the Chamfer in pixels too.
pub fn observed_line(o: &crate::metrics::ObservedMetrics, footprint: Option<f64>) -> String {
    let d = |x: Option<f64>| x.map_or("∞".to_string(), |v| format!("{v:.4}"));
    let pixels = o.chamfer.map_or(String::new(), |c| in_pixels(c, footprint));
    format!(
        "over what the training views observe ({:.1} % of the truth): Chamfer {}{pixels} (accuracy {}, completeness {}), F-score {:.3}{}{}",
        100.0 * o.truth_observed,
        d(o.chamfer),
        d(o.accuracy),
        d(o.completeness),
        o.f_score,
        normals_part(o.normal_consistency),
        o.mesh_floor.map_or(String::new(), |f| format!("; the truth's own mesh: {f:.4}"))
    )
}

/// What observed the scene of a run ([`run_observers`]).
#[derive(Debug, Clone)]
pub struct RunObservers {
    /// The cameras of the training views (normalised frame, [`crate::observation`]).
    pub train_cameras: Vec<camera_geom::PinholeCamera>,
    /// The side of one pixel at the region of interest, the median over all views (normalised
    /// units; as the run's `metrics.json` gives it, [`crate::trainer::Trainer::pixel_footprint`]).
    pub pixel_footprint: Option<f64>,
}

/// The training cameras and the photos' pixel footprint of the run in `dir`. Loads the data;
/// needs no checkpoint.
pub fn run_observers(dir: &Path) -> Result<RunObservers> {
    let (config, record) = read_run_config(dir)?;
    let data = load_run_data(dir, &config, &record, None)?;
    Ok(RunObservers {
        train_cameras: crate::data::ViewSplit::new(&config, &data.scene).train_cameras(&data.scene),
        pixel_footprint: crate::sizing::median_footprint(data.scene.views.iter().map(|v| &v.camera)),
    })
}

/// The data of the run in `dir`: from `repointed` or the recorded path, verified.
fn load_run_data(dir: &Path, config: &TrainConfig, record: &DataRecord, repointed: Option<&Path>) -> Result<SceneData> {
    let path = repointed.or(record.path.as_deref());
    if let Some(p) = path.filter(|p| !p.exists()) {
        bail!(Input, "the data of {} is gone: {} does not exist (give its new place with --data)", dir.display(), p.display());
    }
    let data = SceneData::load(config, path).with_context(|| format!("loading the data of {}", dir.display()))?;
    record.verify(dir, &data.scene, repointed.is_some())?;
    Ok(data)
}

/// The trainer of `config` on `data` at the checkpoint of run folder `dir`.
fn restore_run(dir: &Path, config: TrainConfig, data: SceneData) -> Result<Trainer> {
    restore_checkpoint(&RunModel::Last.checkpoint(dir)?, config, data)
}

/// The trainer of `config` on `data` at the checkpoint `ckpt_path`.
fn restore_checkpoint(ckpt_path: &Path, config: TrainConfig, data: SceneData) -> Result<Trainer> {
    let file = std::fs::File::open(ckpt_path).with_context(|| format!("cannot open {}", ckpt_path.display()))?;
    let len = file.metadata().with_context(|| format!("{}", ckpt_path.display()))?.len();
    let mut input = std::io::BufReader::new(file);
    let reader = CheckpointReader::open(&mut input, len).with_context(|| format!("{} is truncated or corrupt", ckpt_path.display()))?;
    Trainer::from_checkpoint(config, data, &reader, &mut input).with_context(|| format!("restoring {}", ckpt_path.display()))
}

/// Runs `request`: the library's entry point. Everything that can fail on input fails before
/// the run folder is touched, and the memory is checked before anything large is allocated.
pub fn run(request: &RunRequest, options: &RunOptions, stop: &AtomicBool, sink: Arc<dyn Sink>) -> Result<Outcome> {
    PHASE.store(PHASE_TRAINING, Ordering::SeqCst);
    match request {
        RunRequest::Resume { dir, data } => {
            let folder = RunFolder::open(dir, sink)?;
            let (config, mut record) = read_run_config(dir)?;
            let path = data.as_deref().or(record.path.as_deref());
            let estimate = check_memory(&config, &SceneData::size_before_loading(&config, path)?, options.max_memory)?;
            let scene = load_run_data(dir, &config, &record, data.as_deref())?;
            let trainer = restore_run(dir, config, scene)?;
            folder.trim_log(trainer.state().step)?;
            if data.is_some() || record.fingerprint.is_none() {
                // Re-pointed (or of an earlier version): the record now says where the data is.
                record = DataRecord::new(trainer.data().path.as_deref(), trainer.data().description(), &trainer.data().scene)?;
                folder.write_data_record(&record)?;
            }
            run_folder(trainer, &folder, options, stop, &estimate)
        }
        RunRequest::Fresh { config, data, out, overwrite } => {
            // A folder that cannot take the run is refused before the data is loaded.
            RunFolder::check_fresh(out, *overwrite)?;
            // The memory is checked before any pixel is decoded or rendered.
            let estimate = check_memory(config, &SceneData::size_before_loading(config, data.as_deref())?, options.max_memory)?;
            let scene = SceneData::load(config, data.as_deref())?;
            let trainer = Trainer::new((**config).clone(), scene)?;
            let (folder, created) = RunFolder::create(out, *overwrite, sink)?;
            let record = DataRecord::new(trainer.data().path.as_deref(), trainer.data().description(), &trainer.data().scene)?;
            let result = folder
                .write("config.toml", config.to_toml().as_bytes())
                .and_then(|()| folder.write_data_record(&record))
                .and_then(|()| run_folder(trainer, &folder, options, stop, &estimate));
            if result.is_err() && created && !checkpoint_path(out).exists() {
                // Nothing worth keeping was made: leave no stray folder.
                let _ = std::fs::remove_dir_all(out);
            }
            result
        }
    }
}

/// Whether a due validation picture is taken: while the pictures so far took at most `share` of
/// the training time so far (the time a budget counts; `share` = 0: always).
fn pictures_due(picture_seconds: f64, trainer: &Trainer, share: f64) -> bool {
    share == 0.0 || picture_seconds <= share * trainer.state().train_seconds
}

fn run_folder(mut trainer: Trainer, folder: &RunFolder, options: &RunOptions, stop: &AtomicBool, estimate: &MemoryEstimate) -> Result<Outcome> {
    let config = trainer.config().clone();
    let split = trainer.split().clone();
    eprintln!(
        "train: {} · {} sampler · {} views ({} held out) · {} parameters · {} rays × {} samples · {} → {}",
        trainer.data().description(),
        config.sampler.name(),
        trainer.data().scene.views.len(),
        split.held_out.len(),
        trainer.state().params.len(),
        config.render.rays,
        config.render.coarse + config.render.fine,
        config.budget,
        folder.dir().display()
    );
    if let Some(choice) = trainer.grid_choice() {
        eprintln!("model: {}", choice.describe());
    } else if let Some(line) = crate::sizing::describe_preset_grid(&config.model, trainer.pixel_footprint()) {
        eprintln!("model: {line}");
    }
    if config.model.init_radius == crate::config::InitRadius::Auto && trainer.init_radius() < crate::sizing::MAX_INITIAL_RADIUS {
        eprintln!(
            "model.init_radius = auto: {:.3} (without masks, the largest sphere up to {} that leaves every view room around it)",
            trainer.init_radius(),
            crate::sizing::MAX_INITIAL_RADIUS
        );
    }
    if config.model.products == crate::config::Products::Bf16 {
        eprintln!(
            "model.products = bf16: {}",
            if sdf_backbone::kernels::bf16::available() {
                "the hidden-to-hidden layers' products in bf16 (AVX512_BF16)"
            } else {
                "this CPU has no AVX512_BF16, so the products run in f32"
            }
        );
    }
    let progress = Progress::new(&config);
    progress.set(trainer.state().step, trainer.progress(), trainer.seconds_left(), "");
    let mut history = Vec::new();
    let start = Instant::now();
    let mut measured_seconds = 0.0;
    let mut picture_seconds = 0.0;
    let mut snapshots = Snapshots::new(&config.output.snapshots, trainer.state().train_seconds);
    let snapshot_views = final_eval_views(&config, &split);
    while !trainer.done() {
        let first_phase = trainer.sphere_fit().is_none();
        let report = trainer.step()?;
        if let Some(fit) = trainer.sphere_fit().filter(|_| first_phase) {
            eprintln!("{}", fit.describe());
            folder.log(&json!({"step": 0, "sphere_fit": fit}))?;
        }
        log_step(folder, &progress, &trainer, &report)?;
        let step = report.step;
        let stopping = stop.load(Ordering::SeqCst) || options.stop_at == Some(step);
        let periodic = |every: Option<u64>| every.is_some_and(|every| step.is_multiple_of(every)) && !trainer.done();
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
        for at in snapshots.due(trainer.state().train_seconds) {
            let t = Instant::now();
            let record = write_snapshot(&trainer, folder, at, &snapshot_views)?;
            measured_seconds += t.elapsed().as_secs_f64();
            folder.log(&record)?;
        }
        if stopping {
            progress.abandon();
            eprintln!("stopped at step {step}: checkpoint written; continue with `cargo xtask train --resume {}`", folder.dir().display());
            return Ok(Outcome::Stopped { step, out: folder.dir().to_path_buf() });
        }
    }
    progress.finish_phase();
    PHASE.store(PHASE_FINISHING, Ordering::SeqCst);
    let t = Instant::now();
    progress.phase("checkpoint", 0, 1);
    // A run that made no step in this process (resumed after its budget was spent, stopped
    // during meshing) has its checkpoint already.
    if trainer.timing().steps > 0 {
        folder.write_checkpoint(&trainer)?;
    }
    progress.phase("checkpoint", 1, 1);
    let timing = FinishTiming {
        train_wall: start.elapsed().as_secs_f64() - measured_seconds,
        checkpoint: t.elapsed().as_secs_f64(),
        pictures: picture_seconds,
    };
    curves(folder)?;
    let Some(mut summary) = finish(&trainer, folder, &progress, &timing, estimate, stop)? else {
        progress.abandon();
        let step = trainer.state().step;
        eprintln!(
            "stopped after training, at step {step}: the checkpoint is kept; `cargo xtask train --resume {}` writes the mesh and metrics",
            folder.dir().display()
        );
        return Ok(Outcome::Stopped { step, out: folder.dir().to_path_buf() });
    };
    let t = trainer.timing();
    let m = &summary.metrics;
    history.push(json!({"step": trainer.state().step, "chamfer": m.chamfer, "f_score": m.f_score, "psnr": m.psnr, "psnr_masked": m.psnr_masked, "time_s": t.step_seconds + t.grid_seconds}));
    summary.history = history;
    if options.json {
        println!("{}", serde_json::to_string(&summary)?);
    }
    Ok(Outcome::Finished(Box::new(summary)))
}

/// `pictures/curves.png` from the run's log: loss, batch PSNR and s against iterations and
/// against training time, and, when the run logged metrics (`output.metrics_every`,
/// `output.snapshots`), Chamfer and held-out PSNR.
fn curves(folder: &RunFolder) -> Result<()> {
    let text = std::fs::read_to_string(folder.dir().join("log.jsonl")).unwrap_or_default();
    let records: Vec<serde_json::Value> = text.lines().filter_map(|l| serde_json::from_str(l).ok()).collect();
    let steps: Vec<&serde_json::Value> = records.iter().filter(|r| r["loss"].is_number()).collect();
    let evals: Vec<&serde_json::Value> = records.iter().filter(|r| r["eval"] == true || r["snapshot"].is_number()).collect();
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

/// The validation panel of the first held-out view (or view 0) and the guide's pdf heat map;
/// where the view has a mask, the split between object and backdrop is logged
/// (`{"split": …}`, [`crate::trainer::SplitStats`]).
fn validation_pictures(trainer: &Trainer, folder: &RunFolder, step: u64) -> Result<()> {
    let view = trainer.split().evaluation_views()[0];
    let render = trainer.render_view(view, trainer.config().output.validate_downscale)?;
    folder.write_png(&format!("pictures/val_{step:06}.png"), &render.panel())?;
    if let Some(map) = trainer.pdf_heat_map(view) {
        folder.write_png(&format!("pictures/pdf_{step:06}.png"), &map)?;
    }
    if let Some(split) = trainer.split_stats(&render, view) {
        folder.log(&json!({"step": step, "split": split}))?;
    }
    Ok(())
}

/// Chamfer (and per part of an analytic truth) of the current mesh and PSNR of the first held-out
/// view (not counted as training).
fn interim_metrics(trainer: &Trainer) -> Result<serde_json::Value> {
    let config = trainer.config();
    let view = trainer.split().evaluation_views()[0];
    let (psnr, masked) = trainer.render_view(view, config.output.eval_downscale)?.psnr();
    let mesh = trainer.extract_mesh(&|_, _| {})?;
    let geometry = run_geometry(trainer.data(), &config.output, &mesh, None, &[])?;
    let t = trainer.timing();
    Ok(json!({"eval": true, "step": trainer.state().step, "psnr": psnr, "psnr_masked": masked,
        "chamfer": geometry.as_ref().map(|g| g.metrics.chamfer), "f_score": geometry.as_ref().map(|g| g.metrics.f_score),
        "parts": geometry.map(|g| g.parts).unwrap_or_default(), "time_s": t.step_seconds + t.grid_seconds}))
}

#[cfg(test)]
mod tests {
    use super::in_pixels;

    #[test]
    fn a_distance_reads_in_the_photos_pixels_only_where_a_footprint_exists() {
        assert_eq!(in_pixels(0.0034, Some(0.00525)), ", 0.65 px");
        assert_eq!(in_pixels(0.0105, Some(0.00525)), ", 2.00 px");
        for footprint in [None, Some(0.0), Some(-1.0)] {
            assert_eq!(in_pixels(0.0034, footprint), "");
        }
        assert_eq!(in_pixels(f64::INFINITY, Some(0.00525)), "");
    }
}
