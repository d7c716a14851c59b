//! Finite-difference gradient checks in f64 of the rendering and of the whole pipeline (normals,
//! curvature, backgrounds, masks, deferred table gradients, analytic normals), and its
//! behaviour at the extremes and across thread counts.

mod common;

use common::*;
use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
use sdf_backbone::*;

#[test]
fn rendering_matches_the_worked_example() {
    // Choose S so that α = [0.4, 0.8, 0.1] exactly: with s = 1, Φ(Sᵢ₊₁) = (1 − αᵢ) Φ(Sᵢ).
    let logit = |p: f64| (p / (1.0 - p)).ln();
    let mut phi = vec![0.9];
    for a in [0.4, 0.8, 0.1] {
        phi.push(phi.last().unwrap() * (1.0 - a));
    }
    let sdf: Vec<f64> = phi.iter().map(|p| logit(*p)).collect();
    let t = [1.0, 2.0, 3.0, 4.0];
    let r = render_ray(&sdf, &t, &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], 1.0);
    for (w, e) in r.weights.iter().zip([0.4, 0.48, 0.012]) {
        assert!((w - e).abs() < 1e-12, "{:?}", r.weights);
    }
    assert!((r.color[1] - 0.48).abs() < 1e-12 && (r.opacity - 0.892).abs() < 1e-12);
}

fn ray_loss_check(s: f64, sdf: &[f64]) -> f64 {
    let n = sdf.len() - 1;
    let t: Vec<f64> = (0..=n).map(|i| 1.0 + 0.1 * i as f64).collect();
    let colors: Vec<[f64; 3]> = (0..n).map(|i| [0.1 * i as f64, 0.5, 1.0 - 0.05 * i as f64]).collect();
    let (dc, dd, do_) = ([0.3, -0.7, 0.2], 0.4, -0.25);
    let dw: Vec<f64> = (0..n).map(|i| 0.05 * i as f64 - 0.1).collect();
    let loss = |sdf: &[f64], colors: &[[f64; 3]], s: f64| {
        let r = render_ray(sdf, &t, colors, s);
        (0..3).map(|k| dc[k] * r.color[k]).sum::<f64>() + dd * r.depth + do_ * r.opacity + r.weights.iter().zip(&dw).map(|(w, g)| w * g).sum::<f64>()
    };
    let fwd = render_ray(sdf, &t, &colors, s);
    let g = render_ray_backward(sdf, &t, &colors, s, &fwd, dc, dd, do_, Some(&dw));
    let rel = |a: f64, n: f64| (a - n).abs() / a.abs().max(n.abs()).max(1e-6);
    let h = 1e-7;
    let mut worst = 0.0f64;
    for i in 0..=n {
        let (mut p, mut m) = (sdf.to_vec(), sdf.to_vec());
        p[i] += h;
        m[i] -= h;
        let numeric = (loss(&p, &colors, s) - loss(&m, &colors, s)) / (2.0 * h);
        if rel(g.sdf[i], numeric) > 1e-5 {
            eprintln!("sdf[{i}]: analytic {:e} numeric {numeric:e}", g.sdf[i]);
        }
        worst = worst.max(rel(g.sdf[i], numeric));
    }
    for i in 0..n {
        for k in 0..3 {
            let (mut p, mut m) = (colors.clone(), colors.clone());
            p[i][k] += h;
            m[i][k] -= h;
            worst = worst.max(rel(g.colors[i][k], (loss(sdf, &p, s) - loss(sdf, &m, s)) / (2.0 * h)));
        }
    }
    let hs = h * s.max(1.0);
    worst.max(rel(g.s, (loss(sdf, &colors, s + hs) - loss(sdf, &colors, s - hs)) / (2.0 * hs)))
}

