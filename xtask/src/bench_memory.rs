//! `cargo xtask bench memory` and `cargo xtask bench soak`: every backbone preset end to end
//! (a few iterations, mesh, evaluation) with its peak resident memory against the memory
//! model's estimate and the time of each phase; and a long run of the default preset with its
//! resident size sampled along the way (flat after warm-up, or it leaks).
//!
//! Each run is a child `xtask train` in its own process, so that its peak is its own; the
//! figures come from the run's `metrics.json` and `log.jsonl` (`peak_rss_bytes` is the kernel's
//! high-water mark `VmHWM`, `rss_bytes` the resident size when the line was logged).

use anyhow::{Context, Result, bail};
use sdf_backbone::Preset;
use serde_json::{Value, json};
use std::path::Path;
use std::time::Instant;
use trainer::metrics::RunMetrics;

/// Runs `xtask train` in a child process with `overrides` into `out`; its wall time.
fn train_child(out: &Path, overrides: &[String]) -> Result<f64> {
    let started = Instant::now();
    let output = crate::machine::xtask_child()?.arg("train").arg("--out").arg(out).args(overrides).output().context("starting xtask train")?;
    if !output.status.success() {
        let stderr = String::from_utf8_lossy(&output.stderr);
        let tail: Vec<&str> = stderr.lines().rev().take(12).collect();
        bail!("xtask train {} failed ({}):\n{}", overrides.join(" "), output.status, tail.into_iter().rev().collect::<Vec<_>>().join("\n"));
    }
    Ok(started.elapsed().as_secs_f64())
}

/// `bench memory`: each preset for `steps` iterations end to end.
pub fn memory(presets: &[Preset], steps: u64, json_out: bool) -> Result<()> {
    let presets = if presets.is_empty() { &Preset::ALL[..] } else { presets };
    let work = tempfile_dir()?;
    if !json_out {
        println!(
            "| preset | iterations | s / iteration | mesh s | evaluation s | checkpoint-free wall s | peak RSS | estimate | estimate / peak |\n|---|---|---|---|---|---|---|---|---|"
        );
    }
    for preset in presets.iter().map(|p| p.name()) {
        let out = work.join(preset);
        let overrides = vec![
            format!("steps={steps}"),
            format!("model.preset={preset}"),
            "output.validate_every=0".into(),
            "output.checkpoint_every=0".into(),
            "output.metrics_every=0".into(),
        ];
        let wall = train_child(&out, &overrides)?;
        let m = RunMetrics::read(&out)?;
        let peak = m.peak_rss_bytes.context("the peak resident memory is not known on this system")?;
        let estimate = m.memory_estimate_bytes;
        let eval_s = m.eval_s + m.geometry_s;
        if json_out {
            println!(
                "{}",
                crate::machine::tag(json!({"bench": "memory", "preset": preset, "steps": m.steps, "iteration_s": m.iteration_s, "mesh_s": m.mesh_s,
                    "eval_s": eval_s, "wall_s": wall, "peak_rss_bytes": peak, "memory_estimate_bytes": estimate}))
            );
        } else {
            println!(
                "| {preset} | {} | {:.3} | {:.1} | {:.1} | {wall:.0} | {:.2} GB | {:.2} GB | {:.2} |",
                m.steps,
                m.iteration_s,
                m.mesh_s,
                eval_s,
                peak / 1e9,
                estimate / 1e9,
                estimate / peak
            );
        }
        let _ = std::fs::remove_dir_all(&out);
    }
    Ok(())
}

/// `bench soak`: the default preset for `iterations`, resident size every `every` iterations.
pub fn soak(iterations: u64, every: u64, json_out: bool) -> Result<()> {
    let work = tempfile_dir()?;
    let out = work.join("soak");
    let overrides =
        vec![format!("steps={iterations}"), format!("output.log_every={every}"), "output.validate_every=0".into(), "output.metrics_every=0".into()];
    let wall = train_child(&out, &overrides)?;
    let text = std::fs::read_to_string(out.join("log.jsonl")).context("reading the soak run's log")?;
    let samples: Vec<(u64, f64)> = text
        .lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .filter_map(|r| Some((r["step"].as_u64()?, r["rss_bytes"].as_f64()?)))
        .filter(|(s, _)| s % every == 0)
        .collect();
    if samples.len() < 4 {
        bail!("the soak run logged {} resident sizes; too few", samples.len());
    }
    // After warm-up (the first quarter): the spread and the drift (least-squares slope).
    let warm: Vec<(u64, f64)> = samples.iter().copied().filter(|(s, _)| *s as f64 >= 0.25 * iterations as f64).collect();
    if warm.len() < 2 {
        bail!("the soak run logged {} resident sizes after warm-up; too few for a drift", warm.len());
    }
    let (lo, hi) = warm.iter().fold((f64::INFINITY, 0.0f64), |(a, b), (_, r)| (a.min(*r), b.max(*r)));
    let n = warm.len() as f64;
    let (mx, my) = (warm.iter().map(|(s, _)| *s as f64).sum::<f64>() / n, warm.iter().map(|(_, r)| *r).sum::<f64>() / n);
    let slope = warm.iter().map(|(s, r)| (*s as f64 - mx) * (r - my)).sum::<f64>() / warm.iter().map(|(s, _)| (*s as f64 - mx).powi(2)).sum::<f64>();
    let m = RunMetrics::read(&out)?;
    if json_out {
        println!(
            "{}",
            crate::machine::tag(
                json!({"bench": "soak", "iterations": iterations, "wall_s": wall, "samples": samples, "after_warmup_min": lo, "after_warmup_max": hi,
                "slope_bytes_per_1000_iterations": slope * 1000.0, "peak_rss_bytes": m.peak_rss_bytes})
            )
        );
    } else {
        println!("| iteration | resident (MB) |\n|---|---|");
        for (s, r) in &samples {
            println!("| {s} | {:.1} |", r / 1e6);
        }
        println!(
            "\nafter warm-up (iterations ≥ {}): {:.1}–{:.1} MB, drift {:+.2} MB per 1000 iterations; peak {:.1} MB; {iterations} iterations in {wall:.0} s",
            iterations / 4,
            lo / 1e6,
            hi / 1e6,
            slope * 1000.0 / 1e6,
            m.peak_rss_bytes.unwrap_or(f64::NAN) / 1e6
        );
    }
    let _ = std::fs::remove_dir_all(&out);
    Ok(())
}

/// A fresh folder under the system's temporary directory.
fn tempfile_dir() -> Result<std::path::PathBuf> {
    let dir = std::env::temp_dir().join(format!("psneus-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    Ok(dir)
}
