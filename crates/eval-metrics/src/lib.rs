//! psneus: PSNR, SSIM, DTU-protocol Chamfer and F-score.
//!
//! **Status: not implemented yet** (issue #5). This crate is an empty placeholder in the
//! workspace so that the crate layout of the design card is visible; it exports nothing.
