//! `psneus.evaluate_mesh`: the DTU-protocol evaluation of a mesh (Chamfer, F-score).

use crate::convert::to_py_err;
use numpy::{PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};
use std::path::PathBuf;
use trainer::evaluation::{Distances, GroundTruth, MeshArrays, Protocol, evaluate_mesh as evaluate, read_mesh};

/// An (N, 3) array as rows.
fn rows<T: numpy::Element + Copy>(name: &str, array: &Bound<'_, PyAny>) -> PyResult<Vec<[T; 3]>> {
    let array: PyReadonlyArray2<T> =
        array.extract().map_err(|_| PyTypeError::new_err(format!("{name}: expected an (N, 3) numpy array of {}", std::any::type_name::<T>())))?;
    if array.shape()[1] != 3 {
        return Err(PyValueError::new_err(format!("{name}: shape {:?}, expected (N, 3)", array.shape())));
    }
    let view = array.as_array();
    Ok(view.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect())
}

/// `numpy.ascontiguousarray(value, dtype)`.
fn contiguous<'py>(value: &Bound<'py, PyAny>, dtype: &str) -> PyResult<Bound<'py, PyAny>> {
    value.py().import("numpy")?.call_method1("ascontiguousarray", (value, dtype))
}

/// A mesh given as a file path or as `(vertices (N, 3) float32, faces (M, 3) uint32)`.
fn mesh_arrays(name: &str, mesh: &Bound<'_, PyAny>) -> PyResult<MeshArrays> {
    if let Ok(tuple) = mesh.cast::<PyTuple>() {
        if tuple.len() != 2 {
            return Err(PyValueError::new_err(format!("{name}: a tuple (vertices, faces)")));
        }
        let vertices = rows::<f32>(&format!("{name} vertices"), &contiguous(&tuple.get_item(0)?, "float32")?)?;
        let faces = rows::<u32>(&format!("{name} faces"), &contiguous(&tuple.get_item(1)?, "uint32")?)?;
        if let Some(f) = faces.iter().find(|f| f.iter().any(|&i| i as usize >= vertices.len())) {
            return Err(PyValueError::new_err(format!("{name}: face {f:?} indexes past the {} vertices", vertices.len())));
        }
        return Ok((vertices, faces));
    }
    let path: PathBuf = mesh.extract().map_err(|_| PyTypeError::new_err(format!("{name}: a path or a tuple (vertices, faces)")))?;
    read_mesh(&path).map_err(|e| to_py_err(e.context(format!("reading the mesh {}", path.display()))))
}

/// The DTU-protocol evaluation of `mesh` (a .ply/.obj/.gltf/.glb path, or `(vertices,
/// faces)`) against `gt_points` ((N, 3) array) or `gt_mesh` (path or arrays), in the mesh's
/// units: accuracy, completeness, chamfer, precision, recall, fscore, normal_consistency (the
/// mesh's normals against a truth mesh's; `None` against points), and the distances used.
/// `spacing`, `max_dist`, `tau` default to the ground truth's bounding-box diagonal / 1000,
/// / 20, / 200 (DTU: 0.2, 20 mm; τ as you report it).
#[pyfunction]
#[pyo3(signature = (mesh, gt_points = None, gt_mesh = None, spacing = None, max_dist = None, tau = None))]
pub fn evaluate_mesh<'py>(
    py: Python<'py>,
    mesh: &Bound<'py, PyAny>,
    gt_points: Option<&Bound<'py, PyAny>>,
    gt_mesh: Option<&Bound<'py, PyAny>>,
    spacing: Option<f64>,
    max_dist: Option<f64>,
    tau: Option<f64>,
) -> PyResult<Bound<'py, PyDict>> {
    let (vertices, faces) = mesh_arrays("mesh", mesh)?;
    let gt = match (gt_points, gt_mesh) {
        (Some(p), None) => GroundTruth::Points(rows::<f32>("gt_points", &contiguous(p, "float32")?)?),
        (None, Some(m)) => GroundTruth::Mesh(mesh_arrays("gt_mesh", m)?),
        _ => return Err(PyValueError::new_err("give exactly one of gt_points and gt_mesh")),
    };
    let protocol = Protocol { spacing, max_dist, tau };
    let evaluation = py.detach(|| evaluate(&vertices, &faces, gt, protocol)).map_err(to_py_err)?;
    let (m, Distances { spacing, max_dist, tau }) = (evaluation.metrics, evaluation.distances);
    let d = PyDict::new(py);
    for (k, v) in [
        ("accuracy", m.accuracy),
        ("completeness", m.completeness),
        ("chamfer", m.chamfer),
        ("precision", m.precision),
        ("recall", m.recall),
        ("fscore", m.f_score),
        ("tau", tau),
        ("spacing", spacing),
        ("max_dist", max_dist),
    ] {
        d.set_item(k, v)?;
    }
    d.set_item("normal_consistency", evaluation.normal_consistency)?;
    d.set_item("pred_points", m.n_pred)?;
    d.set_item("gt_points", m.n_gt)?;
    Ok(d)
}
