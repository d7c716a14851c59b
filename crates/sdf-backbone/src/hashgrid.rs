//! Multi-resolution hash-grid encoding (Instant-NGP; Neuralangelo's SDF encoding).
//!
//! Level l has resolution `N_l = ⌊N_min · b^l⌋` with `b = exp((ln N_max − ln N_min)/(L − 1))`.
//! A point x ∈ [−1, 1]³ maps to `p = (x + 1)/2 · N_l`; its 8 surrounding vertices are looked up
//! in the level's table of T entries — directly when `(N_l + 1)³ ≤ T` (dense coarse levels),
//! otherwise by the spatial hash `(i · 1 ⊕ j · 2654435761 ⊕ k · 805459861) mod T` — and their
//! F-dimensional features trilinearly interpolated. Output: the L·F features, level-major.
//! Levels above `active_levels` output zeros (coarse-to-fine activation, Neuralangelo).

use crate::module::Module;
use crate::real::Real;

/// Hash-grid shape.
#[derive(Debug, Clone, PartialEq)]
pub struct HashGridConfig {
    /// Number of levels L (Neuralangelo: 16).
    pub levels: usize,
    /// Features per level F (2).
    pub features: usize,
    /// log₂ of the table size T (Neuralangelo: 22; a CPU preset uses fewer).
    pub log2_table: u32,
    /// Coarsest resolution N_min (16).
    pub base_resolution: u32,
    /// Finest resolution N_max (2048).
    pub finest_resolution: u32,
}

impl HashGridConfig {
    /// The CPU-sized Neuralangelo-style grid: 8 levels × 2 features, 2¹⁶ entries, 16 → 256.
    pub fn neuralangelo_cpu() -> HashGridConfig {
        HashGridConfig { levels: 8, features: 2, log2_table: 16, base_resolution: 16, finest_resolution: 256 }
    }
}

/// The encoding. Parameters: L tables of T × F features.
#[derive(Debug, Clone)]
pub struct HashGrid {
    config: HashGridConfig,
    resolutions: Vec<u32>,
    dense: Vec<bool>,
    table: usize,
    /// Levels that output features; the rest output zeros and get no gradient.
    pub active_levels: usize,
}

impl HashGrid {
    /// Builds the level table (all levels active).
    pub fn new(config: HashGridConfig) -> HashGrid {
        assert!(config.levels >= 1 && config.features >= 1 && config.log2_table <= 30, "invalid hash grid");
        let table = 1usize << config.log2_table;
        let (lo, hi) = (config.base_resolution.max(1) as f64, config.finest_resolution.max(1) as f64);
        let growth = if config.levels > 1 { ((hi.ln() - lo.ln()) / (config.levels - 1) as f64).exp() } else { 1.0 };
        // (+1e-9: N_min · b^{L−1} must give N_max exactly despite rounding.)
        let resolutions: Vec<u32> = (0..config.levels).map(|l| (lo * growth.powi(l as i32) + 1e-9).floor().max(1.0) as u32).collect();
        let dense = resolutions.iter().map(|&n| ((n as u64 + 1).pow(3)) <= table as u64).collect();
        let levels = config.levels;
        HashGrid { config, resolutions, dense, table, active_levels: levels }
    }

    /// Resolution of each level.
    pub fn resolutions(&self) -> &[u32] {
        &self.resolutions
    }

    /// Uniform initialisation in ±`scale` (Instant-NGP: 1e-4), deterministic for a seed.
    pub fn init(&self, params: &mut [f32], scale: f32, seed: u64) {
        use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        for p in params.iter_mut() {
            *p = (rng.random::<f32>() * 2.0 - 1.0) * scale;
        }
    }

    #[inline]
    fn vertex_index(&self, level: usize, v: [u32; 3]) -> usize {
        let n = self.resolutions[level] as usize + 1;
        if self.dense[level] {
            v[0] as usize + n * (v[1] as usize + n * v[2] as usize)
        } else {
            ((v[0].wrapping_mul(1) ^ v[1].wrapping_mul(2_654_435_761) ^ v[2].wrapping_mul(805_459_861)) as usize) & (self.table - 1)
        }
    }

