//! The probability-guided ray sampler of PS-NeuS (Sec. 4.4 and 5.1 of the paper).
//!
//! `prob-grid` turns an SDF into a view-dependent probability grid p̃(u, v, λ) per camera; this
//! crate draws rays from it:
//! - [`CameraDistribution`]: per camera, the marginal p̃(u), the conditionals p̃(v | u) and
//!   p̃(λ | u, v) (eqs. 9–12) by inverse transform, pbrt style (explicit uniform numbers in,
//!   value and pdf out, `pdf` and `invert` for checks). λ-only sampling serves uniform rays.
//! - [`ViewSampler`]: a batch of N rays over all cameras → (camera, pixel, λ̃, pdf), mixing
//!   guided and uniform rays by a [`UniformSchedule`] (the paper: 20 % uniform, then 40, 60,
//!   80 % in the later quarters of training).
//! - [`ErrorMap`]: the loss-guided competitors, instant-ngp's error map and soft mining (pixels
//!   drawn in proportion to the recent loss, with or without the importance correction).
//!
//! # Choices
//! - Continuous (ũ, ṽ) is snapped to the nearest pixel centre for the colour target (docs/DECISIONS.md §4);
//!   the continuous coordinates and the pdf are returned too.
//! - A camera whose grid has no mass falls back to uniform pixels and depths
//!   ([`CameraDistribution::is_uniform_fallback`], listed by [`ViewSampler::fallback_cameras`]).
//! - Randomness: each chunk of [`CHUNK`] rays has its own RNG stream, seeded from
//!   (seed, step, chunk index), so a batch is identical whatever the number of threads.
//!
//! # Invariant
//! Sampling is outside any gradient graph: it returns numbers, and nothing here differentiates.
//!
//! ```
//! use prob_grid::{update, CameraGridConfig, SceneGridConfig, Shape};
//! use view_sampler::{ViewSampler, SamplerConfig};
//! use camera_geom::{Intrinsics, PinholeCamera, PixelCenters};
//! use glam::DVec3;
//! let k = Intrinsics { fx: 300.0, fy: 300.0, cx: 99.5, cy: 74.5, skew: 0.0 };
//! let camera = PinholeCamera::look_at(DVec3::new(0.0, -3.0, 0.0), DVec3::ZERO, DVec3::Z, k, 200, 150, PixelCenters::Integer).unwrap();
//! let sphere = Shape::Sphere { center: DVec3::ZERO, radius: 0.5 };
//! let grids = update(&sphere, 200.0, &[camera], &SceneGridConfig { resolution: 32, ..Default::default() },
//!                    &CameraGridConfig { ru: 16, rv: 16, rl: 32, ..Default::default() }).unwrap();
//! let sampler = ViewSampler::new(grids.cameras, SamplerConfig::default());
//! let rays = sampler.sample_batch(1024, 0.0, 7, 0);
//! assert_eq!(rays.len(), 1024);
//! ```
#![deny(missing_docs)]

mod distribution;
mod error_map;
mod estimator;

pub use distribution::{CameraDistribution, ImageSpaceSample, Interpolation};
pub use error_map::{ErrorMap, ErrorMapConfig, ErrorMapStateError};
pub use estimator::{
    CARRIED_LIPSCHITZ_MARGIN, CoarseRay, DrawnRay, Estimator, EstimatorConfig, EstimatorState, INITIAL_LIPSCHITZ, SurfaceDistance, UpdateReport,
    march_through, march_through_with, near_far,
};

use camera_geom::PinholeCamera;
use glam::DVec2;
use prob_grid::CameraGrid;
use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
use rayon::prelude::*;

/// Rays per RNG stream.
pub const CHUNK: usize = 256;

/// Fraction of uniform rays as training progresses: `fractions[i]` for progress in
/// `[i/n, (i+1)/n)`. The paper: 0.2, 0.4, 0.6, 0.8 (docs/DECISIONS.md §5: equal parts of the run).
#[derive(Debug, Clone, PartialEq)]
pub struct UniformSchedule {
    /// Uniform fraction per equal part of the run.
    pub fractions: Vec<f64>,
}

impl Default for UniformSchedule {
    fn default() -> Self {
        UniformSchedule { fractions: vec![0.2, 0.4, 0.6, 0.8] }
    }
}