#[test]
fn rendering_gradients_match_finite_differences() {
    // A surface crossing (decreasing SDF), a crossing back out, and a grazing ray.
    let crossing: Vec<f64> = (0..12).map(|i| 0.3 - 0.055 * i as f64).collect();
    // (No two samples equal: α is clamped at 0 exactly where Sᵢ = Sᵢ₊₁, a kink.)
    let through: Vec<f64> = (0..12).map(|i| ((i as f64 - 5.3) * 0.06).abs() - 0.15).collect();
    let grazing: Vec<f64> = (0..12).map(|i| 0.02 + ((i as f64 - 6.0) * 0.03).powi(2)).collect();
    for s in [5.0, 30.0] {
        for sdf in [&crossing, &through, &grazing] {
            let err = ray_loss_check(s, sdf);
            assert!(err <= 1e-5, "s {s}: relative error {err:e}");
        }
    }
}

#[test]
fn rendering_is_stable_at_the_extremes() {
    let t: Vec<f64> = (0..9).map(|i| 1.0 + 0.1 * i as f64).collect();
    let colors = vec![[0.5f64; 3]; 8];
    let cases: Vec<(&str, Vec<f64>, Vec<f64>)> = vec![
        ("crossing", (0..9).map(|i| 0.2 - 0.05 * i as f64).collect(), t.clone()),
        ("background (misses the surface)", (0..9).map(|i| 0.5 + 0.01 * i as f64).collect(), t.clone()),
        ("inside", (0..9).map(|i| -0.5 - 0.01 * i as f64).collect(), t.clone()),
        ("zero-length intervals", vec![0.1; 9], vec![1.0; 9]),
        ("far inside and outside", vec![1e9, 1e9, -1e9, -1e9, 1e9, 1e9, 1e9, -1e9, -1e9], t.clone()),
    ];
    for s in [1e-3, 64.0, 1e4, 1e6] {
        for (name, sdf, t) in &cases {
            let r = render_ray(sdf, t, &colors, s);
            let g = render_ray_backward(sdf, t, &colors, s, &r, [1.0; 3], 1.0, 1.0, None);
            let finite = r.weights.iter().chain(&r.alphas).chain(&g.sdf).all(|v| v.is_finite())
                && r.color.iter().all(|v| v.is_finite())
                && r.depth.is_finite()
                && g.s.is_finite();
            assert!(finite, "{name}, s {s}: non-finite output");
            assert!(r.opacity >= -1e-12 && r.opacity <= 1.0 + 1e-12, "{name}, s {s}: opacity {}", r.opacity);
        }
        // A head-on crossing at large s is opaque, with its depth at the zero crossing (t = 1.4,
        // a sample: the weight splits between the two intervals around it).
        if s >= 1e4 {
            let r = render_ray(&cases[0].1, &t, &colors, s);
            assert!((r.opacity - 1.0).abs() < 1e-9 && (r.depth - 1.4).abs() < 1e-9, "s {s}: {r:?}");
        }
    }
    // f32 too.
    let sdf: Vec<f32> = (0..9).map(|i| 0.2 - 0.05 * i as f32).collect();
    let t32: Vec<f32> = t.iter().map(|v| *v as f32).collect();
    let r = render_ray(&sdf, &t32, &[[0.5f32; 3]; 8], 1e6f32);
    assert!(r.weights.iter().all(|w| w.is_finite()));
}

