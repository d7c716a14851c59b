//! Dense layers with activations, an optional skip connection, and NeuS's geometric initialisation.

use crate::module::{Activation, Module};
use crate::real::Real;
use rand::{SeedableRng, rngs::Xoshiro256PlusPlus};
use rand_distr::{Distribution, Normal};

/// Shape of a multi-layer perceptron.
#[derive(Debug, Clone, PartialEq)]
pub struct MlpConfig {
    /// Inputs per row.
    pub n_inputs: usize,
    /// Width of the hidden layers.
    pub width: usize,
    /// Number of hidden layers (the output layer comes after them).
    pub hidden_layers: usize,
    /// Outputs per row.
    pub n_outputs: usize,
    /// If `Some(k)`, hidden layer k (0-based, ≥ 1) takes `[h, x] / √2` (NeuS's skip at layer 4).
    pub skip: Option<usize>,
    /// Activation of the hidden layers.
    pub hidden_activation: Activation,
    /// Activation of the output layer.
    pub output_activation: Activation,
}

/// A multi-layer perceptron. Parameters per layer: weights (out × in, row-major), then biases.
#[derive(Debug, Clone)]
pub struct Mlp {
    config: MlpConfig,
    /// (n_in, n_out, parameter offset) per layer.
    layers: Vec<(usize, usize, usize)>,
    n_params: usize,
}

impl Mlp {
    /// Builds the layer table.
    pub fn new(config: MlpConfig) -> Mlp {
        assert!(config.skip.is_none_or(|k| k >= 1 && k <= config.hidden_layers), "skip layer must be a hidden layer ≥ 1");
        let mut layers = Vec::new();
        let mut offset = 0;
        let mut n_in = config.n_inputs;
        for l in 0..=config.hidden_layers {
            if config.skip == Some(l) {
                n_in += config.n_inputs;
            }
            let n_out = if l == config.hidden_layers { config.n_outputs } else { config.width };
            layers.push((n_in, n_out, offset));
            offset += n_in * n_out + n_out;
            n_in = n_out;
        }
        Mlp { config, layers, n_params: offset }
    }

    /// The configuration.
    pub fn config(&self) -> &MlpConfig {
        &self.config
    }

    /// Default initialisation: weights N(0, 2/fan_in) (He), zero biases.
    pub fn init_default(&self, params: &mut [f32], seed: u64) {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        for &(n_in, n_out, off) in &self.layers {
            let normal = Normal::new(0.0, (2.0 / n_in as f64).sqrt()).expect("finite std");
            for w in &mut params[off..off + n_in * n_out] {
                *w = normal.sample(&mut rng) as f32;
            }
            params[off + n_in * n_out..off + n_in * n_out + n_out].fill(0.0);
        }
    }

    /// NeuS's geometric initialisation (Atzmon & Lipman, SAL): the first output approximates the
    /// signed distance to a sphere of radius `radius`, `|x| − radius`. Only the first `raw`
    /// inputs (the raw coordinates, before any encoding) get weights in the first and the skip
    /// layer, so that the encoding's high frequencies start silent.
    pub fn init_geometric(&self, params: &mut [f32], radius: f64, raw: usize, seed: u64) {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let last = self.layers.len() - 1;
        for (l, &(n_in, n_out, off)) in self.layers.iter().enumerate() {
            let (w, b) = params[off..off + n_in * n_out + n_out].split_at_mut(n_in * n_out);
            if l == last {
                let normal = Normal::new(std::f64::consts::PI.sqrt() / (n_in as f64).sqrt(), 1e-4).expect("finite");
                for v in w.iter_mut() {
                    *v = normal.sample(&mut rng) as f32;
                }
                b.fill(0.0);
                b[0] = -radius as f32;
            } else {
                let normal = Normal::new(0.0, 2f64.sqrt() / (n_out as f64).sqrt()).expect("finite");
                let skip_part = if self.config.skip == Some(l) { n_in - self.config.n_inputs } else { usize::MAX };
                for o in 0..n_out {
                    for i in 0..n_in {
                        // Encoded inputs start at zero weight: in the first layer everything past
                        // `raw`; in the skip layer the re-injected input's encoded part.
                        let silent = (l == 0 && i >= raw) || (i >= skip_part && i - skip_part >= raw);
                        w[o * n_in + i] = if silent { 0.0 } else { normal.sample(&mut rng) as f32 };
                    }
                }
                b.fill(0.0);
            }
        }
    }

