//! `transforms*.json` layouts: NeRF-synthetic (Blender) and instant-ngp / Neuralangelo.
//!
//! Poses are camera-to-world in OpenGL/Blender axes (+x right, +y up, +z backwards); we flip y
//! and z to OpenCV axes. Pixel centres are at half-integers (`cx = w/2` is the image centre).
//! Intrinsics: `fl_x`/`fl_y` or `camera_angle_x`/`camera_angle_y` (`fx = w / (2 tan(angle/2))`),
//! `cx`, `cy` (default: image centre), `sk_x` (skew); each may be overridden per frame
//! (instant-ngp). Lens distortion is not modelled: non-zero coefficients are an error.

use crate::error::{DatasetError, Result, io_err};
use crate::idr::image_size;
use crate::scene::{CameraRecord, Format, LoadOptions, SceneCameras, SceneSource};
use camera_geom::{Intrinsics, PinholeCamera, PixelCenters, Rigid3};
use glam::{DMat3, DMat4, DVec3};
use serde::Deserialize;
use std::path::{Path, PathBuf};

#[derive(Debug, Default, Clone, Deserialize)]
struct IntrinsicFields {
    camera_angle_x: Option<f64>,
    camera_angle_y: Option<f64>,
    fl_x: Option<f64>,
    fl_y: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    w: Option<f64>,
    h: Option<f64>,
    sk_x: Option<f64>,
    sk_y: Option<f64>,
    k1: Option<f64>,
    k2: Option<f64>,
    k3: Option<f64>,
    k4: Option<f64>,
    p1: Option<f64>,
    p2: Option<f64>,
}

impl IntrinsicFields {
    /// Frame values override file values.
    fn or(&self, base: &IntrinsicFields) -> IntrinsicFields {
        macro_rules! pick { ($($f:ident),*) => { IntrinsicFields { $($f: self.$f.or(base.$f)),* } } }
        pick!(camera_angle_x, camera_angle_y, fl_x, fl_y, cx, cy, w, h, sk_x, sk_y, k1, k2, k3, k4, p1, p2)
    }
}

#[derive(Debug, Deserialize)]
struct Frame {
    file_path: String,
    transform_matrix: Vec<Vec<f64>>,
    #[serde(flatten)]
    intrinsics: IntrinsicFields,
}

#[derive(Debug, Deserialize)]
struct Transforms {
    #[serde(flatten)]
    intrinsics: IntrinsicFields,
    sphere_center: Option<[f64; 3]>,
    sphere_radius: Option<f64>,
    aabb: Option<[[f64; 3]; 2]>,
    frames: Vec<Frame>,
}

/// The image file of a frame's `file_path` (already joined to the folder): the path itself, or
/// it with an image extension added.
fn resolve_image(p: PathBuf) -> Option<PathBuf> {
    if p.extension().is_some() && p.is_file() {
        return Some(p);
    }
    ["png", "jpg", "jpeg", "PNG", "JPG"]
        .iter()
        .map(|e| {
            let mut s = p.clone().into_os_string();
            s.push(".");
            s.push(e);
            PathBuf::from(s)
        })
        .find(|p| p.is_file())
}

/// An image file and its size, found from a frame's `file_path` and index.
pub(crate) type FrameImage = (PathBuf, (u32, u32));

/// Reads the cameras of a transforms JSON (image headers only).
pub(crate) fn read_cameras(json_path: &Path, format: Format, options: &LoadOptions) -> Result<SceneCameras> {
    let dir = json_path.parent().unwrap_or(Path::new("."));
    let text = std::fs::read(json_path).map_err(io_err(json_path))?;
    let image = |file_path: &str, camera: usize| -> Result<FrameImage> {
        let entry = format!("frames[{camera}].file_path");
        let named = crate::contain::join_inside(dir, file_path, json_path, &entry)?;
        let image_path = resolve_image(named.clone()).ok_or(DatasetError::MissingImage { dir: named, camera })?;
        let image_path = crate::contain::inside(dir, image_path, json_path, &entry)?;
        let size = image_size(&image_path)?;
        Ok((image_path, size))
    };
    cameras_from_json(&text, json_path, format, options, &image)
}

