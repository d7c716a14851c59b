//! The guard on the foreground (`PipelineConfig::opacity_guard`): an L1 on the opacity of the
//! rays whose learned background alone paints the pixel (within the tolerance, at least as
//! close as the composite), and nothing on the others; its gradients against finite
//! differences in f64.

mod common;

use common::{Grid, TestSampleLoss, pipeline_gradient_error, small_grid_pipeline};
use sdf_backbone::*;

/// The learned background's colour along `ray`: the same ray through a foreground interval of
/// 10⁻⁹, which lets the background through whole.
fn background_of(pipeline: &Grid, params: &[f64], ray: &RayInput<f64>) -> [f64; 3] {
    let t0 = ray.depths[0];
    let bare = RayInput { depths: vec![t0, t0 + 1e-9], ..ray.clone() };
    let (_, out) = pipeline.loss(params, &[bare], None, &TestSampleLoss);
    assert!(out[0].opacity < 1e-6, "the bare ray is not transparent: {}", out[0].opacity);
    out[0].color
}

/// Three rays of the small pipeline with a partly opaque foreground: the first's target is what
/// its background paints (the background explains it exactly), the second's the composite (the
/// foreground is needed there), the third's 0.15 (RMS 0.087 per channel) beyond its background,
/// away from the composite (closer to the background than to the composite, but not within the
/// tolerance 0.05). Returns them and their opacities.
fn guarded_and_needed(pipeline: &Grid, params: &[f64]) -> (Vec<RayInput<f64>>, [f64; 3]) {
    let (_, _, rays) = small_grid_pipeline(NormalScheme::Analytic, true, 0.2);
    let mut rays: Vec<RayInput<f64>> = rays.into_iter().take(3).collect();
    let (_, out) = pipeline.loss(params, &rays, None, &TestSampleLoss);
    let opacity = [out[0].opacity, out[1].opacity, out[2].opacity];
    assert!(opacity.iter().all(|o| *o > 0.05 && *o < 0.95), "want partly opaque rays: {opacity:?}");
    rays[0].target = background_of(pipeline, params, &rays[0]);
    rays[1].target = out[1].color;
    rays[1].weight = 0.6;
    let background = background_of(pipeline, params, &rays[2]);
    let away: [f64; 3] = [0, 1, 2].map(|k| background[k] - out[2].color[k]);
    let len = away.iter().map(|v| v * v).sum::<f64>().sqrt();
    rays[2].target = [0, 1, 2].map(|k| background[k] + 0.15 * away[k] / len);
    (rays, opacity)
}

const GUARD: OpacityGuard = OpacityGuard { weight: 0.3, tolerance: Some(0.05) };

#[test]
fn the_guard_takes_opacity_only_where_the_background_paints_the_pixel() {
    let (mut pipeline, params, _) = small_grid_pipeline(NormalScheme::Analytic, true, 0.2);
    let (rays, opacity) = guarded_and_needed(&pipeline, &params);
    let without = pipeline.loss(&params, &rays, None, &TestSampleLoss).0;
    pipeline.config.opacity_guard = Some(GUARD);
    let with = pipeline.loss(&params, &rays, None, &TestSampleLoss).0;
    // The batch's loss is the mean over its 3 rays: the guard adds 0.3 × weight × opacity of the
    // first ray only.
    let expected = 0.3 * 1.0 * opacity[0] / 3.0;
    assert!((with - without - expected).abs() < 1e-12, "guard added {} (expected {expected})", with - without);
    // Without a tolerance the third ray, closer to its background than to the composite, is
    // guarded too.
    pipeline.config.opacity_guard = Some(OpacityGuard { tolerance: None, ..GUARD });
    let unbounded = pipeline.loss(&params, &rays, None, &TestSampleLoss).0;
    let expected = 0.3 * (opacity[0] + opacity[2]) / 3.0;
    assert!((unbounded - without - expected).abs() < 1e-12, "guard added {} (expected {expected})", unbounded - without);
    pipeline.config.opacity_guard = Some(GUARD);
    // Without a learned background there is nothing to compare with: no guard.
    let (mut fixed, fixed_params, _) = small_grid_pipeline(NormalScheme::Analytic, false, 0.2);
    let base = fixed.loss(&fixed_params, &rays, None, &TestSampleLoss).0;
    fixed.config.opacity_guard = Some(GUARD);
    assert_eq!(base, fixed.loss(&fixed_params, &rays, None, &TestSampleLoss).0, "a fixed background was guarded");
    // With masks the masks say where the object is: no guard.
    let masked: Vec<RayInput<f64>> = rays.iter().map(|r| RayInput { mask: Some(0.0), ..r.clone() }).collect();
    let guarded = pipeline.loss(&params, &masked, None, &TestSampleLoss).0;
    pipeline.config.opacity_guard = None;
    assert_eq!(guarded, pipeline.loss(&params, &masked, None, &TestSampleLoss).0, "a masked ray was guarded");
}

#[test]
fn the_guards_gradients_match_finite_differences() {
    for normals in [NormalScheme::Analytic, NormalScheme::Central] {
        let (mut pipeline, params, _) = small_grid_pipeline(normals, true, 0.2);
        let (rays, _) = guarded_and_needed(&pipeline, &params);
        pipeline.config.opacity_guard = Some(GUARD);
        let worst = pipeline_gradient_error(&pipeline, &params, &rays);
        assert!(worst <= 1e-5, "{normals:?}: relative error {worst:e}");
    }
}
