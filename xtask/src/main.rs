//! `cargo xtask …`: the psneus runner (always built optimised through the cargo alias). This
//! binary parses the command line and calls the `xtask` library; it is the only place that ends
//! the process with an exit code.

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use datasets::golden::{self, GeometrySource, GoldenSpec, rig::Rig};
use datasets::io::PlyData;
use datasets::{LoadOptions, read_cameras};
use glam::{DVec2, DVec3};
use std::path::PathBuf;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};
use trainer::run;
use xtask::{bench, bench_backbone, bench_memory, bench_overhead, eval, fuzz, sample, trade, train};

/// The heap, counted (and capped by `cargo xtask fuzz`; no limit otherwise).
#[global_allocator]
static ALLOCATOR: cap::Cap<std::alloc::System> = cap::Cap::new(std::alloc::System, usize::MAX);

#[derive(Parser)]
#[command(name = "xtask", about = "psneus: neural implicit surfaces with a probability-guided sampler")]
struct Cli {
    /// Run the kernels on at most this instruction set: avx512, avx2 or baseline (x86-64's SSE2) —
    /// a narrower CPU's path measured on this one; benchmarks name it and limit the PyTorch peer
    /// alike. Default: the widest this CPU has.
    #[arg(long, global = true, value_parser = xtask::machine::parse_instruction_set)]
    isa: Option<sdf_backbone::kernels::InstructionSet>,
    #[command(subcommand)]
    command: Command,
}

#[derive(clap::Args)]
struct DataArgs {
    /// Dataset folder (IDR/NeuS/DTU, NeRF-synthetic or instant-ngp layout).
    #[arg(long)]
    data: PathBuf,
    /// Integer downscale factor (area average; intrinsics follow).
    #[arg(long, default_value_t = 1)]
    downscale: u32,
    /// NeRF-synthetic split.
    #[arg(long, default_value = "train")]
    split: String,
    /// The region of interest `x,y,z,radius` in the dataset's units (overrides the format's:
    /// COLMAP's sparse points, instant-ngp's aabb).
    #[arg(long, value_parser = parse_bound)]
    bound: Option<(DVec3, f64)>,
}

impl DataArgs {
    fn options(&self) -> LoadOptions {
        LoadOptions { downscale: self.downscale, split: self.split.clone(), bound_sphere: self.bound, ..LoadOptions::default() }
    }
}