/// The cameras of the bytes of a transforms JSON; `image` finds a frame's image file and its
/// size (the loader reads headers; the fuzzer makes them up).
pub(crate) fn cameras_from_json(
    text: &[u8],
    json_path: &Path,
    format: Format,
    options: &LoadOptions,
    image: &dyn Fn(&str, usize) -> Result<FrameImage>,
) -> Result<SceneCameras> {
    let dir = json_path.parent().unwrap_or(Path::new("."));
    options.validate(json_path)?;
    let t: Transforms =
        serde_json::from_slice(text).map_err(|e| DatasetError::Corrupt { path: json_path.to_path_buf(), kind: "JSON", message: e.to_string() })?;
    let invalid = |entry: String, message: String| DatasetError::InvalidValue { path: json_path.to_path_buf(), entry, message };

    let (center, radius) = bound_sphere(&t, json_path, format, options)?;
    if !(center.is_finite() && radius.is_finite() && radius > 0.0) {
        return Err(invalid("bound sphere".into(), format!("centre {center}, radius {radius}")));
    }
    if t.frames.is_empty() {
        return Err(DatasetError::MissingKey { path: json_path.to_path_buf(), key: "frames (none listed)".into() });
    }

    let mut records = Vec::with_capacity(t.frames.len());
    for (i, frame) in t.frames.iter().enumerate() {
        let entry = format!("frames[{i}]");
        let (image_path, intrinsics, (w, h)) = frame_intrinsics(frame, &t.intrinsics, i, json_path, image)?;

        let m = &frame.transform_matrix;
        if !(m.len() == 3 || m.len() == 4) || m.iter().take(3).any(|r| r.len() != 4) {
            return Err(invalid(format!("{entry}.transform_matrix"), "expected 4×4 (or 3×4)".into()));
        }
        if !m.iter().flatten().all(|v| v.is_finite()) {
            return Err(invalid(format!("{entry}.transform_matrix"), "non-finite value".into()));
        }
        // OpenGL camera-to-world → OpenCV: flip the camera's y and z axes.
        let world_rotation_gl =
            DMat3::from_cols(DVec3::new(m[0][0], m[1][0], m[2][0]), DVec3::new(m[0][1], m[1][1], m[2][1]), DVec3::new(m[0][2], m[1][2], m[2][2]));
        let world_rotation_cv = world_rotation_gl * DMat3::from_diagonal(DVec3::new(1.0, -1.0, -1.0));
        let center_in_normalized = (DVec3::new(m[0][3], m[1][3], m[2][3]) - center) / radius;
        let rotation = world_rotation_cv.transpose();
        let camera_from_world = Rigid3 { rotation, translation: -(rotation * center_in_normalized) };
        let n = options.downscale;
        let camera = PinholeCamera::new(
            intrinsics.downscaled(n, PixelCenters::HalfInteger),
            w as u32 / n,
            h as u32 / n,
            camera_from_world,
            PixelCenters::HalfInteger,
        )
        .map_err(|source| DatasetError::Camera { path: json_path.to_path_buf(), entry: entry.clone(), source })?;
        records.push(CameraRecord {
            name: image_path.file_stem().unwrap_or_default().to_string_lossy().into_owned(),
            camera,
            image_path: Some(image_path),
            mask_path: None,
        });
    }
    let world_from_normalized = DMat4::from_translation(center) * DMat4::from_scale(DVec3::splat(radius));
    let description = format!(
        "{} layout: {} views from {}, bound sphere centre {center} radius {radius}, downscale {}",
        if format == Format::NerfSynthetic { "NeRF-synthetic" } else { "instant-ngp" },
        records.len(),
        json_path.display(),
        options.downscale
    );
    Ok(SceneCameras { records, world_from_normalized, source: SceneSource { format, path: Some(dir.to_path_buf()), description } })
}

