//! Input encodings without parameters.

use crate::module::{Module, ScatterGradient, ScatterTangent, TangentAdjoints, TangentModule};
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

impl<R: Real> TangentModule<R> for PositionalEncoding {
    /// `[ẋ, f cos(f x) ẋ, −f sin(f x) ẋ, …]`.
    fn forward_tangents(&self, _: &[R], input: &[R], _: &[R], k: usize, tangents_in: &[R], tangents_out: &mut [R]) {
        let n_out = 3 + 6 * self.frequencies;
        for (t, (dx, dy)) in tangents_in.chunks_exact(3).zip(tangents_out.chunks_exact_mut(n_out)).enumerate() {
            let x = &input[3 * (t / k)..3 * (t / k) + 3];
            dy[..3].copy_from_slice(dx);
            let mut f = R::ONE;
            for j in 0..self.frequencies {
                for d in 0..3 {
                    dy[3 + 6 * j + d] = f * (f * x[d]).cos() * dx[d];
                    dy[6 + 6 * j + d] = -f * (f * x[d]).sin() * dx[d];
                }
                f = f + f;
            }
        }
    }
    /// No parameters: only the input's adjoints, when asked for. With ẏ = J(x) ẋ:
    /// x̄ = Jᵀȳ + (∂J/∂x · ẋ)ᵀ ẏ̄ (−f² sin and −f² cos terms), ẋ̄ = Jᵀ ẏ̄.
    fn backward_tangent(&self, pass: TangentAdjoints<'_, R>, _: &mut [R], d_input: Option<(&mut [R], &mut [R])>) {
        let Some((d_in, d_in_tangent)) = d_input else { return };
        let TangentAdjoints { input, tangent_in, d_output, d_tangent_out, .. } = pass;
        let n_out = 3 + 6 * self.frequencies;
        for r in 0..input.len() / 3 {
            let (x, t) = (&input[3 * r..3 * r + 3], &tangent_in[3 * r..3 * r + 3]);
            let (dy, du) = (&d_output[r * n_out..(r + 1) * n_out], &d_tangent_out[r * n_out..(r + 1) * n_out]);
            for d in 0..3 {
                let (mut g, mut gt) = (dy[d], du[d]);
                let mut f = R::ONE;
                for j in 0..self.frequencies {
                    let (s, c) = ((f * x[d]).sin(), (f * x[d]).cos());
                    let (sin_at, cos_at) = (3 + 6 * j + d, 6 + 6 * j + d);
                    g += f * (c * dy[sin_at] - s * dy[cos_at]) - f * f * t[d] * (s * du[sin_at] + c * du[cos_at]);
                    gt += f * (c * du[sin_at] - s * du[cos_at]);
                    f = f + f;
                }
                d_in[3 * r + d] = g;
                d_in_tangent[3 * r + d] = gt;
            }
        }
    }
    /// The reverse pass of [`Module::backward`] (no parameters to add to).
    fn input_gradient(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_input: &mut [R]) {
        self.backward(params, input, ctx, d_output, &mut [], Some(d_input));
    }
}

/// No parameters: no blocks, nothing to scatter.
impl<R: Real> ScatterGradient<R> for PositionalEncoding {
    fn gradient_blocks(&self) -> usize {
        0
    }
    fn gradient_block_range(&self, _: usize) -> std::ops::Range<usize> {
        0..0
    }
    fn backward_parts_block(&self, _: &[(&[R], &[R])], _: usize, _: usize, _: &mut [R]) {}
}

/// No parameters: nothing to scatter.
impl<R: Real> ScatterTangent<R> for PositionalEncoding {
    fn tangent_parts_block(&self, _: &[(&[R], &[R])], _: usize, _: usize, _: &mut [R]) {}
}

/// Real spherical harmonics of a unit direction up to degree 4 (16 outputs, tiny-cuda-nn's
/// "SphericalHarmonics" with degree 4), for the colour network's view direction.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SphericalHarmonics;