/// The whole render + loss pipeline (SDF net with PE, normals and curvature by central and by
/// tetrahedral differences, colour net on [x, n, SH(d), features], NeuS rendering, L2 colour over a grey
/// or a learned background, or masked (foreground rays only) + eikonal + mask BCE + a loss on the
/// samples, learnt variance) against finite differences in f64.
#[test]
fn whole_pipeline_gradients_match_finite_differences() {
    // Analytic normals through the positional encoding too (no curvature: it needs the probes).
    for (normals, masked_color) in
        [(NormalScheme::Central, false), (NormalScheme::Tetrahedral, false), (NormalScheme::Central, true), (NormalScheme::Analytic, false)]
    {
        let pe = PositionalEncoding { frequencies: 2 };
        let sdf_mlp = Mlp::new(MlpConfig {
            n_inputs: 15,
            width: 8,
            hidden_layers: 2,
            n_outputs: 1 + 4,
            skip: None,
            hidden_activation: Activation::Softplus { beta: 10.0 },
            output_activation: Activation::Identity,
        });
        let color = Mlp::new(MlpConfig {
            n_inputs: 22 + 4,
            width: 8,
            hidden_layers: 1,
            n_outputs: 3,
            skip: None,
            hidden_activation: Activation::Softplus { beta: 10.0 },
            output_activation: Activation::Sigmoid,
        });
        let mut pipeline = Pipeline {
            sdf: Chain { a: pe, b: sdf_mlp },
            color,
            // The learned background (NeRF++) on two of the variants: 5 samples beyond the bound,
            // on one of them with a hash grid among its inputs.
            background: (normals == NormalScheme::Tetrahedral || (normals == NormalScheme::Central && !masked_color))
                .then(|| BackgroundModel {
                    net: Mlp::new(MlpConfig {
                        // No view direction: the default model (docs/DECISIONS.md §23).
                        n_inputs: 4 + 8,
                        width: 4,
                        hidden_layers: 1,
                        n_outputs: 4,
                        skip: None,
                        hidden_activation: Activation::Softplus { beta: 10.0 },
                        output_activation: Activation::Identity,
                    }),
                    samples: 5,
                    near: 1.5,
                    frequencies: 1,
                    view_dependent: false,
                    grid: None,
                })
                .map(|model| {
                    if normals == NormalScheme::Central {
                        model.with_grid(HashGridConfig { levels: 2, features: 2, log2_table: 6, base_resolution: 2, finest_resolution: 5 })
                    } else {
                        model
                    }
                }),
            config: PipelineConfig {
                // h = 1e-2: the Laplacian divides by h², and with h = 1e-3 the finite differences
                // of the check itself lose 5 digits to rounding (measured 2e-4 "error").
                color_loss: ColorLoss::L2,
                eikonal_weight: 0.1,
                mask_weight: 0.1,
                normal_step: 1e-2,
                normals: Differences::Central,
                curvature_weight: if normals == NormalScheme::Analytic { 0.0 } else { 1e-3 },
                background: [0.3, 0.5, 0.1],
                masked_color,
                opacity_entropy: 0.05,
                opacity_sparsity: 0.05,
                opacity_guard: None,
                normal_smoothness: 0.05,
                // The analytic variant checks the region that leaves the solid's inside out.
                normal_smoothness_region: if normals == NormalScheme::Analytic {
                    SmoothnessRegion::Outside { depth: 0.0 }
                } else {
                    SmoothnessRegion::Everywhere
                },
            },
            analytic: None,
        };
        pipeline.set_normals(normals);
        let n = pipeline.n_params::<f64>();
        let mut params = random_params(n, 0.5, 21);
        params[n - 1] = 0.25; // s = e^{2.5} ≈ 12
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(22);
        let rays: Vec<RayInput<f64>> = (0..3)
            .map(|r| {
                let d = [0.3 + 0.1 * r as f64, -0.2, 1.0];
                let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                RayInput {
                    origin: [-0.1 * r as f64, 0.2, -1.0],
                    direction: d.map(|v| v / len),
                    depths: (0..7).map(|i| 0.2 + 0.25 * i as f64 + 0.05 * rng.random::<f64>()).collect(),
                    target: [0.2, 0.5 + 0.1 * r as f64, 0.7],
                    // Ray 2 has no mask: the opacity entropy's gradient is checked on it.
                    mask: [Some(1.0), Some(0.0), None][r],
                    // Unequal weights (soft mining's correction) are checked on every term.
                    weight: [1.0, 0.7, 1.6][r],
                }
            })
            .collect();
        let worst = pipeline_gradient_error(&pipeline, &params, &rays);
        assert!(worst <= 1e-5, "{normals:?}, masked colour {masked_color}: relative error {worst:e}");
    }
}

