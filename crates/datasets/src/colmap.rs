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
use crate::npy::{npy_bytes, write_npz};
use crate::scene::{CameraRecord, Format, LoadOptions, Scene, SceneCameras, SceneSource, View};
use crate::undistort::{Distortion, Undistortion};
use camera_geom::{Intrinsics, PinholeCamera, PixelCenters, Rigid3, projection_from_parts};
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

// ----- binary ------------------------------------------------------------------------------

/// A cursor over a binary model file that checks every read against the bytes left.
struct Bin<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Bin<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8]> {
        let left = self.bytes.len() - self.pos;
        if n > left {
            return Err(corrupt_binary(self.path, format!("cut short at byte {}: {what} needs {n} bytes, {left} left", self.pos)));
        }
        let out = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(out)
    }
    fn u8(&mut self, what: &str) -> Result<u8> {
        Ok(self.take(1, what)?[0])
    }
    fn u32(&mut self, what: &str) -> Result<u32> {
        Ok(u32::from_le_bytes(self.take(4, what)?.try_into().expect("4 bytes")))
    }
    fn i32(&mut self, what: &str) -> Result<i32> {
        Ok(i32::from_le_bytes(self.take(4, what)?.try_into().expect("4 bytes")))
    }
    fn u64(&mut self, what: &str) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take(8, what)?.try_into().expect("8 bytes")))
    }
    fn f64(&mut self, what: &str) -> Result<f64> {
        Ok(f64::from_le_bytes(self.take(8, what)?.try_into().expect("8 bytes")))
    }
    /// A count of items of at least `min_bytes` each, checked against the bytes left so that a
    /// corrupt count never drives an allocation.
    fn count(&mut self, what: &str, min_bytes: usize) -> Result<usize> {
        let at = self.pos;
        let n = self.u64(what)?;
        let left = (self.bytes.len() - self.pos) as u64;
        if n.checked_mul(min_bytes as u64).is_none_or(|need| need > left) {
            return Err(corrupt_binary(
                self.path,
                format!("cut short or corrupt: {what} at byte {at} is {n}, needing at least {min_bytes} bytes each, {left} bytes left"),
            ));
        }
        Ok(n as usize)
    }
    fn size(&mut self, what: &str) -> Result<u32> {
        let v = self.u64(what)?;
        u32::try_from(v).map_err(|_| corrupt_binary(self.path, format!("{what} {v} at byte {} is out of range", self.pos - 8)))
    }
    fn name(&mut self) -> Result<String> {
        let at = self.pos;
        let end = self.bytes[self.pos..]
            .iter()
            .position(|b| *b == 0)
            .ok_or_else(|| corrupt_binary(self.path, format!("cut short at byte {at}: image name without its terminating NUL")))?;
        let bytes = self.take(end + 1, "image name")?;
        String::from_utf8(bytes[..end].to_vec()).map_err(|_| corrupt_binary(self.path, format!("image name at byte {at} is not UTF-8")))
    }
    fn finish(&self) -> Result<()> {
        let left = self.bytes.len() - self.pos;
        if left != 0 {
            return Err(corrupt_binary(self.path, format!("{left} unexpected bytes after the last record (byte {})", self.pos)));
        }
        Ok(())
    }
}

fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(io_err(path))
}

fn cameras_binary(bytes: &[u8], path: &Path) -> Result<Vec<ColmapCamera>> {
    let mut b = Bin { path, bytes, pos: 0 };
    let n = b.count("number of cameras", 24)?;
    let mut cameras = Vec::with_capacity(n);
    for _ in 0..n {
        let camera_id = b.u32("camera id")?;
        let model_id = b.i32("camera model id")?;
        let width = b.size("camera width")?;
        let height = b.size("camera height")?;
        let Some(&count) = usize::try_from(model_id).ok().and_then(|i| SUPPORTED_PARAMS.get(i)) else {
            let name = match usize::try_from(model_id).ok().and_then(|i| MODEL_NAMES.get(i)) {
                Some(name) => format!("{name} (id {model_id})"),
                None => format!("with unknown id {model_id}"),
            };
            return Err(unsupported_model(path, camera_id, &name));
        };
        let mut params = [0.0; 8];
        for p in params.iter_mut().take(count) {
            *p = b.f64("camera parameter")?;
        }
        let camera = ColmapCamera { camera_id, width, height, model: CameraModel::from_params(model_id as usize, &params[..count]) };
        check_camera(path, &camera)?;
        cameras.push(camera);
    }
    b.finish()?;
    Ok(cameras)
}

