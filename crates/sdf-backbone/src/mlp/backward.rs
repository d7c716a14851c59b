//! The reverse pass of an MLP, layer by layer from the output, and the pieces it shares with the
//! reverse pass through tangents (`tangents.rs`): the padded output adjoint, the layer's
//! parameter gradient, the input adjoint dA = dZ W and its split at the skip connection. They
//! run inside [`crate::kernels::dispatch`]: `#[inline(always)]`, so that they are compiled with
//! the caller's vector instructions (a function that is not inlined gets the baseline's: 8×
//! slower measured, `calibrated_init` test).

use super::Mlp;
use crate::kernels::{Strided, gemm_in, pad};
use crate::real::Real;
use crate::scratch::Buf;

impl Mlp {
    /// [`crate::Module::backward`]: dZ = dY ⊙ act'(Z), dW += dZᵀA, db += ΣdZ, dA = dZ W; without
    /// `d_params` (the input's adjoint alone) no dW.
    pub(super) fn backward_pass<R: Real>(
        &self,
        params: &[R],
        input: &[R],
        ctx: &[R],
        d_output: &[R],
        d_params: Option<&mut [R]>,
        d_input: Option<&mut [R]>,
    ) {
        let _span = crate::profile::span(crate::profile::Stage::MlpBackward);
        let rows = input.len() / self.config.n_inputs;
        if rows == 0 {
            return;
        }
        let starts = self.ctx_starts(rows);
        let (mut d_params, mut d_input) = (d_params, d_input);
        crate::kernels::dispatch(
            #[inline(always)]
            || {
                let mut dy = padded_rows(d_output, self.config.n_outputs);
                // The output adjoint's columns past the last nonzero one (a normal's reverse pass
                // starts from the SDF output alone) are left out of the last layer's products.
                let mut used = used_columns(d_output, self.config.n_outputs);
                let mut d_skip: Option<Buf<R>> = None;
                for l in (0..self.layers.len()).rev() {
                    let (n_in, n_out, _) = self.layers[l];
                    let (ip, op) = (pad(n_in), pad(n_out));
                    let a = &ctx[starts[l].0..starts[l].0 + rows * ip];
                    let slope = &ctx[starts[l].1..starts[l].1 + rows * op];
                    // dZ = dY ⊙ act'(Z), in place.
                    for (g, s) in dy.iter_mut().zip(slope) {
                        *g *= *s;
                    }
                    if let Some(d_params) = d_params.as_deref_mut() {
                        let mut dw = Buf::<R>::to_overwrite(n_out * ip);
                        gemm_in(self.in_bf16(l), &mut dw, ip, Strided { data: &dy, sm: 1, sk: op }, a, ip, n_out, ip, rows, false);
                        self.add_layer_gradient(l, &dw, &dy, d_params);
                    }
                    if l == 0 && d_input.is_none() {
                        break;
                    }
                    let wp = self.padded(params, l);
                    let da = self.input_adjoint_of(l, &wp, &dy, rows, used);
                    used = usize::MAX;
                    if l == 0 {
                        if let Some(d_in) = d_input.as_deref_mut() {
                            self.write_input_adjoint(&da, d_skip.as_deref(), d_in);
                        }
                        break;
                    }
                    let (next, skip) = self.previous_adjoint(l, rows, da, d_input.is_some());
                    d_skip = skip.or(d_skip);
                    dy = next;
                }
            },
        );
    }

    /// Adds layer `l`'s parameter gradient: its weights' from `dw` (n_out × in_pad: dZᵀA, and
    /// for tangents + ŻᵀȦ) and its bias' Σ over the rows of `dz` (rows × out_pad).
    #[inline(always)]
    pub(super) fn add_layer_gradient<R: Real>(&self, l: usize, dw: &[R], dz: &[R], d_params: &mut [R]) {
        let (n_in, n_out, off) = self.layers[l];
        let (ip, op) = (pad(n_in), pad(n_out));
        let (dwp, dbp) = d_params[off..off + n_in * n_out + n_out].split_at_mut(n_in * n_out);
        for o in 0..n_out {
            for i in 0..n_in {
                dwp[o * n_in + i] += dw[o * ip + i];
            }
        }
        let mut db = vec![R::ZERO; op];
        for row in dz.chunks_exact(op) {
            for (b, g) in db.iter_mut().zip(row) {
                *b += *g;
            }
        }
        for (b, g) in dbp.iter_mut().zip(&db) {
            *b += *g;
        }
    }

    /// dA = dZ W of layer `l` (rows × in_pad), `wp` its padded weights ([`Mlp::padded`]).
    #[inline(always)]
    pub(super) fn input_adjoint<R: Real>(&self, l: usize, wp: &[R], dz: &[R], rows: usize) -> Buf<R> {
        self.input_adjoint_of(l, wp, dz, rows, self.layers[l].1)
    }