/// The 16 real SH basis functions of degree < 4 at (x, y, z), and their partial derivatives.
fn sh16<R: Real>(x: R, y: R, z: R) -> ([R; 16], [[R; 3]; 16]) {
    let c = |v: f64| R::of(v);
    let (xx, yy, zz) = (x * x, y * y, z * z);
    let v = [
        c(0.282_094_791_773_878_14),
        c(-0.488_602_511_902_919_9) * y,
        c(0.488_602_511_902_919_9) * z,
        c(-0.488_602_511_902_919_9) * x,
        c(1.092_548_430_592_079_2) * x * y,
        c(-1.092_548_430_592_079_2) * y * z,
        c(0.946_174_695_757_560_1) * zz - c(0.315_391_565_252_520_05),
        c(-1.092_548_430_592_079_2) * x * z,
        c(0.546_274_215_296_039_6) * (xx - yy),
        c(0.590_043_589_926_643_5) * y * (c(-3.0) * xx + yy),
        c(2.890_611_442_640_554) * x * y * z,
        c(0.457_045_799_464_465_8) * y * (c(1.0) - c(5.0) * zz),
        c(0.373_176_332_590_115_4) * z * (c(5.0) * zz - c(3.0)),
        c(0.457_045_799_464_465_8) * x * (c(1.0) - c(5.0) * zz),
        c(1.445_305_721_320_277) * z * (xx - yy),
        c(0.590_043_589_926_643_5) * x * (-xx + c(3.0) * yy),
    ];
    let z0 = R::ZERO;
    let d = [
        [z0, z0, z0],
        [z0, c(-0.488_602_511_902_919_9), z0],
        [z0, z0, c(0.488_602_511_902_919_9)],
        [c(-0.488_602_511_902_919_9), z0, z0],
        [c(1.092_548_430_592_079_2) * y, c(1.092_548_430_592_079_2) * x, z0],
        [z0, c(-1.092_548_430_592_079_2) * z, c(-1.092_548_430_592_079_2) * y],
        [z0, z0, c(2.0 * 0.946_174_695_757_560_1) * z],
        [c(-1.092_548_430_592_079_2) * z, z0, c(-1.092_548_430_592_079_2) * x],
        [c(2.0 * 0.546_274_215_296_039_6) * x, c(-2.0 * 0.546_274_215_296_039_6) * y, z0],
        [c(0.590_043_589_926_643_5) * c(-6.0) * x * y, c(0.590_043_589_926_643_5) * (c(-3.0) * xx + c(3.0) * yy), z0],
        [c(2.890_611_442_640_554) * y * z, c(2.890_611_442_640_554) * x * z, c(2.890_611_442_640_554) * x * y],
        [z0, c(0.457_045_799_464_465_8) * (c(1.0) - c(5.0) * zz), c(0.457_045_799_464_465_8) * y * c(-10.0) * z],
        [z0, z0, c(0.373_176_332_590_115_4) * (c(15.0) * zz - c(3.0))],
        [c(0.457_045_799_464_465_8) * (c(1.0) - c(5.0) * zz), z0, c(0.457_045_799_464_465_8) * x * c(-10.0) * z],
        [c(1.445_305_721_320_277) * z * c(2.0) * x, c(1.445_305_721_320_277) * z * c(-2.0) * y, c(1.445_305_721_320_277) * (xx - yy)],
        [c(0.590_043_589_926_643_5) * (c(-3.0) * xx + c(3.0) * yy), c(0.590_043_589_926_643_5) * c(6.0) * x * y, z0],
    ];
    (v, d)
}

impl<R: Real> Module<R> for SphericalHarmonics {
    fn n_params(&self) -> usize {
        0
    }
    fn n_inputs(&self) -> usize {
        3
    }
    fn n_outputs(&self) -> usize {
        16
    }
    fn ctx_per_row(&self) -> usize {
        0
    }
    fn forward(&self, _: &[R], input: &[R], output: &mut [R], _: &mut [R]) {
        for (d, y) in input.chunks_exact(3).zip(output.chunks_exact_mut(16)) {
            y.copy_from_slice(&sh16(d[0], d[1], d[2]).0);
        }
    }
    fn backward(&self, _: &[R], input: &[R], _: &[R], d_output: &[R], _: &mut [R], d_input: Option<&mut [R]>) {
        let Some(d_input) = d_input else { return };
        for ((d, dy), dx) in input.chunks_exact(3).zip(d_output.chunks_exact(16)).zip(d_input.chunks_exact_mut(3)) {
            let (_, grad) = sh16(d[0], d[1], d[2]);
            for k in 0..3 {
                dx[k] = (0..16).fold(R::ZERO, |acc, j| acc + dy[j] * grad[j][k]);
            }
        }
    }
}

