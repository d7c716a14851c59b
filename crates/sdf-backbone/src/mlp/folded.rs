//! A network's first layer with some of its input columns held fixed over a batch of rows: their
//! products are the same on every row, so they fold into the layer's bias once and the rows carry
//! the other columns alone. A render's learned background is the user: its sample k's inverse
//! radius and that value's sines (1 + 2L columns of the encoding's 4 + 8L) are the same on every
//! ray, so a quarter of each row's first-layer products had been spent on constants.
//!
//! The outputs are the forward pass's up to the order of the first layer's sum (the fixed
//! columns' products added to the bias in f64 before the rows', not in their place among them):
//! a few units in the last place of f32, not the same bits.

use super::{Mlp, PackedLayer};
use crate::kernels::{Dense, pad};
use crate::real::Real;
use crate::scratch::Buf;

/// [`Mlp::fold_first`]: the first layer's Wᵀ split into the rows of the columns the batch
/// carries and those of the fixed ones.
pub(crate) struct FoldedFirst<R: Real> {
    /// Wᵀ's rows of the columns the rows carry, in their order (kept × `pad(n_out)`).
    kept: Buf<R>,
    /// Wᵀ's rows of the fixed columns, in their order (fixed × `pad(n_out)`).
    fixed: Buf<R>,
    /// The layer's own bias (`pad(n_out)`).
    bias: Buf<R>,
}

/// The first layer's operands for [`Mlp::infer_rows`]: Wᵀ (`n_in` × `pad(n_out)`), the bias
/// and the inputs per row.
pub(super) struct FirstLayer<'a, R> {
    wt: &'a [R],
    bias: &'a [R],
    pub(super) n_in: usize,
}

impl<R: Real> FirstLayer<'_, R> {
    /// The layer on the input rows `a` (row stride `pad(n_in)`), with the network's first
    /// layer's activation.
    pub(super) fn dense<'b>(&'b self, mlp: &Mlp, a: &'b [R]) -> Dense<'b, R> {
        let (act, scale) = mlp.layer_activation::<R>(0);
        let n_out_pad = pad(mlp.layers[0].1);
        Dense { a, a_s: pad(self.n_in), n_in: self.n_in, wt: self.wt, bias: self.bias, n_out_pad, act, scale, pairs: None }
    }
}

impl<R: Real> FoldedFirst<R> {
    /// The columns the rows carry.
    pub(crate) fn n_kept(&self) -> usize {
        self.kept.len() / self.bias.len()
    }

    /// The first layer's bias with the fixed columns at `values` (one per fixed column, in their
    /// order): `b + Σ_c v_c W_c`, summed in f64 and rounded once.
    pub(crate) fn bias_at(&self, values: &[R]) -> Buf<R> {
        let width = self.bias.len();
        assert_eq!(values.len() * width, self.fixed.len(), "one value per fixed column");
        let mut bias = Buf::<R>::to_overwrite(width);
        for (o, b) in bias.iter_mut().enumerate() {
            let folded = values.iter().zip(self.fixed.chunks_exact(width)).map(|(v, w)| v.to_f64() * w[o].to_f64()).sum::<f64>();
            *b = R::of(self.bias[o].to_f64() + folded);
        }
        bias
    }
}

impl Mlp {
    /// The first layer of `packed` ([`Self::packed_layers`]) with the input columns `fixed`
    /// (ascending) held fixed, for [`Self::infer_folded`].
    ///
    /// # Panics
    /// Where `fixed` is not ascending within the inputs, or the network has a skip layer (which
    /// reads the whole input row again).
    pub(crate) fn fold_first<R: Real>(&self, packed: &[PackedLayer<R>], fixed: &[usize]) -> FoldedFirst<R> {
        let (n_in, n_out, _) = self.layers[0];
        assert!(self.config.skip.is_none(), "a folded first layer: the skip layer would read the whole input row");
        assert!(fixed.windows(2).all(|w| w[0] < w[1]) && fixed.last().is_none_or(|&c| c < n_in), "fixed columns ascending, within {n_in}");
        let width = pad(n_out);
        let rows_of = |columns: &mut dyn Iterator<Item = usize>| -> Buf<R> {
            let columns: Vec<usize> = columns.collect();
            let mut out = Buf::<R>::to_overwrite(columns.len() * width);
            for (dst, &c) in out.chunks_exact_mut(width).zip(&columns) {
                dst.copy_from_slice(&packed[0].wt[c * width..(c + 1) * width]);
            }
            out
        };
        let kept = rows_of(&mut (0..n_in).filter(|c| fixed.binary_search(c).is_err()));
        let fixed_rows = rows_of(&mut fixed.iter().copied());
        let mut bias = Buf::<R>::to_overwrite(width);
        bias.copy_from_slice(&packed[0].bias);
        FoldedFirst { kept, fixed: fixed_rows, bias }
    }

