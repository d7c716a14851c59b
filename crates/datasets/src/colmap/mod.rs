//! COLMAP sparse models (`cameras`, `images`, `points3D`, binary `.bin` or text `.txt`, as COLMAP
//! 3.8 writes them) and COLMAP workspaces (`images/` + `sparse/0/`) as scenes.
//!
//! # COLMAP's conventions (`src/colmap/scene/reconstruction_io.cc`, `doc/format.rst`)
//! - An image stores the rigid map world → camera, `camera_from_world`, as a unit quaternion
//!   `(qw, qx, qy, qz)` (Hamilton, Eigen's) and a translation `t`:
//!   `point_in_camera = R(q) · point_in_world + t`. The camera centre is `−Rᵀ t`.
//! - Camera axes are OpenCV's: +x right, +y down, +z forward, the same as ours: no flips.
//! - Pixel coordinates put the centre of the top-left pixel at (0.5, 0.5):
//!   [`PixelCenters::HalfInteger`] with COLMAP's `cx`, `cy` unchanged.
//! - Camera models read here: SIMPLE_PINHOLE `f, cx, cy`; PINHOLE `fx, fy, cx, cy`;
//!   SIMPLE_RADIAL `f, cx, cy, k`; RADIAL `f, cx, cy, k1, k2`; OPENCV
//!   `fx, fy, cx, cy, k1, k2, p1, p2`. Any other model is an [`DatasetError::Unsupported`] error.
//! - Binary files are little-endian: `cameras.bin` = u64 count, then per camera u32 id, i32 model
//!   id, u64 width, u64 height, f64 params; `images.bin` = u64 count, then per image u32 id,
//!   4 f64 quaternion, 3 f64 translation, u32 camera id, NUL-terminated name, u64 number of 2D
//!   points, each (f64 x, f64 y, u64 point3D id); `points3D.bin` = u64 count, then per point u64
//!   id, 3 f64 xyz, 3 u8 rgb, f64 error, u64 track length, each (u32 image id, u32 point2D index).
//!   Every count is checked against the bytes left before anything is allocated for it.
//! - Text files: `#` comments; `images.txt` has two lines per image (the second, the 2D points,
//!   may be empty).
//!
//! # Our scene
//! - Distorted cameras are undistorted at load time into pinhole cameras of the same size
//!   ([`Undistortion`]: same principal point, focal scaled so that no border is blank); pinhole
//!   models pass through without resampling.
//! - The normalised frame (region of interest = unit sphere) is a similarity of COLMAP's world:
//!   isotropic scale and translation, **no rotation** (orientation is kept). Its sphere comes from
//!   the sparse points ([`ColmapModel::bound_sphere`]) or from [`LoadOptions::bound_sphere`]
//!   (COLMAP units). `world_from_normalized` maps back to COLMAP units.
//! - Views are sorted by image name, so the order does not depend on COLMAP's image ids.

use crate::error::{DatasetError, Result, io_err};
use crate::idr::image_size;
use crate::images::MAX_IMAGE_SIDE;
use crate::images::{Mask, RgbImage, load_mask, load_rgb};
use crate::io::write_atomic;
use crate::scene::{CameraRecord, Format, LoadOptions, Scene, SceneCameras, SceneSource, View};
use crate::undistort::{Distortion, Undistortion};
use camera_geom::{Intrinsics, PinholeCamera, PixelCenters, Rigid3};
use glam::{DMat3, DMat4, DQuat, DVec3};
use rayon::prelude::*;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::str::FromStr;

// ----- files -------------------------------------------------------------------------------

/// Binary (`.bin`) or text (`.txt`) model files.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModelEncoding {
    /// `cameras.bin`, `images.bin`, `points3D.bin`.
    Binary,
    /// `cameras.txt`, `images.txt`, `points3D.txt`.
    Text,
}

/// The three files of a sparse model.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ModelFiles {
    /// `cameras.bin` or `cameras.txt`.
    pub cameras: PathBuf,
    /// `images.bin` or `images.txt`.
    pub images: PathBuf,
    /// `points3D.bin` or `points3D.txt`.
    pub points3d: PathBuf,
    /// Which form.
    pub encoding: ModelEncoding,
}

