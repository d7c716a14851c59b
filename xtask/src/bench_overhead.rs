//! `cargo xtask bench overhead --run RUN`: the guided sampler's cost per iteration, measured
//! side by side with uniform sampling on the same trained model (iterations alternate between
//! the two, so machine noise hits both alike).

use crate::train::{RestoredRun, StepInputs, guide};
use anyhow::Result;
use serde_json::json;
use std::path::Path;
use std::time::Instant;

/// Runs the benchmark on the model of `run` for `iterations` pairs.
pub fn run(run_dir: &Path, iterations: u64, json_out: bool) -> Result<()> {
    let run = RestoredRun::load(run_dir)?;
    let (train_views, train_cameras, use_masks) = run.training_views();
    let inputs = StepInputs {
        config: &run.config,
        backbone: &run.backbone,
        scene: run.scene(),
        train_views: &train_views,
        train_cameras: &train_cameras,
        use_masks,
    };
    // Grid updates: the mean of three.
    let mut update_seconds = 0.0;
    let mut sampler = None;
    for _ in 0..3 {
        let (s, secs) = guide(&run.config, &run.backbone, &run.params, &train_cameras)?;
        update_seconds += secs / 3.0;
        sampler = Some(s);
    }
    let sampler = sampler.expect("three updates");
    let mut grads = vec![0.0f32; run.params.len()];
    let (mut uniform, mut guided) = (0.0, 0.0);
    // Warm-up pair, then alternate which sampler goes first.
    for i in 0..=iterations {
        let mut times = [0.0; 2];
        for k in 0..2 {
            let which = (k + i as usize) % 2; // 0 uniform, 1 guided
            grads.fill(0.0);
            let t = Instant::now();
            // Iterations spread over the run, so the uniform/guided mix follows its schedule.
            let step = i * run.config.steps / (iterations + 1);
            let _ = inputs.gradient(&run.params, step, (which == 1).then_some(&sampler), &mut grads);
            times[which] = t.elapsed().as_secs_f64();
        }
        if i > 0 {
            uniform += times[0] / iterations as f64;
            guided += times[1] / iterations as f64;
        }
    }
    let per_iteration_update = update_seconds / run.config.guide.update_every as f64;
    let overhead = (guided + per_iteration_update) / uniform - 1.0;
    let result = json!({
        "figure": "sampler_overhead", "run": run_dir.display().to_string(), "iterations": iterations,
        "rays": run.config.render.rays, "samples": run.config.render.coarse + run.config.render.fine,
        "uniform_s": uniform, "guided_s": guided, "grid_update_s": update_seconds, "update_every": run.config.guide.update_every,
        "overhead": overhead, "threads": rayon::current_num_threads(),
    });
    if json_out {
        println!("{result}");
    } else {
        println!(
            "{} rays × {} samples, {iterations} alternating pairs on the model of {}: uniform {uniform:.4} s, guided {guided:.4} s per iteration (draw + rays + forward + backward); grid update {update_seconds:.3} s every {} iterations = {per_iteration_update:.4} s; guided costs {:+.1} % per iteration",
            run.config.render.rays,
            run.config.render.coarse + run.config.render.fine,
            run_dir.display(),
            run.config.guide.update_every,
            100.0 * overhead
        );
    }
    Ok(())
}