    /// Refits the output layer's first row (weights and bias) by ridge regression so that the
    /// first output matches `target` on `inputs` (rows of `n_inputs`): a cheap calibration after
    /// [`Self::init_geometric`], whose finite-width result is |x| − r only on average (measured
    /// ±0.2 at 8 × 256). The hidden layers stay random features; this solves for the readout.
    pub fn calibrate_first_output(&self, params: &mut [f32], inputs: &[f32], target: &[f32]) {
        let rows = target.len();
        let &(n_in, _, off) = self.layers.last().expect("an MLP has an output layer");
        // The last hidden activations (the output layer's inputs) from the context.
        let per_row = self.ctx_layout();
        let mut out = vec![0.0f32; rows * self.config.n_outputs];
        let mut ctx = vec![0.0f32; rows * per_row];
        Module::<f32>::forward(self, params, inputs, &mut out, &mut ctx);
        let a_start: usize = self.layers[..self.layers.len() - 1].iter().map(|(i, o, _)| i + o).sum();
        // The context is tiled by LANES rows: value k of row r sits at tile_base + k·w + lane.
        let value = |r: usize, k: usize| {
            let r0 = r / LANES * LANES;
            let w = LANES.min(rows - r0);
            ctx[r0 * per_row + k * w + (r - r0)]
        };
        // Normal equations for [w, b]: (AᵀA + λI) θ = Aᵀy, in f64.
        let m = n_in + 1;
        let mut ata = vec![0.0f64; m * m];
        let mut aty = vec![0.0f64; m];
        let mut a = vec![0.0f64; m];
        for r in 0..rows {
            for i in 0..n_in {
                a[i] = value(r, a_start + i) as f64;
            }
            a[n_in] = 1.0;
            for i in 0..m {
                aty[i] += a[i] * target[r] as f64;
                for j in 0..=i {
                    ata[i * m + j] += a[i] * a[j];
                }
            }
        }
        let ridge = 1e-6 * (0..m).map(|i| ata[i * m + i]).sum::<f64>() / m as f64;
        for i in 0..m {
            ata[i * m + i] += ridge;
            for j in 0..i {
                ata[j * m + i] = ata[i * m + j];
            }
        }
        let theta = cholesky_solve(&mut ata, &aty, m).expect("ridge regression is positive definite");
        let (w, b) = params[off..off + n_in * self.config.n_outputs + self.config.n_outputs].split_at_mut(n_in * self.config.n_outputs);
        for i in 0..n_in {
            w[i] = theta[i] as f32;
        }
        b[0] = theta[n_in] as f32;
    }

    /// Context values per row: each layer's input and pre-activation.
    fn ctx_layout(&self) -> usize {
        self.layers.iter().map(|(i, o, _)| i + o).sum()
    }
}

impl<R: Real> Module<R> for Mlp {
    fn n_params(&self) -> usize {
        self.n_params
    }
    fn n_inputs(&self) -> usize {
        self.config.n_inputs
    }
    fn n_outputs(&self) -> usize {
        self.config.n_outputs
    }
    fn ctx_per_row(&self) -> usize {
        self.ctx_layout()
    }