impl UniformSchedule {
    /// The uniform fraction at `progress` ∈ [0, 1].
    pub fn fraction(&self, progress: f64) -> f64 {
        if self.fractions.is_empty() {
            return 0.0;
        }
        let n = self.fractions.len();
        let i = ((progress.clamp(0.0, 1.0) * n as f64) as usize).min(n - 1);
        self.fractions[i].clamp(0.0, 1.0)
    }
}

/// Sampler configuration.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SamplerConfig {
    /// Interpolation of the conditionals.
    pub interpolation: Interpolation,
    /// Uniform/guided mix.
    pub schedule: UniformSchedule,
}

/// One ray drawn by a sampler.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RaySample {
    /// Camera index.
    pub camera: u32,
    /// The pixel (column, row) whose centre is nearest to (ũ, ṽ): the colour target.
    pub pixel: [u32; 2],
    /// Continuous pixel coordinates (ũ, ṽ) (for uniform rays, the pixel centre).
    pub pixel_coords: DVec2,
    /// Density of (ũ, ṽ) under the guided distribution of this camera, per pixel² (for rays
    /// drawn without a guide, the uniform density 1 / (width · height)).
    pub pdf_pixel: f32,
    /// True for guided rays, false for uniform ones.
    pub guided: bool,
    /// λ̃ for this pixel, when a guide exists (uniform rays of a guided run get one too, as the
    /// paper does); `None` without a guide.
    pub depth: Option<DepthSample>,
}

/// The depth λ̃ drawn for a ray's pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthSample {
    /// λ̃ along the optical axis (normalised units).
    pub depth: f32,
    /// Density of λ̃ given the pixel, per unit depth.
    pub pdf: f32,
    /// True when λ̃ was drawn from the pixel's depth conditional; false when the pixel's column
    /// held no mass and λ̃ is uniform over the depth range (the ray likely misses the surface).
    pub from_grid: bool,
}

/// A uniform pixel of `camera` from two uniform numbers: (column, row), its centre, its density.
pub fn uniform_pixel(camera: &PinholeCamera, u: [f64; 2]) -> ([u32; 2], DVec2, f64) {
    let col = ((u[0] * camera.width as f64) as u32).min(camera.width - 1);
    let row = ((u[1] * camera.height as f64) as u32).min(camera.height - 1);
    ([col, row], camera.pixel_center(col, row), 1.0 / (camera.width as f64 * camera.height as f64))
}

/// Guided ray sampling over a set of cameras.
#[derive(Debug, Clone)]
pub struct ViewSampler {
    cameras: Vec<CameraDistribution>,
    config: SamplerConfig,
}

/// `n` rays in chunks of [`CHUNK`], each chunk with its own RNG stream from (seed, step, chunk):
/// ray i gets a camera (uniform over `cameras`) and three uniforms for `draw(i, camera, u)`.
/// Deterministic whatever the thread count.
pub(crate) fn draw_batch(
    n: usize,
    cameras: usize,
    seed: u64,
    step: u64,
    draw: impl Fn(usize, usize, [f64; 3]) -> RaySample + Sync,
) -> Vec<RaySample> {
    let empty = RaySample { camera: 0, pixel: [0, 0], pixel_coords: DVec2::ZERO, pdf_pixel: 0.0, guided: false, depth: None };
    let mut out = vec![empty; n];
    out.par_chunks_mut(CHUNK).enumerate().for_each(|(chunk, rays)| {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(stream_seed(seed, step, chunk as u64));
        for (k, ray) in rays.iter_mut().enumerate() {
            let camera = ((rng.random::<f64>() * cameras as f64) as usize).min(cameras - 1);
            *ray = draw(chunk * CHUNK + k, camera, [rng.random(), rng.random(), rng.random()]);
        }
    });
    out
}

