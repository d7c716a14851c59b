//! Analytic normals as a capability of the SDF network's type: [`AnalyticNormals`] can only be
//! made for a network with tangents ([`DeferringTangentModule`] in f32 and f64), so a pipeline
//! whose network has none cannot be asked for them.
//!
//! ```
//! use sdf_backbone::pipeline::AnalyticNormals;
//! use sdf_backbone::{Chain, Mlp, PositionalEncoding};
//! // Positional encoding and an MLP: both have tangents.
//! let _ = AnalyticNormals::<Chain<PositionalEncoding, Mlp>>::new();
//! ```
//!
//! A network without tangents (here spherical harmonics as its second module) does not compile:
//!
//! ```compile_fail
//! use sdf_backbone::pipeline::AnalyticNormals;
//! use sdf_backbone::{Chain, PositionalEncoding, SphericalHarmonics};
//! let _ = AnalyticNormals::<Chain<PositionalEncoding, SphericalHarmonics>>::new();
//! ```
//!
//! The pipeline's code is generic over the precision `R`, while the network's tangent passes
//! exist only where the type has them; so the passes are taken at construction, for each
//! precision they are compiled for, as function pointers ([`TangentFns`]), and each precision
//! picks its own ([`TangentPrecision`]): f32, and f64 with the feature `f64-tangents` (the
//! gradient checks; without it a pipeline in f64 does not compile).

#[cfg(doc)]
use crate::module::TangentModule;
use crate::module::{DeferringTangentModule, TangentAdjoints};
use crate::real::Real;

/// [`TangentModule::backward_tangent`] without the input's adjoints.
pub type BackwardTangentFn<S, R> = fn(&S, TangentAdjoints<'_, R>, &mut [R]);
/// [`DeferringTangentModule::backward_tangent_deferring`].
pub type BackwardTangentDeferringFn<S, R> = fn(&S, TangentAdjoints<'_, R>, &mut [R], &mut [R]);
/// [`DeferringTangentModule::apply_deferred_tangent_block`].
pub type ApplyTangentBlockFn<S, R> = fn(&S, &[(&[R], &[R])], usize, &mut [R]);
/// [`TangentModule::input_gradient`].
pub type InputGradientFn<S, R> = fn(&S, &[R], &[R], &[R], &[R], &mut [R]);
/// [`TangentModule::forward_keeping_tangents`].
pub type ForwardKeepingFn<S, R> = fn(&S, &[R], &[R], &mut [R], &mut [R]);

/// The tangent passes of a network `S` in precision `R`.
pub struct TangentFns<S, R> {
    /// The forward pass whose context the others read.
    pub forward: ForwardKeepingFn<S, R>,
    /// Its context's values per row ([`TangentModule::tangent_ctx_per_row`]).
    pub ctx_per_row: fn(&S) -> usize,
    /// The reverse pass through values and one tangent per row.
    pub backward: BackwardTangentFn<S, R>,
    /// The same with the leading parameters' gradient deferred.
    pub backward_deferring: BackwardTangentDeferringFn<S, R>,
    /// One block of the deferred gradient from the records.
    pub apply_block: ApplyTangentBlockFn<S, R>,
    /// The input's adjoint by one reverse pass (the normals ∇ₓS: no gradient to carry on).
    pub input_gradient: InputGradientFn<S, R>,
    /// The same after the plain forward ([`TangentModule::input_gradient_of_forward`]).
    pub input_gradient_of_forward: InputGradientFn<S, R>,
}

impl<S, R> Clone for TangentFns<S, R> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<S, R> Copy for TangentFns<S, R> {}

impl<S: DeferringTangentModule<R>, R: Real> TangentFns<S, R> {
    fn of() -> Self {
        TangentFns {
            forward: |net, params, input, output, ctx| net.forward_keeping_tangents(params, input, output, ctx),
            ctx_per_row: |net| net.tangent_ctx_per_row(),
            backward: |net, pass, d_params| net.backward_tangent(pass, d_params, None),
            backward_deferring: |net, pass, d_params, deferred| net.backward_tangent_deferring(pass, d_params, deferred),
            apply_block: |net, parts, block, d_block| net.apply_deferred_tangent_block(parts, block, d_block),
            input_gradient: |net, params, input, ctx, d_output, d_input| net.input_gradient(params, input, ctx, d_output, d_input),
            input_gradient_of_forward: |net, params, input, ctx, d_output, d_input| {
                net.input_gradient_of_forward(params, input, ctx, d_output, d_input)
            },
        }
    }
}

/// Proof that the SDF network `S` has tangents (in f32 and f64), and its tangent passes in f32
/// (and f64 with the feature `f64-tangents`): a [`crate::Pipeline`] with one takes its normals
/// as the exact gradient ∇ₓS by one reverse pass, and the loss's gradient through them by a
/// forward-mode tangent and the reverse pass through it ([`crate::NormalScheme::Analytic`]).
pub struct AnalyticNormals<S> {
    f32: TangentFns<S, f32>,
    /// Only with the feature `f64-tangents` (the gradient checks): the passes in f64 are as much
    /// code again, which a training build does not run.
    #[cfg(feature = "f64-tangents")]
    f64: TangentFns<S, f64>,
}

impl<S> Clone for AnalyticNormals<S> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<S> Copy for AnalyticNormals<S> {}

impl<S> std::fmt::Debug for AnalyticNormals<S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("AnalyticNormals")
    }
}

impl<S: DeferringTangentModule<f32> + DeferringTangentModule<f64>> AnalyticNormals<S> {
    /// The tangent passes of `S`.
    pub fn new() -> Self {
        AnalyticNormals {
            f32: TangentFns::of(),
            #[cfg(feature = "f64-tangents")]
            f64: TangentFns::of(),
        }
    }
}

impl<S: DeferringTangentModule<f32> + DeferringTangentModule<f64>> Default for AnalyticNormals<S> {
    fn default() -> Self {
        Self::new()
    }
}

/// The precisions the tangent passes are compiled for: f32 to train, and f64 to check gradients
/// with the feature `f64-tangents` (the crate's tests turn it on). What renders or differentiates
/// a pipeline in precision `R` asks `R: TangentPrecision`, so a pipeline in f64 without the
/// feature does not compile.
pub trait TangentPrecision: Sized {
    /// This precision's passes.
    fn tangent_fns<S>(normals: &AnalyticNormals<S>) -> &TangentFns<S, Self>;
}

impl TangentPrecision for f32 {
    fn tangent_fns<S>(normals: &AnalyticNormals<S>) -> &TangentFns<S, f32> {
        &normals.f32
    }
}

#[cfg(feature = "f64-tangents")]
impl TangentPrecision for f64 {
    fn tangent_fns<S>(normals: &AnalyticNormals<S>) -> &TangentFns<S, f64> {
        &normals.f64
    }
}
