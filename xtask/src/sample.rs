//! `cargo xtask sample`: the guided sampler on a dataset with an analytic or mesh field, as
//! pictures (pixel-marginal heat maps with the drawn pixels, depth profiles) and a JSON summary.

use anyhow::{Context, Result, bail};
use datasets::golden::mesh_io::load_mesh;
use datasets::{LoadOptions, Scene, load_scene};
use glam::DVec2;
use prob_grid::{CameraGridConfig, MeshSdf, SdfField, ShapeName, TriangleMesh};
use std::path::{Path, PathBuf};
use std::time::Instant;
use trainer::draw::{colormap, put};
use trainer::plot::{Panel, Series, render};
use view_sampler::{Estimator, EstimatorConfig, UniformSchedule};

/// Options of `cargo xtask sample`.
#[derive(clap::Args)]
pub struct SampleArgs {
    /// Dataset folder (any supported layout).
    #[arg(long)]
    pub data: PathBuf,
    /// Integer downscale factor.
    #[arg(long, default_value_t = 1)]
    pub downscale: u32,
    /// The SDF: sphere (r = 0.5), torus, box, composite, or mesh:FILE (closed, world units).
    #[arg(long, default_value = "sphere", value_parser = field_spec)]
    pub field: FieldSpec,
    /// Logistic scale s.
    #[arg(long, default_value_t = 200.0)]
    pub s: f32,
    /// Scene-grid resolution (the trainer's default: 64).
    #[arg(long, default_value_t = 128)]
    pub scene_resolution: usize,
    /// Camera-grid cells `RU,RV,RL` (the trainer's default: 32,32,64).
    #[arg(long, value_delimiter = ',', default_values_t = [64, 64, 128])]
    pub camera_grid: Vec<usize>,
    /// Output folder for pictures and summary.json.
    #[arg(long, default_value = "out/sample")]
    pub out: PathBuf,
    /// Number of guided rays to draw.
    #[arg(long, default_value_t = 200_000)]
    pub rays: usize,
    /// Number of views to draw pictures for.
    #[arg(long, default_value_t = 6)]
    pub views: usize,
    /// Print the summary as one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

/// The SDF to sample: a named analytic shape or a closed mesh in the dataset's world units.
#[derive(Debug, Clone)]
pub enum FieldSpec {
    /// A named analytic shape.
    Shape(ShapeName),
    /// `mesh:FILE`.
    Mesh(PathBuf),
}

impl std::fmt::Display for FieldSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FieldSpec::Shape(name) => write!(f, "{name}"),
            FieldSpec::Mesh(path) => write!(f, "mesh:{}", path.display()),
        }
    }
}

/// `sphere|torus|box|composite|multipart` or `mesh:FILE`.
fn field_spec(text: &str) -> std::result::Result<FieldSpec, String> {
    match text.strip_prefix("mesh:") {
        Some(path) => Ok(FieldSpec::Mesh(PathBuf::from(path))),
        None => ShapeName::from_name(text).map(FieldSpec::Shape).map_err(|e| format!("{e}, or mesh:FILE")),
    }
}

/// The field of `spec`, in the scene's normalised frame.
fn make_field(spec: &FieldSpec, scene: &Scene) -> Result<Box<dyn SdfField>> {
    match spec {
        FieldSpec::Mesh(path) => {
            let mesh = load_mesh(path)?;
            let normalized_from_world = scene.world_from_normalized.inverse();
            let positions = mesh.mesh.positions.iter().map(|p| normalized_from_world.transform_point3(p.as_dvec3()).as_vec3()).collect();
            Ok(Box::new(MeshSdf { mesh: TriangleMesh::new(positions, mesh.mesh.triangles.clone()) }))
        }
        FieldSpec::Shape(name) => Ok(Box::new(name.shape())),
    }
}

/// The depth map `depth/NAME.npy` written by golden scenes, if present and of the right size.
fn depth_map(data: &Path, name: &str, width: u32, height: u32) -> Option<Vec<f32>> {
    let path = data.join("depth").join(format!("{name}.npy"));
    let bytes = std::fs::read(&path).ok()?;
    let a = datasets::npy::parse_npy(&bytes, &path).ok()?;
    (a.shape == [height as usize, width as usize]).then(|| a.data.iter().map(|v| *v as f32).collect())
}

