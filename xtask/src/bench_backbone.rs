//! `cargo xtask bench backbone`: the training step of each backbone preset (forward + backward +
//! Adam on 512 rays × 128 samples), FLOP per sample, the rate inside the MLPs against the best
//! f32 matrix product measured here, peak memory per preset (each preset in its own process),
//! and, with `--peer PYTHON`, the PyTorch-CPU peer (`scripts/torch_peer.py`) of the default preset
//! in the same run, with the ratio.

use anyhow::{Context, Result, bail};
use rayon::prelude::*;
use sdf_backbone::kernels::{Strided, dispatch, gemm};
use sdf_backbone::{Adam, Backbone, InputEncoding, Module, NoSampleLoss, NormalScheme, Preset, RayInput, StepRates, build};
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Options of `cargo xtask bench backbone`.
#[derive(clap::Args, Debug, Clone)]
pub struct BackboneArgs {
    /// One JSON object per figure on stdout.
    #[arg(long)]
    pub json: bool,
    /// Only the 2-core presets (skip paper-scale NeuS and Neuralangelo).
    #[arg(long)]
    pub quick: bool,
    /// Also run the PyTorch-CPU peer with this Python (e.g. `python3`; needs torch and numpy).
    #[arg(long)]
    pub peer: Option<PathBuf>,
    /// Timed steps per figure.
    #[arg(long, default_value_t = 3)]
    pub reps: usize,
    /// Run one preset in this process (the parent runs each preset this way, so that every
    /// figure's peak memory is its own).
    #[arg(long, hide = true, value_parser = Preset::from_name)]
    pub preset: Option<Preset>,
    /// With `--preset`: only this normal scheme (tetrahedral, central, analytic), e.g. to profile
    /// one step with `perf record`.
    #[arg(long, requires = "preset", value_parser = NormalScheme::from_name)]
    pub normals: Option<NormalScheme>,
    /// With `--preset`: where one step's time goes (CPU seconds per stage, summed over threads:
    /// hash-grid gathers and scatters, MLP passes, the pipeline's own work, Adam), as a table.
    #[arg(long, requires = "preset")]
    pub profile: bool,
    /// With `--preset`: the networks' matrix products, `f32` or `bf16` (the trainer's
    /// `model.products`).
    #[arg(long, requires = "preset", value_parser = parse_products, default_value = "f32")]
    pub products: trainer::config::Products,
    /// With `--profile`: rays per work item (the trainer's `render.chunk`).
    #[arg(long, requires = "profile", default_value_t = trainer::config::RenderConfig::default().chunk)]
    pub chunk: usize,
}

/// `f32` or `bf16`, as `model.products` spells them.
fn parse_products(text: &str) -> Result<trainer::config::Products, String> {
    match text {
        "f32" => Ok(trainer::config::Products::F32),
        "bf16" => Ok(trainer::config::Products::Bf16),
        other => Err(format!("`{other}`: the products are f32 or bf16")),
    }
}

/// Multiply-adds of one row through an MLP.
fn mlp_macs(mlp: &sdf_backbone::Mlp) -> f64 {
    let c = mlp.config();
    let mut n_in = c.n_inputs;
    let mut macs = 0.0;
    for l in 0..=c.hidden_layers {
        if c.skip == Some(l) {
            n_in += c.n_inputs;
        }
        let n_out = if l == c.hidden_layers { c.n_outputs } else { c.width };
        macs += (n_in * n_out) as f64;
        n_in = n_out;
    }
    macs
}