    /// [`Mlp::input_adjoint`] of a `dz` whose columns from `used` on are zero in every row: the
    /// product over its first `used` columns alone.
    #[inline(always)]
    pub(super) fn input_adjoint_of<R: Real>(&self, l: usize, wp: &[R], dz: &[R], rows: usize, used: usize) -> Buf<R> {
        let (n_in, n_out, _) = self.layers[l];
        let (ip, op) = (pad(n_in), pad(n_out));
        let mut da = Buf::<R>::to_overwrite(rows * ip);
        gemm_in(self.in_bf16(l), &mut da, ip, Strided { data: dz, sm: op, sk: 1 }, wp, ip, rows, ip, used.min(n_out), false);
        da
    }

    /// Layer `l`'s (≥ 1) input adjoint `da` split into the previous layer's output adjoint (rows
    /// × its out_pad; × 1/√2 at the skip layer) and, at the skip layer when `skip_share`, the raw
    /// input's share of the concatenation (rows × n_inputs, × 1/√2), added at layer 0. Away from
    /// the skip layer `da` is that adjoint as it is (its padding columns are products with the
    /// weights' zero padding): no copy.
    #[inline(always)]
    pub(super) fn previous_adjoint<R: Real>(&self, l: usize, rows: usize, da: Buf<R>, skip_share: bool) -> (Buf<R>, Option<Buf<R>>) {
        let (n_x, ip) = (self.config.n_inputs, pad(self.layers[l].0));
        let prev_out = self.layers[l - 1].1;
        let prev_op = pad(prev_out);
        let skip = self.config.skip == Some(l);
        if !skip {
            debug_assert_eq!(ip, prev_op, "a layer's input is the previous layer's output");
            return (da, None);
        }
        let inv_sqrt2 = R::of(std::f64::consts::FRAC_1_SQRT_2);
        let share = skip_share.then(|| {
            let mut g = Buf::<R>::to_overwrite(rows * n_x);
            for (dst, src) in g.chunks_exact_mut(n_x).zip(da.chunks_exact(ip)) {
                for k in 0..n_x {
                    dst[k] = src[prev_out + k] * inv_sqrt2;
                }
            }
            g
        });
        let next = padded_block(rows, prev_op, |r, dst| {
            let src = &da[r * ip..r * ip + prev_out];
            for k in 0..prev_out {
                dst[k] = src[k] * inv_sqrt2;
            }
            prev_out
        });
        (next, share)
    }

    /// The network input's adjoint into `d_in` (rows × n_inputs): layer 0's input adjoint `da`
    /// plus the skip's share.
    #[inline(always)]
    pub(super) fn write_input_adjoint<R: Real>(&self, da: &[R], skip: Option<&[R]>, d_in: &mut [R]) {
        let (n_x, ip) = (self.config.n_inputs, pad(self.layers[0].0));
        for (r, (dst, src)) in d_in.chunks_exact_mut(n_x).zip(da.chunks_exact(ip)).enumerate() {
            dst.copy_from_slice(&src[..n_x]);
            if let Some(skip) = skip {
                for k in 0..n_x {
                    dst[k] += skip[r * n_x + k];
                }
            }
        }
    }
}

/// How many of the first columns of `d` (rows × n) hold a nonzero value in some row: the columns
/// after them are zero in every row.
#[inline(always)]
pub(super) fn used_columns<R: Real>(d: &[R], n: usize) -> usize {
    d.chunks_exact(n).fold(0, |used, row| row.iter().rposition(|&v| v != R::ZERO).map_or(used, |q| used.max(q + 1)))
}

/// `src` (rows × n) as rows × pad(n), zero-padded.
#[inline(always)]
pub(super) fn padded_rows<R: Real>(src: &[R], n: usize) -> Buf<R> {
    padded_block(src.len() / n, pad(n), |r, dst| {
        dst[..n].copy_from_slice(&src[r * n..r * n + n]);
        n
    })
}

/// A block of `rows` × `stride` values written once, without zeroing it first: `write(r, row)`
/// fills row r's first columns and returns how many; the rest of the row (its padding, zero in
/// every padded block) is zeroed here. Zeroing whole blocks that were then overwritten cost a
/// training step 7 % on the Xeon (BENCHMARKS.md, "Where a step's time goes").
#[inline(always)]
pub(super) fn padded_block<R: Real>(rows: usize, stride: usize, mut write: impl FnMut(usize, &mut [R]) -> usize) -> Buf<R> {
    let mut out = Buf::<R>::to_overwrite(rows * stride);
    for (r, row) in out.chunks_exact_mut(stride).enumerate() {
        let written = write(r, row);
        row[written..].fill(R::ZERO);
    }
    out
}