impl ModelFiles {
    /// The model files of `model_dir` in one encoding, if all three exist.
    pub fn in_dir(model_dir: &Path, encoding: ModelEncoding) -> Option<ModelFiles> {
        let ext = match encoding {
            ModelEncoding::Binary => "bin",
            ModelEncoding::Text => "txt",
        };
        let files = ModelFiles {
            cameras: model_dir.join(format!("cameras.{ext}")),
            images: model_dir.join(format!("images.{ext}")),
            points3d: model_dir.join(format!("points3D.{ext}")),
            encoding,
        };
        (files.cameras.is_file() && files.images.is_file() && files.points3d.is_file()).then_some(files)
    }

    /// The model files of `model_dir`: binary when all three `.bin` exist (COLMAP's default),
    /// otherwise text.
    pub fn find(model_dir: &Path) -> Option<ModelFiles> {
        ModelFiles::in_dir(model_dir, ModelEncoding::Binary).or_else(|| ModelFiles::in_dir(model_dir, ModelEncoding::Text))
    }
}

// ----- model -------------------------------------------------------------------------------

/// The camera models psneus reads, with COLMAP's parameters (pixels, half-integer centres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CameraModel {
    /// `SIMPLE_PINHOLE` (id 0): `f, cx, cy`.
    SimplePinhole {
        /// Focal length.
        f: f64,
        /// Principal point x.
        cx: f64,
        /// Principal point y.
        cy: f64,
    },
    /// `PINHOLE` (id 1): `fx, fy, cx, cy`.
    Pinhole {
        /// Focal length x.
        fx: f64,
        /// Focal length y.
        fy: f64,
        /// Principal point x.
        cx: f64,
        /// Principal point y.
        cy: f64,
    },
    /// `SIMPLE_RADIAL` (id 2): `f, cx, cy, k`.
    SimpleRadial {
        /// Focal length.
        f: f64,
        /// Principal point x.
        cx: f64,
        /// Principal point y.
        cy: f64,
        /// Radial coefficient of r².
        k: f64,
    },
    /// `RADIAL` (id 3): `f, cx, cy, k1, k2`.
    Radial {
        /// Focal length.
        f: f64,
        /// Principal point x.
        cx: f64,
        /// Principal point y.
        cy: f64,
        /// Radial coefficient of r².
        k1: f64,
        /// Radial coefficient of r⁴.
        k2: f64,
    },
    /// `OPENCV` (id 4): `fx, fy, cx, cy, k1, k2, p1, p2`.
    OpenCv {
        /// Focal length x.
        fx: f64,
        /// Focal length y.
        fy: f64,
        /// Principal point x.
        cx: f64,
        /// Principal point y.
        cy: f64,
        /// Radial coefficient of r².
        k1: f64,
        /// Radial coefficient of r⁴.
        k2: f64,
        /// Tangential coefficient p1.
        p1: f64,
        /// Tangential coefficient p2.
        p2: f64,
    },
}

/// COLMAP's camera model names by model id (`src/colmap/sensor/models.h`), supported or not.
const MODEL_NAMES: [&str; 12] = [
    "SIMPLE_PINHOLE",
    "PINHOLE",
    "SIMPLE_RADIAL",
    "RADIAL",
    "OPENCV",
    "OPENCV_FISHEYE",
    "FULL_OPENCV",
    "FOV",
    "SIMPLE_RADIAL_FISHEYE",
    "RADIAL_FISHEYE",
    "THIN_PRISM_FISHEYE",
    "RAD_TAN_THIN_PRISM_FISHEYE",
];

/// Number of parameters of the supported models, by model id.
const SUPPORTED_PARAMS: [usize; 5] = [3, 4, 4, 5, 8];

impl CameraModel {
    /// The names of the supported models.
    pub const SUPPORTED: [&'static str; 5] = ["SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV"];

    /// COLMAP's name of the model.
    pub fn name(&self) -> &'static str {
        MODEL_NAMES[self.id()]
    }

    /// COLMAP's model id.
    pub fn id(&self) -> usize {
        match self {
            CameraModel::SimplePinhole { .. } => 0,
            CameraModel::Pinhole { .. } => 1,
            CameraModel::SimpleRadial { .. } => 2,
            CameraModel::Radial { .. } => 3,
            CameraModel::OpenCv { .. } => 4,
        }
    }

