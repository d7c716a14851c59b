//! Dense layers with activations, an optional skip connection, and NeuS's geometric initialisation.

use crate::kernels::{Dense, bf16, dense_forward, pad};
use crate::module::{Activation, Module};
use crate::real::Real;
use crate::scratch::Buf;

mod backward;
mod folded;
mod infer;
mod init;
mod tangents;

pub(crate) use infer::pad_rows;

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

/// The precision of an MLP's matrix products (in f32; the f64 gradient checks keep every
/// product exact).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Products {
    /// f32 throughout.
    #[default]
    F32,
    /// The hidden-to-hidden layers' products (forward, tangents and backward) in bf16 with f32
    /// accumulation where the CPU has AVX512_BF16 ([`crate::kernels::bf16`]), f32 elsewhere and
    /// on other CPUs. The first layer (its input holds the position) and the output layer (the
    /// SDF value) stay f32: bf16 keeps 8 bits of a value, 2⁻⁹ of it at most lost.
    Bf16Hidden,
}

/// A multi-layer perceptron. Parameters per layer: weights (out × in, row-major), then biases.
#[derive(Debug, Clone)]
pub struct Mlp {
    config: MlpConfig,
    /// (n_in, n_out, parameter offset) per layer.
    layers: Vec<(usize, usize, usize)>,
    n_params: usize,
    products: Products,
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
        Mlp { config, layers, n_params: offset, products: Products::F32 }
    }

    /// Runs this network's products in `products` from now on.
    pub fn set_products(&mut self, products: Products) {
        self.products = products;
    }

    /// The precision asked of the products ([`Products::Bf16Hidden`] says where it applies).
    pub fn products(&self) -> Products {
        self.products
    }

    /// Whether layer `l`'s products run in bf16: a hidden-to-hidden layer, [`Products::Bf16Hidden`]
    /// asked, and the CPU has the instruction.
    pub(crate) fn in_bf16(&self, l: usize) -> bool {
        self.products == Products::Bf16Hidden && l >= 1 && l + 1 < self.layers.len() && bf16::available()
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

    /// Wᵀ of layer `l` (n_in × out_pad) and its bias (out_pad), zero-padded: the weights of the
    /// forward pass and the tangents.
    fn transposed<R: Real>(&self, params: &[R], l: usize) -> (Buf<R>, Buf<R>) {
        let (n_in, n_out, off) = self.layers[l];
        let w = &params[off..off + n_in * n_out];
        let wt = backward::padded_block(n_in, pad(n_out), |i, row| {
            for o in 0..n_out {
                row[o] = w[o * n_in + i];
            }
            n_out
        });
        (wt, backward::padded_rows(&params[off + n_in * n_out..off + n_in * n_out + n_out], n_out))
    }

    /// W of layer `l` (n_out × in_pad), zero-padded: the weights of the input adjoints.
    fn padded<R: Real>(&self, params: &[R], l: usize) -> Buf<R> {
        let (n_in, n_out, off) = self.layers[l];
        backward::padded_rows(&params[off..off + n_in * n_out], n_in)
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
        self.forward_into(params, input, output, ctx);
    }

    fn forward_first(&self, params: &[R], input: &[R], first: &mut [R]) {
        self.infer_columns(params, input, first, 1);
    }

    fn infer(&self, params: &[R], input: &[R], output: &mut [R]) {
        self.infer_columns(params, input, output, self.config.n_outputs);
    }

    fn backward(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_params: &mut [R], d_input: Option<&mut [R]>) {
        self.backward_pass(params, input, ctx, d_output, Some(d_params), d_input);
    }
}

/// A layer's weights as a forward pass reads them: Wᵀ (n_in × out_pad) and the bias, zero-padded
/// ([`Mlp::transposed`]), and Wᵀ packed in pairs where the layer's products run in bf16.
pub(crate) struct PackedLayer<R: Real> {
    wt: Buf<R>,
    bias: Buf<R>,
    pairs: Option<Buf<u32>>,
}