/// f32 matrix-product rates of this machine, GFLOP/s over all threads (one independent product
/// per thread): `matrixmultiply` (ndarray's sgemm, AVX2 kernels) on 256³, and psneus's own
/// runtime-dispatched tile kernel (AVX-512 here) on 256³ and on a layer's shape (16 384 rows ×
/// 64 · 64 × 64). Each rate is the median of 5 timings after a warm-up (one timing is a few
/// milliseconds). The machine's own state varies more: on this 2-vCPU Zen 5 machine the 256³
/// tile read 197–208 GFLOP/s in every run but one, which read 382 (BENCHMARKS.md).
pub fn gemm_rates() -> Vec<(&'static str, f64)> {
    let threads = rayon::current_num_threads();
    let time = |f: &(dyn Fn() + Sync)| {
        (0..threads).into_par_iter().for_each(|_| f());
        let mut times: Vec<f64> = (0..5)
            .map(|_| {
                let t = Instant::now();
                (0..threads).into_par_iter().for_each(|_| f());
                t.elapsed().as_secs_f64()
            })
            .collect();
        times.sort_by(f64::total_cmp);
        times[2]
    };
    let n = 256;
    let reps = 40;
    let a = ndarray::Array2::<f32>::from_elem((n, n), 1.0);
    let b = ndarray::Array2::<f32>::from_elem((n, n), 0.5);
    let mm = time(&|| {
        for _ in 0..reps {
            std::hint::black_box(a.dot(&b));
        }
    });
    let cube = 2.0 * (n * n * n) as f64 * reps as f64 * threads as f64;
    let av: Vec<f32> = (0..n * n).map(|i| (i % 7) as f32 * 0.1).collect();
    let tile = time(&|| {
        let mut c = vec![0.0f32; n * n];
        for _ in 0..reps {
            dispatch(
                #[inline(always)]
                || gemm(&mut c, n, Strided { data: &av, sm: n, sk: 1 }, &av, n, n, n, n, false),
            );
            std::hint::black_box(&c);
        }
    });
    let rows = 16384;
    let x: Vec<f32> = (0..rows * 64).map(|i| (i % 13) as f32 * 0.05).collect();
    let w: Vec<f32> = (0..64 * 64).map(|i| (i % 5) as f32 * 0.1).collect();
    let layer = time(&|| {
        let mut c = vec![0.0f32; rows * 64];
        for _ in 0..10 {
            dispatch(
                #[inline(always)]
                || gemm(&mut c, 64, Strided { data: &x, sm: 64, sk: 1 }, &w, 64, rows, 64, 64, false),
            );
            std::hint::black_box(&c);
        }
    });
    let layer_flop = 2.0 * (rows * 64 * 64) as f64 * 10.0 * threads as f64;
    vec![
        ("matrixmultiply sgemm 256³", cube / mm / 1e9),
        ("psneus tile kernel 256³", cube / tile / 1e9),
        ("psneus tile kernel 16384×64·64×64", layer_flop / layer / 1e9),
    ]
}

/// The benchmark's rays: a fan around the object, `n_samples` intervals each.
fn rays(n_rays: usize, n_samples: usize) -> Vec<RayInput<f32>> {
    (0..n_rays)
        .map(|r| {
            let a = r as f32 * 0.01;
            let d = glam::Vec3::new(-a.cos(), -a.sin(), -0.1).normalize();
            RayInput {
                origin: [3.0 * a.cos(), 3.0 * a.sin(), 0.3],
                direction: d.to_array(),
                depths: (0..=n_samples).map(|i| 2.0 + 2.0 * i as f32 / n_samples as f32).collect(),
                target: [0.5, 0.4, 0.3],
                mask: Some(1.0),
                weight: 1.0,
            }
        })
        .collect()
}

/// The trainer's default rates and clipping (`optim.lr_grid`, `optim.lr`, `optim.clip_norm`: 0
/// is off; the peer does not clip either).
fn trainer_rates() -> StepRates {
    let optim = trainer::config::OptimConfig::default();
    StepRates { tables: optim.lr_grid as f32, rest: optim.lr as f32, clip_norm: optim.clip_norm.map(|c| c as f32), geometry: 1.0 }
}

