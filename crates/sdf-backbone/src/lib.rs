//! SDF backbones with hand-written, verified gradients (issue #4).
//!
//! **Status: in progress.** Implemented and tested: the module interface over flat parameter
//! slices ([`Module`]), dense layers with activations, skip connection and NeuS's geometric
//! initialisation ([`Mlp`]), the positional encoding ([`PositionalEncoding`]), the multi-resolution
//! hash grid with coarse-to-fine levels ([`HashGrid`]), module chaining ([`Chain`]), NeuS volume
//! rendering of one ray and its backward ([`render_ray`], [`render_ray_backward`]), Adam/AdamW and
//! the warm-up + cosine schedule ([`optim`]); every gradient is checked against finite
//! differences in f64; spherical harmonics (degree 4) for view directions. Not implemented yet: the SDF + colour networks with
//! normals, hierarchical sampling, the backbone API (SDF field, batch rendering, save/load),
//! presets, benchmarks.
//!
//! # Design (tiny-cuda-nn's shape)
//! Modules own no parameters: a model is one flat `params` slice and one `grads` slice, each
//! module at an offset; the optimiser works on the slices; a checkpoint is one tensor each.
//! Modules are generic over [`Real`] (f32 for training, f64 for gradient checks).
#![deny(missing_docs)]

pub mod encoding;
pub mod hashgrid;
pub mod mlp;
pub mod module;
pub mod optim;
pub mod real;
pub mod render;

pub use encoding::{PositionalEncoding, SphericalHarmonics};
pub use hashgrid::{HashGrid, HashGridConfig};
pub use render::{RayGradients, RayRender, render_ray, render_ray_backward};
pub use mlp::{Mlp, MlpConfig};
pub use module::{Activation, Chain, Module, batch_gradients};
pub use optim::{Adam, WarmupCosine};
pub use real::Real;