    /// The model with id `id` from its parameters (`params.len()` must be the model's count).
    fn from_params(id: usize, p: &[f64]) -> CameraModel {
        match id {
            0 => CameraModel::SimplePinhole { f: p[0], cx: p[1], cy: p[2] },
            1 => CameraModel::Pinhole { fx: p[0], fy: p[1], cx: p[2], cy: p[3] },
            2 => CameraModel::SimpleRadial { f: p[0], cx: p[1], cy: p[2], k: p[3] },
            3 => CameraModel::Radial { f: p[0], cx: p[1], cy: p[2], k1: p[3], k2: p[4] },
            _ => CameraModel::OpenCv { fx: p[0], fy: p[1], cx: p[2], cy: p[3], k1: p[4], k2: p[5], p1: p[6], p2: p[7] },
        }
    }

    /// The pinhole part: `K` in COLMAP's pixel coordinates (half-integer centres), no skew.
    pub fn intrinsics(&self) -> Intrinsics {
        let (fx, fy, cx, cy) = match *self {
            CameraModel::SimplePinhole { f, cx, cy } | CameraModel::SimpleRadial { f, cx, cy, .. } | CameraModel::Radial { f, cx, cy, .. } => {
                (f, f, cx, cy)
            }
            CameraModel::Pinhole { fx, fy, cx, cy } | CameraModel::OpenCv { fx, fy, cx, cy, .. } => (fx, fy, cx, cy),
        };
        Intrinsics { fx, fy, cx, cy, skew: 0.0 }
    }

    /// The lens distortion ([`Distortion::NONE`] for the pinhole models).
    pub fn distortion(&self) -> Distortion {
        match *self {
            CameraModel::SimplePinhole { .. } | CameraModel::Pinhole { .. } => Distortion::NONE,
            CameraModel::SimpleRadial { k, .. } => Distortion { k1: k, ..Distortion::NONE },
            CameraModel::Radial { k1, k2, .. } => Distortion { k1, k2, ..Distortion::NONE },
            CameraModel::OpenCv { k1, k2, p1, p2, .. } => Distortion { k1, k2, p1, p2 },
        }
    }
}

/// A camera of `cameras.bin|txt` (shared by the images that name its id).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColmapCamera {
    /// COLMAP's camera id.
    pub camera_id: u32,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Model and parameters.
    pub model: CameraModel,
}

/// A registered image of `images.bin|txt`.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapImage {
    /// COLMAP's image id.
    pub image_id: u32,
    /// The camera it was taken with.
    pub camera_id: u32,
    /// File name relative to the image folder (may contain `/`).
    pub name: String,
    /// Rotation of `camera_from_world` as a quaternion `[qw, qx, qy, qz]`, as stored (COLMAP
    /// writes unit quaternions; [`ColmapImage::camera_from_world`] normalises).
    pub quaternion: [f64; 4],
    /// Translation of `camera_from_world`, as stored.
    pub translation: DVec3,
    /// Number of 2D keypoints listed for the image (they are not kept).
    pub points2d: usize,
}

impl ColmapImage {
    /// COLMAP's `camera_from_world` (world units as COLMAP's), the quaternion normalised.
    pub fn camera_from_world(&self) -> Rigid3 {
        let [w, x, y, z] = self.quaternion;
        Rigid3 { rotation: DMat3::from_quat(DQuat::from_xyzw(x, y, z, w).normalize()), translation: self.translation }
    }
}

/// A 3D point of `points3D.bin|txt` (its track is summarised, not kept).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColmapPoint {
    /// COLMAP's point id.
    pub point3d_id: u64,
    /// Position in COLMAP's world frame.
    pub point_in_world: DVec3,
    /// Colour.
    pub color: [u8; 3],
    /// Mean reprojection error (pixels).
    pub error: f64,
    /// Number of observations in the track.
    pub track_length: u32,
    /// Number of distinct images in the track.
    pub images: u32,
}

/// A sparse model as read from its three files.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapModel {
    /// Where it was read from.
    pub files: ModelFiles,
    /// The cameras, in file order.
    pub cameras: Vec<ColmapCamera>,
    /// The registered images, in file order.
    pub images: Vec<ColmapImage>,
    /// The 3D points, in file order.
    pub points: Vec<ColmapPoint>,
}

