//! Helpers shared by the gradient checks: a module's finite-difference check, random
//! parameters, and a loss on the samples that touches what the surface losses touch.
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
