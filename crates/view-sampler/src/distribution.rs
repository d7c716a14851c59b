//! One camera's distribution over its 3D image space: marginal p̃(u), conditional p̃(v | u) and
//! p̃(λ | u, v) (paper eqs. 9–12), sampled by inverse transform.
//!
//! pbrt style: every sampler takes explicit uniform numbers in [0, 1) and returns the value with
//! its pdf; `pdf` evaluates the same density and `invert` maps a value back to the uniform
//! numbers (round trips are tested).
//!
//! **Interpolation (Sec. 4.4; docs/DECISIONS.md §4).** ũ is drawn from the piecewise-constant marginal over
//! the R_u columns. With [`Interpolation::Linear`] (default, the paper's choice), p̃(v | ũ) mixes
//! the two u-columns whose centres bracket ũ with linear weights, and p̃(λ | ũ, ṽ) mixes the four
//! (u, v)-columns around (ũ, ṽ) with bilinear weights. Mixtures of piecewise-constant densities
//! on the same bins are piecewise constant on those bins, so each step is still an exact inverse
//! transform, and the returned pdf is exactly the density of what was drawn (tested by
//! histogram). [`Interpolation::Nearest`] uses the cell that contains the point (cheaper; the
//! density is the grid's own).
//!
//! Units: pixel coordinates are continuous (the camera's convention: NeuS integer coordinates
//! are pixel centres); densities are per pixel² (pixel marginal) and per unit depth.

use camera_geom::{ImageSpaceBounds, PinholeCamera};
use glam::DVec2;
use prob_grid::CameraGrid;

/// How the conditionals are evaluated between column centres.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Interpolation {
    /// The cell that contains the point.
    Nearest,
    /// Linear in u for p̃(v | u), bilinear in (u, v) for p̃(λ | u, v) (the paper). Default.
    #[default]
    Linear,
}

/// A point of a camera's 3D image space with its density.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageSpaceSample {
    /// Continuous pixel coordinates (ũ, ṽ).
    pub pixel: DVec2,
    /// Depth λ̃ along the optical axis.
    pub depth: f64,
    /// Density of (ũ, ṽ), per pixel².
    pub pdf_pixel: f64,
    /// Density of λ̃ given (ũ, ṽ), per unit depth.
    pub pdf_depth: f64,
}

impl ImageSpaceSample {
    /// The joint density, per pixel² per unit depth.
    pub fn pdf(&self) -> f64 {
        self.pdf_pixel * self.pdf_depth
    }
}

/// Bins per guide entry of the λ columns (two-level search: guide, then one block).
const BLOCK: usize = 16;