    /// For one point and level: the 8 vertex table indices, their trilinear weights and the
    /// weights' derivatives with respect to x (chain rule through p = (x + 1)/2 · N).
    #[inline]
    fn corners<R: Real>(&self, level: usize, x: &[R]) -> ([usize; 8], [R; 8], [[R; 3]; 8]) {
        let n = self.resolutions[level];
        let scale = R::of(n as f64 * 0.5);
        let mut cell = [0u32; 3];
        let mut frac = [R::ZERO; 3];
        // Inputs outside [−1, 1] are clamped to the grid; there the gradient in x is zero.
        let mut slope = [scale; 3];
        for d in 0..3 {
            let raw = (x[d] + R::ONE) * scale;
            let p = raw.max(R::ZERO).min(R::of(n as f64));
            if p != raw {
                slope[d] = R::ZERO;
            }
            // The last cell is closed: p = N is its far face (frac = 1), never a cell N (whose
            // corners N + 1 would read another row of a dense table).
            let c = p.to_f64().floor().min(f64::from(n) - 1.0);
            cell[d] = c as u32;
            frac[d] = p - R::of(c);
        }
        let mut idx = [0usize; 8];
        let mut w = [R::ZERO; 8];
        let mut dw = [[R::ZERO; 3]; 8];
        for c in 0..8 {
            let bit = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
            idx[c] = self.vertex_index(level, [cell[0] + bit[0] as u32, cell[1] + bit[1] as u32, cell[2] + bit[2] as u32]);
            let f = [0, 1, 2].map(|d| if bit[d] == 1 { frac[d] } else { R::ONE - frac[d] });
            let s = [0, 1, 2].map(|d| if bit[d] == 1 { slope[d] } else { -slope[d] });
            w[c] = f[0] * f[1] * f[2];
            dw[c] = [s[0] * f[1] * f[2], f[0] * s[1] * f[2], f[0] * f[1] * s[2]];
        }
        (idx, w, dw)
    }
}

impl<R: Real> Module<R> for HashGrid {
    fn n_params(&self) -> usize {
        self.config.levels * self.table * self.config.features
    }
    fn n_inputs(&self) -> usize {
        3
    }
    fn n_outputs(&self) -> usize {
        self.config.levels * self.config.features
    }
    fn ctx_per_row(&self) -> usize {
        0
    }
    fn forward(&self, params: &[R], input: &[R], output: &mut [R], _: &mut [R]) {
        let f = self.config.features;
        let n_out = self.config.levels * f;
        for (x, y) in input.chunks_exact(3).zip(output.chunks_exact_mut(n_out)) {
            y.fill(R::ZERO);
            for level in 0..self.active_levels.min(self.config.levels) {
                let (idx, w, _) = self.corners(level, x);
                let base = level * self.table * f;
                for c in 0..8 {
                    let feature = &params[base + idx[c] * f..base + idx[c] * f + f];
                    for k in 0..f {
                        y[level * f + k] += w[c] * feature[k];
                    }
                }
            }
        }
    }
    fn backward(&self, params: &[R], input: &[R], _: &[R], d_output: &[R], d_params: &mut [R], mut d_input: Option<&mut [R]>) {
        let f = self.config.features;
        let n_out = self.config.levels * f;
        for (row, (x, dy)) in input.chunks_exact(3).zip(d_output.chunks_exact(n_out)).enumerate() {
            let mut dx = [R::ZERO; 3];
            for level in 0..self.active_levels.min(self.config.levels) {
                let (idx, w, dw) = self.corners(level, x);
                let base = level * self.table * f;
                for c in 0..8 {
                    let at = base + idx[c] * f;
                    let mut g = R::ZERO;
                    for k in 0..f {
                        d_params[at + k] += w[c] * dy[level * f + k];
                        g += params[at + k] * dy[level * f + k];
                    }
                    for d in 0..3 {
                        dx[d] += g * dw[c][d];
                    }
                }
            }
            if let Some(d_in) = d_input.as_deref_mut() {
                d_in[3 * row..3 * row + 3].copy_from_slice(&dx);
            }
        }
    }
}