fn parse_bound(text: &str) -> Result<(DVec3, f64)> {
    let v: Vec<f64> = text
        .split(',')
        .map(|s| s.trim().parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .with_context(|| format!("--bound {text:?}: numbers x,y,z,radius"))?;
    match v.as_slice() {
        [x, y, z, r] if v.iter().all(|a| a.is_finite()) && *r > 0.0 => Ok((DVec3::new(*x, *y, *z), *r)),
        _ => bail!("--bound {text:?}: expected x,y,z,radius with radius > 0"),
    }
}

#[derive(Subcommand)]
enum ImportKind {
    /// A COLMAP sparse model and its images → the IDR layout (undistorted pinhole images,
    /// masks, cameras_sphere.npz with scale_mat in COLMAP units), readable by every tool.
    Colmap {
        /// The sparse model folder (cameras, images, points3D as .bin or .txt), e.g. sparse/0.
        #[arg(long)]
        model: PathBuf,
        /// The folder COLMAP's image names are relative to.
        #[arg(long)]
        images: PathBuf,
        /// Masks (same names as the images, any image format; white = object).
        #[arg(long)]
        masks: Option<PathBuf>,
        /// Output folder (IDR layout): new or empty.
        #[arg(long)]
        out: PathBuf,
        /// Replace an earlier import in --out (a folder holding `colmap_import.json`; any other
        /// non-empty folder is refused).
        #[arg(long)]
        overwrite: bool,
        /// Integer downscale of the images (area average; intrinsics follow).
        #[arg(long, default_value_t = 1)]
        downscale: u32,
        /// The region of interest `x,y,z,radius` in COLMAP units (default: from the sparse
        /// points seen by ≥ 3 images, 2–98 % percentiles, × 1.1).
        #[arg(long, value_parser = parse_bound)]
        bound: Option<(DVec3, f64)>,
    },
}

#[derive(Subcommand)]
enum Command {
    /// Print every camera as JSON (K, world_from_camera in the normalised frame, centre, size)
    /// and, with --ply, write a PLY of the camera frusta and the unit sphere.
    Cameras {
        #[command(flatten)]
        data: DataArgs,
        /// Write a PLY of the frusta and the unit sphere here (nothing is written without it).
        #[arg(long)]
        ply: Option<PathBuf>,
    },
    /// Load a dataset fully (images and masks) and report what was loaded.
    Inspect {
        #[command(flatten)]
        data: DataArgs,
    },
    /// Train a backbone with the probability-guided (or uniform) sampler: progress, pictures,
    /// checkpoints, the mesh and its metrics. With no arguments: the built-in scene in ≤ 5 min.
    Train(train::TrainArgs),
    /// Evaluate a mesh against ground truth (DTU-protocol Chamfer, F-score), or a run's model on
    /// its held-out views (PSNR, SSIM).
    Eval(Box<eval::EvalArgs>),
    /// What each minute of CPU buys: variants (uniform, guided, ablations) trained to the same
    /// wall-time budgets over seeds and scenes; table (mean ± std) and plots.
    Trade(trade::TradeArgs),
    /// Convert a capture into the IDR layout (`import colmap --model sparse/0 --images images
    /// --out scene`).
    Import {
        #[command(subcommand)]
        which: ImportKind,
    },
    /// Feed every parser of user input (PLY, NPY/NPZ, IDR cameras, transforms JSON, COLMAP,
    /// images, configurations, checkpoints) mutated bytes under an allocation cap; findings
    /// (panics, over-cap allocations, hangs) are saved with their inputs.
    Fuzz(fuzz::FuzzArgs),
    /// The guided sampler on a dataset with an analytic or mesh field: heat maps of the pixel
    /// marginal with the drawn pixels, depth profiles, and a JSON summary.
    Sample(sample::SampleArgs),
    /// Benchmarks (tables for BENCHMARKS.md; `--json`: one JSON object per figure).
    Bench {
        #[command(subcommand)]
        which: BenchKind,
    },
    /// Render a golden scene (known geometry) in the IDR layout.
    Golden {
        /// Analytic shape: sphere, torus, box, composite. With neither --shape nor --mesh, the
        /// built-in default scene (composite, DTU rig, 49 views of 200×150) is rendered.
        #[arg(long, conflicts_with = "mesh", value_parser = prob_grid::ShapeName::from_name)]
        shape: Option<prob_grid::ShapeName>,
        /// Mesh file (OBJ with MTL texture, glTF, GLB).
        #[arg(long)]
        mesh: Option<PathBuf>,
        /// Camera rig: dtu, sphere, random, ring.
        #[arg(long, default_value = "dtu", value_parser = parse_rig)]
        rig: Rig,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// Number of views.
        #[arg(long, default_value_t = 49)]
        views: usize,
        /// Image width (default 400; 200 for the built-in scene).
        #[arg(long)]
        width: Option<u32>,
        /// Image height (default 300; 150 for the built-in scene).
        #[arg(long)]
        height: Option<u32>,
        /// Seed.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// The mesh file is z-up (default: y-up, the OBJ and glTF convention).
        #[arg(long)]
        mesh_z_up: bool,
        /// What lies behind the object: none (black), checker, coarse-checker, gradient, noise
        /// (environments at infinity), floor, wall (near, crossing the bound).
        #[arg(long, default_value = "checker", value_parser = golden::Backdrop::from_name)]
        backdrop: golden::Backdrop,
        /// The region of interest's radius in the object's units (≥ 1; 1: the object fills the
        /// bound).
        #[arg(long, default_value_t = 1.0)]
        bound: f64,
        /// Also write a thumbnail grid of the views to this PNG.
        #[arg(long)]
        thumbnail: Option<PathBuf>,
    },
}

#[derive(Subcommand)]
enum BenchKind {
    /// The guided sampler's cost per iteration against uniform sampling, side by side on a
    /// trained model (iterations alternate).
    Overhead {
        /// A run folder (its model, data and configuration).
        #[arg(long)]
        run: PathBuf,
        /// Pairs of iterations.
        #[arg(long, default_value_t = 20)]
        iterations: u64,
        /// One JSON object on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Every preset end to end (a few iterations, mesh, evaluation), each in its own process:
    /// time per phase, peak resident memory against the memory model's estimate.
    Memory {
        /// Presets (repeat); default all four.
        #[arg(long, value_parser = sdf_backbone::Preset::from_name)]
        preset: Vec<sdf_backbone::Preset>,
        /// Iterations per preset.
        #[arg(long, default_value_t = 3)]
        steps: u64,
        /// One JSON object per preset.
        #[arg(long)]
        json: bool,
    },
    /// A long run of the default preset with its resident size logged every `--every`
    /// iterations: flat after warm-up, or it leaks.
    Soak {
        /// Iterations.
        #[arg(long, default_value_t = 2000)]
        iterations: u64,
        /// Sampling period (iterations).
        #[arg(long, default_value_t = 100)]
        every: u64,
        /// One JSON object.
        #[arg(long)]
        json: bool,
    },
    /// Backbone presets: training-step time (512 rays × 128 samples), FLOP per sample, MLP rate
    /// against the measured f32 matrix-product rate, peak memory.
    Backbone(bench_backbone::BackboneArgs),
    /// Probability update (F, s, dense vs sparse), draw throughput, accuracy vs cost.
    Sampler {
        /// DTU scan 24 folder (default ../shared/data/dtu_scan24; a golden DTU-like rig if absent).
        #[arg(long)]
        data: Option<PathBuf>,
        /// One JSON object per figure on stdout.
        #[arg(long)]
        json: bool,
        /// A smaller matrix (for a quick look).
        #[arg(long)]
        quick: bool,
    },
}

/// The signal that stopped the run (0: none; the exit code is 128 + it, as a shell reports a
/// process that a signal ended).
static STOP_SIGNAL: AtomicI32 = AtomicI32::new(0);

/// The exit code of a run that stopped early: 128 + the signal (130 for Ctrl-C or `--stop-at`).
fn stopped_exit_code() -> i32 {
    match STOP_SIGNAL.load(Ordering::SeqCst) {
        0 => 130,
        signal => 128 + signal,
    }
}

/// A flag that Ctrl-C, SIGTERM or SIGHUP sets — what a terminal, a batch scheduler, `timeout`,
/// `docker stop` and systemd send: the first one stops the run with a checkpoint; a second one
/// ends the process at once (exit 128 + the signal).
#[cfg(unix)]
fn stop_signal() -> Arc<AtomicBool> {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    use std::io::Write;
    let flag = Arc::new(AtomicBool::new(false));
    let handler_flag = flag.clone();
    match signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP]) {
        Ok(mut signals) => {
            std::thread::spawn(move || {
                for signal in signals.forever() {
                    if handler_flag.swap(true, Ordering::SeqCst) {
                        std::process::exit(128 + signal);
                    }
                    STOP_SIGNAL.store(signal, Ordering::SeqCst);
                    let name = match signal {
                        SIGINT => run::StopSource::CtrlC,
                        SIGTERM => run::StopSource::Terminate,
                        _ => run::StopSource::HangUp,
                    };
                    // A hung-up terminal may refuse the message: the stop goes ahead all the same.
                    let _ = writeln!(std::io::stderr(), "\n{}", run::stop_message(name));
                }
            });
        }
        Err(e) => eprintln!("warning: cannot catch Ctrl-C, SIGTERM or SIGHUP ({e}): a stop will not write a checkpoint"),
    }
    flag
}