/// Bytes of an image record before its name: id, quaternion, translation, camera id.
const IMAGE_HEAD_BYTES: usize = 4 + 4 * 8 + 3 * 8 + 4;

fn images_binary(bytes: &[u8], path: &Path) -> Result<Vec<ColmapImage>> {
    let mut b = Bin { path, bytes, pos: 0 };
    // Smallest record: head, an empty name (1 NUL byte), the 2D point count.
    let n = b.count("number of images", IMAGE_HEAD_BYTES + 1 + 8)?;
    let mut images = Vec::with_capacity(n);
    for _ in 0..n {
        let image_id = b.u32("image id")?;
        let mut quaternion = [0.0; 4];
        for q in &mut quaternion {
            *q = b.f64("image quaternion")?;
        }
        let translation = DVec3::new(b.f64("image translation")?, b.f64("image translation")?, b.f64("image translation")?);
        let camera_id = b.u32("image camera id")?;
        let name = b.name()?;
        let points2d = b.count("number of 2D points", 24)?;
        b.take(points2d * 24, "2D points")?;
        images.push(ColmapImage { image_id, camera_id, name, quaternion, translation, points2d });
    }
    b.finish()?;
    Ok(images)
}

/// Number of distinct values in `ids` (sorted in place).
fn distinct(ids: &mut [u32]) -> u32 {
    ids.sort_unstable();
    (ids.len() - ids.windows(2).filter(|w| w[0] == w[1]).count()) as u32
}

fn points_binary(bytes: &[u8], path: &Path) -> Result<Vec<ColmapPoint>> {
    let mut b = Bin { path, bytes, pos: 0 };
    let n = b.count("number of 3D points", 8 + 24 + 3 + 8 + 8)?;
    let mut points = Vec::with_capacity(n);
    let mut track = Vec::new();
    for _ in 0..n {
        let point3d_id = b.u64("point id")?;
        let point_in_world = DVec3::new(b.f64("point xyz")?, b.f64("point xyz")?, b.f64("point xyz")?);
        let color = [b.u8("point colour")?, b.u8("point colour")?, b.u8("point colour")?];
        let error = b.f64("point error")?;
        let length = b.count("track length", 8)?;
        track.clear();
        for _ in 0..length {
            track.push(b.u32("track image id")?);
            b.u32("track point2D index")?;
        }
        let track_length = u32::try_from(length).map_err(|_| corrupt_binary(path, format!("track of point {point3d_id} is too long")))?;
        points.push(ColmapPoint { point3d_id, point_in_world, color, error, track_length, images: distinct(&mut track) });
    }
    b.finish()?;
    Ok(points)
}

// ----- text --------------------------------------------------------------------------------

fn as_text<'a>(bytes: &'a [u8], path: &Path) -> Result<&'a str> {
    std::str::from_utf8(bytes).map_err(|e| DatasetError::Corrupt {
        path: path.to_path_buf(),
        kind: "COLMAP text model",
        message: format!("not UTF-8 text (byte {})", e.valid_up_to()),
    })
}

/// The whitespace-separated fields of one line, with the line number for messages.
struct Fields<'a> {
    path: &'a Path,
    line: usize,
    rest: &'a str,
}

impl<'a> Fields<'a> {
    fn token(&mut self) -> Option<&'a str> {
        let s = self.rest.trim_start();
        if s.is_empty() {
            return None;
        }
        let end = s.find(char::is_whitespace).unwrap_or(s.len());
        self.rest = &s[end..];
        Some(&s[..end])
    }
    fn next<T: FromStr>(&mut self, what: &str) -> Result<T> {
        let token = self.token().ok_or_else(|| corrupt_text(self.path, self.line, format!("missing {what}")))?;
        token.parse().map_err(|_| corrupt_text(self.path, self.line, format!("{what}: cannot read {token:?}")))
    }
    /// The rest of the line, trimmed.
    fn rest(&mut self) -> &'a str {
        std::mem::take(&mut self.rest).trim()
    }
}