/// Masked training (NeuS): a backdrop ray's colour does not enter the loss, so changing its
/// target changes nothing, while a foreground ray's does; and the sample-loss hook is handed the
/// very s the pipeline renders with.
#[test]
fn masked_colour_loss_ignores_backdrop_rays_and_the_hook_sees_the_pipelines_s() {
    let (mut backbone, params) = sdf_backbone::build(sdf_backbone::Preset::NeusCpu, 0.5, 3);
    backbone.config.masked_color = true;
    let ray = |target: [f32; 3], mask: f32| RayInput {
        origin: [0.0, -3.0, 0.1],
        direction: [0.0, 1.0, 0.0],
        depths: (0..=16).map(|i| 2.0 + 2.0 * i as f32 / 16.0).collect(),
        target,
        mask: Some(mask),
        weight: 1.0,
    };
    let loss = |rays: &[RayInput<f32>]| backbone.loss(&params, rays, None, &NoSampleLoss).0;
    let base = loss(&[ray([0.1; 3], 1.0), ray([0.2; 3], 0.0)]);
    assert_eq!(base, loss(&[ray([0.1; 3], 1.0), ray([0.9; 3], 0.0)]), "a backdrop target changed the masked loss");
    assert_ne!(base, loss(&[ray([0.7; 3], 1.0), ray([0.2; 3], 0.0)]), "a foreground target did not change the loss");
    struct Record(std::sync::Mutex<Vec<f64>>);
    impl SampleLoss for Record {
        fn ray_loss(&self, _: usize, s: f64, _: &[f64], _: &[f64], _: &[f64], _: &mut [f64], _: &mut [f64]) -> f64 {
            self.0.lock().unwrap().push(s);
            0.0
        }
    }
    let record = Record(std::sync::Mutex::new(Vec::new()));
    backbone.loss(&params, &[ray([0.1; 3], 1.0)], None, &record);
    let seen = record.0.lock().unwrap()[0];
    assert!((seen - backbone.scale(&params)).abs() <= 1e-5 * seen, "hook saw s = {seen}, the backbone's is {}", backbone.scale(&params));
}

