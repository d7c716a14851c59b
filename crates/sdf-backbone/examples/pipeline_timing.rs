//! Times one training step (forward + backward of the whole render + loss pipeline) on random
//! rays, for a Neuralangelo-style CPU configuration (a profiling aid, not the benchmark of
//! issue #4): `cargo run --release -p sdf-backbone --example pipeline_timing [rays] [samples] [chunk]`.
use sdf_backbone::*;
use std::time::Instant;

fn main() {
    let args: Vec<usize> = std::env::args().skip(1).filter_map(|a| a.parse().ok()).collect();
    let (n_rays, n_samples) = (args.first().copied().unwrap_or(512), args.get(1).copied().unwrap_or(64));
    let (pipeline, params) = build(Preset::NeuralangeloCpu, 0.5, 1);
    let n = params.len();
    let rays: Vec<RayInput<f32>> = (0..n_rays)
        .map(|r| {
            let a = r as f32 * 0.01;
            RayInput {
                origin: [3.0 * a.cos(), 3.0 * a.sin(), 0.3],
                direction: [-a.cos(), -a.sin(), -0.1],
                depths: (0..=n_samples).map(|i| 2.0 + 2.0 * i as f32 / n_samples as f32).collect(),
                target: [0.5, 0.4, 0.3],
                mask: Some(1.0),
            }
        })
        .collect();
    let mut grads = vec![0.0f32; n];
    // Rays per work item (each has its own gradient buffer and goes through each network at once).
    let chunk = args.get(2).copied().unwrap_or(32);
    let _ = pipeline.loss_parallel(&params, &rays, &mut grads, chunk, &NoSampleLoss);
    let steps = 3;
    let t = Instant::now();
    for _ in 0..steps {
        grads.fill(0.0);
        let _ = pipeline.loss_parallel(&params, &rays, &mut grads, chunk, &NoSampleLoss);
    }
    let per_step = t.elapsed().as_secs_f64() / steps as f64;
    let evaluations = n_rays * (5 * n_samples + 1);
    println!(
        "{n_rays} rays × {n_samples} samples ({evaluations} SDF evaluations incl. normals), {n} parameters, chunks of {chunk} rays: {:.3} s per step on {} threads",
        per_step,
        rayon::current_num_threads()
    );
}