/// A flag that Ctrl-C sets (the first press; a second one ends the process as usual).
#[cfg(not(unix))]
fn stop_signal() -> Arc<AtomicBool> {
    let flag = Arc::new(AtomicBool::new(false));
    let handler_flag = flag.clone();
    let _ = ctrlc::set_handler(move || {
        if handler_flag.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
        STOP_SIGNAL.store(2, Ordering::SeqCst);
        eprintln!("\n{}", run::stop_message(run::StopSource::CtrlC));
    });
    flag
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    if let Some(isa) = cli.isa {
        sdf_backbone::kernels::limit_instruction_set(isa);
    }
    match cli.command {
        Command::Sample(args) => sample::run(&args),
        Command::Train(args) if args.print_config => {
            print!("{}", trainer::config::annotated_default());
            Ok(())
        }
        Command::Train(args) => match train::train(&args, &stop_signal())? {
            run::Outcome::Finished(_) => Ok(()),
            run::Outcome::Stopped { .. } => std::process::exit(stopped_exit_code()),
        },
        Command::Eval(args) => eval::run(&args),
        Command::Trade(args) => trade::run(&args, &stop_signal()),
        Command::Import { which: ImportKind::Colmap { model, images, masks, out, overwrite, downscale, bound } } => {
            let options = LoadOptions { downscale, bound_sphere: bound, ..LoadOptions::default() };
            if overwrite && out.join("colmap_import.json").is_file() {
                std::fs::remove_dir_all(&out).with_context(|| format!("cannot clear the earlier import in {}", out.display()))?;
            }
            let report = datasets::import_colmap(&model, &images, masks.as_deref(), &out, &options)?;
            let scale = report.world_from_normalized.col(0).truncate().length();
            let centre = report.world_from_normalized.col(3).truncate();
            println!(
                "wrote {}: {} views ({} undistorted){}; region of interest: centre {centre:.4}, radius {scale:.4} (COLMAP units)\n{}",
                out.display(),
                report.views,
                report.undistorted,
                if report.masks { ", with masks" } else { "" },
                report.description
            );
            println!("next: cargo xtask train --data {}", out.display());
            Ok(())
        }
        Command::Fuzz(args) => {
            fn cap(bytes: usize) -> bool {
                ALLOCATOR.set_limit(bytes).is_ok()
            }
            fn end(code: i32) -> ! {
                std::process::exit(code)
            }
            if !fuzz::run(&args, &fuzz::ProcessHooks { memory_cap: cap, end_process: end })? {
                std::process::exit(1);
            }
            Ok(())
        }
        Command::Bench { which: BenchKind::Sampler { data, json, quick } } => bench::sampler(data.as_deref(), json, quick),
        Command::Bench { which: BenchKind::Backbone(args) } => bench_backbone::run(&args),
        Command::Bench { which: BenchKind::Overhead { run, iterations, json } } => bench_overhead::run(&run, iterations, json),
        Command::Bench { which: BenchKind::Memory { preset, steps, json } } => bench_memory::memory(&preset, steps, json),
        Command::Bench { which: BenchKind::Soak { iterations, every, json } } => bench_memory::soak(iterations, every, json),
        Command::Cameras { data, ply } => cameras(&data, ply.as_deref()),
        Command::Inspect { data } => inspect(&data),
        Command::Golden { shape, mesh, rig, out, views, width, height, seed, mesh_z_up, backdrop, bound, thumbnail } => {
            let mut spec = match (shape, mesh) {
                (Some(s), None) => GoldenSpec::new(GeometrySource::Shape(s)),
                (None, Some(m)) => GoldenSpec::new(GeometrySource::Mesh(m)),
                (None, None) => GoldenSpec::builtin(),
                _ => bail!("give at most one of --shape and --mesh"),
            };
            let width = width.unwrap_or(spec.rig.width);
            let height = height.unwrap_or(spec.rig.height);
            if views == 0 || width == 0 || height == 0 {
                bail!("--views, --width and --height must be positive");
            }
            spec.rig.rig = rig;
            spec.rig.count = views;
            spec.rig.width = width;
            spec.rig.height = height;
            spec.rig.seed = seed;
            spec.backdrop = backdrop;
            spec.bound = bound;
            spec.mesh_y_up = !mesh_z_up;
            let start = std::time::Instant::now();
            let scene = golden::generate(&spec)?;
            golden::write_idr(&scene, &out).with_context(|| format!("writing the golden scene to {}", out.display()))?;
            if let Some(path) = thumbnail {
                golden::thumbnail_grid(&scene.scene, 4, 2, 200).save_png(&path)?;
            }
            eprintln!(
                "{}: {} views, {} surface points, written to {} in {:.1} s",
                scene.scene.source.description,
                scene.scene.views.len(),
                scene.surface_points.len(),
                out.display(),
                start.elapsed().as_secs_f64()
            );
            Ok(())
        }
    }
}

