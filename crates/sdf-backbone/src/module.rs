//! Differentiable modules over flat parameter slices (tiny-cuda-nn's shape).
//!
//! A module owns no parameters: `forward(params, input) → output` saves what its backward needs
//! in a caller-owned context, and `backward(params, input, ctx, d_output)` *adds* into
//! `d_params` and (optionally) writes `d_input`. Batches are row-major: `input[row · n_inputs + i]`.

use crate::real::Real;
use crate::scratch::Buf;

/// What a reverse pass through the outputs and their tangents reads ([`TangentModule::backward_tangent`]):
/// the forward pass's parameters, inputs and context, the input's tangent (one direction per
/// row) and the adjoints of the outputs and of their tangents.
#[derive(Debug, Clone, Copy)]
pub struct TangentAdjoints<'a, R> {
    /// Parameters.
    pub params: &'a [R],
    /// Inputs, rows × n_inputs.
    pub input: &'a [R],
    /// The context of [`TangentModule::forward_keeping_tangents`].
    pub ctx: &'a [R],
    /// The input's tangent, rows × n_inputs.
    pub tangent_in: &'a [R],
    /// ∂L/∂y, rows × n_outputs.
    pub d_output: &'a [R],
    /// ∂L/∂ẏ, rows × n_outputs.
    pub d_tangent_out: &'a [R],
}

/// A differentiable map from `n_inputs` to `n_outputs` values per batch row: what every module
/// has. What only some have is an extension trait: [`ScatterGradient`] (a parameter gradient
/// that can be computed later, block by block), [`TangentModule`] (forward-mode derivatives
/// along the input, for analytic normals), and for networks that put the two together
/// [`DeferringModule`] and [`DeferringTangentModule`]. A call a module cannot answer does not
/// compile.
pub trait Module<R: Real>: Sync {
    /// Number of parameters.
    fn n_params(&self) -> usize;
    /// Inputs per row.
    fn n_inputs(&self) -> usize;
    /// Outputs per row.
    fn n_outputs(&self) -> usize;
    /// Context values saved per row by `forward` for `backward`.
    fn ctx_per_row(&self) -> usize;
    /// Forward pass for a batch; `ctx` has `rows · ctx_per_row()` values. Writes every value of
    /// `output` and `ctx` (callers pass buffers with stale values: [`crate::scratch::Buf::to_overwrite`]).
    fn forward(&self, params: &[R], input: &[R], output: &mut [R], ctx: &mut [R]);
    /// The first output alone (an SDF network's value) of every row, into `first` (one value a
    /// row): an SDF network's value alone (an up-sampling's, which the presets' backbone computes
    /// with its MLP packed once: `Backbone::sdf_rows`). By default [`Module::forward`]'s first column; an MLP
    /// computes it with no context ([`Module::infer`]'s pass, its first column kept), to the bit.
    fn forward_first(&self, params: &[R], input: &[R], first: &mut [R]) {
        let (rows, n_out) = (first.len(), self.n_outputs());
        let mut output = crate::scratch::Buf::<R>::to_overwrite(rows * n_out);
        let mut ctx = crate::scratch::Buf::<R>::to_overwrite(rows * self.ctx_per_row());
        self.forward(params, input, &mut output, &mut ctx);
        for (f, row) in first.iter_mut().zip(output.chunks_exact(n_out)) {
            *f = row[0];
        }
    }
    /// Every output of every row as [`Module::forward`] writes them, with no backward pass after
    /// it (a render): by default through a context that is dropped; an MLP keeps none.
    fn infer(&self, params: &[R], input: &[R], output: &mut [R]) {
        let rows = input.len() / self.n_inputs().max(1);
        let mut ctx = crate::scratch::Buf::<R>::to_overwrite(rows * self.ctx_per_row());
        self.forward(params, input, output, &mut ctx);
    }
    /// Backward pass: adds ∂L/∂params into `d_params`, writes ∂L/∂input (every value) into
    /// `d_input` if given.
    fn backward(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_params: &mut [R], d_input: Option<&mut [R]>);
}

/// A module whose parameter gradient is a function of (input, ∂L/∂output) alone, without a
/// context or the parameter values (a hash grid: a scatter into large tables, better done once
/// per batch in order than per work item into a private copy), in independent blocks of its
/// parameters (a hash grid's levels). Encodings without parameters have it trivially.
pub trait ScatterGradient<R: Real>: Module<R> {
    /// Independent blocks of the parameters.
    fn gradient_blocks(&self) -> usize;

