//! A learned background for captures without masks: NeRF++'s inverted-sphere model of
//! everything outside the unit sphere (the scene bound), so that a *near* background (DTU's
//! table and walls, a room) has parallax and is not pushed into the bound as geometry.
//!
//! A point at distance r > 1 from the origin is represented by `(x/r, 1/r)` ∈ the unit 4-ball's
//! shell × (0, 1]: bounded whatever r. Along each ray, `samples` points beyond the bound are
//! placed at inverse distances `1/r_k = (1 − (k + ½)/K) / near` (increasing t; `near` = 1 is
//! NeRF++, [`BackgroundModel::near`]), the
//! network maps `[PE_L(x/r, 1/r)]` (and `SH₄(d)` when view-dependent) to a density σ (softplus) and a colour (sigmoid),
//! and the ray's background is rendered by standard volume rendering, the last sample taking
//! all the transmittance left (the background is opaque at infinity):
//! `w_k = T_k (1 − e^{−σ_k δ_k})`, `T_k = Π_{j<k} e^{−σ_j δ_j}`, `C_bg = Σ w_k c_k`.
//! The pipeline composites `C = C_fg + (1 − O_fg) C_bg`.
//!
//! With a hash grid (`grid`, instant-nsr-pl's remedy), the network also reads the features of a
//! multiresolution hash grid at the contracted point `(x/r)(2 − 1/r)/2` (the shell between radii
//! ½ and 1 of the grid's cube; infinity on its outer sphere): a backdrop's sharp edges are then
//! learnt as fast as the object's network learns them, instead of by an MLP's slow high
//! frequencies. Parameters: the network's, then the grid's tables ([`BackgroundModel::tables`]).
//!
//! The backward pass is exact (checked against finite differences in f64 with the pipeline):
//! `∂C/∂c_k = w_k`, `∂C/∂σ_m = δ_m (T_{m+1} c_m − Σ_{k>m} w_k c_k)`.

use crate::hashgrid::{HashGrid, HashGridConfig};
use crate::mlp::{Mlp, MlpConfig};
use crate::module::{Activation, Module};
use crate::real::Real;
use crate::scratch::Buf;
use rows::{Layout, SampleRows};

mod render;
mod rows;

pub use render::RENDER_BLOCK;

/// The background model: its network and how it samples.
#[derive(Debug, Clone)]
pub struct BackgroundModel {
    /// `[PE_L(x/r, 1/r) (4 + 8L), the grid's features (with a grid), SH₄(d) (16, when
    /// view-dependent)]` → `[σ_raw, rgb_raw]`.
    pub net: Mlp,
    /// Samples per ray beyond the bound.
    pub samples: usize,
    /// Frequencies L of the positional encoding of (x/r, 1/r).
    pub frequencies: usize,
    /// Whether the colour depends on the view direction (SH₄(d) among the inputs).
    pub view_dependent: bool,
    /// The radius (in bound radii, ≥ 1) from which the background holds anything: samples at
    /// `1/r_k = (1 − (k + ½)/K) / near`. NeRF++: 1. Further out, the background cannot paint
    /// the object on a shell just behind it, whose parallax is close to the object's own.
    pub near: f64,
    /// A hash grid over the contracted background whose features the network also reads.
    pub grid: Option<HashGrid>,
}

/// What the forward pass keeps for the backward pass.
pub struct BackgroundPass<R: Real> {
    /// Network inputs (rows = rays × samples).
    input: Buf<R>,
    /// Network context.
    ctx: Buf<R>,
    /// The grid's inputs (rows × 3; empty without a grid).
    points: Buf<R>,
    /// Raw outputs (rows × 4).
    raw: Buf<R>,
    /// Per row: σ, dσ/draw, c (3), dc/draw (3), δ, w.
    rows: Vec<[R; 10]>,
    /// Per ray: the background colour.
    pub colors: Vec<[R; 3]>,
}

impl BackgroundModel {
    /// The most frequencies a background's encoding has (2¹⁵ · 1/r: finer than f32 resolves).
    pub const MAX_FREQUENCIES: usize = 16;

    /// A model with `samples` samples per ray, `frequencies` frequencies, an MLP of `layers` ×
    /// `width` (ReLU).
    ///
    /// # Panics
    /// With more than [`Self::MAX_FREQUENCIES`] frequencies.
    pub fn new(samples: usize, frequencies: usize, width: usize, layers: usize) -> BackgroundModel {
        BackgroundModel::with_view(samples, frequencies, width, layers, true)
    }