    fn forward(&self, params: &[R], input: &[R], output: &mut [R], ctx: &mut [R]) {
        let n_x = self.config.n_inputs;
        let n_y = self.config.n_outputs;
        let per_row = self.ctx_layout();
        let rows = input.len() / n_x;
        let inv_sqrt2 = R::of(std::f64::consts::FRAC_1_SQRT_2);
        let widest = self.layers.iter().map(|(i, o, _)| (*i).max(*o)).max().unwrap_or(0);
        let (mut a, mut z) = (vec![[R::ZERO; LANES]; widest], vec![[R::ZERO; LANES]; widest]);
        for r0 in (0..rows).step_by(LANES) {
            let w = LANES.min(rows - r0);
            // This tile's context: value k of lane j at k·w + j.
            let c = &mut ctx[r0 * per_row..(r0 + w) * per_row];
            let mut at = 0;
            for (l, &(n_in, n_out, off)) in self.layers.iter().enumerate() {
                // Layer input a_l (lanes past w stay zero).
                if l == 0 {
                    for k in 0..n_x {
                        a[k] = [R::ZERO; LANES];
                        for j in 0..w {
                            a[k][j] = input[(r0 + j) * n_x + k];
                        }
                    }
                } else {
                    let prev = self.layers[l - 1].1;
                    let act = self.config.hidden_activation;
                    for k in 0..prev {
                        for j in 0..w {
                            a[k][j] = act.apply(z[k][j]);
                        }
                    }
                    if self.config.skip == Some(l) {
                        for k in 0..prev {
                            for j in 0..w {
                                a[k][j] *= inv_sqrt2;
                            }
                        }
                        for k in 0..n_x {
                            for j in 0..w {
                                a[prev + k][j] = input[(r0 + j) * n_x + k] * inv_sqrt2;
                            }
                        }
                    }
                }
                for k in 0..n_in {
                    c[(at + k) * w..(at + k) * w + w].copy_from_slice(&a[k][..w]);
                }
                at += n_in;
                // z = W a + b, eight rows at a time (one vector lane per row).
                let (wt, b) = params[off..off + n_in * n_out + n_out].split_at(n_in * n_out);
                for o in 0..n_out {
                    let mut acc = [b[o]; LANES];
                    for (i, wv) in wt[o * n_in..(o + 1) * n_in].iter().enumerate() {
                        for j in 0..LANES {
                            acc[j] += *wv * a[i][j];
                        }
                    }
                    z[o] = acc;
                    c[(at + o) * w..(at + o) * w + w].copy_from_slice(&acc[..w]);
                }
                at += n_out;
            }
            for j in 0..w {
                for k in 0..n_y {
                    output[(r0 + j) * n_y + k] = self.config.output_activation.apply(z[k][j]);
                }
            }
        }
    }

