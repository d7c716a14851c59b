//! `cargo xtask bench backbone`: training-step cost of each backbone preset, FLOP per sample and
//! the rate achieved inside the MLPs against this machine's measured f32 matrix-product rate.

use anyhow::Result;
use rayon::prelude::*;
use sdf_backbone::{Backbone, Module, NoSampleLoss, NormalScheme, Preset, RayInput, batch_gradients, build};
use serde_json::json;
use std::time::Instant;

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

/// The f32 matrix-product rate of this machine: 256³ products with ndarray's `dot` (the
/// matrixmultiply sgemm kernels), one independent product per thread, GFLOP/s over all threads.
pub fn gemm_rate() -> f64 {
    let n = 256;
    let threads = rayon::current_num_threads();
    let a = ndarray::Array2::<f32>::from_elem((n, n), 1.0);
    let b = ndarray::Array2::<f32>::from_elem((n, n), 0.5);
    let reps = 40;
    let run = || {
        (0..threads).into_par_iter().for_each(|_| {
            for _ in 0..reps {
                std::hint::black_box(a.dot(&b));
            }
        })
    };
    run();
    let t = Instant::now();
    run();
    let secs = t.elapsed().as_secs_f64();
    2.0 * (n * n * n) as f64 * reps as f64 * threads as f64 / secs / 1e9
}

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
            }
        })
        .collect()
}

fn time_step(backbone: &Backbone, params: &[f32], rays: &[RayInput<f32>], reps: usize) -> f64 {
    let mut grads = vec![0.0f32; params.len()];
    let _ = backbone.loss_parallel(params, rays, &mut grads, 32, &NoSampleLoss);
    let t = Instant::now();
    for _ in 0..reps {
        grads.fill(0.0);
        let _ = backbone.loss_parallel(params, rays, &mut grads, 32, &NoSampleLoss);
    }
    t.elapsed().as_secs_f64() / reps as f64
}

/// Seconds for forward + backward of `mlp` over `rows` random rows (parallel chunks).
fn time_mlp(mlp: &sdf_backbone::Mlp, params: &[f32], rows: usize) -> f64 {
    let n_in = Module::<f32>::n_inputs(mlp);
    let x: Vec<f32> = (0..rows * n_in).map(|i| ((i * 7919) % 1000) as f32 / 1000.0 - 0.5).collect();
    let mut grads = vec![0.0f32; params.len()];
    let run = |g: &mut [f32]| {
        batch_gradients(mlp, params, &x, 1024, g, |_, _, dy| {
            dy.fill(1e-3);
            0.0
        })
    };
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

/// Runs the benchmark; `quick` skips the paper-scale presets.
pub fn run(json: bool, quick: bool) -> Result<()> {
    let threads = rayon::current_num_threads();
    let gemm = gemm_rate();
    if json {
        println!("{}", json!({"figure": "gemm_rate", "gflops": gemm, "threads": threads, "shape": "256x256x256 sgemm per thread (matrixmultiply)"}));
    } else {
        println!("f32 matrix product (matrixmultiply sgemm 256³, one per thread, {threads} threads): {gemm:.1} GFLOP/s");
        println!("| preset | sizes | rays × samples | normals | step (s) | samples/s | FLOP/sample | GFLOP/s (step) | MLP GFLOP/s | MLP / GEMM |");
        println!("|---|---|---|---|---|---|---|---|---|---|");
    }
    let mut presets = vec![(Preset::NeuralangeloCpu, 512, 128), (Preset::NeusCpu, 512, 128)];
    // Paper-scale Neuralangelo is not timed: its 16 × 2²² × 8 hash tables are 537 M parameters
    // (2.1 GB), and with Adam's moments and one dense gradient buffer per ray chunk a step needs
    // ~10 GB (sparse per-thread gradient accumulation would fix that; not done).
    if !quick {
        presets.push((Preset::Neus, 64, 128));
    }
    for (preset, n_rays, n_samples) in presets {
        let (mut backbone, params) = build(preset, 0.5, 1);
        let rays = rays(n_rays, n_samples);
        let layout = backbone.layout();
        let sdf_mlp = &backbone.sdf.b;
        let (sdf_macs, color_macs) = (mlp_macs(sdf_mlp), mlp_macs(&backbone.color));
        let sizes = format!(
            "{} params; SDF MLP {}×{}; colour MLP {}×{}{}",
            params.len(),
            sdf_mlp.config().hidden_layers,
            sdf_mlp.config().width,
            backbone.color.config().hidden_layers,
            backbone.color.config().width,
            match backbone.levels() {
                Some(l) => format!("; hash grid {l} levels, {} table entries", layout.encoding.len()),
                None => "; positional encoding".into(),
            }
        );
        for normals in [NormalScheme::Tetrahedral, NormalScheme::Central] {
            backbone.config.normals = normals;
            let probes = if normals == NormalScheme::Tetrahedral { 4 } else { 6 };
            let reps = if n_rays >= 512 { 3 } else { 1 };
            let step = time_step(&backbone, &params, &rays, reps);
            let samples = (n_rays * n_samples) as f64;
            // Forward 2·MACs, backward 4·MACs (input and weight gradients) per row.
            let flop_per_sample = 6.0 * ((probes + 1) as f64 * sdf_macs + color_macs);
            let sdf_rows = n_rays * ((probes + 1) * n_samples + 1);
            let t_mlp = time_mlp(sdf_mlp, &params[layout.sdf_mlp.clone()], sdf_rows)
                + time_mlp(&backbone.color, &params[layout.color.clone()], n_rays * n_samples);
            let mlp_gflops = flop_per_sample * samples / t_mlp / 1e9;
            let step_gflops = flop_per_sample * samples / step / 1e9;
            let name = format!("{normals:?}").to_lowercase();
            if json {
                println!(
                    "{}",
                    json!({"figure": "backbone_step", "preset": preset.name(), "sizes": sizes, "rays": n_rays, "samples": n_samples, "normals": name,
                        "step_s": step, "samples_per_s": samples / step, "flop_per_sample": flop_per_sample, "step_gflops": step_gflops,
                        "mlp_s": t_mlp, "mlp_gflops": mlp_gflops, "mlp_fraction_of_gemm": mlp_gflops / gemm, "threads": threads})
                );
            } else {
                println!(
                    "| {} | {sizes} | {n_rays} × {n_samples} | {name} | {step:.3} | {:.0} | {:.2e} | {step_gflops:.1} | {mlp_gflops:.1} | {:.0} % |",
                    preset.name(),
                    samples / step,
                    flop_per_sample,
                    100.0 * mlp_gflops / gemm
                );
            }
        }
    }
    let rss = peak_rss_mb();
    if json {
        println!("{}", json!({"figure": "peak_memory", "mb": rss}));
    } else {
        println!("peak resident memory: {:.0} MB", rss.unwrap_or(f64::NAN));
    }
    Ok(())
}