/// Numbered lines that are neither empty nor comments.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines().enumerate().map(|(i, l)| (i + 1, l.trim())).filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

fn cameras_text(bytes: &[u8], path: &Path) -> Result<Vec<ColmapCamera>> {
    let text = as_text(bytes, path)?;
    let mut cameras = Vec::new();
    for (line, content) in data_lines(text) {
        let mut f = Fields { path, line, rest: content };
        let camera_id: u32 = f.next("CAMERA_ID")?;
        let model = f.token().ok_or_else(|| corrupt_text(path, line, "missing MODEL".into()))?;
        let width = f.next("WIDTH")?;
        let height = f.next("HEIGHT")?;
        let Some(id) = CameraModel::SUPPORTED.iter().position(|m| *m == model) else {
            return Err(unsupported_model(path, camera_id, model));
        };
        let mut params = [0.0; 8];
        let count = SUPPORTED_PARAMS[id];
        for (i, p) in params.iter_mut().take(count).enumerate() {
            *p = f.next(&format!("{model} parameter {}", i + 1))?;
        }
        if f.token().is_some() {
            return Err(corrupt_text(path, line, format!("{model} takes {count} parameters, the line has more")));
        }
        let camera = ColmapCamera { camera_id, width, height, model: CameraModel::from_params(id, &params[..count]) };
        check_camera(path, &camera)?;
        cameras.push(camera);
    }
    Ok(cameras)
}

fn images_text(bytes: &[u8], path: &Path) -> Result<Vec<ColmapImage>> {
    let text = as_text(bytes, path)?;
    let mut images = Vec::new();
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l));
    while let Some((line, content)) = lines.next() {
        let content = content.trim();
        if content.is_empty() || content.starts_with('#') {
            continue;
        }
        let mut f = Fields { path, line, rest: content };
        let image_id = f.next("IMAGE_ID")?;
        let quaternion = [f.next("QW")?, f.next("QX")?, f.next("QY")?, f.next("QZ")?];
        let translation = DVec3::new(f.next("TX")?, f.next("TY")?, f.next("TZ")?);
        let camera_id = f.next("CAMERA_ID")?;
        let name = f.rest();
        if name.is_empty() {
            return Err(corrupt_text(path, line, "missing NAME".into()));
        }
        // The 2D points: the very next line, possibly empty (or absent at the end of the file).
        let (line, points_line) = lines.next().unwrap_or((line + 1, ""));
        let mut f = Fields { path, line, rest: points_line };
        let hint = "two lines per image: the second lists X Y POINT3D_ID per 2D point, or is empty";
        let mut values = 0usize;
        while let Some(token) = f.token() {
            let field = ["X", "Y", "POINT3D_ID"][values % 3];
            let ok = if values % 3 == 2 { token.parse::<i64>().is_ok() } else { token.parse::<f64>().is_ok() };
            if !ok {
                return Err(corrupt_text(path, line, format!("{field} of a 2D point of image {image_id}: cannot read {token:?} ({hint})")));
            }
            values += 1;
        }
        if !values.is_multiple_of(3) {
            return Err(corrupt_text(path, line, format!("{values} values for the 2D points of image {image_id}, not a multiple of 3 ({hint})")));
        }
        let points2d = values / 3;
        images.push(ColmapImage { image_id, camera_id, name: name.to_string(), quaternion, translation, points2d });
    }
    Ok(images)
}