    /// [`Self::new`], with the view direction among the inputs or not (`view_dependent`).
    ///
    /// # Panics
    /// With more than [`Self::MAX_FREQUENCIES`] frequencies.
    pub fn with_view(samples: usize, frequencies: usize, width: usize, layers: usize, view_dependent: bool) -> BackgroundModel {
        assert!(frequencies <= Self::MAX_FREQUENCIES, "a background of {frequencies} frequencies: at most {}", Self::MAX_FREQUENCIES);
        let net = Mlp::new(MlpConfig {
            n_inputs: Layout::Whole.encoding_width(frequencies) + if view_dependent { 16 } else { 0 },
            width,
            hidden_layers: layers,
            n_outputs: 4,
            skip: None,
            hidden_activation: Activation::Relu,
            output_activation: Activation::Identity,
        });
        BackgroundModel { net, samples, frequencies, view_dependent, near: 1.0, grid: None }
    }

    /// This model with the features of a hash grid `config` among its network's inputs (the
    /// network's shape otherwise kept; initialise the parameters again).
    pub fn with_grid(self, config: HashGridConfig) -> BackgroundModel {
        assert!(self.grid.is_none(), "with_grid: the model has a grid already");
        let grid = HashGrid::new(config);
        let n_inputs = self.net.config().n_inputs + Module::<f32>::n_outputs(&grid);
        BackgroundModel { net: Mlp::new(MlpConfig { n_inputs, ..self.net.config().clone() }), grid: Some(grid), ..self }
    }

    /// The grid the trainer gives a background with one: 8 levels × 2 features from 16 to 512
    /// cells across the grid's cube (a cell of ≈ 0.2° at infinity), 2¹⁵ entries per level.
    pub fn cpu_grid() -> HashGridConfig {
        HashGridConfig { levels: 8, features: 2, log2_table: 15, base_resolution: 16, finest_resolution: 512 }
    }

    /// The model a run learns without masks (16 samples per ray, MLP 2 × 64) with `frequencies`
    /// frequencies, its colour depending on the view direction or not (`view_dependent`).
    pub fn cpu(frequencies: usize, view_dependent: bool) -> BackgroundModel {
        BackgroundModel::with_view(16, frequencies, 64, 2, view_dependent)
    }

    /// Parameters: the network's, then the grid's.
    pub fn n_params(&self) -> usize {
        Module::<f32>::n_params(&self.net) + self.grid.as_ref().map_or(0, Module::<f32>::n_params)
    }

    /// Where the grid's tables lie among the model's parameters (empty without a grid): they
    /// learn at the tables' rate.
    pub fn tables(&self) -> std::ops::Range<usize> {
        Module::<f32>::n_params(&self.net)..self.n_params()
    }

    /// Default initialisation (He; the grid's tables in ±10⁻⁴, Instant-NGP's), deterministic in
    /// `seed`.
    pub fn init(&self, params: &mut [f32], seed: u64) {
        let (net, tables) = params.split_at_mut(self.tables().start);
        self.net.init_default(net, seed);
        if let Some(grid) = &self.grid {
            grid.init(tables, 1e-4, seed ^ 0x9E37_79B9_7F4A_7C15);
        }
    }

    /// Sample k's 1/r: `(1 − (k + ½)/K) / near`, the same on every ray.
    fn inverse_radius<R: Real>(&self, k: usize) -> R {
        R::of((1.0 - (k as f64 + 0.5) / self.samples as f64) * (1.0 / self.near))
    }

    /// Sample k's 1/r and depth along the ray from `o` in unit direction `d`: `1/r = (1 − (k +
    /// ½)/K) / near` (increasing t), the far root of `|o + t d| = r` (points beyond the bound, in
    /// front).
    fn sample_depth<R: Real>(&self, o: [R; 3], d: [R; 3], k: usize) -> (R, R) {
        let inv_r = self.inverse_radius(k);
        let radius = R::ONE / inv_r;
        let od = o[0] * d[0] + o[1] * d[1] + o[2] * d[2];
        let oo = o[0] * o[0] + o[1] * o[1] + o[2] * o[2];
        let disc = (od * od - oo + radius * radius).max(R::ZERO);
        (inv_r, -od + disc.sqrt())
    }

