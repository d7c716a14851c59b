//! Snapshots along one run (`output.snapshots`): at given training times the mesh and its
//! metrics are written to `snapshots/<seconds>s/` (`mesh.*`, `metrics.json`, and the model's
//! `checkpoint.safetensors` to mesh or render it again later) and logged
//! (`"snapshot"` records in `log.jsonl`), outside the training time, so that one run per seed
//! draws quality against time; budgeted runs remain for the headline figures (their schedules
//! follow the fraction of *their* budget, so a snapshot at 60 s of a 10-minute run is not a
//! 1-minute run).

use crate::bail;
use crate::error::{Context, Result};
use crate::folder::RunFolder;
use crate::metrics::RunMetrics;
use crate::outputs::{mesh_files, run_geometry};
use crate::trainer::Trainer;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The snapshot times still to take.
#[derive(Debug, Clone, Default)]
pub struct Snapshots {
    pending: Vec<f64>,
}

impl Snapshots {
    /// The times of `times` after `trained` seconds (a resumed run keeps the snapshots it took).
    pub fn new(times: &[f64], trained: f64) -> Snapshots {
        let mut pending: Vec<f64> = times.iter().copied().filter(|&t| t > trained).collect();
        pending.sort_by(f64::total_cmp);
        pending.dedup();
        Snapshots { pending }
    }

    /// The snapshot times reached after `trained` seconds, removed from the pending ones.
    pub fn due(&mut self, trained: f64) -> Vec<f64> {
        let n = self.pending.iter().take_while(|&&t| t <= trained).count();
        self.pending.drain(..n).collect()
    }
}

/// The folder of the snapshot at `at` seconds, relative to the run folder.
pub fn snapshot_dir(at: f64) -> String {
    format!("snapshots/{at}s")
}

/// The times of the snapshots the run in `run_dir` took (its `snapshots/<seconds>s/` folders),
/// in order.
pub fn snapshot_times(run_dir: &Path) -> Vec<f64> {
    let Ok(entries) = std::fs::read_dir(run_dir.join("snapshots")) else { return Vec::new() };
    let mut times: Vec<f64> =
        entries.filter_map(|e| e.ok()?.file_name().to_str()?.strip_suffix('s')?.parse::<f64>().ok()).filter(|t| t.is_finite()).collect();
    times.sort_by(f64::total_cmp);
    times
}

/// Which model of a run folder: the last one (its checkpoint) or the one a snapshot kept.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum RunModel {
    /// The run's checkpoint: the last model (or where a stopped run stopped).
    #[default]
    Last,
    /// The checkpoint the snapshot at these training seconds kept (`output.snapshot_checkpoints`).
    Snapshot(f64),
}

impl RunModel {
    /// The snapshot at `seconds` of the run in `run_dir`, at the time its folder names when one
    /// lies within a microsecond (a time typed as `6m` or `360` finds `snapshots/360s`).
    pub fn snapshot_near(run_dir: &Path, seconds: f64) -> RunModel {
        let taken = snapshot_times(run_dir).into_iter().find(|t| (t - seconds).abs() <= 1e-6);
        RunModel::Snapshot(taken.unwrap_or(seconds))
    }

    /// The snapshot's training seconds (`None`: the last model).
    pub fn snapshot(self) -> Option<f64> {
        match self {
            RunModel::Last => None,
            RunModel::Snapshot(at) => Some(at),
        }
    }

    /// The model's folder relative to the run folder (`None`: the run folder itself).
    pub fn sub_dir(self) -> Option<String> {
        self.snapshot().map(snapshot_dir)
    }

    /// The model's folder, where its checkpoint is and what is made from it goes.
    pub fn dir(self, run_dir: &Path) -> PathBuf {
        self.sub_dir().map_or_else(|| run_dir.to_path_buf(), |sub| run_dir.join(sub))
    }

