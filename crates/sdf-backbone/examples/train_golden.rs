//! A first end-to-end training run of the pipeline on the built-in golden scene (uniform rays,
//! no guided sampler, no hierarchical sampling): a sanity check that the hand-written gradients
//! train, not the runner of issue #5.
//!
//! `cargo run --release -p sdf-backbone --example train_golden [steps] [rays] [samples]`
use camera_geom::ray_sphere;
use datasets::golden::{self, GoldenSpec};
use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
use sdf_backbone::*;
use std::time::Instant;

fn main() {
    let args: Vec<usize> = std::env::args().skip(1).filter_map(|a| a.parse().ok()).collect();
    let steps = args.first().copied().unwrap_or(300);
    let n_rays = args.get(1).copied().unwrap_or(512);
    let n_samples = args.get(2).copied().unwrap_or(48);
    let mut spec = GoldenSpec::builtin();
    spec.rig.width = 100;
    spec.rig.height = 75;
    spec.backdrop = false; // masked training, black background
    let scene = golden::generate(&spec).expect("built-in scene").scene;

    let (pipeline, mut params) = neuralangelo_cpu(0.5, 1);
    let n = params.len();
    let mut adam = Adam::new(n);
    adam.epsilon = 1e-15;
    let schedule = WarmupCosine { base: 5e-3, warmup: 20, total: steps as u64, final_factor: 0.1 };
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);

    let make_ray = |view: usize, col: u32, row: u32, jitter: f32| -> Option<RayInput<f32>> {
        let v = &scene.views[view];
        let ray = v.camera.ray_through_pixel_index(col, row);
        let (t0, t1) = ray_sphere(&ray, glam::DVec3::ZERO, 1.0)?;
        let (t0, t1) = (t0.max(0.05) as f32, t1 as f32);
        let step = (t1 - t0) / n_samples as f32;
        let depths = (0..=n_samples).map(|i| t0 + (i as f32 + if i < n_samples { jitter } else { 0.0 }) * step).collect();
        let o = ray.origin.as_vec3();
        let d = ray.direction.as_vec3();
        Some(RayInput {
            origin: o.to_array(),
            direction: d.to_array(),
            depths,
            target: v.image.get_f32(col, row),
            mask: v.mask.as_ref().map(|m| if m.get(col, row) { 1.0 } else { 0.0 }),
        })
    };
    let psnr = |params: &[f32], view: usize| -> f64 {
        let v = &scene.views[view];
        let rays: Vec<RayInput<f32>> =
            (0..v.camera.height).flat_map(|r| (0..v.camera.width).map(move |c| (c, r))).filter_map(|(c, r)| make_ray(view, c, r, 0.5)).collect();
        let mut g = vec![0.0f32; params.len()];
        let (_, out) = pipeline.loss_parallel(params, &rays, &mut g, 256, &NoSampleLoss);
        let mse: f64 = rays.iter().zip(&out).map(|(ray, o)| (0..3).map(|k| ((o.color[k] - ray.target[k]) as f64).powi(2)).sum::<f64>() / 3.0).sum::<f64>()
            / rays.len() as f64;
        -10.0 * mse.log10()
    };
    println!("built-in scene, 49 views of 100×75, {n} parameters, {n_rays} rays × {n_samples} samples per step");
    println!("step 0: PSNR view 0 = {:.2} dB", psnr(&params, 0));
    let start = Instant::now();
    let mut grads = vec![0.0f32; n];
    for step in 0..steps {
        let rays: Vec<RayInput<f32>> = (0..n_rays)
            .filter_map(|_| {
                let view = rng.random_range(0..scene.views.len());
                let col = rng.random_range(0..spec.rig.width);
                let row = rng.random_range(0..spec.rig.height);
                make_ray(view, col, row, rng.random())
            })
            .collect();
        grads.fill(0.0);
        let (loss, _) = pipeline.loss_parallel(&params, &rays, &mut grads, 64, &NoSampleLoss);
        adam.update(&mut params, &grads, schedule.at(step as u64));
        if (step + 1) % 50 == 0 || step + 1 == steps {
            println!(
                "step {}: loss {loss:.4}, s = {:.1}, {:.2} s/step, PSNR view 0 = {:.2} dB",
                step + 1,
                (10.0 * params[n - 1]).exp(),
                start.elapsed().as_secs_f64() / (step + 1) as f64,
                psnr(&params, 0)
            );
        }
    }
}