    /// The background colour of each ray (`origins`, unit `directions`, `sh` = SH₄ of each
    /// direction), with what the backward pass needs.
    pub fn forward<R: Real>(&self, params: &[R], origins: &[[R; 3]], directions: &[[R; 3]], sh: &[[R; 16]]) -> BackgroundPass<R> {
        let _span = crate::profile::span(crate::profile::Stage::Background);
        let (k_n, rays) = (self.samples, origins.len());
        let rows_n = rays * k_n;
        let (p_net, p_grid) = params.split_at(self.tables().start);
        let inv_r_sines = self.inverse_radius_sines::<R>();
        let of_rays = (origins, directions, sh);
        let SampleRows { input, points, depths } = self.sample_rows(Layout::Whole, p_grid, of_rays, &inv_r_sines, rows_n, |i| (i / k_n, i % k_n));
        let mut raw = Buf::<R>::to_overwrite(rows_n * 4);
        let mut ctx = Buf::<R>::to_overwrite(rows_n * Module::<R>::ctx_per_row(&self.net));
        self.net.forward(p_net, &input, &mut raw, &mut ctx);
        let mut rows = vec![[R::ZERO; 10]; rows_n];
        let mut colors = vec![[R::ZERO; 3]; rays];
        // Compiled for the CPU's instruction set (the softplus's multiply-adds one instruction
        // each, not a call: the same bits).
        crate::kernels::dispatch(
            #[inline(always)]
            || {
                for r in 0..rays {
                    let mut transmittance = R::ONE;
                    for k in 0..k_n {
                        let i = r * k_n + k;
                        let delta = if k + 1 == k_n { None } else { Some(depths[i + 1] - depths[i]) };
                        let Sample { sigma, d_sigma, c, alpha } = Sample::of(&raw[4 * i..4 * i + 4], delta);
                        let w = transmittance * alpha;
                        for j in 0..3 {
                            colors[r][j] += w * c[j];
                        }
                        let slope = c.map(|c| c * (R::ONE - c));
                        rows[i] = [sigma, d_sigma, c[0], c[1], c[2], slope[0], slope[1], slope[2], delta.unwrap_or(R::ZERO), w];
                        transmittance *= R::ONE - alpha;
                    }
                }
            },
        );
        BackgroundPass { input, ctx, points, raw, rows, colors }
    }

    /// Adds the gradient of the loss into `d_params` from `d_colors` (∂L/∂C_bg per ray).
    pub fn backward<R: Real>(&self, params: &[R], pass: &BackgroundPass<R>, d_colors: &[[R; 3]], d_params: &mut [R]) {
        let split = self.tables().start;
        let (d_net, d_grid) = d_params.split_at_mut(split);
        if let (Some(grid), Some((points, d_features))) = (&self.grid, self.backward_deferring(params, pass, d_colors, d_net)) {
            grid.backward(&params[split..], &points, &[], &d_features, d_grid, None);
        }
    }

    /// [`Self::backward`] into the network's parameters alone (`d_net`, the parameters before
    /// [`Self::tables`]); with a grid, the record of its tables' gradient comes back — the grid's
    /// points and their features' adjoints — for [`Self::add_deferred`].
    pub fn backward_deferring<R: Real>(
        &self,
        params: &[R],
        pass: &BackgroundPass<R>,
        d_colors: &[[R; 3]],
        d_net: &mut [R],
    ) -> Option<(Buf<R>, Buf<R>)> {
        let k_n = self.samples;
        let mut d_raw = Buf::<R>::zeroed(pass.raw.len());
        for (r, dc) in d_colors.iter().enumerate() {
            // From the back: Σ_{k>m} w_k (∂L/∂C · c_k) and Σ_{k>m} w_k = T_{m+1} (the last sample
            // takes all the transmittance left, so the weights behind sum to it).
            let (mut behind, mut behind_w) = (R::ZERO, R::ZERO);
            for k in (0..k_n).rev() {
                let i = r * k_n + k;
                let [_, d_sigma, c0, c1, c2, g0, g1, g2, delta, w] = pass.rows[i];
                let dc_dot_c = dc[0] * c0 + dc[1] * c1 + dc[2] * c2;
                let d_sigma_k = delta * (behind_w * dc_dot_c - behind);
                d_raw[4 * i] = d_sigma_k * d_sigma;
                d_raw[4 * i + 1] = w * dc[0] * g0;
                d_raw[4 * i + 2] = w * dc[1] * g1;
                d_raw[4 * i + 3] = w * dc[2] * g2;
                behind += w * dc_dot_c;
                behind_w += w;
            }
        }
        let p_net = &params[..self.tables().start];
        if self.grid.is_none() {
            self.net.backward(p_net, &pass.input, &pass.ctx, &d_raw, d_net, None);
            return None;
        }
        let (n_in, columns) = (Module::<R>::n_inputs(&self.net), self.grid_columns(Layout::Whole));
        let mut d_input = Buf::<R>::zeroed(pass.input.len());
        self.net.backward(p_net, &pass.input, &pass.ctx, &d_raw, d_net, Some(&mut d_input));
        let mut d_features = Buf::<R>::to_overwrite(d_input.len() / n_in * columns.len());
        for (d, row) in d_features.chunks_exact_mut(columns.len()).zip(d_input.chunks_exact(n_in)) {
            d.copy_from_slice(&row[columns.clone()]);
        }
        let mut points = Buf::<R>::to_overwrite(pass.points.len());
        points.copy_from_slice(&pass.points);
        Some((points, d_features))
    }

