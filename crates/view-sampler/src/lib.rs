//! psneus: conditional sampling of pixels and depths from the camera pdfs.
//!
//! **Status: not implemented yet** (issue #3). This crate is an empty placeholder in the
//! workspace so that the crate layout of the design card is visible; it exports nothing.