    /// The parameters of block `block` (< [`ScatterGradient::gradient_blocks`]): the blocks are
    /// contiguous and in order, and may differ in size (a hash grid's dense coarse levels are
    /// smaller than its hashed ones).
    fn gradient_block_range(&self, block: usize) -> std::ops::Range<usize>;

    /// Adds block `block` of the parameter gradient of several work items, `parts` = (input,
    /// d_output) each, in order, to `d_block` (that block's gradient; so blocks can be done in
    /// parallel, or one at a time into a small buffer). Each row of a `d_output` holds `lead`
    /// values before this module's outputs' adjoints (rows of `lead` + n_outputs: a
    /// [`crate::encoding::WithInput`]'s raw input columns), which are not read: a record of a
    /// wider module's input adjoints is read where it lies, not copied once per block.
    fn backward_parts_block(&self, parts: &[(&[R], &[R])], lead: usize, block: usize, d_block: &mut [R]);

    /// Every block of [`ScatterGradient::backward_parts_block`] into `d_params`, in parallel over
    /// blocks: the same bits for any thread count.
    fn backward_parts(&self, parts: &[(&[R], &[R])], lead: usize, d_params: &mut [R]) {
        use rayon::prelude::*;
        let blocks = split_blocks(d_params, (0..self.gradient_blocks()).map(|b| self.gradient_block_range(b)));
        blocks.into_par_iter().enumerate().for_each(|(block, d)| self.backward_parts_block(parts, lead, block, d));
    }
}

/// Forward-mode derivatives with respect to the input (analytic normals ∇ₓS), and the reverse
/// pass through them.
pub trait TangentModule<R: Real>: Module<R> {
    /// Context values per row that [`TangentModule::forward_keeping_tangents`] writes (the
    /// forward's own, [`Module::ctx_per_row`], unless the module keeps more for its tangents).
    fn tangent_ctx_per_row(&self) -> usize {
        self.ctx_per_row()
    }

    /// [`Module::forward`], keeping in `ctx` (rows × [`TangentModule::tangent_ctx_per_row`])
    /// what this module's tangent passes read: every other method of this trait takes the `ctx`
    /// of this call. A hash grid keeps its features' Jacobian (§46), which its corners give in
    /// the forward's one visit; a module without such a store forwards as [`Module::forward`].
    fn forward_keeping_tangents(&self, params: &[R], input: &[R], output: &mut [R], ctx: &mut [R]) {
        self.forward(params, input, output, ctx);
    }

    /// After [`TangentModule::forward_keeping_tangents`] (with its `ctx`): the outputs' derivatives along `k` input
    /// directions per row. `tangents_in` is rows × k × n_inputs (direction j of row r at
    /// `(r·k + j)·n_inputs`), `tangents_out` rows × k × n_outputs, every value written.
    fn forward_tangents(&self, params: &[R], input: &[R], ctx: &[R], k: usize, tangents_in: &[R], tangents_out: &mut [R]);

