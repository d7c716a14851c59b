//! `psneus.load_scene` and `Scene`: any layout the loaders read, or the built-in golden scene.

use crate::convert::{config, overrides, to_py_err};
use camera_geom::PinholeCamera;
use numpy::{PyArray1, PyArray2, PyArray3, PyArrayMethods};
use pyo3::exceptions::PyIndexError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;
use trainer::data::SceneData;

/// A calibrated multi-view scene in the normalised frame (region of interest = unit sphere).
#[pyclass(module = "psneus", frozen)]
pub struct Scene {
    pub data: SceneData,
}

/// Row-major 4×4 of a rigid transform.
fn rigid_rows(r: &camera_geom::Rigid3) -> Vec<Vec<f64>> {
    (0..3).map(|i| r.rotation.row(i).to_array().into_iter().chain([r.translation[i]]).collect()).chain([vec![0.0, 0.0, 0.0, 1.0]]).collect()
}

/// `K` with pixel centres at integer coordinates (OpenCV's convention, whatever the dataset's).
fn k_rows(camera: &PinholeCamera) -> Vec<Vec<f64>> {
    let k = camera.intrinsics;
    let o = camera.pixel_centers.offset();
    vec![vec![k.fx, k.skew, k.cx - o], vec![0.0, k.fy, k.cy - o], vec![0.0, 0.0, 1.0]]
}

impl Scene {
    pub fn view_count(&self) -> usize {
        self.data.scene.views.len()
    }

    fn view(&self, i: usize) -> PyResult<&datasets::View> {
        self.data.scene.views.get(i).ok_or_else(|| PyIndexError::new_err(format!("view {i} of a scene of {} views", self.view_count())))
    }
}

#[pymethods]
impl Scene {
    /// One dict per view: `K` (3×3, pixel centres at integer coordinates), `world_from_camera`
    /// (4×4, normalised frame, OpenCV axes: x right, y down, z forward), `width`, `height`, `name`.
    #[getter]
    fn cameras<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.data
            .scene
            .views
            .iter()
            .map(|v| {
                let d = PyDict::new(py);
                d.set_item("K", PyArray2::from_vec2(py, &k_rows(&v.camera))?)?;
                d.set_item("world_from_camera", PyArray2::from_vec2(py, &rigid_rows(&v.camera.world_from_camera()))?)?;
                d.set_item("width", v.camera.width)?;
                d.set_item("height", v.camera.height)?;
                d.set_item("name", &v.name)?;
                Ok(d)
            })
            .collect()
    }

    /// The normalised frame → the dataset's world frame (4×4), e.g. DTU's `scale_mat`.
    #[getter]
    fn world_from_normalized<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let m = self.data.scene.world_from_normalized.transpose().to_cols_array_2d();
        Ok(PyArray2::from_vec2(py, &m.map(|r| r.to_vec()))?)
    }

    /// View `i`'s image, (height, width, 3) float32 in [0, 1].
    fn image<'py>(&self, py: Python<'py>, i: usize) -> PyResult<Bound<'py, PyArray3<f32>>> {
        let image = &self.view(i)?.image;
        let values: Vec<f32> = image.data.iter().map(|&b| f32::from(b) / 255.0).collect();
        PyArray1::from_vec(py, values).reshape([image.height as usize, image.width as usize, 3])
    }

    /// View `i`'s foreground mask, (height, width) bool, or `None` when the view has none.
    fn mask<'py>(&self, py: Python<'py>, i: usize) -> PyResult<Option<Bound<'py, PyArray2<bool>>>> {
        let Some(mask) = &self.view(i)?.mask else { return Ok(None) };
        let (w, h) = (mask.width, mask.height);
        let values: Vec<bool> = (0..h).flat_map(|r| (0..w).map(move |c| (c, r))).map(|(c, r)| mask.get(c, r)).collect();
        Ok(Some(PyArray1::from_vec(py, values).reshape([h as usize, w as usize])?))
    }

    /// Ground-truth surface points in the normalised frame, (N, 3) float32: the built-in
    /// scene's, or the data folder's `gt_mesh.ply` (sampled every `spacing`) / `gt_points.ply`;
    /// `None` when the data has none.
    #[pyo3(signature = (spacing = 0.004))]
    fn ground_truth<'py>(&self, py: Python<'py>, spacing: f64) -> PyResult<Option<Bound<'py, PyArray2<f32>>>> {
        let points = py.detach(|| self.data.ground_truth(spacing)).map_err(to_py_err)?;
        points.map(|p| PyArray1::from_vec(py, p.concat()).reshape([p.len(), 3])).transpose()
    }

    /// What was read, how, with which options.
    #[getter]
    fn description(&self) -> &str {
        self.data.description()
    }

    /// The data folder (`None` for the built-in scene).
    #[getter]
    fn path(&self) -> Option<PathBuf> {
        self.data.path.clone()
    }

    fn __len__(&self) -> usize {
        self.view_count()
    }

    fn __repr__(&self) -> String {
        format!("Scene({}: {} views)", self.data.description(), self.view_count())
    }
}

/// Loads a scene: `path` a dataset folder in any layout the loaders read (IDR/NeuS/DTU,
/// NeRF-synthetic, instant-ngp, COLMAP), or `None` for the built-in golden scene (no files).
/// `options` are the `data.*` keys of the configuration: `downscale`, `bound` ([x, y, z, r] in
/// the dataset's units), `builtin={"shape": ..., "width": ..., "views": ..., "backdrop": ...}`.
#[pyfunction]
#[pyo3(signature = (path = None, **options))]
pub fn load_scene(py: Python<'_>, path: Option<PathBuf>, options: Option<&Bound<'_, PyDict>>) -> PyResult<Scene> {
    let config = config(None, &overrides(options, "data.")?)?;
    let data = py.detach(|| SceneData::load(&config, path.as_deref())).map_err(to_py_err)?;
    Ok(Scene { data })
}
