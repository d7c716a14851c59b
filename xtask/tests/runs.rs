//! Run folders under faults: resume with a changed configuration or a damaged checkpoint, failed
//! runs that must leave no stray folder, write failures of each kind (through an injectable sink)
//! that must keep the previous checkpoint, and `eval --run` values (renders and meshes made again)
//! against the run's own.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use trainer::run::{AtomicFiles, Outcome, Sink, checkpoint_path};
use xtask::train::{TrainArgs, train_with};

mod common;
use common::TINY;

fn xtask(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_xtask")).args(args).output().expect("xtask runs")
}

fn tiny_args(out: &Path) -> TrainArgs {
    TrainArgs { out: Some(out.to_path_buf()), overrides: TINY.iter().map(|s| s.to_string()).collect(), ..TrainArgs::default() }
}

#[test]
fn resume_with_a_changed_configuration_or_a_damaged_checkpoint_is_refused_and_keeps_the_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let mut args: Vec<&str> = vec!["train", "--out", run.to_str().unwrap(), "--stop-at", "3"];
    args.extend_from_slice(TINY);
    assert_eq!(xtask(&args).status.code(), Some(130));
    let ckpt = checkpoint_path(&run);
    let original = std::fs::read(&ckpt).unwrap();
    let resume = |extra: &[&str]| {
        let mut a = vec!["train", "--resume", run.to_str().unwrap()];
        a.extend_from_slice(extra);
        let o = xtask(&a);
        (o.status.success(), String::from_utf8_lossy(&o.stderr).to_string())
    };
    // Overrides on resume.
    let (ok, err) = resume(&["steps=10"]);
    assert!(!ok && err.contains("overrides"), "{err}");
    // config.toml edited by hand: the keys that differ are named.
    let config_path = run.join("config.toml");
    let config = std::fs::read_to_string(&config_path).unwrap();
    std::fs::write(&config_path, config.replace("steps = 6", "steps = 9")).unwrap();
    let (ok, err) = resume(&[]);
    assert!(!ok && err.contains("steps") && err.contains("differs"), "{err}");
    std::fs::write(&config_path, &config).unwrap();
    // A truncated and a corrupt checkpoint.
    for damaged in [original[..original.len() / 2].to_vec(), original.iter().map(|b| b ^ 0x5a).collect::<Vec<u8>>()] {
        std::fs::write(&ckpt, &damaged).unwrap();
        let (ok, err) = resume(&[]);
        assert!(!ok && err.contains("checkpoint.safetensors"), "{err}");
        assert!(!err.contains("panicked"), "{err}");
        assert!(std::fs::read(&ckpt).unwrap() == damaged, "the checkpoint was touched");
    }
    // The intact checkpoint resumes.
    std::fs::write(&ckpt, &original).unwrap();
    let (ok, err) = resume(&[]);
    assert!(ok, "{err}");
}

#[test]
fn a_failed_run_leaves_no_stray_folder() {
    let dir = tempfile::tempdir().unwrap();
    // Bad data: fails before anything is created.
    let out = dir.path().join("bad_data");
    let o = xtask(&["train", "--out", out.to_str().unwrap(), "--data", "/nonexistent/scan"]);
    assert!(!o.status.success() && !out.exists());
    // A write that fails before the first checkpoint: the folder it created is removed.
    let out = dir.path().join("failed_write");
    struct FailConfig;
    impl Sink for FailConfig {
        fn write(&self, path: &Path, bytes: &[u8]) -> std::io::Result<()> {
            if path.ends_with("data.json") { Err(std::io::Error::other("disk full (injected)")) } else { AtomicFiles.write(path, bytes) }
        }
    }
    let err = train_with(&tiny_args(&out), &AtomicBool::new(false), Arc::new(FailConfig)).expect_err("the run fails");
    assert!(format!("{err:#}").contains("data.json") && format!("{err:#}").contains("disk full"), "{err:#}");
    assert!(!out.exists(), "a stray run folder was left");
    // A folder that existed before is never removed.
    let existing = dir.path().join("existing");
    std::fs::create_dir_all(&existing).unwrap();
    std::fs::write(existing.join("notes.txt"), "mine").unwrap();
    assert!(train_with(&tiny_args(&existing), &AtomicBool::new(false), Arc::new(FailConfig)).is_err());
    assert_eq!(std::fs::read_to_string(existing.join("notes.txt")).unwrap(), "mine");
}

