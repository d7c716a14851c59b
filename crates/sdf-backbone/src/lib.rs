//! SDF backbones with hand-written, verified gradients (issue #4).
//!
//! **Status: in progress.** Implemented, with every gradient checked against finite differences
//! in f64: the module interface over flat parameter slices ([`Module`], [`Chain`],
//! [`batch_gradients`]); dense layers with activations, skip connection, NeuS's geometric
//! initialisation and a least-squares calibration of the SDF readout ([`Mlp`]); the positional
//! encoding, spherical harmonics of degree 4 ([`PositionalEncoding`], [`SphericalHarmonics`]); the
//! multi-resolution hash grid with coarse-to-fine levels ([`HashGrid`]); NeuS volume rendering of
//! one ray and its backward ([`render_ray`], [`render_ray_backward`]); Adam/AdamW and the
//! warm-up-then-cosine schedule ([`optim`]); an SDF network ([`SdfNetwork`]) that implements
//! `prob_grid::SdfField`; the whole NeuS render + loss pipeline for a batch of rays with its
//! backward ([`Pipeline`]: SDF network, normals by central differences, colour network on
//! [x, n, SH(d), features], rendering, L1/L2 colour + eikonal + mask BCE, learnt variance).
//! Not implemented yet: hierarchical up-sampling, merging of the sampler's extra depths, the
//! learned background, a fast batched (GEMM-style, multi-threaded) path, curvature loss, the
//! backbone API around it (save/load, presets sized for the CPU), the render-fit test and the
//! benchmarks: the pipeline is correct (gradient-checked) but not yet fast.
//!
//! # Design (tiny-cuda-nn's shape)
//! Modules own no parameters: a model is one flat `params` slice and one `grads` slice, each
//! module at an offset; the optimiser works on the slices; a checkpoint is one tensor each.
//! Modules are generic over [`Real`] (f32 for training, f64 for gradient checks).
#![deny(missing_docs)]

pub mod backbone;
pub mod encoding;
pub mod hashgrid;
pub mod mlp;
pub mod module;
pub mod optim;
pub mod pipeline;
pub mod real;
pub mod render;

pub use encoding::{PositionalEncoding, SphericalHarmonics, WithInput};
pub use hashgrid::{HashGrid, HashGridConfig};
pub use render::{RayGradients, RayRender, merge_sorted, render_ray, render_ray_backward, sample_intervals};
pub use mlp::{Mlp, MlpConfig};
pub use module::{Activation, Chain, Module, batch_gradients};
pub use backbone::{Backbone, BackboneError, BackboneField, Checkpoint, InputEncoding, ParamLayout, Preset, SdfNet, adam_step, build};
pub use optim::{Adam, WarmupCosine, WarmupStep};
pub use pipeline::{
    ColorLoss, NoSampleLoss, NormalScheme, Pipeline, PipelineConfig, RayInput, RayOutput, SampleLoss, interval_weights,
};
pub use real::Real;