/// A registered image as a pinhole camera in COLMAP's world frame and units, at the model's
/// resolution, with the resampling that makes its image pinhole (if any).
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapView {
    /// The image name (relative path in the image folder).
    pub name: String,
    /// COLMAP's image id.
    pub image_id: u32,
    /// COLMAP's camera id.
    pub camera_id: u32,
    /// The (undistorted) pinhole camera, [`PixelCenters::HalfInteger`], COLMAP world units.
    pub camera: PinholeCamera,
    /// The resampling from the file's pixels to `camera`; `None` for pinhole models.
    pub undistortion: Option<Undistortion>,
}

/// The sphere that becomes the unit sphere of the normalised frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoundSphere {
    /// Centre, COLMAP world units.
    pub center: DVec3,
    /// Radius, COLMAP world units.
    pub radius: f64,
    /// How many sparse points defined it (0 when it was given).
    pub points_used: usize,
}

/// A 3D point takes part in the bound sphere when at least this many distinct images observe it
/// and it projects inside at least this many images with positive depth.
pub const MIN_VIEWS: u32 = 3;
/// Per-axis percentile (and 1 − it) of the sparse points that bounds the region of interest:
/// robust to the stray points SfM always leaves.
pub const BOUND_PERCENTILE: f64 = 0.02;
/// The bound sphere's radius is the farthest inlier's distance times this margin.
pub const RADIUS_MARGIN: f64 = 1.1;

fn corrupt_binary(path: &Path, message: String) -> DatasetError {
    DatasetError::Corrupt { path: path.to_path_buf(), kind: "COLMAP binary model", message }
}

fn corrupt_text(path: &Path, line: usize, message: String) -> DatasetError {
    DatasetError::Corrupt { path: path.to_path_buf(), kind: "COLMAP text model", message: format!("line {line}: {message}") }
}

fn unsupported_model(path: &Path, camera_id: u32, name: &str) -> DatasetError {
    DatasetError::Unsupported {
        path: path.to_path_buf(),
        message: format!(
            "camera {camera_id}: camera model {name} (supported: {}); rerun COLMAP with one of them, or \
             write pinhole images with `colmap image_undistorter`",
            CameraModel::SUPPORTED.join(", ")
        ),
    }
}

fn check_camera(path: &Path, camera: &ColmapCamera) -> Result<()> {
    let k = camera.model.intrinsics();
    let d = camera.model.distortion();
    let entry = || format!("camera {}", camera.camera_id);
    if ![k.fx, k.fy, k.cx, k.cy].iter().all(|v| v.is_finite()) || !d.is_finite() {
        return Err(DatasetError::InvalidValue { path: path.to_path_buf(), entry: entry(), message: "non-finite parameter".into() });
    }
    if k.fx <= 0.0 || k.fy <= 0.0 || camera.width == 0 || camera.height == 0 {
        return Err(DatasetError::InvalidValue {
            path: path.to_path_buf(),
            entry: entry(),
            message: format!("focal lengths ({}, {}) and size {}×{} must be positive", k.fx, k.fy, camera.width, camera.height),
        });
    }
    // A larger size is corruption, and would make the undistortion plan scan an absurd border.
    if camera.width > MAX_IMAGE_SIDE || camera.height > MAX_IMAGE_SIDE {
        return Err(DatasetError::InvalidValue {
            path: path.to_path_buf(),
            entry: entry(),
            message: format!("size {}×{} exceeds {MAX_IMAGE_SIDE} pixels a side: corrupt", camera.width, camera.height),
        });
    }
    Ok(())
}

mod binary;
mod text;
mod workspace;
use binary::*;
use text::*;
pub use workspace::*;

impl ColmapModel {
    /// Reads the model in `model_dir` (binary if all three `.bin` files exist, else text).
    pub fn read(model_dir: &Path) -> Result<ColmapModel> {
        let files = ModelFiles::find(model_dir).ok_or_else(|| DatasetError::MissingKey {
            path: model_dir.to_path_buf(),
            key: "cameras, images and points3D (.bin or .txt): a COLMAP sparse model".into(),
        })?;
        ColmapModel::read_files(files)
    }