/// A sink that fails on the n-th write of files whose name contains `pattern`, and records what
/// the checkpoint held before each write.
struct FailNth {
    run: PathBuf,
    pattern: &'static str,
    fail_at: usize,
    count: AtomicUsize,
    checkpoint_before_failure: Mutex<Option<Vec<u8>>>,
}

impl Sink for FailNth {
    fn write(&self, path: &Path, bytes: &[u8]) -> std::io::Result<()> {
        if path.to_string_lossy().contains(self.pattern) {
            let n = self.count.fetch_add(1, Ordering::SeqCst) + 1;
            if n == self.fail_at {
                let ckpt = std::fs::read(checkpoint_path(&self.run)).ok();
                *self.checkpoint_before_failure.lock().unwrap() = ckpt;
                return Err(std::io::Error::other("no space left on device (injected)"));
            }
        }
        AtomicFiles.write(path, bytes)
    }
}

#[test]
fn write_failures_name_the_file_and_keep_the_previous_checkpoint() {
    // (file pattern, which write of it fails): the second checkpoint, the mesh, a picture, the
    // metrics.
    for (pattern, fail_at) in [("checkpoint.safetensors", 2), ("mesh.ply", 1), ("pictures/", 1), ("metrics.json", 1)] {
        let dir = tempfile::tempdir().unwrap();
        let out: PathBuf = dir.path().join("run");
        let sink = Arc::new(FailNth { run: out.clone(), pattern, fail_at, count: AtomicUsize::new(0), checkpoint_before_failure: Mutex::new(None) });
        let result = train_with(&tiny_args(&out), &AtomicBool::new(false), sink.clone());
        let err = result.err().unwrap_or_else(|| panic!("{pattern}: the run succeeded"));
        let msg = format!("{err:#}");
        assert!(msg.contains(pattern.trim_end_matches('/')) && msg.contains("no space left"), "{pattern}: {msg}");
        // The checkpoint on disk is the one that was there before the failed write.
        let before = sink.checkpoint_before_failure.lock().unwrap().clone();
        let now = std::fs::read(checkpoint_path(&out)).ok();
        assert!(now == before, "{pattern}: the previous checkpoint changed");
        if pattern == "checkpoint.safetensors" {
            assert!(now.is_some(), "the first checkpoint must survive the failure of the second");
        }
    }
}

