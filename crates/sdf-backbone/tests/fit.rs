//! Fit test: a hash grid + MLP learns an analytic torus SDF from point samples (300 Adam steps of
//! 4096 points, 6 s in the test profile; measured mean |error| near the surface 0.00055, the
//! issue asks ≤ 0.005).

use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
use sdf_backbone::*;

fn torus(p: [f32; 3]) -> f32 {
    let ring = (p[0] * p[0] + p[1] * p[1]).sqrt() - 0.5;
    (ring * ring + p[2] * p[2]).sqrt() - 0.2
}

/// Points: half uniform in [−1, 1]³, half within ±0.05 of the surface (by rejection).
fn samples(rng: &mut Xoshiro256PlusPlus, n: usize) -> Vec<f32> {
    let mut x = Vec::with_capacity(3 * n);
    while x.len() < 3 * n {
        let p = [0, 1, 2].map(|_| rng.random::<f32>() * 2.0 - 1.0);
        if x.len() < 3 * n / 2 || torus(p).abs() < 0.05 {
            x.extend_from_slice(&p);
        }
    }
    x
}

#[test]
fn hash_grid_mlp_learns_a_torus_sdf() {
    let grid = HashGrid::new(HashGridConfig { levels: 8, features: 2, log2_table: 14, base_resolution: 8, finest_resolution: 128 });
    let mlp = Mlp::new(MlpConfig {
        n_inputs: 3 + 16,
        width: 32,
        hidden_layers: 2,
        n_outputs: 1,
        skip: None,
        hidden_activation: Activation::Softplus { beta: 100.0 },
        output_activation: Activation::Identity,
    });
    // Raw coordinates alongside the grid features, as NeuS-style networks do.
    let input = WithInput { encoding: grid };
    let mut params = vec![0.0f32; Module::<f32>::n_params(&input) + Module::<f32>::n_params(&mlp)];
    let split = Module::<f32>::n_params(&input);
    input.encoding.init(&mut params[..split], 1e-4, 1);
    mlp.init_geometric(&mut params[split..], 0.5, 3, 2);
    let net = Chain { a: input, b: mlp };
    let mut adam = Adam::new(params.len());
    adam.epsilon = 1e-15;
    let schedule = WarmupCosine { base: 1e-2, warmup: 50, total: 300, final_factor: 0.05 };
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
    let batch = 4096;
    let mut grads = vec![0.0f32; params.len()];
    for step in 0..schedule.total {
        let x = samples(&mut rng, batch);
        grads.fill(0.0);
        batch_gradients(&net, &params, &x, 512, &mut grads, |x, y, dy| {
            // L1 on the SDF, averaged over the batch.
            let mut l = 0.0;
            for r in 0..y.len() {
                let e = y[r] - torus([x[3 * r], x[3 * r + 1], x[3 * r + 2]]);
                l += e.abs() as f64;
                dy[r] = e.signum() / batch as f32;
            }
            l
        });
        adam.update(&mut params, &grads, schedule.at(step));
    }
    // Mean |error| on fresh points near the surface (|S| < 0.05) and everywhere.
    let x = samples(&mut Xoshiro256PlusPlus::seed_from_u64(99), 20_000);
    let mut y = vec![0.0f32; 20_000];
    let mut ctx = vec![0.0f32; 20_000 * Module::<f32>::ctx_per_row(&net)];
    net.forward(&params, &x, &mut y, &mut ctx);
    let errors: Vec<f32> = (0..20_000).map(|r| (y[r] - torus([x[3 * r], x[3 * r + 1], x[3 * r + 2]])).abs()).collect();
    let near = errors[10_000..].iter().sum::<f32>() / 10_000.0;
    let all = errors.iter().sum::<f32>() / 20_000.0;
    eprintln!("mean |error|: near the surface {near:.5}, all points {all:.5}");
    assert!(near <= 0.005, "mean |error| near the surface {near}");
}
