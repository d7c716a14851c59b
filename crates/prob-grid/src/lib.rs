//! The probability field of the PS-NeuS sampler.
//!
//! **Status:** this crate currently provides the *fields* the sampler is guided by
//! ([`field::SdfField`], analytic [`field::Shape`]s, [`mesh::TriangleMesh`] ray casting). The scene
//! grid p(x) = φ_s(S(x)), the partition factor F and the reprojection into each camera's 3D
//! image space are issue #3 and are not implemented yet.
//!
//! Architecture invariant: this crate knows nothing of the backbone; it sees an SDF only through
//! [`field::SdfField`].
#![deny(missing_docs)]

pub mod field;
pub mod mesh;

pub use field::{SdfField, Shape};
pub use mesh::{MeshHit, TriangleMesh};