/// The raw input alongside an encoding: `[x, m(x)]` (NeuS and Neuralangelo feed xyz next to
/// their encodings).
#[derive(Debug, Clone)]
pub struct WithInput<M> {
    /// The encoding.
    pub encoding: M,
}

impl<R: Real, M: Module<R>> Module<R> for WithInput<M> {
    fn n_params(&self) -> usize {
        self.encoding.n_params()
    }
    fn n_inputs(&self) -> usize {
        self.encoding.n_inputs()
    }
    fn n_outputs(&self) -> usize {
        self.encoding.n_inputs() + self.encoding.n_outputs()
    }
    fn ctx_per_row(&self) -> usize {
        self.encoding.ctx_per_row() + self.encoding.n_outputs()
    }
    fn forward(&self, params: &[R], input: &[R], output: &mut [R], ctx: &mut [R]) {
        let rows = input.len() / self.encoding.n_inputs();
        let (enc_ctx, enc_out) = ctx.split_at_mut(rows * self.encoding.ctx_per_row());
        self.encoding.forward(params, input, enc_out, enc_ctx);
        self.join(input, enc_out, output);
    }
    fn backward(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_params: &mut [R], d_input: Option<&mut [R]>) {
        let enc_ctx = &ctx[..input.len() / self.encoding.n_inputs() * self.encoding.ctx_per_row()];
        let d_enc = self.encoding_columns(d_output);
        match d_input {
            Some(d_in) => {
                self.encoding.backward(params, input, enc_ctx, &d_enc, d_params, Some(&mut *d_in));
                self.add_pass_through(d_output, d_in);
            }
            None => self.encoding.backward(params, input, enc_ctx, &d_enc, d_params, None),
        }
    }
}

impl<R: Real, M: ScatterGradient<R>> ScatterGradient<R> for WithInput<M> {
    fn gradient_blocks(&self) -> usize {
        self.encoding.gradient_blocks()
    }
    fn gradient_block_range(&self, block: usize) -> std::ops::Range<usize> {
        self.encoding.gradient_block_range(block)
    }
    /// The encoding's adjoints follow the raw input's in each row: `n_inputs` more to pass by.
    fn backward_parts(&self, parts: &[(&[R], &[R])], lead: usize, d_params: &mut [R]) {
        self.encoding.backward_parts(parts, lead + self.encoding.n_inputs(), d_params);
    }
    fn backward_parts_block(&self, parts: &[(&[R], &[R])], lead: usize, block: usize, d_block: &mut [R]) {
        self.encoding.backward_parts_block(parts, lead + self.encoding.n_inputs(), block, d_block);
    }
}

impl<M> WithInput<M> {
    /// The encoding's columns of output adjoints `d` (rows × (n_in + n_enc)): rows × n_enc.
    fn encoding_columns<R: Real>(&self, d: &[R]) -> crate::scratch::Buf<R>
    where
        M: Module<R>,
    {
        let (n_in, n_enc) = (self.encoding.n_inputs(), self.encoding.n_outputs());
        let n_out = n_in + n_enc;
        let mut e = crate::scratch::Buf::<R>::to_overwrite(d.len() / n_out * n_enc);
        for (dst, src) in e.chunks_exact_mut(n_enc).zip(d.chunks_exact(n_out)) {
            dst.copy_from_slice(&src[n_in..]);
        }
        e
    }

    /// Adds the raw input's columns of output adjoints `d` (rows × (n_in + n_enc)) to the input's
    /// adjoint `d_input` (rows × n_in): the pass-through's share, `x̄ += ȳ[..n_in]`.
    fn add_pass_through<R: Real>(&self, d: &[R], d_input: &mut [R])
    where
        M: Module<R>,
    {
        let n_in = self.encoding.n_inputs();
        for (d_in, dy) in d_input.chunks_exact_mut(n_in).zip(d.chunks_exact(n_in + self.encoding.n_outputs())) {
            for (x, &g) in d_in.iter_mut().zip(&dy[..n_in]) {
                *x += g;
            }
        }
    }

    /// The output rows `[x, m(x)]` from the input and the encoding's rows.
    fn join<R: Real>(&self, input: &[R], encoded: &[R], output: &mut [R])
    where
        M: Module<R>,
    {
        let (n_in, n_enc) = (self.encoding.n_inputs(), self.encoding.n_outputs());
        for ((out, x), e) in output.chunks_exact_mut(n_in + n_enc).zip(input.chunks_exact(n_in)).zip(encoded.chunks_exact(n_enc)) {
            out[..n_in].copy_from_slice(x);
            out[n_in..].copy_from_slice(e);
        }
    }
}

