//! Pixel samplers guided by the training loss instead of the surface: the competitors a user
//! would pick instead of the probability-guided sampler.
//!
//! - **Error map** (instant-ngp / torch-ngp): per camera a coarse map of the recent per-pixel
//!   loss (at most 128 × 128 cells, initialised to 1 so that every cell is visited before its
//!   error is known, updated by an exponential moving average that gives the new error weight
//!   0.9); pixels are drawn with probability proportional to their cell's error, and the loss is
//!   not corrected (hard mining).
//! - **Soft mining** (Kheradmand et al., CVPR 2024): the same importance distribution Q, but each
//!   pixel's loss is weighted by `(p_uniform / Q)^α` ([`ErrorMap::mining_weight`]); α = 0 is the
//!   error map, α = 1 unbiased importance sampling. The paper draws from Q by Langevin Monte Carlo
//!   because its Q is continuous; ours is tabulated, so it is drawn exactly by inverse transform.
//!
//! Both mix a share of uniform pixels into Q (`uniform_share`): a cell whose error fell to zero
//! would otherwise never be drawn again, and so never updated (torch-ngp has no such floor).
//!
//! pbrt style like the rest of the crate: explicit uniform numbers in, the pixel and its density
//! out; a batch depends on (seed, step) only ([`crate::CHUNK`] rays per RNG stream).

use crate::{RaySample, draw_batch};
use camera_geom::PinholeCamera;

/// Configuration of an [`ErrorMap`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ErrorMapConfig {
    /// Cells per side at most (a camera narrower than this has one cell per pixel column or row).
    pub cells: u32,
    /// Weight of a new error in a cell's moving average (torch-ngp: 0.9).
    pub new_weight: f32,
    /// Share of uniform density mixed into Q, in [0, 1].
    pub uniform_share: f64,
}

impl Default for ErrorMapConfig {
    fn default() -> Self {
        ErrorMapConfig { cells: 128, new_weight: 0.9, uniform_share: 0.1 }
    }
}

/// One camera's map: `cols × rows` cells over its `width × height` pixels, with the cumulative
/// sums of the cells' errors (row-major) for inverse-transform sampling.
#[derive(Debug, Clone)]
struct CameraMap {
    width: u32,
    height: u32,
    cols: u32,
    rows: u32,
    errors: Vec<f32>,
    cumulative: Vec<f64>,
}

impl CameraMap {
    fn new(camera: &PinholeCamera, cells: u32) -> CameraMap {
        let (cols, rows) = (cells.clamp(1, camera.width), cells.clamp(1, camera.height));
        let mut map =
            CameraMap { width: camera.width, height: camera.height, cols, rows, errors: vec![1.0; (cols * rows) as usize], cumulative: Vec::new() };
        map.rebuild();
        map
    }

    fn rebuild(&mut self) {
        self.cumulative.clear();
        let mut sum = 0.0;
        for &e in &self.errors {
            sum += f64::from(e);
            self.cumulative.push(sum);
        }
    }

    fn total(&self) -> f64 {
        self.cumulative.last().copied().unwrap_or(0.0)
    }

    /// The first pixel and the pixel count of cell `c` along an axis of `n` pixels in `cells`.
    fn span(c: u32, cells: u32, n: u32) -> (u32, u32) {
        let start = (u64::from(c) * u64::from(n) / u64::from(cells)) as u32;
        let end = (u64::from(c + 1) * u64::from(n) / u64::from(cells)) as u32;
        (start, end - start)
    }

    /// The cell along an axis whose [`Self::span`] holds pixel `p`: the c with
    /// ⌊c·n/cells⌋ ≤ p < ⌊(c+1)·n/cells⌋, i.e. ⌈(p+1)·cells/n⌉ − 1.
    fn cell_along(p: u32, cells: u32, n: u32) -> u32 {
        (((u64::from(p) + 1) * u64::from(cells) - 1) / u64::from(n)) as u32
    }

    /// The cell of a pixel.
    fn cell_of(&self, [col, row]: [u32; 2]) -> usize {
        let cx = Self::cell_along(col, self.cols, self.width);
        let cy = Self::cell_along(row, self.rows, self.height);
        (cy.min(self.rows - 1) * self.cols + cx.min(self.cols - 1)) as usize
    }

    fn cell_pixels(&self, cell: usize) -> f64 {
        let (cx, cy) = (cell as u32 % self.cols, cell as u32 / self.cols);
        let (_, w) = Self::span(cx, self.cols, self.width);
        let (_, h) = Self::span(cy, self.rows, self.height);
        f64::from(w) * f64::from(h)
    }

