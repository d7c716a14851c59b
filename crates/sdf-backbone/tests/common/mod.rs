//! Helpers shared by the gradient checks: a module's finite-difference check, random
//! parameters, a loss on the samples that touches what the surface losses touch, a small
//! hash-grid pipeline with rays through it, and rays through the default preset's sphere.
#![allow(dead_code)] // each test crate uses a subset

use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
use sdf_backbone::*;

/// Checks ∂L/∂params and ∂L/∂input of `L = Σ r ⊙ module(x)` against central differences.
/// Returns the largest relative error (|a − n| / max(|a|, |n|, 1e-3)).
pub fn grad_check<M: Module<f64>>(module: &M, params: &[f64], rows: usize, seed: u64) -> f64 {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let input: Vec<f64> = (0..rows * module.n_inputs()).map(|_| rng.random::<f64>() * 1.6 - 0.8).collect();
    let r: Vec<f64> = (0..rows * module.n_outputs()).map(|_| rng.random::<f64>() * 2.0 - 1.0).collect();
    let loss = |p: &[f64], x: &[f64]| {
        let mut out = vec![0.0; rows * module.n_outputs()];
        let mut ctx = vec![0.0; rows * module.ctx_per_row()];
        module.forward(p, x, &mut out, &mut ctx);
        out.iter().zip(&r).map(|(a, b)| a * b).sum::<f64>()
    };
    let mut out = vec![0.0; rows * module.n_outputs()];
    let mut ctx = vec![0.0; rows * module.ctx_per_row()];
    module.forward(params, &input, &mut out, &mut ctx);
    let mut d_params = vec![0.0; params.len()];
    let mut d_input = vec![0.0; input.len()];
    module.backward(params, &input, &ctx, &r, &mut d_params, Some(&mut d_input));
    let h = 1e-6;
    let mut worst = 0.0f64;
    let rel = |a: f64, n: f64| (a - n).abs() / a.abs().max(n.abs()).max(1e-3);
    for i in 0..params.len() {
        let (mut plus, mut minus) = (params.to_vec(), params.to_vec());
        plus[i] += h;
        minus[i] -= h;
        let numeric = (loss(&plus, &input) - loss(&minus, &input)) / (2.0 * h);
        worst = worst.max(rel(d_params[i], numeric));
    }
    for i in 0..input.len() {
        let (mut plus, mut minus) = (input.clone(), input.clone());
        plus[i] += h;
        minus[i] -= h;
        let numeric = (loss(params, &plus) - loss(params, &minus)) / (2.0 * h);
        worst = worst.max(rel(d_input[i], numeric));
    }
    worst
}

pub fn random_params(n: usize, scale: f64, seed: u64) -> Vec<f64> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    (0..n).map(|_| (rng.random::<f64>() * 2.0 - 1.0) * scale).collect()
}

/// A per-ray loss on the samples for the checks: Σ (S·w)² + 0.3 Σ S·t (touches SDF values,
/// weights and depths the way the surface losses do).
pub struct TestSampleLoss;

impl SampleLoss for TestSampleLoss {
    fn ray_loss(&self, ray: usize, _s: f64, t: &[f64], sdf: &[f64], w: &[f64], d_sdf: &mut [f64], d_w: &mut [f64]) -> f64 {
        let scale = 1.0 + ray as f64;
        let mut loss = 0.0;
        for i in 0..w.len() {
            loss += scale * (sdf[i] * w[i]).powi(2);
            d_sdf[i] += scale * 2.0 * sdf[i] * w[i] * w[i];
            d_w[i] += scale * 2.0 * sdf[i] * sdf[i] * w[i];
        }
        for i in 0..sdf.len() {
            loss += 0.3 * sdf[i] * t[i];
            d_sdf[i] += 0.3 * t[i];
        }
        loss
    }
}

/// The small hash-grid pipeline of the render-pass and guard tests.
pub type Grid = Pipeline<Chain<WithInput<HashGrid>, Mlp>, Mlp>;

