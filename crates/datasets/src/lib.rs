//! Loaders for the multi-view formats people have, into one [`Scene`], and golden scenes whose
//! true geometry is known.
//!
//! # Formats
//! - **IDR / NeuS / DTU** (`cameras_sphere.npz` or `cameras.npz`, `image/` or `images/`,
//!   optional `mask/`; the `idr` module): `world_mat_i` / `scale_mat_i` per view.
//! - **NeRF-synthetic** (`transforms_{train,val,test}.json`, RGBA images: alpha becomes the mask,
//!   colour is composited over [`LoadOptions::background`]).
//! - **instant-ngp / Neuralangelo** (`transforms.json` with `fl_x`, `cx`, …, per-frame overrides,
//!   `sphere_center`/`sphere_radius` or `aabb`). Lens distortion is rejected with a clear error.
//! - **COLMAP** (`images/` with a sparse model `sparse/0/{cameras,images,points3D}.{bin,txt}`,
//!   optional `masks/`): see [`colmap`]. Distorted cameras (SIMPLE_RADIAL, RADIAL, OPENCV) are
//!   undistorted at load time ([`undistort`]); the region of interest comes from the sparse
//!   points; [`colmap::import_colmap`] writes the IDR layout.
//!
//! Every scene lives in a *normalised frame* where the region of interest is the unit sphere;
//! [`Scene::world_from_normalized`] maps back to the input's units (DTU: millimetres).
//!
//! # Invariants
//! - This crate never trains: it reads, checks and writes data.
//! - Bad input is a [`DatasetError`] naming the file and the problem, never a panic.
//! - Pixels are u8 RGB and masks one bit per pixel (DTU scan 24, 49 × 1600×1200: < 400 MB).
#![deny(missing_docs)]

pub mod colmap;
mod contain;
mod error;
pub mod golden;
mod idr;
pub mod images;
pub mod io;
mod load;
pub mod npy;
pub mod parse;
mod scene;
mod transforms;
pub mod undistort;

pub use colmap::{ImportReport, import_colmap};
pub use error::{DatasetError, Result};
pub use images::{Mask, RgbImage};
pub use load::{detect_format, load_scene, read_cameras};
pub use scene::{CameraRecord, Format, LoadOptions, Scene, SceneCameras, SceneSource, View};
