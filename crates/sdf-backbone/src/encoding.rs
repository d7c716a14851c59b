//! Input encodings without parameters.

use crate::module::Module;
use crate::real::Real;

/// NeuS's positional (Fourier) encoding of a 3-vector with L frequencies:
/// `[x, sin(2⁰x), cos(2⁰x), sin(2¹x), cos(2¹x), …, sin(2^{L−1}x), cos(2^{L−1}x)]`
/// (each function applied to the three coordinates; no π, as in NeuS's embedder).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionalEncoding {
    /// Number of frequencies L (NeuS: 6 for the SDF, 4 for view directions).
    pub frequencies: usize,
}

impl<R: Real> Module<R> for PositionalEncoding {
    fn n_params(&self) -> usize {
        0
    }
    fn n_inputs(&self) -> usize {
        3
    }
    fn n_outputs(&self) -> usize {
        3 + 6 * self.frequencies
    }
    fn ctx_per_row(&self) -> usize {
        0
    }
    fn forward(&self, _: &[R], input: &[R], output: &mut [R], _: &mut [R]) {
        let n_out = 3 + 6 * self.frequencies;
        for (x, y) in input.chunks_exact(3).zip(output.chunks_exact_mut(n_out)) {
            y[..3].copy_from_slice(x);
            let mut f = R::ONE;
            for k in 0..self.frequencies {
                for d in 0..3 {
                    y[3 + 6 * k + d] = (f * x[d]).sin();
                    y[6 + 6 * k + d] = (f * x[d]).cos();
                }
                f = f + f;
            }
        }
    }
    fn backward(&self, _: &[R], input: &[R], _: &[R], d_output: &[R], _: &mut [R], d_input: Option<&mut [R]>) {
        let Some(d_input) = d_input else { return };
        let n_out = 3 + 6 * self.frequencies;
        for ((x, dy), dx) in input.chunks_exact(3).zip(d_output.chunks_exact(n_out)).zip(d_input.chunks_exact_mut(3)) {
            dx.copy_from_slice(&dy[..3]);
            let mut f = R::ONE;
            for k in 0..self.frequencies {
                for d in 0..3 {
                    dx[d] += f * (f * x[d]).cos() * dy[3 + 6 * k + d] - f * (f * x[d]).sin() * dy[6 + 6 * k + d];
                }
                f = f + f;
            }
        }
    }
}