    /// The reverse pass through the outputs y and their derivative ẏ along one input direction
    /// per row (`tangent_in`, rows × n_inputs): adds ∂L/∂params for a loss with adjoints
    /// `d_output` (of y) and `d_tangent_out` (of ẏ), both rows × n_outputs; writes the adjoints
    /// of the input and of its tangent into `d_input` when given (encodings that come first in
    /// a network need not: the pipeline's inputs are not learnt).
    fn backward_tangent(&self, pass: TangentAdjoints<'_, R>, d_params: &mut [R], d_input: Option<(&mut [R], &mut [R])>);

    /// After [`TangentModule::forward_keeping_tangents`] (with its `ctx`): the input's adjoint `d_input` (rows ×
    /// n_inputs, written) for the outputs' adjoints `d_output` (rows × n_outputs), and no
    /// parameter gradient. The gradient of one output (a render's analytic normal ∇ₓS) is one
    /// such reverse pass, where [`TangentModule::forward_tangents`] takes one forward pass per
    /// input direction.
    fn input_gradient(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_input: &mut [R]);

    /// [`TangentModule::input_gradient`] after [`Module::forward`] (with its `ctx`): what
    /// [`TangentModule::forward_keeping_tangents`] would have kept is found again, which costs
    /// less where the tangents serve once (a render's normal) and the store costs a pass of its
    /// own (a hash grid's Jacobian). The default reads `ctx` as the tangents' context: modules
    /// that keep more for their tangents, and those that hold one, override it.
    fn input_gradient_of_forward(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_input: &mut [R]) {
        self.input_gradient(params, input, ctx, d_output, d_input);
    }
}

/// A [`ScatterGradient`] module with tangents: the scatter of the reverse pass through values
/// and tangents.
pub trait ScatterTangent<R: Real>: ScatterGradient<R> + TangentModule<R> {
    /// The tangent counterpart of [`ScatterGradient::backward_parts_block`]: `parts` =
    /// ([inputs block; input tangents block], [output adjoints block; output-tangent adjoints
    /// block]) per work item, `lead` as there.
    fn tangent_parts_block(&self, parts: &[(&[R], &[R])], lead: usize, block: usize, d_block: &mut [R]);
}

/// A network whose leading parameters' gradient can be left out of its backward pass and
/// computed later from a per-row record (an encoding with a [`ScatterGradient`] first: the
/// pipeline's SDF network).
pub trait DeferringModule<R: Real>: Module<R> {
    /// Leading parameters whose gradient [`DeferringModule::backward_deferring`] leaves out
    /// (0: nothing deferred).
    fn deferred_params(&self) -> usize;

    /// Values per row that [`DeferringModule::backward_deferring`] records.
    fn deferred_width(&self) -> usize;

    /// [`Module::backward`] without the gradient of the first
    /// [`DeferringModule::deferred_params`] parameters: `d_params` covers the parameters after
    /// them, and what their gradient needs is written to `deferred` (rows ×
    /// [`DeferringModule::deferred_width`]).
    fn backward_deferring(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_params: &mut [R], deferred: &mut [R]);

    /// Adds the deferred gradients of several work items, `parts` = (input, deferred record) in
    /// order, to `d_deferred` (the first [`DeferringModule::deferred_params`] parameters'
    /// gradient).
    fn apply_deferred(&self, parts: &[(&[R], &[R])], d_deferred: &mut [R]);

    /// Blocks of the deferred parameters for [`DeferringModule::apply_deferred_block`].
    fn deferred_blocks(&self) -> usize;

    /// The deferred parameters of block `block` (contiguous, in order; sizes may differ).
    fn deferred_block_range(&self, block: usize) -> std::ops::Range<usize>;

    /// [`DeferringModule::apply_deferred`] for one block of the deferred parameters into
    /// `d_block`.
    fn apply_deferred_block(&self, parts: &[(&[R], &[R])], block: usize, d_block: &mut [R]);
}

/// A [`DeferringModule`] with tangents: the deferred reverse pass of analytic normals.
pub trait DeferringTangentModule<R: Real>: DeferringModule<R> + TangentModule<R> {
    /// [`TangentModule::backward_tangent`] without the gradient of the first
    /// [`DeferringModule::deferred_params`] parameters; what it needs goes to `deferred`, rows ×
    /// 2·[`DeferringModule::deferred_width`] in two blocks (the adjoints of the deferred
    /// module's outputs, then of their tangents), for
    /// [`DeferringTangentModule::apply_deferred_tangent_block`] with the input `[points block;
    /// tangents block]`.
    fn backward_tangent_deferring(&self, pass: TangentAdjoints<'_, R>, d_params: &mut [R], deferred: &mut [R]);

    /// The tangent counterpart of [`DeferringModule::apply_deferred_block`], for the records of
    /// [`DeferringTangentModule::backward_tangent_deferring`].
    fn apply_deferred_tangent_block(&self, parts: &[(&[R], &[R])], block: usize, d_block: &mut [R]);
}

/// Element-wise activations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Activation {
    /// y = z.
    Identity,
    /// y = max(z, 0).
    Relu,
    /// y = ln(1 + e^{βz}) / β (NeuS: β = 100); linear beyond βz > 20 to avoid overflow.
    Softplus {
        /// Sharpness β.
        beta: f64,
    },
    /// y = 1 / (1 + e^{−z}).
    Sigmoid,
}

impl Activation {
    /// y(z).
    #[inline]
    pub fn apply<R: Real>(self, z: R) -> R {
        match self {
            Activation::Identity => z,
            Activation::Relu => z.max(R::ZERO),
            Activation::Softplus { beta } => {
                let b = R::of(beta);
                let bz = b * z;
                if bz > R::of(20.0) { z } else { bz.exp().ln_1p() / b }
            }
            Activation::Sigmoid => sigmoid(z),
        }
    }