    /// Adds the gradient of the grid's tables from the records of several work items
    /// ([`Self::backward_deferring`], in order) to `d_tables` (the gradient of [`Self::tables`]),
    /// bit for bit as a dense buffer per work item summed in that order
    /// ([`HashGrid::add_level_gradient`]), in parallel over the levels. Without a grid, nothing.
    pub fn add_deferred<R: Real>(&self, records: &[(Buf<R>, Buf<R>)], d_tables: &mut [R]) {
        use rayon::prelude::*;
        let Some(grid) = &self.grid else { return };
        let levels = (0..grid.config().levels).map(|l| grid.level_params(l));
        crate::module::split_blocks(d_tables, levels).into_par_iter().enumerate().for_each(|(level, d_level)| {
            let mut scratch = Buf::<R>::zeroed(d_level.len());
            for (points, d_features) in records {
                grid.add_level_gradient(level, points, d_features, 0, &mut scratch, d_level);
            }
        });
    }
}

/// A sample's density σ (softplus of the first raw output) with dσ/draw, its colour (sigmoid of
/// the other three) and its opacity α over the interval `delta` to the next sample (`None`: the
/// last sample, which takes all the transmittance left).
struct Sample<R> {
    sigma: R,
    d_sigma: R,
    c: [R; 3],
    alpha: R,
}

impl<R: Real> Sample<R> {
    #[inline(always)]
    fn of(raw: &[R], delta: Option<R>) -> Sample<R> {
        let (sigma, d_sigma) = raw[0].softplus_with_derivative(R::ONE);
        let c = [1, 2, 3].map(|j| crate::module::sigmoid(raw[j]));
        let alpha = delta.map_or(R::ONE, |delta| R::ONE - (-sigma * delta).exp());
        Sample { sigma, d_sigma, c, alpha }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng, rngs::StdRng};