/// Up to four weighted columns of bins and the inverse transform over their mixture. Each column
/// is an inclusive prefix sum; a mixture of piecewise-constant densities on the same bins is
/// piecewise constant on those bins, with CDF `Σ_c w_c · C_c[k]`.
struct Mixture<'a> {
    parts: [(&'a [f32], f64); 4],
    count: usize,
    /// Optional guide: per column, the prefix sum at the end of every block of [`BLOCK`] bins.
    guide: Option<[&'a [f32]; 4]>,
}

impl<'a> Mixture<'a> {
    fn single(column: &'a [f32]) -> Self {
        Mixture { parts: [(column, 1.0), (&[], 0.0), (&[], 0.0), (&[], 0.0)], count: 1, guide: None }
    }

    #[inline]
    fn cdf(&self, k: usize) -> f64 {
        let mut acc = 0.0;
        for (c, w) in &self.parts[..self.count] {
            acc += w * c[k] as f64;
        }
        acc
    }

    #[inline]
    fn guide_cdf(&self, guide: &[&[f32]; 4], b: usize) -> f64 {
        let mut acc = 0.0;
        for (g, (_, w)) in guide.iter().zip(&self.parts[..self.count]) {
            acc += w * g[b] as f64;
        }
        acc
    }

    fn bins(&self) -> usize {
        self.parts[0].0.len()
    }

    /// The mixture's total: the last guide entry when there is a guide (its cache line is read
    /// by the search anyway), else the last prefix sum.
    fn total(&self) -> f64 {
        match &self.guide {
            Some(guide) => self.guide_cdf(guide, guide[0].len() - 1),
            None => self.cdf(self.bins() - 1),
        }
    }

    fn before(&self, k: usize) -> f64 {
        if k == 0 { 0.0 } else { self.cdf(k - 1) }
    }

    /// The first bin in `[lo, hi)` whose inclusive CDF exceeds `target` (`hi − 1` if none).
    /// (A branch-free variant measured slower over 49 cameras: branches let the CPU speculate
    /// the next loads, which matters more than mispredictions when the data is not cached.)
    fn search(&self, mut lo: usize, mut hi: usize, target: f64) -> usize {
        hi -= 1;
        while lo < hi {
            let mid = (lo + hi) / 2;
            if self.cdf(mid) > target { hi = mid } else { lo = mid + 1 }
        }
        lo
    }

    /// (bin, fraction within the bin, bin mass / total), or `None` for an all-zero mixture.
    fn sample(&self, u: f64) -> Option<(usize, f64, f64)> {
        let total = self.total();
        if !(total > 0.0) {
            return None;
        }
        let target = u.clamp(0.0, 1.0) * total;
        let bins = self.bins();
        let k = match &self.guide {
            Some(guide) => {
                let blocks = bins.div_ceil(BLOCK);
                let mut b = 0;
                while b + 1 < blocks && self.guide_cdf(guide, b) <= target {
                    b += 1;
                }
                self.search(b * BLOCK, ((b + 1) * BLOCK).min(bins), target)
            }
            None => self.search(0, bins, target),
        };
        let before = self.before(k);
        let mass = self.cdf(k) - before;
        if !(mass > 0.0) {
            // u = 1 walked past the end onto trailing empty bins: step back to the last full one.
            let last = (0..bins).rev().find(|&j| self.cdf(j) - self.before(j) > 0.0)?;
            return Some((last, 1.0, (self.cdf(last) - self.before(last)) / total));
        }
        Some((k, ((target - before) / mass).clamp(0.0, 1.0), mass / total))
    }

    /// Bin mass / total of bin k.
    fn probability(&self, k: usize) -> f64 {
        let total = self.total();
        if !(total > 0.0) {
            return 0.0;
        }
        (self.cdf(k) - self.before(k)) / total
    }

    /// The uniform number that `sample` maps to (bin k, fraction).
    fn invert(&self, k: usize, fraction: f64) -> f64 {
        let before = self.before(k);
        (before + fraction * (self.cdf(k) - before)) / self.total()
    }
}

/// A camera's sampling distribution, built from its [`CameraGrid`].
#[derive(Debug, Clone)]
pub struct CameraDistribution {
    camera: PinholeCamera,
    bounds: ImageSpaceBounds,
    ru: usize,
    rv: usize,
    rl: usize,
    /// Per (u, v) column: inclusive prefix sums of p̃ along λ.
    lambda_cdf: Vec<f32>,
    /// Per column: `lambda_cdf` at the end of every block of [`BLOCK`] bins. Random draws are
    /// bound by memory latency once 49 grids outgrow the caches; the guide turns a 7-step binary
    /// search over 8 cache lines into a scan of one line and a search inside one block.
    lambda_guide: Vec<f32>,
    /// Per u: inclusive prefix sums along v of the column totals (f32 for the mixture code).
    v_cdf: Vec<f32>,
    /// Per u: `v_cdf` at the end of every block of [`BLOCK`] rows.
    v_guide: Vec<f32>,
    /// Inclusive prefix sums along u of the u-slab totals.
    u_cdf: Vec<f32>,
    interpolation: Interpolation,
    uniform_fallback: bool,
}

/// Position of `x` in cells, and the two cells whose centres bracket it with the weight of the
/// second: (j0, j1, t).
fn bracket(x: f64, origin: f64, size: f64, n: usize) -> (usize, usize, f64) {
    let c = (x - origin) / size - 0.5;
    // floor without a libm call (baseline x86-64 has no rounding instruction): truncation is
    // floor for c ≥ 0, and c ≥ −0.5 inside the grid.
    let j = if c >= 0.0 { (c as i64) as f64 } else { -1.0 };
    let t = c - j;
    let j0 = (j.max(0.0) as usize).min(n - 1);
    let j1 = ((j + 1.0).max(0.0) as usize).min(n - 1);
    (j0, j1, if j0 == j1 { 0.0 } else { t })
}

fn cell_of(x: f64, origin: f64, size: f64, n: usize) -> usize {
    // `as usize` truncates (= floor for x ≥ origin) and saturates negatives and NaN to 0.
    (((x - origin) / size) as usize).min(n - 1)
}

impl CameraDistribution {
    /// Builds the CDFs (in place over the grid's values). An empty grid (no mass, or non-finite
    /// total) gives a uniform distribution over pixels and depths; [`Self::is_uniform_fallback`]
    /// says so.
    pub fn new(grid: CameraGrid, interpolation: Interpolation) -> CameraDistribution {
        let CameraGrid { camera, bounds, ru, rv, rl, mut values, .. } = grid;
        let total: f64 = values.iter().map(|v| *v as f64).sum();
        let uniform_fallback = !(total > 0.0 && total.is_finite()) || values.iter().any(|v| !v.is_finite() || *v < 0.0);
        if uniform_fallback {
            values.iter_mut().for_each(|v| *v = 1.0);
        }
        let blocks = rl.div_ceil(BLOCK);
        let mut lambda_guide = vec![0.0f32; ru * rv * blocks];
        let mut v_cdf = vec![0.0f32; ru * rv];
        let mut u_cdf = vec![0.0f32; ru];
        let mut u_acc = 0.0f64;
        for iu in 0..ru {
            let mut v_acc = 0.0f64;
            for iv in 0..rv {
                let column = iu * rv + iv;
                let q = &mut values[column * rl..(column + 1) * rl];
                // Most columns see no mass: their prefix sums and guide are already zero.
                if q.iter().all(|x| *x == 0.0) {
                    v_cdf[column] = v_acc as f32;
                    continue;
                }
                let mut acc = 0.0f64;
                for x in q.iter_mut() {
                    acc += *x as f64;
                    *x = acc as f32;
                }
                for b in 0..blocks {
                    lambda_guide[column * blocks + b] = q[((b + 1) * BLOCK).min(rl) - 1];
                }
                v_acc += acc;
                v_cdf[column] = v_acc as f32;
            }
            u_acc += v_acc;
            u_cdf[iu] = u_acc as f32;
        }
        let v_blocks = rv.div_ceil(BLOCK);
        let mut v_guide = vec![0.0f32; ru * v_blocks];
        for iu in 0..ru {
            for b in 0..v_blocks {
                v_guide[iu * v_blocks + b] = v_cdf[iu * rv + ((b + 1) * BLOCK).min(rv) - 1];
            }
        }
        CameraDistribution { camera, bounds, ru, rv, rl, lambda_cdf: values, lambda_guide, v_cdf, v_guide, u_cdf, interpolation, uniform_fallback }
    }

    /// The camera.
    pub fn camera(&self) -> &PinholeCamera {
        &self.camera
    }

    /// The bounds of its 3D image space.
    pub fn bounds(&self) -> &ImageSpaceBounds {
        &self.bounds
    }

    /// True when the grid held no mass and the distribution is uniform.
    pub fn is_uniform_fallback(&self) -> bool {
        self.uniform_fallback
    }

    /// The depth span of one λ bin: the resolution of every λ̃ drawn from this distribution.
    pub fn depth_bin(&self) -> f64 {
        self.sizes().2
    }

    fn sizes(&self) -> (f64, f64, f64) {
        let b = &self.bounds;
        ((b.u[1] - b.u[0]) / self.ru as f64, (b.v[1] - b.v[0]) / self.rv as f64, (b.depth[1] - b.depth[0]) / self.rl as f64)
    }

    /// A λ column's prefix sums and its guide.
    fn lambda_column(&self, iu: usize, iv: usize) -> (&[f32], &[f32]) {
        let column = iu * self.rv + iv;
        let blocks = self.rl.div_ceil(BLOCK);
        (&self.lambda_cdf[column * self.rl..(column + 1) * self.rl], &self.lambda_guide[column * blocks..(column + 1) * blocks])
    }

    fn u_mixture(&self) -> Mixture<'_> {
        Mixture::single(&self.u_cdf)
    }

    fn v_mixture(&self, pixel_u: f64) -> Mixture<'_> {
        let (du, _, _) = self.sizes();
        let blocks = self.rv.div_ceil(BLOCK);
        let col = |iu: usize| &self.v_cdf[iu * self.rv..(iu + 1) * self.rv];
        let guide = |iu: usize| &self.v_guide[iu * blocks..(iu + 1) * blocks];
        let (j0, j1, t) = match self.interpolation {
            Interpolation::Nearest => {
                let j = cell_of(pixel_u, self.bounds.u[0], du, self.ru);
                (j, j, 0.0)
            }
            Interpolation::Linear => bracket(pixel_u, self.bounds.u[0], du, self.ru),
        };
        let count = if j0 == j1 { 1 } else { 2 };
        Mixture { parts: [(col(j0), 1.0 - t), (col(j1), t), (&[], 0.0), (&[], 0.0)], count, guide: Some([guide(j0), guide(j1), &[], &[]]) }
    }

    fn lambda_mixture(&self, pixel: DVec2) -> Mixture<'_> {
        let (du, dv, _) = self.sizes();
        let (columns, weights): ([(usize, usize); 4], [f64; 4]) = match self.interpolation {
            Interpolation::Nearest => {
                let j = cell_of(pixel.x, self.bounds.u[0], du, self.ru);
                let k = cell_of(pixel.y, self.bounds.v[0], dv, self.rv);
                ([(j, k); 4], [1.0, 0.0, 0.0, 0.0])
            }
            Interpolation::Linear => {
                let (j0, j1, t) = bracket(pixel.x, self.bounds.u[0], du, self.ru);
                let (k0, k1, s) = bracket(pixel.y, self.bounds.v[0], dv, self.rv);
                ([(j0, k0), (j1, k0), (j0, k1), (j1, k1)], [(1.0 - t) * (1.0 - s), t * (1.0 - s), (1.0 - t) * s, t * s])
            }
        };
        let count = if self.interpolation == Interpolation::Nearest { 1 } else { 4 };
        let mut parts: [(&[f32], f64); 4] = [(&[], 0.0); 4];
        let mut guide: [&[f32]; 4] = [&[]; 4];
        for c in 0..count {
            let (cdf, g) = self.lambda_column(columns[c].0, columns[c].1);
            parts[c] = (cdf, weights[c]);
            guide[c] = g;
        }
        Mixture { parts, count, guide: Some(guide) }
    }

    /// Draws (ũ, ṽ, λ̃) from three uniform numbers.
    pub fn sample(&self, u: [f64; 3]) -> ImageSpaceSample {
        let (pixel, pdf_pixel) = self.sample_pixel([u[0], u[1]]);
        let (depth, pdf_depth) = self.sample_depth(pixel, u[2]).expect("the λ-mixture at a drawn (ũ, ṽ) has mass");
        ImageSpaceSample { pixel, depth, pdf_pixel, pdf_depth }
    }

    /// Draws (ũ, ṽ) from the pixel marginal with two uniform numbers: `(pixel, pdf per pixel²)`.
    pub fn sample_pixel(&self, u: [f64; 2]) -> (DVec2, f64) {
        let (du, dv, _) = self.sizes();
        let (ju, fu, pu) = self.u_mixture().sample(u[0]).expect("a distribution always has mass (uniform fallback)");
        let pixel_u = self.bounds.u[0] + (ju as f64 + fu) * du;
        let (kv, fv, pv) = self.v_mixture(pixel_u).sample(u[1]).expect("the v-mixture at a drawn ũ has mass");
        (DVec2::new(pixel_u, self.bounds.v[0] + (kv as f64 + fv) * dv), pu * pv / (du * dv))
    }

    /// Draws λ̃ for given pixel coordinates (uniform rays, evaluation) from one uniform number:
    /// `(λ̃, pdf per unit depth)`, or `None` when p̃(λ | u, v) has no mass there.
    pub fn sample_depth(&self, pixel: DVec2, u: f64) -> Option<(f64, f64)> {
        let (_, _, dl) = self.sizes();
        let (kl, fl, pl) = self.lambda_mixture(pixel).sample(u)?;
        Some((self.bounds.depth[0] + (kl as f64 + fl) * dl, pl / dl))
    }

    /// Density of pixel coordinates (per pixel²): 0 outside the grid.
    pub fn pdf_pixel(&self, pixel: DVec2) -> f64 {
        let b = &self.bounds;
        if !(pixel.x >= b.u[0] && pixel.x < b.u[1] && pixel.y >= b.v[0] && pixel.y < b.v[1]) {
            return 0.0;
        }
        let (du, dv, _) = self.sizes();
        let ju = cell_of(pixel.x, b.u[0], du, self.ru);
        let kv = cell_of(pixel.y, b.v[0], dv, self.rv);
        self.u_mixture().probability(ju) * self.v_mixture(pixel.x).probability(kv) / (du * dv)
    }

    /// Density of λ given pixel coordinates (per unit depth): 0 outside the depth range.
    pub fn pdf_depth(&self, pixel: DVec2, depth: f64) -> f64 {
        let b = &self.bounds;
        if !(depth >= b.depth[0] && depth < b.depth[1]) {
            return 0.0;
        }
        let (_, _, dl) = self.sizes();
        self.lambda_mixture(pixel).probability(cell_of(depth, b.depth[0], dl, self.rl)) / dl
    }

    /// Joint density (per pixel² per unit depth) of a point of the 3D image space.
    pub fn pdf(&self, pixel: DVec2, depth: f64) -> f64 {
        self.pdf_pixel(pixel) * self.pdf_depth(pixel, depth)
    }

    /// The uniform numbers that [`Self::sample`] maps to (ũ, ṽ, λ̃).
    pub fn invert(&self, pixel: DVec2, depth: f64) -> [f64; 3] {
        let b = &self.bounds;
        let (du, dv, dl) = self.sizes();
        let split = |x: f64, origin: f64, size: f64, n: usize| {
            let k = cell_of(x, origin, size, n);
            (k, ((x - origin) / size - k as f64).clamp(0.0, 1.0))
        };
        let (ju, fu) = split(pixel.x, b.u[0], du, self.ru);
        let (kv, fv) = split(pixel.y, b.v[0], dv, self.rv);
        let (kl, fl) = split(depth, b.depth[0], dl, self.rl);
        [self.u_mixture().invert(ju, fu), self.v_mixture(pixel.x).invert(kv, fv), self.lambda_mixture(pixel).invert(kl, fl)]
    }

    /// The pixel marginal as an R_u × R_v grid of probabilities, row-major in v (`[iv·ru + iu]`).
    pub fn pixel_marginal(&self) -> Vec<f64> {
        let total = *self.u_cdf.last().unwrap() as f64;
        let mut out = vec![0.0; self.ru * self.rv];
        for iu in 0..self.ru {
            for iv in 0..self.rv {
                let c = &self.v_cdf[iu * self.rv..(iu + 1) * self.rv];
                let mass = c[iv] as f64 - if iv == 0 { 0.0 } else { c[iv - 1] as f64 };
                out[iv * self.ru + iu] = mass / total;
            }
        }
        out
    }

    /// Grid resolution (R_u, R_v, R_λ).
    pub fn resolution(&self) -> (usize, usize, usize) {
        (self.ru, self.rv, self.rl)
    }
}
