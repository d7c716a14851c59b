//! A Python callable as the library's signed distance field.

use glam::Vec3;
use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray1, PyUntypedArrayMethods};
use prob_grid::SdfField;
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use std::sync::Mutex;

/// What a failed callback leaves in the field's outputs: far outside, so the update ends fast
/// (its result is discarded and the error raised).
const FAR: f32 = 1.0e3;

/// A Python callable `(N, 3) float32 → (N,)` as an [`SdfField`]. The update calls it from
/// several threads, each taking the GIL in turn; the first error is kept and raised afterwards.
pub struct PyField {
    sdf: Py<PyAny>,
    /// The Lipschitz bound claimed for the callable (checked against its values by the grid).
    bound: f32,
    error: Mutex<Option<PyErr>>,
}

impl PyField {
    /// `sdf` (a callable) with the Lipschitz bound `bound` claimed for it.
    fn new(sdf: Bound<'_, PyAny>, bound: f32) -> PyResult<PyField> {
        if !sdf.is_callable() {
            return Err(PyTypeError::new_err("sdf must be a callable taking an (N, 3) float32 array of points and returning (N,) distances"));
        }
        Ok(PyField { sdf: sdf.unbind(), bound, error: Mutex::new(None) })
    }

    /// The first error the callable raised (or returned: a wrong shape, a non-finite value).
    fn finish(&self) -> PyResult<()> {
        self.error.lock().unwrap_or_else(|e| e.into_inner()).take().map_or(Ok(()), Err)
    }

    fn call(&self, py: Python<'_>, points: &[Vec3], out: &mut [f32]) -> PyResult<()> {
        let n = points.len();
        let flat: Vec<f32> = points.iter().flat_map(|p| p.to_array()).collect();
        let array = PyArray1::from_vec(py, flat).reshape([n, 3])?;
        let result = self.sdf.call1(py, (array,))?;
        let numpy = py.import("numpy")?;
        let values = numpy.call_method1("asarray", (result, "float32"))?.call_method1("reshape", (-1,))?;
        let values: PyReadonlyArray1<f32> = values.extract()?;
        if values.len() != n {
            return Err(PyValueError::new_err(format!("the sdf returned {} values for {n} points: expected shape ({n},)", values.len())));
        }
        let values = values.as_slice()?;
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(PyValueError::new_err(format!("the sdf returned {} at the point {:?}", values[i], points[i].to_array())));
        }
        out.copy_from_slice(values);
        Ok(())
    }
}

impl SdfField for PyField {
    fn sdf_batch(&self, points: &[Vec3], out: &mut [f32]) {
        let failed = self.error.lock().unwrap_or_else(|e| e.into_inner()).is_some();
        if failed {
            out.fill(FAR);
            return;
        }
        Python::attach(|py| {
            if let Err(e) = self.call(py, points, out) {
                out.fill(FAR);
                self.error.lock().unwrap_or_else(|e| e.into_inner()).get_or_insert(e);
            }
        });
    }

    fn lipschitz_bound(&self) -> f32 {
        self.bound
    }
}

/// An analytic sphere, evaluated in Rust when given to `Estimator.update` or `extract_mesh`
/// (no Python call per batch), and callable from Python like any SDF.
#[pyclass(module = "psneus", frozen)]
pub struct Sphere {
    shape: prob_grid::Shape,
}

#[pymethods]
impl Sphere {
    #[new]
    fn new(center: [f64; 3], radius: f64) -> PyResult<Sphere> {
        if !(center.iter().all(|c| c.is_finite()) && radius.is_finite() && radius > 0.0) {
            return Err(PyValueError::new_err(format!("a sphere of centre {center:?} and radius {radius}: finite, radius > 0")));
        }
        Ok(Sphere { shape: prob_grid::Shape::Sphere { center: glam::DVec3::from_array(center), radius } })
    }