/// Central and tetrahedral differences both give the gradient of a smooth SDF to O(h²).
#[test]
fn both_normal_schemes_recover_a_known_gradient() {
    // S(x) = |x| − 0.5 via PE-free identity network is not available; use a one-layer MLP whose
    // SDF output is linear, S(x) = a·x + b: every scheme must return a exactly (up to rounding).
    let mlp = Mlp::new(MlpConfig {
        n_inputs: 3,
        width: 4,
        hidden_layers: 0,
        n_outputs: 1,
        skip: None,
        hidden_activation: Activation::Identity,
        output_activation: Activation::Identity,
    });
    let color = Mlp::new(MlpConfig {
        n_inputs: 22,
        width: 4,
        hidden_layers: 0,
        n_outputs: 3,
        skip: None,
        hidden_activation: Activation::Identity,
        output_activation: Activation::Sigmoid,
    });
    for normals in [NormalScheme::Central, NormalScheme::Tetrahedral, NormalScheme::Analytic] {
        let mut pipeline = Pipeline {
            // A plain MLP of xyz: PositionalEncoding with no frequency is the identity.
            sdf: Chain { a: PositionalEncoding { frequencies: 0 }, b: mlp.clone() },
            color: color.clone(),
            background: None,
            config: PipelineConfig {
                color_loss: ColorLoss::L2,
                eikonal_weight: 0.0,
                mask_weight: 0.0,
                normal_step: 1e-2,
                normals: Differences::Central,
                curvature_weight: 0.0,
                background: [0.0; 3],
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
        let n = pipeline.n_params::<f64>();
        let mut params = vec![0.0; n];
        let a = [0.6, -0.48, 0.64]; // |a| = 1
        params[..3].copy_from_slice(&a); // weights of the single (linear) layer, then bias
        params[3] = -0.2;
        params[n - 1] = 0.5;
        let ray =
            RayInput { origin: [0.0, 0.0, -1.0], direction: [0.0, 0.0, 1.0], depths: vec![0.5, 1.0, 1.5], target: [0.0; 3], mask: None, weight: 1.0 };
        let (_, out) = pipeline.loss(&params, &[ray], None, &NoSampleLoss);
        let o = &out[0];
        for k in 0..3 {
            assert!((o.normal[k] - a[k] * o.opacity).abs() < 1e-9, "{normals:?}: {:?} vs {a:?}·{}", o.normal, o.opacity);
        }
    }
}

#[test]
fn parallel_pipeline_equals_sequential_and_ignores_the_thread_count() {
    let pe = PositionalEncoding { frequencies: 2 };
    let sdf_mlp = Mlp::new(MlpConfig {
        n_inputs: 15,
        width: 8,
        hidden_layers: 2,
        n_outputs: 1 + 4,
        skip: None,
        hidden_activation: Activation::Softplus { beta: 100.0 },
        output_activation: Activation::Identity,
    });
    let color = Mlp::new(MlpConfig {
        n_inputs: 26,
        width: 8,
        hidden_layers: 1,
        n_outputs: 3,
        skip: None,
        hidden_activation: Activation::Relu,
        output_activation: Activation::Sigmoid,
    });
    let pipeline = Pipeline {
        sdf: Chain { a: pe, b: sdf_mlp },
        color,
        background: None,
        config: PipelineConfig {
            color_loss: ColorLoss::L1,
            eikonal_weight: 0.1,
            mask_weight: 0.0,
            normal_step: 1e-3,
            normals: Differences::Tetrahedral,
            curvature_weight: 1e-4,
            background: [0.2; 3],
            masked_color: false,
            opacity_entropy: 0.0,
            opacity_sparsity: 0.0,
            opacity_guard: None,
            normal_smoothness: 0.0,
            normal_smoothness_region: SmoothnessRegion::Everywhere,
        },
        analytic: None,
    };
    let n = pipeline.n_params::<f64>();
    let params = random_params(n, 0.5, 41);
    let rays: Vec<RayInput<f64>> = (0..37)
        .map(|r| RayInput {
            origin: [0.01 * r as f64, 0.0, -2.0],
            direction: [0.0, 0.0, 1.0],
            depths: (0..9).map(|i| 1.0 + 0.25 * i as f64).collect(),
            target: [0.5; 3],
            mask: None,
            weight: 1.0,
        })
        .collect();
    let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
    let (la, oa) = pipeline.loss(&params, &rays, Some(&mut a), &TestSampleLoss);
    let (lb, ob) = pipeline.loss_parallel(&params, &rays, &mut b, 5, &TestSampleLoss);
    assert!((la - lb).abs() < 1e-12 * la.abs().max(1.0));
    assert_eq!(oa, ob);
    // Equal up to the order of additions (chunks are summed one after another).
    for (x, y) in a.iter().zip(&b) {
        assert!((x - y).abs() < 1e-9 * x.abs().max(1e-9), "{x} vs {y}");
    }
    // Bit-identical whatever the thread count (resumed runs depend on it).
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        let mut c = vec![0.0; n];
        let (lc, _) = pool.install(|| pipeline.loss_parallel(&params, &rays, &mut c, 5, &TestSampleLoss));
        assert_eq!(lc.to_bits(), lb.to_bits(), "{threads} threads");
        assert!(c.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()), "{threads} threads");
    }
}

/// A positional-encoding SDF network and a colour network.
type SinePipeline = Pipeline<Chain<PositionalEncoding, Mlp>, Mlp>;

