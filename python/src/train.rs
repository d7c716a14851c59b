//! `psneus.train`: the trainer with the command line's behaviour, the GIL released, Ctrl-C a
//! clean stop with a checkpoint.

use crate::convert::{json_to_py, overrides, to_py_err};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyFloat, PyInt, PyString};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;
use trainer::config::{Budget, SamplerKind, parse_duration, positive_duration};
use trainer::folder::AtomicFiles;
use trainer::run::{Outcome, RunOptions, RunRequest, free_default_out, run};

/// How often the waiting interpreter looks for Ctrl-C.
const SIGNAL_POLL: Duration = Duration::from_millis(100);

/// A budget given in Python: `"90s"`, `"10m"`, `"1.5h"`, or seconds as a number.
fn time_budget(budget: &Bound<'_, PyAny>) -> PyResult<Budget> {
    let duration = if let Ok(text) = budget.cast::<PyString>() {
        parse_duration(&text.to_cow()?).map_err(|e| PyValueError::new_err(format!("budget {text}: {}", e.chain())))?
    } else if budget.is_instance_of::<PyFloat>() || budget.is_instance_of::<PyInt>() {
        let seconds: f64 = budget.extract()?;
        positive_duration(seconds).map_err(|e| PyValueError::new_err(format!("budget = {seconds} s: {}", e.chain())))?
    } else {
        return Err(PyTypeError::new_err("budget: a duration such as \"2m\", or seconds as a number"));
    };
    Ok(Budget::Time(duration))
}

/// Trains a model and returns the run's metrics (the `metrics.json` fields) with `mesh` (the
/// mesh written), `meshes`, `out` (the run folder) and `history`.
///
/// `data`: a dataset folder (default: the built-in scene); `budget`: `"2m"`, `"10m"`, seconds,
/// or `None` for the configuration's (2 minutes by default; `steps=N` as an override trains N
/// iterations); `out`: the run folder (default `out/train`, or `out/train-N` when taken; never
/// an existing folder that is not an earlier run, and an earlier run only with `overwrite`);
/// `config`: a TOML file; `overrides`: configuration keys, dotted through `**{"data.masks":
/// False}` or with `__` (`data__masks=False`). `resume`: continue the run in that folder.
/// Ctrl-C stops after the current iteration, writes the checkpoint and raises
/// `KeyboardInterrupt`; `train(resume=out)` continues.
#[pyfunction]
#[pyo3(signature = (data = None, budget = None, out = None, sampler = None, seed = None, config = None, resume = None, overwrite = false, max_memory_gb = None, **options))]
#[allow(clippy::too_many_arguments)]
pub fn train<'py>(
    py: Python<'py>,
    data: Option<PathBuf>,
    budget: Option<Bound<'py, PyAny>>,
    out: Option<PathBuf>,
    sampler: Option<&str>,
    seed: Option<u64>,
    config: Option<PathBuf>,
    resume: Option<PathBuf>,
    overwrite: bool,
    max_memory_gb: Option<f64>,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyAny>> {
    let request = match resume {
        Some(dir) => {
            let given = [
                budget.is_some(),
                out.is_some(),
                sampler.is_some(),
                seed.is_some(),
                config.is_some(),
                overwrite,
                options.is_some_and(|o| !o.is_empty()),
            ];
            if given.iter().any(|g| *g) {
                return Err(PyValueError::new_err(
                    "resume continues a run with its own configuration, budget and folder: only data (the same data at a new place) may be given with it",
                ));
            }
            RunRequest::Resume { dir, data }
        }
        None => {
            let budget = budget.as_ref().map(time_budget).transpose()?;
            let sampler = sampler.map(SamplerKind::from_name).transpose().map_err(PyValueError::new_err)?;
            let mut config = crate::convert::config(config.as_deref(), &overrides(options, "")?)?;
            // The arguments replace the file's and the overrides' values, as on the command line.
            config.budget = budget.unwrap_or(config.budget);
            config.sampler = sampler.unwrap_or(config.sampler);
            config.seed = seed.unwrap_or(config.seed);
            config.validate().map_err(|e| PyValueError::new_err(e.chain()))?;
            let out = out.unwrap_or_else(free_default_out);
            RunRequest::Fresh { config: Box::new(config), data, out, overwrite }
        }
    };
    if let Some(gb) = max_memory_gb.filter(|g| !(g.is_finite() && *g > 0.0)) {
        return Err(PyValueError::new_err(format!("max_memory_gb = {gb}: expected a positive number")));
    }
    let options = RunOptions { max_memory: max_memory_gb.map(|g| g * 1e9), stop_at: None, json: false };
    let stop = Arc::new(AtomicBool::new(false));
    let (sender, receiver) = std::sync::mpsc::channel();
    // Waited on with the GIL released, from this thread only.
    let receiver = std::sync::Mutex::new(receiver);
    let worker = {
        let stop = stop.clone();
        std::thread::spawn(move || {
            let outcome = run(&request, &options, &stop, Arc::new(AtomicFiles));
            // The receiver waits until this arrives; it cannot be gone.
            let _ = sender.send(outcome);
        })
    };
    let mut interrupted = None;
    let outcome = loop {
        match py.detach(|| receiver.lock().unwrap_or_else(|e| e.into_inner()).recv_timeout(SIGNAL_POLL)) {
            Ok(outcome) => break outcome,
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                if interrupted.is_none()
                    && let Err(e) = py.check_signals()
                {
                    // Ctrl-C: the run stops after this iteration and writes its checkpoint.
                    stop.store(true, Ordering::SeqCst);
                    interrupted = Some(e);
                }
            }
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => {
                return Err(PyValueError::new_err("the training thread ended without a result (it panicked: see the message above)"));
            }
        }
    };
    let _ = worker.join();
    let outcome = outcome.map_err(to_py_err)?;
    if let Some(e) = interrupted {
        return Err(e);
    }
    let record = match outcome {
        Outcome::Finished(summary) => {
            let mut record = serde_json::to_value(&summary.metrics).map_err(|e| PyValueError::new_err(e.to_string()))?;
            let map = record.as_object_mut().expect("metrics serialise as an object");
            map.insert("mesh".into(), summary.meshes.first().cloned().map_or(serde_json::Value::Null, serde_json::Value::String));
            map.insert("meshes".into(), serde_json::json!(summary.meshes));
            map.insert("out".into(), serde_json::Value::String(summary.out.clone()));
            map.insert("history".into(), serde_json::Value::Array(summary.history.clone()));
            record
        }
        Outcome::Stopped { step, out } => serde_json::json!({"stopped": true, "steps": step, "out": out.display().to_string()}),
    };
    json_to_py(py, &record)
}

/// The default configuration as TOML, every key with its description (what
/// `cargo xtask train --print-config` prints).
#[pyfunction]
pub fn default_config() -> String {
    trainer::config::annotated_default()
}