    /// Reads the three files.
    pub fn read_files(files: ModelFiles) -> Result<ColmapModel> {
        let (cameras, images, points3d) = (read_bytes(&files.cameras)?, read_bytes(&files.images)?, read_bytes(&files.points3d)?);
        ColmapModel::parse(files, &cameras, &images, &points3d)
    }

    /// Parses the contents of the three files (`files` gives their names for messages and the
    /// encoding). Every count and length is checked against the bytes present.
    pub fn parse(files: ModelFiles, cameras: &[u8], images: &[u8], points3d: &[u8]) -> Result<ColmapModel> {
        let (cameras, images, points) = match files.encoding {
            ModelEncoding::Binary => {
                (cameras_binary(cameras, &files.cameras)?, images_binary(images, &files.images)?, points_binary(points3d, &files.points3d)?)
            }
            ModelEncoding::Text => {
                (cameras_text(cameras, &files.cameras)?, images_text(images, &files.images)?, points_text(points3d, &files.points3d)?)
            }
        };
        Ok(ColmapModel { files, cameras, images, points })
    }

    /// The camera with id `camera_id`.
    pub fn camera(&self, camera_id: u32) -> Option<&ColmapCamera> {
        self.cameras.iter().find(|c| c.camera_id == camera_id)
    }

    /// The registered images as pinhole cameras in COLMAP's world frame and units, sorted by
    /// name. Distorted cameras get an [`Undistortion`] (computed once per COLMAP camera, from
    /// the intrinsics alone). Errors: duplicate image names or ids, an unknown camera id, a
    /// quaternion that is not a rotation, a distortion that cannot be undistorted.
    pub fn views(&self) -> Result<Vec<ColmapView>> {
        let images_path = &self.files.images;
        // One undistortion plan per COLMAP camera (shared by its images), in parallel.
        let planned = self
            .cameras
            .par_iter()
            .map(|camera| {
                let distortion = camera.model.distortion();
                if distortion.is_none() {
                    return Ok((camera, None));
                }
                let plan = Undistortion::new(camera.model.intrinsics(), distortion, camera.width, camera.height).ok_or_else(|| {
                    DatasetError::Unsupported {
                        path: self.files.cameras.clone(),
                        message: format!(
                            "camera {}: {distortion:?} cannot be undistorted without a blank border (principal point outside \
                             the image, or a lens model that folds inside it)",
                            camera.camera_id
                        ),
                    }
                })?;
                Ok((camera, Some(plan)))
            })
            .collect::<Result<Vec<_>>>()?;
        let mut plans: HashMap<u32, (&ColmapCamera, Option<Undistortion>)> = HashMap::with_capacity(planned.len());
        for (camera, plan) in planned {
            if plans.insert(camera.camera_id, (camera, plan)).is_some() {
                return Err(DatasetError::InvalidValue {
                    path: self.files.cameras.clone(),
                    entry: format!("camera {}", camera.camera_id),
                    message: "duplicate camera id".into(),
                });
            }
        }
        let mut order: Vec<&ColmapImage> = self.images.iter().collect();
        order.sort_by(|a, b| a.name.cmp(&b.name).then(a.image_id.cmp(&b.image_id)));
        for pair in order.windows(2) {
            if pair[0].name == pair[1].name {
                return Err(DatasetError::InvalidValue {
                    path: images_path.clone(),
                    entry: format!("image {}", pair[1].image_id),
                    message: format!("duplicate name {:?} (also image {})", pair[1].name, pair[0].image_id),
                });
            }
        }
        let mut ids: Vec<u32> = self.images.iter().map(|i| i.image_id).collect();
        ids.sort_unstable();
        if let Some(w) = ids.windows(2).find(|w| w[0] == w[1]) {
            return Err(DatasetError::InvalidValue {
                path: images_path.clone(),
                entry: format!("image {}", w[0]),
                message: "duplicate image id".into(),
            });
        }
        order
            .into_iter()
            .map(|image| {
                let entry = || format!("image {} ({})", image.image_id, image.name);
                let Some(&(camera, undistortion)) = plans.get(&image.camera_id) else {
                    return Err(DatasetError::InvalidValue {
                        path: images_path.clone(),
                        entry: entry(),
                        message: format!("camera {} is not in {}", image.camera_id, self.files.cameras.display()),
                    });
                };
                let q = image.quaternion;
                let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
                if !(norm.is_finite() && norm > 1e-12) {
                    return Err(DatasetError::InvalidValue {
                        path: images_path.clone(),
                        entry: entry(),
                        message: format!("quaternion {q:?} is not a rotation"),
                    });
                }
                let intrinsics = undistortion.map_or(camera.model.intrinsics(), |u| u.target);
                let camera_view = PinholeCamera::new(intrinsics, camera.width, camera.height, image.camera_from_world(), PixelCenters::HalfInteger)
                    .map_err(|source| DatasetError::Camera { path: images_path.clone(), entry: entry(), source })?;
                Ok(ColmapView { name: image.name.clone(), image_id: image.image_id, camera_id: camera.camera_id, camera: camera_view, undistortion })
            })
            .collect()
    }