#[test]
fn eval_of_a_run_reproduces_the_runs_own_psnr() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let Outcome::Finished(summary) = train_with(&tiny_args(&out), &AtomicBool::new(false), Arc::new(AtomicFiles)).unwrap() else {
        panic!("the run was stopped")
    };
    let o = xtask(&["eval", "--run", out.to_str().unwrap(), "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let eval: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    // Both at the resolution trained on (`output.eval_downscale` = 1), not the pictures' 4.
    assert_eq!(eval["downscale"].as_u64(), Some(1), "{eval}");
    // The run's metrics are on the first of its evaluation views at the same downscale.
    let view = summary.metrics.psnr_views[0] as u64;
    let per_view = eval["per_view"].as_array().unwrap().iter().find(|p| p["view"].as_u64() == Some(view)).expect("the view is evaluated");
    let (a, b) = (per_view["psnr"].as_f64().unwrap(), summary.metrics.psnr_per_view[0].whole);
    assert!((a - b).abs() < 1e-6, "eval --run gives {a} dB, the run {b} dB on view {view}");
    let masked = per_view["psnr_masked"].as_f64().unwrap();
    assert!(a.is_finite() && a > 5.0 && masked.is_finite() && masked > 5.0, "{per_view}");
    // SSIM is in [−1, 1] (below 0 for a model of 6 iterations), absent for images smaller than its window.
    assert!(eval["ssim"].is_null() || eval["ssim"].as_f64().is_some_and(|s| (-1.0..=1.0).contains(&s)), "{}", eval["ssim"]);
    // The renders' up-sampling is not part of what was learnt: another one re-renders the run
    // (a changed training key would be refused).
    let o = xtask(&["eval", "--run", out.to_str().unwrap(), "--render-fine", "4", "--render-rounds", "1", "--render-colour-stride", "2", "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let coarse: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!((coarse["render_fine"].as_u64(), coarse["render_upsample_rounds"].as_u64()), (Some(4), Some(1)), "{coarse}");
    assert_eq!((eval["render_colour_stride"].as_u64(), coarse["render_colour_stride"].as_u64()), (Some(4), Some(2)), "the default, then the flag's");
    assert!(coarse["psnr"].as_f64().is_some_and(f64::is_finite), "{coarse}");
}

#[test]
fn remeshing_a_run_at_its_own_resolution_measures_what_the_run_measured() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let Outcome::Finished(summary) = train_with(&tiny_args(&out), &AtomicBool::new(false), Arc::new(AtomicFiles)).unwrap() else {
        panic!("the run was stopped")
    };
    let own_mesh = std::fs::read(out.join("mesh.ply")).unwrap();
    let remesh = |resolution: &str| {
        let o = xtask(&["eval", "--run", out.to_str().unwrap(), "--mesh-resolution", resolution, "--json"]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice::<serde_json::Value>(&o.stdout).unwrap()
    };
    // The run's own resolution (`output.mesh_resolution=24`): the run's mesh, byte for byte
    // (vertex colours included), and its figures.
    let same = remesh("24");
    assert_eq!(same["mesh_resolution"].as_u64(), Some(24), "{same}");
    assert_eq!(std::fs::read(out.join("mesh-24.ply")).unwrap(), own_mesh);
    let g = &same["geometry"];
    assert_eq!(g["chamfer"].as_f64(), summary.metrics.chamfer, "{same}");
    assert_eq!(g["mesh_floor"].as_f64(), summary.metrics.mesh_floor, "{same}");
    assert_eq!(same["mesh_triangles"].as_u64(), Some(summary.metrics.mesh_triangles as u64));
    assert_eq!(g["observed"]["chamfer"].as_f64(), summary.metrics.observed.as_ref().and_then(|o| o.chamfer), "{same}");
    let written: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("mesh-24.json")).unwrap()).unwrap();
    assert_eq!(written["geometry"], same["geometry"]);
    assert!(written["cpu"].is_string(), "a time figure names the machine: {written}");
    // The photos' pixel at the region of interest, as the run's metrics give it: the Chamfer in pixels.
    assert!(summary.metrics.pixel_footprint.is_some_and(|f| f > 0.0), "{:?}", summary.metrics.pixel_footprint);
    assert_eq!(same["pixel_footprint"].as_f64(), summary.metrics.pixel_footprint);
    // Twice as fine: more triangles, a lower floor; the run's own mesh is left as it was.
    let fine = remesh("48");
    assert!(fine["mesh_triangles"].as_u64() > same["mesh_triangles"].as_u64(), "{fine}");
    assert!(fine["geometry"]["mesh_floor"].as_f64().unwrap() < g["mesh_floor"].as_f64().unwrap(), "{fine}");
    assert!(out.join("mesh-48.ply").is_file());
    assert_eq!(std::fs::read(out.join("mesh.ply")).unwrap(), own_mesh);
    // `model`: the preset's finest hash-grid level (256 cells per side).
    assert_eq!(remesh("model")["mesh_resolution"].as_u64(), Some(256));
    assert_eq!(same["mesh_components"].as_u64(), Some(summary.metrics.mesh_components as u64));
    // What cannot work is refused, naming what is expected; the run's protocol is not changed
    // by a flag that would be ignored.
    for (args, says) in [
        (vec!["--mesh-resolution", "4"], "8 … 2048"),
        (vec!["--mesh-resolution", "fine"], "\"model\""),
        (vec!["--mesh-resolution", "24", "--render-fine", "4"], "cannot be used with"),
        (vec!["--mesh-resolution", "24", "--tau", "0.005"], "cannot be used with"),
    ] {
        let mut all = vec!["eval", "--run", out.to_str().unwrap()];
        all.extend(args);
        let o = xtask(&all);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && stderr.contains(says), "{all:?}: {stderr}");
    }
}