    /// The model's checkpoint, checked to exist: the error names the snapshots the run took
    /// and says when a snapshot kept none.
    pub fn checkpoint(self, run_dir: &Path) -> Result<PathBuf> {
        let path = crate::folder::checkpoint_path(&self.dir(run_dir));
        match self {
            _ if path.is_file() => Ok(path),
            // A missing file, as the binding reports one (`OSError`).
            RunModel::Last => Err(std::io::Error::new(std::io::ErrorKind::NotFound, format!("no checkpoint in {}", run_dir.display())).into()),
            RunModel::Snapshot(at) if self.dir(run_dir).is_dir() => bail!(
                Input,
                "the snapshot at {at} s of {} kept no checkpoint (output.snapshot_checkpoints was false, or a build before snapshots kept one took it): only its mesh and metrics",
                run_dir.display()
            ),
            RunModel::Snapshot(at) => {
                let taken = snapshot_times(run_dir);
                let list = if taken.is_empty() {
                    "it took none".to_string()
                } else {
                    format!("its snapshots: {}", taken.iter().map(|t| format!("{t} s")).collect::<Vec<_>>().join(", "))
                };
                bail!(Input, "{} has no snapshot at {at} s ({list})", run_dir.display())
            }
        }
    }
}

/// What a snapshot measured (`snapshots/<seconds>s/metrics.json`), typed like the run's
/// [`RunMetrics`]: written and read by this one struct.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct SnapshotMetrics {
    /// The training time it was taken at (s).
    pub snapshot: f64,
    /// Iterations done.
    pub step: u64,
    /// Training time when it was taken (s; ≥ `snapshot`).
    pub train_s: f64,
    /// Chamfer (normalised units).
    pub chamfer: Option<f64>,
    /// Mesh → truth mean distance.
    pub accuracy: Option<f64>,
    /// Truth → mesh mean distance.
    pub completeness: Option<f64>,
    /// F-score at `f_score_tau`.
    pub f_score: Option<f64>,
    /// The F-score threshold τ.
    pub f_score_tau: f64,
    /// Normal consistency ([`RunMetrics::normal_consistency`]).
    pub normal_consistency: Option<f64>,
    /// Mean whole-image PSNR of `psnr_views` (dB).
    pub psnr: Option<f64>,
    /// Mean PSNR inside their masks (dB).
    pub psnr_masked: Option<f64>,
    /// The views rendered.
    pub psnr_views: Vec<usize>,
    /// Triangles of the mesh.
    pub mesh_triangles: usize,
    /// The mesh's marching-cubes resolution.
    pub mesh_resolution: u32,
    /// The truth's own mesh at that resolution ([`RunMetrics::mesh_floor`]).
    pub mesh_floor: Option<f64>,
    /// Per part of an analytic truth ([`RunMetrics::parts`]).
    pub parts: Vec<crate::metrics::PartMetrics>,
    /// Over what the training views observed ([`RunMetrics::observed`]).
    pub observed: Option<crate::metrics::ObservedMetrics>,
}

impl SnapshotMetrics {
    /// Reads the snapshot at `at` seconds of the run in `run_dir` (`None`: it was not taken).
    pub fn read(run_dir: &Path, at: f64) -> Result<Option<SnapshotMetrics>> {
        let path = run_dir.join(snapshot_dir(at)).join("metrics.json");
        if !path.is_file() {
            return Ok(None);
        }
        let text = std::fs::read_to_string(&path).with_context(|| format!("cannot read {}", path.display()))?;
        serde_json::from_str(&text).map(Some).with_context(|| format!("{} is not a snapshot's metrics", path.display()))
    }

    /// The figures a run's metrics share with a snapshot (the rest: defaults), for tables that
    /// read both (`cargo xtask trade`).
    pub fn as_run_metrics(&self, sampler: crate::config::SamplerKind) -> RunMetrics {
        RunMetrics {
            sampler,
            steps: self.step,
            psnr: self.psnr,
            psnr_masked: self.psnr_masked,
            psnr_views: self.psnr_views.clone(),
            chamfer: self.chamfer,
            accuracy: self.accuracy,
            completeness: self.completeness,
            f_score: self.f_score,
            f_score_tau: self.f_score_tau,
            normal_consistency: self.normal_consistency,
            mesh_resolution: self.mesh_resolution,
            mesh_floor: self.mesh_floor,
            observed: self.observed.clone(),
            mesh_triangles: self.mesh_triangles,
            train_s: self.train_s,
            ..Default::default()
        }
    }
}

