//! psneus: SDF backbones (hash grid, MLP) with hand-written gradients and NeuS volume rendering.
//!
//! **Status: not implemented yet** (issue #4). This crate is an empty placeholder in the
//! workspace so that the crate layout of the design card is visible; it exports nothing.
