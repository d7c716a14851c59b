//! IDR / NeuS / DTU layout: `cameras_sphere.npz` (or `cameras.npz`) with `world_mat_i` and
//! `scale_mat_i`, numbered images in `image/` (or `images/`), optional masks in `mask/`.
//!
//! Convention (NeuS `dataset.py`): `P = world_mat_i · scale_mat_i` maps the normalised frame to
//! pixels; K and `camera_from_world` come from decomposing P (see
//! [`camera_geom::decompose_projection`]); integer pixel coordinates are pixel centres.
//! `scale_mat_0` is `world_from_normalized`. Other keys (`camera_mat_i`, `*_inv_i`) are ignored.

use crate::error::{DatasetError, Result, io_err};
use crate::npy::{NpyArray, Npz};
use crate::scene::{CameraRecord, Format, LoadOptions, SceneCameras, SceneSource};
use camera_geom::{Intrinsics, PinholeCamera, PixelCenters, decompose_projection, projection_from_parts};
use glam::DMat4;
use std::path::{Path, PathBuf};

/// The camera file of an IDR folder, if there is one.
pub(crate) fn camera_file(dir: &Path) -> Option<PathBuf> {
    ["cameras_sphere.npz", "cameras.npz"].iter().map(|n| dir.join(n)).find(|p| p.is_file())
}

fn is_image(path: &Path) -> bool {
    matches!(path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref(), Some("png" | "jpg" | "jpeg"))
}

/// A 4 × 4 matrix as its 16 values, row by row (NumPy's order).
pub(crate) fn mat4_rows(m: &DMat4) -> Vec<f64> {
    (0..4).flat_map(|r| (0..4).map(move |c| m.col(c)[r])).collect()
}

/// Writes `cameras_sphere.npz` of the IDR layout for `cameras` (in the normalised frame):
/// `scale_mat_i` = `world_from_normalized`, `world_mat_i` = P · scale_mat⁻¹ with P = K [R|t] in
/// integer pixel centres, so that world_mat · scale_mat gives P back, as NeuS computes it. The
/// one writer of the layout's cameras (golden scenes, COLMAP imports).
pub(crate) fn write_cameras(out: &Path, cameras: &[PinholeCamera], world_from_normalized: &DMat4) -> Result<()> {
    let normalized_from_world = world_from_normalized.inverse();
    let mut entries = Vec::with_capacity(2 * cameras.len());
    for (i, c) in cameras.iter().enumerate() {
        let shift = c.pixel_centers.offset() - PixelCenters::Integer.offset();
        let k = Intrinsics { cx: c.intrinsics.cx - shift, cy: c.intrinsics.cy - shift, ..c.intrinsics };
        let p = projection_from_parts(&k, &c.camera_from_world);
        let mut p4 = DMat4::IDENTITY;
        for (r, row) in p.iter().enumerate() {
            for (col, v) in row.iter().enumerate() {
                p4.col_mut(col)[r] = *v;
            }
        }
        entries.push((format!("world_mat_{i}"), crate::npy::npy_bytes(&[4, 4], &mat4_rows(&(p4 * normalized_from_world)))));
        entries.push((format!("scale_mat_{i}"), crate::npy::npy_bytes(&[4, 4], &mat4_rows(world_from_normalized))));
    }
    let npz_path = out.join("cameras_sphere.npz");
    let bytes = crate::npy::write_npz(std::io::Cursor::new(Vec::new()), &entries)
        .map_err(|e| DatasetError::Io { path: npz_path.clone(), source: std::io::Error::other(e) })?
        .into_inner();
    crate::io::write_atomic(&npz_path, &bytes)
}

/// The number a file's stem ends with (`000` → 0, `img10` → 10, `img_0007` → 7).
fn trailing_number(path: &Path) -> Option<usize> {
    let stem = path.file_stem()?.to_str()?;
    let digits = &stem[stem.trim_end_matches(|c: char| c.is_ascii_digit()).len()..];
    digits.parse().ok()
}