/// The context of [`TangentModule::forward_keeping_tangents`]: the encoding's tangent context,
/// then its outputs.
impl<R: Real, M: TangentModule<R>> TangentModule<R> for WithInput<M> {
    fn tangent_ctx_per_row(&self) -> usize {
        self.encoding.tangent_ctx_per_row() + self.encoding.n_outputs()
    }
    fn forward_keeping_tangents(&self, params: &[R], input: &[R], output: &mut [R], ctx: &mut [R]) {
        let rows = input.len() / self.encoding.n_inputs();
        let (enc_ctx, enc_out) = ctx.split_at_mut(rows * self.encoding.tangent_ctx_per_row());
        self.encoding.forward_keeping_tangents(params, input, enc_out, enc_ctx);
        self.join(input, enc_out, output);
    }
    /// `[ẋ, ∂m/∂x · ẋ]`.
    fn forward_tangents(&self, params: &[R], input: &[R], ctx: &[R], k: usize, tangents_in: &[R], tangents_out: &mut [R]) {
        let (n_in, n_enc) = (self.encoding.n_inputs(), self.encoding.n_outputs());
        let rows = input.len() / n_in;
        let mut enc = crate::scratch::Buf::<R>::to_overwrite(rows * k * n_enc);
        self.encoding.forward_tangents(params, input, &ctx[..rows * self.encoding.tangent_ctx_per_row()], k, tangents_in, &mut enc);
        let n_out = n_in + n_enc;
        for ((out, t), e) in tangents_out.chunks_exact_mut(n_out).zip(tangents_in.chunks_exact(n_in)).zip(enc.chunks_exact(n_enc)) {
            out[..n_in].copy_from_slice(t);
            out[n_in..].copy_from_slice(e);
        }
    }
    fn backward_tangent(&self, pass: TangentAdjoints<'_, R>, d_params: &mut [R], d_input: Option<(&mut [R], &mut [R])>) {
        let TangentAdjoints { params, input, ctx, tangent_in, d_output, d_tangent_out } = pass;
        let (d_enc, d_enc_tangent) = (self.encoding_columns(d_output), self.encoding_columns(d_tangent_out));
        let enc_ctx = &ctx[..input.len() / self.encoding.n_inputs() * self.encoding.tangent_ctx_per_row()];
        let inner = TangentAdjoints { params, input, ctx: enc_ctx, tangent_in, d_output: &d_enc, d_tangent_out: &d_enc_tangent };
        match d_input {
            Some((d_in, d_in_tangent)) => {
                self.encoding.backward_tangent(inner, d_params, Some((&mut *d_in, &mut *d_in_tangent)));
                self.add_pass_through(d_output, d_in);
                self.add_pass_through(d_tangent_out, d_in_tangent);
            }
            None => self.encoding.backward_tangent(inner, d_params, None),
        }
    }
    /// `x̄ = ȳ[..n_in] + (∂m/∂x)ᵀ ȳ[n_in..]`.
    fn input_gradient(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_input: &mut [R]) {
        let enc_ctx = &ctx[..input.len() / self.encoding.n_inputs() * self.encoding.tangent_ctx_per_row()];
        self.encoding.input_gradient(params, input, enc_ctx, &self.encoding_columns(d_output), d_input);
        self.add_pass_through(d_output, d_input);
    }
    fn input_gradient_of_forward(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_input: &mut [R]) {
        let enc_ctx = &ctx[..input.len() / self.encoding.n_inputs() * self.encoding.ctx_per_row()];
        self.encoding.input_gradient_of_forward(params, input, enc_ctx, &self.encoding_columns(d_output), d_input);
        self.add_pass_through(d_output, d_input);
    }
}

impl<R: Real, M: ScatterTangent<R>> ScatterTangent<R> for WithInput<M> {
    /// As [`ScatterGradient::backward_parts_block`]: the raw input's columns passed by in both
    /// halves of each record (output adjoints, then tangent adjoints).
    fn tangent_parts_block(&self, parts: &[(&[R], &[R])], lead: usize, block: usize, d_block: &mut [R]) {
        self.encoding.tangent_parts_block(parts, lead + self.encoding.n_inputs(), block, d_block);
    }
}