    /// Signed distances of (N, 3) float32 points, (N,) float32.
    fn __call__<'py>(&self, py: Python<'py>, points: numpy::PyReadonlyArray2<'py, f32>) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let view = points.as_array();
        if view.shape()[1] != 3 {
            return Err(PyValueError::new_err(format!("points of shape {:?}: expected (N, 3)", view.shape())));
        }
        let points: Vec<Vec3> = view.rows().into_iter().map(|r| Vec3::new(r[0], r[1], r[2])).collect();
        let mut out = vec![0.0; points.len()];
        self.shape.sdf_batch(&points, &mut out);
        Ok(PyArray1::from_vec(py, out))
    }
}

/// The field of an `sdf` argument: a [`Sphere`] natively, any other callable through Python.
pub enum Field {
    /// Evaluated in Rust.
    Native(prob_grid::Shape),
    /// A Python callable.
    Python(PyField),
}

impl Field {
    /// `sdf` with `bound` claimed for a Python callable (an analytic field claims its own).
    pub fn new(sdf: Bound<'_, PyAny>, bound: f32) -> PyResult<Field> {
        if let Ok(sphere) = sdf.cast::<Sphere>() {
            return Ok(Field::Native(sphere.get().shape.clone()));
        }
        PyField::new(sdf, bound).map(Field::Python)
    }

    /// The first error a Python callable raised.
    pub fn finish(&self) -> PyResult<()> {
        match self {
            Field::Native(_) => Ok(()),
            Field::Python(f) => f.finish(),
        }
    }
}

impl SdfField for Field {
    fn sdf_batch(&self, points: &[Vec3], out: &mut [f32]) {
        match self {
            Field::Native(s) => s.sdf_batch(points, out),
            Field::Python(f) => f.sdf_batch(points, out),
        }
    }

    fn lipschitz_bound(&self) -> f32 {
        match self {
            Field::Native(s) => s.lipschitz_bound(),
            Field::Python(f) => f.lipschitz_bound(),
        }
    }
}

/// Vertices (N, 3) and faces (M, 3) of a mesh.
type MeshPair<'py> = (Bound<'py, numpy::PyArray2<f32>>, Bound<'py, numpy::PyArray2<u32>>);

/// The zero level set of `sdf` (a Python callable, see `Estimator.update`, or a `Sphere`) by marching cubes over
/// the cube [−bound, bound]³ at `resolution` cells per axis, in blocks near the surface (the
/// `lipschitz` bound claimed for the field is checked against its values and raised if broken):
/// `(vertices (N, 3) float32, faces (M, 3) uint32)` in the frame the callable takes.
#[pyfunction]
#[pyo3(signature = (sdf, resolution = 128, bound = 1.0, lipschitz = 1.5))]
pub fn extract_mesh<'py>(py: Python<'py>, sdf: Bound<'py, PyAny>, resolution: u32, bound: f32, lipschitz: f32) -> PyResult<MeshPair<'py>> {
    if !(bound.is_finite() && bound > 0.0 && lipschitz.is_finite() && lipschitz > 0.0) {
        return Err(PyValueError::new_err(format!("bound = {bound}, lipschitz = {lipschitz}: expected positive numbers")));
    }
    if resolution < 2 {
        return Err(PyValueError::new_err(format!("resolution = {resolution}: expected ≥ 2")));
    }
    let field = Field::new(sdf, lipschitz)?;
    let config = prob_grid::MarchingCubesConfig { min: Vec3::splat(-bound), max: Vec3::splat(bound), resolution, ..Default::default() };
    let result = py.detach(|| prob_grid::marching_cubes(&field, &config));
    field.finish()?;
    let (mesh, _) = result.map_err(|e| crate::convert::to_py_err(e.into()))?;
    let (nv, nf) = (mesh.vertices.len(), mesh.triangles.len());
    let vertices = PyArray1::from_vec(py, mesh.vertices.iter().flat_map(|v| v.to_array()).collect()).reshape([nv, 3])?;
    let faces = PyArray1::from_vec(py, mesh.triangles.concat()).reshape([nf, 3])?;
    Ok((vertices, faces))
}