/// S(x) = sin(x₀) (positional encoding, one linear layer) with `normals`, no loss term but the
/// colour's, and a ray along the x axis through 5 samples: (pipeline, parameters, ray).
fn sine_pipeline(normals: NormalScheme) -> (SinePipeline, Vec<f64>, RayInput<f64>) {
    let pe = PositionalEncoding { frequencies: 1 };
    let mlp = Mlp::new(MlpConfig {
        n_inputs: 9,
        width: 4,
        hidden_layers: 0,
        n_outputs: 1,
        skip: None,
        hidden_activation: Activation::Identity,
        output_activation: Activation::Identity,
    });
    let color = Mlp::new(MlpConfig {
        n_inputs: 22,
        width: 4,
        hidden_layers: 0,
        n_outputs: 3,
        skip: None,
        hidden_activation: Activation::Identity,
        output_activation: Activation::Sigmoid,
    });
    let ray = RayInput {
        origin: [-1.0, 0.2, 0.1],
        direction: [1.0, 0.0, 0.0],
        depths: vec![0.3, 0.7, 1.1, 1.6, 1.9],
        target: [0.1; 3],
        mask: None,
        weight: 1.0,
    };
    let mut pipeline = Pipeline {
        sdf: Chain { a: pe, b: mlp },
        color,
        background: None,
        config: PipelineConfig {
            color_loss: ColorLoss::L2,
            eikonal_weight: 0.0,
            mask_weight: 0.0,
            normal_step: 1e-3,
            normals: Differences::Central,
            curvature_weight: 0.0,
            background: [0.0; 3],
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
    let n = pipeline.n_params::<f64>();
    let mut params = vec![0.0; n];
    params[3] = 1.0; // weight of sin(x₀)
    params[n - 1] = 0.3;
    (pipeline, params, ray)
}

/// The curvature term is mean |ΔS|: for S(x) = sin(x₀), ΔS = −sin(x₀), with both probe schemes.
#[test]
fn curvature_term_is_the_mean_absolute_laplacian() {
    for normals in [NormalScheme::Central, NormalScheme::Tetrahedral] {
        let (mut pipeline, params, ray) = sine_pipeline(normals);
        let expected: f64 = (0..4).map(|i| (ray.origin[0] + ray.depths[i]).sin().abs()).sum::<f64>() / 4.0;
        let base = pipeline.loss(&params, std::slice::from_ref(&ray), None, &NoSampleLoss).0;
        pipeline.config.curvature_weight = 1.0;
        let with = pipeline.loss(&params, std::slice::from_ref(&ray), None, &NoSampleLoss).0;
        assert!(((with - base) - expected).abs() < 1e-5, "{normals:?}: {} vs {expected}", with - base);
    }
}

/// The normal smoothness term adds the mean squared change of the normals between neighbouring
/// samples: for S(x) = sin(x₀) along the x axis, nᵢ = (cos(x₀ᵢ), 0, 0) at the first four samples.
#[test]
fn normal_smoothness_is_the_mean_squared_change_of_neighbouring_normals() {
    for normals in [NormalScheme::Central, NormalScheme::Tetrahedral, NormalScheme::Analytic] {
        let (mut pipeline, params, ray) = sine_pipeline(normals);
        let normal = |i: usize| (ray.origin[0] + ray.depths[i]).cos();
        let expected: f64 = (0..3).map(|i| (normal(i + 1) - normal(i)).powi(2)).sum::<f64>() / 3.0;
        let base = pipeline.loss(&params, std::slice::from_ref(&ray), None, &NoSampleLoss).0;
        pipeline.config.normal_smoothness = 1.0;
        let with = pipeline.loss(&params, std::slice::from_ref(&ray), None, &NoSampleLoss).0;
        assert!(((with - base) - expected).abs() < 1e-5, "{normals:?}: {} vs {expected}", with - base);
    }
}

/// With `SmoothnessRegion::Outside` the normal smoothness leaves out the pairs deeper inside the
/// solid than its depth: for S(x) = sin(x₀) the first two samples (x₀ = −0.7, −0.3; S = −0.64,
/// −0.30) are inside, so at depth 0 of the three pairs the first drops out of the sum (the mean
/// still divides by three), at depth 0.5 its second sample is within the band and it counts.
#[test]
fn normal_smoothness_outside_leaves_out_the_pairs_inside_the_solid() {
    for normals in [NormalScheme::Central, NormalScheme::Analytic] {
        let (mut pipeline, params, ray) = sine_pipeline(normals);
        let x = |i: usize| ray.origin[0] + ray.depths[i];
        assert!(x(0).sin() < 0.0 && x(1).sin() < 0.0 && x(2).sin() > 0.0, "the ray starts inside");
        let change = |i: usize| (x(i + 1).cos() - x(i).cos()).powi(2);
        let base = pipeline.loss(&params, std::slice::from_ref(&ray), None, &NoSampleLoss).0;
        pipeline.config.normal_smoothness = 1.0;
        for (depth, expected) in [(0.0, (change(1) + change(2)) / 3.0), (0.5, (change(0) + change(1) + change(2)) / 3.0)] {
            pipeline.config.normal_smoothness_region = SmoothnessRegion::Outside { depth };
            let with = pipeline.loss(&params, std::slice::from_ref(&ray), None, &NoSampleLoss).0;
            assert!(((with - base) - expected).abs() < 1e-5, "{normals:?}, depth {depth}: {} vs {expected}", with - base);
        }
    }
}

/// The whole pipeline (CPU hash-grid preset) gives a finite loss and finite gradients at the
/// extremes: s = 1e6, rays that graze or miss the unit sphere, zero-length intervals, and a batch
/// where every ray is background (mask 0, target = background).
#[test]
fn pipeline_is_finite_at_the_extremes() {
    let (mut backbone, mut params) = build(Preset::NeuralangeloCpu, 0.5, 9);
    backbone.config.curvature_weight = 5e-4;
    let n = params.len();
    let ray = |origin: [f32; 3], direction: [f32; 3], depths: Vec<f32>, mask: f32| RayInput {
        origin,
        direction,
        depths,
        target: [0.0; 3],
        mask: Some(mask),
        weight: 1.0,
    };
    let line = |a: f32, b: f32, k: usize| (0..=k).map(|i| a + (b - a) * i as f32 / k as f32).collect::<Vec<f32>>();
    let cases: Vec<(&str, Vec<RayInput<f32>>)> = vec![
        ("through the centre", vec![ray([0.0, -3.0, 0.0], [0.0, 1.0, 0.0], line(2.0, 4.0, 32), 1.0)]),
        ("grazing the unit sphere", vec![ray([0.999, -3.0, 0.0], [0.0, 1.0, 0.0], line(2.9, 3.1, 32), 0.0)]),
        ("missing the unit sphere", vec![ray([1.5, -3.0, 0.0], [0.0, 1.0, 0.0], line(2.0, 4.0, 32), 0.0)]),
        ("zero-length intervals", vec![ray([0.0, -3.0, 0.0], [0.0, 1.0, 0.0], vec![2.0, 2.0, 2.5, 2.5, 2.5, 3.0, 3.0], 1.0)]),
        ("all background", (0..8).map(|i| ray([1.2 + 0.1 * i as f32, -3.0, 0.0], [0.0, 1.0, 0.0], line(2.0, 4.0, 16), 0.0)).collect()),
    ];
    for log10_s in [1.0f32, 3.0, 6.0] {
        params[n - 1] = log10_s * std::f32::consts::LN_10 / 10.0; // s = exp(10 v)
        for (name, rays) in &cases {
            let mut grads = vec![0.0f32; n];
            let (loss, out) = backbone.loss_parallel(&params, rays, &mut grads, 4, &NoSampleLoss);
            assert!(loss.is_finite(), "s = 1e{log10_s}, {name}: loss {loss}");
            assert!(
                out.iter().all(|o| o.color.iter().chain(&o.normal).all(|v| v.is_finite()) && o.opacity.is_finite() && o.depth.is_finite()),
                "s = 1e{log10_s}, {name}: outputs"
            );
            assert!(grads.iter().all(|g| g.is_finite()), "s = 1e{log10_s}, {name}: gradients");
        }
    }
}

/// The hash-grid pipeline through `loss_parallel`, whose table gradient is deferred (recorded per
/// work item, scattered once in chunk order, in parallel over levels): against finite differences
/// in f64 on the hash tables and the MLPs, and bit-identical for 1 and 3 threads.
#[test]
fn hash_grid_pipeline_with_deferred_table_gradients_matches_finite_differences() {
    check_hash_grid_pipeline(NormalScheme::Tetrahedral);
}

/// The same with analytic normals: the forward-mode derivatives through the hash grid and the
/// MLP, and the reverse pass through them (deferred table records of values and tangents).
#[test]
fn analytic_normals_pipeline_gradients_match_finite_differences() {
    check_hash_grid_pipeline(NormalScheme::Analytic);
}

fn check_hash_grid_pipeline(normals: NormalScheme) {
    let grid = HashGrid::new(HashGridConfig { levels: 3, features: 2, log2_table: 8, base_resolution: 2, finest_resolution: 12 });
    let sdf_mlp = Mlp::new(MlpConfig {
        n_inputs: 3 + 6,
        width: 8,
        hidden_layers: 1,
        n_outputs: 1 + 3,
        skip: None,
        hidden_activation: Activation::Softplus { beta: 10.0 },
        output_activation: Activation::Identity,
    });
    let color = Mlp::new(MlpConfig {
        n_inputs: 22 + 3,
        width: 8,
        hidden_layers: 1,
        n_outputs: 3,
        skip: None,
        hidden_activation: Activation::Relu,
        output_activation: Activation::Sigmoid,
    });
    let mut pipeline = Pipeline {
        sdf: Chain { a: WithInput { encoding: grid }, b: sdf_mlp },
        color,
        background: None,
        config: PipelineConfig {
            color_loss: ColorLoss::L2,
            eikonal_weight: 0.1,
            mask_weight: 0.1,
            normal_step: 1e-2,
            normals: Differences::Central,
            curvature_weight: 0.0,
            background: [0.2; 3],
            masked_color: true,
            opacity_entropy: 0.0,
            opacity_sparsity: 0.0,
            opacity_guard: None,
            normal_smoothness: 0.05,
            normal_smoothness_region: SmoothnessRegion::Everywhere,
        },
        analytic: None,
    };
    pipeline.set_normals(normals);
    assert!(DeferringModule::<f64>::deferred_params(&pipeline.sdf) > 0, "the tables are deferred");
    let n = pipeline.n_params::<f64>();
    let mut params = random_params(n, 0.3, 51);
    params[n - 1] = 0.2;
    let rays: Vec<RayInput<f64>> = (0..7)
        .map(|r| {
            let d = [0.2 + 0.05 * r as f64, -0.1, 1.0];
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            RayInput {
                origin: [-0.2, 0.1 * r as f64 - 0.3, -1.2],
                direction: d.map(|v| v / len),
                depths: (0..6).map(|i| 0.5 + 0.3 * i as f64 + 0.01 * r as f64).collect(),
                target: [0.3, 0.5, 0.1 * r as f64],
                mask: Some(if r % 3 == 0 { 0.0 } else { 1.0 }),
                weight: 1.0,
            }
        })
        .collect();
    let mut grads = vec![0.0; n];
    let (loss, _) = pipeline.loss_parallel(&params, &rays, &mut grads, 2, &TestSampleLoss);
    assert!(loss.is_finite());
    let h = 1e-6;
    let mut worst = 0.0f64;
    let mut checked = 0;
    for i in 0..n {
        let (mut p, mut m) = (params.clone(), params.clone());
        p[i] += h;
        m[i] -= h;
        let numeric = (pipeline.loss(&p, &rays, None, &TestSampleLoss).0 - pipeline.loss(&m, &rays, None, &TestSampleLoss).0) / (2.0 * h);
        if numeric == 0.0 && grads[i] == 0.0 {
            continue; // a table entry no sample touches
        }
        checked += 1;
        let rel = (grads[i] - numeric).abs() / grads[i].abs().max(numeric.abs()).max(1e-4);
        worst = worst.max(rel);
    }
    assert!(checked > 200, "only {checked} parameters have a gradient");
    assert!(worst <= 1e-5, "{normals:?}: relative error {worst:e}");
    // The sequential loss gives the same gradient (up to the order of additions).
    let mut sequential = vec![0.0; n];
    pipeline.loss(&params, &rays, Some(&mut sequential), &TestSampleLoss);
    for (a, b) in sequential.iter().zip(&grads) {
        assert!((a - b).abs() <= 1e-12 * a.abs().max(b.abs()).max(1.0), "{normals:?}: sequential {a} vs parallel {b}");
    }
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        let mut g = vec![0.0; n];
        pool.install(|| pipeline.loss_parallel(&params, &rays, &mut g, 2, &TestSampleLoss));
        assert!(g == grads, "{threads} threads give other bits");
    }
}