/// A small hash-grid pipeline (normals by `normals`), with a learned background or the fixed
/// grey, its parameters (v set so that s = e^(10 v)), and rays through it.
pub fn small_grid_pipeline(normals: NormalScheme, learned_background: bool, v: f64) -> (Grid, Vec<f64>, Vec<RayInput<f64>>) {
    let grid = HashGrid::new(HashGridConfig { levels: 3, features: 2, log2_table: 8, base_resolution: 2, finest_resolution: 12 });
    let mlp = |n_inputs, n_outputs, hidden_activation, output_activation| {
        Mlp::new(MlpConfig { n_inputs, width: 8, hidden_layers: 1, n_outputs, skip: None, hidden_activation, output_activation })
    };
    let mut pipeline = Pipeline {
        sdf: Chain { a: WithInput { encoding: grid }, b: mlp(3 + 6, 1 + 3, Activation::Softplus { beta: 10.0 }, Activation::Identity) },
        color: mlp(22 + 3, 3, Activation::Relu, Activation::Sigmoid),
        background: learned_background.then(|| BackgroundModel::with_view(4, 2, 8, 1, true)),
        config: PipelineConfig {
            color_loss: ColorLoss::L2,
            eikonal_weight: 0.1,
            mask_weight: 0.0,
            normal_step: 1e-2,
            normals: Differences::Central,
            curvature_weight: 0.0,
            background: [0.2, 0.4, 0.6],
            masked_color: false,
            opacity_entropy: 0.0,
            opacity_sparsity: 0.0,
            opacity_guard: None,
            normal_smoothness: 0.0,
            normal_smoothness_region: SmoothnessRegion::Everywhere,
        },
        analytic: None,
    };
    pipeline.set_normals(normals);
    let mut params = random_params(pipeline.n_params::<f64>(), 0.3, 7);
    let n_sdf = Module::<f64>::n_params(&pipeline.sdf);
    let n_col = Module::<f64>::n_params(&pipeline.color);
    params[n_sdf + n_col] = v;
    let rays = (0..9)
        .map(|r| {
            let d = [0.15 * (r % 3) as f64 - 0.15, 0.1 * (r / 3) as f64 - 0.1, 1.0];
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            RayInput {
                origin: [-0.1, 0.05 * r as f64 - 0.2, -1.0],
                direction: d.map(|v| v / len),
                depths: (0..24).map(|i| 0.2 + 0.07 * i as f64 + 0.003 * r as f64).collect(),
                target: [0.0; 3],
                mask: None,
                weight: 1.0,
            }
        })
        .collect();
    (pipeline, params, rays)
}

/// The largest relative error (|a − n| / max(|a|, |n|, 1e-4)) of `pipeline`'s loss gradient
/// over `rays` against central differences (h = 1e-6) in every parameter; each parameter off by
/// more than 1e-5 is printed.
pub fn pipeline_gradient_error<S: DeferringModule<f64>, C: Module<f64>>(pipeline: &Pipeline<S, C>, params: &[f64], rays: &[RayInput<f64>]) -> f64 {
    let n = params.len();
    let mut grads = vec![0.0; n];
    let (loss, out) = pipeline.loss(params, rays, Some(&mut grads), &TestSampleLoss);
    assert!(loss.is_finite() && out.len() == rays.len());
    let h = 1e-6;
    let mut worst = 0.0f64;
    for i in 0..n {
        let (mut p, mut m) = (params.to_vec(), params.to_vec());
        p[i] += h;
        m[i] -= h;
        let numeric = (pipeline.loss(&p, rays, None, &TestSampleLoss).0 - pipeline.loss(&m, rays, None, &TestSampleLoss).0) / (2.0 * h);
        let rel = (grads[i] - numeric).abs() / grads[i].abs().max(numeric.abs()).max(1e-4);
        if rel > 1e-5 {
            eprintln!("param {i}/{n}: analytic {:e} numeric {numeric:e}", grads[i]);
        }
        worst = worst.max(rel);
    }
    worst
}

/// `n_rays` rays from a circle of radius 3 towards the axis, each with `n_samples` intervals
/// over depths 2 … 4 (through the preset's initial sphere) and a constant target.
pub fn rays_through_the_sphere<R: Real>(n_rays: usize, n_samples: usize) -> Vec<RayInput<R>> {
    (0..n_rays)
        .map(|r| {
            let a = r as f64 * 0.05;
            RayInput {
                origin: [R::of(3.0 * a.cos()), R::of(3.0 * a.sin()), R::of(0.3)],
                direction: [R::of(-a.cos()), R::of(-a.sin()), R::of(-0.1)],
                depths: (0..=n_samples).map(|i| R::of(2.0 + 2.0 * i as f64 / n_samples as f64)).collect(),
                target: [R::of(0.5), R::of(0.4), R::of(0.3)],
                mask: Some(R::ONE),
                weight: R::ONE,
            }
        })
        .collect()
}
