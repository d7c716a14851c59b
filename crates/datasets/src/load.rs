//! Layout detection and loading of pixels.

use crate::colmap::ColmapWorkspace;
use crate::error::{DatasetError, Result};
use crate::images::{Mask, load_mask, load_rgb};
use crate::scene::{Format, LoadOptions, Scene, SceneCameras, View};
use crate::{idr, transforms};
use rayon::prelude::*;
use std::path::Path;

/// Which layout a folder holds, by the files in it.
pub fn detect_format(dir: &Path) -> Result<Format> {
    if !dir.is_dir() {
        let why = if dir.exists() { "the dataset must be a folder, this is a file" } else { "no such dataset folder" };
        return Err(DatasetError::NotFound { path: dir.to_path_buf(), why: why.into() });
    }
    if idr::camera_file(dir).is_some() {
        Ok(Format::Idr)
    } else if dir.join("transforms_train.json").is_file() {
        Ok(Format::NerfSynthetic)
    } else if dir.join("transforms.json").is_file() {
        Ok(Format::InstantNgp)
    } else if ColmapWorkspace::find(dir).is_some() {
        Ok(Format::Colmap)
    } else {
        Err(DatasetError::UnknownLayout { dir: dir.to_path_buf() })
    }
}

/// Reads the cameras of a dataset folder (any supported layout) without decoding pixels.
pub fn read_cameras(dir: &Path, options: &LoadOptions) -> Result<SceneCameras> {
    options.validate(dir)?;
    match detect_format(dir)? {
        Format::Idr => idr::read_cameras(dir, options),
        Format::NerfSynthetic => {
            let json = dir.join(format!("transforms_{}.json", options.split));
            if !json.is_file() {
                return Err(DatasetError::MissingKey { path: dir.to_path_buf(), key: format!("transforms_{}.json", options.split) });
            }
            transforms::read_cameras(&json, Format::NerfSynthetic, options)
        }
        Format::InstantNgp => transforms::read_cameras(&dir.join("transforms.json"), Format::InstantNgp, options),
        Format::Colmap => colmap_workspace(dir)?.read_cameras(options),
        Format::Generated => unreachable!("detect_format never returns Generated"),
    }
}

fn colmap_workspace(dir: &Path) -> Result<ColmapWorkspace> {
    ColmapWorkspace::find(dir).ok_or_else(|| DatasetError::UnknownLayout { dir: dir.to_path_buf() })
}

/// Loads a dataset folder: cameras, images (u8, decoded in parallel) and masks (from `mask/` or
/// from the images' alpha channel). COLMAP images are undistorted as they are decoded.
pub fn load_scene(dir: &Path, options: &LoadOptions) -> Result<Scene> {
    if detect_format(dir)? == Format::Colmap {
        return colmap_workspace(dir)?.load_scene(options);
    }
    let cameras = read_cameras(dir, options)?;
    let views = cameras
        .records
        .par_iter()
        .map(|record| -> Result<View> {
            let image_path = record.image_path.as_deref().expect("file datasets have image paths");
            let decoded = load_rgb(image_path, options.downscale, options.background)?;
            let expected = (record.camera.width, record.camera.height);
            if (decoded.rgb.width, decoded.rgb.height) != expected {
                return Err(DatasetError::SizeMismatch {
                    path: image_path.to_path_buf(),
                    found: (decoded.rgb.width, decoded.rgb.height),
                    expected,
                    why: "the image changed size since its header was read",
                });
            }
            let mask: Option<Mask> = match &record.mask_path {
                Some(p) => Some(load_mask(p, options.downscale)?.0),
                None => decoded.alpha_mask,
            };
            Ok(View { name: record.name.clone(), camera: record.camera, image: decoded.rgb, mask })
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(Scene { views, world_from_normalized: cameras.world_from_normalized, source: cameras.source })
}