/// `--rig`: a camera rig by name.
fn parse_rig(name: &str) -> Result<Rig, String> {
    Rig::by_name(name).ok_or_else(|| format!("unknown rig {name:?} (dtu, sphere, random, ring)"))
}

fn cameras(data: &DataArgs, ply_path: Option<&std::path::Path>) -> Result<()> {
    let cams = read_cameras(&data.data, &data.options())?;
    let mut list = Vec::new();
    let mut ply = PlyData::default();
    for record in &cams.records {
        let c = &record.camera;
        let world_from_camera = c.world_from_camera();
        let r = world_from_camera.rotation;
        let t = world_from_camera.translation;
        let k = c.intrinsics;
        list.push(serde_json::json!({
            "name": record.name,
            "width": c.width,
            "height": c.height,
            "K": [[k.fx, k.skew, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]],
            "world_from_camera": (0..4).map(|i| if i < 3 {
                vec![r.col(0)[i], r.col(1)[i], r.col(2)[i], t[i]]
            } else { vec![0.0, 0.0, 0.0, 1.0] }).collect::<Vec<_>>(),
            "center": t.to_array(),
            "distance_from_origin": t.length(),
            "pixel_centers": format!("{:?}", c.pixel_centers),
        }));
        // Frustum: centre and the four image corners at depth 0.25 (normalised units).
        let base = ply.positions.len() as u32;
        ply.positions.push(t.as_vec3());
        let (w, h) = (c.width as f64, c.height as f64);
        for corner in [DVec2::new(0.0, 0.0), DVec2::new(w, 0.0), DVec2::new(w, h), DVec2::new(0.0, h)] {
            ply.positions.push(c.world_from_pixel_space(corner.extend(0.25)).as_vec3());
        }
        for k in 0..4 {
            ply.edges.push([base, base + 1 + k]);
            ply.edges.push([base + 1 + k, base + 1 + (k + 1) % 4]);
        }
    }
    // The unit sphere (region of interest): three great circles.
    let segments = 96;
    for axis in 0..3 {
        let base = ply.positions.len() as u32;
        for s in 0..segments {
            let a = std::f64::consts::TAU * s as f64 / segments as f64;
            let mut p = DVec3::ZERO;
            p[(axis + 1) % 3] = a.cos();
            p[(axis + 2) % 3] = a.sin();
            ply.positions.push(p.as_vec3());
            ply.edges.push([base + s, base + (s + 1) % segments]);
        }
    }
    ply.colors = vec![[255, 255, 255]; ply.positions.len()];
    if let Some(path) = ply_path {
        ply.write(path)?;
    }
    let m = cams.world_from_normalized;
    let out = serde_json::json!({
        "source": cams.source,
        "world_from_normalized": (0..4).map(|r| (0..4).map(|c| m.col(c)[r]).collect::<Vec<_>>()).collect::<Vec<_>>(),
        "cameras": list,
        "ply": ply_path,
    });
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}

fn inspect(data: &DataArgs) -> Result<()> {
    let start = std::time::Instant::now();
    let scene = datasets::load_scene(&data.data, &data.options())?;
    let masks = scene.views.iter().filter(|v| v.mask.is_some()).count();
    let fg: usize = scene.views.iter().filter_map(|v| v.mask.as_ref()).map(|m| m.count()).sum();
    let px: usize = scene.views.iter().map(|v| (v.camera.width * v.camera.height) as usize).sum();
    let first = &scene.views[0].camera;
    println!(
        "{}\n{} views of {}×{}, {} with masks ({:.1}% foreground), {:.1} MB of pixels, loaded in {:.2} s",
        scene.source.description,
        scene.views.len(),
        first.width,
        first.height,
        masks,
        100.0 * fg as f64 / px.max(1) as f64,
        scene.pixel_bytes() as f64 / 1e6,
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
