//! `psneus.Estimator`: the view-sampler estimator for any backbone, its SDF a Python callable.

use crate::convert::{config, overrides, to_py_err};
use crate::field::Field;
use crate::scene::Scene;
use glam::DVec3;
use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use view_sampler::{EstimatorState, UpdateReport, near_far, stream_seed};

/// The stream of the coarse samples' jitter, apart from the draws' own streams.
const JITTER_STREAM: u64 = 0x6A09_E667_F3BC_C909;

/// The view-sampler estimator: `update(sdf, s)` rebuilds the guide from any SDF, `draw(n,
/// seed)` returns rays as numpy arrays (see the stubs for every field).
#[pyclass(module = "psneus")]
pub struct Estimator {
    inner: view_sampler::Estimator,
    /// The scene view of each estimator camera.
    views: Vec<usize>,
}

fn report_dict<'py>(py: Python<'py>, r: &UpdateReport) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("seconds", r.seconds)?;
    d.set_item("s", r.s)?;
    d.set_item("field_queries", r.field_queries)?;
    d.set_item("scene_mass", r.scene_mass)?;
    d.set_item("occupied_fraction", r.occupied_fraction)?;
    d.set_item("empty_views", PyList::new(py, &r.empty_cameras)?)?;
    d.set_item("lipschitz_measured", r.lipschitz.measured)?;
    d.set_item("lipschitz_claimed", r.lipschitz.claimed)?;
    d.set_item("lipschitz_used", r.lipschitz.used)?;
    d.set_item("lipschitz_retries", r.lipschitz.retries)?;
    Ok(d)
}

impl Estimator {
    /// Runs an update with the GIL released, restoring the previous grids if the callback
    /// failed.
    fn run_update(
        &mut self,
        py: Python<'_>,
        sdf: Bound<'_, PyAny>,
        update: impl FnOnce(&mut view_sampler::Estimator, &Field) -> Result<Option<UpdateReport>, prob_grid::GridError> + Send,
    ) -> PyResult<Option<UpdateReport>> {
        // The estimator claims its own carried bound for the field (`update_at`).
        let field = Field::new(sdf, 1.0)?;
        let before = self.inner.state();
        let inner = &mut self.inner;
        let result = py.detach(|| update(inner, &field));
        if let Err(e) = field.finish() {
            self.inner.restore(&before).map_err(|e| to_py_err(e.into()))?;
            return Err(e);
        }
        result.map_err(|e| to_py_err(e.into()))
    }
}

