//! From drawn pixels to the backbone's rays: the estimator's coarse samples along each pixel's
//! ray, NeuS's hierarchical up-sampling, and (guided) the extra points around λ̃ with what the
//! surface losses need per ray.

use datasets::View;
use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
use rayon::prelude::*;
use sdf_backbone::{Backbone, RayInput, merge_sorted};
use surface_losses::{ExtraPoints, RaySurface, extra_depths};
use view_sampler::{CoarseRay, ErrorMap, Estimator, RaySample};

/// Samples per ray and how they are placed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sampling {
    /// Coarse samples (stratified over the ray's occupied intervals, or [near, far]).
    pub coarse: usize,
    /// Up-sampled samples, extra points included.
    pub fine: usize,
    /// Up-sampling rounds.
    pub rounds: usize,
    /// Scale of the first up-sampling round.
    pub upsample_s: f64,
    /// Extra points around λ̃ (rays that have one), taken from `fine`.
    pub extra_points: usize,
    /// Their law.
    pub extra: ExtraPoints,
    /// Widen their spread by λ̃'s own resolution (one λ bin of the camera grid), in quadrature.
    pub extra_bin_spread: bool,
}

/// Where a batch's pixels come from.
#[derive(Debug, Clone, Copy)]
pub enum PixelSource<'a> {
    /// The estimator's draw: guided, or uniform without a guide.
    Estimator,
    /// A loss-guided sampler: pixels from the error map, each ray's pixel terms weighted by
    /// [`ErrorMap::mining_weight`] at `alpha` (0: the error map's hard mining).
    Mined {
        /// The error map.
        map: &'a ErrorMap,
        /// Soft mining's α at this step.
        alpha: f64,
    },
}

/// The rays of one iteration with the surface-loss information of each.
#[derive(Debug, Clone)]
pub struct Batch {
    /// What the estimator drew.
    pub drawn: Vec<RaySample>,
    /// Rays with their final sample depths, targets and masks.
    pub rays: Vec<RayInput<f32>>,
    /// Per ray: λ̃ as a distance along the ray and whether it is a background ray (rays without
    /// λ̃: background, unused by the losses).
    pub surfaces: Vec<RaySurface>,
}

/// A stream seed from (seed, step, item): the sampler's SplitMix64 finalisation, on a seed
/// offset so that the trainer's streams differ from the sampler's.
pub fn stream_seed(seed: u64, step: u64, item: u64) -> u64 {
    view_sampler::stream_seed(seed ^ 0x7261_7973, step, item)
}

/// The backbone's ray of an estimator's ray (no target yet).
fn ray_input(ray: CoarseRay) -> RayInput<f32> {
    RayInput { origin: ray.origin, direction: ray.direction, depths: ray.depths, target: [0.0; 3], mask: None, weight: 1.0 }
}

/// Builds the `n` rays of iteration `step` at `progress` (the estimator's draw, camera indices
/// into `views`): coarse depths, up-sampling (fewer for rays that get extra points), extra
/// points around λ̃ at scale `s`; targets and masks (`use_masks`) from the views; the pixels from
/// `pixels`.
/// Deterministic in (seed, step).
#[allow(clippy::too_many_arguments)]
pub fn build_batch(
    estimator: &Estimator,
    views: &[&View],
    use_masks: bool,
    backbone: &Backbone,
    params: &[f32],
    sampling: &Sampling,
    pixels: PixelSource<'_>,
    (n, progress): (usize, f64),
    seed: u64,
    step: u64,
    s: f64,
) -> Batch {
    // One stream per ray: its coarse jitter first, then its extra points' uniforms.
    let mut rngs: Vec<Xoshiro256PlusPlus> = (0..n).map(|i| Xoshiro256PlusPlus::seed_from_u64(stream_seed(seed, step, i as u64))).collect();
    let jitters: Vec<f64> = rngs.iter_mut().map(|rng| rng.random()).collect();
    let drawn = match pixels {
        PixelSource::Estimator => estimator.draw_rays(n, progress, seed, step, sampling.coarse, &|i| jitters[i]),
        PixelSource::Mined { map, .. } => estimator.rays_of(map.draw(n, seed, step), sampling.coarse, &|i| jitters[i]),
    };
    let guided = drawn.iter().any(|d| d.sample.depth.is_some());
    let n_extra = if guided { sampling.extra_points } else { 0 };
    // The coarse rays become the backbone's rays by value (their depths are not copied).
    let (heads, coarse): (Vec<_>, Vec<_>) = drawn.into_iter().map(|d| ((d.sample, d.surface), d.ray)).unzip();
    let mut rays: Vec<RayInput<f32>> = coarse
        .into_par_iter()
        .zip(heads.par_iter())
        .map(|(coarse, (sample, _))| {
            let view = views[sample.camera as usize];
            let [col, row] = sample.pixel;
            let mut ray = ray_input(coarse);
            ray.target = view.image.get_f32(col, row);
            ray.mask = if use_masks { view.mask.as_ref().map(|m| if m.get(col, row) { 1.0 } else { 0.0 }) } else { None };
            if let PixelSource::Mined { map, alpha } = pixels {
                ray.weight = map.mining_weight(sample, alpha);
            }
            ray
        })
        .collect();
    backbone.upsample(params, &mut rays, sampling.fine - n_extra, sampling.rounds, sampling.upsample_s);
    let surfaces = rays
        .par_iter_mut()
        .zip(rngs.par_iter_mut())
        .zip(heads.par_iter())
        .map(|((ray, rng), (_, surface))| {
            let Some(surface) = surface else {
                return RaySurface { depth: 0.0, background: true };
            };
            if n_extra > 0 {
                let (near, far) = (f64::from(ray.depths[0]), f64::from(*ray.depths.last().expect("depths")));
                let u: Vec<f64> = (0..n_extra).map(|_| rng.random()).collect();
                let depth_sigma = if sampling.extra_bin_spread { surface.bin } else { 0.0 };
                let extra: Vec<f32> =
                    extra_depths(sampling.extra, surface.distance, s, depth_sigma, near, far, &u).into_iter().map(|t| t as f32).collect();
                ray.depths = merge_sorted(&ray.depths, &extra);
            }
            RaySurface { depth: surface.distance, background: surface.background }
        })
        .collect();
    Batch { drawn: heads.into_iter().map(|(sample, _)| sample).collect(), rays, surfaces }
}
