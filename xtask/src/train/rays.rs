//! Turning drawn pixels into rays with sample depths: NeuS's near/far from the unit sphere,
//! stratified coarse depths, hierarchical up-sampling, and (guided) the extra points around λ̃.

use super::config::TrainConfig;
use camera_geom::PinholeCamera;
use glam::DVec3;
use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
use sdf_backbone::{Backbone, RayInput, merge_sorted};
use surface_losses::{ExtraPoints, RaySurface, extra_depths};

/// One drawn ray: camera, pixel, and (guided) λ̃ along the optical axis.
#[derive(Debug, Clone, Copy)]
pub struct DrawnRay {
    /// Index of the training view.
    pub view: usize,
    /// Pixel column.
    pub col: u32,
    /// Pixel row.
    pub row: u32,
    /// λ̃ (depth along the optical axis), for guided runs, and whether it was drawn from the
    /// grid (false: the pixel's column held no mass, a background ray).
    pub depth: Option<(f32, bool)>,
}

/// A stream seed from (seed, step, item): the sampler's SplitMix64 finalisation, on a seed
/// offset so that the trainer's streams differ from the sampler's.
pub fn stream_seed(seed: u64, step: u64, item: u64) -> u64 {
    view_sampler::stream_seed(seed ^ 0x7261_7973, step, item)
}

/// NeuS's near/far: the sphere of radius 1 around the origin, measured from the closest
/// approach of the ray (`mid = −o·d`, `[mid − 1, mid + 1]`), near clamped to 0.05 so that cameras
/// inside the bound still get samples in front of them.
pub fn near_far(origin: DVec3, direction: DVec3) -> (f64, f64) {
    let mid = -origin.dot(direction);
    let near = (mid - 1.0).max(0.05);
    (near, (mid + 1.0).max(near + 1e-3))
}

/// `n + 1` stratified depths over [near, far] with one jitter per ray (the last is `far`).
pub fn coarse_depths(near: f64, far: f64, n: usize, jitter: f64) -> Vec<f32> {
    let step = (far - near) / n as f64;
    (0..=n).map(|i| (near + (i as f64 + if i < n { jitter } else { 0.0 }) * step) as f32).collect()
}

/// A ray through the centre of (col, row) of `camera` with its target colour and mask.
pub fn base_ray(camera: &PinholeCamera, col: u32, row: u32, target: [f32; 3], mask: Option<f32>, n_coarse: usize, jitter: f64) -> RayInput<f32> {
    let ray = camera.ray_through_pixel_index(col, row);
    let (near, far) = near_far(ray.origin, ray.direction);
    RayInput {
        origin: ray.origin.as_vec3().to_array(),
        direction: ray.direction.as_vec3().to_array(),
        depths: coarse_depths(near, far, n_coarse, jitter),
        target,
        mask,
    }
}

/// The rays of one iteration, with the surface-loss information of each (guided).
pub struct Batch {
    /// Rays with their final sample depths.
    pub rays: Vec<RayInput<f32>>,
    /// Per ray: λ̃ as a distance along the ray, and whether it lies outside the bound.
    pub surfaces: Vec<RaySurface>,
}

/// Builds the rays of `drawn`: coarse depths, up-sampling (`render.fine` minus the extra points
/// for guided rays), and the extra points around λ̃. Deterministic in (seed, step).
#[allow(clippy::too_many_arguments)]
pub fn build_batch(
    config: &TrainConfig,
    backbone: &Backbone,
    params: &[f32],
    cameras: &[&PinholeCamera],
    target: impl Fn(usize, u32, u32) -> ([f32; 3], Option<f32>),
    drawn: &[DrawnRay],
    step: u64,
    s: f64,
) -> Batch {
    let guided = drawn.iter().any(|d| d.depth.is_some());
    let n_extra = if guided { config.guide.extra_points } else { 0 };
    let mut rngs: Vec<Xoshiro256PlusPlus> =
        (0..drawn.len()).map(|i| Xoshiro256PlusPlus::seed_from_u64(stream_seed(config.seed, step, i as u64))).collect();
    let mut rays: Vec<RayInput<f32>> = drawn
        .iter()
        .zip(&mut rngs)
        .map(|(d, rng)| {
            let (t, m) = target(d.view, d.col, d.row);
            base_ray(cameras[d.view], d.col, d.row, t, m, config.render.coarse, rng.random())
        })
        .collect();
    backbone.upsample(params, &mut rays, config.render.fine - n_extra, config.render.upsample_rounds, config.render.upsample_s);
    let kind = match config.guide.extra.as_str() {
        "uniform" => ExtraPoints::Uniform,
        "log" => ExtraPoints::LogVariance,
        _ => ExtraPoints::Gaussian,
    };
    let mut surfaces = Vec::with_capacity(rays.len());
    for ((ray, d), rng) in rays.iter_mut().zip(drawn).zip(&mut rngs) {
        let o = DVec3::from_array(ray.origin.map(f64::from));
        let dir = DVec3::from_array(ray.direction.map(f64::from));
        let Some((lambda, from_grid)) = d.depth else {
            surfaces.push(RaySurface { depth: 0.0, background: true });
            continue;
        };
        let t_surface = f64::from(lambda) / cameras[d.view].depth_per_distance(dir).max(1e-9);
        // Background: no mass in the pixel's column, or λ̃ outside the scene bound.
        let background = !from_grid || (o + t_surface * dir).length() > 1.0;
        surfaces.push(RaySurface { depth: t_surface, background });
        if n_extra > 0 {
            let (near, far) = (f64::from(ray.depths[0]), f64::from(*ray.depths.last().expect("depths")));
            let u: Vec<f64> = (0..n_extra).map(|_| rng.random()).collect();
            let extra: Vec<f32> = extra_depths(kind, t_surface, s, near, far, &u).into_iter().map(|t| t as f32).collect();
            ray.depths = merge_sorted(&ray.depths, &extra);
        }
    }
    Batch { rays, surfaces }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn near_far_brackets_the_unit_sphere_and_stays_in_front_of_the_camera() {
        let (n, f) = near_far(DVec3::new(0.0, 0.0, -3.0), DVec3::Z);
        assert!((n - 2.0).abs() < 1e-12 && (f - 4.0).abs() < 1e-12);
        // Camera inside the bound: near is clamped in front of it.
        let (n, f) = near_far(DVec3::new(0.0, 0.0, 0.5), DVec3::Z);
        assert!(n >= 0.05 && f > n);
        let d = coarse_depths(2.0, 4.0, 4, 0.5);
        assert_eq!(d, vec![2.25, 2.75, 3.25, 3.75, 4.0]);
    }
}
