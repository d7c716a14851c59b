//! The probability field of the PS-NeuS sampler (Sec. 4.1–4.3 of the paper).
//!
//! ```text
//!  SdfField ──evaluate──▶ ActiveCells ──reproject (per camera)──▶ CameraGrid p̃(u, v, λ)
//!  S(x)         p(x) = φ_s(S(x)) on R³ cells,      f = g∘h, η⁻² or mass weighting,
//!               partitioned by F                   view dependency along λ
//! ```
//! The result is consumed by `view-sampler`, which builds the marginal and conditional CDFs and
//! draws (camera, pixel, λ̃) samples. The crate also extracts meshes from any field
//! ([`marching_cubes()`]: block-wise, shared vertices, blocks skipped by the Lipschitz bound).
//!
//! # Choices (docs/DECISIONS.md) and what they cost
//! - **Cell density** ([`CellDensity`]): the paper's φ_s at the cell centre aliases when the
//!   logistic shell is thinner than a cell (s·cell ≳ 10); the default averages φ_s over the
//!   cell's SDF range, so the grid's mass is right for any s in 1e-3…1e7. Same cost.
//! - **Partition F** ([`SceneGridConfig::partition`]): F³ sub-cells per cell, with the parent's
//!   mass split (paper) or re-evaluated ([`SubcellMass`], F³ × the field queries). Projection
//!   cost grows as F³.
//! - **Weighting** ([`Weighting`]): η⁻² as printed (default) or mass-preserving.
//! - **View dependency** ([`ViewDependency`]): opaque (default), quadrature, paper-literal, off.
//! - **Sparse update** ([`Evaluation::Sparse`], default): octree descent with the field's
//!   Lipschitz bound; equal to the dense reference within the mass tolerance (tests), with work
//!   proportional to the surface for large s.
//!
//! **Which won:** the paper's defaults (F = 2, opaque view dependency, η⁻² weighting); no
//! alternative beat them beyond the seed noise at equal wall time, and the guide itself is what
//! matters against uniform sampling. The figures, with their commands and builds:
//! BENCHMARKS.md, "The paper's ablation" and "Guided vs uniform at equal wall time"; the
//! decisions: docs/DECISIONS.md §13 and §18.
//!
//! # Invariants
//! - Knows nothing of the backbone: it sees an SDF only through [`SdfField`].
//! - Every value it produces is finite and ≥ 0, for any s > 0 and any field output (NaN = no mass).
//! - No allocation per cell or per sample: per update, per camera buffers only.
//!
//! ```
//! use prob_grid::{update, CameraGridConfig, SceneGridConfig, Shape};
//! use camera_geom::{Intrinsics, PinholeCamera, PixelCenters};
//! use glam::DVec3;
//! let k = Intrinsics { fx: 300.0, fy: 300.0, cx: 99.5, cy: 74.5, skew: 0.0 };
//! let camera = PinholeCamera::look_at(DVec3::new(0.0, -3.0, 0.0), DVec3::ZERO, DVec3::Z, k, 200, 150, PixelCenters::Integer).unwrap();
//! let sphere = Shape::Sphere { center: DVec3::ZERO, radius: 0.5 };
//! let scene = SceneGridConfig { resolution: 32, ..Default::default() };
//! let cams = CameraGridConfig { ru: 16, rv: 16, rl: 32, ..Default::default() };
//! let grids = update(&sphere, 200.0, &[camera], &scene, &cams).unwrap();
//! assert!(grids.cameras[0].total() > 0.0);
//! ```
#![deny(missing_docs)]

pub mod camera;
pub mod density;
pub mod field;
pub mod marching_cubes;
mod mc_tables;
pub mod mesh;
pub mod occupancy;
pub mod scene;

pub use camera::{CameraGrid, CameraGridConfig, ViewDependency, Weighting, reproject};
pub use density::{CellDensity, logistic_density};
pub use field::{SdfField, Shape, ShapeName};
pub use marching_cubes::{ExtractionStats, IsoMesh, MarchingCubesConfig, marching_cubes, marching_cubes_with_progress};
pub use mesh::{MeshHit, MeshSdf, TriangleMesh, vertex_normals};
pub use occupancy::Occupancy;
pub use scene::{ActiveCells, Evaluation, GridError, LIPSCHITZ_MARGIN, LipschitzCheck, SceneGridConfig, SubcellMass, evaluate};

use camera_geom::PinholeCamera;
use rayon::prelude::*;

/// The result of one probability update: a grid per camera and what it cost.
#[derive(Debug, Clone)]
pub struct ProbabilityGrids {
    /// One grid per camera, in the order given.
    pub cameras: Vec<CameraGrid>,
    /// Scene mass Σ p(x)·volume.
    pub scene_mass: f64,
    /// Field queries made.
    pub field_queries: usize,
    /// Sub-cells projected into each camera (cells kept × offsets).
    pub subcells: usize,
    /// Field values that were NaN (counted as no mass).
    pub nan_values: usize,
    /// Cameras whose grid holds no mass (the sampler falls back to uniform for them).
    pub empty_cameras: Vec<usize>,
}

/// Evaluates the field on the scene grid and reprojects it into every camera (in parallel).
pub fn update(
    field: &dyn SdfField,
    s: f32,
    cameras: &[PinholeCamera],
    scene: &SceneGridConfig,
    camera_config: &CameraGridConfig,
) -> Result<ProbabilityGrids, GridError> {
    camera_config.validate()?;
    let active = evaluate(field, s, scene)?;
    let grids: Vec<CameraGrid> = cameras.par_iter().map(|c| reproject(&active, c, camera_config)).collect();
    let empty_cameras = grids.iter().enumerate().filter(|(_, g)| !(g.total() > 0.0)).map(|(i, _)| i).collect();
    Ok(ProbabilityGrids {
        cameras: grids,
        scene_mass: active.total_mass,
        field_queries: active.field_queries,
        subcells: active.points.len() * active.offsets.len(),
        nan_values: active.nan_values,
        empty_cameras,
    })
}

/// The grids "as a sphere" (the paper's initialisation: the backbone's initial SDF is a sphere
/// of radius `radius`).
pub fn initial_sphere(
    radius: f64,
    s: f32,
    cameras: &[PinholeCamera],
    scene: &SceneGridConfig,
    camera_config: &CameraGridConfig,
) -> Result<ProbabilityGrids, GridError> {
    update(&Shape::Sphere { center: glam::DVec3::ZERO, radius }, s, cameras, scene, camera_config)
}
