//! Forward-mode tangents of an MLP with respect to its input (`Ż = Ȧ Wᵀ`, `Ȧ' = act'(Z) ⊙ Ż`)
//! and the reverse pass through values and tangents together, for analytic normals.

use super::Mlp;
use super::backward::{padded_block, padded_rows, used_columns};
use crate::kernels::{Strided, gemm_in, pad};
use crate::module::{TangentAdjoints, TangentModule};
use crate::real::Real;
use crate::scratch::Buf;

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
    /// Z̄ = act'(Z) ⊙ ȳ + act''(Z) ⊙ Ż ⊙ ū; W̄ += Z̄ᵀA + Ż̄ᵀȦ, b̄ += ΣZ̄; Ā = Z̄W, Ǡ = Ż̄W.
    fn backward_tangent(&self, pass: TangentAdjoints<'_, R>, d_params: &mut [R], d_input: Option<(&mut [R], &mut [R])>) {
        let TangentAdjoints { params, input, ctx, tangent_in, d_output, d_tangent_out } = pass;
        let _span = crate::profile::span(crate::profile::Stage::MlpTangents);
        let rows = input.len() / self.config.n_inputs;
        if rows == 0 {
            return;
        }
        let starts = self.ctx_starts(rows);
        let tangents = self.tangent_pass(params, ctx, rows, 1, tangent_in, None);
        // The output tangent's adjoint is often zero past its first columns (a normal is the
        // SDF output's gradient alone): the last layer's products over those columns are skipped.
        let n_y = self.config.n_outputs;
        let du_used = used_columns(&d_tangent_out[..rows * n_y], n_y);
        let mut d_input = d_input;
        crate::kernels::dispatch(
            #[inline(always)]
            || {
                let (mut dy, mut du) = (padded_rows(d_output, n_y), padded_rows(d_tangent_out, n_y));
                let (mut d_skip, mut d_skip_tangent): (Option<Buf<R>>, Option<Buf<R>>) = (None, None);
                for l in (0..self.layers.len()).rev() {
                    let (n_in, n_out, _) = self.layers[l];
                    let (ip, op) = (pad(n_in), pad(n_out));
                    let (act, _) = self.layer_activation::<R>(l);
                    let a = &ctx[starts[l].0..starts[l].0 + rows * ip];
                    let slope = &ctx[starts[l].1..starts[l].1 + rows * op];
                    let (a_dot, z_dot) = &tangents[l];
                    // Z̄ and Ż̄ in place of ȳ and ū (Ż only where act'' is not zero).
                    if act.is_piecewise_linear() {
                        for i in 0..rows * op {
                            (dy[i], du[i]) = (slope[i] * dy[i], slope[i] * du[i]);
                        }
                    } else {
                        let values = act.second_needs_value().then(|| self.layer_values(params, ctx, &starts, rows, l));
                        for i in 0..rows * op {
                            let second = act.second_derivative(slope[i], values.as_ref().map_or(R::ZERO, |v| v[i]));
                            let (g, u) = (dy[i], du[i]);
                            dy[i] = slope[i] * g + second * z_dot[i] * u;
                            du[i] = slope[i] * u;
                        }
                    }
                    let used = if l + 1 == self.layers.len() { du_used } else { n_out };
                    let mut dw = Buf::<R>::to_overwrite(n_out * ip);
                    let in_bf16 = self.in_bf16(l);
                    gemm_in(in_bf16, &mut dw, ip, Strided { data: &dy, sm: 1, sk: op }, a, ip, n_out, ip, rows, false);
                    gemm_in(in_bf16, &mut dw, ip, Strided { data: &du, sm: 1, sk: op }, a_dot, ip, used, ip, rows, true);
                    self.add_layer_gradient(l, &dw, &dy, d_params);
                    if l == 0 && d_input.is_none() {
                        break;
                    }
                    let wp = self.padded(params, l);
                    let (da, da_dot) = (self.input_adjoint(l, &wp, &dy, rows), self.input_adjoint_of(l, &wp, &du, rows, used));
                    if l == 0 {
                        if let Some((d_in, d_in_tangent)) = d_input.as_mut() {
                            self.write_input_adjoint(&da, d_skip.as_deref(), d_in);
                            self.write_input_adjoint(&da_dot, d_skip_tangent.as_deref(), d_in_tangent);
                        }
                        break;
                    }
                    let (next, skip) = self.previous_adjoint(l, rows, da, d_input.is_some());
                    let (next_u, skip_tangent) = self.previous_adjoint(l, rows, da_dot, d_input.is_some());
                    (d_skip, d_skip_tangent) = (skip.or(d_skip), skip_tangent.or(d_skip_tangent));
                    (dy, du) = (next, next_u);
                }
            },
        );
    }

    /// The reverse pass without the weights' gradients (dA = dZ W layer by layer).
    fn input_gradient(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_input: &mut [R]) {
        self.backward_pass(params, input, ctx, d_output, None, Some(d_input));
    }
}

impl Mlp {
    /// act(Z) of layer `l` (rows × out_pad) for an activation whose second derivative needs it
    /// ([`crate::Activation::second_needs_value`]): the next layer's input block (its first columns,
    /// the skip's 1/√2 undone), or for the output layer act(A Wᵀ + b) recomputed from its input.
    #[inline(always)]
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
    /// tangent of its input (t_rows × in_pad) and of its pre-activation Ż (t_rows × out_pad; empty
    /// for the output layer when `tangents_out` is `None` and its activation piecewise linear);
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
        let mut a_dot = padded_rows(&tangents_in[..t_rows * n_x], n_x);
        let mut tangents_out = tangents_out;
        crate::kernels::dispatch(
            #[inline(always)]
            || {
                for (l, &(n_in, n_out, _)) in self.layers.iter().enumerate() {
                    let (ip, op) = (pad(n_in), pad(n_out));
                    let (act, scale) = self.layer_activation::<R>(l);
                    if l == self.layers.len() - 1 && tangents_out.is_none() && act.is_piecewise_linear() {
                        // Nothing reads the output's Ż: the reverse pass needs it for act'' alone.
                        blocks.push((std::mem::replace(&mut a_dot, Buf::zeroed(0)), Buf::zeroed(0)));
                        break;
                    }
                    let (wt, _) = self.transposed(params, l);
                    // Ż = Ȧ Wᵀ (no bias).
                    let mut z_dot = Buf::<R>::to_overwrite(t_rows * op);
                    gemm_in(self.in_bf16(l), &mut z_dot, op, Strided { data: &a_dot, sm: ip, sk: 1 }, &wt, op, t_rows, op, n_in, false);
                    let slope = &ctx[starts[l].1..starts[l].1 + rows * op];
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
                    let next = padded_block(t_rows, next_ip, |t, dst| {
                        let (sl, z) = (&slope[(t / k) * op..(t / k) * op + op], &z_dot[t * op..t * op + op]);
                        for q in 0..n_out {
                            dst[q] = sl[q] * z[q] * scale;
                        }
                        if self.config.skip != Some(l + 1) {
                            return n_out;
                        }
                        for q in 0..n_x {
                            dst[n_out + q] = tangents_in[t * n_x + q] * inv_sqrt2;
                        }
                        n_out + n_x
                    });
                    blocks.push((std::mem::replace(&mut a_dot, next), z_dot));
                }
            },
        );
        blocks
    }
}