/// A stream seed from (seed, step, chunk) by SplitMix64 finalisation (one RNG stream per work
/// item; also used by the trainer for its per-ray streams).
pub fn stream_seed(seed: u64, step: u64, chunk: u64) -> u64 {
    let mut z = seed ^ step.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ chunk.wrapping_mul(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl ViewSampler {
    /// Builds every camera's CDFs (in parallel).
    pub fn new(grids: Vec<CameraGrid>, config: SamplerConfig) -> ViewSampler {
        let cameras = grids.into_par_iter().map(|g| CameraDistribution::new(g, config.interpolation)).collect();
        ViewSampler { cameras, config }
    }

    /// The per-camera distributions.
    pub fn cameras(&self) -> &[CameraDistribution] {
        &self.cameras
    }

    /// Cameras whose grid held no mass (sampled uniformly).
    pub fn fallback_cameras(&self) -> Vec<usize> {
        self.cameras.iter().enumerate().filter(|(_, c)| c.is_uniform_fallback()).map(|(i, _)| i).collect()
    }

    fn uniform_depth(d: &CameraDistribution, u: f64) -> (f64, f64) {
        let b = d.bounds().depth;
        (b[0] + u * (b[1] - b[0]), 1.0 / (b[1] - b[0]))
    }

    /// First half of a ray: the pixel (guided: from the marginal; uniform: a uniform pixel
    /// centre), with its pdf under the guided distribution and the nearest pixel.
    fn ray_pixel(&self, camera: usize, guided: bool, u: [f64; 2]) -> ((u32, u32), DVec2, f64) {
        let d = &self.cameras[camera];
        let cam = d.camera();
        if guided {
            let (coords, pdf) = d.sample_pixel(u);
            let o = cam.pixel_centers.offset();
            let pixel = cam.nearest_pixel(coords).unwrap_or_else(|| {
                // Bounds are the image's edges, so this only guards rounding at the last pixel.
                let c = (coords.x - o).round().clamp(0.0, cam.width as f64 - 1.0) as u32;
                let r = (coords.y - o).round().clamp(0.0, cam.height as f64 - 1.0) as u32;
                (c, r)
            });
            (pixel, coords, pdf)
        } else {
            let ([col, row], coords, _) = uniform_pixel(cam, u);
            ((col, row), coords, d.pdf_pixel(coords))
        }
    }

    /// Second half of a ray: λ̃ for its pixel (uniform in depth where the column is empty), and
    /// whether it came from the grid.
    fn ray_depth(&self, camera: usize, coords: DVec2, u: f64) -> (f64, f64, bool) {
        let d = &self.cameras[camera];
        match d.sample_depth(coords, u) {
            Some((depth, pdf)) => (depth, pdf, true),
            None => {
                let (depth, pdf) = Self::uniform_depth(d, u);
                (depth, pdf, false)
            }
        }
    }

    /// Draws one ray of `camera` from three uniform numbers (pixel, then depth).
    pub fn sample_ray(&self, camera: usize, guided: bool, u: [f64; 3]) -> RaySample {
        let (pixel, coords, pdf_pixel) = self.ray_pixel(camera, guided, [u[0], u[1]]);
        let (depth, pdf_depth, from_grid) = self.ray_depth(camera, coords, u[2]);
        RaySample {
            camera: camera as u32,
            pixel: [pixel.0, pixel.1],
            pixel_coords: coords,
            pdf_pixel: pdf_pixel as f32,
            guided,
            depth: Some(DepthSample { depth: depth as f32, pdf: pdf_depth as f32, from_grid }),
        }
    }

    /// Draws `n` rays over all cameras (uniformly chosen) at training `progress` ∈ [0, 1]: the
    /// first `round(fraction · n)` are uniform, the rest guided. Deterministic in (seed, step),
    /// whatever the thread count.
    pub fn sample_batch(&self, n: usize, progress: f64, seed: u64, step: u64) -> Vec<RaySample> {
        self.sample_batch_mixed(n, self.config.schedule.fraction(progress), seed, step)
    }

    /// [`Self::sample_batch`] with the uniform share given instead of the schedule's:
    /// the first `round(uniform_fraction · n)` rays are uniform (`uniform_fraction` clamped to
    /// [0, 1]; NaN counts as 0).
    pub fn sample_batch_mixed(&self, n: usize, uniform_fraction: f64, seed: u64, step: u64) -> Vec<RaySample> {
        let fraction = if uniform_fraction.is_nan() { 0.0 } else { uniform_fraction.clamp(0.0, 1.0) };
        let uniform = (fraction * n as f64).round() as usize;
        draw_batch(n, self.cameras.len(), seed, step, |i, camera, u| self.sample_ray(camera, i >= uniform, u))
    }
}
