//! The loss-guided samplers in a run (`sampler = "error-map"` or `"soft-mining"`): the error map
//! the trainer keeps, what each ray's loss is for it, and soft mining's α along the run.

use crate::config::{SamplerKind, TrainConfig};
use camera_geom::PinholeCamera;
use sdf_backbone::{RayInput, RayOutput};
use view_sampler::{ErrorMap, ErrorMapConfig, RaySample};

/// The error map of a run whose sampler mines the loss, over its training cameras; `None` for
/// the other samplers.
pub fn error_map(config: &TrainConfig, cameras: &[PinholeCamera]) -> Option<ErrorMap> {
    config.sampler.mines().then(|| {
        let m = &config.mining;
        ErrorMap::new(cameras.to_vec(), ErrorMapConfig { cells: m.cells, new_weight: m.new_weight as f32, uniform_share: m.uniform })
    })
}

/// Soft mining's α at `progress` (0 for the error map), warmed up linearly over
/// `mining.alpha_warmup` of the run.
pub fn alpha_at(config: &TrainConfig, progress: f64) -> f64 {
    if config.sampler != SamplerKind::SoftMining {
        return 0.0;
    }
    let m = &config.mining;
    let ramp = if m.alpha_warmup > 0.0 { (progress / m.alpha_warmup).min(1.0) } else { 1.0 };
    m.alpha * ramp
}

/// The pixel's loss as the error map sees it: the mean absolute colour error where the colour is
/// learnt (every ray without masks, the foreground with them), plus the opacity's distance to
/// the mask where there is one.
pub fn pixel_error(ray: &RayInput<f32>, output: &RayOutput<f32>) -> f32 {
    let foreground = ray.mask.is_none_or(|m| m >= 0.5);
    let color = if foreground { (0..3).map(|k| (output.color[k] - ray.target[k]).abs()).sum::<f32>() / 3.0 } else { 0.0 };
    color + ray.mask.map_or(0.0, |m| (output.opacity - m).abs())
}

/// Folds a step's losses into the map (in ray order: the same map whatever the thread count)
/// and rebuilds its sums.
pub fn record(map: &mut ErrorMap, drawn: &[RaySample], rays: &[RayInput<f32>], outputs: &[RayOutput<f32>]) {
    for ((sample, ray), output) in drawn.iter().zip(rays).zip(outputs) {
        map.record(sample.camera, sample.pixel, pixel_error(ray, output));
    }
    map.rebuild();
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ray(mask: Option<f32>) -> RayInput<f32> {
        RayInput { origin: [0.0; 3], direction: [0.0, 0.0, 1.0], depths: vec![0.0, 1.0], target: [0.5; 3], mask, weight: 1.0 }
    }

    #[test]
    fn the_pixel_error_counts_colour_where_it_is_learnt_and_the_mask_where_there_is_one() {
        let out = RayOutput { color: [0.2, 0.5, 0.8], opacity: 0.75, depth: 1.0, normal: [0.0; 3] };
        assert!((pixel_error(&ray(None), &out) - 0.2).abs() < 1e-6);
        assert!((pixel_error(&ray(Some(1.0)), &out) - 0.45).abs() < 1e-6);
        // A backdrop ray's colour is not learnt with masks: only its opacity counts.
        assert!((pixel_error(&ray(Some(0.0)), &out) - 0.75).abs() < 1e-6);
    }

    #[test]
    fn alpha_warms_up_for_soft_mining_only() {
        let mut config = TrainConfig { sampler: SamplerKind::SoftMining, ..Default::default() };
        config.mining.alpha = 0.6;
        config.mining.alpha_warmup = 0.2;
        assert!((alpha_at(&config, 0.1) - 0.3).abs() < 1e-12);
        assert!((alpha_at(&config, 0.9) - 0.6).abs() < 1e-12);
        config.sampler = SamplerKind::ErrorMap;
        assert_eq!(alpha_at(&config, 0.9), 0.0);
        assert!(error_map(&config, &[]).is_some());
        config.sampler = SamplerKind::Guided;
        assert!(error_map(&config, &[]).is_none());
    }
}
