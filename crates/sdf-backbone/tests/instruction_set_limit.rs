//! The kernels limited to a narrower instruction set (`kernels::limit_instruction_set`, `cargo
//! xtask --isa`) run that set's path — its tile shape, no bf16 — and compute what the widest path
//! computes. So an AVX-512 machine tests the AVX2 and baseline paths too. One test in its own
//! binary: the limit is process-wide, and tests in one binary run side by side.
use sdf_backbone::kernels::{self, InstructionSet, bf16};
use sdf_backbone::*;

mod common;
use common::rays_through_the_sphere as rays;

/// What a training step and a render compute: loss, gradient, the rays' outputs, the SDF at
/// points of the bound.
type Results = (f32, Vec<f32>, Vec<[f32; 8]>, Vec<f32>);

/// [`Results`] of `backbone`.
fn results(backbone: &Backbone, params: &[f32]) -> Results {
    let mut grads = vec![0.0; params.len()];
    let (loss, out) = backbone.loss_parallel(params, &rays::<f32>(48, 40), &mut grads, 8, &NoSampleLoss);
    let out = out.iter().map(|o| [o.color[0], o.color[1], o.color[2], o.opacity, o.depth, o.normal[0], o.normal[1], o.normal[2]]).collect();
    let points: Vec<f32> = (0..1500).map(|i| ((i * 37 % 1000) as f32 / 1000.0 - 0.5) * 1.6).collect();
    (loss, grads, out, backbone.sdf_values(params, &points))
}

/// Every value of a set of results, as bits (so that a NaN on one side only shows).
fn bits(r: &Results) -> Vec<u32> {
    std::iter::once(r.0).chain(r.1.iter().copied()).chain(r.2.iter().flatten().copied()).chain(r.3.iter().copied()).map(f32::to_bits).collect()
}

#[test]
fn a_narrower_instruction_set_runs_its_own_path_and_computes_the_same() {
    let (backbone, params) = build(Preset::NeuralangeloCpu, 0.5, 1);
    let mut backbone = backbone.with_analytic_normals();
    // A trained-like field: the initial sphere perturbed, so that every layer carries signal.
    let params: Vec<f32> = params.iter().enumerate().map(|(i, p)| p + 0.01 * ((i * 7919 % 1000) as f32 / 500.0 - 1.0)).collect();
    let widest = results(&backbone, &params);
    // Asked for bf16 products from now on: a path without them runs f32, and computes the same.
    backbone.set_products(Products::Bf16Hidden);
    let widest_name = kernels::instruction_set();
    #[cfg(target_arch = "x86_64")]
    let has_avx2 = std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma");
    #[cfg(not(target_arch = "x86_64"))]
    let has_avx2 = false;
    for (limit, name) in [(InstructionSet::Avx2, "AVX2 + FMA (x86-64-v3)"), (InstructionSet::Baseline, "SSE2 (x86-64 baseline)")] {
        kernels::limit_instruction_set(limit);
        assert_eq!(kernels::instruction_set_limit(), Some(limit));
        assert!(!kernels::wide_tiles() && !bf16::available(), "{limit:?}: no AVX-512 tiles and no bf16 products");
        if cfg!(target_arch = "x86_64") && (has_avx2 || limit == InstructionSet::Baseline) {
            assert_eq!(kernels::instruction_set(), name, "the limit names the path it runs");
        }
        let (expected, limited) = (bits(&widest), bits(&results(&backbone, &params)));
        let differing = expected.iter().zip(&limited).filter(|(a, b)| a != b).count();
        eprintln!("{widest_name} (f32) against {}: {differing} of {} values differ", kernels::instruction_set(), expected.len());
        // Every product sums its terms in the same order whatever the tile shape, with fused
        // multiply-adds on every path (the baseline's in software), and every other loop is the
        // same arithmetic in the same order: the results agree to the bit.
        assert_eq!((differing, limited.len()), (0, expected.len()), "{limit:?}: the limited path computes something else");
    }
    kernels::limit_instruction_set(InstructionSet::Avx512);
    assert_eq!((kernels::instruction_set_limit(), kernels::instruction_set()), (None, widest_name), "the limit lifted");
}
