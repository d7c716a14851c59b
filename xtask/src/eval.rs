//! `cargo xtask eval`: a mesh against ground truth (DTU-protocol Chamfer, F-score), or a run's
//! held-out views (PSNR whole and masked, SSIM).

use anyhow::{Context, Result, bail};
use datasets::io::{PlyData, write_atomic};
use datasets::{LoadOptions, load_scene};
use serde_json::json;
use std::num::NonZeroUsize;
use std::path::{Path, PathBuf};
use trainer::evaluation::{Distances, GroundTruth, PRED_SAMPLING_SEED, Protocol, read_mesh};
use trainer::outputs::dilate;
use trainer::run::{RunModel, open_run_model};

/// A built-in analytic shape by name.
fn shape_by_name(name: &str) -> std::result::Result<prob_grid::Shape, String> {
    prob_grid::ShapeName::from_name(name).map(prob_grid::ShapeName::shape)
}

/// A positive finite number (the evaluation's distances).
fn positive(text: &str) -> Result<f64> {
    let v: f64 = text.trim().parse().with_context(|| format!("{text:?} is not a number"))?;
    if !(v.is_finite() && v > 0.0) {
        bail!("{text:?}: expected a positive distance");
    }
    Ok(v)
}

/// Options of `cargo xtask eval`.
#[derive(clap::Args, Debug)]
pub struct EvalArgs {
    /// The mesh to evaluate (.ply, .obj, .gltf, .glb), in the data's world units.
    #[arg(long, required_unless_present = "run")]
    pub mesh: Option<PathBuf>,
    /// Ground-truth points (.ply).
    #[arg(long, conflicts_with_all = ["gt_mesh", "run"])]
    pub gt_points: Option<PathBuf>,
    /// An analytic ground truth, a built-in shape by name (composite, multipart, sphere, torus,
    /// box; the built-in scenes' normalised frame), sampled at the protocol's spacing.
    #[arg(long, value_parser = shape_by_name, conflicts_with_all = ["gt_points", "gt_mesh", "data", "run"])]
    pub gt_shape: Option<prob_grid::Shape>,
    /// With --gt-shape: also measure the shape's own marching-cubes mesh at this resolution
    /// (cells per side of the bound's cube) by the same protocol — the floor a mesh of that
    /// resolution cannot beat.
    #[arg(long, requires = "gt_shape", value_parser = clap::value_parser!(u32).range(8..=2048))]
    pub floor_resolution: Option<u32>,
    /// With --gt-shape: also measure over what the training views of this run folder observe
    /// (the DTU evaluation's observation mask): the truth's points no training view sees and the
    /// mesh's points nearest them are left out.
    #[arg(long, requires = "gt_shape")]
    pub observed_by: Option<PathBuf>,
    /// Ground-truth mesh (sampled at the same density as the prediction).
    #[arg(long, conflicts_with = "run")]
    pub gt_mesh: Option<PathBuf>,
    /// A data folder with gt_mesh.ply or gt_points.ply (golden scenes); with --cull its masks.
    /// With --run: the run's data at a new place (checked against the run's fingerprint of it).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// A run folder: PSNR/SSIM of its model on its held-out views.
    #[arg(long)]
    pub run: Option<PathBuf>,
    /// Sampling spacing on meshes (world units; DTU: 0.2 mm). Default: GT diagonal / 1000.
    #[arg(long, value_parser = positive, conflicts_with = "run")]
    pub spacing: Option<f64>,
    /// Outlier distance (DTU: 20 mm). Default: GT diagonal / 20.
    #[arg(long, value_parser = positive, conflicts_with = "run")]
    pub max_dist: Option<f64>,
    /// F-score threshold τ. Default: GT diagonal / 200.
    #[arg(long, value_parser = positive, conflicts_with = "run")]
    pub tau: Option<f64>,
    /// NeuralWarp-style culling: keep predicted points inside the masks (dilated by
    /// `--dilate` pixels) of at least two views of --data.
    #[arg(long, requires = "data", conflicts_with = "run")]
    pub cull: bool,
    /// The mesh was made in the world of this dataset folder (e.g. imported from COLMAP): it is
    /// carried into --data's world by the similarity that best maps this folder's camera
    /// centres onto --data's (views matched in order).
    #[arg(long, requires = "data", conflicts_with = "run")]
    pub mesh_cameras: Option<PathBuf>,
    /// Refine the mesh's placement by similarity ICP of its surface samples onto the ground
    /// truth before measuring (thresholds max distance → √(max distance · τ) → 2τ), as the
    /// Tanks and Temples evaluation does after its trajectory alignment: for meshes made with
    /// estimated cameras (--mesh-cameras), whose alignment by camera centres carries the camera
    /// solver's error. The unrefined figures are reported too.
    #[arg(long, conflicts_with = "run")]
    pub icp: bool,
    /// Mask dilation in pixels for --cull.
    #[arg(long, default_value_t = 12)]
    pub dilate: u32,
    /// Image downscale for --run renders (default: the run's `output.eval_downscale`).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    pub downscale: Option<u32>,
    /// Up-sampled samples per ray of the --run renders (default: the run's `render.render_fine`).
    #[arg(long, requires = "run")]
    pub render_fine: Option<usize>,
    /// Up-sampling rounds of the --run renders (default: the run's `render.render_upsample_rounds`).
    #[arg(long, requires = "run")]
    pub render_rounds: Option<usize>,
    /// Weight a --run render may drop on each side of a ray (default: the run's
    /// `render.render_trim`; 0 renders every sample).
    #[arg(long, requires = "run")]
    pub render_trim: Option<f64>,
    /// Weight above which no interval of a --run render's ray may be for its up-sampling to stop
    /// after the first round (default: the run's `render.render_resolved`; 0: every round; with
    /// a trim of 0 every ray takes every round).
    #[arg(long, requires = "run")]
    pub render_resolved: Option<f64>,
    /// Whether --run renders skip empty space (default: the run's `render.render_skip_empty`).
    #[arg(long, requires = "run")]
    pub render_skip_empty: Option<bool>,
    /// Colour stride of the --run renders: the colour networks on every k-th kept interval of
    /// a ray, the others interpolated (default: the run's `render.render_colour_stride`; 1:
    /// every interval).
    #[arg(long, requires = "run")]
    pub render_colour_stride: Option<NonZeroUsize>,
    /// With --run: mesh the run's model again at this resolution (cells per side of the bound's
    /// cube, 8 … 2048, or `model`: its finest cell) instead of rendering its views — `mesh-N.*`
    /// and `mesh-N.json` in the run folder, the geometry against the run's truth by its protocol
    /// with the truth's own mesh at N (the floor); the run's own mesh is left as it is.
    #[arg(long, requires = "run", value_parser = str::parse::<trainer::config::MeshResolution>, conflicts_with_all = ["downscale", "render_fine", "render_rounds", "render_trim", "render_resolved", "render_skip_empty", "render_colour_stride", "profile"])]
    pub mesh_resolution: Option<trainer::config::MeshResolution>,
    /// With --run: the model the snapshot at this training time kept (`snapshots/<seconds>s/`,
    /// e.g. 6m or 360) instead of the run's last one; what is made from it (eval.json, mesh-N.*)
    /// goes into the snapshot's folder.
    #[arg(long, requires = "run", value_parser = trainer::config::parse_duration)]
    pub snapshot: Option<std::time::Duration>,
    /// With --run: where the renders' CPU time goes, by stage (up-sampling, the forward pass,
    /// the modules inside them).
    #[arg(long, requires = "run")]
    pub profile: bool,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// The camera centres of a dataset folder in its world units, in view order.
fn centres_in_world(dir: &Path) -> Result<Vec<[f64; 3]>> {
    let cams = datasets::read_cameras(dir, &LoadOptions::default()).with_context(|| format!("reading the cameras of {}", dir.display()))?;
    Ok(cams.records.iter().map(|r| cams.world_from_normalized.transform_point3(r.camera.center_in_world()).to_array()).collect())
}

/// The similarity from `from`'s world to `to`'s by their camera centres, and the RMS residual.
fn camera_alignment(from: &Path, to: &Path) -> Result<(eval_metrics::align::Similarity, f64)> {
    let (a, b) = (centres_in_world(from)?, centres_in_world(to)?);
    if a.len() != b.len() {
        bail!("{} has {} views and {} has {}: views are matched in order", from.display(), a.len(), to.display(), b.len());
    }
    let s = eval_metrics::align::similarity(&a, &b).with_context(|| format!("the cameras of {} do not determine a similarity", from.display()))?;
    let rms = (a.iter().zip(&b).map(|(p, q)| (0..3).map(|i| (s.apply(*p)[i] - q[i]).powi(2)).sum::<f64>()).sum::<f64>() / a.len() as f64).sqrt();
    // The rig's size: RMS distance of --data's centres from their mean.
    let mean: [f64; 3] = std::array::from_fn(|i| b.iter().map(|q| q[i]).sum::<f64>() / b.len() as f64);
    let size = (b.iter().map(|q| (0..3).map(|i| (q[i] - mean[i]).powi(2)).sum::<f64>()).sum::<f64>() / b.len() as f64).sqrt();
    if !(rms <= 0.05 * size) {
        bail!(
            "the camera centres of {} and {} do not match up to a similarity (residual {rms:.4} against a rig of size {size:.4}): are the views in the same order?",
            from.display(),
            to.display()
        );
    }
    Ok((s, rms))
}

/// Runs `cargo xtask eval`.
pub fn run(args: &EvalArgs) -> Result<()> {
    if let Some(dir) = &args.run {
        let model = args.snapshot.map_or(RunModel::Last, |at| RunModel::snapshot_near(dir, at.as_secs_f64()));
        return match args.mesh_resolution {
            Some(resolution) => remesh_run(dir, args.data.as_deref(), model, resolution, args.json),
            None => eval_run(dir, model, args),
        };
    }
    let mesh_path = args.mesh.as_ref().context("--mesh is required")?;
    let (mut vertices, triangles) = read_mesh(mesh_path).with_context(|| format!("reading the mesh {}", mesh_path.display()))?;
    if triangles.is_empty() {
        bail!("the mesh {} has no triangles", mesh_path.display());
    }
    let mut alignment = serde_json::Value::Null;
    if let (Some(from), Some(to)) = (&args.mesh_cameras, &args.data) {
        let (similarity, rms) = camera_alignment(from, to)?;
        for v in &mut vertices {
            *v = similarity.apply(v.map(f64::from)).map(|c| c as f32);
        }
        alignment = json!({"from": from.display().to_string(), "scale": similarity.scale, "centre_rms": rms});
        if !args.json {
            println!(
                "aligned by the camera centres of {} → {}: scale {:.6}, centre residual {:.5} (RMS, --data units)",
                from.display(),
                to.display(),
                similarity.scale,
                rms
            );
        }
    }
    // Ground truth: points, or a mesh to sample.
    let gt_mesh = args.gt_mesh.clone().or_else(|| args.data.as_ref().map(|d| d.join("gt_mesh.ply")).filter(|p| p.exists()));
    let gt_points_path = args.gt_points.clone().or_else(|| args.data.as_ref().map(|d| d.join("gt_points.ply")).filter(|p| p.exists()));
    let (gt, gt_name) = match (&args.gt_shape, &gt_mesh, &gt_points_path) {
        (Some(shape), _, _) => (GroundTruth::Shape(shape.clone()), "the analytic shape".to_string()),
        (None, Some(m), _) => {
            (GroundTruth::Mesh(read_mesh(m).with_context(|| format!("reading the ground-truth mesh {}", m.display()))?), m.display().to_string())
        }
        (None, None, Some(p)) => {
            let ply = PlyData::read(p).with_context(|| format!("reading the ground-truth points {}", p.display()))?;
            (GroundTruth::Points(ply.positions.iter().map(|p| p.to_array()).collect()), p.display().to_string())
        }
        (None, None, None) => bail!("no ground truth: give --gt-points, --gt-mesh, --gt-shape, or --data with gt_mesh.ply / gt_points.ply"),
    };
    let protocol = Protocol { spacing: args.spacing, max_dist: args.max_dist, tau: args.tau };
    let Distances { spacing, max_dist, tau } = gt.distances(protocol, &gt_name)?;
    let truth = gt.into_truth(spacing)?;
    let gt = &truth.points;
    let floor = match (&args.gt_shape, args.floor_resolution) {
        (Some(shape), Some(resolution)) => Some(trainer::outputs::shape_floor(shape, gt, resolution, spacing)?),
        _ => None,
    };
    let mut oriented = eval_metrics::sample_mesh_oriented(&vertices, &triangles, spacing, PRED_SAMPLING_SEED)
        .with_context(|| format!("the mesh {}", args.mesh.as_ref().map_or(String::new(), |m| m.display().to_string())))?;
    let before = oriented.points.len();
    if args.cull {
        let dir = args.data.as_ref().expect("clap: --cull requires --data");
        let scene = load_scene(dir, &LoadOptions::default()).with_context(|| format!("loading {} for culling", dir.display()))?;
        let normalized_from_world = scene.world_from_normalized.inverse();
        let masks: Vec<_> = scene.views.iter().filter_map(|v| v.mask.as_ref().map(|m| (v.camera, dilate(m, args.dilate)))).collect();
        if masks.len() < 2 {
            bail!("--cull needs masks for at least two views in {}", dir.display());
        }
        oriented = oriented.culled(|p| {
            let x = normalized_from_world.transform_point3(glam::DVec3::from_array(p.map(f64::from)));
            masks
                .iter()
                .filter(|(cam, m)| {
                    cam.pixel_space_from_world(x).z > 0.0
                        && cam.nearest_pixel(cam.pixel_space_from_world(x).truncate()).is_some_and(|(c, r)| m.get(c, r))
                })
                .count()
                >= 2
        });
    }
    let mut icp = serde_json::Value::Null;
    if args.icp {
        let pred = &oriented.points;
        let unrefined = eval_metrics::chamfer(pred, gt, max_dist, tau)?;
        let gt_cloud = eval_metrics::PointCloud::new(gt)?;
        let thresholds = [max_dist, (max_dist * tau).sqrt(), 2.0 * tau];
        let r = eval_metrics::align::refine_icp(pred, &gt_cloud, gt, eval_metrics::align::Similarity::IDENTITY, &thresholds, 200_000)
            .with_context(|| format!("ICP found too few matches between {} and the ground truth (within {max_dist:.4})", mesh_path.display()))?;
        oriented = oriented.moved(&r.similarity);
        let rot = &r.similarity.rotation;
        let degrees = ((rot[0][0] + rot[1][1] + rot[2][2] - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees();
        let shift = r.similarity.translation.iter().map(|t| t * t).sum::<f64>().sqrt();
        icp = json!({
            "scale": r.similarity.scale, "rotation_deg": degrees, "translation": shift, "iterations": r.iterations,
            "pair_rms_before": r.rms_before, "pair_rms_after": r.rms_after, "pairs": r.pairs,
            "chamfer_before": unrefined.chamfer, "f_score_before": unrefined.f_score,
        });
        if !args.json {
            println!(
                "ICP refinement: scale {:.5}, rotation {degrees:.3}°, translation {shift:.5} in {} iterations (before it: Chamfer {:.5}, F-score {:.4})",
                r.similarity.scale, r.iterations, unrefined.chamfer, unrefined.f_score
            );
        }
    }
    let pred = &oriented.points;
    let nearest = eval_metrics::Nearest::new(pred, gt)?;
    let m = nearest.chamfer(max_dist, tau);
    let normals = trainer::outputs::normal_pairs(&oriented, &truth);
    let normal_consistency = trainer::outputs::normal_consistency(&nearest, normals, max_dist, None)?;
    let (observed, pixel_footprint) = match (&args.gt_shape, &args.observed_by) {
        (Some(shape), Some(run)) => {
            let observers = trainer::run::run_observers(run)?;
            let measured =
                trainer::outputs::observed_metrics(shape, &observers.train_cameras, gt, &nearest, (max_dist, tau), floor.as_ref(), normals);
            (Some(measured.with_context(|| format!("over what the training views of {} observe", run.display()))?), observers.pixel_footprint)
        }
        _ => (None, None),
    };
    let parts = match &args.gt_shape {
        Some(shape) => trainer::outputs::part_metrics(shape, pred, gt, &nearest, max_dist, tau),
        None => Vec::new(),
    };
    let floor = floor.map(|f| f.chamfer(max_dist, tau).chamfer);
    let result = json!({
        "mesh": mesh_path.display().to_string(),
        "chamfer": m.chamfer, "accuracy": m.accuracy, "completeness": m.completeness,
        "precision": m.precision, "recall": m.recall, "f_score": m.f_score, "tau": tau, "normal_consistency": normal_consistency,
        "spacing": spacing, "max_dist": max_dist, "pred_points": m.n_pred, "culled": before - pred.len(), "gt_points": m.n_gt,
        "alignment": alignment, "icp": icp, "floor": floor, "floor_resolution": args.floor_resolution,
        "parts": parts, "observed": observed, "pixel_footprint": pixel_footprint,
    });
    if args.json {
        println!("{result}");
    } else {
        println!(
            "Chamfer {:.5} (accuracy {:.5}, completeness {:.5}), F-score {:.4} at τ = {tau:.4} (P {:.3}, R {:.3}){}; {} / {} points, spacing {spacing:.4}, max distance {max_dist:.4}",
            m.chamfer,
            m.accuracy,
            m.completeness,
            m.f_score,
            m.precision,
            m.recall,
            trainer::run::normals_part(normal_consistency),
            m.n_pred,
            m.n_gt
        );
        if let (Some(floor), Some(resolution)) = (floor, args.floor_resolution) {
            println!("the shape's own {resolution}³ marching-cubes mesh by the same protocol: Chamfer {floor:.5}");
        }
        if let Some(o) = &observed {
            println!("{}", trainer::run::observed_line(o, pixel_footprint));
        }
        for p in &parts {
            let d = |x: Option<f64>| x.map_or("-".to_string(), |c| format!("{c:.5}"));
            println!("part {}: completeness {}, recall {:.3}, accuracy {}", p.part, d(p.completeness), p.recall, d(p.accuracy));
        }
    }
    Ok(())
}

fn eval_run(dir: &Path, model: RunModel, args: &EvalArgs) -> Result<()> {
    // It writes eval.json into the run folder: not while another process trains there.
    let _lock = trainer::folder::is_run_folder(dir).then(|| trainer::folder::FolderLock::acquire(dir)).transpose()?;
    let mut trainer = open_run_model(dir, args.data.as_deref(), model)?;
    trainer.set_render_sampling(|r| {
        r.render_fine = args.render_fine.unwrap_or(r.render_fine);
        r.render_upsample_rounds = args.render_rounds.unwrap_or(r.render_upsample_rounds);
        r.render_trim = args.render_trim.unwrap_or(r.render_trim);
        r.render_resolved = args.render_resolved.map_or(r.render_resolved, |most| (most != 0.0).then_some(most));
        r.render_skip_empty = args.render_skip_empty.unwrap_or(r.render_skip_empty);
        r.render_colour_stride = args.render_colour_stride.unwrap_or(r.render_colour_stride);
    })?;
    let downscale = args.downscale.unwrap_or(trainer.config().output.eval_downscale);
    let views = trainer.split().evaluation_views();
    sdf_backbone::profile::take();
    sdf_backbone::profile::enable(args.profile);
    let started = std::time::Instant::now();
    let metrics = views.iter().map(|&v| trainer.view_metrics(v, downscale)).collect::<trainer::Result<Vec<_>>>()?;
    let seconds = started.elapsed().as_secs_f64();
    sdf_backbone::profile::enable(false);
    if args.profile {
        print_render_profile(seconds);
    }
    let pixels: u64 = views
        .iter()
        .map(|&v| {
            let c = &trainer.data().scene.views[v].camera;
            u64::from(c.width / downscale) * u64::from(c.height / downscale)
        })
        .sum();
    let mut per_view = Vec::new();
    for (&v, (whole, masked, ssim)) in views.iter().zip(&metrics) {
        per_view.push(json!({"view": v, "psnr": whole, "psnr_masked": masked, "ssim": ssim}));
        if !args.json {
            println!("view {v}: PSNR {whole:.2} dB{}", masked.map_or(String::new(), |m| format!(", masked {m:.2} dB")));
        }
    }
    let mean = |key: &str| {
        let v: Vec<f64> = per_view.iter().filter_map(|p| p[key].as_f64()).collect();
        (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
    };
    let r = &trainer.config().render;
    let result = json!({"run": dir.display().to_string(), "snapshot": model.snapshot(), "step": trainer.state().step, "views": views, "psnr": mean("psnr"),
        "psnr_masked": mean("psnr_masked"), "ssim": mean("ssim"), "per_view": per_view, "downscale": downscale,
        "render_fine": r.render_fine, "render_upsample_rounds": r.render_upsample_rounds, "render_trim": r.render_trim, "render_resolved": r.resolved_applied().unwrap_or(0.0),
        "render_skip_empty": r.render_skip_empty, "render_colour_stride": r.render_colour_stride, "seconds": seconds, "pixels_per_s": pixels as f64 / seconds});
    // A speed figure: it names the machine.
    let result = crate::machine::tag(result);
    let written = model.dir(dir).join("eval.json");
    write_atomic(&written, serde_json::to_string_pretty(&result)?.as_bytes())?;
    if args.json {
        println!("{result}");
    } else {
        println!(
            "mean over {} {} views: PSNR {:.2} dB, masked {:?}, SSIM {:?}; {pixels} pixels rendered in {seconds:.1} s ({:.0} pixels/s on {}) (written to {})",
            views.len(),
            if trainer.split().held_out.is_empty() { "training (none held out)" } else { "held-out" },
            mean("psnr").unwrap_or(f64::NAN),
            mean("psnr_masked"),
            mean("ssim"),
            pixels as f64 / seconds,
            crate::machine::Machine::this().line(),
            written.display()
        );
    }
    Ok(())
}

/// `eval --run DIR --mesh-resolution N [--snapshot T]`: the run's model (or a snapshot's) meshed
/// at N and measured.
fn remesh_run(dir: &Path, data: Option<&Path>, model: RunModel, resolution: trainer::config::MeshResolution, json: bool) -> Result<()> {
    let folder = trainer::run::RunFolder::open(dir, std::sync::Arc::new(trainer::run::AtomicFiles))?;
    let progress = |done: usize, total: usize| {
        if !json && (done == total || done.is_multiple_of(256)) {
            eprintln!("mesh {done}/{total} blocks");
        }
    };
    let remeshed = trainer::run::remesh(&folder, data, model, resolution, &progress)?;
    // A time figure: it names the machine.
    let result = crate::machine::tag(serde_json::to_value(&remeshed)?);
    let name = format!("mesh-{}.json", remeshed.mesh_resolution);
    let name = model.sub_dir().map_or(name.clone(), |sub| format!("{sub}/{name}"));
    folder.write(&name, serde_json::to_string_pretty(&result)?.as_bytes())?;
    if json {
        println!("{result}");
        return Ok(());
    }
    println!(
        "{}step {}: meshed at {}³ in {:.1} s on {} ({} triangles, {} of {} components): {}",
        remeshed.snapshot.map_or(String::new(), |at| format!("the snapshot at {at} s, ")),
        remeshed.step,
        remeshed.mesh_resolution,
        remeshed.seconds,
        crate::machine::Machine::this().line(),
        remeshed.mesh_triangles,
        remeshed.mesh_components_kept,
        remeshed.mesh_components,
        remeshed.files.join(", ")
    );
    match &remeshed.geometry {
        None if remeshed.mesh_triangles == 0 => println!("the mesh is empty (no triangle): nothing measured"),
        None => println!("the run's data has no ground truth: nothing measured"),
        Some(g) => {
            let d = |x: Option<f64>| x.map_or("∞".to_string(), |v| format!("{v:.4}"));
            let floor = g.mesh_floor.map_or(String::new(), |f| format!(" (the truth's own {}³ mesh: {f:.4})", remeshed.mesh_resolution));
            println!(
                "Chamfer {}{} (accuracy {}, completeness {}), F-score {:.3} at τ = {}{}{floor}",
                d(g.chamfer),
                g.chamfer.map_or(String::new(), |c| trainer::run::in_pixels(c, remeshed.pixel_footprint)),
                d(g.accuracy),
                d(g.completeness),
                g.f_score,
                g.f_score_tau,
                trainer::run::normals_part(g.normal_consistency)
            );
            if let Some(o) = &g.observed {
                println!("{}", trainer::run::observed_line(o, remeshed.pixel_footprint));
            }
        }
    }
    println!("written to {}", dir.join(name).display());
    Ok(())
}

/// The CPU seconds of every stage that ran during renders of `seconds` wall time (stderr).
fn print_render_profile(seconds: f64) {
    let cpu = seconds * rayon::current_num_threads() as f64;
    eprintln!("| render stage | CPU s | share of the renders' CPU time ({cpu:.2} s) |");
    eprintln!("|---|---|---|");
    for (stage, t) in sdf_backbone::profile::take().into_iter().filter(|(_, t)| *t > 0.0) {
        eprintln!("| {} | {t:.3} | {:.1} % |", stage.name(), 100.0 * t / cpu);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use trainer::evaluation::evaluate_mesh;

    /// An analytic truth measures the shape's own mesh exactly as the floor does, and a finer
    /// mesh or a finer protocol lowers the floor.
    #[test]
    fn the_floor_is_the_shapes_own_mesh_measured_like_any_other() {
        let shape = prob_grid::ShapeName::Sphere.shape();
        let protocol = |spacing| Protocol { spacing: Some(spacing), max_dist: Some(0.1), tau: Some(0.01) };
        let floor = |resolution, spacing| {
            trainer::outputs::shape_floor(&shape, &trainer::data::analytic_truth(&shape, spacing), resolution, spacing)
                .unwrap()
                .chamfer(0.1, 0.01)
                .chamfer
        };
        let config = prob_grid::MarchingCubesConfig { resolution: 64, block: 16, ..Default::default() };
        let (mesh, _) = prob_grid::marching_cubes(&shape, &config).unwrap();
        let vertices: Vec<[f32; 3]> = mesh.vertices.iter().map(|v| v.to_array()).collect();
        let e = evaluate_mesh(&vertices, &mesh.triangles, GroundTruth::Shape(shape.clone()), protocol(0.004)).unwrap();
        let (m, d) = (e.metrics, e.distances);
        assert_eq!(d.spacing, 0.004);
        assert_eq!(m.chamfer, floor(64, 0.004));
        // Its facets' normals follow the sphere's to within a fraction of a degree.
        assert!(e.normal_consistency.is_some_and(|nc| nc > 0.999 && nc < 1.0), "{:?}", e.normal_consistency);
        assert!(floor(128, 0.004) < floor(64, 0.004));
        assert!(floor(128, 0.002) < floor(128, 0.004));
        // The sphere (radius 0.5) has its bounding box from the analytic surface.
        let d = GroundTruth::Shape(shape).distances(Protocol::default(), "").unwrap();
        assert!((d.spacing - 3f64.sqrt() / 1000.0).abs() < 2e-5, "{d:?}");
    }

    #[test]
    fn dilation_grows_a_pixel_into_a_square() {
        let mut m = datasets::images::Mask::new(9, 7);
        m.set(4, 3, true);
        let d = dilate(&m, 2);
        assert_eq!(d.count(), 25);
        assert!(d.get(2, 1) && d.get(6, 5) && !d.get(1, 3) && !d.get(4, 6));
    }
}