    /// A small model (`samples` a ray, a grid or not, 3 frequencies and the view among the
    /// inputs, or `plain`: no frequency and no view) with its parameters, the density output's
    /// bias raised by `opaque`, and `n` rays from inside the bound with their SH inputs.
    #[allow(clippy::type_complexity)]
    fn model_and_rays(
        (samples, grid, plain): (usize, bool, bool),
        opaque: f32,
        n: usize,
    ) -> (BackgroundModel, Vec<f32>, Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<[f32; 16]>) {
        let (frequencies, view) = if plain { (0, false) } else { (3, true) };
        let mut model = BackgroundModel::with_view(samples, frequencies, 16, 2, view);
        if grid {
            model = model.with_grid(HashGridConfig { levels: 2, features: 2, log2_table: 8, base_resolution: 4, finest_resolution: 16 });
        }
        let mut params = vec![0.0f32; model.n_params()];
        model.init(&mut params, 7);
        params[model.tables().start - 4] += opaque;
        let mut rng = StdRng::seed_from_u64(3);
        let unit = |rng: &mut StdRng| {
            let v: [f32; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
            v.map(|x| x / norm)
        };
        let origins = (0..n).map(|_| unit(&mut rng).map(|x| 0.5 * x)).collect();
        let directions = (0..n).map(|_| unit(&mut rng)).collect();
        let sh = (0..n).map(|_| std::array::from_fn(|_| rng.random_range(-1.0..1.0))).collect();
        (model, params, origins, directions, sh)
    }

    /// With no budget a render evaluates every sample and gives the forward pass's colours, to
    /// the rounding of its encoding's sines (the series, against training's libm).
    #[test]
    fn a_background_render_with_no_budget_is_the_forward_pass() {
        // 18 samples: the last block shorter than `RENDER_BLOCK`; no frequency and no view: no
        // column but 1/r folded, and none of SH₄(d).
        for (samples, grid, plain) in [(16, false, false), (16, true, false), (18, true, false), (16, false, true)] {
            let (model, params, origins, directions, sh) = model_and_rays((samples, grid, plain), 0.0, 37);
            let expected = model.forward(&params, &origins, &directions, &sh).colors;
            let (colors, evaluated) = model.render(&params, &origins, &directions, &sh, &[0.0; 37]);
            assert_eq!(evaluated, 37 * samples, "{samples} samples, grid {grid}: every sample evaluated");
            for (c, e) in colors.iter().zip(&expected) {
                for j in 0..3 {
                    assert!((c[j] - e[j]).abs() <= 1e-6, "{samples} samples, grid {grid}: {c:?} against {e:?}");
                }
            }
        }
    }

    /// Each ray stops after the first block past which its transmittance (one minus the forward
    /// pass's weights so far) is within its budget — the samples evaluated counted exactly — and
    /// drops at most its budget of colour (f64; f32's render below).
    #[test]
    fn a_background_render_stops_each_ray_after_the_block_where_its_budget_is_reached() {
        for grid in [false, true] {
            let (model, params, origins, directions, sh) = model_and_rays((16, grid, false), 4.0, 40);
            let to_f64 = |v: &[[f32; 3]]| v.iter().map(|c| c.map(f64::from)).collect::<Vec<_>>();
            let params: Vec<f64> = params.iter().map(|&p| f64::from(p)).collect();
            let (origins, directions) = (to_f64(&origins), to_f64(&directions));
            let sh: Vec<[f64; 16]> = sh.iter().map(|s| s.map(f64::from)).collect();
            let budgets: Vec<f64> = (0..40).map(|r| [1e-4, 1e-3, 1e-2, 0.1, 0.5][r % 5]).collect();
            let pass = model.forward(&params, &origins, &directions, &sh);
            let (colors, evaluated) = model.render(&params, &origins, &directions, &sh, &budgets);
            let mut expected = 0;
            let mut stops = std::collections::BTreeSet::new();
            for (r, budget) in budgets.iter().enumerate() {
                let weights = pass.rows[r * 16..(r + 1) * 16].iter().map(|row| row[9]);
                let left: Vec<f64> = weights.scan(1.0, |t, w| Some(*t - w).inspect(|v| *t = *v)).collect();
                let blocks = (1..=16 / RENDER_BLOCK).find(|b| left[b * RENDER_BLOCK - 1] <= *budget).unwrap_or(16 / RENDER_BLOCK);
                expected += blocks * RENDER_BLOCK;
                stops.insert(blocks);
                for j in 0..3 {
                    // The dropped tail is a sum of non-negative weights times colours in (0, 1).
                    let dropped = pass.colors[r][j] - colors[r][j];
                    assert!((-1e-12..=*budget).contains(&dropped), "grid {grid}, ray {r}, channel {j}: {dropped:e} dropped, budget {budget}");
                }
            }
            assert_eq!(evaluated, expected, "grid {grid}: the samples evaluated");
            assert!(stops.len() >= 3, "grid {grid}: the rays stop after blocks {stops:?}: the budgets do not test stopping");
        }
    }

    /// A render in f32 (its compositing by polynomials) with budgets drops at most its budget of
    /// colour on each ray, to f32's rounding, and stops some rays early.
    #[test]
    fn an_f32_background_render_drops_at_most_each_rays_budget() {
        let (model, params, origins, directions, sh) = model_and_rays((16, false, false), 4.0, 40);
        let budgets: Vec<f32> = (0..40).map(|r| [1e-4, 1e-3, 1e-2, 0.1, 0.5][r % 5]).collect();
        let expected = model.forward(&params, &origins, &directions, &sh).colors;
        let (colors, evaluated) = model.render(&params, &origins, &directions, &sh, &budgets);
        assert!(evaluated < 40 * 16, "{evaluated} samples evaluated: no ray stopped early");
        for (r, budget) in budgets.iter().enumerate() {
            for j in 0..3 {
                let dropped = expected[r][j] - colors[r][j];
                assert!((-1e-6..=budget + 1e-6).contains(&dropped), "ray {r}, channel {j}: {dropped:e} dropped, budget {budget}");
            }
        }
    }
}