/// The region of interest: the caller's bound sphere, NeRF-synthetic's radius 1.5 at the origin,
/// or the file's `sphere_center` + `sphere_radius` or `aabb`.
fn bound_sphere(t: &Transforms, json_path: &Path, format: Format, options: &LoadOptions) -> Result<(DVec3, f64)> {
    Ok(match (options.bound_sphere, format) {
        (Some(b), _) => b,
        (None, Format::NerfSynthetic) => (DVec3::ZERO, 1.5),
        (None, _) => match (t.sphere_center, t.sphere_radius, t.aabb) {
            (Some(c), Some(r), _) => (DVec3::from_array(c), r),
            (_, _, Some([lo, hi])) => {
                let (lo, hi) = (DVec3::from_array(lo), DVec3::from_array(hi));
                ((lo + hi) / 2.0, (hi - lo).length() / 2.0)
            }
            _ => {
                return Err(DatasetError::MissingKey {
                    path: json_path.to_path_buf(),
                    key: "sphere_center + sphere_radius, or aabb (the region of interest; or pass a bound sphere)".into(),
                });
            }
        },
    })
}

/// Frame `i`'s image (path, size) and intrinsics: its own keys over the file's, no distortion, w
/// and h whole and those of the image, fx from `fl_x` or `camera_angle_x` (fy likewise, else fx).
fn frame_intrinsics(
    frame: &Frame,
    shared: &IntrinsicFields,
    i: usize,
    json_path: &Path,
    image: &dyn Fn(&str, usize) -> Result<FrameImage>,
) -> Result<(PathBuf, Intrinsics, (f64, f64))> {
    let entry = format!("frames[{i}]");
    let invalid = |entry: String, message: String| DatasetError::InvalidValue { path: json_path.to_path_buf(), entry, message };
    let f = frame.intrinsics.or(shared);
    let distortion = [f.k1, f.k2, f.k3, f.k4, f.p1, f.p2];
    if distortion.iter().any(|k| k.is_some_and(|k| k != 0.0)) {
        return Err(DatasetError::Unsupported {
            path: json_path.to_path_buf(),
            message: format!("{entry}: lens distortion (k1..k4, p1, p2 non-zero); undistort the images first"),
        });
    }
    if f.sk_y.is_some_and(|s| s != 0.0) {
        return Err(DatasetError::Unsupported {
            path: json_path.to_path_buf(), message: format!("{entry}: sk_y ≠ 0 makes K not upper-triangular")
        });
    }
    let (image_path, (w_file, h_file)) = image(&frame.file_path, i)?;
    for (key, value) in [("w", f.w), ("h", f.h)] {
        if let Some(v) = value.filter(|v| !(v.is_finite() && *v >= 1.0 && v.fract() == 0.0)) {
            return Err(invalid(format!("{entry}.{key} (or the file's {key})"), format!("{v} is not a whole number of pixels")));
        }
    }
    let w = f.w.unwrap_or(w_file as f64);
    let h = f.h.unwrap_or(h_file as f64);
    if (w, h) != (w_file as f64, h_file as f64) {
        return Err(DatasetError::SizeMismatch {
            path: image_path,
            found: (w_file, h_file),
            expected: (w as u32, h as u32),
            why: "the transforms file gives another w, h",
        });
    }
    let fx = match (f.fl_x, f.camera_angle_x) {
        (Some(fx), _) => fx,
        (None, Some(a)) => 0.5 * w / (0.5 * a).tan(),
        (None, None) => return Err(DatasetError::MissingKey { path: json_path.to_path_buf(), key: format!("{entry}: fl_x or camera_angle_x") }),
    };
    let fy = match (f.fl_y, f.camera_angle_y) {
        (Some(fy), _) => fy,
        (None, Some(a)) => 0.5 * h / (0.5 * a).tan(),
        (None, None) => fx,
    };
    let intrinsics = Intrinsics { fx, fy, cx: f.cx.unwrap_or(w / 2.0), cy: f.cy.unwrap_or(h / 2.0), skew: f.sk_x.unwrap_or(0.0) };
    Ok((image_path, intrinsics, (w, h)))
}
