//! Finite-difference gradient checks in f64 for every module (MLP, encodings, hash grid, their
//! tangents), and the geometric initialisation.

mod common;

use common::*;
use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
use sdf_backbone::*;

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
            let mlp = Mlp::new(MlpConfig {
                n_inputs: 3,
                width: 7,
                hidden_layers: 3,
                n_outputs: 4,
                skip,
                hidden_activation: hidden,
                output_activation: output,
            });
            let params = random_params(Module::<f64>::n_params(&mlp), 0.6, 1);
            let err = grad_check(&mlp, &params, 5, 2);
            assert!(err <= 1e-5, "{hidden:?}/{output:?} skip {skip:?}: relative error {err:e}");
        }
    }
}

#[test]
fn mlp_batch_equals_row_by_row() {
    // A batch of 600 rows (several kernel tiles and a partial one), with the skip connection,
    // gives each row's output and input gradient, and the sum of the rows' parameter
    // gradients, as each row alone does.
    let mlp = Mlp::new(MlpConfig {
        n_inputs: 3,
        width: 9,
        hidden_layers: 3,
        n_outputs: 2,
        skip: Some(2),
        hidden_activation: Activation::Softplus { beta: 10.0 },
        output_activation: Activation::Identity,
    });
    let params = random_params(Module::<f64>::n_params(&mlp), 0.6, 3);
    let rows = 600;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
    let input: Vec<f64> = (0..rows * 3).map(|_| rng.random::<f64>() * 1.6 - 0.8).collect();
    let d_out: Vec<f64> = (0..rows * 2).map(|_| rng.random::<f64>() * 2.0 - 1.0).collect();
    let pass = |x: &[f64], dy: &[f64], d_params: &mut [f64]| {
        let n = x.len() / 3;
        let (mut out, mut ctx, mut d_x) = (vec![0.0; n * 2], vec![0.0; n * Module::<f64>::ctx_per_row(&mlp)], vec![0.0; n * 3]);
        mlp.forward(&params, x, &mut out, &mut ctx);
        mlp.backward(&params, x, &ctx, dy, d_params, Some(&mut d_x));
        (out, d_x)
    };
    let mut d_batch = vec![0.0; params.len()];
    let (out, d_x) = pass(&input, &d_out, &mut d_batch);
    let mut d_rows = vec![0.0; params.len()];
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * a.abs().max(b.abs()).max(1.0);
    for r in 0..rows {
        let (o, dx) = pass(&input[3 * r..3 * r + 3], &d_out[2 * r..2 * r + 2], &mut d_rows);
        assert!(o.iter().zip(&out[2 * r..2 * r + 2]).all(|(a, b)| close(*a, *b)), "row {r}: output");
        assert!(dx.iter().zip(&d_x[3 * r..3 * r + 3]).all(|(a, b)| close(*a, *b)), "row {r}: input gradient");
    }
    for (i, (a, b)) in d_batch.iter().zip(&d_rows).enumerate() {
        assert!((a - b).abs() <= 1e-10 * a.abs().max(b.abs()).max(1.0), "parameter {i}: {a} vs {b}");
    }
}