#[pymethods]
impl Estimator {
    /// An estimator over `views` of `scene` (default: all), with the `guide.*` options of the
    /// configuration as keywords (`updates`, `scene={...}`, `camera={...}`, `interpolation`,
    /// `fixed_s`, `uniform_fractions`, ...; `scene__resolution=64` sets one key of a section),
    /// `sampler` "guided" or "uniform" (the loss-guided ones are refused: they need the loss),
    /// and the empty-space skipping of `render.skip_empty` /
    /// `render.occupancy_dilation`.
    #[new]
    #[pyo3(signature = (scene, views = None, sampler = "guided", skip_empty = None, occupancy_dilation = None, **guide))]
    fn new(
        scene: &Scene,
        views: Option<Vec<usize>>,
        sampler: &str,
        skip_empty: Option<bool>,
        occupancy_dilation: Option<u32>,
        guide: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Estimator> {
        let mut values = overrides(guide, "guide.")?;
        values.push(("sampler".into(), toml::Value::String(sampler.into())));
        if let Some(v) = skip_empty {
            values.push(("render.skip_empty".into(), toml::Value::Boolean(v)));
        }
        if let Some(v) = occupancy_dilation {
            values.push(("render.occupancy_dilation".into(), toml::Value::Integer(v.into())));
        }
        let config = config(None, &values)?;
        if config.sampler.mines() {
            // The estimator draws guided or uniform rays; mining the loss needs the loss.
            return Err(PyValueError::new_err(format!(
                "sampler {:?}: the Estimator draws \"guided\" or \"uniform\" rays; the loss-guided samplers train through psneus.train(sampler=...)",
                config.sampler.name()
            )));
        }
        let views = views.unwrap_or_else(|| (0..scene.view_count()).collect());
        if let Some(&v) = views.iter().find(|&&v| v >= scene.view_count()) {
            return Err(PyValueError::new_err(format!("view {v} of a scene of {} views", scene.view_count())));
        }
        let cameras = views.iter().map(|&v| scene.data.scene.views[v].camera).collect();
        let inner = view_sampler::Estimator::new(cameras, trainer::trainer::estimator_config(&config)).map_err(|e| to_py_err(e.into()))?;
        Ok(Estimator { inner, views })
    }

    /// Rebuilds the guide (and the occupancy) now from `sdf` at logistic scale `s`; returns what
    /// the update did (dict). `progress` ∈ [0, 1] is the part of the run it belongs to, for
    /// `update_due`. The field's Lipschitz bound is the one the estimator carries (a steeper
    /// field is detected and the evaluation redone).
    #[pyo3(signature = (sdf, s, progress = 0.0))]
    fn update<'py>(&mut self, py: Python<'py>, sdf: Bound<'py, PyAny>, s: f32, progress: f64) -> PyResult<Bound<'py, PyDict>> {
        let report = self.run_update(py, sdf, |e, f| e.update_at(progress, f, s).map(Some))?;
        report_dict(py, &report.expect("update_at reports"))
    }

    /// The scheduled update (`updates` per run, at the start of each equal part of `progress`):
    /// the report when one was due, else `None`.
    fn update_due<'py>(&mut self, py: Python<'py>, progress: f64, sdf: Bound<'py, PyAny>, s: f32) -> PyResult<Option<Bound<'py, PyDict>>> {
        let report = self.run_update(py, sdf, |e, f| e.update_due(progress, f, s))?;
        report.map(|r| report_dict(py, &r)).transpose()
    }

    /// `n` rays (dict of numpy arrays, see the stubs), deterministic for (`seed`, `step`):
    /// guided and uniform by the schedule at `progress`, or with the uniform share
    /// `uniform_fraction`; with `coarse` > 0 also `coarse + 1` coarse sample depths per ray
    /// (in occupied space when skipping is on).
    #[pyo3(signature = (n, seed, uniform_fraction = None, progress = 0.0, step = 0, coarse = 0))]
    #[allow(clippy::too_many_arguments)]
    fn draw<'py>(
        &self,
        py: Python<'py>,
        n: usize,
        seed: u64,
        uniform_fraction: Option<f64>,
        progress: f64,
        step: u64,
        coarse: usize,
    ) -> PyResult<Bound<'py, PyDict>> {
        if let Some(f) = uniform_fraction.filter(|f| !(0.0..=1.0).contains(f)) {
            return Err(PyValueError::new_err(format!("uniform_fraction = {f}: expected a number in [0, 1]")));
        }
        if !(0.0..=1.0).contains(&progress) {
            return Err(PyValueError::new_err(format!("progress = {progress}: expected a number in [0, 1]")));
        }
        let fraction = uniform_fraction.unwrap_or_else(|| self.inner.config().schedule.fraction(progress));
        let jitter = |i: usize| (stream_seed(seed ^ JITTER_STREAM, step, i as u64) >> 11) as f64 / (1u64 << 53) as f64;
        let inner = &self.inner;
        let rays = py.detach(|| inner.draw_rays_mixed(n, fraction, seed, step, coarse.max(1), &jitter));
        let cameras = self.inner.cameras();
        let (mut view, mut pixel, mut pixel_coords, mut origin, mut direction) = (vec![], vec![], vec![], vec![], vec![]);
        let (mut depth, mut depth_bin, mut background, mut guided, mut pdf, mut near, mut far, mut coarse_depths) =
            (vec![], vec![], vec![], vec![], vec![], vec![], vec![], vec![]);
        for r in &rays {
            let camera = &cameras[r.sample.camera as usize];
            let offset = camera.pixel_centers.offset();
            view.push(self.views[r.sample.camera as usize] as i64);
            pixel.extend(r.sample.pixel.map(f64::from));
            pixel_coords.extend((r.sample.pixel_coords - offset).to_array());
            origin.extend(r.ray.origin);
            direction.extend(r.ray.direction);
            depth.push(r.surface.map_or(f32::NAN, |s| s.distance as f32));
            depth_bin.push(r.surface.map_or(f32::NAN, |s| s.bin as f32));
            background.push(r.surface.is_none_or(|s| s.background));
            guided.push(r.sample.guided);
            pdf.push(r.sample.pdf_pixel);
            let (t0, t1) = near_far(DVec3::from_array(r.ray.origin.map(f64::from)), DVec3::from_array(r.ray.direction.map(f64::from)));
            near.push(t0 as f32);
            far.push(t1 as f32);
            if coarse > 0 {
                coarse_depths.extend_from_slice(&r.ray.depths);
            }
        }
        let d = PyDict::new(py);
        d.set_item("view", PyArray1::from_vec(py, view))?;
        d.set_item("pixel", PyArray1::from_vec(py, pixel).reshape([n, 2])?)?;
        d.set_item("pixel_coords", PyArray1::from_vec(py, pixel_coords).reshape([n, 2])?)?;
        d.set_item("origin", PyArray1::from_vec(py, origin).reshape([n, 3])?)?;
        d.set_item("direction", PyArray1::from_vec(py, direction).reshape([n, 3])?)?;
        d.set_item("depth", PyArray1::from_vec(py, depth))?;
        d.set_item("depth_bin", PyArray1::from_vec(py, depth_bin))?;
        d.set_item("background", PyArray1::from_vec(py, background))?;
        d.set_item("guided", PyArray1::from_vec(py, guided))?;
        d.set_item("pdf", PyArray1::from_vec(py, pdf))?;
        d.set_item("near", PyArray1::from_vec(py, near))?;
        d.set_item("far", PyArray1::from_vec(py, far))?;
        if coarse > 0 {
            d.set_item("coarse_depths", PyArray1::from_vec(py, coarse_depths).reshape([n, coarse + 1])?)?;
        }
        Ok(d)
    }

    /// What the last update built, as a dict of numpy arrays (picklable) for `restore`.
    fn state<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = self.inner.state();
        let d = PyDict::new(py);
        d.set_item("grids", s.grids.into_iter().map(|g| PyArray1::from_vec(py, g)).collect::<Vec<_>>())?;
        d.set_item("occupancy", s.occupancy.map(|o| PyArray1::from_vec(py, o)))?;
        d.set_item("part", s.part)?;
        d.set_item("lipschitz", s.lipschitz)?;
        Ok(d)
    }

    /// Restores what `state()` returned (an estimator of the same scene views and options).
    fn restore(&mut self, state: &Bound<'_, PyDict>) -> PyResult<()> {
        let get = |key: &str| state.get_item(key)?.ok_or_else(|| PyValueError::new_err(format!("the state has no {key:?}")));
        let arrays = |v: Bound<'_, PyAny>| -> PyResult<Vec<f32>> { Ok(v.extract::<PyReadonlyArray1<f32>>()?.as_slice()?.to_vec()) };
        let grids = get("grids")?.try_iter()?.map(|g| arrays(g?)).collect::<PyResult<Vec<_>>>()?;
        let occupancy = get("occupancy")?;
        let occupancy = if occupancy.is_none() { None } else { Some(arrays(occupancy)?) };
        let part = get("part")?;
        let state = EstimatorState {
            grids,
            occupancy,
            part: if part.is_none() { None } else { Some(part.extract()?) },
            lipschitz: get("lipschitz")?.extract()?,
        };
        self.inner.restore(&state).map_err(|e| to_py_err(e.into()))
    }

    /// The scene view of each of the estimator's cameras.
    #[getter]
    fn views(&self) -> Vec<usize> {
        self.views.clone()
    }

    /// The Lipschitz bound the next scheduled update claims for the field.
    #[getter]
    fn lipschitz_bound(&self) -> f32 {
        self.inner.lipschitz_bound()
    }

    /// The uniform share of the schedule at `progress`.
    fn uniform_fraction(&self, progress: f64) -> f64 {
        self.inner.config().schedule.fraction(progress)
    }

    fn __repr__(&self) -> String {
        let c = self.inner.config();
        format!(
            "Estimator({} views, {}, skip_empty={}, updates={})",
            self.views.len(),
            if c.guided { "guided" } else { "uniform" },
            c.skip_empty,
            c.updates
        )
    }
}