impl Mlp {
    /// Every layer's [`PackedLayer`]: once per pass, shared by all its rows.
    pub(crate) fn packed_layers<R: Real>(&self, params: &[R]) -> Vec<PackedLayer<R>> {
        (0..self.layers.len())
            .map(|l| {
                let (n_in, n_out, _) = self.layers[l];
                let (wt, bias) = self.transposed(params, l);
                let pairs = R::f32s(&wt).filter(|_| self.in_bf16(l)).map(|wt| {
                    let mut right = Buf::<u32>::zeroed(n_in.div_ceil(2) * pad(n_out));
                    bf16::pack_right(wt, pad(n_out), n_in, pad(n_out), &mut right);
                    right
                });
                PackedLayer { wt, bias, pairs }
            })
            .collect()
    }

    /// Layer `l` ([`PackedLayer`] `packed`) on the input rows `a` (row stride `pad(n_in)`): in
    /// bf16 where the layer was packed for it.
    pub(crate) fn dense<'a, R: Real>(&self, l: usize, packed: &'a PackedLayer<R>, a: &'a [R]) -> Dense<'a, R> {
        let (n_in, n_out, _) = self.layers[l];
        let (ip, op) = (pad(n_in), pad(n_out));
        let (act, scale) = self.layer_activation::<R>(l);
        let pairs = packed.pairs.as_deref().zip(R::f32s(a)).map(|(right, left)| bf16::Pairs { left, stride: ip, k: n_in, right, n: op });
        Dense { a, a_s: ip, n_in, wt: &packed.wt, bias: &packed.bias, n_out_pad: op, act, scale, pairs }
    }

    /// After hidden layer `l` wrote `y` (rows of `pad` of the next layer's inputs): where the
    /// next layer is the skip layer, the skip's `x / √2` after its outputs (`input` the network's
    /// rows) and the padding zeroed. Otherwise the next layer's inputs are this layer's outputs,
    /// whose row is exactly the `pad(n_out)` the tile wrote: nothing to add.
    pub(crate) fn finish_next_input<R: Real>(&self, l: usize, y: &mut [R], input: &[R]) {
        if self.config.skip != Some(l + 1) {
            return;
        }
        let (n_x, n_out) = (self.config.n_inputs, self.layers[l].1);
        // [h, x] / √2: the raw input after the previous layer's output.
        let inv_sqrt2 = R::of(std::f64::consts::FRAC_1_SQRT_2);
        for (row, x) in y.chunks_exact_mut(pad(self.layers[l + 1].0)).zip(input.chunks_exact(n_x)) {
            for k in 0..n_x {
                row[n_out + k] = x[k] * inv_sqrt2;
            }
            row[n_out + n_x..].fill(R::ZERO);
        }
    }

    /// [`Module::forward`] into `output`, layer by layer through `ctx`.
    fn forward_into<R: Real>(&self, params: &[R], input: &[R], output: &mut [R], ctx: &mut [R]) {
        let _span = crate::profile::span(crate::profile::Stage::MlpForward);
        let n_x = self.config.n_inputs;
        let n_y = self.config.n_outputs;
        let rows = input.len() / n_x;
        if rows == 0 {
            return;
        }
        let packed = self.packed_layers(params);
        // The first layer's input block: the input, padded.
        pad_rows(input, n_x, &mut ctx[..rows * pad(n_x)]);
        let last = self.layers.len() - 1;
        crate::kernels::dispatch(
            #[inline(always)]
            || {
                let mut at = 0;
                for (l, &(n_in, n_out, _)) in self.layers.iter().enumerate() {
                    let (ip, op) = (pad(n_in), pad(n_out));
                    let (head, rest) = ctx[at..].split_at_mut(rows * ip);
                    let (d, next) = rest.split_at_mut(rows * op);
                    let dense = self.dense(l, &packed[l], head);
                    if l == last {
                        // Into a padded temporary, then the unpadded output.
                        let mut y = Buf::<R>::to_overwrite(rows * op);
                        dense_forward(&dense, &mut y, op, 0, Some(d), rows);
                        for (o, yr) in output.chunks_exact_mut(n_y).zip(y.chunks_exact(op)) {
                            o.copy_from_slice(&yr[..n_y]);
                        }
                    } else {
                        // Straight into the next layer's input block (its padding stays zero).
                        let y = &mut next[..rows * pad(self.layers[l + 1].0)];
                        dense_forward(&dense, y, pad(self.layers[l + 1].0), 0, Some(d), rows);
                        self.finish_next_input(l, y, input);
                    }
                    at += rows * (ip + op);
                }
            },
        );
    }

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
}