    /// The region of interest from the sparse points, in COLMAP units.
    ///
    /// Points count when at least [`MIN_VIEWS`] distinct images observe them and they project,
    /// with positive depth, inside at least [`MIN_VIEWS`] of `views` (what the cameras see). The
    /// centre is the middle of the per-axis [`BOUND_PERCENTILE`] / 1 − [`BOUND_PERCENTILE`]
    /// percentiles (robust to stray points); the radius is the farthest point inside that
    /// percentile box times [`RADIUS_MARGIN`]. Errors (naming the points file, suggesting
    /// [`LoadOptions::bound_sphere`]) when no point qualifies.
    pub fn bound_sphere(&self, views: &[ColmapView]) -> Result<BoundSphere> {
        let seen = |p: &DVec3| {
            let mut count = 0;
            for v in views {
                let q = v.camera.pixel_space_from_world(*p);
                if q.z > 0.0 && q.x >= 0.0 && q.y >= 0.0 && q.x <= v.camera.width as f64 && q.y <= v.camera.height as f64 {
                    count += 1;
                    if count >= MIN_VIEWS {
                        return true;
                    }
                }
            }
            false
        };
        let kept: Vec<DVec3> =
            self.points.par_iter().filter(|p| p.images >= MIN_VIEWS && p.point_in_world.is_finite()).map(|p| p.point_in_world).filter(seen).collect();
        let no_sphere = |why: String| DatasetError::InvalidValue {
            path: self.files.points3d.clone(),
            entry: "3D points".into(),
            message: format!(
                "{why}: the region of interest (the unit sphere of the normalised frame) cannot be found; \
                 give it in COLMAP units: `data.bound=[x, y, z, radius]` (train) or `--bound x,y,z,radius` (import, cameras)"
            ),
        };
        if kept.is_empty() {
            return Err(no_sphere(format!(
                "none of the {} points is seen by ≥ {MIN_VIEWS} images and projects inside ≥ {MIN_VIEWS} of the {} cameras",
                self.points.len(),
                views.len()
            )));
        }
        let mut lo = DVec3::ZERO;
        let mut hi = DVec3::ZERO;
        let mut axis: Vec<f64> = Vec::with_capacity(kept.len());
        let last = kept.len() - 1;
        let (i_lo, i_hi) = ((BOUND_PERCENTILE * last as f64).floor() as usize, ((1.0 - BOUND_PERCENTILE) * last as f64).ceil() as usize);
        for a in 0..3 {
            axis.clear();
            axis.extend(kept.iter().map(|p| p[a]));
            lo[a] = *axis.select_nth_unstable_by(i_lo, f64::total_cmp).1;
            hi[a] = *axis.select_nth_unstable_by(i_hi, f64::total_cmp).1;
        }
        let center = 0.5 * (lo + hi);
        let inside = kept.iter().filter(|p| p.cmpge(lo).all() && p.cmple(hi).all());
        let (count, farthest) = inside.fold((0usize, 0.0f64), |(n, r), p| (n + 1, r.max((*p - center).length())));
        let radius = farthest * RADIUS_MARGIN;
        if !(radius.is_finite() && radius > 0.0) {
            return Err(no_sphere(format!("the {} qualifying points span no volume (radius {radius})", kept.len())));
        }
        Ok(BoundSphere { center, radius, points_used: count })
    }
}
