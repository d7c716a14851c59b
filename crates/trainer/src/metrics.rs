//! What a finished run measured, typed: written once to the run folder's `metrics.json` and read
//! back by the same struct (`trade`, the benches, the tests), so that a renamed field is a
//! compile error rather than a silent NaN.

use crate::config::SamplerKind;
use crate::error::{Context, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// PSNR of one rendered view.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ViewPsnr {
    /// Whole image (dB).
    pub whole: f64,
    /// Inside the mask, when the view has one (dB).
    pub masked: Option<f64>,
}

/// How well a mesh covers one part of an analytic truth (the built-in scenes): the truth's
/// surface points nearest that part ([`prob_grid::Shape::nearest_part`]) against the mesh.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PartMetrics {
    /// The part ([`prob_grid::Shape::describe`]), e.g. `torus 0.58 × 0.04` (the thin ring).
    pub part: String,
    /// Truth → mesh mean distance over the part's points (normalised units; `None`: infinite).
    pub completeness: Option<f64>,
    /// Fraction of the part's points within `f_score_tau` of the mesh.
    pub recall: f64,
    /// Mesh → truth mean distance over the mesh's points nearest this part (`None`: no point of
    /// the mesh is, or none within the protocol's outlier distance).
    pub accuracy: Option<f64>,
}

/// The geometry over what the training views observed ([`crate::observation`]): the DTU
/// evaluation's observation mask for an analytic truth (the built-in scenes), whose truth is the
/// whole surface, undersides no photo shows included.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct ObservedMetrics {
    /// Mean of `accuracy` and `completeness` (`None`: infinite).
    pub chamfer: Option<f64>,
    /// Mesh → truth mean distance over the mesh's points nearest an observed truth point.
    pub accuracy: Option<f64>,
    /// Observed truth → mesh mean distance.
    pub completeness: Option<f64>,
    /// F-score at the run's τ over the same points.
    pub f_score: f64,
    /// Share of the truth's points that a training view sees.
    pub truth_observed: f64,
    /// The truth's own mesh at the run's resolution, measured the same way.
    pub mesh_floor: Option<f64>,
    /// Normal consistency over the same pairs ([`RunMetrics::normal_consistency`]).
    pub normal_consistency: Option<f64>,
}

/// A distance as `metrics.json` holds it: `None` when not finite (no point within the protocol's
/// maximum distance; JSON has no infinity).
pub fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

impl ObservedMetrics {
    /// From the observed [`eval_metrics::GeometryMetrics`], the observed share and the floor.
    pub fn new(m: &eval_metrics::GeometryMetrics, truth_observed: f64, mesh_floor: Option<f64>) -> ObservedMetrics {
        ObservedMetrics {
            chamfer: finite(m.chamfer),
            accuracy: finite(m.accuracy),
            completeness: finite(m.completeness),
            f_score: m.f_score,
            truth_observed,
            mesh_floor,
            normal_consistency: None,
        }
    }
}