    /// (y(z), dy/dz) together, sharing the exponential (softplus and sigmoid).
    #[inline]
    pub fn apply_with_derivative<R: Real>(self, z: R) -> (R, R) {
        match self {
            Activation::Softplus { beta } => {
                let b = R::of(beta);
                let bz = b * z;
                if bz > R::of(20.0) {
                    (z, R::ONE)
                } else {
                    let e = bz.exp();
                    (e.ln_1p() / b, e / (R::ONE + e))
                }
            }
            Activation::Sigmoid => {
                let s = sigmoid(z);
                (s, s * (R::ONE - s))
            }
            other => (other.apply(z), other.derivative(z)),
        }
    }

    /// d²y/dz² from dy/dz (what a forward pass keeps) and y: 0 for the piecewise-linear ones;
    /// softplus: β·σ(βz)(1 − σ(βz)) with σ(βz) = dy/dz; sigmoid: σ'(z)(1 − 2σ(z)), which needs
    /// y = σ(z) too (dy/dz alone does not tell z's side; [`Activation::second_needs_value`]).
    /// `value` is read only when that says so.
    #[inline]
    pub fn second_derivative<R: Real>(self, slope: R, value: R) -> R {
        match self {
            Activation::Identity | Activation::Relu => R::ZERO,
            Activation::Softplus { beta } => R::of(beta) * slope * (R::ONE - slope),
            Activation::Sigmoid => slope * (R::ONE - (value + value)),
        }
    }

    /// Whether [`Activation::second_derivative`] is zero everywhere (identity, ReLU).
    pub fn is_piecewise_linear(self) -> bool {
        matches!(self, Activation::Identity | Activation::Relu)
    }

    /// Whether [`Activation::second_derivative`] reads y (the sigmoid).
    pub fn second_needs_value(self) -> bool {
        matches!(self, Activation::Sigmoid)
    }