    /// The density Q of a pixel of `cell`, per pixel², uniform share included.
    fn density(&self, cell: usize, uniform_share: f64) -> f64 {
        let uniform = 1.0 / (f64::from(self.width) * f64::from(self.height));
        let total = self.total();
        if total <= 0.0 || !total.is_finite() {
            return uniform;
        }
        let mined = f64::from(self.errors[cell]) / total / self.cell_pixels(cell);
        uniform_share * uniform + (1.0 - uniform_share) * mined
    }

    /// The pixel of three uniform numbers: the first picks uniform or mined, then the cell by
    /// the cumulative sums, the last two the pixel inside the cell.
    fn sample(&self, u: [f64; 3], uniform_share: f64) -> [u32; 2] {
        let total = self.total();
        let (pick, ux, uy) = (u[0], u[1], u[2]);
        if pick < uniform_share || total <= 0.0 || !total.is_finite() {
            let col = ((ux * f64::from(self.width)) as u32).min(self.width - 1);
            let row = ((uy * f64::from(self.height)) as u32).min(self.height - 1);
            return [col, row];
        }
        // Rescale the first number to [0, 1) within the mined branch: it picks the cell.
        let v = ((pick - uniform_share) / (1.0 - uniform_share)).clamp(0.0, 1.0) * total;
        let cell = self.cumulative.partition_point(|&c| c <= v).min(self.cumulative.len() - 1);
        let (cx, cy) = (cell as u32 % self.cols, cell as u32 / self.cols);
        let (x0, w) = Self::span(cx, self.cols, self.width);
        let (y0, h) = Self::span(cy, self.rows, self.height);
        [x0 + ((ux * f64::from(w)) as u32).min(w - 1), y0 + ((uy * f64::from(h)) as u32).min(h - 1)]
    }
}

/// Per-camera maps of the recent training loss, and the pixel distribution they define.
#[derive(Debug, Clone)]
pub struct ErrorMap {
    cameras: Vec<PinholeCamera>,
    maps: Vec<CameraMap>,
    config: ErrorMapConfig,
}

/// What [`ErrorMap::restore`] refuses.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ErrorMapStateError {
    /// The state holds another number of cells than the map.
    #[error("the error map holds {expected} cells, the state {found}")]
    Size {
        /// Cells of the map.
        expected: usize,
        /// Values in the state.
        found: usize,
    },
    /// A cell's error is negative, infinite or NaN.
    #[error("the error map's cell {0} is negative or not finite")]
    Value(usize),
}

impl ErrorMap {
    /// Maps of every camera with all cells at 1 (`config.cells` clamped to at least 1 and
    /// `uniform_share` to [0, 1]).
    pub fn new(cameras: Vec<PinholeCamera>, config: ErrorMapConfig) -> ErrorMap {
        let config = ErrorMapConfig {
            cells: config.cells.max(1),
            uniform_share: if config.uniform_share.is_nan() { 0.0 } else { config.uniform_share.clamp(0.0, 1.0) },
            new_weight: if config.new_weight.is_nan() { 1.0 } else { config.new_weight.clamp(0.0, 1.0) },
        };
        let maps = cameras.iter().map(|c| CameraMap::new(c, config.cells)).collect();
        ErrorMap { cameras, maps, config }
    }

    /// The configuration in use.
    pub fn config(&self) -> &ErrorMapConfig {
        &self.config
    }

    /// One pixel of `camera` from three uniform numbers, with its density Q per pixel²
    /// (`pdf_pixel`; no depth: the sampler knows nothing of the surface).
    pub fn sample(&self, camera: usize, u: [f64; 3]) -> RaySample {
        let map = &self.maps[camera];
        let pixel = map.sample(u, self.config.uniform_share);
        RaySample {
            camera: camera as u32,
            pixel,
            pixel_coords: self.cameras[camera].pixel_center(pixel[0], pixel[1]),
            pdf_pixel: map.density(map.cell_of(pixel), self.config.uniform_share) as f32,
            guided: false,
            depth: None,
        }
    }

    /// The density Q of a pixel of `camera`, per pixel².
    pub fn pdf(&self, camera: usize, pixel: [u32; 2]) -> f64 {
        let map = &self.maps[camera];
        map.density(map.cell_of(pixel), self.config.uniform_share)
    }

    /// `n` pixels over all cameras (each ray's camera uniform, as the other samplers'), with
    /// their densities. Deterministic in (seed, step), whatever the thread count.
    pub fn draw(&self, n: usize, seed: u64, step: u64) -> Vec<RaySample> {
        draw_batch(n, self.maps.len(), seed, step, |_, camera, u| self.sample(camera, u))
    }