/// Runs the command.
pub fn run(args: &SampleArgs) -> Result<()> {
    let scene = load_scene(&args.data, &LoadOptions { downscale: args.downscale, ..LoadOptions::default() })
        .with_context(|| format!("loading {}", args.data.display()))?;
    let field = make_field(&args.field, &scene)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let cameras: Vec<_> = scene.views.iter().map(|v| v.camera).collect();

    let &[ru, rv, rl] = args.camera_grid.as_slice() else { bail!("--camera-grid takes three numbers RU,RV,RL") };
    let camera_config = CameraGridConfig { ru, rv, rl, ..CameraGridConfig::default() };
    let config = EstimatorConfig {
        scene: prob_grid::SceneGridConfig { resolution: args.scene_resolution, ..Default::default() },
        camera: camera_config.clone(),
        schedule: UniformSchedule { fractions: vec![0.0] },
        skip_empty: false,
        ..EstimatorConfig::default()
    };
    let mut estimator = Estimator::new(cameras, config)?;
    let report = estimator.update(field.as_ref(), args.s)?;
    let update_seconds = report.seconds;
    let empty = report.empty_cameras.clone();
    if !empty.is_empty() {
        eprintln!("note: {} camera(s) see no mass and are sampled uniformly: {empty:?}", empty.len());
    }
    let t = Instant::now();
    let rays = estimator.draw(args.rays, 0.0, 0, 0);
    let draw_seconds = t.elapsed().as_secs_f64();
    let sampler = estimator.sampler().expect("a guided estimator has a sampler after its update");

    // Statistics over every view.
    let (mut in_mask, mut with_mask, mut depth_errors) = (0usize, 0usize, Vec::new());
    let depths: Vec<Option<Vec<f32>>> = scene.views.iter().map(|v| depth_map(&args.data, &v.name, v.camera.width, v.camera.height)).collect();
    for r in &rays {
        let view = &scene.views[r.camera as usize];
        if let Some(mask) = &view.mask {
            with_mask += 1;
            in_mask += mask.get(r.pixel[0], r.pixel[1]) as usize;
        }
        if let Some(depth) = &depths[r.camera as usize] {
            let d = depth[(r.pixel[1] * view.camera.width + r.pixel[0]) as usize];
            if d > 0.0 {
                let cell = sampler.cameras()[r.camera as usize].depth_bin();
                let drawn = r.depth.expect("guided rays have a depth").depth;
                depth_errors.push(((drawn as f64 - d as f64).abs(), cell));
            }
        }
    }
    // |λ̃ − true depth| in depth units and in λ bins, medians and 90th percentiles.
    let quantiles = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (!v.is_empty()).then(|| [v[v.len() / 2], v[v.len() * 9 / 10]])
    };
    let error_depth = quantiles(depth_errors.iter().map(|e| e.0).collect());
    let error_cells = quantiles(depth_errors.iter().map(|e| e.0 / e.1).collect());

    // Pictures for the first views.
    let mut written = Vec::new();
    for (c, view) in scene.views.iter().enumerate().take(args.views) {
        let dist = &sampler.cameras()[c];
        let drawn: Vec<&view_sampler::RaySample> = rays.iter().filter(|r| r.camera as usize == c).collect();
        let heat_path = args.out.join(format!("heatmap_{}.png", view.name));
        heat_map_picture(view, dist, &drawn).save_png(&heat_path)?;
        let profile_path = args.out.join(format!("profile_{}.png", view.name));
        render(&[depth_profiles(view, dist, &drawn, depths[c].as_deref())], 1, (720, 360))?.save_png(&profile_path)?;
        written.push(serde_json::json!({"view": view.name, "heatmap": heat_path, "depth_profile": profile_path}));
    }

    let summary = serde_json::json!({
        "data": args.data,
        "field": args.field.to_string(),
        "s": args.s,
        "cameras": scene.views.len(),
        "scene_grid": estimator.config().scene.resolution, "partition": estimator.config().scene.partition,
        "camera_grid": [camera_config.ru, camera_config.rv, camera_config.rl],
        "update_seconds": update_seconds,
        "rays": rays.len(),
        "draw_seconds": draw_seconds,
        "samples_per_second": rays.len() as f64 / draw_seconds,
        "guided_fraction_inside_mask": (with_mask > 0).then(|| in_mask as f64 / with_mask as f64),
        "median_depth_error_cells": error_cells.map(|q| q[0]),
        "p90_depth_error_cells": error_cells.map(|q| q[1]),
        "median_depth_error": error_depth.map(|q| q[0]),
        "p90_depth_error": error_depth.map(|q| q[1]),
        // The extra points' spread at this s (the paper's N(λ̃, σ²)), to compare with the errors.
        "logistic_std": surface_losses::logistic_std(f64::from(args.s)),
        "rays_with_true_depth": depth_errors.len(),
        "empty_cameras": empty,
        "pictures": written,
    });
    datasets::io::write_atomic(&args.out.join("summary.json"), serde_json::to_string_pretty(&summary)?.as_bytes())?;
    if args.json {
        println!("{summary}");
    } else {
        eprintln!(
            "{} cameras, update (CDFs included) {:.3} s, {:.1} M draws/s; guided inside mask: {}; median depth error: {} cells ({} against σ = {:.4} at s); pictures in {}",
            scene.views.len(),
            update_seconds,
            rays.len() as f64 / draw_seconds / 1e6,
            summary["guided_fraction_inside_mask"],
            summary["median_depth_error_cells"],
            summary["median_depth_error"],
            summary["logistic_std"],
            args.out.display()
        );
    }
    Ok(())
}