#[test]
fn softplus_beta_100_gradient_matches_where_smooth() {
    let mlp = Mlp::new(MlpConfig {
        n_inputs: 3,
        width: 6,
        hidden_layers: 2,
        n_outputs: 2,
        skip: None,
        hidden_activation: Activation::Softplus { beta: 100.0 },
        output_activation: Activation::Identity,
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
        n_inputs: Module::<f64>::n_outputs(&pe),
        width: 8,
        hidden_layers: 3,
        n_outputs: 3,
        skip: Some(2),
        hidden_activation: Activation::Softplus { beta: 10.0 },
        output_activation: Activation::Identity,
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
        n_inputs: Module::<f32>::n_outputs(&pe),
        width: 256,
        hidden_layers: 8,
        n_outputs: 33,
        skip: Some(4),
        hidden_activation: Activation::Softplus { beta: 100.0 },
        output_activation: Activation::Identity,
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

#[test]
fn hash_grid_gradients_match_finite_differences_dense_and_hashed_levels() {
    // 4 levels from 2 to 40 with a 2¹⁰ table: the coarse levels are dense, the fine ones hashed.
    let grid = HashGrid::new(HashGridConfig { levels: 4, features: 2, log2_table: 10, base_resolution: 2, finest_resolution: 40 });
    assert!(grid.resolutions()[0] == 2 && grid.resolutions()[3] == 40);
    let params = random_params(Module::<f64>::n_params(&grid), 1.0, 11);
    let err = grad_check(&grid, &params, 6, 12);
    assert!(err <= 1e-5, "relative error {err:e}");
    // Through an MLP, as in Neuralangelo's SDF network.
    let mlp = Mlp::new(MlpConfig {
        n_inputs: 8,
        width: 8,
        hidden_layers: 2,
        n_outputs: 2,
        skip: None,
        hidden_activation: Activation::Softplus { beta: 10.0 },
        output_activation: Activation::Identity,
    });
    let net = Chain { a: grid, b: mlp };
    let params = random_params(Module::<f64>::n_params(&net), 0.5, 13);
    let err = grad_check(&net, &params, 4, 14);
    assert!(err <= 1e-5, "relative error {err:e}");
}

#[test]
fn hash_grid_inactive_levels_output_zero_and_get_no_gradient() {
    let mut grid = HashGrid::new(HashGridConfig { levels: 3, features: 2, log2_table: 8, base_resolution: 4, finest_resolution: 16 });
    grid.active_levels = 1;
    let params = random_params(Module::<f64>::n_params(&grid), 1.0, 15);
    let x = [0.1, -0.3, 0.7];
    let mut out = vec![0.0; 6];
    grid.forward(&params, &x, &mut out, &mut []);
    assert!(out[0] != 0.0 && out[2..].iter().all(|v| *v == 0.0));
    let mut d_params = vec![0.0; params.len()];
    grid.backward(&params, &x, &[], &[1.0; 6], &mut d_params, None);
    assert!(d_params[grid.level_params(1).start..].iter().all(|v| *v == 0.0));
}

/// tiny-cuda-nn's layout: a dense level's table holds its (N + 1)³ vertices, not T entries (the
/// default preset's three dense levels would otherwise carry 131 k unused entries, paper-scale
/// Neuralangelo's six 171 M unused parameters, 2 GB with Adam's moments).
#[test]
fn hash_grid_dense_levels_hold_only_their_vertices() {
    let grid = HashGrid::new(HashGridConfig::neuralangelo_cpu());
    assert_eq!(grid.resolutions(), &[16, 23, 35, 52, 78, 115, 172, 256]);
    let dense = [17usize.pow(3), 24usize.pow(3), 36usize.pow(3)];
    assert_eq!(grid.level_params(0), 0..dense[0] * 2);
    let hashed = dense.iter().sum::<usize>() * 2;
    assert_eq!(grid.level_params(3), hashed..hashed + (1 << 16) * 2);
    assert_eq!(Module::<f32>::n_params(&grid), hashed + 5 * (1 << 16) * 2);
    let paper = HashGrid::new(HashGridConfig { levels: 16, features: 8, log2_table: 22, base_resolution: 32, finest_resolution: 2048 });
    assert_eq!(Module::<f32>::n_params(&paper), 365_817_640);
}

#[test]
fn spherical_harmonics_are_orthonormal_and_differentiable() {
    let sh = SphericalHarmonics;
    assert!(grad_check(&sh, &[], 5, 16) <= 1e-6);
    // Monte-Carlo orthonormality on the sphere: ∫ Yᵢ Yⱼ dω = δᵢⱼ (4π · mean).
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(17);
    let n = 200_000;
    let mut gram = [[0.0f64; 16]; 16];
    let mut y = [0.0f64; 16];
    for _ in 0..n {
        let z: f64 = 1.0 - 2.0 * rng.random::<f64>();
        let phi = std::f64::consts::TAU * rng.random::<f64>();
        let r = (1.0 - z * z).sqrt();
        sh.forward(&[], &[r * phi.cos(), r * phi.sin(), z], &mut y, &mut []);
        for i in 0..16 {
            for j in 0..16 {
                gram[i][j] += y[i] * y[j];
            }
        }
    }
    for i in 0..16 {
        for j in 0..16 {
            let g = gram[i][j] * 4.0 * std::f64::consts::PI / n as f64;
            let expect = if i == j { 1.0 } else { 0.0 };
            assert!((g - expect).abs() < 0.03, "⟨Y{i}, Y{j}⟩ = {g}");
        }
    }
}

/// Regression: in f32, `N − 1e-6` rounds to N for N ≥ 32, so a point at x = 1 fell in cell N and
/// indexed vertex N + 1 (with weight 0): another row of a dense table, and past the end of the
/// parameters for a dense last level whose (N + 1)³ nearly fills the table (N = 39, 2¹⁶: panic).
/// f32 and f64 must agree there, in the forward and the backward pass.
#[test]
fn hash_grid_points_on_the_far_face_read_the_last_cell() {
    let grid = HashGrid::new(HashGridConfig { levels: 2, features: 2, log2_table: 16, base_resolution: 33, finest_resolution: 39 });
    let n = Module::<f64>::n_params(&grid);
    let p64 = random_params(n, 1.0, 5);
    let p32: Vec<f32> = p64.iter().map(|v| *v as f32).collect();
    for x in [[1.0, 0.3, -0.2], [1.2, 1.0, 0.999_999], [1.0, 1.0, 1.0]] {
        let (mut y32, mut y64) = (vec![0.0f32; 4], vec![0.0f64; 4]);
        grid.forward(&p32, &x.map(|v| v as f32), &mut y32, &mut []);
        grid.forward(&p64, &x, &mut y64, &mut []);
        let mut g32 = vec![0.0f32; n];
        grid.backward(&p32, &x.map(|v| v as f32), &[], &[1.0; 4], &mut g32, None);
        assert!(g32.iter().all(|g| g.is_finite()));
        for k in 0..4 {
            assert!((f64::from(y32[k]) - y64[k]).abs() < 1e-5, "x = {x:?}, output {k}: f32 {} vs f64 {}", y32[k], y64[k]);
        }
    }
}

#[test]
fn with_input_gradients_match() {
    let grid = HashGrid::new(HashGridConfig { levels: 2, features: 2, log2_table: 8, base_resolution: 3, finest_resolution: 9 });
    let m = WithInput { encoding: grid };
    let params = random_params(Module::<f64>::n_params(&m), 1.0, 31);
    assert!(grad_check(&m, &params, 5, 32) <= 1e-5);
}

/// Checks `d_params`, `d_input` and the adjoint of the input tangent of
/// [`TangentModule::backward_tangent`], [`TangentModule::forward_tangents`] itself and
/// [`TangentModule::input_gradient`], against central differences of L = Σ r ⊙ y(x) + Σ q ⊙
/// (∂y/∂x · v) (of its first sum, for the input gradient). Returns the largest relative error.
fn tangent_check<M: TangentModule<f64>>(module: &M, params: &[f64], rows: usize, check_input: bool, seed: u64) -> f64 {
    tangent_check_of(module, params, rows, check_input, seed, usize::MAX)
}

/// [`tangent_check`] with the adjoints r and q zero past their first `used` columns in every row.
fn tangent_check_of<M: TangentModule<f64>>(module: &M, params: &[f64], rows: usize, check_input: bool, seed: u64, used: usize) -> f64 {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let (n_in, n_out) = (module.n_inputs(), module.n_outputs());
    let input: Vec<f64> = (0..rows * n_in).map(|_| rng.random::<f64>() * 1.6 - 0.8).collect();
    let v: Vec<f64> = (0..rows * n_in).map(|_| rng.random::<f64>() * 2.0 - 1.0).collect();
    let mut adjoint = |_| (0..rows * n_out).map(|i| if i % n_out < used { rng.random::<f64>() * 2.0 - 1.0 } else { 0.0 }).collect::<Vec<f64>>();
    let (r, q) = (adjoint(()), adjoint(()));
    let run = |p: &[f64], x: &[f64], t: &[f64]| {
        let mut out = vec![0.0; rows * n_out];
        let mut ctx = vec![0.0; rows * module.tangent_ctx_per_row()];
        module.forward_keeping_tangents(p, x, &mut out, &mut ctx);
        let mut tangent = vec![0.0; rows * n_out];
        module.forward_tangents(p, x, &ctx, 1, t, &mut tangent);
        (out, tangent, ctx)
    };
    let loss = |p: &[f64], x: &[f64], t: &[f64]| {
        let (out, tangent, _) = run(p, x, t);
        out.iter().zip(&r).map(|(a, b)| a * b).sum::<f64>() + tangent.iter().zip(&q).map(|(a, b)| a * b).sum::<f64>()
    };
    let rel = |a: f64, n: f64| (a - n).abs() / a.abs().max(n.abs()).max(1e-3);
    let mut worst = 0.0f64;
    let h = 1e-6;
    // The tangent is the directional derivative of the outputs.
    let (_, tangent, ctx) = run(params, &input, &v);
    let shifted = |sign: f64| -> Vec<f64> { input.iter().zip(&v).map(|(x, d)| x + sign * h * d).collect() };
    let (plus, minus) = (run(params, &shifted(1.0), &v).0, run(params, &shifted(-1.0), &v).0);
    for i in 0..rows * n_out {
        worst = worst.max(rel(tangent[i], (plus[i] - minus[i]) / (2.0 * h)));
    }
    // Three directions at once give the same as one at a time.
    let axes: Vec<f64> = (0..rows).flat_map(|_| [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]).collect();
    if n_in == 3 {
        let mut three = vec![0.0; rows * 3 * n_out];
        module.forward_tangents(params, &input, &ctx, 3, &axes, &mut three);
        for row in 0..rows {
            for k in 0..3 {
                let e: Vec<f64> = (0..rows).flat_map(|_| [0, 1, 2].map(|j| if j == k { 1.0 } else { 0.0 })).collect();
                let one = run(params, &input, &e).1;
                for o in 0..n_out {
                    worst = worst.max(rel(three[(row * 3 + k) * n_out + o], one[row * n_out + o]));
                }
            }
        }
    }
    // The input's adjoint alone (one reverse pass, no parameter gradient) is ∂(Σ r ⊙ y)/∂x.
    // So is the same after the plain forward, whose context keeps nothing for the tangents.
    let mut reverse = vec![0.0; input.len()];
    module.input_gradient(params, &input, &ctx, &r, &mut reverse);
    let (mut out, mut plain_ctx, mut found) = (vec![0.0; rows * n_out], vec![0.0; rows * module.ctx_per_row()], vec![0.0; input.len()]);
    module.forward(params, &input, &mut out, &mut plain_ctx);
    module.input_gradient_of_forward(params, &input, &plain_ctx, &r, &mut found);
    let values = |x: &[f64]| run(params, x, &v).0.iter().zip(&r).map(|(a, b)| a * b).sum::<f64>();
    for i in 0..input.len() {
        let (mut p, mut m) = (input.clone(), input.clone());
        p[i] += h;
        m[i] -= h;
        let numeric = (values(&p) - values(&m)) / (2.0 * h);
        worst = worst.max(rel(reverse[i], numeric)).max(rel(found[i], numeric));
    }
    let mut d_params = vec![0.0; params.len()];
    let (mut d_input, mut d_tangent) = (vec![0.0; input.len()], vec![0.0; input.len()]);
    let d_in = check_input.then_some((&mut d_input[..], &mut d_tangent[..]));
    let pass = TangentAdjoints { params, input: &input, ctx: &ctx, tangent_in: &v, d_output: &r, d_tangent_out: &q };
    module.backward_tangent(pass, &mut d_params, d_in);
    for i in 0..params.len() {
        let (mut p, mut m) = (params.to_vec(), params.to_vec());
        p[i] += h;
        m[i] -= h;
        worst = worst.max(rel(d_params[i], (loss(&p, &input, &v) - loss(&m, &input, &v)) / (2.0 * h)));
    }
    if check_input {
        for i in 0..input.len() {
            let (mut p, mut m) = (input.clone(), input.clone());
            p[i] += h;
            m[i] -= h;
            worst = worst.max(rel(d_input[i], (loss(params, &p, &v) - loss(params, &m, &v)) / (2.0 * h)));
            let (mut p, mut m) = (v.clone(), v.clone());
            p[i] += h;
            m[i] -= h;
            worst = worst.max(rel(d_tangent[i], (loss(params, &input, &p) - loss(params, &input, &m)) / (2.0 * h)));
        }
    }
    worst
}

/// An MLP 5 → 7 → 7 → 7 → 4 (softplus), with `skip` and `output_activation`.
fn deep_mlp(skip: Option<usize>, output_activation: Activation) -> Mlp {
    Mlp::new(MlpConfig {
        n_inputs: 5,
        width: 7,
        hidden_layers: 3,
        n_outputs: 4,
        skip,
        hidden_activation: Activation::Softplus { beta: 10.0 },
        output_activation,
    })
}

#[test]
fn mlp_tangents_and_their_backward_match_finite_differences() {
    for skip in [None, Some(2)] {
        let mlp = deep_mlp(skip, Activation::Identity);
        let params = random_params(Module::<f64>::n_params(&mlp), 0.6, 21);
        let worst = tangent_check(&mlp, &params, 6, true, 22);
        assert!(worst < 1e-6, "skip {skip:?}: relative error {worst:e}");
    }
    // Inputs of three (the SDF's) also check three directions at once.
    let mlp = Mlp::new(MlpConfig {
        n_inputs: 3,
        width: 6,
        hidden_layers: 2,
        n_outputs: 2,
        skip: None,
        hidden_activation: Activation::Softplus { beta: 10.0 },
        output_activation: Activation::Identity,
    });
    let params = random_params(Module::<f64>::n_params(&mlp), 0.6, 23);
    assert!(tangent_check(&mlp, &params, 5, true, 24) < 1e-6);
    // Sigmoids, hidden (act'' from the next layer's input, through the skip's 1/√2) and at the
    // output (act'' from the output recomputed).
    let sigmoid = Mlp::new(MlpConfig {
        hidden_layers: 3,
        skip: Some(2),
        hidden_activation: Activation::Sigmoid,
        output_activation: Activation::Sigmoid,
        ..mlp.config().clone()
    });
    let params = random_params(Module::<f64>::n_params(&sigmoid), 0.8, 25);
    let worst = tangent_check(&sigmoid, &params, 5, true, 26);
    assert!(worst < 1e-6, "sigmoid: relative error {worst:e}");
}

/// The reverse passes leave out of the output layer's products the adjoint's columns that are
/// zero in every row (a normal's reverse pass starts from the SDF output alone): with adjoints in
/// the first column only, and in the first two of four, for a linear output (whose Ż the tangents'
/// reverse pass does not compute) and a sigmoid one (whose Ż it reads).
#[test]
fn mlp_reverse_passes_from_the_first_outputs_alone_match_finite_differences() {
    for output in [Activation::Identity, Activation::Relu, Activation::Sigmoid] {
        let mlp = deep_mlp(None, output);
        let params = random_params(Module::<f64>::n_params(&mlp), 0.6, 27);
        for used in [1, 2] {
            let worst = tangent_check_of(&mlp, &params, 6, true, 28, used);
            assert!(worst < 1e-6, "{output:?}, {used} column(s): relative error {worst:e}");
        }
    }
}

/// Identity and ReLU, and only they, have a second derivative that is zero everywhere.
#[test]
fn piecewise_linear_activations_have_no_second_derivative() {
    for act in [Activation::Identity, Activation::Relu, Activation::Softplus { beta: 10.0 }, Activation::Sigmoid] {
        let zero = [-1.0f64, -0.1, 0.3, 2.0].iter().all(|&z| {
            let (slope, value) = (act.derivative(z), act.apply(z));
            act.second_derivative(slope, value) == 0.0
        });
        assert_eq!(act.is_piecewise_linear(), zero, "{act:?}");
    }
}

/// The positional encoding's tangents and their reverse pass (second derivatives of sin and
/// cos), alone and in front of an MLP as the NeuS presets have it.
#[test]
fn positional_encoding_tangents_and_their_backward_match_finite_differences() {
    let pe = PositionalEncoding { frequencies: 3 };
    let worst = tangent_check(&pe, &[], 6, true, 41);
    assert!(worst < 1e-6, "relative error {worst:e}");
    let mlp = Mlp::new(MlpConfig {
        n_inputs: 3 + 18,
        width: 6,
        hidden_layers: 1,
        n_outputs: 2,
        skip: None,
        hidden_activation: Activation::Softplus { beta: 10.0 },
        output_activation: Activation::Identity,
    });
    let net = Chain { a: pe, b: mlp };
    let params = random_params(Module::<f64>::n_params(&net), 0.5, 42);
    let worst = tangent_check(&net, &params, 6, true, 43);
    assert!(worst < 1e-6, "relative error {worst:e}");
}

/// Two features per level (a compiled kernel) and three (the per-row loop for other counts);
/// every level active, and the finest off (coarse to fine: its Jacobian columns zero).
#[test]
fn hash_grid_network_tangents_and_their_backward_match_finite_differences() {
    for features in [2, 3] {
        for active in [3, 2] {
            check_hash_grid_network_tangents(features, active);
        }
    }
}

/// A small SDF network of the hash-grid presets' shape: 3 levels of `features`, raw xyz beside
/// them, one hidden layer of 6, 3 outputs.
fn small_grid_network(features: usize) -> Chain<WithInput<HashGrid>, Mlp> {
    let grid = HashGrid::new(HashGridConfig { levels: 3, features, log2_table: 6, base_resolution: 2, finest_resolution: 9 });
    let mlp = Mlp::new(MlpConfig {
        n_inputs: 3 + 3 * features,
        width: 6,
        hidden_layers: 1,
        n_outputs: 3,
        skip: None,
        hidden_activation: Activation::Softplus { beta: 10.0 },
        output_activation: Activation::Identity,
    });
    Chain { a: WithInput { encoding: grid }, b: mlp }
}

fn check_hash_grid_network_tangents(features: usize, active: usize) {
    let mut net = small_grid_network(features);
    net.a.encoding.active_levels = active;
    let params = random_params(Module::<f64>::n_params(&net), 0.5, 31);
    // 21 rows: the hash grid's Jacobian kernel works in blocks of 16 rows, so a full block and
    // the last, short one.
    let worst = tangent_check(&net, &params, 21, false, 32);
    assert!(worst < 1e-6, "{features} features, {active} levels active: relative error {worst:e}");
}

/// Every pass that callers hand a buffer with stale values (`Buf::to_overwrite`) writes all of
/// it: the outputs and context of `forward` and of `forward_keeping_tangents`, the output
/// tangents, the input adjoints of `backward` and `input_gradient` — each buffer filled with NaN
/// first, none left; and both forwards give the same outputs to the bit.
fn assert_writes_everything<M: TangentModule<f64>>(name: &str, module: &M, params: &[f64]) {
    // A block of 16 rows and a short one (the hash grid's Jacobian kernel works in blocks).
    let rows = 21;
    let (n_in, n_out) = (module.n_inputs(), module.n_outputs());
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
    let input: Vec<f64> = (0..rows * n_in).map(|_| rng.random::<f64>() * 1.6 - 0.8).collect();
    let d_output: Vec<f64> = (0..rows * n_out).map(|_| rng.random::<f64>() - 0.5).collect();
    let (mut output, mut ctx) = (vec![f64::NAN; rows * n_out], vec![f64::NAN; rows * module.ctx_per_row()]);
    module.forward(params, &input, &mut output, &mut ctx);
    let (mut kept, mut tangent_ctx) = (vec![f64::NAN; rows * n_out], vec![f64::NAN; rows * module.tangent_ctx_per_row()]);
    module.forward_keeping_tangents(params, &input, &mut kept, &mut tangent_ctx);
    let k = 3;
    let tangents_in: Vec<f64> = (0..rows * k * n_in).map(|_| rng.random::<f64>() - 0.5).collect();
    let mut tangents = vec![f64::NAN; rows * k * n_out];
    module.forward_tangents(params, &input, &tangent_ctx, k, &tangents_in, &mut tangents);
    let (mut d_input, mut reverse) = (vec![f64::NAN; rows * n_in], vec![f64::NAN; rows * n_in]);
    module.backward(params, &input, &ctx, &d_output, &mut vec![0.0; params.len()], Some(&mut d_input));
    module.input_gradient(params, &input, &tangent_ctx, &d_output, &mut reverse);
    let mut found = vec![f64::NAN; rows * n_in];
    module.input_gradient_of_forward(params, &input, &ctx, &d_output, &mut found);
    for (what, values) in [
        ("output", &output),
        ("context", &ctx),
        ("tangents' context", &tangent_ctx),
        ("tangents", &tangents),
        ("input adjoint", &d_input),
        ("input gradient", &reverse),
        ("input gradient after the plain forward", &found),
    ] {
        assert!(values.iter().all(|v| v.is_finite()), "{name}: its {what} is not written in full");
    }
    assert!(output.iter().zip(&kept).all(|(a, b)| a.to_bits() == b.to_bits()), "{name}: the forward keeping tangents changes the outputs");
}

#[test]
fn every_pass_writes_all_of_the_buffers_it_is_given() {
    let mlp = |n_inputs, hidden_layers, skip, hidden_activation| {
        Mlp::new(MlpConfig { n_inputs, width: 6, hidden_layers, n_outputs: 5, skip, hidden_activation, output_activation: Activation::Identity })
    };
    let softplus = Activation::Softplus { beta: 10.0 };
    for (name, net) in [
        ("one hidden layer", mlp(19, 1, None, softplus)),
        ("a skip", mlp(5, 3, Some(2), softplus)),
        ("sigmoids", mlp(3, 2, None, Activation::Sigmoid)),
        ("relu", mlp(4, 2, None, Activation::Relu)),
    ] {
        assert_writes_everything(name, &net, &random_params(Module::<f64>::n_params(&net), 0.5, 3));
    }
    for features in [2, 3] {
        let grid = HashGrid::new(HashGridConfig { levels: 3, features, log2_table: 6, base_resolution: 2, finest_resolution: 9 });
        let params = random_params(Module::<f64>::n_params(&grid), 0.5, 4);
        assert_writes_everything("hash grid", &grid, &params);
        let mut net = small_grid_network(features);
        assert_writes_everything("hash-grid network", &net, &random_params(Module::<f64>::n_params(&net), 0.5, 6));
        net.a.encoding.active_levels = 2;
        assert_writes_everything("hash-grid network, a level off", &net, &random_params(Module::<f64>::n_params(&net), 0.5, 6));
    }
    let net = Chain { a: PositionalEncoding { frequencies: 2 }, b: mlp(15, 2, None, softplus) };
    assert_writes_everything("positional network", &net, &random_params(Module::<f64>::n_params(&net), 0.5, 7));
}

/// Every output of `module`'s passes (forward, three tangents, backward, the input gradient, the
/// reverse pass through values and tangents, to the input's adjoints where `to_input`), for
/// [`no_pass_reads_what_a_pooled_buffer_held`].
fn every_output<M: TangentModule<f64>>(module: &M, params: &[f64], to_input: bool) -> Vec<f64> {
    let rows = 7;
    let (n_in, n_out) = (module.n_inputs(), module.n_outputs());
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
    let mut draw = |n: usize| -> Vec<f64> { (0..n).map(|_| rng.random::<f64>() - 0.5).collect() };
    let (input, d_output, d_tangent_out) = (draw(rows * n_in), draw(rows * n_out), draw(rows * n_out));
    let (tangents_in, tangent_in) = (draw(rows * 3 * n_in), draw(rows * n_in));
    let (mut output, mut ctx) = (vec![0.0; rows * n_out], vec![0.0; rows * module.ctx_per_row()]);
    module.forward(params, &input, &mut output, &mut ctx);
    let (mut kept, mut tangent_ctx) = (vec![0.0; rows * n_out], vec![0.0; rows * module.tangent_ctx_per_row()]);
    module.forward_keeping_tangents(params, &input, &mut kept, &mut tangent_ctx);
    let mut tangents = vec![0.0; rows * 3 * n_out];
    module.forward_tangents(params, &input, &tangent_ctx, 3, &tangents_in, &mut tangents);
    let (mut d_params, mut d_input) = (vec![0.0; params.len()], vec![0.0; rows * n_in]);
    module.backward(params, &input, &ctx, &d_output, &mut d_params, Some(&mut d_input));
    let mut reverse = vec![0.0; rows * n_in];
    module.input_gradient(params, &input, &tangent_ctx, &d_output, &mut reverse);
    let mut found = vec![0.0; rows * n_in];
    module.input_gradient_of_forward(params, &input, &ctx, &d_output, &mut found);
    let (mut t_params, mut t_input, mut t_tangent) = (vec![0.0; params.len()], vec![0.0; rows * n_in], vec![0.0; rows * n_in]);
    let pass =
        TangentAdjoints { params, input: &input, ctx: &tangent_ctx, tangent_in: &tangent_in, d_output: &d_output, d_tangent_out: &d_tangent_out };
    module.backward_tangent(pass, &mut t_params, to_input.then_some((&mut t_input[..], &mut t_tangent[..])));
    [output, ctx, kept, tangent_ctx, tangents, d_params, d_input, reverse, found, t_params, t_input, t_tangent].concat()
}

/// The passes' scratch buffers that are not zeroed first ([`sdf_backbone::scratch::Buf::to_overwrite`],
/// the padded blocks of the MLP's tangents and adjoints) are written before they are read: with
/// the pool full of NaN-filled buffers of every size, every output is the same to the bit as with
/// a clean pool (a block's last column left unwritten changes 915 of 1 542 outputs).
#[test]
fn no_pass_reads_what_a_pooled_buffer_held() {
    fn poison_the_pool() {
        sdf_backbone::scratch::release_all();
        let bufs: Vec<_> = (0..200)
            .map(|i| {
                let mut b = sdf_backbone::scratch::Buf::<f64>::to_overwrite((1.045f64.powi(i) as usize).max(i as usize + 1));
                b.fill(f64::NAN);
                b
            })
            .collect();
        drop(bufs);
    }
    let mlp = |n_inputs, hidden_layers, skip, hidden_activation| {
        Mlp::new(MlpConfig { n_inputs, width: 6, hidden_layers, n_outputs: 5, skip, hidden_activation, output_activation: Activation::Identity })
    };
    let softplus = Activation::Softplus { beta: 10.0 };
    let nets = [
        ("one hidden layer", mlp(19, 1, None, softplus)),
        ("a skip", mlp(5, 3, Some(2), softplus)),
        ("sigmoids", mlp(3, 2, None, Activation::Sigmoid)),
    ];
    for (name, net) in &nets {
        let params = random_params(Module::<f64>::n_params(net), 0.5, 3);
        sdf_backbone::scratch::release_all();
        let clean = every_output(net, &params, true);
        poison_the_pool();
        let poisoned = every_output(net, &params, true);
        let differ = clean.iter().zip(&poisoned).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
        assert_eq!(differ, 0, "{name}: {differ} of {} outputs depend on what the pool held", clean.len());
    }
    for features in [2, 3] {
        let net = small_grid_network(features);
        let params = random_params(Module::<f64>::n_params(&net), 0.5, 6);
        sdf_backbone::scratch::release_all();
        let clean = every_output(&net, &params, false);
        poison_the_pool();
        assert!(
            clean.iter().zip(&every_output(&net, &params, false)).all(|(a, b)| a.to_bits() == b.to_bits()),
            "hash-grid network, {features} features"
        );
    }
}

/// `forward_first` (an up-sampling's SDF values: an MLP's pass with no context, DECISIONS §55)
/// is the first column of `forward` to the bit (the same sums in the same order, through the
/// same tile kernel), for MLPs with skips and output activations and for a hash-grid network,
/// in f64 and f32.
#[test]
fn the_first_output_alone_is_the_first_column_of_the_forward_pass() {
    fn check<M: Module<f64> + Module<f32>>(name: &str, net: &M, params: &[f64]) {
        let rows = 11;
        let n_in = Module::<f64>::n_inputs(net);
        let n_out = Module::<f64>::n_outputs(net);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(8);
        let input: Vec<f64> = (0..rows * n_in).map(|_| rng.random::<f64>() * 1.6 - 0.8).collect();
        let mut output = vec![0.0; rows * n_out];
        net.forward(params, &input, &mut output, &mut vec![0.0; rows * Module::<f64>::ctx_per_row(net)]);
        let mut first = vec![f64::NAN; rows];
        net.forward_first(params, &input, &mut first);
        for (r, f) in first.iter().enumerate() {
            assert_eq!(f.to_bits(), output[r * n_out].to_bits(), "{name}, row {r}: {f} against {}", output[r * n_out]);
        }
        let (p32, x32): (Vec<f32>, Vec<f32>) = (params.iter().map(|&p| p as f32).collect(), input.iter().map(|&x| x as f32).collect());
        let mut output32 = vec![0.0f32; rows * n_out];
        net.forward(&p32, &x32, &mut output32, &mut vec![0.0; rows * Module::<f32>::ctx_per_row(net)]);
        let mut first32 = vec![f32::NAN; rows];
        net.forward_first(&p32, &x32, &mut first32);
        for (r, f) in first32.iter().enumerate() {
            assert_eq!(f.to_bits(), output32[r * n_out].to_bits(), "{name}, f32 row {r}: {f} against {}", output32[r * n_out]);
        }
    }
    for (skip, output_activation) in [(None, Activation::Identity), (Some(2), Activation::Sigmoid)] {
        let mlp = deep_mlp(skip, output_activation);
        check("mlp", &mlp, &random_params(Module::<f64>::n_params(&mlp), 0.6, 9));
    }
    let net = small_grid_network(2);
    check("hash-grid network", &net, &random_params(Module::<f64>::n_params(&net), 0.5, 10));
}
