//! Dense layers with activations, an optional skip connection, and NeuS's geometric initialisation.

use crate::kernels::{Dense, Strided, dense_forward, gemm, pad};
use crate::module::{Activation, Module, TangentAdjoints, TangentModule};
use crate::real::Real;
use crate::scratch::Buf;

mod init;

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
        let _span = crate::profile::span(crate::profile::Stage::MlpForward);
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
                    let (act, scale) = self.layer_activation::<R>(l);
                    if l == last {
                        // Into a padded temporary, then the unpadded output.
                        let mut y = Buf::<R>::zeroed(rows * op);
                        dense_forward(&Dense { a, a_s: ip, n_in, wt, bias, n_out_pad: op, act, scale }, &mut y, op, 0, d, rows);
                        for (o, yr) in output.chunks_exact_mut(n_y).zip(y.chunks_exact(op)) {
                            o.copy_from_slice(&yr[..n_y]);
                        }
                    } else {
                        // Straight into the next layer's input block (its padding stays zero).
                        let next_ip = pad(self.layers[l + 1].0);
                        let y = &mut next[..rows * next_ip];
                        dense_forward(&Dense { a, a_s: ip, n_in, wt, bias, n_out_pad: op, act, scale }, y, next_ip, 0, d, rows);
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
        let _span = crate::profile::span(crate::profile::Stage::MlpBackward);
        let n_x = self.config.n_inputs;
        let n_y = self.config.n_outputs;
        let rows = input.len() / n_x;
        if rows == 0 {
            return;
        }
        let inv_sqrt2 = R::of(std::f64::consts::FRAC_1_SQRT_2);
        let starts = self.ctx_starts(rows);
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

/// Tangents through every activation (act'' from act' and, for the sigmoid, act).
impl<R: Real> TangentModule<R> for Mlp {
    fn forward_tangents(&self, params: &[R], input: &[R], ctx: &[R], k: usize, tangents_in: &[R], tangents_out: &mut [R]) {
        let _span = crate::profile::span(crate::profile::Stage::MlpTangents);
        let rows = input.len() / self.config.n_inputs;
        if rows > 0 {
            self.tangent_pass(params, ctx, rows, k, tangents_in, Some(tangents_out));
        }
    }

    /// Layer by layer, with u = act'(Z) ⊙ Ż the tangent of the activation: Ż̄ = act'(Z) ⊙ ū,
    /// Z̄ = act'(Z) ⊙ ȳ + act''(Z) ⊙ Ż ⊙ ū; W̄ += Z̄ᵀA + Ż̄ᵀȦ, b̄ += ΣZ̄; Ā = Z̄W, Ǡ = Ż̄W.
    fn backward_tangent(&self, pass: TangentAdjoints<'_, R>, d_params: &mut [R], d_input: Option<(&mut [R], &mut [R])>) {
        let TangentAdjoints { params, input, ctx, tangent_in, d_output, d_tangent_out } = pass;
        let _span = crate::profile::span(crate::profile::Stage::MlpTangents);
        let n_x = self.config.n_inputs;
        let n_y = self.config.n_outputs;
        let rows = input.len() / n_x;
        if rows == 0 {
            return;
        }
        let inv_sqrt2 = R::of(std::f64::consts::FRAC_1_SQRT_2);
        let starts = self.ctx_starts(rows);
        let tangents = self.tangent_pass(params, ctx, rows, 1, tangent_in, None);
        let mut d_input = d_input;
        crate::kernels::dispatch(
            #[inline(always)]
            || {
                let op_last = pad(n_y);
                let mut dy = Buf::<R>::zeroed(rows * op_last);
                let mut du = Buf::<R>::zeroed(rows * op_last);
                for r in 0..rows {
                    dy[r * op_last..r * op_last + n_y].copy_from_slice(&d_output[r * n_y..(r + 1) * n_y]);
                    du[r * op_last..r * op_last + n_y].copy_from_slice(&d_tangent_out[r * n_y..(r + 1) * n_y]);
                }
                let (mut d_skip, mut d_skip_tangent): (Option<Buf<R>>, Option<Buf<R>>) = (None, None);
                for l in (0..self.layers.len()).rev() {
                    let (n_in, n_out, off) = self.layers[l];
                    let (ip, op) = (pad(n_in), pad(n_out));
                    let (act, _) = self.layer_activation::<R>(l);
                    let a = &ctx[starts[l].0..starts[l].0 + rows * ip];
                    let slope = &ctx[starts[l].1..starts[l].1 + rows * op];
                    let (a_dot, z_dot) = &tangents[l];
                    let values = act.second_needs_value().then(|| self.layer_values(params, ctx, &starts, rows, l));
                    // Z̄ and Ż̄ in place of ȳ and ū.
                    for i in 0..rows * op {
                        let second = act.second_derivative(slope[i], values.as_ref().map_or(R::ZERO, |v| v[i]));
                        let (g, u) = (dy[i], du[i]);
                        dy[i] = slope[i] * g + second * z_dot[i] * u;
                        du[i] = slope[i] * u;
                    }
                    let mut dw = Buf::<R>::zeroed(n_out * ip);
                    gemm(&mut dw, ip, Strided { data: &dy, sm: 1, sk: op }, a, ip, n_out, ip, rows, false);
                    gemm(&mut dw, ip, Strided { data: &du, sm: 1, sk: op }, a_dot, ip, n_out, ip, rows, true);
                    let (dwp, dbp) = d_params[off..off + n_in * n_out + n_out].split_at_mut(n_in * n_out);
                    for o in 0..n_out {
                        for i in 0..n_in {
                            dwp[o * n_in + i] += dw[o * ip + i];
                        }
                    }
                    for row in dy.chunks_exact(op) {
                        for (b, g) in dbp.iter_mut().zip(row) {
                            *b += *g;
                        }
                    }
                    if l == 0 && d_input.is_none() {
                        break;
                    }
                    let (_, wp, _) = self.packed(params, l);
                    let mut da = Buf::<R>::zeroed(rows * ip);
                    let mut da_dot = Buf::<R>::zeroed(rows * ip);
                    gemm(&mut da, ip, Strided { data: &dy, sm: op, sk: 1 }, &wp, ip, rows, ip, n_out, false);
                    gemm(&mut da_dot, ip, Strided { data: &du, sm: op, sk: 1 }, &wp, ip, rows, ip, n_out, false);
                    if l == 0 {
                        if let Some((d_in, d_in_tangent)) = d_input.as_mut() {
                            for r in 0..rows {
                                for q in 0..n_x {
                                    d_in[r * n_x + q] = da[r * ip + q] + d_skip.as_ref().map_or(R::ZERO, |s| s[r * n_x + q]);
                                    d_in_tangent[r * n_x + q] = da_dot[r * ip + q] + d_skip_tangent.as_ref().map_or(R::ZERO, |s| s[r * n_x + q]);
                                }
                            }
                        }
                        break;
                    }
                    let prev_out = self.layers[l - 1].1;
                    let prev_op = pad(prev_out);
                    let skip = self.config.skip == Some(l);
                    if skip && d_input.is_some() {
                        let take = |d: &[R]| {
                            let mut g = Buf::<R>::zeroed(rows * n_x);
                            for (dst, src) in g.chunks_exact_mut(n_x).zip(d.chunks_exact(ip)) {
                                for q in 0..n_x {
                                    dst[q] = src[prev_out + q] * inv_sqrt2;
                                }
                            }
                            g
                        };
                        d_skip = Some(take(&da));
                        d_skip_tangent = Some(take(&da_dot));
                    }
                    let scale = if skip { inv_sqrt2 } else { R::ONE };
                    let (mut next, mut next_u) = (Buf::<R>::zeroed(rows * prev_op), Buf::<R>::zeroed(rows * prev_op));
                    for r in 0..rows {
                        for q in 0..prev_out {
                            next[r * prev_op + q] = da[r * ip + q] * scale;
                            next_u[r * prev_op + q] = da_dot[r * ip + q] * scale;
                        }
                    }
                    dy = next;
                    du = next_u;
                }
            },
        );
    }
}

impl Mlp {
    /// Block offsets of each layer's input A and act'(Z) in a context of `rows` rows.
    fn ctx_starts(&self, rows: usize) -> Vec<(usize, usize)> {
        let mut starts = Vec::with_capacity(self.layers.len());
        let mut at = 0;
        for &(n_in, n_out, _) in &self.layers {
            starts.push((at, at + rows * pad(n_in)));
            at += rows * (pad(n_in) + pad(n_out));
        }
        starts
    }

    /// The activation of layer `l` and the scale of its output (1/√2 before the skip layer).
    fn layer_activation<R: Real>(&self, l: usize) -> (Activation, R) {
        if l == self.layers.len() - 1 {
            (self.config.output_activation, R::ONE)
        } else if self.config.skip == Some(l + 1) {
            (self.config.hidden_activation, R::of(std::f64::consts::FRAC_1_SQRT_2))
        } else {
            (self.config.hidden_activation, R::ONE)
        }
    }

    /// act(Z) of layer `l` (rows × out_pad) for an activation whose second derivative needs it
    /// ([`Activation::second_needs_value`]): the next layer's input block (its first columns,
    /// the skip's 1/√2 undone), or for the output layer act(A Wᵀ + b) recomputed from its input.
    fn layer_values<R: Real>(&self, params: &[R], ctx: &[R], starts: &[(usize, usize)], rows: usize, l: usize) -> Buf<R> {
        let (n_in, n_out, off) = self.layers[l];
        let (ip, op) = (pad(n_in), pad(n_out));
        let (act, scale) = self.layer_activation::<R>(l);
        let mut y = Buf::<R>::zeroed(rows * op);
        if l + 1 < self.layers.len() {
            let next_ip = pad(self.layers[l + 1].0);
            let a = &ctx[starts[l + 1].0..starts[l + 1].0 + rows * next_ip];
            for r in 0..rows {
                for q in 0..n_out {
                    y[r * op + q] = a[r * next_ip + q] / scale;
                }
            }
        } else {
            let a = &ctx[starts[l].0..starts[l].0 + rows * ip];
            let (w, b) = params[off..off + n_in * n_out + n_out].split_at(n_in * n_out);
            for r in 0..rows {
                for o in 0..n_out {
                    let z = (0..n_in).fold(b[o], |z, i| w[o * n_in + i].mul_add(a[r * ip + i], z));
                    y[r * op + o] = act.apply(z);
                }
            }
        }
        y
    }

    /// Forward-mode pass of `t_rows` tangent rows, `k` per input row (row r's tangents are rows
    /// r·k … r·k + k − 1): `tangents_in` (t_rows × n_inputs). Returns, per layer, the padded
    /// tangent of its input (t_rows × in_pad) and of its pre-activation Ż (t_rows × out_pad);
    /// the output tangents go to `tangents_out` (t_rows × n_outputs) when given.
    fn tangent_pass<R: Real>(
        &self,
        params: &[R],
        ctx: &[R],
        rows: usize,
        k: usize,
        tangents_in: &[R],
        tangents_out: Option<&mut [R]>,
    ) -> Vec<(Buf<R>, Buf<R>)> {
        let n_x = self.config.n_inputs;
        let t_rows = rows * k;
        let inv_sqrt2 = R::of(std::f64::consts::FRAC_1_SQRT_2);
        let starts = self.ctx_starts(rows);
        let mut blocks: Vec<(Buf<R>, Buf<R>)> = Vec::with_capacity(self.layers.len());
        let ip0 = pad(n_x);
        let mut a_dot = Buf::<R>::zeroed(t_rows * ip0);
        for (dst, src) in a_dot.chunks_exact_mut(ip0).zip(tangents_in.chunks_exact(n_x)) {
            dst[..n_x].copy_from_slice(src);
        }
        let mut tangents_out = tangents_out;
        crate::kernels::dispatch(
            #[inline(always)]
            || {
                for (l, &(n_in, n_out, _)) in self.layers.iter().enumerate() {
                    let (ip, op) = (pad(n_in), pad(n_out));
                    let (wt, _, _) = self.packed(params, l);
                    // Ż = Ȧ Wᵀ (no bias).
                    let mut z_dot = Buf::<R>::zeroed(t_rows * op);
                    gemm(&mut z_dot, op, Strided { data: &a_dot, sm: ip, sk: 1 }, &wt, op, t_rows, op, n_in, false);
                    let slope = &ctx[starts[l].1..starts[l].1 + rows * op];
                    let (_, scale) = self.layer_activation::<R>(l);
                    if l == self.layers.len() - 1 {
                        if let Some(out) = tangents_out.as_deref_mut() {
                            for (t, (o, z)) in out.chunks_exact_mut(n_out).zip(z_dot.chunks_exact(op)).enumerate() {
                                let sl = &slope[(t / k) * op..(t / k) * op + op];
                                for q in 0..n_out {
                                    o[q] = sl[q] * z[q] * scale;
                                }
                            }
                        }
                        blocks.push((std::mem::replace(&mut a_dot, Buf::zeroed(0)), z_dot));
                        break;
                    }
                    // The next layer's input tangent: act'(Z) ⊙ Ż · scale (and ẋ/√2 after a skip).
                    let next_ip = pad(self.layers[l + 1].0);
                    let mut next = Buf::<R>::zeroed(t_rows * next_ip);
                    for (t, (dst, z)) in next.chunks_exact_mut(next_ip).zip(z_dot.chunks_exact(op)).enumerate() {
                        let sl = &slope[(t / k) * op..(t / k) * op + op];
                        for q in 0..n_out {
                            dst[q] = sl[q] * z[q] * scale;
                        }
                        if self.config.skip == Some(l + 1) {
                            for q in 0..n_x {
                                dst[n_out + q] = tangents_in[t * n_x + q] * inv_sqrt2;
                            }
                        }
                    }
                    blocks.push((std::mem::replace(&mut a_dot, next), z_dot));
                }
            },
        );
        blocks
    }
}
