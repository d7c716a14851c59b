//! The forward pass with no backward pass after it (renders, up-sampling, meshing): no context,
//! no activation slopes, the rows in blocks small enough that every layer's input and output of
//! a block stay in the core's cache — where [`Module::forward`](crate::Module::forward) writes
//! each layer's input and slope for every row of the batch (≈ 1.2 KB a row for a two-layer SDF
//! network: a thousand rows overflow a Zen 3's 512 KB L2), only to drop them.
//!
//! Each output is that of the forward pass to the bit: the same packed weights, the same tile
//! kernel summing each output over its inputs in the same order, the same activation — but for
//! a folded first layer ([`Mlp::infer_folded`], `folded.rs`: to rounding).

use super::folded::FirstLayer;
use super::{Mlp, PackedLayer};
use crate::kernels::{dense_forward, pad};
use crate::real::Real;
use crate::scratch::Buf;

/// Rows per block: a multiple of both tile heights (6 on AVX2, 4 on AVX-512), each 64-wide
/// layer's output block 12 KB in f32.
const BLOCK: usize = 48;
const _: () = assert!(BLOCK.is_multiple_of(crate::kernels::NARROW_ROWS) && BLOCK.is_multiple_of(crate::kernels::WIDE_ROWS));

/// `input` (rows of `n`) into `padded` (rows of `pad(n)`), the padding zeroed.
pub(crate) fn pad_rows<R: Real>(input: &[R], n: usize, padded: &mut [R]) {
    for (dst, src) in padded.chunks_exact_mut(pad(n)).zip(input.chunks_exact(n)) {
        dst[..n].copy_from_slice(src);
        dst[n..].fill(R::ZERO);
    }
}

impl Mlp {
    /// The first `keep` outputs of every row (≤ the network's outputs) into `output` (rows ×
    /// `keep`), as [`Module::forward`](crate::Module::forward) computes them, to the bit, without
    /// its context.
    pub(crate) fn infer_columns<R: Real>(&self, params: &[R], input: &[R], output: &mut [R], keep: usize) {
        self.check_inference(self.config.n_inputs, input, output, keep);
        if !output.is_empty() {
            self.infer_packed(&self.packed_layers(params), input, output, keep);
        }
    }

    /// Panics where `output` is not one row of `keep` (≤ the network's outputs) per input row
    /// of `n_in` values.
    pub(super) fn check_inference<R: Real>(&self, n_in: usize, input: &[R], output: &[R], keep: usize) {
        assert!(keep <= self.config.n_outputs, "{keep} outputs asked of a network of {}", self.config.n_outputs);
        assert_eq!(input.len() / n_in.max(1) * keep, output.len(), "one row of {keep} outputs per input row");
    }

    /// [`Self::infer_columns`] with the layers packed once by the caller ([`Self::packed_layers`]
    /// of the same parameters), for a caller that runs the network on many small batches (an
    /// up-sampling, chunk by chunk and round by round): packing the weights is a pass over all
    /// of them, as long as the products of a few hundred rows.
    pub(crate) fn infer_packed<R: Real>(&self, packed: &[PackedLayer<R>], input: &[R], output: &mut [R], keep: usize) {
        self.check_inference(self.config.n_inputs, input, output, keep);
        self.infer_rows(None, packed, input, output, keep);
    }

