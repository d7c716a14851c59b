//! The evaluation protocol of a mesh against a ground truth (points, a mesh or an analytic
//! shape): the DTU protocol's distances ([`Protocol`], defaults from the truth's size), both sides
//! sampled at the protocol's spacing, Chamfer and F-score ([`evaluate_mesh`]); mesh files
//! ([`read_mesh`]). `cargo xtask eval --mesh`, the runs' metrics and the Python binding use it.

use crate::bail;
use crate::data::Truth;
use crate::error::{Context, Result};
use datasets::io::PlyData;
use glam::Vec3;
use std::path::Path;

/// Vertices and triangles.
pub type MeshArrays = (Vec<[f32; 3]>, Vec<[u32; 3]>);

/// The ground truth of a mesh evaluation.
#[derive(Debug, Clone)]
pub enum GroundTruth {
    /// Points (e.g. DTU's `stl*_total.ply`).
    Points(Vec<[f32; 3]>),
    /// A mesh, sampled at the protocol's spacing like the prediction.
    Mesh(MeshArrays),
    /// An analytic surface, sampled at the protocol's spacing like a mesh.
    Shape(prob_grid::Shape),
}

/// The protocol's distances in the mesh's units; `None`: from the ground truth's bounding-box
/// diagonal (spacing / 1000, outlier distance / 20, F-score τ / 200).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Protocol {
    /// Sampling spacing on meshes (DTU: 0.2 mm).
    pub spacing: Option<f64>,
    /// Outlier distance (DTU: 20 mm).
    pub max_dist: Option<f64>,
    /// F-score threshold τ.
    pub tau: Option<f64>,
}

/// The distances an evaluation used.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Distances {
    /// Sampling spacing on meshes.
    pub spacing: f64,
    /// Outlier distance.
    pub max_dist: f64,
    /// F-score threshold τ.
    pub tau: f64,
}

impl GroundTruth {
    /// The protocol's distances for this ground truth (`name` says which in errors): a given
    /// distance must be finite and positive; a missing one comes from the bounding box, which
    /// must not be degenerate.
    pub fn distances(&self, protocol: Protocol, name: &str) -> Result<Distances> {
        for (key, v) in [("spacing", protocol.spacing), ("max_dist", protocol.max_dist), ("tau", protocol.tau)] {
            if let Some(v) = v.filter(|v| !(v.is_finite() && *v > 0.0)) {
                bail!(Config, "{key} = {v}: expected a positive distance");
            }
        }
        let coarse;
        let points = match self {
            GroundTruth::Points(p) => p,
            GroundTruth::Mesh((v, _)) => v,
            GroundTruth::Shape(shape) => {
                // The bounding box of a thousand-odd surface points.
                coarse = crate::data::analytic_truth(shape, (shape.area() / 1000.0).sqrt());
                &coarse
            }
        };
        let (lo, hi) =
            points.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(a, b), p| (a.min(Vec3::from_array(*p)), b.max(Vec3::from_array(*p))));
        let diagonal = f64::from((hi - lo).length());
        if !(diagonal.is_finite() && diagonal > 0.0) {
            let what = if name.is_empty() { "the ground truth".to_string() } else { format!("the ground truth {name}") };
            bail!(Input, "{what} is degenerate (its bounding box has diagonal {diagonal}): a single point or non-finite coordinates");
        }
        Ok(Distances {
            spacing: protocol.spacing.unwrap_or(diagonal / 1000.0),
            max_dist: protocol.max_dist.unwrap_or(diagonal / 20.0),
            tau: protocol.tau.unwrap_or(diagonal / 200.0),
        })
    }

    /// The ground-truth points (the points, or the mesh or shape sampled every `spacing`) with
    /// the truth's unit normals where it has them (a mesh's triangles, a shape's gradient; points
    /// have none).
    pub fn into_truth(self, spacing: f64) -> Result<Truth> {
        Ok(match self {
            GroundTruth::Points(points) => Truth { points, normals: None },
            GroundTruth::Mesh((v, f)) => {
                let sampled = eval_metrics::sample_mesh_oriented(&v, &f, spacing, GT_SAMPLING_SEED).context("the ground-truth mesh")?;
                Truth { points: sampled.points, normals: Some(sampled.normals) }
            }
            GroundTruth::Shape(shape) => {
                let points = crate::data::analytic_truth(&shape, spacing);
                Truth { normals: Some(crate::data::analytic_normals(&shape, &points)), points }
            }
        })
    }
}

/// The truth's sampling seed: a truth mesh's surface sampling, and an analytic surface's.
pub const GT_SAMPLING_SEED: u64 = 7;
/// The predicted mesh's sampling seed.
pub const PRED_SAMPLING_SEED: u64 = 11;

/// What [`evaluate_mesh`] measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshEvaluation {
    /// Chamfer, accuracy, completeness, F-score.
    pub metrics: eval_metrics::GeometryMetrics,
    /// The mesh's normals against the truth's over the same pairs
    /// (`eval_metrics::Nearest::normal_consistency`; `None`: truth points have no normals, or no
    /// pair lies within the outlier distance).
    pub normal_consistency: Option<f64>,
    /// The distances used.
    pub distances: Distances,
}

/// A mesh (`vertices`, `triangles`) against `gt` under `protocol`: the DTU-protocol Chamfer and
/// F-score in the mesh's units, the normal consistency, and the distances used. What `cargo
/// xtask eval --mesh` does without culling, alignment or ICP; the Python binding's
/// `evaluate_mesh`.
pub fn evaluate_mesh(vertices: &[[f32; 3]], triangles: &[[u32; 3]], gt: GroundTruth, protocol: Protocol) -> Result<MeshEvaluation> {
    if triangles.is_empty() {
        bail!(Input, "the mesh has no triangles");
    }
    let d = gt.distances(protocol, "")?;
    let truth = gt.into_truth(d.spacing)?;
    let pred = eval_metrics::sample_mesh_oriented(vertices, triangles, d.spacing, PRED_SAMPLING_SEED).context("the mesh")?;
    let nearest = eval_metrics::Nearest::new(&pred.points, &truth.points)?;
    let normal_consistency = crate::outputs::normal_consistency(&nearest, crate::outputs::normal_pairs(&pred, &truth), d.max_dist, None)?;
    Ok(MeshEvaluation { metrics: nearest.chamfer(d.max_dist, d.tau), normal_consistency, distances: d })
}

/// Reads a mesh file (.ply, .obj, .gltf, .glb).
pub fn read_mesh(path: &Path) -> Result<MeshArrays> {
    let is_ply = path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("ply"));
    if is_ply {
        let ply = PlyData::read(path)?;
        Ok((ply.positions.iter().map(|p| p.to_array()).collect(), ply.faces))
    } else {
        let m = datasets::golden::mesh_io::load_mesh(path)?;
        Ok((m.mesh.positions.iter().map(|p| p.to_array()).collect(), m.mesh.triangles.clone()))
    }
}
