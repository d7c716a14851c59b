//! `cargo xtask compare`: uniform and guided training with the same seed, rays and samples per
//! ray, side by side: a table (Chamfer, F-score, PSNR whole/masked, wall time, time per
//! iteration) and a plot of Chamfer and PSNR against iterations.

use crate::draw::{plot, text};
use crate::run::{Outcome, RunSummary, TrainArgs, train};
use anyhow::Result;
use datasets::images::RgbImage;
use datasets::io::write_atomic;
use serde_json::json;
use std::path::PathBuf;

/// Options of `cargo xtask compare`.
#[derive(clap::Args, Debug)]
pub struct CompareArgs {
    /// Dataset folder (default: the built-in scene).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Iterations of each run (default: the config's `steps`).
    #[arg(long)]
    pub iters: Option<u64>,
    /// TOML configuration shared by both runs.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Output folder (one run folder per sampler, compare.md, compare.json, compare.png).
    #[arg(long, default_value = "out/compare")]
    pub out: PathBuf,
    /// Seed shared by both runs.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Points on the metric curves per run.
    #[arg(long, default_value_t = 4)]
    pub points: u64,
    /// Configuration overrides `key=value`, for both runs.
    pub overrides: Vec<String>,
}

fn field(s: &RunSummary, key: &str) -> f64 {
    s.metrics[key].as_f64().unwrap_or(f64::NAN)
}

/// Runs `cargo xtask compare`.
pub fn run(args: &CompareArgs, stop: &std::sync::atomic::AtomicBool) -> Result<()> {
    let mut overrides = args.overrides.clone();
    if let Some(n) = args.iters {
        overrides.push(format!("steps={n}"));
    }
    let steps = crate::config::TrainConfig::load(args.config.as_deref(), &overrides)?.steps;
    overrides.push(format!("output.metrics_every={}", (steps / args.points.max(1)).max(1)));
    let mut runs = Vec::new();
    for sampler in ["uniform", "guided"] {
        let train_args = TrainArgs {
            data: args.data.clone(),
            config: args.config.clone(),
            sampler: Some(sampler.into()),
            out: args.out.join(sampler),
            seed: Some(args.seed),
            overrides: overrides.clone(),
            ..TrainArgs::default()
        };
        match train(&train_args, stop)? {
            Outcome::Finished(summary) => runs.push((sampler, *summary)),
            Outcome::Stopped { step, .. } => anyhow::bail!("the {sampler} run was stopped at step {step}"),
        }
    }
    let mut table = String::from(
        "| sampler | Chamfer | F-score | PSNR (dB) | PSNR masked (dB) | wall time (s) | time / iteration (s) |\n|---|---|---|---|---|---|---|\n",
    );
    for (name, s) in &runs {
        table += &format!(
            "| {name} | {:.5} | {:.3} | {:.2} | {:.2} | {:.0} | {:.3} |\n",
            field(s, "chamfer"),
            field(s, "f_score"),
            field(s, "psnr"),
            field(s, "psnr_masked"),
            field(s, "train_s"),
            field(s, "iteration_s")
        );
    }
    let (u, g) = (&runs[0].1, &runs[1].1);
    let overhead = 100.0 * (field(g, "iteration_s") / field(u, "iteration_s") - 1.0);
    table += &format!("\nguided vs uniform: time per iteration {overhead:+.1} % (grid updates included).\n");
    print!("{table}");
    std::fs::create_dir_all(&args.out)?;
    write_atomic(&args.out.join("compare.md"), table.as_bytes())?;
    let summary = json!({"steps": steps, "seed": args.seed, "runs": runs.iter().map(|(n, s)| json!({"sampler": n, "metrics": s.metrics, "history": s.history})).collect::<Vec<_>>()});
    write_atomic(&args.out.join("compare.json"), serde_json::to_string_pretty(&summary)?.as_bytes())?;

    // Chamfer (top) and PSNR (bottom) against iterations: uniform blue, guided red.
    let (blue, red) = ([0.15, 0.35, 0.85], [0.85, 0.15, 0.15]);
    let curve =
        |s: &RunSummary, key: &str| -> Vec<(f64, f64)> { s.history.iter().filter_map(|h| Some((h["step"].as_f64()?, h[key].as_f64()?))).collect() };
    let (w, h) = (480u32, 240u32);
    let mut img = RgbImage::new(w, 2 * h);
    for (row, key) in ["chamfer", "psnr"].iter().enumerate() {
        let panel = plot(w, h, &[(blue, curve(u, key)), (red, curve(g, key))], &[]);
        for y in 0..h {
            for x in 0..w {
                img.set_f32(x, row as u32 * h + y, panel.get_f32(x, y));
            }
        }
        // Labels: the panel's maximum value at its top left (digits only).
        let peak = curve(u, key).into_iter().chain(curve(g, key)).map(|p| p.1).fold(0.0f64, f64::max);
        text(&mut img, 24, row as i64 * h as i64 + 4, &format!("{peak:.4}"), 2, [0.2; 3]);
    }
    img.save_png(&args.out.join("compare.png"))?;
    println!("table, JSON and plot (top: Chamfer, bottom: PSNR; blue uniform, red guided) in {}", args.out.display());
    Ok(())
}