    /// Soft mining's weight of a drawn pixel: `(p_uniform / Q)^α`, 1 at α = 0 (the error map) and
    /// the importance weight at α = 1; finite and positive for any density.
    pub fn mining_weight(&self, sample: &RaySample, alpha: f64) -> f32 {
        if alpha == 0.0 {
            return 1.0;
        }
        let uniform = uniform_density(&self.cameras[sample.camera as usize]);
        let q = f64::from(sample.pdf_pixel).max(uniform * 1e-6);
        let w = (uniform / q).powf(alpha);
        if w.is_finite() { w as f32 } else { 1.0 }
    }

    /// Folds one ray's loss into its pixel's cell (the moving average); a non-finite or negative
    /// error is ignored. [`Self::rebuild`] makes it count for sampling.
    pub fn record(&mut self, camera: u32, pixel: [u32; 2], error: f32) {
        if !(error.is_finite() && error >= 0.0) {
            return;
        }
        let Some(map) = self.maps.get_mut(camera as usize) else { return };
        if pixel[0] >= map.width || pixel[1] >= map.height {
            return;
        }
        let cell = map.cell_of(pixel);
        let a = self.config.new_weight;
        map.errors[cell] = (1.0 - a) * map.errors[cell] + a * error;
    }

    /// Recomputes the cumulative sums after [`Self::record`]s.
    pub fn rebuild(&mut self) {
        for map in &mut self.maps {
            map.rebuild();
        }
    }

    /// Every cell's error, camera after camera (row-major): what a checkpoint stores.
    pub fn state(&self) -> Vec<f32> {
        self.maps.iter().flat_map(|m| m.errors.iter().copied()).collect()
    }

    /// Restores [`Self::state`]; refuses a state of another size or with a bad value.
    pub fn restore(&mut self, state: &[f32]) -> Result<(), ErrorMapStateError> {
        let expected: usize = self.maps.iter().map(|m| m.errors.len()).sum();
        if state.len() != expected {
            return Err(ErrorMapStateError::Size { expected, found: state.len() });
        }
        if let Some(i) = state.iter().position(|e| !(e.is_finite() && *e >= 0.0)) {
            return Err(ErrorMapStateError::Value(i));
        }
        let mut rest = state;
        for map in &mut self.maps {
            let (mine, next) = rest.split_at(map.errors.len());
            map.errors.copy_from_slice(mine);
            rest = next;
        }
        self.rebuild();
        Ok(())
    }

    /// The error map of `camera` as (cols, rows, errors row-major), for pictures.
    pub fn camera_errors(&self, camera: usize) -> (u32, u32, &[f32]) {
        let m = &self.maps[camera];
        (m.cols, m.rows, &m.errors)
    }
}

/// The uniform density of `camera`'s pixels, per pixel².
fn uniform_density(camera: &PinholeCamera) -> f64 {
    1.0 / (f64::from(camera.width) * f64::from(camera.height))
}

#[cfg(test)]
mod tests {
    use super::*;
    use camera_geom::{Intrinsics, PixelCenters};
    use glam::{DVec2, DVec3};

    fn camera(width: u32, height: u32) -> PinholeCamera {
        let k = Intrinsics { fx: 100.0, fy: 100.0, cx: width as f64 / 2.0, cy: height as f64 / 2.0, skew: 0.0 };
        PinholeCamera::look_at(DVec3::new(0.0, -3.0, 0.0), DVec3::ZERO, DVec3::Z, k, width, height, PixelCenters::Integer).unwrap()
    }

    /// Sums Q over every pixel of a camera.
    fn total_density(map: &ErrorMap, camera: usize) -> f64 {
        let c = map.cameras[camera];
        (0..c.height).flat_map(|r| (0..c.width).map(move |col| [col, r])).map(|p| map.pdf(camera, p)).sum()
    }

    #[test]
    fn the_pixel_density_integrates_to_one_whatever_the_errors() {
        // Cells that do not divide the image evenly (37 × 23 pixels in 5 × 4 cells).
        let mut map = ErrorMap::new(vec![camera(37, 23)], ErrorMapConfig { cells: 5, ..Default::default() });
        assert!((total_density(&map, 0) - 1.0).abs() < 1e-9);
        for (i, p) in [[0, 0], [36, 22], [10, 5], [20, 20]].into_iter().enumerate() {
            map.record(0, p, i as f32 * 3.0);
        }
        map.rebuild();
        assert!((total_density(&map, 0) - 1.0).abs() < 1e-9, "{}", total_density(&map, 0));
    }

