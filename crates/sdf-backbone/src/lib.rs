//! SDF backbones with hand-written, verified gradients.
//!
//! Every backward pass is checked against finite differences in f64 (tests/gradients.rs):
//! the module interface over flat parameter slices ([`Module`], [`Chain`], [`batch_gradients`]);
//! dense layers as matrix products with activations, skip connection, NeuS's geometric
//! initialisation and a least-squares calibration of the SDF readout ([`Mlp`]); positional
//! encoding, spherical harmonics of degree 4 ([`PositionalEncoding`], [`SphericalHarmonics`]);
//! the multi-resolution hash grid with coarse-to-fine levels ([`HashGrid`]); NeuS volume rendering
//! of one ray and its backward ([`render_ray`], [`render_ray_backward`]), hierarchical
//! up-sampling ([`sample_intervals`], [`Backbone::upsample`]); the whole render + loss pipeline
//! for a batch of rays ([`Pipeline`]: SDF network, tetrahedral or central normals, colour network
//! on [x, n, SH(d), features], L1/L2 colour over a fixed or learned background, eikonal,
//! curvature, mask BCE, a [`SampleLoss`] hook for the surface losses, learnt variance); Adam/AdamW
//! with parameter groups and the warm-up + cosine or step schedules ([`optim`]).
//! [`backbone`] is the API the trainer and the sampler use, [`presets`] its [`Preset`]s sized for a 2-core CPU
//! and at the papers' scale, [`build`], [`Backbone::field`] (a `prob_grid::SdfField`),
//! coarse-to-fine, [`CheckpointWriter`] / [`CheckpointReader`] (safetensors).
//!
//! # Design (tiny-cuda-nn's shape)
//! Modules own no parameters: a model is one flat `params` slice and one `grads` slice, each
//! module at an offset; the optimiser works on the slices; a checkpoint is one tensor each.
//! Modules are generic over [`Real`] (f32 for training, f64 for gradient checks).
#![deny(missing_docs)]

pub mod backbone;
pub mod background;
pub mod checkpoint;
pub mod compiled;
pub mod encoding;
pub mod hashgrid;
pub mod kernels;
pub mod mlp;
pub mod module;
pub mod optim;
pub mod pipeline;
pub mod presets;
pub mod profile;
pub mod real;
pub mod render;
pub mod scratch;
mod sines;
pub mod upsample;

pub use backbone::{Backbone, BackboneError, BackboneField, InputEncoding, ParamLayout, SdfNet, StepRates, adam_step};
pub use background::BackgroundModel;
pub use checkpoint::{CheckpointReader, CheckpointWriter};
pub use encoding::{PositionalEncoding, SphericalHarmonics, WithInput};
pub use hashgrid::{HashGrid, HashGridConfig};
pub use mlp::{Mlp, MlpConfig, Products};
pub use module::{
    Activation, Chain, DeferringModule, DeferringTangentModule, Module, ScatterGradient, ScatterTangent, TangentAdjoints, TangentModule,
    batch_gradients,
};
pub use optim::{Adam, AdamStep, CompactMoments, Decay, LrSchedule, Moments, WarmupCosine, WarmupStep};
pub use pipeline::{
    AnalyticNormals, ColorLoss, DeferredGradient, Differences, NoSampleLoss, NormalScheme, OpacityGuard, Pipeline, PipelineConfig, RayInput,
    RayOutput, SampleLoss, SmoothnessRegion, scale_from_variance, variance_from_scale,
};
pub use presets::{Preset, Variation, architecture, architecture_varied, architecture_with_grid, build, build_varied, build_with_grid};
pub use real::Real;
pub use render::{RayGradients, RayRender, merge_sorted, render_ray, render_ray_backward, sample_intervals};
pub use upsample::{Trim, interval_weights, proven_faint, trim_to_weight};