    fn backward(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_params: &mut [R], mut d_input: Option<&mut [R]>) {
        let n_x = self.config.n_inputs;
        let n_y = self.config.n_outputs;
        let per_row = self.ctx_layout();
        let rows = input.len() / n_x;
        let last = self.layers.len() - 1;
        let inv_sqrt2 = R::of(std::f64::consts::FRAC_1_SQRT_2);
        let widest = self.layers.iter().map(|(i, o, _)| (*i).max(*o)).max().unwrap_or(0);
        let (mut dz, mut da) = (vec![[R::ZERO; LANES]; widest], vec![[R::ZERO; LANES]; widest]);
        let mut a = vec![[R::ZERO; LANES]; widest];
        // Offsets of a_l and z_l in a tile's context (in values per lane).
        let mut starts = Vec::with_capacity(self.layers.len());
        let mut at = 0;
        for &(n_in, n_out, _) in &self.layers {
            starts.push((at, at + n_in));
            at += n_in + n_out;
        }
        for r0 in (0..rows).step_by(LANES) {
            let w = LANES.min(rows - r0);
            let c = &ctx[r0 * per_row..(r0 + w) * per_row];
            let lane = |k: usize, j: usize| c[k * w + j];
            let (_, z_last) = starts[last];
            for k in 0..n_y {
                dz[k] = [R::ZERO; LANES];
                for j in 0..w {
                    dz[k][j] = d_output[(r0 + j) * n_y + k] * self.config.output_activation.derivative(lane(z_last + k, j));
                }
            }
            let mut dx = vec![[R::ZERO; LANES]; n_x];
            for l in (0..self.layers.len()).rev() {
                let (n_in, n_out, off) = self.layers[l];
                let (a_start, _) = starts[l];
                for i in 0..n_in {
                    a[i] = [R::ZERO; LANES];
                    for j in 0..w {
                        a[i][j] = lane(a_start + i, j);
                    }
                }
                let (dw, db) = d_params[off..off + n_in * n_out + n_out].split_at_mut(n_in * n_out);
                let wt = &params[off..off + n_in * n_out];
                for i in 0..n_in {
                    da[i] = [R::ZERO; LANES];
                }
                // (Accumulating dW per lane across tiles and summing once was measured slower:
                // the lane buffers leave L1. The horizontal sum per weight and tile stays.)
                for o in 0..n_out {
                    let g = dz[o];
                    db[o] += lanes_sum(&g);
                    let row_w = &wt[o * n_in..(o + 1) * n_in];
                    let row_dw = &mut dw[o * n_in..(o + 1) * n_in];
                    for i in 0..n_in {
                        let mut prod = [R::ZERO; LANES];
                        for j in 0..LANES {
                            prod[j] = g[j] * a[i][j];
                            da[i][j] += row_w[i] * g[j];
                        }
                        row_dw[i] += lanes_sum(&prod);
                    }
                }
                if l == 0 {
                    for k in 0..n_x {
                        for j in 0..LANES {
                            dx[k][j] += da[k][j];
                        }
                    }
                    break;
                }
                // Back through the skip concatenation and the previous activation.
                let prev_len = self.layers[l - 1].1;
                if self.config.skip == Some(l) {
                    for k in 0..n_x {
                        for j in 0..LANES {
                            dx[k][j] += da[prev_len + k][j] * inv_sqrt2;
                        }
                    }
                    for k in 0..prev_len {
                        for j in 0..LANES {
                            da[k][j] *= inv_sqrt2;
                        }
                    }
                }
                let (_, z_prev) = starts[l - 1];
                let act = self.config.hidden_activation;
                for k in 0..prev_len {
                    dz[k] = [R::ZERO; LANES];
                    for j in 0..w {
                        dz[k][j] = da[k][j] * act.derivative(lane(z_prev + k, j));
                    }
                }
            }
            if let Some(d_in) = d_input.as_deref_mut() {
                for j in 0..w {
                    for k in 0..n_x {
                        d_in[(r0 + j) * n_x + k] = dx[k][j];
                    }
                }
            }
        }
    }
}

/// Σ of the lanes, pairwise.
#[inline]
fn lanes_sum<R: Real>(v: &[R; LANES]) -> R {
    ((v[0] + v[1]) + (v[2] + v[3])) + ((v[4] + v[5]) + (v[6] + v[7]))
}

/// Rows processed together: one vector lane per row in the layer products.
const LANES: usize = 8;

/// Solves A x = b for a symmetric positive-definite A (row-major, overwritten by its Cholesky
/// factor). `None` if A is not positive definite.
fn cholesky_solve(a: &mut [f64], b: &[f64], n: usize) -> Option<Vec<f64>> {
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= a[j * n + k] * a[j * n + k];
        }
        if !(d > 0.0) {
            return None;
        }
        let d = d.sqrt();
        a[j * n + j] = d;
        for i in j + 1..n {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= a[i * n + k] * a[j * n + k];
            }
            a[i * n + j] = s / d;
        }
    }
    let mut y = b.to_vec();
    for i in 0..n {
        for k in 0..i {
            y[i] -= a[i * n + k] * y[k];
        }
        y[i] /= a[i * n + i];
    }
    for i in (0..n).rev() {
        for k in i + 1..n {
            y[i] -= a[k * n + i] * y[k];
        }
        y[i] /= a[i * n + i];
    }
    Some(y)
}

