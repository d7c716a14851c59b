//! The one error type of this crate: every variant names the file (or folder) at fault.

use std::path::PathBuf;

/// What went wrong while loading or writing a scene. Each message starts with the path.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The folder matches none of the known layouts.
    #[error(
        "{dir}: unknown dataset layout (expected cameras_sphere.npz or cameras.npz with image/ (IDR, NeuS, DTU), \
         transforms_train.json (NeRF-synthetic), transforms.json (instant-ngp, Neuralangelo), or images/ with a \
         COLMAP model in sparse/0/, sparse/ or the folder itself (COLMAP))"
    )]
    UnknownLayout {
        /// The folder.
        dir: PathBuf,
    },
    /// No image file for a camera.
    #[error("{dir}: no image for camera {camera} (expected a file numbered {camera})")]
    MissingImage {
        /// The image folder.
        dir: PathBuf,
        /// The camera index.
        camera: usize,
    },
    /// A file that another file refers to does not exist (a COLMAP image, a mask).
    #[error("{path}: not found ({why})")]
    NotFound {
        /// The missing file.
        path: PathBuf,
        /// Who refers to it.
        why: String,
    },
    /// Numbers of cameras and of images (or masks) differ.
    #[error("{path}: {found} {what} for {cameras} cameras")]
    CountMismatch {
        /// The folder or file holding the items.
        path: PathBuf,
        /// Number of cameras.
        cameras: usize,
        /// Number of items found.
        found: usize,
        /// What was counted ("images", "masks").
        what: &'static str,
    },
    /// An image (or mask) has another size than it must.
    #[error("{path}: size {found:?} differs from {expected:?} ({why})")]
    SizeMismatch {
        /// The file.
        path: PathBuf,
        /// Its size (width, height).
        found: (u32, u32),
        /// The expected size.
        expected: (u32, u32),
        /// Why that size is expected.
        why: &'static str,
    },
    /// A file could not be parsed.
    #[error("{path}: corrupt {kind}: {message}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What kind of file ("PNG image", "npz archive", "JSON", "OBJ mesh"…).
        kind: &'static str,
        /// The parser's message.
        message: String,
    },
    /// A required entry is missing from a file.
    #[error("{path}: missing {key}")]
    MissingKey {
        /// The file.
        path: PathBuf,
        /// The entry.
        key: String,
    },
    /// A camera read from a file is invalid (NaN, singular P, not a rotation, zero focal…).
    #[error("{path}: {entry}: {source}")]
    Camera {
        /// The file.
        path: PathBuf,
        /// The entry (e.g. `world_mat_3`, `frames[2]`).
        entry: String,
        /// What is wrong with it.
        source: camera_geom::CameraError,
    },
    /// A value the loader could not use (non-finite numbers, a non-invertible scale matrix…).
    #[error("{path}: {entry}: {message}")]
    InvalidValue {
        /// The file.
        path: PathBuf,
        /// The entry.
        entry: String,
        /// What is wrong.
        message: String,
    },
    /// The file asks for something psneus does not model.
    #[error("{path}: unsupported: {message}")]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// What and what to do instead.
        message: String,
    },
}

/// Shorthand for this crate's results.
pub type Result<T, E = DatasetError> = std::result::Result<T, E>;

pub(crate) fn io_err(path: impl Into<PathBuf>) -> impl FnOnce(std::io::Error) -> DatasetError {
    let path = path.into();
    move |source| DatasetError::Io { path, source }
}
