//! A render's learned background: forward only, front to back in blocks of samples, each ray
//! stopped where what lies behind is negligible; the network's layers packed once, and its first
//! layer folded per sample — sample k's 1/r and that value's sines are the same on every ray
//! (1 + 2L of the 4 + 8L encoding's columns), so their products are added to the bias once per
//! sample (`Mlp::fold_first`, `mlp/folded.rs`) and a row carries the point's columns alone.

use super::BackgroundModel;
use super::rows::{Layout, SampleRows};
use crate::real::Real;

/// Samples a render evaluates at once per ray ([`BackgroundModel::render`]): after each block,
/// the rays whose transmittance has fallen to their budget stop.
pub const RENDER_BLOCK: usize = 4;

impl BackgroundModel {
    /// The background colour of each ray as [`Self::forward`] gives it, forward only (no
    /// context kept), front to back in blocks of [`RENDER_BLOCK`] samples: a ray is evaluated no
    /// further once the transmittance past its evaluated samples is at most `budgets[r]`, the
    /// rest of its colour (at most that, per channel) dropped. A ray's samples behind an opaque
    /// backdrop carry nothing, so a render need not evaluate them; with budgets 0 nothing is
    /// dropped and the colours are [`Self::forward`]'s (rows of the network are independent) but
    /// for rounding: the encoding's sines by their series (`sines::double_angles_of_all`) and
    /// the first layer's sum in another order (the folded columns first). Returns the colours
    /// and the samples evaluated.
    pub fn render<R: Real>(&self, params: &[R], origins: &[[R; 3]], directions: &[[R; 3]], sh: &[[R; 16]], budgets: &[R]) -> (Vec<[R; 3]>, usize) {
        let _span = crate::profile::span(crate::profile::Stage::Background);
        let k_n = self.samples;
        let mut colors = vec![[R::ZERO; 3]; origins.len()];
        let mut transmittance = vec![R::ONE; origins.len()];
        let mut active: Vec<usize> = (0..origins.len()).collect();
        let mut evaluated = 0;
        if origins.is_empty() {
            return (colors, evaluated);
        }
        let (p_net, p_grid) = params.split_at(self.tables().start);
        let packed = self.net.packed_layers(p_net);
        let first = self.net.fold_first(&packed, &self.folded_columns());
        let inv_r_sines = self.inverse_radius_sines::<R>();
        // Sample k's first-layer bias.
        let biases: Vec<_> = (0..k_n).map(|k| first.bias_at(&self.folded_values(k, &inv_r_sines))).collect();
        for start in (0..k_n).step_by(RENDER_BLOCK) {
            let block = start..(start + RENDER_BLOCK).min(k_n);
            let n_active = active.len();
            // Sample-major: a block's rows of one sample, one per active ray, share its bias.
            let which = |i: usize| (active[i % n_active], start + i / n_active);
            let rows_n = n_active * block.len();
            let SampleRows { input, depths, .. } = self.sample_rows(Layout::Folded, p_grid, (origins, directions, sh), &inv_r_sines, rows_n, which);
            let mut raw = crate::scratch::Buf::<R>::to_overwrite(rows_n * 4);
            let width = first.n_kept();
            for (b, k) in block.clone().enumerate() {
                let rows = b * n_active..(b + 1) * n_active;
                let (input, raw) = (&input[rows.start * width..rows.end * width], &mut raw[rows.start * 4..rows.end * 4]);
                self.net.infer_folded(&first, &biases[k], &packed, input, raw, 4);
            }
            evaluated += rows_n;
            // The next sample's depth after the block's last, on each active ray.
            let after: Vec<R> =
                active.iter().map(|&r| if block.end < k_n { self.sample_depth(origins[r], directions[r], block.end).1 } else { R::ZERO }).collect();
            let mut light: Vec<R> = active.iter().map(|&r| transmittance[r]).collect();
            let painted = composite_block(&raw, &depths, &after, (block.clone(), k_n), &mut light);
            for (a, &r) in active.iter().enumerate() {
                transmittance[r] = light[a];
                for j in 0..3 {
                    colors[r][j] += painted[a][j];
                }
            }
            active.retain(|&r| transmittance[r] > budgets[r]);
            if active.is_empty() {
                break;
            }
        }
        (colors, evaluated)
    }
}

/// The colour a block of samples (`block` of `k_n`) adds to each of its rays, front to back,
/// each ray's transmittance `light` carried through: `raw` and `depths` the block's rows,
/// sample-major (one per ray of `light`, in its order), `after` each ray's depth of the sample
/// after the block (unread where the block ends the ray). Compiled for the CPU's instruction
/// set: a sample's rows in vector lanes, the softplus, sigmoids and exponential by polynomials in
/// f32 ([`shade`]).
fn composite_block<R: Real>(raw: &[R], depths: &[R], after: &[R], (block, k_n): (std::ops::Range<usize>, usize), light: &mut [R]) -> Vec<[R; 3]> {
    let n = light.len();
    let mut painted = vec![[R::ZERO; 3]; n];
    crate::kernels::dispatch(
        #[inline(always)]
        || {
            for (b, k) in block.clone().enumerate() {
                let (rows, last) = (b * n..(b + 1) * n, k + 1 == k_n);
                let next = if b + 1 < block.len() { &depths[rows.end..rows.end + n] } else { after };
                let (depths, raw) = (&depths[rows.clone()], &raw[4 * rows.start..4 * rows.end]);
                for a in 0..n {
                    let (c, alpha) = shade(&raw[4 * a..4 * a + 4], (!last).then(|| next[a] - depths[a]));
                    let w = light[a] * alpha;
                    for j in 0..3 {
                        painted[a][j] += w * c[j];
                    }
                    light[a] *= R::ONE - alpha;
                }
            }
        },
    );
    painted
}

/// A sample's colour (the sigmoid of raw outputs 1–3) and opacity over `delta` to the next sample
/// (`None`: the last, which takes all the transmittance left), as [`super::Sample::of`] gives
/// them up to rounding: in f32 by polynomials and selects alone (the sigmoid as the softplus's
/// slope, `1 − e^{−σδ}` by [`Real::exp_nonpositive`]), so that a loop over samples vectorises.
#[inline(always)]
fn shade<R: Real>(raw: &[R], delta: Option<R>) -> ([R; 3], R) {
    // Written out, not by an array's `map`, which was not inlined into the dispatched loop (its
    // softplus then called the C library's `fmaf`).
    let sigma = raw[0].softplus_with_derivative(R::ONE).0;
    let sigmoid = |z: R| z.softplus_with_derivative(R::ONE).1;
    let c = [sigmoid(raw[1]), sigmoid(raw[2]), sigmoid(raw[3])];
    let alpha = match delta {
        Some(delta) => R::ONE - (-(sigma * delta)).exp_nonpositive(),
        None => R::ONE,
    };
    (c, alpha)
}
