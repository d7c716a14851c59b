//! Finite-difference gradient checks in f64 for every module, and the geometric initialisation.

use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
use sdf_backbone::*;

/// Checks ∂L/∂params and ∂L/∂input of `L = Σ r ⊙ module(x)` against central differences.
/// Returns the largest relative error (|a − n| / max(|a|, |n|, 1e-3)).
fn grad_check<M: Module<f64>>(module: &M, params: &[f64], rows: usize, seed: u64) -> f64 {
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

fn random_params(n: usize, scale: f64, seed: u64) -> Vec<f64> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    (0..n).map(|_| (rng.random::<f64>() * 2.0 - 1.0) * scale).collect()
}

#[test]
fn mlp_gradients_match_finite_differences_for_every_activation() {
    // Softplus with β = 100 is nearly a kink: use β = 10 so that central differences with
    // h = 1e-6 stay in one regime; β = 100 is checked on its own below.
    for (hidden, output) in [
        (Activation::Softplus { beta: 10.0 }, Activation::Identity),
        (Activation::Relu, Activation::Sigmoid),
        (Activation::Sigmoid, Activation::Softplus { beta: 2.0 }),
    ] {
        for skip in [None, Some(2)] {
            let mlp = Mlp::new(MlpConfig { n_inputs: 3, width: 7, hidden_layers: 3, n_outputs: 4, skip, hidden_activation: hidden, output_activation: output });
            let params = random_params(Module::<f64>::n_params(&mlp), 0.6, 1);
            let err = grad_check(&mlp, &params, 5, 2);
            assert!(err <= 1e-5, "{hidden:?}/{output:?} skip {skip:?}: relative error {err:e}");
        }
    }
}

#[test]
fn softplus_beta_100_gradient_matches_where_smooth() {
    let mlp = Mlp::new(MlpConfig {
        n_inputs: 3, width: 6, hidden_layers: 2, n_outputs: 2, skip: None,
        hidden_activation: Activation::Softplus { beta: 100.0 }, output_activation: Activation::Identity,
    });
    let params = random_params(Module::<f64>::n_params(&mlp), 0.5, 3);
    let err = grad_check(&mlp, &params, 4, 4);
    assert!(err <= 1e-5, "relative error {err:e}");
}

#[test]
fn positional_encoding_and_chain_gradients_match() {
    let pe = PositionalEncoding { frequencies: 4 };
    assert!(grad_check(&pe, &[], 6, 5) <= 1e-6);
    let mlp = Mlp::new(MlpConfig {
        n_inputs: Module::<f64>::n_outputs(&pe), width: 8, hidden_layers: 3, n_outputs: 3, skip: Some(2),
        hidden_activation: Activation::Softplus { beta: 10.0 }, output_activation: Activation::Identity,
    });
    let net = Chain { a: pe, b: mlp };
    let params = random_params(Module::<f64>::n_params(&net), 0.4, 6);
    let err = grad_check(&net, &params, 4, 7);
    assert!(err <= 1e-5, "relative error {err:e}");
}

/// NeuS's geometric initialisation at NeuS's size (PE 6 → 8 × 256 softplus(100), skip at 4 →
/// 1 + 32) approximates |x| − r *on average*; at finite width the random features leave
/// fluctuations of ±0.2 (measured: mean error −0.012, max 0.23 inside the unit sphere). The
/// issue asks for ≤ 1e-2 everywhere, which this recipe does not give; a post-initialisation
/// calibration is the next step (noted on issue #4). This test guards the recipe itself.
#[test]
fn geometric_init_approximates_a_sphere_sdf_on_average() {
    let pe = PositionalEncoding { frequencies: 6 };
    let mlp = Mlp::new(MlpConfig {
        n_inputs: Module::<f32>::n_outputs(&pe), width: 256, hidden_layers: 8, n_outputs: 33, skip: Some(4),
        hidden_activation: Activation::Softplus { beta: 100.0 }, output_activation: Activation::Identity,
    });
    let mut params = vec![0.0f32; Module::<f32>::n_params(&mlp)];
    let radius = 0.5;
    mlp.init_geometric(&mut params, radius, 3, 9);
    let net = Chain { a: pe, b: mlp };
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(10);
    let rows = 2000;
    let mut x = Vec::with_capacity(rows * 3);
    while x.len() < rows * 3 {
        let p = [rng.random::<f32>() * 2.0 - 1.0, rng.random::<f32>() * 2.0 - 1.0, rng.random::<f32>() * 2.0 - 1.0];
        if p.iter().map(|v| v * v).sum::<f32>() < 1.0 {
            x.extend_from_slice(&p);
        }
    }
    let mut out = vec![0.0f32; rows * 33];
    let mut ctx = vec![0.0f32; rows * Module::<f32>::ctx_per_row(&net)];
    net.forward(&params, &x, &mut out, &mut ctx);
    let errors: Vec<f32> = (0..rows)
        .map(|r| {
            let p = &x[3 * r..3 * r + 3];
            let truth = p.iter().map(|v| v * v).sum::<f32>().sqrt() - radius as f32;
            out[33 * r] - truth
        })
        .collect();
    let worst = errors.iter().fold(0.0f32, |a, e| a.max(e.abs()));
    let mean = errors.iter().sum::<f32>() / rows as f32;
    let mean_abs = errors.iter().map(|e| e.abs()).sum::<f32>() / rows as f32;
    assert!(mean.abs() <= 0.03, "mean SDF − (|x| − r) = {mean}");
    assert!(mean_abs <= 0.1, "mean |SDF − (|x| − r)| = {mean_abs}");
    assert!(worst <= 0.3, "max |SDF − (|x| − r)| = {worst}");
    // The zero level set is near the sphere: points at |x| = r ± 0.3 have the right sign.
    let signs_right = (0..rows)
        .filter(|r| {
            let p = &x[3 * r..3 * r + 3];
            let d = p.iter().map(|v| v * v).sum::<f32>().sqrt() - radius as f32;
            d.abs() < 0.3 || (out[33 * r] > 0.0) == (d > 0.0)
        })
        .count();
    assert_eq!(signs_right, rows);
}
