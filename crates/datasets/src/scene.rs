//! The one scene type every loader produces.

use crate::images::{Mask, RgbImage};
use camera_geom::PinholeCamera;
use glam::{DMat4, DVec3};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// The input formats psneus reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Format {
    /// IDR / NeuS / DTU: `cameras_sphere.npz` (or `cameras.npz`), `image/`, `mask/`.
    Idr,
    /// NeRF-synthetic (Blender): `transforms_{train,val,test}.json`.
    NerfSynthetic,
    /// instant-ngp / Neuralangelo: `transforms.json`.
    InstantNgp,
    /// COLMAP: a sparse model (`sparse/0/{cameras,images,points3D}.{bin,txt}`) with `images/`.
    Colmap,
    /// A golden scene generated in memory (no files).
    Generated,
}

/// Where a scene came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneSource {
    /// The format.
    pub format: Format,
    /// The folder it was read from (`None` for generated scenes).
    pub path: Option<PathBuf>,
    /// One line for people: what was read, how, with which options.
    pub description: String,
}

/// A camera as read from a file, with the image and mask files that belong to it.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraRecord {
    /// A name for the view (the image file stem).
    pub name: String,
    /// The camera in the normalised frame, at the loaded resolution (after downscaling).
    pub camera: PinholeCamera,
    /// The image file (`None` for generated scenes).
    pub image_path: Option<PathBuf>,
    /// The mask file, if the dataset has one per view.
    pub mask_path: Option<PathBuf>,
}

/// Cameras of a scene without their pixels: cheap to read (image headers only).
#[derive(Debug, Clone, PartialEq)]
pub struct SceneCameras {
    /// One record per view.
    pub records: Vec<CameraRecord>,
    /// The normalised frame (region of interest = unit sphere) → the input's world frame, e.g.
    /// DTU's `scale_mat` (millimetres). Meshes are written in world units by applying this.
    pub world_from_normalized: DMat4,
    /// Where it came from.
    pub source: SceneSource,
}

/// One view: a camera, its image and (optionally) its mask.
#[derive(Debug, Clone, PartialEq)]
pub struct View {
    /// A name (the image file stem, or an index for generated scenes).
    pub name: String,
    /// The camera, in the normalised frame.
    pub camera: PinholeCamera,
    /// The image, u8 RGB, same size as the camera.
    pub image: RgbImage,
    /// The foreground mask, same size as the image.
    pub mask: Option<Mask>,
}

/// A calibrated multi-view scene in the normalised frame (region of interest = unit sphere).
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// The views.
    pub views: Vec<View>,
    /// The normalised frame → the input's world frame.
    pub world_from_normalized: DMat4,
    /// Where it came from.
    pub source: SceneSource,
}

impl Scene {
    /// Maps a point of the normalised frame to the input's world frame.
    pub fn point_in_input_world(&self, point_in_normalized: DVec3) -> DVec3 {
        self.world_from_normalized.transform_point3(point_in_normalized)
    }

    /// Resident bytes of the pixel data (images and masks).
    pub fn pixel_bytes(&self) -> usize {
        self.views.iter().map(|v| v.image.data.len() + v.mask.as_ref().map_or(0, |m| (m.width as usize * m.height as usize).div_ceil(8))).sum()
    }
}

/// Options shared by the loaders.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadOptions {
    /// Integer downscale factor (area average), ≥ 1. Intrinsics follow, see
    /// [`camera_geom::Intrinsics::downscaled`].
    pub downscale: u32,
    /// Background colour for images with alpha (NeRF-synthetic), RGB in [0, 1]. Default white,
    /// as NeRF and NeuS use for the Blender scenes.
    pub background: [f32; 3],
    /// NeRF-synthetic split to read: `train`, `val`, `test`.
    pub split: String,
    /// Overrides the bound sphere (centre and radius in the input's world frame) that defines the
    /// normalised frame, for formats that do not store one (NeRF-synthetic defaults to the
    /// origin and radius 1.5; instant-ngp reads `sphere_center`/`sphere_radius` or `aabb`;
    /// COLMAP derives it from the sparse points, in COLMAP units).
    pub bound_sphere: Option<(DVec3, f64)>,
}

impl LoadOptions {
    /// Checks the options for the data at `path`: downscale ≥ 1, a finite bound sphere of
    /// positive radius.
    pub fn validate(&self, path: &std::path::Path) -> crate::error::Result<()> {
        let invalid =
            |entry: &str, message: String| crate::error::DatasetError::InvalidValue { path: path.to_path_buf(), entry: entry.into(), message };
        if self.downscale == 0 {
            return Err(invalid("downscale", "must be ≥ 1".into()));
        }
        if let Some((center, radius)) = self.bound_sphere.filter(|(c, r)| !(c.is_finite() && r.is_finite() && *r > 0.0)) {
            return Err(invalid("bound sphere", format!("centre {center}, radius {radius}: finite, radius > 0")));
        }
        Ok(())
    }
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions { downscale: 1, background: [1.0; 3], split: "train".into(), bound_sphere: None }
    }
}
