//! The byte-level entry point of every parser in this crate: what the loaders call once a file
//! is read, and what `cargo xtask fuzz` drives with mutated bytes. Each takes the bytes and the
//! path to name in errors and never touches the file system; sizes of image files, which the
//! loaders read from headers, are given.
//!
//! Invariant (fuzzed): for any bytes, each function returns a value or a [`DatasetError`]
//! naming `path`; it never panics and never loops without bound. Counts and lengths are checked
//! against the bytes present before they drive a loop or an allocation; what a compressed
//! format may expand to is capped: an NPZ entry at [`MAX_NPZ_ENTRY_BYTES`] (and a camera array
//! must have a camera's shape before its data are read), an image at [`MAX_IMAGE_PIXELS`]
//! pixels and [`MAX_IMAGE_SIDE`] a side (checked from the header, before decoding).
//!
//! [`MAX_NPZ_ENTRY_BYTES`]: crate::npy::MAX_NPZ_ENTRY_BYTES
//! [`MAX_IMAGE_PIXELS`]: crate::images::MAX_IMAGE_PIXELS
//! [`MAX_IMAGE_SIDE`]: crate::images::MAX_IMAGE_SIDE
//!
//! [`DatasetError`]: crate::DatasetError

use crate::colmap::{BoundSphere, ColmapModel, ColmapView, ModelFiles};
use crate::error::Result;
use crate::images::{Mask, RgbImage, decode_bytes, mask_of, rgb_of};
use crate::io::PlyData;
use crate::npy::{NpyArray, Npz, parse_npy};
use crate::scene::{Format, LoadOptions, SceneCameras};
use std::io::Cursor;
use std::path::{Path, PathBuf};

/// A PLY file (ASCII or binary little-endian).
pub fn ply(bytes: &[u8], path: &Path) -> Result<PlyData> {
    PlyData::parse(bytes, path)
}

/// An `.npy` array.
pub fn npy(bytes: &[u8], path: &Path) -> Result<NpyArray> {
    parse_npy(bytes, path)
}

/// Every array of an `.npz` archive, by name.
pub fn npz(bytes: &[u8], path: &Path) -> Result<Vec<(String, NpyArray)>> {
    let mut npz = Npz::from_reader(Cursor::new(bytes), path)?;
    let mut arrays = Vec::new();
    for key in npz.keys() {
        if let Some(array) = npz.get(&key)? {
            arrays.push((key, array));
        }
    }
    Ok(arrays)
}

/// The cameras of an IDR/NeuS camera archive (`cameras_sphere.npz`) whose images (and masks,
/// with `masks`) all have `image_size`.
pub fn idr_cameras(bytes: &[u8], path: &Path, image_size: (u32, u32), masks: bool, options: &LoadOptions) -> Result<SceneCameras> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut npz = Npz::from_reader(Cursor::new(bytes), path)?;
    let files = |n: usize| -> Result<crate::idr::ViewFiles> {
        let named = |folder: &str| (0..n).map(|i| dir.join(folder).join(format!("{i:03}.png"))).collect::<Vec<PathBuf>>();
        Ok((named("image"), masks.then(|| named("mask"))))
    };
    crate::idr::cameras_from_npz(&mut npz, path, dir, options, &files, &|_| Ok(image_size))
}

/// The cameras of a `transforms*.json` (NeRF-synthetic or instant-ngp `format`) whose images
/// all have `image_size`.
pub fn transforms_cameras(bytes: &[u8], path: &Path, format: Format, image_size: (u32, u32), options: &LoadOptions) -> Result<SceneCameras> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let image = |file_path: &str, _camera: usize| -> Result<crate::transforms::FrameImage> { Ok((dir.join(file_path), image_size)) };
    crate::transforms::cameras_from_json(bytes, path, format, options, &image)
}

/// A COLMAP sparse model from the contents of its three files, its registered views and the
/// bound sphere of its points (as the loader computes them).
pub fn colmap_model(files: ModelFiles, cameras: &[u8], images: &[u8], points3d: &[u8]) -> Result<(ColmapModel, Vec<ColmapView>, BoundSphere)> {
    let model = ColmapModel::parse(files, cameras, images, points3d)?;
    let views = model.views()?;
    let bound = model.bound_sphere(&views)?;
    Ok((model, views, bound))
}

/// An image file: RGB (composited over `background` where it has alpha) and the alpha mask,
/// downscaled by `downscale` (≥ 1).
pub fn image(bytes: &[u8], path: &Path, downscale: u32, background: [f32; 3]) -> Result<(RgbImage, Option<Mask>)> {
    let decoded = rgb_of(decode_bytes(bytes, path)?, downscale.max(1), background);
    Ok((decoded.rgb, decoded.alpha_mask))
}

/// A mask file, downscaled by `downscale` (≥ 1).
pub fn mask(bytes: &[u8], path: &Path, downscale: u32) -> Result<Mask> {
    Ok(mask_of(decode_bytes(bytes, path)?, downscale.max(1)).0)
}

/// An OBJ mesh (geometry; its material library and textures, files of their own, are not read).
pub fn obj(bytes: &[u8], path: &Path) -> Result<crate::golden::mesh_io::TexturedMesh> {
    crate::golden::mesh_io::parse_obj(bytes, path, &|_| Err(tobj::LoadError::OpenFileFailed), &|name| {
        Err(crate::DatasetError::NotFound { path: PathBuf::from(name), why: "a texture (not read from bytes)".into() })
    })
}

/// A glTF (JSON) or GLB mesh with embedded buffers (`data:` URIs or GLB's binary chunk); an
/// external buffer is an error.
pub fn gltf(bytes: &[u8], path: &Path) -> Result<crate::golden::mesh_io::TexturedMesh> {
    crate::golden::mesh_io::parse_gltf(bytes, path, None)
}