fn points_text(bytes: &[u8], path: &Path) -> Result<Vec<ColmapPoint>> {
    let text = as_text(bytes, path)?;
    let mut points = Vec::new();
    let mut track = Vec::new();
    for (line, content) in data_lines(text) {
        let mut f = Fields { path, line, rest: content };
        let point3d_id = f.next("POINT3D_ID")?;
        let point_in_world = DVec3::new(f.next("X")?, f.next("Y")?, f.next("Z")?);
        let color = [f.next("R")?, f.next("G")?, f.next("B")?];
        let error = f.next("ERROR")?;
        track.clear();
        while !f.rest.trim().is_empty() {
            track.push(f.next::<u32>("TRACK IMAGE_ID")?);
            f.next::<u32>("TRACK POINT2D_IDX")?;
        }
        let track_length = track.len() as u32;
        points.push(ColmapPoint { point3d_id, point_in_world, color, error, track_length, images: distinct(&mut track) });
    }
    Ok(points)
}

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

// ----- workspace ---------------------------------------------------------------------------

/// A COLMAP workspace: a sparse model, the images it was made from, optional masks.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ColmapWorkspace {
    /// The folder of the model files.
    pub model_dir: PathBuf,
    /// The folder the image names are relative to.
    pub images_dir: PathBuf,
    /// One mask per image (same name, or same stem with `.png`, or COLMAP's `NAME.png`).
    pub masks_dir: Option<PathBuf>,
}

impl ColmapWorkspace {
    /// The workspace of `dir`, if it is one: an `images/` folder and a model in `sparse/0/`,
    /// `sparse/` (as `colmap image_undistorter` writes) or `dir` itself; masks in `masks/` or
    /// `mask/` when present.
    pub fn find(dir: &Path) -> Option<ColmapWorkspace> {
        let images_dir = dir.join("images");
        if !images_dir.is_dir() {
            return None;
        }
        let model_dir = [dir.join("sparse").join("0"), dir.join("sparse"), dir.to_path_buf()].into_iter().find(|d| ModelFiles::find(d).is_some())?;
        let masks_dir = ["masks", "mask"].iter().map(|m| dir.join(m)).find(|p| p.is_dir());
        Some(ColmapWorkspace { model_dir, images_dir, masks_dir })
    }

    /// Reads the cameras (image headers only, no pixels), undistorted and normalised.
    pub fn read_cameras(&self, options: &LoadOptions) -> Result<SceneCameras> {
        Ok(self.plan(options)?.cameras)
    }