    #[test]
    fn draws_follow_the_error_and_their_pdf_is_the_density_drawn() {
        let config = ErrorMapConfig { cells: 2, new_weight: 1.0, uniform_share: 0.2 };
        let mut map = ErrorMap::new(vec![camera(40, 20)], config);
        // Left-top cell error 7, the others 1: Q = 0.2/800 + 0.8 · e/10/200 per pixel.
        map.record(0, [3, 3], 7.0);
        for p in [[30, 3], [3, 15], [30, 15]] {
            map.record(0, p, 1.0);
        }
        map.rebuild();
        let draws = map.draw(40_000, 3, 0);
        let hot = draws.iter().filter(|d| d.pixel[0] < 20 && d.pixel[1] < 10).count() as f64 / draws.len() as f64;
        let expected = 0.2 * 0.25 + 0.8 * 0.7;
        assert!((hot - expected).abs() < 0.01, "{hot} vs {expected}");
        for d in &draws[..100] {
            assert_eq!(f64::from(d.pdf_pixel) as f32, map.pdf(0, d.pixel) as f32);
            assert!(d.pixel[0] < 40 && d.pixel[1] < 20 && d.depth.is_none() && !d.guided);
        }
        assert!((map.pdf(0, [3, 3]) - (0.2 / 800.0 + 0.8 * 0.7 / 200.0)).abs() < 1e-12);
    }

    #[test]
    fn a_batch_is_the_same_whatever_the_thread_count() {
        let map = ErrorMap::new(vec![camera(30, 20), camera(16, 16)], ErrorMapConfig::default());
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(|| map.draw(1000, 9, 4));
        assert_eq!(one, map.draw(1000, 9, 4));
    }

    #[test]
    fn soft_mining_weights_undo_the_density_at_alpha_one_and_are_one_at_zero() {
        let mut map = ErrorMap::new(vec![camera(10, 10)], ErrorMapConfig { cells: 10, new_weight: 1.0, uniform_share: 0.0 });
        map.record(0, [0, 0], 0.0);
        map.record(0, [1, 0], 50.0);
        map.rebuild();
        // E_Q[w · f] = E_uniform[f] at α = 1: here f = 1, so Σ Q · w over pixels = 1.
        let sum: f64 = (0..10)
            .flat_map(|r| (0..10).map(move |c| [c, r]))
            .map(|p| {
                let s = RaySample { camera: 0, pixel: p, pixel_coords: DVec2::ZERO, pdf_pixel: map.pdf(0, p) as f32, guided: false, depth: None };
                map.pdf(0, p) * f64::from(map.mining_weight(&s, 1.0))
            })
            .sum();
        // The pixel of error 0 has Q = 0 (no uniform share): its weight is capped and its
        // uniform mass (1/100) is what importance sampling cannot recover.
        assert!((sum - 0.99).abs() < 1e-4, "{sum}");
        let zero = RaySample { camera: 0, pixel: [0, 0], pixel_coords: DVec2::ZERO, pdf_pixel: 0.0, guided: false, depth: None };
        assert!(map.mining_weight(&zero, 0.6).is_finite());
        assert_eq!(map.mining_weight(&zero, 0.0), 1.0);
    }

    #[test]
    fn bad_errors_and_pixels_are_ignored_and_bad_states_refused() {
        let mut map = ErrorMap::new(vec![camera(8, 8)], ErrorMapConfig::default());
        let before = map.state();
        map.record(0, [1, 1], f32::NAN);
        map.record(0, [1, 1], -1.0);
        map.record(0, [8, 1], 5.0);
        map.record(3, [1, 1], 5.0);
        assert_eq!(map.state(), before);
        assert_eq!(map.restore(&[1.0; 3]), Err(ErrorMapStateError::Size { expected: 64, found: 3 }));
        let mut bad = before.clone();
        bad[5] = f32::INFINITY;
        assert_eq!(map.restore(&bad), Err(ErrorMapStateError::Value(5)));
        let mut good = before;
        good[0] = 4.0;
        map.restore(&good).unwrap();
        assert_eq!(map.state(), good);
    }

    #[test]
    fn an_all_zero_map_falls_back_to_uniform_pixels() {
        let mut map = ErrorMap::new(vec![camera(6, 4)], ErrorMapConfig { cells: 6, new_weight: 1.0, uniform_share: 0.0 });
        for r in 0..4 {
            for c in 0..6 {
                map.record(0, [c, r], 0.0);
            }
        }
        map.rebuild();
        assert!((total_density(&map, 0) - 1.0).abs() < 1e-9);
        let d = map.sample(0, [0.5, 0.5, 0.5]);
        assert!((f64::from(d.pdf_pixel) - 1.0 / 24.0).abs() < 1e-7);
    }
}
