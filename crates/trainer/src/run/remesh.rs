//! A run's model meshed again at another resolution (`cargo xtask eval --run RUN
//! --mesh-resolution N [--snapshot T]`): the mesh files beside the run's own (or the
//! snapshot's), named by their resolution, and their geometry against the truth by the run's
//! protocol — so that a finished run shows what a finer (or coarser) mesh of the same model
//! gains, without training it again.

use super::{RunFolder, finish::write_meshes, open_run_model};
use crate::config::MeshResolution;
use crate::error::Result;
use crate::metrics::{ObservedMetrics, PartMetrics};
use crate::outputs::run_geometry;
use crate::snapshot::RunModel;
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// What [`remesh`] made and measured.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Remeshed {
    /// The snapshot whose model it is (training seconds; `None`: the run's last model).
    pub snapshot: Option<f64>,
    /// The checkpoint's step.
    pub step: u64,
    /// Marching-cubes cells per side of the bound's cube.
    pub mesh_resolution: u32,
    /// The files written (the run's `output.mesh_formats`, named `mesh-{resolution}`).
    pub files: Vec<String>,
    /// Triangles of the mesh kept.
    pub mesh_triangles: usize,
    /// Connected components of the extracted mesh.
    pub mesh_components: usize,
    /// Components kept by `output.mesh_filter`.
    pub mesh_components_kept: usize,
    /// Wall seconds of the marching cubes and the files (vertex colours included).
    pub seconds: f64,
    /// The side of one pixel at the region of interest (normalised units; as `metrics.json`'s).
    pub pixel_footprint: Option<f64>,
    /// Against the data's ground truth by the run's protocol (`None`: the data has no truth, or
    /// the mesh no triangle).
    pub geometry: Option<RemeshedGeometry>,
}

/// The geometry of a [`Remeshed`] mesh ([`crate::outputs::RunGeometry`] flattened).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RemeshedGeometry {
    /// Chamfer: (accuracy + completeness) / 2 (`None`: not finite — no point within the
    /// protocol's maximum distance).
    pub chamfer: Option<f64>,
    /// Mesh → truth.
    pub accuracy: Option<f64>,
    /// Truth → mesh.
    pub completeness: Option<f64>,
    /// F-score at [`Self::f_score_tau`].
    pub f_score: f64,
    /// The F-score's threshold (`output.fscore_tau`).
    pub f_score_tau: f64,
    /// Normal consistency (`metrics.json`'s `normal_consistency`).
    pub normal_consistency: Option<f64>,
    /// The truth's own mesh at the same resolution by the same protocol (an analytic truth).
    pub mesh_floor: Option<f64>,
    /// Over what the training views observe (an analytic truth), with its floor.
    pub observed: Option<ObservedMetrics>,
    /// Per part of an analytic truth.
    pub parts: Vec<PartMetrics>,
}

/// Meshes `model` of the run in `folder` (its checkpoint or a snapshot's, on its data or the
/// same data at `data`) at `resolution` (`"model"`: its finest cell), writes
/// `mesh-{n}.{extension}` into the model's folder (the run's, or the snapshot's; vertex colours
/// and formats as the run's configuration says; an earlier remesh at the same resolution is
/// replaced, the run's own `mesh.*` never) and measures it against the data's truth with the
/// floor at that resolution. `progress(blocks done, blocks)`.
pub fn remesh(
    folder: &RunFolder,
    data: Option<&Path>,
    model: RunModel,
    resolution: MeshResolution,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Remeshed> {
    let mut trainer = open_run_model(folder.dir(), data, model)?;
    let n = trainer.set_mesh_resolution(resolution)?;
    let started = Instant::now();
    let (mesh, found, kept) = trainer.extract_mesh_with_stats(progress)?;
    let stem = model.sub_dir().map_or(format!("mesh-{n}"), |sub| format!("{sub}/mesh-{n}"));
    let files = write_meshes(&trainer, folder, &mesh, &stem)?;
    let seconds = started.elapsed().as_secs_f64();
    let measured = run_geometry(trainer.data(), &trainer.config().output, &mesh, Some(n), &trainer.train_cameras())?;
    let finite = crate::metrics::finite;
    let geometry = measured.map(|g| RemeshedGeometry {
        chamfer: finite(g.metrics.chamfer),
        accuracy: finite(g.metrics.accuracy),
        completeness: finite(g.metrics.completeness),
        f_score: g.metrics.f_score,
        f_score_tau: g.metrics.tau,
        normal_consistency: g.normal_consistency,
        mesh_floor: g.floor,
        observed: g.observed,
        parts: g.parts,
    });
    Ok(Remeshed {
        snapshot: model.snapshot(),
        step: trainer.state().step,
        mesh_resolution: n,
        files,
        mesh_triangles: mesh.triangles.len(),
        mesh_components: found,
        mesh_components_kept: kept,
        seconds,
        pixel_footprint: trainer.pixel_footprint(),
        geometry,
    })
}