#[test]
fn a_snapshots_model_is_meshed_and_rendered_again_from_the_checkpoint_it_kept() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let mut args = tiny_args(&out);
    args.overrides.push("output.snapshots=[0.001]".into());
    let Outcome::Finished(summary) = train_with(&args, &AtomicBool::new(false), Arc::new(AtomicFiles)).unwrap() else {
        panic!("the run was stopped")
    };
    let snapshot = out.join("snapshots/0.001s");
    let taken: serde_json::Value = serde_json::from_slice(&std::fs::read(snapshot.join("metrics.json")).unwrap()).unwrap();
    assert!(taken["step"].as_u64() < Some(summary.metrics.steps), "the snapshot comes before the end: {taken}");
    assert!(snapshot.join("checkpoint.safetensors").is_file(), "a snapshot keeps its model");
    let eval = |extra: &[&str]| {
        let mut all = vec!["eval", "--run", out.to_str().unwrap(), "--json"];
        all.extend(extra);
        let o = xtask(&all);
        assert!(o.status.success(), "{all:?}: {}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice::<serde_json::Value>(&o.stdout).unwrap()
    };
    // Meshed again at the run's resolution: the snapshot's own mesh and Chamfer, from the
    // snapshot's step (not the run's last), written into the snapshot's folder.
    let remeshed = eval(&["--snapshot", "0.001", "--mesh-resolution", "24"]);
    assert_eq!((remeshed["snapshot"].as_f64(), remeshed["step"].as_u64()), (Some(0.001), taken["step"].as_u64()), "{remeshed}");
    assert_eq!(std::fs::read(snapshot.join("mesh-24.ply")).unwrap(), std::fs::read(snapshot.join("mesh.ply")).unwrap());
    assert_eq!(remeshed["geometry"]["chamfer"], taken["chamfer"], "{remeshed}");
    assert!(snapshot.join("mesh-24.json").is_file() && !out.join("mesh-24.ply").exists() && !out.join("mesh-24.json").exists());
    // Rendered again (every held-out view): the snapshot's PSNR on the view it rendered,
    // eval.json in the snapshot's folder.
    let rendered = eval(&["--snapshot", "0.001"]);
    assert_eq!((rendered["step"].as_u64(), &rendered["views"][0]), (taken["step"].as_u64(), &taken["psnr_views"][0]), "{rendered}");
    assert_eq!(taken["psnr_views"].as_array().map(Vec::len), Some(1), "{taken}");
    let (again, then) = (rendered["per_view"][0]["psnr"].as_f64().unwrap(), taken["psnr"].as_f64().unwrap());
    assert!((again - then).abs() < 1e-6, "PSNR {again} rendered again, {then} when taken");
    assert!(snapshot.join("eval.json").is_file() && !out.join("eval.json").exists());
    // A time the run took no snapshot at names the ones it took; a snapshot without a
    // checkpoint (output.snapshot_checkpoints=false, or an earlier build) says so.
    std::fs::remove_file(snapshot.join("checkpoint.safetensors")).unwrap();
    for (at, says) in [("5s", "has no snapshot at 5 s (its snapshots: 0.001 s)"), ("0.001", "kept no checkpoint")] {
        let o = xtask(&["eval", "--run", out.to_str().unwrap(), "--snapshot", at, "--mesh-resolution", "24"]);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && stderr.contains(says), "--snapshot {at}: {stderr}");
    }
}