/// Seconds per training step: forward + backward of the whole loss + Adam, as the trainer
/// runs it (`Backbone::train_step`: hash tables updated level by level from their deferred
/// gradient, the trainer's default rates and clipping), the best of `reps` after a warm-up step.
fn time_step(backbone: &Backbone, params: &mut [f32], rays: &[RayInput<f32>], reps: usize) -> f64 {
    let mut adam = Adam::new(params.len());
    let rates = trainer_rates();
    let mut step = |params: &mut [f32]| {
        let _ = backbone.train_step(params, &mut adam, rays, trainer::config::RenderConfig::default().chunk, &NoSampleLoss, rates);
    };
    step(params);
    (0..reps.max(1))
        .map(|_| {
            let t = Instant::now();
            step(params);
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

/// Where the time of one step of `preset` with `normals` goes: each stage's CPU seconds per
/// step (summed over threads, mean of `reps` steps after a warm-up), against the step's wall
/// time × threads, and the MLP stages' rate per thread against the best GEMM's. Printed as a
/// table.
fn profile_step(preset: Preset, normals: NormalScheme, products: sdf_backbone::Products, reps: usize, chunk: usize, gemm_best: f64) {
    use sdf_backbone::profile::{self, Stage};
    let (mut backbone, mut params) = build(preset, 0.5, 1);
    backbone.set_normal_scheme(normals);
    backbone.set_products(products);
    let (n_rays, n_samples) = batch_of(preset);
    let rays = rays(n_rays, n_samples);
    let mut adam = Adam::new(params.len());
    let rates = trainer_rates();
    let _ = backbone.train_step(&mut params, &mut adam, &rays, chunk, &NoSampleLoss, rates);
    let reps = reps.max(1);
    profile::take();
    profile::enable(true);
    let t = Instant::now();
    for _ in 0..reps {
        let _ = backbone.train_step(&mut params, &mut adam, &rays, chunk, &NoSampleLoss, rates);
    }
    let wall = t.elapsed().as_secs_f64() / reps as f64;
    profile::enable(false);
    let stages: Vec<(Stage, f64)> = profile::take().into_iter().map(|(s, t)| (s, t / reps as f64)).collect();
    let threads = rayon::current_num_threads();
    let cpu = wall * threads as f64;
    let of = |stage: Stage| stages.iter().find(|(s, _)| *s == stage).map_or(0.0, |(_, t)| *t);
    // The MLP stages' FLOP (2·MACs forward, 4·MACs backward per row; analytic normals: the
    // normal by one reverse pass, 2, in the backward stage; the SDF network's backward in its
    // tangent stage: 2 for the tangent along ∂L/∂n and 2 · 4 for values and tangents).
    let sdf_macs = mlp_macs(&backbone.sdf.b);
    let color_macs = mlp_macs(&backbone.color);
    let analytic = normals == NormalScheme::Analytic;
    let sdf_rows = (n_rays * ((if analytic { 1 } else { 1 + normals.probe_count() }) * n_samples + 1)) as f64;
    let col_rows = (n_rays * n_samples) as f64;
    let flop = |stage: Stage| match stage {
        Stage::MlpForward => 2.0 * (sdf_rows * sdf_macs + col_rows * color_macs),
        Stage::MlpBackward if analytic => 2.0 * sdf_rows * sdf_macs + 4.0 * col_rows * color_macs,
        Stage::MlpBackward => 4.0 * (sdf_rows * sdf_macs + col_rows * color_macs),
        Stage::MlpTangents if analytic => 10.0 * sdf_rows * sdf_macs,
        _ => 0.0,
    };
    let inside = [Stage::HashForward, Stage::HashTangents, Stage::MlpForward, Stage::MlpTangents, Stage::MlpBackward];
    let modules_inside: f64 = inside.iter().map(|s| of(*s)).sum();
    let outside = [Stage::LossPass, Stage::HashScatter, Stage::HashTangentScatter, Stage::Adam];
    let counted: f64 = outside.iter().map(|s| of(*s)).sum();
    println!(
        "{} preset, {n_rays} rays × {n_samples} samples ({chunk} rays per work item), {normals:?} normals, {threads} threads: step {wall:.4} s wall ({cpu:.4} CPU-s), mean of {reps}",
        preset.name()
    );
    let per_thread = gemm_best / threads as f64;
    println!("| stage | CPU s per step | share of the step's CPU time | GFLOP/s per thread (best GEMM {per_thread:.0}) |");
    println!("|---|---|---|---|");
    let row = |name: &str, t: f64, flop: f64| {
        let rate = if flop > 0.0 && t > 0.0 { format!("{:.0} ({:.0} %)", flop / t / 1e9, 100.0 * flop / t / 1e9 / per_thread) } else { "—".into() };
        println!("| {name} | {t:.4} | {:.1} % | {rate} |", 100.0 * t / cpu)
    };
    for stage in inside {
        row(stage.name(), of(stage), flop(stage));
    }
    row("pipeline's own work (points, rendering, losses, buffers)", of(Stage::LossPass) - modules_inside, 0.0);
    for stage in [Stage::HashScatter, Stage::HashTangentScatter, Stage::Adam] {
        row(stage.name(), of(stage), 0.0);
    }
    row("outside every stage (idle threads, reductions, allocation)", cpu - counted, 0.0);
}

/// Seconds for forward + backward of `mlp` over `rows` rows (parallel chunks of 1024 rows).
fn time_mlp(mlp: &sdf_backbone::Mlp, params: &[f32], rows: usize) -> f64 {
    let n_in = Module::<f32>::n_inputs(mlp);
    let x: Vec<f32> = (0..rows * n_in).map(|i| ((i * 7919) % 1000) as f32 / 1000.0 - 0.5).collect();
    let mut grads = vec![0.0f32; params.len()];
    let run = |g: &mut [f32]| mlp.gradients_for_adjoint(params, &x, 1024, g, 1e-3);
    run(&mut grads);
    let t = Instant::now();
    run(&mut grads);
    t.elapsed().as_secs_f64()
}

fn peak_rss_mb() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    Some(line.split_whitespace().nth(1)?.parse::<f64>().ok()? / 1024.0)
}

/// Rays and samples per preset: the paper-scale ones run fewer rays (their steps take seconds).
fn batch_of(preset: Preset) -> (usize, usize) {
    match preset {
        Preset::NeuralangeloCpu | Preset::NeusCpu => (512, 128),
        Preset::Neus | Preset::Neuralangelo => (64, 128),
    }
}

/// The figures of one preset (every normal scheme it has, or `only`), in this process.
fn preset_figures(preset: Preset, reps: usize, gemm_best: f64, only: Option<NormalScheme>, products: sdf_backbone::Products) -> Vec<Value> {
    let (mut backbone, mut params) = build(preset, 0.5, 1);
    backbone.set_products(products);
    let (n_rays, n_samples) = batch_of(preset);
    let rays = rays(n_rays, n_samples);
    let layout = backbone.layout();
    let sdf_mlp = backbone.sdf.b.clone();
    let (sdf_macs, color_macs) = (mlp_macs(&sdf_mlp), mlp_macs(&backbone.color));
    let grid = match &backbone.sdf.a {
        InputEncoding::HashGrid(g) => Some(g.encoding.config().clone()),
        InputEncoding::Positional(_) => None,
    };
    let mut out = Vec::new();
    // Every preset's network has tangents.
    let schemes = [NormalScheme::Tetrahedral, NormalScheme::Central, NormalScheme::Analytic];
    for normals in schemes.into_iter().filter(|n| only.is_none_or(|o| o == *n)) {
        backbone.set_normal_scheme(normals);
        let step = time_step(&backbone, &mut params, &rays, reps);
        let samples = (n_rays * n_samples) as f64;
        // Forward 2·MACs, backward 4·MACs (input and weight gradients) per SDF row: 1 + probes
        // rows per sample. Analytic normals: forward 2 (values) + 2 (the normal by one reverse
        // pass), backward 2 (the tangent along ∂L/∂n) + 2·4 (values and tangents): 14 MACs, as
        // 7/3 rows (the networks' nominal MACs: the products over columns whose adjoint is zero,
        // which the tangents' reverse pass skips, are counted).
        let (rows_num, rows_den) = if normals == NormalScheme::Analytic { (7, 3) } else { (1 + normals.probe_count(), 1) };
        let flop_per_sample = 6.0 * (rows_num as f64 / rows_den as f64 * sdf_macs + color_macs);
        let sdf_rows = n_rays * (rows_num * n_samples / rows_den + 1);
        let t_mlp = time_mlp(&sdf_mlp, &params[layout.sdf_mlp.clone()], sdf_rows)
            + time_mlp(&backbone.color, &params[layout.color.clone()], n_rays * n_samples);
        let mlp_gflops = flop_per_sample * samples / t_mlp / 1e9;
        out.push(crate::machine::tag(json!({
            "figure": "backbone_step", "preset": preset.name(), "params": params.len(),
            "levels": grid.as_ref().map(|g| g.levels), "features_per_level": grid.as_ref().map(|g| g.features),
            "log2_table_size": grid.as_ref().map(|g| g.log2_table), "base_resolution": grid.as_ref().map(|g| g.base_resolution),
            "max_resolution": grid.as_ref().map(|g| g.finest_resolution),
            "sdf_hidden": sdf_mlp.config().width, "sdf_layers": sdf_mlp.config().hidden_layers,
            "colour_hidden": backbone.color.config().width, "colour_layers": backbone.color.config().hidden_layers,
            "normals": normals_name(normals), "products": format!("{products:?}"), "rays": n_rays, "samples": n_samples,
            "step_s": step, "samples_per_s": samples / step, "flop_per_sample": flop_per_sample,
            "step_gflops": flop_per_sample * samples / step / 1e9, "mlp_s": t_mlp, "mlp_gflops": mlp_gflops,
            "mlp_fraction_of_gemm": mlp_gflops / gemm_best, "gemm_gflops": gemm_best,
            "threads": rayon::current_num_threads(),
            // The trainer's default model: its preset and the normals `model.normals = auto` gives it.
            "default": preset == default_model().preset && normals == default_model().normal_scheme(),
        })));
    }
    let rss = peak_rss_mb();
    for f in &mut out {
        f["peak_rss_mb"] = json!(rss);
    }
    out
}

/// The trainer's default model configuration.
fn default_model() -> trainer::config::ModelConfig {
    trainer::config::ModelConfig::default()
}

/// A normal scheme as the figures name it (`tetrahedral`, `central`, `analytic`).
fn normals_name(normals: NormalScheme) -> String {
    format!("{normals:?}").to_lowercase()
}

/// Runs one preset in a child process (`--preset`), returning its JSON figures.
fn child_figures(preset: Preset, reps: usize, gemm_best: f64) -> Result<Vec<Value>> {
    let out = crate::machine::xtask_child()?
        .args(["bench", "backbone", "--json", "--preset", preset.name(), "--reps", &reps.to_string()])
        .env("PSNEUS_GEMM_GFLOPS", gemm_best.to_string())
        .output()
        .context("running the preset's child process")?;
    if !out.status.success() {
        bail!("the {} preset failed: {}", preset.name(), String::from_utf8_lossy(&out.stderr));
    }
    String::from_utf8_lossy(&out.stdout).lines().map(|l| serde_json::from_str(l).with_context(|| format!("child output {l:?}"))).collect()
}

/// The peer's script, `scripts/torch_peer.py` of the repository this xtask was built from
/// (whatever the working directory), checked to exist.
fn peer_script() -> Result<PathBuf> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/torch_peer.py");
    if !script.is_file() {
        bail!("the PyTorch peer's script {} is missing (it ships with the repository this xtask was built from)", script.display());
    }
    Ok(script)
}

/// The peer's figures (`script`: [`peer_script`]), with glibc's allocator tuned as its docs ask,
/// on the instruction set our kernels are limited to (`--isa`).
fn peer_figures(python: &Path, script: &Path, rays: usize, samples: usize) -> Result<Vec<Value>> {
    let threads = rayon::current_num_threads().to_string();
    let out = std::process::Command::new(python)
        .arg(script)
        .args(["--threads", &threads, "--rays", &rays.to_string(), "--samples", &samples.to_string(), "--no-check"])
        .env("MALLOC_MMAP_MAX_", "0")
        .env("MALLOC_TRIM_THRESHOLD_", "100000000000")
        .envs(crate::machine::peer_instruction_set_env())
        .output()
        .with_context(|| format!("running {} {} (pip install torch numpy)", python.display(), script.display()))?;
    if !out.status.success() {
        bail!("the peer failed: {}", String::from_utf8_lossy(&out.stderr));
    }
    Ok(String::from_utf8_lossy(&out.stdout).lines().filter_map(|l| serde_json::from_str(l).ok()).collect())
}

fn number(v: &Value, key: &str) -> f64 {
    v[key].as_f64().unwrap_or(f64::NAN)
}

fn print_row(f: &Value) {
    println!(
        "| {} | {} | {} × {} | {} | {:.3} | {:.0} | {:.2e} | {:.1} | {:.1} | {:.0} % | {:.0} |",
        f["preset"].as_str().unwrap_or("?"),
        f["params"],
        f["rays"],
        f["samples"],
        f["normals"].as_str().unwrap_or("?"),
        number(f, "step_s"),
        number(f, "samples_per_s"),
        number(f, "flop_per_sample"),
        number(f, "step_gflops"),
        number(f, "mlp_gflops"),
        100.0 * number(f, "mlp_fraction_of_gemm"),
        number(f, "peak_rss_mb"),
    );
}

/// Runs the benchmark.
pub fn run(args: &BackboneArgs) -> Result<()> {
    if let Some(preset) = args.preset {
        let gemm_best: f64 = std::env::var("PSNEUS_GEMM_GFLOPS")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or_else(|| gemm_rates().iter().map(|g| g.1).fold(0.0, f64::max));
        let only = args.normals;
        if args.profile {
            profile_step(
                preset,
                only.unwrap_or(trainer::config::ModelConfig { preset, ..default_model() }.normal_scheme()),
                args.products.into(),
                args.reps,
                args.chunk,
                gemm_best,
            );
            return Ok(());
        }
        for f in preset_figures(preset, args.reps, gemm_best, only, args.products.into()) {
            println!("{f}");
        }
        return Ok(());
    }
    // Found before the presets' minutes, not after.
    let peer = args.peer.as_ref().map(|python| peer_script().map(|script| (python, script))).transpose()?;
    let threads = rayon::current_num_threads();
    let rates = gemm_rates();
    let gemm_best = rates.iter().map(|g| g.1).fold(0.0, f64::max);
    if args.json {
        for (name, gflops) in &rates {
            println!("{}", crate::machine::tag(json!({"figure": "gemm_rate", "kernel": name, "gflops": gflops, "threads": threads})));
        }
    } else {
        for (name, gflops) in &rates {
            println!("f32 matrix product, {name}, one per thread, {threads} threads: {gflops:.1} GFLOP/s");
        }
        println!("machine: {}", crate::machine::Machine::this().line());
        println!(
            "| preset | parameters | rays × samples | normals | step (s) | samples/s | FLOP/sample | GFLOP/s (step) | MLP GFLOP/s | MLP / best GEMM | peak RSS (MB) |"
        );
        println!("|---|---|---|---|---|---|---|---|---|---|---|");
    }
    let mut presets = vec![Preset::NeuralangeloCpu, Preset::NeusCpu];
    if !args.quick {
        presets.extend([Preset::Neus, Preset::Neuralangelo]);
    }
    // The default preset's steps: with the trainer's default normals, and with tetrahedral ones.
    let default_normals = normals_name(default_model().normal_scheme());
    let (mut default_steps, mut tetrahedral_steps) = (Vec::new(), Vec::new());
    for preset in presets {
        match child_figures(preset, args.reps, gemm_best) {
            Ok(figures) => {
                for f in &figures {
                    if args.json {
                        println!("{f}");
                    } else {
                        print_row(f);
                    }
                    if f["default"] == true {
                        default_steps.push(number(f, "step_s"));
                    }
                    if preset == default_model().preset && f["normals"] == "tetrahedral" {
                        tetrahedral_steps.push(number(f, "step_s"));
                    }
                }
            }
            Err(e) if args.json => {
                println!("{}", crate::machine::tag(json!({"figure": "backbone_step", "preset": preset.name(), "error": format!("{e:#}")})))
            }
            Err(e) => println!("| {} | error: {e:#} |", preset.name()),
        }
    }
    if let Some((python, script)) = peer {
        let (rays, samples) = batch_of(default_model().preset);
        let peer = peer_figures(python, &script, rays, samples)?;
        // Our default step again after the peer, so that both sides see the same machine state.
        if let Ok(figures) = child_figures(default_model().preset, args.reps, gemm_best) {
            default_steps.extend(figures.iter().filter(|f| f["default"] == true).map(|f| number(f, "step_s")));
            tetrahedral_steps.extend(figures.iter().filter(|f| f["normals"] == "tetrahedral").map(|f| number(f, "step_s")));
        }
        let ours = default_steps.iter().copied().fold(f64::INFINITY, f64::min);
        let ours_tetrahedral = tetrahedral_steps.iter().copied().fold(f64::INFINITY, f64::min);
        let steps: Vec<&Value> = peer.iter().filter(|f| f["figure"] == "torch_step").collect();
        let best = steps.iter().filter(|f| f["step_s"].is_number()).min_by(|a, b| number(a, "step_s").total_cmp(&number(b, "step_s")));
        for f in &steps {
            if args.json {
                println!("{}", crate::machine::tag((*f).clone()));
            } else {
                println!(
                    "PyTorch {} {} normals, {}: step {} s (median; min {} s), peak RSS {} MB",
                    f["torch_version"].as_str().unwrap_or("?"),
                    f["normals"].as_str().unwrap_or("?"),
                    f["mode"].as_str().unwrap_or("?"),
                    f["step_s"],
                    f["step_min_s"],
                    f["peak_rss_mb"]
                );
            }
        }
        let best_s = best.map_or(f64::NAN, |b| number(b, "step_s"));
        let ratio =
            crate::machine::tag(json!({"figure": "peer_ratio", "ours_step_s": ours, "ours_normals": default_normals, "peer_best_step_s": best_s,
            "peer_best": best.map(|b| format!("{} {}", b["normals"].as_str().unwrap_or("?"), b["mode"].as_str().unwrap_or("?"))),
            "speedup": best_s / ours, "ours_tetrahedral_step_s": ours_tetrahedral, "speedup_tetrahedral": best_s / ours_tetrahedral,
            "threads": threads}));
        if args.json {
            println!("{ratio}");
        } else {
            println!(
                "default preset, 512 × 128: best PyTorch-CPU variant {best_s:.3} s ({}); psneus {default_normals} (the default) {ours:.3} s per step, {:.2}× faster; tetrahedral {ours_tetrahedral:.3} s, {:.2}× faster",
                ratio["peer_best"],
                best_s / ours,
                best_s / ours_tetrahedral
            );
        }
    }
    Ok(())
}