    /// Loads the scene: cameras, images (decoded, undistorted and downscaled in parallel) and
    /// masks (from the masks folder, or the images' alpha channel).
    pub fn load_scene(&self, options: &LoadOptions) -> Result<Scene> {
        let plan = self.plan(options)?;
        let views = plan
            .cameras
            .records
            .par_iter()
            .zip(&plan.views)
            .map(|(record, view)| {
                let (image, mask) = load_pixels(record, view, options)?;
                Ok(View { name: record.name.clone(), camera: record.camera, image, mask })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Scene { views, world_from_normalized: plan.cameras.world_from_normalized, source: plan.cameras.source })
    }

    /// Writes the workspace as an IDR folder `out` (see [`import_colmap`]).
    pub fn import_idr(&self, out: &Path, options: &LoadOptions) -> Result<ImportReport> {
        let plan = self.plan(options)?;
        // An earlier import's images and masks would mix with this one's.
        if std::fs::read_dir(out).is_ok_and(|mut entries| entries.next().is_some()) {
            return Err(DatasetError::Unsupported {
                path: out.to_path_buf(),
                message: "the import's folder is not empty: nothing was written (choose a new or empty folder)".into(),
            });
        }
        let (image_dir, mask_dir) = (out.join("image"), out.join("mask"));
        std::fs::create_dir_all(&image_dir).map_err(io_err(&image_dir))?;
        let has_mask = plan
            .cameras
            .records
            .par_iter()
            .zip(&plan.views)
            .enumerate()
            .map(|(i, (record, view))| {
                let (image, mask) = load_pixels(record, view, options)?;
                image.save_png(&image_dir.join(format!("{i:03}.png")))?;
                if let Some(mask) = &mask {
                    std::fs::create_dir_all(&mask_dir).map_err(io_err(&mask_dir))?;
                    mask.save_png(&mask_dir.join(format!("{i:03}.png")))?;
                }
                Ok(mask.is_some())
            })
            .collect::<Result<Vec<bool>>>()?;
        let masks = has_mask.iter().filter(|m| **m).count();
        if masks != 0 && masks != has_mask.len() {
            return Err(DatasetError::CountMismatch {
                path: self.images_dir.clone(),
                cameras: has_mask.len(),
                found: masks,
                what: "masks (alpha channels)",
            });
        }
        // P (normalised → pixels, integer centres) = K [R|t]; world_mat = P · scale_mat⁻¹ so that
        // world_mat · scale_mat gives P back, as NeuS computes it (the layout of golden::write_idr).
        let scale_mat = plan.cameras.world_from_normalized;
        let normalized_from_world = scale_mat.inverse();
        let mut entries = Vec::with_capacity(2 * plan.cameras.records.len());
        for (i, record) in plan.cameras.records.iter().enumerate() {
            let c = &record.camera;
            let shift = c.pixel_centers.offset() - PixelCenters::Integer.offset();
            let k = Intrinsics { cx: c.intrinsics.cx - shift, cy: c.intrinsics.cy - shift, ..c.intrinsics };
            let p = projection_from_parts(&k, &c.camera_from_world);
            let mut p4 = DMat4::IDENTITY;
            for (r, row) in p.iter().enumerate() {
                for (col, v) in row.iter().enumerate() {
                    p4.col_mut(col)[r] = *v;
                }
            }
            entries.push((format!("world_mat_{i}"), npy_bytes(&[4, 4], &rows_of(&(p4 * normalized_from_world)))));
            entries.push((format!("scale_mat_{i}"), npy_bytes(&[4, 4], &rows_of(&scale_mat))));
        }
        let npz_path = out.join("cameras_sphere.npz");
        let bytes = write_npz(std::io::Cursor::new(Vec::new()), &entries)
            .map_err(|e| DatasetError::Io { path: npz_path.clone(), source: std::io::Error::other(e) })?
            .into_inner();
        write_atomic(&npz_path, &bytes)?;
        let names: Vec<String> = plan.views.iter().map(|v| v.name.clone()).collect();
        let report = ImportReport {
            views: names.len(),
            undistorted: plan.views.iter().filter(|v| v.undistortion.is_some()).count(),
            masks: masks != 0,
            world_from_normalized: scale_mat,
            description: plan.cameras.source.description.clone(),
            names,
        };
        let meta = serde_json::json!({
            "source": plan.cameras.source.description,
            "model": self.model_dir,
            "images": self.images_dir,
            "masks": self.masks_dir,
            "names": report.names,
            "world_from_normalized (rows)": rows_of(&scale_mat),
        });
        write_atomic(&out.join("colmap_import.json"), serde_json::to_string_pretty(&meta).expect("json").as_bytes())?;
        Ok(report)
    }

    fn plan(&self, options: &LoadOptions) -> Result<Plan> {
        options.validate(&self.model_dir)?;
        let model = ColmapModel::read(&self.model_dir)?;
        let views = model.views()?;
        if views.is_empty() {
            return Err(DatasetError::MissingKey { path: model.files.images.clone(), key: "registered images (none listed)".into() });
        }
        let (sphere, given) = match options.bound_sphere {
            Some((center, radius)) => (BoundSphere { center, radius, points_used: 0 }, true),
            None => (model.bound_sphere(&views)?, false),
        };
        if !(sphere.center.is_finite() && sphere.radius.is_finite() && sphere.radius > 0.0) {
            return Err(DatasetError::InvalidValue {
                path: self.model_dir.clone(),
                entry: "bound sphere".into(),
                message: format!("centre {}, radius {}", sphere.center, sphere.radius),
            });
        }
        let n = options.downscale;
        let records = views
            .par_iter()
            .map(|view| -> Result<CameraRecord> {
                let listed_in = &model.files.images;
                let entry = format!("the name of image {:?}", view.name);
                let image_path = crate::contain::join_inside(&self.images_dir, &view.name, listed_in, &entry)?;
                let image_path = crate::contain::inside(&self.images_dir, image_path, listed_in, &entry)?;
                if !image_path.is_file() {
                    return Err(DatasetError::NotFound { path: image_path, why: format!("listed in {}", model.files.images.display()) });
                }
                let size = image_size(&image_path)?;
                let expected = (view.camera.width, view.camera.height);
                if size != expected {
                    return Err(DatasetError::SizeMismatch { path: image_path, found: size, expected, why: "the size of its COLMAP camera" });
                }
                let mask_path = match &self.masks_dir {
                    Some(dir) => {
                        let path = crate::contain::inside(dir, mask_file(dir, &view.name)?, listed_in, &entry)?;
                        let found = image_size(&path)?;
                        if found != expected {
                            return Err(DatasetError::SizeMismatch { path, found, expected, why: "a mask must match its image" });
                        }
                        Some(path)
                    }
                    None => None,
                };
                // point_in_world = centre + radius · point_in_normalized, so
                // point_in_camera = R·centre + t + radius·R·point_in_normalized; divide by the
                // radius (a scale of the camera frame changes no pixel).
                let cfw = view.camera.camera_from_world;
                let camera_from_normalized = Rigid3 { rotation: cfw.rotation, translation: (cfw.transform_point(sphere.center)) / sphere.radius };
                let camera = PinholeCamera::new(
                    view.camera.intrinsics.downscaled(n, PixelCenters::HalfInteger),
                    view.camera.width / n,
                    view.camera.height / n,
                    camera_from_normalized,
                    PixelCenters::HalfInteger,
                )
                .map_err(|source| DatasetError::Camera {
                    path: model.files.images.clone(),
                    entry: format!("image {} ({})", view.image_id, view.name),
                    source,
                })?;
                Ok(CameraRecord { name: strip_extension(&view.name), camera, image_path: Some(image_path), mask_path })
            })
            .collect::<Result<Vec<_>>>()?;
        let undistorted = views.iter().filter(|v| v.undistortion.is_some()).count();
        let scales: Vec<String> = {
            let mut s: Vec<(u32, f64)> = views.iter().filter_map(|v| v.undistortion.map(|u| (v.camera_id, u.focal_scale()))).collect();
            s.sort_by_key(|(id, _)| *id);
            s.dedup_by_key(|(id, _)| *id);
            s.iter().map(|(id, f)| format!("camera {id} focal ×{f:.6}")).collect()
        };
        let description = format!(
            "COLMAP {} model {}: {} views from {}{}, {}, bound sphere centre {} radius {} ({}), downscale {}",
            match model.files.encoding {
                ModelEncoding::Binary => "binary",
                ModelEncoding::Text => "text",
            },
            self.model_dir.display(),
            views.len(),
            self.images_dir.display(),
            if self.masks_dir.is_some() { " with masks" } else { "" },
            if undistorted == 0 { "pinhole (no resampling)".to_string() } else { format!("{undistorted} undistorted ({})", scales.join(", ")) },
            sphere.center,
            sphere.radius,
            if given { "given".to_string() } else { format!("from {} sparse points", sphere.points_used) },
            n
        );
        let world_from_normalized = DMat4::from_translation(sphere.center) * DMat4::from_scale(DVec3::splat(sphere.radius));
        Ok(Plan {
            cameras: SceneCameras {
                records,
                world_from_normalized,
                source: SceneSource { format: Format::Colmap, path: Some(self.model_dir.clone()), description },
            },
            views,
        })
    }
}

/// Cameras and the per-view resampling, in one order.
struct Plan {
    cameras: SceneCameras,
    views: Vec<ColmapView>,
}

fn strip_extension(name: &str) -> String {
    let path = Path::new(name);
    match path.extension() {
        Some(_) => path.with_extension("").to_string_lossy().into_owned(),
        None => name.to_string(),
    }
}

/// The mask of image `name`: `masks/NAME`, `masks/STEM.png` or COLMAP's `masks/NAME.png`.
fn mask_file(dir: &Path, name: &str) -> Result<PathBuf> {
    let same = dir.join(name);
    let png = dir.join(format!("{}.png", strip_extension(name)));
    let colmap = dir.join(format!("{name}.png"));
    [&same, &png, &colmap].into_iter().find(|p| p.is_file()).cloned().ok_or_else(|| DatasetError::NotFound {
        path: png.clone(),
        why: format!("the mask of image {name} (tried {}, {}, {})", same.display(), png.display(), colmap.display()),
    })
}

/// Decodes, undistorts and downscales one view's image and mask.
fn load_pixels(record: &CameraRecord, view: &ColmapView, options: &LoadOptions) -> Result<(RgbImage, Option<Mask>)> {
    let image_path = record.image_path.as_deref().expect("COLMAP records have image paths");
    let n = options.downscale;
    let full = (view.camera.width, view.camera.height);
    let check = |found: (u32, u32), path: &Path| {
        if found != full {
            return Err(DatasetError::SizeMismatch {
                path: path.to_path_buf(),
                found,
                expected: full,
                why: "the file changed size since its header was read",
            });
        }
        Ok(())
    };
    match &view.undistortion {
        None => {
            let decoded = load_rgb(image_path, n, options.background)?;
            let found = (decoded.rgb.width, decoded.rgb.height);
            if found != (full.0 / n, full.1 / n) {
                return Err(DatasetError::SizeMismatch {
                    path: image_path.to_path_buf(),
                    found,
                    expected: (full.0 / n, full.1 / n),
                    why: "the file changed size since its header was read (sizes after downscaling)",
                });
            }
            let mask = match &record.mask_path {
                Some(p) => {
                    let (mask, size) = load_mask(p, n)?;
                    check(size, p)?;
                    Some(mask)
                }
                None => decoded.alpha_mask,
            };
            Ok((decoded.rgb, mask))
        }
        Some(u) => {
            let decoded = load_rgb(image_path, 1, options.background)?;
            check((decoded.rgb.width, decoded.rgb.height), image_path)?;
            let image = u.remap_rgb(&decoded.rgb);
            let mask = match &record.mask_path {
                Some(p) => {
                    let (mask, size) = load_mask(p, 1)?;
                    check(size, p)?;
                    Some(u.remap_mask(&mask))
                }
                None => decoded.alpha_mask.map(|m| u.remap_mask(&m)),
            };
            if n == 1 { Ok((image, mask)) } else { Ok((image.downscaled(n), mask.map(|m| m.downscaled(n)))) }
        }
    }
}

fn rows_of(m: &DMat4) -> Vec<f64> {
    (0..4).flat_map(|r| (0..4).map(move |c| m.col(c)[r])).collect()
}

/// What [`import_colmap`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportReport {
    /// Number of views written (`image/000.png` …).
    pub views: usize,
    /// COLMAP image name of view i, in the order written (sorted by name).
    pub names: Vec<String>,
    /// Number of views resampled to undistort them.
    pub undistorted: usize,
    /// Whether `mask/` was written.
    pub masks: bool,
    /// The normalised frame → COLMAP's world frame (written as every `scale_mat_i`).
    pub world_from_normalized: DMat4,
    /// The loader's one-line description of the source.
    pub description: String,
}

/// Writes a COLMAP model with its images (and masks) as an IDR folder `out`:
/// `image/000.png …` (undistorted, downscaled by `options.downscale`, sorted by name),
/// `mask/000.png …` when there are masks, `cameras_sphere.npz` with `world_mat_i` and
/// `scale_mat_i` as [`golden::write_idr`](crate::golden::write_idr) writes them (integer pixel
/// centres, `scale_mat_i` = `world_from_normalized`, COLMAP units), and `colmap_import.json`
/// (the names and the source). Every file is written atomically; the IDR loader reads the same
/// cameras back.
pub fn import_colmap(model_dir: &Path, images_dir: &Path, masks_dir: Option<&Path>, out: &Path, options: &LoadOptions) -> Result<ImportReport> {
    ColmapWorkspace { model_dir: model_dir.to_path_buf(), images_dir: images_dir.to_path_buf(), masks_dir: masks_dir.map(Path::to_path_buf) }
        .import_idr(out, options)
}
