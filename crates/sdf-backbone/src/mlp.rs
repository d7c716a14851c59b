//! Dense layers with activations, an optional skip connection, and NeuS's geometric initialisation.

use crate::module::{Activation, Module};
use crate::real::Real;
use ndarray::linalg::general_mat_mul;
use ndarray::{ArrayView2, ArrayViewMut2};
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
        // The context is layer-major: the output layer's input A is a rows × n_in block.
        let a_start = rows * self.layers[..self.layers.len() - 1].iter().map(|(i, o, _)| i + o).sum::<usize>();
        let value = |r: usize, k: usize| ctx[a_start + r * n_in + k];
        // Normal equations for [w, b]: (AᵀA + λI) θ = Aᵀy, in f64.
        let m = n_in + 1;
        let mut ata = vec![0.0f64; m * m];
        let mut aty = vec![0.0f64; m];
        let mut a = vec![0.0f64; m];
        for r in 0..rows {
            for i in 0..n_in {
                a[i] = value(r, i) as f64;
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

    /// Context values per row: each layer's input and activation slope. Layout: layer-major, for
    /// each layer a rows × n_in block (its input A) then a rows × n_out block that holds
    /// Z = A Wᵀ + b during the forward pass and act'(Z) after it (for the backward pass).
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
        let rows = input.len() / n_x;
        if rows == 0 {
            return;
        }
        let inv_sqrt2 = R::of(std::f64::consts::FRAC_1_SQRT_2);
        let mut at = 0;
        for (l, &(n_in, n_out, off)) in self.layers.iter().enumerate() {
            let (done, rest) = ctx.split_at_mut(at);
            let (a, rest) = rest.split_at_mut(rows * n_in);
            let z = &mut rest[..rows * n_out];
            // The layer's input A.
            if l == 0 {
                a.copy_from_slice(input);
            } else {
                // A from the previous Z; the previous Z's slot then keeps act'(Z) for backward.
                let prev_out = self.layers[l - 1].1;
                let start = done.len() - rows * prev_out;
                let z_prev = &mut done[start..];
                let act = self.config.hidden_activation;
                if self.config.skip == Some(l) {
                    for r in 0..rows {
                        for k in 0..prev_out {
                            let (y, d) = act.apply_with_derivative(z_prev[r * prev_out + k]);
                            a[r * n_in + k] = y * inv_sqrt2;
                            z_prev[r * prev_out + k] = d;
                        }
                        for k in 0..n_x {
                            a[r * n_in + prev_out + k] = input[r * n_x + k] * inv_sqrt2;
                        }
                    }
                } else {
                    for (ai, zi) in a.iter_mut().zip(z_prev.iter_mut()) {
                        let (y, d) = act.apply_with_derivative(*zi);
                        *ai = y;
                        *zi = d;
                    }
                }
            }
            // Z = A Wᵀ + b: one matrix product per layer for the whole batch.
            let (wt, bias) = params[off..off + n_in * n_out + n_out].split_at(n_in * n_out);
            for row in z.chunks_exact_mut(n_out) {
                row.copy_from_slice(bias);
            }
            let av = ArrayView2::from_shape((rows, n_in), &*a).expect("A shape");
            let wv = ArrayView2::from_shape((n_out, n_in), wt).expect("W shape");
            let mut zv = ArrayViewMut2::from_shape((rows, n_out), z).expect("Z shape");
            general_mat_mul(R::ONE, &av, &wv.t(), R::ONE, &mut zv);
            at += rows * (n_in + n_out);
        }
        let z_last = &mut ctx[at - rows * n_y..at];
        let act = self.config.output_activation;
        for (o, z) in output.iter_mut().zip(z_last.iter_mut()) {
            let (y, d) = act.apply_with_derivative(*z);
            *o = y;
            *z = d;
        }
    }

    fn backward(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_params: &mut [R], d_input: Option<&mut [R]>) {
        let n_x = self.config.n_inputs;
        let n_y = self.config.n_outputs;
        let rows = input.len() / n_x;
        if rows == 0 {
            return;
        }
        let inv_sqrt2 = R::of(std::f64::consts::FRAC_1_SQRT_2);
        // Block offsets of each layer's A and Z in the context.
        let mut starts = Vec::with_capacity(self.layers.len());
        let mut at = 0;
        for &(n_in, n_out, _) in &self.layers {
            starts.push((at, at + rows * n_in));
            at += rows * (n_in + n_out);
        }
        let last = self.layers.len() - 1;
        // The Z slots hold act'(Z) after the forward pass.
        let d_last = &ctx[starts[last].1..starts[last].1 + rows * n_y];
        let mut dz: Vec<R> = d_output.iter().zip(d_last).map(|(d, g)| *d * *g).collect();
        let mut d_input = d_input;
        let mut d_skip: Vec<R> = Vec::new();
        for l in (0..self.layers.len()).rev() {
            let (n_in, n_out, off) = self.layers[l];
            let a = &ctx[starts[l].0..starts[l].0 + rows * n_in];
            let (dw, db) = d_params[off..off + n_in * n_out + n_out].split_at_mut(n_in * n_out);
            let wt = &params[off..off + n_in * n_out];
            let dzv = ArrayView2::from_shape((rows, n_out), &dz[..]).expect("dZ shape");
            // dW += dZᵀ A; db += Σ_rows dZ.
            let av = ArrayView2::from_shape((rows, n_in), a).expect("A shape");
            let mut dwv = ArrayViewMut2::from_shape((n_out, n_in), dw).expect("dW shape");
            general_mat_mul(R::ONE, &dzv.t(), &av, R::ONE, &mut dwv);
            for row in dz.chunks_exact(n_out) {
                for (b, d) in db.iter_mut().zip(row) {
                    *b += *d;
                }
            }
            if l == 0 && d_input.is_none() {
                break;
            }
            // dA = dZ W.
            let mut da = vec![R::ZERO; rows * n_in];
            let wv = ArrayView2::from_shape((n_out, n_in), wt).expect("W shape");
            let mut dav = ArrayViewMut2::from_shape((rows, n_in), &mut da[..]).expect("dA shape");
            general_mat_mul(R::ONE, &dzv, &wv, R::ZERO, &mut dav);
            if l == 0 {
                if let Some(d_in) = d_input.as_deref_mut() {
                    d_in.copy_from_slice(&da);
                    for (d, s) in d_in.iter_mut().zip(&d_skip) {
                        *d += *s;
                    }
                }
                break;
            }
            let prev_out = self.layers[l - 1].1;
            if self.config.skip == Some(l) && d_input.is_some() {
                // The input's share of the skip concatenation, added at layer 0.
                d_skip = vec![R::ZERO; rows * n_x];
                for r in 0..rows {
                    for k in 0..n_x {
                        d_skip[r * n_x + k] = da[r * n_in + prev_out + k] * inv_sqrt2;
                    }
                }
            }
            let scale = if self.config.skip == Some(l) { inv_sqrt2 } else { R::ONE };
            let d_prev = &ctx[starts[l - 1].1..starts[l - 1].1 + rows * prev_out];
            dz = vec![R::ZERO; rows * prev_out];
            for r in 0..rows {
                for k in 0..prev_out {
                    dz[r * prev_out + k] = da[r * n_in + k] * scale * d_prev[r * prev_out + k];
                }
            }
        }
    }
}

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