    /// The first `keep` outputs of every row of `input` (rows of the columns `first` keeps, in
    /// order) with the fixed columns' values folded into `bias` ([`FoldedFirst::bias_at`]), the
    /// other layers `packed` ([`Self::packed_layers`]).
    pub(crate) fn infer_folded<R: Real>(
        &self,
        first: &FoldedFirst<R>,
        bias: &[R],
        packed: &[PackedLayer<R>],
        input: &[R],
        output: &mut [R],
        keep: usize,
    ) {
        self.check_inference(first.n_kept(), input, output, keep);
        assert_eq!(bias.len(), first.bias.len(), "the folded bias: one value per padded output");
        let layer = FirstLayer { wt: &first.kept, bias, n_in: first.n_kept() };
        self.infer_rows(Some(layer), packed, input, output, keep);
    }
}

#[cfg(test)]
mod tests {
    use crate::mlp::{Mlp, MlpConfig};
    use crate::module::{Activation, Module};
    use crate::real::Real;

    /// The largest difference, relative to 1 + |expected|, between the folded pass's outputs and
    /// the forward pass's of the whole rows (`whole`: rows of 21, `fixed` their fixed columns).
    fn folded_against_whole<R: Real>(mlp: &Mlp, params: &[R], whole: &[f64], fixed: &[usize]) -> f64 {
        let n = 21;
        let (whole, rows): (Vec<R>, usize) = (whole.iter().map(|&v| R::of(v)).collect(), whole.len() / n);
        let kept: Vec<R> = whole.iter().enumerate().filter(|(i, _)| !fixed.contains(&(i % n))).map(|(_, &v)| v).collect();
        let values: Vec<R> = fixed.iter().map(|&c| whole[c]).collect();
        let mut expected = vec![R::ZERO; rows * 4];
        mlp.infer(params, &whole, &mut expected);
        let packed = mlp.packed_layers(params);
        let first = mlp.fold_first(&packed, fixed);
        let mut got = vec![R::ZERO; rows * 4];
        mlp.infer_folded(&first, &first.bias_at(&values), &packed, &kept, &mut got, 4);
        got.iter().zip(&expected).map(|(a, b)| (a.to_f64() - b.to_f64()).abs() / (1.0 + b.to_f64().abs())).fold(0.0, f64::max)
    }

    /// Guards the folding: the outputs with some columns fixed and folded into the bias are the
    /// forward pass's of the whole rows (f64 to 1e-12; f32 to a few units in the last place, the
    /// fixed products summed in another order), for fixed columns at the start, in the middle
    /// and at the end, none and all but one.
    #[test]
    fn a_folded_first_layer_gives_the_whole_rows_outputs() {
        let mlp = Mlp::new(MlpConfig {
            n_inputs: 21,
            width: 64,
            hidden_layers: 2,
            n_outputs: 4,
            skip: None,
            hidden_activation: Activation::Relu,
            output_activation: Activation::Identity,
        });
        let mut params32 = vec![0.0f32; Module::<f32>::n_params(&mlp)];
        mlp.init_default(&mut params32, 3);
        let params: Vec<f64> = params32.iter().map(|&v| f64::from(v)).collect();
        let value = |i: usize| ((i * 37 % 101) as f64 / 50.0 - 1.0) * 0.9;
        for fixed in [vec![], vec![0, 1], vec![3, 7, 11, 15, 19], vec![20], (1..21).collect::<Vec<_>>()] {
            // 101 rows, the fixed columns the same on each.
            let whole: Vec<f64> = (0..101 * 21).map(|i| if fixed.contains(&(i % 21)) { value(1000 + i % 21) } else { value(i) }).collect();
            let worst = folded_against_whole(&mlp, &params, &whole, &fixed);
            assert!(worst <= 1e-12, "f64, fixed {fixed:?}: off by {worst:e}");
            let worst = folded_against_whole(&mlp, &params32, &whole, &fixed);
            assert!(worst <= 2e-6, "f32, fixed {fixed:?}: off by {worst:e}");
        }
    }
}
