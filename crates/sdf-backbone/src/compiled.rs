//! The passes other crates run on a [`Backbone`], compiled once, here.
//!
//! A generic function is compiled in the crate that instantiates it, and an optimised build
//! shares no instances between crates: a generic method called on a [`Backbone`] from the
//! trainer compiles there the networks' passes it reaches, their kernels once per instruction
//! set, and from xtask again; analytic normals ([`Pipeline::set_normals`]) compile the tangent
//! passes (in f64 too, before the feature `f64-tangents`). That was 60 % of the code generated
//! for the trainer and for xtask, most of a first `cargo xtask train`'s build (BENCHMARKS.md,
//! "The release build of a first run"). The methods here are not generic (the presets'
//! networks, f32): they are compiled in sdf-backbone and called from the others, as
//! [`Backbone::train_step`], [`Backbone::field`], [`Backbone::upsample`],
//! [`Backbone::upsample_for_render`] and [`Backbone::sdf_along`] are.
//! Other crates call these; the generic methods stay for other networks and for the f64
//! gradient checks.

use crate::backbone::Backbone;
use crate::mlp::Mlp;
use crate::module::batch_gradients;
#[cfg(doc)]
use crate::pipeline::Pipeline;
use crate::pipeline::{NormalScheme, RayInput, RayOutput, SampleLoss};
use std::num::NonZeroUsize;

impl Backbone {
    /// [`Pipeline::set_normals`]: takes normals by `scheme`.
    pub fn set_normal_scheme(&mut self, scheme: NormalScheme) {
        self.set_normals(scheme);
    }

    /// [`Pipeline::render_known`] in f32: renders `rays` forward only, given the SDF at every
    /// depth of each ray ([`Backbone::upsample_for_render`]).
    pub fn render(
        &self,
        params: &[f32],
        rays: &[RayInput<f32>],
        sdf: &[Vec<f32>],
        negligible: f32,
        colour_stride: NonZeroUsize,
    ) -> Vec<RayOutput<f32>> {
        self.render_known(params, rays, sdf, negligible, colour_stride)
    }

    /// [`Pipeline::loss_parallel`] in f32: the loss of `rays` and its gradient added into
    /// `d_params`, over chunks of `chunk` rays in parallel.
    pub fn loss_and_gradient(
        &self,
        params: &[f32],
        rays: &[RayInput<f32>],
        d_params: &mut [f32],
        chunk: usize,
        extra: &dyn SampleLoss,
    ) -> (f32, Vec<RayOutput<f32>>) {
        self.loss_parallel(params, rays, d_params, chunk, extra)
    }
}

impl Mlp {
    /// [`batch_gradients`] in f32 with every output's adjoint `d_output` (the benches time a
    /// network's forward and reverse passes with it): the gradient added into `d_params`.
    pub fn gradients_for_adjoint(&self, params: &[f32], input: &[f32], chunk_rows: usize, d_params: &mut [f32], d_output: f32) {
        batch_gradients(self, params, input, chunk_rows, d_params, |_, _, dy| {
            dy.fill(d_output);
            0.0
        });
    }
}