    /// The forward pass of `input`'s rows in blocks of [`BLOCK`], the first layer's operands
    /// `first` where given (a folded first layer: its Wᵀ, bias and inputs per row, the rows of
    /// `input` that many wide) else `packed[0]`'s; the first `keep` outputs of each row into
    /// `output`.
    pub(super) fn infer_rows<R: Real>(
        &self,
        first: Option<FirstLayer<'_, R>>,
        packed: &[PackedLayer<R>],
        input: &[R],
        output: &mut [R],
        keep: usize,
    ) {
        let _span = crate::profile::span(crate::profile::Stage::MlpForward);
        assert_eq!(packed.len(), self.layers.len(), "one packed layer per layer");
        let n_x = first.as_ref().map_or(self.config.n_inputs, |f| f.n_in);
        if output.is_empty() {
            return;
        }
        let widest = self.layers.iter().map(|&(n_in, n_out, _)| pad(n_in).max(pad(n_out))).max().unwrap_or(0);
        // A block's layer input and output, in turn.
        let (mut a, mut y) = (Buf::<R>::to_overwrite(BLOCK * widest), Buf::<R>::to_overwrite(BLOCK * widest));
        let last = self.layers.len() - 1;
        crate::kernels::dispatch(
            #[inline(always)]
            || {
                for (x, out) in input.chunks(BLOCK * n_x).zip(output.chunks_mut(BLOCK * keep)) {
                    let rows = x.len() / n_x;
                    pad_rows(x, n_x, &mut a[..rows * pad(n_x)]);
                    for l in 0..=last {
                        let (n_in, n_out, _) = self.layers[l];
                        let ys = if l == last { pad(n_out) } else { pad(self.layers[l + 1].0) };
                        let dense = match &first {
                            Some(f) if l == 0 => f.dense(self, &a[..rows * pad(n_x)]),
                            _ => self.dense(l, &packed[l], &a[..rows * pad(n_in)]),
                        };
                        dense_forward(&dense, &mut y[..rows * ys], ys, 0, None, rows);
                        if l < last {
                            self.finish_next_input(l, &mut y[..rows * ys], x);
                            std::mem::swap(&mut a, &mut y);
                        }
                    }
                    for (o, yr) in out.chunks_exact_mut(keep).zip(y.chunks_exact(pad(self.layers[last].1))) {
                        o.copy_from_slice(&yr[..keep]);
                    }
                }
            },
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mlp::MlpConfig;
    use crate::module::{Activation, Module};

    /// Random values in [−1, 1) (xorshift).
    fn values(n: usize, seed: u64) -> Vec<f64> {
        let mut x = seed | 1;
        (0..n)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                (x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
            })
            .collect()
    }

    /// Guards the context-free pass: every output of every row is the forward pass's to the bit
    /// (f32 and f64, and f32 with the hidden products in bf16 — exercised where the CPU has
    /// AVX512_BF16), for networks with a skip layer, each activation, row counts around the
    /// block and the tiles, and the first output alone ([`Module::forward_first`]) too.
    #[test]
    fn inference_is_the_forward_pass_to_the_bit() {
        let configs = [
            (19, 64, 1, 16, None, Activation::Softplus { beta: 100.0 }, Activation::Identity),
            (19, 64, 2, 16, None, Activation::Softplus { beta: 100.0 }, Activation::Identity),
            (37, 64, 2, 3, None, Activation::Relu, Activation::Sigmoid),
            (5, 32, 4, 7, Some(2), Activation::Softplus { beta: 10.0 }, Activation::Relu),
        ];
        for (n_inputs, width, hidden_layers, n_outputs, skip, hidden_activation, output_activation) in configs {
            let mlp = Mlp::new(MlpConfig { n_inputs, width, hidden_layers, n_outputs, skip, hidden_activation, output_activation });
            let n_params = Module::<f64>::n_params(&mlp);
            let params: Vec<f64> = values(n_params, 7).iter().map(|v| v * 0.3).collect();
            for rows in [1, 5, 47, 48, 49, 101, 200] {
                let input: Vec<f64> = values(rows * n_inputs, rows as u64);
                check(&mlp, &params, &input, rows);
                let (params32, input32): (Vec<f32>, Vec<f32>) =
                    (params.iter().map(|&v| v as f32).collect(), input.iter().map(|&v| v as f32).collect());
                check(&mlp, &params32, &input32, rows);
                // The hidden products in bf16 where the CPU has AVX512_BF16 (else f32 again).
                let mut bf16 = mlp.clone();
                bf16.set_products(crate::Products::Bf16Hidden);
                check(&bf16, &params32, &input32, rows);
            }
        }
    }

    fn check<R: Real>(mlp: &Mlp, params: &[R], input: &[R], rows: usize) {
        let n_y = Module::<R>::n_outputs(mlp);
        let (mut full, mut ctx) = (vec![R::ZERO; rows * n_y], vec![R::ZERO; rows * Module::<R>::ctx_per_row(mlp)]);
        mlp.forward(params, input, &mut full, &mut ctx);
        let mut inferred = vec![R::ZERO; rows * n_y];
        mlp.infer(params, input, &mut inferred);
        let bits = |v: &[R]| v.iter().map(|x| x.to_f64().to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&inferred), bits(&full), "{:?}, {rows} rows: all outputs", mlp.config());
        let mut first = vec![R::ZERO; rows];
        mlp.forward_first(params, input, &mut first);
        let column: Vec<R> = full.chunks_exact(n_y).map(|r| r[0]).collect();
        assert_eq!(bits(&first), bits(&column), "{:?}, {rows} rows: the first output", mlp.config());
    }
}