/// The image files of `dir` assigned to cameras 0..n: by the number each stem ends with when
/// every stem has one (`000.png`, `img2.png` before `img10.png`), otherwise in sorted order.
pub(crate) fn numbered_files(dir: &Path, n: usize, what: &'static str) -> Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> =
        std::fs::read_dir(dir).map_err(io_err(dir))?.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.is_file() && is_image(p)).collect();
    files.sort();
    let numbers: Option<Vec<usize>> = files.iter().map(|p| trailing_number(p)).collect();
    // Numbers must name one file each (`img1.png` and `mask1.png` in one folder are not a list).
    let numbers = numbers.filter(|v| {
        let mut sorted = v.clone();
        sorted.sort_unstable();
        sorted.windows(2).all(|w| w[0] != w[1])
    });
    if let Some(numbers) = numbers {
        let mut by_index = vec![None; n];
        for (file, k) in files.iter().zip(numbers) {
            if k < n {
                by_index[k] = Some(file.clone());
            }
        }
        if let Some(camera) = by_index.iter().position(Option::is_none) {
            return Err(DatasetError::MissingImage { dir: dir.to_path_buf(), camera });
        }
        if files.len() != n {
            return Err(DatasetError::CountMismatch { path: dir.to_path_buf(), cameras: n, found: files.len(), what });
        }
        Ok(by_index.into_iter().map(Option::unwrap).collect())
    } else {
        if files.len() != n {
            return Err(DatasetError::CountMismatch { path: dir.to_path_buf(), cameras: n, found: files.len(), what });
        }
        Ok(files)
    }
}

/// Width and height of an image file from its header.
pub(crate) fn image_size(path: &Path) -> Result<(u32, u32)> {
    image::image_dimensions(path).map_err(|e| match e {
        image::ImageError::IoError(source) => DatasetError::Io { path: path.to_path_buf(), source },
        other => DatasetError::Corrupt { path: path.to_path_buf(), kind: "image", message: other.to_string() },
    })
}

fn matrix4<R: std::io::Read + std::io::Seek>(npz: &mut Npz<R>, path: &Path, key: &str) -> Result<Option<DMat4>> {
    let four_by_four = |shape: &[usize]| matches!(shape, [4, 4] | [3, 4]);
    let Some(NpyArray { shape, data }) = npz.get_shaped(key, &four_by_four, "[4, 4] or [3, 4]")? else { return Ok(None) };
    let rows = shape[0];
    if !data.iter().all(|v| v.is_finite()) {
        return Err(DatasetError::InvalidValue { path: path.to_path_buf(), entry: key.into(), message: "non-finite value (NaN or inf)".into() });
    }
    let mut m = DMat4::IDENTITY;
    for r in 0..rows {
        for c in 0..4 {
            m.col_mut(c)[r] = data[r * 4 + c];
        }
    }
    Ok(Some(m))
}

/// Image and mask files of a scene with `n` cameras.
pub(crate) type ViewFiles = (Vec<PathBuf>, Option<Vec<PathBuf>>);

/// Reads the cameras of an IDR folder (image headers only, no pixels).
pub(crate) fn read_cameras(dir: &Path, options: &LoadOptions) -> Result<SceneCameras> {
    let npz_path = camera_file(dir).ok_or_else(|| DatasetError::UnknownLayout { dir: dir.to_path_buf() })?;
    let mut npz = Npz::open(&npz_path)?;
    let files = |n: usize| -> Result<ViewFiles> {
        let image_dir = ["image", "images"]
            .iter()
            .map(|d| dir.join(d))
            .find(|p| p.is_dir())
            .ok_or_else(|| DatasetError::MissingKey { path: dir.to_path_buf(), key: "image/ (or images/) folder".into() })?;
        let images = numbered_files(&image_dir, n, "images")?;
        let mask_dir = dir.join("mask");
        let masks = if mask_dir.is_dir() { Some(numbered_files(&mask_dir, n, "masks")?) } else { None };
        Ok((images, masks))
    };
    cameras_from_npz(&mut npz, &npz_path, dir, options, &files, &image_size)
}

