//! Dense layers with activations, an optional skip connection, and NeuS's geometric initialisation.

use crate::kernels::{Strided, dense_forward, gemm, pad};
use crate::module::{Activation, Module};
use crate::real::Real;
use crate::scratch::Buf;
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
        // The context is layer-major: the output layer's input A is a rows × pad(n_in) block.
        let a_start = self.last_input_offset(rows);
        let value = |r: usize, k: usize| ctx[a_start + r * pad(n_in) + k];
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

    /// Context values per row: per layer, its input A (padded to [`crate::kernels::LANE`] columns) and the
    /// derivative of its activation act'(Z) (padded likewise). The layout is layer-major: for
    /// each layer a rows × in_pad block, then a rows × out_pad block.
    fn ctx_layout(&self) -> usize {
        self.layers.iter().map(|(i, o, _)| pad(*i) + pad(*o)).sum()
    }

    /// Offset of the output layer's input block in a context of `rows` rows.
    fn last_input_offset(&self, rows: usize) -> usize {
        rows * self.layers[..self.layers.len() - 1].iter().map(|(i, o, _)| pad(*i) + pad(*o)).sum::<usize>()
    }

    /// Weights of layer `l` packed for the kernels: Wᵀ (n_in × out_pad), W (n_out × in_pad) and
    /// the bias (out_pad), zero-padded.
    fn packed<R: Real>(&self, params: &[R], l: usize) -> (Vec<R>, Vec<R>, Vec<R>) {
        let (n_in, n_out, off) = self.layers[l];
        let (ip, op) = (pad(n_in), pad(n_out));
        let w = &params[off..off + n_in * n_out];
        let mut wt = vec![R::ZERO; n_in * op];
        let mut wp = vec![R::ZERO; n_out * ip];
        for o in 0..n_out {
            for i in 0..n_in {
                wt[i * op + o] = w[o * n_in + i];
                wp[o * ip + i] = w[o * n_in + i];
            }
        }
        let mut bias = vec![R::ZERO; op];
        bias[..n_out].copy_from_slice(&params[off + n_in * n_out..off + n_in * n_out + n_out]);
        (wt, wp, bias)
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
        let packed: Vec<(Vec<R>, Vec<R>, Vec<R>)> = (0..self.layers.len()).map(|l| self.packed(params, l)).collect();
        // The first layer's input block: the input, padded.
        let ip0 = pad(n_x);
        for (dst, src) in ctx[..rows * ip0].chunks_exact_mut(ip0).zip(input.chunks_exact(n_x)) {
            dst[..n_x].copy_from_slice(src);
            dst[n_x..].fill(R::ZERO);
        }
        let last = self.layers.len() - 1;
        crate::kernels::dispatch(
            #[inline(always)]
            || {
                let mut at = 0;
                for (l, &(n_in, n_out, _)) in self.layers.iter().enumerate() {
                    let (ip, op) = (pad(n_in), pad(n_out));
                    let (wt, _, bias) = &packed[l];
                    let (head, rest) = ctx[at..].split_at_mut(rows * ip);
                    let (d, next) = rest.split_at_mut(rows * op);
                    let a = &*head;
                    let (act, scale) = if l == last {
                        (self.config.output_activation, R::ONE)
                    } else if self.config.skip == Some(l + 1) {
                        (self.config.hidden_activation, inv_sqrt2)
                    } else {
                        (self.config.hidden_activation, R::ONE)
                    };
                    if l == last {
                        // Into a padded temporary, then the unpadded output.
                        let mut y = Buf::<R>::zeroed(rows * op);
                        dense_forward(a, ip, n_in, wt, bias, op, act, scale, &mut y, op, 0, d, rows);
                        for (o, yr) in output.chunks_exact_mut(n_y).zip(y.chunks_exact(op)) {
                            o.copy_from_slice(&yr[..n_y]);
                        }
                    } else {
                        // Straight into the next layer's input block (its padding stays zero).
                        let next_ip = pad(self.layers[l + 1].0);
                        let y = &mut next[..rows * next_ip];
                        dense_forward(a, ip, n_in, wt, bias, op, act, scale, y, next_ip, 0, d, rows);
                        if self.config.skip == Some(l + 1) {
                            // [h, x] / √2: the raw input after the previous layer's output.
                            for (row, x) in y.chunks_exact_mut(next_ip).zip(input.chunks_exact(n_x)) {
                                for k in 0..n_x {
                                    row[n_out + k] = x[k] * inv_sqrt2;
                                }
                                row[n_out + n_x..].fill(R::ZERO);
                            }
                        } else {
                            for row in y.chunks_exact_mut(next_ip) {
                                row[op..].fill(R::ZERO);
                            }
                        }
                    }
                    at += rows * (ip + op);
                }
            },
        );
    }

    fn backward(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_params: &mut [R], d_input: Option<&mut [R]>) {
        let n_x = self.config.n_inputs;
        let n_y = self.config.n_outputs;
        let rows = input.len() / n_x;
        if rows == 0 {
            return;
        }
        let inv_sqrt2 = R::of(std::f64::consts::FRAC_1_SQRT_2);
        // Block offsets of each layer's A and act'(Z) in the context.
        let mut starts = Vec::with_capacity(self.layers.len());
        let mut at = 0;
        for &(n_in, n_out, _) in &self.layers {
            starts.push((at, at + rows * pad(n_in)));
            at += rows * (pad(n_in) + pad(n_out));
        }
        let mut d_input = d_input;
        crate::kernels::dispatch(
            #[inline(always)]
            || {
                // dY of the output layer, padded.
                let op_last = pad(n_y);
                let mut dy = Buf::<R>::zeroed(rows * op_last);
                for (dst, src) in dy.chunks_exact_mut(op_last).zip(d_output.chunks_exact(n_y)) {
                    dst[..n_y].copy_from_slice(src);
                }
                let mut d_skip: Option<Buf<R>> = None;
                for l in (0..self.layers.len()).rev() {
                    let (n_in, n_out, off) = self.layers[l];
                    let (ip, op) = (pad(n_in), pad(n_out));
                    let a = &ctx[starts[l].0..starts[l].0 + rows * ip];
                    let slope = &ctx[starts[l].1..starts[l].1 + rows * op];
                    // dZ = dY ⊙ act'(Z), in place.
                    for (g, s) in dy.iter_mut().zip(slope) {
                        *g *= *s;
                    }
                    // dW += dZᵀ A, db += Σ dZ.
                    let mut dw = Buf::<R>::zeroed(n_out * ip);
                    gemm(&mut dw, ip, Strided { data: &dy, sm: 1, sk: op }, a, ip, n_out, ip, rows, false);
                    let (dwp, dbp) = d_params[off..off + n_in * n_out + n_out].split_at_mut(n_in * n_out);
                    for o in 0..n_out {
                        for i in 0..n_in {
                            dwp[o * n_in + i] += dw[o * ip + i];
                        }
                    }
                    let mut db = vec![R::ZERO; op];
                    for row in dy.chunks_exact(op) {
                        for (b, g) in db.iter_mut().zip(row) {
                            *b += *g;
                        }
                    }
                    for (b, g) in dbp.iter_mut().zip(&db) {
                        *b += *g;
                    }
                    if l == 0 && d_input.is_none() {
                        break;
                    }
                    // dA = dZ W.
                    let (_, wp, _) = self.packed(params, l);
                    let mut da = Buf::<R>::zeroed(rows * ip);
                    gemm(&mut da, ip, Strided { data: &dy, sm: op, sk: 1 }, &wp, ip, rows, ip, n_out, false);
                    if l == 0 {
                        if let Some(d_in) = d_input.as_deref_mut() {
                            for (r, (dst, src)) in d_in.chunks_exact_mut(n_x).zip(da.chunks_exact(ip)).enumerate() {
                                dst.copy_from_slice(&src[..n_x]);
                                if let Some(d_skip) = &d_skip {
                                    for k in 0..n_x {
                                        dst[k] += d_skip[r * n_x + k];
                                    }
                                }
                            }
                        }
                        break;
                    }
                    let prev_out = self.layers[l - 1].1;
                    let prev_op = pad(prev_out);
                    let skip = self.config.skip == Some(l);
                    if skip && d_input.is_some() {
                        // The input's share of the skip concatenation, added at layer 0.
                        let mut skip_grad = Buf::<R>::zeroed(rows * n_x);
                        for (dst, src) in skip_grad.chunks_exact_mut(n_x).zip(da.chunks_exact(ip)) {
                            for k in 0..n_x {
                                dst[k] = src[prev_out + k] * inv_sqrt2;
                            }
                        }
                        d_skip = Some(skip_grad);
                    }
                    let scale = if skip { inv_sqrt2 } else { R::ONE };
                    let mut next = Buf::<R>::zeroed(rows * prev_op);
                    for (dst, src) in next.chunks_exact_mut(prev_op).zip(da.chunks_exact(ip)) {
                        for k in 0..prev_out {
                            dst[k] = src[k] * scale;
                        }
                    }
                    dy = next;
                }
            },
        );
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
