//! The forward-only render pass (`Pipeline::render_known`) against the loss pass's outputs, in
//! f64: equal when nothing is negligible, within the stated bound when something is.

mod common;

use common::{Grid, small_grid_pipeline as pipeline};
use sdf_backbone::*;
use std::num::NonZeroUsize;

/// The SDF at every depth of every ray.
fn sdf_at_depths(pipeline: &Grid, params: &[f64], rays: &[RayInput<f64>]) -> Vec<Vec<f64>> {
    rays.iter()
        .map(|ray| {
            let points: Vec<f64> = ray.depths.iter().flat_map(|&t| [0, 1, 2].map(|k| ray.origin[k] + t * ray.direction[k])).collect();
            pipeline.sdf_values(params, &points)
        })
        .collect()
}

#[test]
fn the_render_pass_with_nothing_negligible_equals_the_loss_pass() {
    for normals in [NormalScheme::Analytic, NormalScheme::Central, NormalScheme::Tetrahedral] {
        for learned_background in [false, true] {
            let (pipeline, params, rays) = pipeline(normals, learned_background, 0.2);
            let (_, expected) = pipeline.loss(&params, &rays, None, &NoSampleLoss);
            let rendered = pipeline.render_known(&params, &rays, &sdf_at_depths(&pipeline, &params, &rays), 0.0, NonZeroUsize::MIN);
            assert!(expected.iter().any(|o| o.opacity > 0.05 && o.opacity < 0.95), "the rays are partly opaque");
            for (r, (a, b)) in rendered.iter().zip(&expected).enumerate() {
                let close = |x: f64, y: f64| (x - y).abs() <= 1e-12 * (1.0 + y.abs());
                let same = (0..3).all(|k| close(a.color[k], b.color[k]) && close(a.normal[k], b.normal[k]))
                    && close(a.opacity, b.opacity)
                    && close(a.depth, b.depth);
                assert!(same, "{normals:?}, learned background {learned_background}, ray {r}: {a:?} against {b:?}");
            }
        }
    }
}

#[test]
fn the_render_pass_drops_at_most_the_negligible_weight_and_background() {
    // A sharper field (s = e^8): most of each ray's intervals carry almost nothing.
    let negligible = 0.02;
    for (learned_background, lift) in [(false, 0.0), (true, 0.0), (true, 0.5)] {
        let (pipeline, params, rays) = pipeline(NormalScheme::Analytic, learned_background, 0.8);
        // `lift` added to the SDF readout's bias (the last SDF output's bias is 4 from the end of
        // the SDF network's parameters): the rays then end before the surface.
        let mut params = params;
        params[Module::<f64>::n_params(&pipeline.sdf) - 4] += lift;
        let (_, expected) = pipeline.loss(&params, &rays, None, &NoSampleLoss);
        let sdf = sdf_at_depths(&pipeline, &params, &rays);
        let rendered = pipeline.render_known(&params, &rays, &sdf, negligible, NonZeroUsize::MIN);
        let s = 8.0f64.exp();
        let mut dropped = 0;
        for (r, (a, b)) in rendered.iter().zip(&expected).enumerate() {
            let weights = render_ray(&sdf[r], &rays[r].depths, &vec![[0.0; 3]; sdf[r].len() - 1], s).weights;
            dropped += weights.iter().filter(|&&w| w <= negligible / weights.len() as f64).count();
            assert!((a.opacity - b.opacity).abs() <= 1e-12 && (a.depth - b.depth).abs() <= 1e-12, "ray {r}: opacity and depth from every interval");
            for k in 0..3 {
                assert!((a.color[k] - b.color[k]).abs() <= 2.0 * negligible, "ray {r}, channel {k}: {} against {}", a.color[k], b.color[k]);
            }
        }
        let through = expected.iter().filter(|o| o.opacity < 0.5).count();
        assert!(lift == 0.0 || through >= 3, "lifted, rays let the background through: {through}");
        assert!(dropped > 20, "only {dropped} intervals were negligible: the test does not test dropping");
    }
}

/// A colour stride k runs the networks on every k-th kept interval: opacity and depth stay those of
/// stride 1 to the bit (computed before the stride applies: a guard against a later change), and
/// the colour and normal, interpolated between evaluated intervals along
/// each ray, stay close to stride 1's on a smooth field (and differ: something was interpolated;
/// measured here: colour 0.8–1.4e-4, normal 0.005–0.010 off, strides 2–5).
#[test]
fn a_colour_stride_keeps_opacity_and_depth_and_interpolates_the_colour() {
    for learned_background in [false, true] {
        let (pipeline, params, rays) = pipeline(NormalScheme::Analytic, learned_background, 0.2);
        let sdf = sdf_at_depths(&pipeline, &params, &rays);
        let every = pipeline.render_known(&params, &rays, &sdf, 0.0, NonZeroUsize::MIN);
        for stride in [2, 3, 5] {
            let strided = pipeline.render_known(&params, &rays, &sdf, 0.0, NonZeroUsize::new(stride).unwrap());
            let mut worst = (0.0f64, 0.0f64);
            for (r, (a, b)) in strided.iter().zip(&every).enumerate() {
                assert!(a.opacity == b.opacity && a.depth == b.depth, "stride {stride}, ray {r}: opacity and depth changed");
                for k in 0..3 {
                    worst.0 = worst.0.max((a.color[k] - b.color[k]).abs());
                    worst.1 = worst.1.max((a.normal[k] - b.normal[k]).abs());
                }
            }
            assert!(worst.0 > 0.0, "stride {stride}: no colour was interpolated");
            assert!(worst.0 <= 3e-4 && worst.1 <= 0.02, "stride {stride}: colour off by {:e}, normal by {:e}", worst.0, worst.1);
        }
    }
}
