//! A COLMAP workspace: the model with its images (and masks) → cameras, a scene, or an import
//! into the IDR layout.

use super::*;

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
        let scale_mat = plan.cameras.world_from_normalized;
        let cameras: Vec<PinholeCamera> = plan.cameras.records.iter().map(|r| r.camera).collect();
        crate::idr::write_cameras(out, &cameras, &scale_mat)?;
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
            "world_from_normalized (rows)": crate::idr::mat4_rows(&scale_mat),
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
pub(super) struct Plan {
    cameras: SceneCameras,
    views: Vec<ColmapView>,
}

pub(super) fn strip_extension(name: &str) -> String {
    let path = Path::new(name);
    match path.extension() {
        Some(_) => path.with_extension("").to_string_lossy().into_owned(),
        None => name.to_string(),
    }
}

/// The mask of image `name`: `masks/NAME`, `masks/STEM.png` or COLMAP's `masks/NAME.png`.
pub(super) fn mask_file(dir: &Path, name: &str) -> Result<PathBuf> {
    let same = dir.join(name);
    let png = dir.join(format!("{}.png", strip_extension(name)));
    let colmap = dir.join(format!("{name}.png"));
    [&same, &png, &colmap].into_iter().find(|p| p.is_file()).cloned().ok_or_else(|| DatasetError::NotFound {
        path: png.clone(),
        why: format!("the mask of image {name} (tried {}, {}, {})", same.display(), png.display(), colmap.display()),
    })
}

/// Decodes, undistorts and downscales one view's image and mask.
pub(super) fn load_pixels(record: &CameraRecord, view: &ColmapView, options: &LoadOptions) -> Result<(RgbImage, Option<Mask>)> {
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