/// The cameras of an IDR camera archive: `files(n)` lists the images (and masks) of its `n`
/// cameras and `image_size` reads a file's size (the loader reads headers; the fuzzer makes
/// them up).
pub(crate) fn cameras_from_npz<R: std::io::Read + std::io::Seek>(
    npz: &mut Npz<R>,
    npz_path: &Path,
    dir: &Path,
    options: &LoadOptions,
    files: &dyn Fn(usize) -> Result<ViewFiles>,
    image_size: &dyn Fn(&Path) -> Result<(u32, u32)>,
) -> Result<SceneCameras> {
    let npz_path = npz_path.to_path_buf();
    options.validate(&npz_path)?;
    if options.bound_sphere.is_some() {
        return Err(DatasetError::Unsupported {
            path: npz_path,
            message: "in the IDR layout scale_mat defines the region of interest; a bound override applies to COLMAP, instant-ngp and \
                      NeRF-synthetic data (re-import a COLMAP model with --bound)"
                .into(),
        });
    }
    let keys = npz.keys();
    let mut indices: Vec<usize> = keys.iter().filter_map(|k| k.strip_prefix("world_mat_").and_then(|s| s.parse::<usize>().ok())).collect();
    indices.sort_unstable();
    indices.dedup();
    let n = indices.len();
    // The cameras are numbered 0..n: a gap is a missing camera, named before any image is.
    if let Some(gap) = (0..=n).find(|i| indices.get(*i) != Some(i)).filter(|&i| i < n || n == 0) {
        return Err(DatasetError::MissingKey { path: npz_path, key: format!("world_mat_{gap}") });
    }
    let (images, masks) = files(n)?;
    let mut scale_mat_0 = None;
    let mut records = Vec::with_capacity(n);
    let mut size0: Option<(u32, u32)> = None;
    let mut missing_scale = false;
    for i in 0..n {
        let world_key = format!("world_mat_{i}");
        let world_mat =
            matrix4(npz, &npz_path, &world_key)?.ok_or_else(|| DatasetError::MissingKey { path: npz_path.clone(), key: world_key.clone() })?;
        let scale_mat = match matrix4(npz, &npz_path, &format!("scale_mat_{i}"))? {
            Some(m) => m,
            None => {
                missing_scale = true;
                DMat4::IDENTITY
            }
        };
        if i == 0 {
            if scale_mat.determinant().abs() < 1e-300 {
                return Err(DatasetError::InvalidValue { path: npz_path, entry: "scale_mat_0".into(), message: "singular".into() });
            }
            scale_mat_0 = Some(scale_mat);
        }
        let p4 = world_mat * scale_mat;
        let p = [0, 1, 2].map(|r| [0, 1, 2, 3].map(|c| p4.col(c)[r]));
        let entry = || format!("{world_key} · scale_mat_{i}");
        let (intrinsics, camera_from_world) =
            decompose_projection(&p).map_err(|source| DatasetError::Camera { path: npz_path.clone(), entry: entry(), source })?;
        let (w, h) = image_size(&images[i])?;
        match size0 {
            None => size0 = Some((w, h)),
            Some(s) if s != (w, h) => {
                return Err(DatasetError::SizeMismatch {
                    path: images[i].clone(),
                    found: (w, h),
                    expected: s,
                    why: "all images of a scene must have one size",
                });
            }
            _ => {}
        }
        if let Some(masks) = &masks {
            let found = image_size(&masks[i])?;
            if found != (w, h) {
                return Err(DatasetError::SizeMismatch { path: masks[i].clone(), found, expected: (w, h), why: "a mask must match its image" });
            }
        }
        let n_down = options.downscale;
        let camera = PinholeCamera::new(
            intrinsics.downscaled(n_down, PixelCenters::Integer),
            w / n_down,
            h / n_down,
            camera_from_world,
            PixelCenters::Integer,
        )
        .map_err(|source| DatasetError::Camera { path: npz_path.clone(), entry: entry(), source })?;
        records.push(CameraRecord {
            name: images[i].file_stem().unwrap_or_default().to_string_lossy().into_owned(),
            camera,
            image_path: Some(images[i].clone()),
            mask_path: masks.as_ref().map(|m| m[i].clone()),
        });
    }
    let description = format!(
        "IDR/NeuS layout: {} views from {}{}{}, downscale {}",
        n,
        npz_path.display(),
        if masks.is_some() { " with masks" } else { " without masks" },
        if missing_scale { " (no scale_mat: identity)" } else { "" },
        options.downscale
    );
    Ok(SceneCameras {
        records,
        world_from_normalized: scale_mat_0.unwrap_or(DMat4::IDENTITY),
        source: SceneSource { format: Format::Idr, path: Some(dir.to_path_buf()), description },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn images_are_paired_with_cameras_by_the_number_their_names_end_with() {
        let dir = tempfile::tempdir().unwrap();
        let names: Vec<String> = (0..12).map(|i| format!("img{i}.png")).collect();
        for n in &names {
            std::fs::write(dir.path().join(n), b"").unwrap();
        }
        let files = numbered_files(dir.path(), 12, "images").unwrap();
        let got: Vec<String> = files.iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect();
        assert_eq!(got, names, "img2 must be camera 2, not img10");
    }
}