/// The metrics of a finished run (`metrics.json`). Optional figures are `None` (JSON `null`)
/// when the run cannot have them: no ground truth, an empty mesh, no masks, no training views
/// rendered — and the distances (`chamfer`, `accuracy`, `completeness`) also when they are
/// infinite: no point of the mesh (or of the truth) within `chamfer_max_dist` of the other, with
/// `f_score` then 0 (JSON has no infinity; `trade` says so beside its means).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct RunMetrics {
    /// The sampler trained with.
    pub sampler: SamplerKind,
    /// Iterations done.
    pub steps: u64,
    /// The time budget (`None`: a run of `steps`).
    pub time_budget_s: Option<f64>,
    /// Mean whole-image PSNR of the evaluation views (dB).
    pub psnr: Option<f64>,
    /// Mean PSNR inside the masks of the evaluation views (dB).
    pub psnr_masked: Option<f64>,
    /// Mean SSIM of the evaluation views.
    pub ssim: Option<f64>,
    /// The evaluation views (held-out; the training views when none is held out).
    pub psnr_views: Vec<usize>,
    /// Whether `psnr_views` are held out (false: no view was held out, they are training views).
    pub psnr_held_out: bool,
    /// Mean whole-image PSNR of the rendered training views (dB).
    pub psnr_train: Option<f64>,
    /// Mean masked PSNR of the rendered training views (dB).
    pub psnr_train_masked: Option<f64>,
    /// The rendered training views.
    pub psnr_train_views: Vec<usize>,
    /// PSNR of each evaluation view, in the order of `psnr_views`.
    pub psnr_per_view: Vec<ViewPsnr>,
    /// Chamfer distance, the mean of accuracy and completeness (normalised units).
    pub chamfer: Option<f64>,
    /// Chamfer in the dataset's own units.
    pub chamfer_world: Option<f64>,
    /// Mesh → truth mean distance (normalised units).
    pub accuracy: Option<f64>,
    /// Truth → mesh mean distance (normalised units).
    pub completeness: Option<f64>,
    /// F-score at `f_score_tau`.
    pub f_score: Option<f64>,
    /// The F-score threshold τ (normalised units).
    pub f_score_tau: f64,
    /// Normal consistency (`eval_metrics::Nearest::normal_consistency`): the mean |n · n'|
    /// between the mesh's and the truth's normals over the pairs the Chamfer distance counts —
    /// bumps on a smooth surface lower it where the Chamfer hardly moves (`None`: the truth has
    /// no normals, e.g. DTU's point cloud, or no pair lies within the outlier distance).
    pub normal_consistency: Option<f64>,
    /// Completeness and recall per part of an analytic truth (built-in scenes whose shape is a
    /// union: the composite's body, thin ring and foot); empty otherwise.
    pub parts: Vec<PartMetrics>,
    /// Length of one normalised unit in the dataset's units.
    pub world_scale: f64,
    /// The side of one pixel at the region of interest (the median over the views, normalised
    /// units; `crate::sizing::median_footprint`): a Chamfer divided by it is in the photos'
    /// pixels, comparable across scenes and resolutions (`None`: no view has the region's
    /// centre in front of it).
    pub pixel_footprint: Option<f64>,
    /// The mesh's marching-cubes resolution (cells per side of the bound's cube).
    pub mesh_resolution: u32,
    /// The Chamfer of the truth's own mesh at `mesh_resolution` by the same protocol: what no
    /// mesh of that resolution can beat (`None` without an analytic truth; built-in scenes).
    pub mesh_floor: Option<f64>,
    /// The geometry over what the training views observed (built-in scenes).
    pub observed: Option<ObservedMetrics>,
    /// Vertices of the mesh written.
    pub mesh_vertices: usize,
    /// Triangles of the mesh written.
    pub mesh_triangles: usize,
    /// Connected components of the extracted mesh.
    pub mesh_components: usize,
    /// Components kept by `output.mesh_filter`.
    pub mesh_components_kept: usize,
    /// Training time (the time a budget counts), over the whole run including earlier sessions.
    pub train_s: f64,
    /// Wall time of this process's training loop, interim metrics excluded.
    pub train_wall_s: f64,
    /// Mean time of a training step (this process).
    pub step_s: f64,
    /// Mean time of an iteration: step and grid updates (this process).
    pub iteration_s: f64,
    /// Mean time spent drawing rays per step (this process).
    pub rays_s: f64,
    /// Time spent on grid updates (this process).
    pub grid_s: f64,
    /// Grid updates done (this process).
    pub grid_updates: u64,
    /// Time of the final image metrics.
    pub eval_s: f64,
    /// Time of meshing and writing the mesh files.
    pub mesh_s: f64,
    /// Time of the geometry metrics.
    pub geometry_s: f64,
    /// Time of the final checkpoint.
    pub checkpoint_s: f64,
    /// Time spent on validation pictures during training.
    pub validation_s: f64,
    /// Worker threads.
    pub threads: usize,
    /// The memory model's peak, printed before the run (bytes).
    pub memory_estimate_bytes: f64,
    /// The process's peak resident memory (`VmHWM`, bytes; Linux).
    pub peak_rss_bytes: Option<f64>,
}

impl RunMetrics {
    /// Reads `metrics.json` of a run folder; the error names the file.
    pub fn read(run_dir: &Path) -> Result<RunMetrics> {
        let path = run_dir.join("metrics.json");
        let text = std::fs::read_to_string(&path).with_context(|| format!("cannot read {}", path.display()))?;
        serde_json::from_str(&text).with_context(|| format!("{} is not a run's metrics", path.display()))
    }

    /// Seconds of training per iteration over the whole run.
    pub fn seconds_per_iteration(&self) -> Option<f64> {
        (self.steps > 0).then(|| self.train_s / self.steps as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metrics_round_trip_through_json_with_missing_figures_as_null() {
        let m = RunMetrics {
            steps: 7,
            chamfer: None,
            psnr: Some(21.5),
            psnr_per_view: vec![ViewPsnr { whole: 21.5, masked: None }],
            ..Default::default()
        };
        let text = serde_json::to_string(&m).unwrap();
        assert!(text.contains("\"chamfer\":null"), "{text}");
        assert_eq!(serde_json::from_str::<RunMetrics>(&text).unwrap(), m);
    }
}