/// Writes the snapshot at `at` seconds of `trainer` into `folder`: the mesh (the run's mesh
/// formats, world units), the checkpoint (`output.snapshot_checkpoints`, [`RunModel::Snapshot`])
/// and, last, `metrics.json` ([`SnapshotMetrics`]: Chamfer, accuracy, completeness, F-score when
/// the data has ground truth; PSNR whole and masked over `views`).
/// Returns the record it logged.
pub fn write_snapshot(trainer: &Trainer, folder: &RunFolder, at: f64, views: &[usize]) -> Result<serde_json::Value> {
    let config = trainer.config();
    let dir = snapshot_dir(at);
    std::fs::create_dir_all(folder.dir().join(&dir)).with_context(|| format!("cannot create {}", folder.dir().join(&dir).display()))?;
    let mesh = trainer.extract_mesh(&|_, _| {})?;
    for (format, bytes) in mesh_files(&mesh, &trainer.data().scene.world_from_normalized, None, &config.output.mesh_formats) {
        folder.write(&format!("{dir}/mesh.{}", format.extension()), &bytes)?;
    }
    let o = &config.output;
    let measured = run_geometry(trainer.data(), o, &mesh, Some(trainer.mesh_resolution()), &trainer.train_cameras())?;
    let geometry = measured.as_ref().map(|g| g.metrics);
    let psnr = views.iter().map(|&v| Ok(trainer.render_view(v, o.eval_downscale)?.psnr())).collect::<Result<Vec<_>>>()?;
    let mean = |values: Vec<f64>| (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64);
    let metrics = SnapshotMetrics {
        snapshot: at,
        step: trainer.state().step,
        train_s: trainer.state().train_seconds,
        chamfer: geometry.map(|g| g.chamfer),
        accuracy: geometry.map(|g| g.accuracy),
        completeness: geometry.map(|g| g.completeness),
        f_score: geometry.map(|g| g.f_score),
        f_score_tau: o.fscore_tau,
        normal_consistency: measured.as_ref().and_then(|g| g.normal_consistency),
        psnr: mean(psnr.iter().map(|p| p.0).collect()),
        psnr_masked: mean(psnr.iter().filter_map(|p| p.1).collect()),
        psnr_views: views.to_vec(),
        mesh_triangles: mesh.triangles.len(),
        mesh_resolution: trainer.mesh_resolution(),
        mesh_floor: measured.as_ref().and_then(|g| g.floor),
        observed: measured.as_ref().and_then(|g| g.observed.clone()),
        parts: measured.map(|g| g.parts).unwrap_or_default(),
    };
    if o.snapshot_checkpoints {
        folder.write_checkpoint_in(&dir, trainer)?;
    }
    folder.write(&format!("{dir}/metrics.json"), serde_json::to_string_pretty(&metrics)?.as_bytes())?;
    Ok(serde_json::to_value(&metrics)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn snapshots_come_once_in_order_and_a_resumed_run_keeps_the_ones_it_took() {
        let mut s = Snapshots::new(&[120.0, 60.0, 300.0, 60.0], 0.0);
        assert!(s.due(59.9).is_empty());
        assert_eq!(s.due(130.0), vec![60.0, 120.0]);
        assert!(s.due(131.0).is_empty());
        assert_eq!(s.due(1e9), vec![300.0]);
        let mut resumed = Snapshots::new(&[60.0, 120.0, 300.0], 120.0);
        assert_eq!(resumed.due(1e9), vec![300.0]);
    }

    /// A time typed with a unit finds the snapshot's folder (`6m` → `snapshots/360s`); a time
    /// no snapshot was taken at stays as typed, for the error to name.
    #[test]
    fn a_snapshot_is_found_by_its_time_in_any_unit() {
        let run = tempfile::tempdir().unwrap();
        for at in [0.001, 360.0] {
            std::fs::create_dir_all(run.path().join(snapshot_dir(at))).unwrap();
        }
        assert_eq!(snapshot_times(run.path()), vec![0.001, 360.0]);
        for (typed, found) in [("6m", 360.0), ("0.1h", 360.0), ("360", 360.0), ("0.001s", 0.001)] {
            let seconds = crate::config::parse_duration(typed).unwrap().as_secs_f64();
            let model = RunModel::snapshot_near(run.path(), seconds);
            assert_eq!(model, RunModel::Snapshot(found), "{typed}");
            assert_eq!(model.dir(run.path()), run.path().join(snapshot_dir(found)));
        }
        assert_eq!(RunModel::snapshot_near(run.path(), 5.0), RunModel::Snapshot(5.0));
        assert_eq!(RunModel::Last.dir(run.path()), run.path());
    }
}
