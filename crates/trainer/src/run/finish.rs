//! The end of a run: final pictures, the image metrics, the mesh files, the geometry against
//! the truth, `metrics.json` and the summary printed — each step skipped once a stop is asked
//! (the checkpoint is kept, `--resume` finishes).

use super::{RunSummary, validation_pictures};
use crate::config::TrainConfig;
use crate::data::ViewSplit;
use crate::error::Result;
use crate::folder::RunFolder;
use crate::memory::{self, MemoryEstimate};
use crate::metrics::{RunMetrics, ViewPsnr};
use crate::outputs::{RunGeometry, mesh_files, mesh_picture, mesh_picture_downscale, run_geometry};
use crate::progress::Progress;
use crate::trainer::Trainer;
use prob_grid::IsoMesh;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// The mean, `None` for no values.
fn mean(values: impl Iterator<Item = f64>) -> Option<f64> {
    let v: Vec<f64> = values.collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// The views of the final PSNR: `output.eval_views` spread over the held-out views (all views
/// when none is held out).
pub(super) fn final_eval_views(config: &TrainConfig, split: &ViewSplit) -> Vec<usize> {
    let candidates = split.evaluation_views();
    let every = candidates.len().div_ceil(config.output.eval_views.max(1));
    candidates.iter().copied().step_by(every.max(1)).collect()
}

/// Times of the training loop and its side work, for the metrics.
pub(super) struct FinishTiming {
    pub(super) train_wall: f64,
    pub(super) checkpoint: f64,
    pub(super) pictures: f64,
}

/// A view's (PSNR, masked PSNR, SSIM).
type ViewMetrics = (f64, Option<f64>, Option<f64>);

/// The final image metrics: on the evaluation views and on some training views.
struct Images {
    eval_views: Vec<usize>,
    held: Vec<ViewMetrics>,
    fit_views: Vec<usize>,
    fit: Vec<ViewMetrics>,
    seconds: f64,
}

/// The final mesh, as written.
struct Mesh {
    mesh: IsoMesh,
    components: usize,
    kept: usize,
    files: Vec<String>,
    seconds: f64,
}

/// Final pictures, mesh, metrics and summary; `None` when `stop` was set on the way (nothing
/// more is written then: the checkpoint is kept).
pub(super) fn finish(
    trainer: &Trainer,
    folder: &RunFolder,
    progress: &Progress,
    times: &FinishTiming,
    estimate: &MemoryEstimate,
    stop: &AtomicBool,
) -> Result<Option<RunSummary>> {
    let stopped = || stop.load(Ordering::SeqCst);
    // Each phase's scratch buffers differ in size: the resident size is the largest phase's.
    sdf_backbone::scratch::release_all();
    validation_pictures(trainer, folder, trainer.state().step)?;
    // `final_images` empties the pool after each view.
    let Some(images) = final_images(trainer, progress, &stopped)? else { return Ok(None) };
    if stopped() {
        return Ok(None);
    }
    let Some(mesh) = final_mesh(trainer, folder, progress, images.eval_views[0], &stopped)? else { return Ok(None) };
    let t = Instant::now();
    let geometry = run_geometry(trainer.data(), &trainer.config().output, &mesh.mesh, Some(trainer.mesh_resolution()), &trainer.train_cameras())?;
    let geometry_seconds = t.elapsed().as_secs_f64();
    progress.finish_phase();
    let metrics = run_metrics(trainer, times, estimate, &images, &mesh, geometry, geometry_seconds);
    folder.write("metrics.json", serde_json::to_string_pretty(&metrics)?.as_bytes())?;
    print_summary(&metrics, &images, &mesh);
    Ok(Some(RunSummary { out: folder.dir().display().to_string(), meshes: mesh.files, metrics, history: Vec::new() }))
}

/// Writes `mesh` (normalised frame) in the run's world as `{stem}.{extension}` for each of
/// `output.mesh_formats`, with vertex colours when `output.vertex_colors` asks; the paths written.
pub(super) fn write_meshes(trainer: &Trainer, folder: &RunFolder, mesh: &IsoMesh, stem: &str) -> Result<Vec<String>> {
    let output = &trainer.config().output;
    let colors = output.vertex_colors.then(|| trainer.vertex_colors(mesh));
    let mut files = Vec::new();
    for (format, bytes) in mesh_files(mesh, &trainer.data().scene.world_from_normalized, colors.as_deref(), &output.mesh_formats) {
        let name = format!("{stem}.{}", format.extension());
        folder.write(&name, &bytes)?;
        files.push(folder.dir().join(name).display().to_string());
    }
    Ok(files)
}

/// Image metrics on the evaluation views (the held-out ones, all views when none are held out)
/// and on `output.eval_train_views` training views; `None` when stopped on the way.
fn final_images(trainer: &Trainer, progress: &Progress, stopped: &dyn Fn() -> bool) -> Result<Option<Images>> {
    let (config, split) = (trainer.config(), trainer.split());
    let eval_views = final_eval_views(config, split);
    let fit_every = split.train.len().div_ceil(config.output.eval_train_views.max(1));
    let fit_views: Vec<usize> =
        if config.output.eval_train_views == 0 { Vec::new() } else { split.train.iter().copied().step_by(fit_every.max(1)).collect() };
    let t = Instant::now();
    let n_renders = eval_views.len() + fit_views.len();
    let (mut held, mut fit) = (Vec::new(), Vec::new());
    for (i, &v) in eval_views.iter().chain(&fit_views).enumerate() {
        if stopped() {
            return Ok(None);
        }
        let metrics = trainer.view_metrics(v, config.output.eval_downscale)?;
        // A view's work items leave buffers of many sizes in the pool: emptied after each view,
        // the resident size is one view's, not the views' together (measured at 1600 × 1200).
        sdf_backbone::scratch::release_all();
        progress.phase("eval", i + 1, n_renders);
        if i < eval_views.len() { held.push(metrics) } else { fit.push(metrics) }
    }
    Ok(Some(Images { eval_views, held, fit_views, fit, seconds: t.elapsed().as_secs_f64() }))
}

/// The mesh, its files (`output.mesh_formats`) and its picture from `picture_view` and a
/// training view; `None` when stopped during meshing.
fn final_mesh(trainer: &Trainer, folder: &RunFolder, progress: &Progress, picture_view: usize, stopped: &dyn Fn() -> bool) -> Result<Option<Mesh>> {
    let (scene, split) = (&trainer.data().scene, trainer.split());
    let t = Instant::now();
    let (mesh, components, kept) = trainer.extract_mesh_with_stats(&|done, total| progress.phase("mesh", done, total))?;
    if stopped() {
        return Ok(None);
    }
    let files = write_meshes(trainer, folder, &mesh, "mesh")?;
    if !mesh.triangles.is_empty() {
        let views = [picture_view, split.train[split.train.len() / 2]];
        let cams =
            views.iter().map(|&v| trainer.downscaled_camera(v, mesh_picture_downscale(scene.views[v].camera.width))).collect::<Result<Vec<_>>>()?;
        folder.write_png("pictures/mesh.png", &mesh_picture(&mesh, &cams))?;
    }
    Ok(Some(Mesh { mesh, components, kept, files, seconds: t.elapsed().as_secs_f64() }))
}

/// `metrics.json` of a finished run.
fn run_metrics(
    trainer: &Trainer,
    times: &FinishTiming,
    estimate: &MemoryEstimate,
    images: &Images,
    mesh: &Mesh,
    geometry: Option<RunGeometry>,
    geometry_seconds: f64,
) -> RunMetrics {
    let config = trainer.config();
    let world_scale = trainer.data().scene.world_from_normalized.determinant().abs().cbrt();
    let timing = trainer.timing();
    let per_step = |x: f64| x / timing.steps.max(1) as f64;
    let (held, fit) = (&images.held, &images.fit);
    let g = geometry.as_ref().map(|g| g.metrics);
    RunMetrics {
        sampler: config.sampler,
        steps: trainer.state().step,
        time_budget_s: config.budget.time_s(),
        psnr: mean(held.iter().map(|p| p.0)),
        psnr_masked: mean(held.iter().filter_map(|p| p.1)),
        ssim: mean(held.iter().filter_map(|p| p.2)),
        psnr_views: images.eval_views.clone(),
        psnr_held_out: !trainer.split().held_out.is_empty(),
        psnr_train: mean(fit.iter().map(|p| p.0)),
        psnr_train_masked: mean(fit.iter().filter_map(|p| p.1)),
        psnr_train_views: images.fit_views.clone(),
        psnr_per_view: held.iter().map(|p| ViewPsnr { whole: p.0, masked: p.1 }).collect(),
        chamfer: g.map(|g| g.chamfer),
        chamfer_world: g.map(|g| g.chamfer * world_scale),
        accuracy: g.map(|g| g.accuracy),
        completeness: g.map(|g| g.completeness),
        f_score: g.map(|g| g.f_score),
        f_score_tau: config.output.fscore_tau,
        normal_consistency: geometry.as_ref().and_then(|g| g.normal_consistency),
        parts: geometry.as_ref().map(|g| g.parts.clone()).unwrap_or_default(),
        world_scale,
        pixel_footprint: trainer.pixel_footprint(),
        mesh_resolution: trainer.mesh_resolution(),
        mesh_floor: geometry.as_ref().and_then(|g| g.floor),
        observed: geometry.as_ref().and_then(|g| g.observed.clone()),
        mesh_vertices: mesh.mesh.vertices.len(),
        mesh_triangles: mesh.mesh.triangles.len(),
        mesh_components: mesh.components,
        mesh_components_kept: mesh.kept,
        train_s: trainer.state().train_seconds,
        train_wall_s: times.train_wall,
        step_s: per_step(timing.step_seconds),
        iteration_s: per_step(timing.step_seconds + timing.grid_seconds),
        rays_s: per_step(timing.ray_seconds),
        grid_s: timing.grid_seconds,
        grid_updates: timing.grid_updates,
        eval_s: images.seconds,
        mesh_s: mesh.seconds,
        geometry_s: geometry_seconds,
        checkpoint_s: times.checkpoint,
        validation_s: times.pictures,
        threads: rayon::current_num_threads(),
        memory_estimate_bytes: estimate.peak(),
        peak_rss_bytes: memory::peak_rss_bytes(),
    }
}

/// The two lines a finished run prints: time and mesh, then PSNR and geometry.
fn print_summary(m: &RunMetrics, images: &Images, mesh: &Mesh) {
    eprintln!(
        "done in {:.0} s ({:.3} s/iteration, {} iterations). mesh: {} ({} triangles, {} of {} components)",
        m.train_s,
        m.iteration_s,
        m.steps,
        mesh.files.first().map_or("-", String::as_str),
        m.mesh_triangles,
        m.mesh_components_kept,
        m.mesh_components
    );
    let geometry = match (m.chamfer, m.f_score) {
        (Some(chamfer), Some(f_score)) => format!(
            "Chamfer {chamfer:.4} ({:.4} in world units{}{}), F-score {f_score:.3} at τ = {}{}",
            chamfer * m.world_scale,
            crate::run::in_pixels(chamfer, m.pixel_footprint),
            m.mesh_floor.map_or(String::new(), |f| format!("; the truth's own {}³ mesh: {f:.4}", m.mesh_resolution)),
            m.f_score_tau,
            crate::run::normals_part(m.normal_consistency)
        ),
        _ if mesh.mesh.triangles.is_empty() => "the mesh is empty: no Chamfer".into(),
        _ => "no ground truth for Chamfer".into(),
    };
    eprintln!(
        "PSNR {} on {} {} view(s){}; {geometry}",
        match (m.psnr, m.psnr_masked) {
            (Some(p), Some(masked)) => format!("{p:.2} dB (masked {masked:.2} dB)"),
            (Some(p), None) => format!("{p:.2} dB"),
            _ => "-".into(),
        },
        images.eval_views.len(),
        if m.psnr_held_out { "held-out" } else { "training (none held out)" },
        m.psnr_train.map_or(String::new(), |p| format!(", {p:.2} dB on {} training view(s)", images.fit_views.len())),
    );
    if let Some(o) = &m.observed {
        eprintln!("{}", crate::run::observed_line(o, m.pixel_footprint));
    }
    if !m.parts.is_empty() {
        let parts: Vec<String> = m.parts.iter().map(|p| format!("{} {:.2}", p.part, p.recall)).collect();
        eprintln!("the truth's points within τ of the mesh, per part: {}", parts.join(", "));
    }
}
