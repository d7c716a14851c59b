//! `cargo xtask bench overhead --run RUN`: the guided sampler's cost per iteration, measured
//! side by side with uniform sampling on the same trained model (iterations alternate between
//! the two, so machine noise hits both alike).

use anyhow::Result;
use serde_json::json;
use std::path::Path;
use std::time::Instant;
use trainer::config::SamplerKind;
use trainer::run::open_run;
use trainer::trainer::Trainer;

/// Runs the benchmark on the model of `run` for `iterations` pairs.
pub fn run(run_dir: &Path, iterations: u64, json_out: bool) -> Result<()> {
    let mut guided = open_run(run_dir, None)?;
    let mut config = guided.config().clone();
    config.sampler = SamplerKind::Uniform;
    let mut uniform = Trainer::new(config, guided.data().clone())?;
    uniform.set_parameters(&guided.state().params)?;
    // Grid updates: the mean of three.
    let mut update_seconds = 0.0;
    for _ in 0..3 {
        update_seconds += guided.update_grids()?.seconds / 3.0;
    }
    let (mut t_uniform, mut t_guided) = (0.0, 0.0);
    let s = guided.s();
    let iterations_done = guided.state().step.max(1);
    // Warm-up pair, then alternate which sampler goes first.
    for i in 0..=iterations {
        let mut times = [0.0; 2];
        for k in 0..2 {
            let which = (k + i as usize) % 2; // 0 uniform, 1 guided
            let trainer = if which == 0 { &mut uniform } else { &mut guided };
            // Iterations spread over the run, so the uniform/guided mix follows its schedule.
            let progress = i as f64 / (iterations + 1) as f64;
            let step = (progress * iterations_done as f64) as u64;
            let t = Instant::now();
            let batch = trainer.batch(step, progress, s);
            let _ = trainer.gradient(&batch);
            times[which] = t.elapsed().as_secs_f64();
        }
        if i > 0 {
            t_uniform += times[0] / iterations as f64;
            t_guided += times[1] / iterations as f64;
        }
    }
    let config = guided.config();
    // The run's grid updates spread over the iterations it did.
    let per_iteration_update = update_seconds * f64::from(config.guide.updates) / iterations_done as f64;
    let overhead = (t_guided + per_iteration_update) / t_uniform - 1.0;
    let result = crate::machine::tag(json!({
        "figure": "sampler_overhead", "run": run_dir.display().to_string(), "iterations": iterations,
        "rays": config.render.rays, "samples": config.render.coarse + config.render.fine,
        "uniform_s": t_uniform, "guided_s": t_guided, "grid_update_s": update_seconds, "updates": config.guide.updates,
        "overhead": overhead, "threads": rayon::current_num_threads(),
    }));
    if json_out {
        println!("{result}");
    } else {
        println!(
            "{} rays × {} samples, {iterations} alternating pairs on the model of {}: uniform {t_uniform:.4} s, guided {t_guided:.4} s per iteration (draw + rays + forward + backward); grid update {update_seconds:.3} s, {} per run = {per_iteration_update:.4} s per iteration; guided costs {:+.1} % per iteration",
            config.render.rays,
            config.render.coarse + config.render.fine,
            run_dir.display(),
            config.guide.updates,
            100.0 * overhead
        );
    }
    Ok(())
}