/// The view darkened under its pixel marginal as a heat map, with at most 1500 of the pixels
/// drawn in it (so that the heat map stays visible).
fn heat_map_picture(view: &datasets::View, dist: &view_sampler::CameraDistribution, drawn: &[&view_sampler::RaySample]) -> datasets::RgbImage {
    let (ru, rv, _) = dist.resolution();
    let marginal = dist.pixel_marginal();
    let peak = marginal.iter().cloned().fold(0.0, f64::max).max(1e-300);
    let b = *dist.bounds();
    let mut img = view.image.clone();
    for row in 0..img.height {
        for col in 0..img.width {
            let p = view.camera.pixel_center(col, row);
            let iu = (((p.x - b.u[0]) / (b.u[1] - b.u[0]) * ru as f64) as usize).min(ru - 1);
            let iv = (((p.y - b.v[0]) / (b.v[1] - b.v[0]) * rv as f64) as usize).min(rv - 1);
            let t = (marginal[iv * ru + iu] / peak).sqrt() as f32;
            let base = img.get_f32(col, row).map(|x| 0.45 * x);
            let heat = colormap(t);
            let a = 0.75 * t.min(1.0);
            img.set_f32(col, row, [0, 1, 2].map(|k| base[k] * (1.0 - a) + heat[k] * a));
        }
    }
    let dot = (img.width / 800) as i64;
    for r in drawn.iter().take(1500) {
        for dy in -dot..=dot {
            for dx in -dot..=dot {
                put(&mut img, r.pixel[0] as i64 + dx, r.pixel[1] as i64 + dy, [0.2, 1.0, 0.3]);
            }
        }
    }
    img
}

/// Depth profiles p̃(λ | u, v) at the first three drawn rays of the view that land in its mask
/// (any three if there is no mask) and at the principal point, with the true depths where the
/// scene has a depth map.
fn depth_profiles(
    view: &datasets::View,
    dist: &view_sampler::CameraDistribution,
    drawn: &[&view_sampler::RaySample],
    depth: Option<&[f32]>,
) -> Panel {
    let b = *dist.bounds();
    let in_mask = |r: &&&view_sampler::RaySample| view.mask.as_ref().is_none_or(|m| m.get(r.pixel[0], r.pixel[1]));
    let mut pixels: Vec<DVec2> = drawn.iter().filter(in_mask).take(3).map(|r| r.pixel_coords).collect();
    pixels.push(DVec2::new(view.camera.intrinsics.cx, view.camera.intrinsics.cy));
    let colours = [[0.85, 0.2, 0.2], [0.2, 0.45, 0.85], [0.15, 0.6, 0.25], [0.5, 0.5, 0.5]];
    let mut panel = Panel {
        title: format!("p̃(λ | u, v), view {}", view.name),
        x_label: "depth λ along the optical axis (normalised units)".into(),
        y_label: "p̃(λ | u, v) (per unit depth)".into(),
        ..Default::default()
    };
    for (i, (p, rgb)) in pixels.iter().zip(colours).enumerate() {
        let points: Vec<(f64, f64, Option<f64>)> = (0..512)
            .map(|k| {
                let depth = b.depth[0] + (k as f64 + 0.5) / 512.0 * (b.depth[1] - b.depth[0]);
                (depth, dist.pdf_depth(*p, depth), None)
            })
            .collect();
        let what = if i + 1 == pixels.len() { "principal point" } else { "drawn pixel" };
        panel.series.push(Series { label: format!("{what} ({:.0}, {:.0})", p.x, p.y), color: rgb, points });
        if let (Some(depth), Some((col, row))) = (depth, view.camera.nearest_pixel(*p)) {
            let d = depth[(row * view.camera.width + col) as usize];
            if d > 0.0 {
                panel.markers.push((d as f64, rgb, format!("true depth ({:.0}, {:.0})", p.x, p.y)));
            }
        }
    }
    panel
}