    /// dy/dz at z.
    #[inline]
    pub fn derivative<R: Real>(self, z: R) -> R {
        match self {
            Activation::Identity => R::ONE,
            Activation::Relu => {
                if z > R::ZERO {
                    R::ONE
                } else {
                    R::ZERO
                }
            }
            Activation::Softplus { beta } => {
                let bz = R::of(beta) * z;
                if bz > R::of(20.0) { R::ONE } else { sigmoid(bz) }
            }
            Activation::Sigmoid => {
                let s = sigmoid(z);
                s * (R::ONE - s)
            }
        }
    }
}

/// The logistic sigmoid without overflow.
#[inline]
pub fn sigmoid<R: Real>(z: R) -> R {
    if z >= R::ZERO {
        R::ONE / (R::ONE + (-z).exp())
    } else {
        let e = z.exp();
        e / (R::ONE + e)
    }
}

/// Splits `values` into consecutive blocks, `ranges` starting at 0 and each starting where the
/// last ended (e.g. a module's [`ScatterGradient::gradient_block_range`]s).
pub fn split_blocks<T>(values: &mut [T], ranges: impl IntoIterator<Item = std::ops::Range<usize>>) -> Vec<&mut [T]> {
    let mut rest = values;
    let mut at = 0;
    let mut blocks = Vec::new();
    for range in ranges {
        assert_eq!(range.start, at, "split_blocks: blocks must follow each other");
        let (block, tail) = std::mem::take(&mut rest).split_at_mut(range.len());
        blocks.push(block);
        rest = tail;
        at = range.end;
    }
    blocks
}

/// The ranges of `net`'s deferred parameter blocks ([`DeferringModule::deferred_block_range`]),
/// in order; none when it defers no gradient.
pub fn deferred_block_ranges<R: Real, M: DeferringModule<R> + ?Sized>(net: &M) -> Vec<std::ops::Range<usize>> {
    if net.deferred_params() == 0 {
        return Vec::new();
    }
    (0..net.deferred_blocks().max(1)).map(|b| net.deferred_block_range(b)).collect()
}

/// Two modules in sequence: `b(a(x))`. Parameters `[a | b]`; context `[a ctx | a output | b ctx]`.
#[derive(Debug, Clone)]
pub struct Chain<A, B> {
    /// First module.
    pub a: A,
    /// Second module.
    pub b: B,
}

impl<A, B> Chain<A, B> {
    /// The context's three blocks for `rows` rows: (a's context, a's output, b's context).
    fn split_ctx<'c, R: Real>(&self, ctx: &'c [R], rows: usize) -> (&'c [R], &'c [R], &'c [R])
    where
        A: Module<R>,
    {
        self.split_at_a(ctx, rows, self.a.ctx_per_row())
    }

    /// [`Self::split_ctx`] of [`TangentModule::forward_keeping_tangents`]'s context.
    fn split_tangent_ctx<'c, R: Real>(&self, ctx: &'c [R], rows: usize) -> (&'c [R], &'c [R], &'c [R])
    where
        A: TangentModule<R>,
    {
        self.split_at_a(ctx, rows, self.a.tangent_ctx_per_row())
    }

    /// The three blocks when a's context takes `a_ctx` values a row.
    fn split_at_a<'c, R: Real>(&self, ctx: &'c [R], rows: usize, a_ctx: usize) -> (&'c [R], &'c [R], &'c [R])
    where
        A: Module<R>,
    {
        let (ca, rest) = ctx.split_at(rows * a_ctx);
        let (mid, cb) = rest.split_at(rows * self.a.n_outputs());
        (ca, mid, cb)
    }
}

impl<R: Real, A: Module<R>, B: Module<R>> Module<R> for Chain<A, B> {
    fn n_params(&self) -> usize {
        self.a.n_params() + self.b.n_params()
    }
    fn n_inputs(&self) -> usize {
        self.a.n_inputs()
    }
    fn n_outputs(&self) -> usize {
        self.b.n_outputs()
    }
    fn ctx_per_row(&self) -> usize {
        self.a.ctx_per_row() + self.a.n_outputs() + self.b.ctx_per_row()
    }
    fn forward(&self, params: &[R], input: &[R], output: &mut [R], ctx: &mut [R]) {
        let rows = input.len() / self.a.n_inputs();
        let (pa, pb) = params.split_at(self.a.n_params());
        let (ca, rest) = ctx.split_at_mut(rows * self.a.ctx_per_row());
        let (mid, cb) = rest.split_at_mut(rows * self.a.n_outputs());
        self.a.forward(pa, input, mid, ca);
        self.b.forward(pb, mid, output, cb);
    }
    fn forward_first(&self, params: &[R], input: &[R], first: &mut [R]) {
        let (pa, pb) = params.split_at(self.a.n_params());
        let mut mid = crate::scratch::Buf::<R>::to_overwrite(first.len() * self.a.n_outputs());
        self.a.infer(pa, input, &mut mid);
        self.b.forward_first(pb, &mid, first);
    }
    fn infer(&self, params: &[R], input: &[R], output: &mut [R]) {
        let (pa, pb) = params.split_at(self.a.n_params());
        let mut mid = crate::scratch::Buf::<R>::to_overwrite(input.len() / self.a.n_inputs().max(1) * self.a.n_outputs());
        self.a.infer(pa, input, &mut mid);
        self.b.infer(pb, &mid, output);
    }
    fn backward(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_params: &mut [R], d_input: Option<&mut [R]>) {
        let rows = input.len() / self.a.n_inputs();
        let (pa, pb) = params.split_at(self.a.n_params());
        let (dpa, dpb) = d_params.split_at_mut(self.a.n_params());
        let (ca, mid, cb) = self.split_ctx(ctx, rows);
        let mut d_mid = crate::scratch::Buf::<R>::to_overwrite(mid.len());
        self.b.backward(pb, mid, cb, d_output, dpb, Some(&mut d_mid));
        self.a.backward(pa, input, ca, &d_mid, dpa, d_input);
    }
}

/// The first module's parameters are deferred (none when it has none): the record is ∂L/∂(its
/// outputs), from which its [`ScatterGradient`] computes them.
impl<R: Real, A: ScatterGradient<R>, B: Module<R>> DeferringModule<R> for Chain<A, B> {
    fn deferred_params(&self) -> usize {
        self.a.n_params()
    }
    fn deferred_width(&self) -> usize {
        self.a.n_outputs()
    }
    fn backward_deferring(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_params: &mut [R], deferred: &mut [R]) {
        let rows = input.len() / self.a.n_inputs();
        let (_, pb) = params.split_at(self.a.n_params());
        let (_, mid, cb) = self.split_ctx(ctx, rows);
        self.b.backward(pb, mid, cb, d_output, d_params, Some(deferred));
    }
    fn apply_deferred(&self, parts: &[(&[R], &[R])], d_deferred: &mut [R]) {
        self.a.backward_parts(parts, 0, d_deferred);
    }
    fn deferred_blocks(&self) -> usize {
        self.a.gradient_blocks()
    }
    fn deferred_block_range(&self, block: usize) -> std::ops::Range<usize> {
        self.a.gradient_block_range(block)
    }
    fn apply_deferred_block(&self, parts: &[(&[R], &[R])], block: usize, d_block: &mut [R]) {
        self.a.backward_parts_block(parts, 0, block, d_block);
    }
}

/// The context of [`TangentModule::forward_keeping_tangents`]: `[a's, a's outputs, b's]`, as
/// [`Module::forward`]'s with each module's tangent context.
impl<R: Real, A: TangentModule<R>, B: TangentModule<R>> TangentModule<R> for Chain<A, B> {
    fn tangent_ctx_per_row(&self) -> usize {
        self.a.tangent_ctx_per_row() + self.a.n_outputs() + self.b.tangent_ctx_per_row()
    }
    fn forward_keeping_tangents(&self, params: &[R], input: &[R], output: &mut [R], ctx: &mut [R]) {
        let rows = input.len() / self.a.n_inputs();
        let (pa, pb) = params.split_at(self.a.n_params());
        let (ca, rest) = ctx.split_at_mut(rows * self.a.tangent_ctx_per_row());
        let (mid, cb) = rest.split_at_mut(rows * self.a.n_outputs());
        self.a.forward_keeping_tangents(pa, input, mid, ca);
        self.b.forward_keeping_tangents(pb, mid, output, cb);
    }
    fn forward_tangents(&self, params: &[R], input: &[R], ctx: &[R], k: usize, tangents_in: &[R], tangents_out: &mut [R]) {
        let rows = input.len() / self.a.n_inputs();
        let (pa, pb) = params.split_at(self.a.n_params());
        let (ca, mid, cb) = self.split_tangent_ctx(ctx, rows);
        let mut mid_tangents = crate::scratch::Buf::<R>::to_overwrite(rows * k * self.a.n_outputs());
        self.a.forward_tangents(pa, input, ca, k, tangents_in, &mut mid_tangents);
        self.b.forward_tangents(pb, mid, cb, k, &mid_tangents, tangents_out);
    }
    fn backward_tangent(&self, pass: TangentAdjoints<'_, R>, d_params: &mut [R], d_input: Option<(&mut [R], &mut [R])>) {
        let TangentAdjoints { params, input, ctx, tangent_in, d_output, d_tangent_out } = pass;
        let rows = input.len() / self.a.n_inputs();
        let (pa, pb) = params.split_at(self.a.n_params());
        let (dpa, dpb) = d_params.split_at_mut(self.a.n_params());
        let (ca, mid, cb) = self.split_tangent_ctx(ctx, rows);
        let mut mid_tangent = crate::scratch::Buf::<R>::to_overwrite(mid.len());
        self.a.forward_tangents(pa, input, ca, 1, tangent_in, &mut mid_tangent);
        let (mut d_mid, mut d_mid_tangent) = (crate::scratch::Buf::<R>::zeroed(mid.len()), crate::scratch::Buf::<R>::zeroed(mid.len()));
        let outer = TangentAdjoints { params: pb, input: mid, ctx: cb, tangent_in: &mid_tangent, d_output, d_tangent_out };
        self.b.backward_tangent(outer, dpb, Some((&mut d_mid, &mut d_mid_tangent)));
        let inner = TangentAdjoints { params: pa, input, ctx: ca, tangent_in, d_output: &d_mid, d_tangent_out: &d_mid_tangent };
        self.a.backward_tangent(inner, dpa, d_input);
    }
    fn input_gradient(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_input: &mut [R]) {
        let rows = input.len() / self.a.n_inputs();
        let (pa, pb) = params.split_at(self.a.n_params());
        let (ca, mid, cb) = self.split_tangent_ctx(ctx, rows);
        let mut d_mid = crate::scratch::Buf::<R>::to_overwrite(mid.len());
        self.b.input_gradient(pb, mid, cb, d_output, &mut d_mid);
        self.a.input_gradient(pa, input, ca, &d_mid, d_input);
    }
    fn input_gradient_of_forward(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_input: &mut [R]) {
        let rows = input.len() / self.a.n_inputs();
        let (pa, pb) = params.split_at(self.a.n_params());
        let (ca, mid, cb) = self.split_ctx(ctx, rows);
        let mut d_mid = crate::scratch::Buf::<R>::to_overwrite(mid.len());
        self.b.input_gradient_of_forward(pb, mid, cb, d_output, &mut d_mid);
        self.a.input_gradient_of_forward(pa, input, ca, &d_mid, d_input);
    }
}

impl<R: Real, A: ScatterTangent<R>, B: TangentModule<R>> DeferringTangentModule<R> for Chain<A, B> {
    fn backward_tangent_deferring(&self, pass: TangentAdjoints<'_, R>, d_params: &mut [R], deferred: &mut [R]) {
        let TangentAdjoints { params, input, ctx, tangent_in, d_output, d_tangent_out } = pass;
        let rows = input.len() / self.a.n_inputs();
        let (pa, pb) = params.split_at(self.a.n_params());
        let (ca, mid, cb) = self.split_tangent_ctx(ctx, rows);
        let mut mid_tangent = crate::scratch::Buf::<R>::to_overwrite(mid.len());
        self.a.forward_tangents(pa, input, ca, 1, tangent_in, &mut mid_tangent);
        // The record: ∂L/∂(first module's outputs), then ∂L/∂(their tangents).
        let (d_mid, d_mid_tangent) = deferred.split_at_mut(mid.len());
        let outer = TangentAdjoints { params: pb, input: mid, ctx: cb, tangent_in: &mid_tangent, d_output, d_tangent_out };
        self.b.backward_tangent(outer, d_params, Some((d_mid, d_mid_tangent)));
    }
    fn apply_deferred_tangent_block(&self, parts: &[(&[R], &[R])], block: usize, d_block: &mut [R]) {
        self.a.tangent_parts_block(parts, 0, block, d_block);
    }
}

/// Forward and backward of `module` over a batch, in parallel chunks of `chunk_rows` rows, one
/// gradient buffer per chunk summed in chunk order: the same result for any thread count.
/// `loss` gets each chunk's (input, output) and writes ∂L/∂output; it returns the chunk's loss.
/// Returns the total loss; gradients are *added* to `d_params`. The chunks' buffers are pooled
/// ([`Buf`]): a fresh gradient of every parameter per chunk cost page faults on each call (half of
/// the sphere fit's time on a hash-grid network, which now sums its tables over the entries each
/// chunk touches instead, [`crate::presets::fit_sphere`]).
pub fn batch_gradients<R: Real, M: Module<R>>(
    module: &M,
    params: &[R],
    input: &[R],
    chunk_rows: usize,
    d_params: &mut [R],
    loss: impl Fn(&[R], &[R], &mut [R]) -> f64 + Sync,
) -> f64 {
    use rayon::prelude::*;
    let (n_in, n_out, n_ctx, n_params) = (module.n_inputs(), module.n_outputs(), module.ctx_per_row(), module.n_params());
    let parts: Vec<(f64, Buf<R>)> = input
        .par_chunks(chunk_rows.max(1) * n_in)
        .map(|x| {
            let rows = x.len() / n_in;
            let mut grads = Buf::<R>::zeroed(n_params);
            let mut out = Buf::<R>::to_overwrite(rows * n_out);
            let mut ctx = Buf::<R>::to_overwrite(rows * n_ctx);
            let mut d_out = Buf::<R>::zeroed(rows * n_out);
            module.forward(params, x, &mut out, &mut ctx);
            let l = loss(x, &out, &mut d_out);
            module.backward(params, x, &ctx, &d_out, &mut grads, None);
            (l, grads)
        })
        .collect();
    let mut total = 0.0;
    for (l, g) in parts {
        total += l;
        for (d, g) in d_params.iter_mut().zip(g.iter()) {
            *d += *g;
        }
    }
    total
}
