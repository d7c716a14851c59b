//! What a careless or unlucky user does, guarded: a resumed run on other data, `--out` on a
//! folder of theirs, a budget built in code, a log after a kill, flags out of range, splits and
//! downscales that leave nothing to train or render. Each test is named after what it guards.

use std::path::Path;
use std::process::{Command, Output};
use trainer::config::{Budget, TrainConfig};
use trainer::data::SceneData;
use trainer::trainer::Trainer;

mod common;
use common::TINY;

fn xtask_in(cwd: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_xtask")).current_dir(cwd).args(args).output().expect("xtask runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A golden scene of `shape` (8 views of 40 × 30) written to `out`.
fn golden(cwd: &Path, shape: &str, out: &str) {
    let o = xtask_in(cwd, &["golden", "--shape", shape, "--views", "8", "--width", "40", "--height", "30", "--out", out]);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn a_step_budget_built_in_code_trains_that_many_steps() {
    let mut config = TrainConfig { budget: Budget::Steps(5), ..TrainConfig::default() };
    config.data.builtin.width = 32;
    config.data.builtin.views = 6;
    config.render.rays = 16;
    config.guide.scene.resolution = 16;
    let mut trainer = Trainer::new(config.clone(), SceneData::builtin(&config).unwrap()).unwrap();
    while !trainer.done() {
        trainer.step().unwrap();
    }
    assert_eq!(trainer.state().step, 5);
}

#[test]
fn a_resumed_run_trains_on_its_own_data_or_refuses() {
    let dir = tempfile::tempdir().unwrap();
    let (here, elsewhere) = (dir.path().join("here"), dir.path().join("elsewhere"));
    std::fs::create_dir_all(&here).unwrap();
    std::fs::create_dir_all(&elsewhere).unwrap();
    golden(&here, "sphere", "scene");
    golden(&elsewhere, "torus", "scene");
    // Trained on `scene` as typed (relative), stopped.
    let mut args = vec!["train", "--data", "scene", "--out", "run", "--stop-at", "2"];
    args.extend_from_slice(TINY);
    assert_eq!(xtask_in(&here, &args).status.code(), Some(130));
    let run = here.join("run");
    let record: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(run.join("data.json")).unwrap()).unwrap();
    assert!(Path::new(record["path"].as_str().unwrap()).is_absolute(), "{record}");
    // Resumed from a folder whose `scene` is another scene: the run's own data is used.
    let o = xtask_in(&elsewhere, &["train", "--resume", run.to_str().unwrap(), "--stop-at", "3"]);
    assert_eq!(o.status.code(), Some(130), "{}", stderr(&o));
    // The data changed in place: refused, naming what differs, the checkpoint untouched.
    let checkpoint = std::fs::read(run.join("checkpoint.safetensors")).unwrap();
    std::fs::rename(here.join("scene"), here.join("sphere")).unwrap();
    std::fs::rename(elsewhere.join("scene"), here.join("scene")).unwrap();
    let o = xtask_in(&here, &["train", "--resume", "run"]);
    let err = stderr(&o);
    assert!(!o.status.success() && err.contains("not what the run trained on") && err.contains("differ"), "{err}");
    assert_eq!(std::fs::read(run.join("checkpoint.safetensors")).unwrap(), checkpoint);
    // The same for `eval --run`.
    let o = xtask_in(&here, &["eval", "--run", "run"]);
    assert!(!o.status.success() && stderr(&o).contains("not what the run trained on"), "{}", stderr(&o));
    // Its own data at a new place, named with --data: accepted and recorded.
    let o = xtask_in(&here, &["train", "--resume", "run", "--data", "sphere"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let record: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(run.join("data.json")).unwrap()).unwrap();
    assert!(record["path"].as_str().unwrap().ends_with("sphere"), "{record}");
}

#[test]
fn an_out_folder_the_user_made_is_never_written_and_a_run_is_replaced_only_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let mine = dir.path().join("mine");
    std::fs::create_dir_all(&mine).unwrap();
    std::fs::write(mine.join("config.toml"), "my notes").unwrap();
    let mut args = vec!["train", "--out", "mine"];
    args.extend_from_slice(TINY);
    let o = xtask_in(dir.path(), &args);
    assert!(!o.status.success() && stderr(&o).contains("not a run folder"), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(mine.join("config.toml")).unwrap(), "my notes");
    assert_eq!(std::fs::read_dir(&mine).unwrap().count(), 1, "something was written");
    // An earlier run: refused without --overwrite, replaced with it.
    let mut args = vec!["train", "--out", "run"];
    args.extend_from_slice(TINY);
    assert!(xtask_in(dir.path(), &args).status.success());
    let o = xtask_in(dir.path(), &args);
    assert!(!o.status.success() && stderr(&o).contains("--overwrite"), "{}", stderr(&o));
    args.push("--overwrite");
    let o = xtask_in(dir.path(), &args);
    assert!(o.status.success(), "{}", stderr(&o));
    let log = std::fs::read_to_string(dir.path().join("run/log.jsonl")).unwrap();
    assert_eq!(log.lines().filter(|l| l.contains("\"step\":6,")).count(), 1, "the earlier run's log was kept: {log}");
}

#[test]
fn a_resumed_run_logs_each_iteration_once() {
    let dir = tempfile::tempdir().unwrap();
    let mut args = vec!["train", "--out", "run", "--stop-at", "2", "output.log_every=1"];
    args.extend_from_slice(TINY);
    assert_eq!(xtask_in(dir.path(), &args).status.code(), Some(130));
    // A session killed after its checkpoint at step 2 had logged steps 3 and 4.
    let log = dir.path().join("run/log.jsonl");
    let mut text = std::fs::read_to_string(&log).unwrap();
    text += "{\"step\":3,\"loss\":1.0}\n{\"step\":4,\"loss\":1.0}\n";
    std::fs::write(&log, text).unwrap();
    let o = xtask_in(dir.path(), &["train", "--resume", "run"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let steps: Vec<u64> =
        std::fs::read_to_string(&log).unwrap().lines().filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok()?["step"].as_u64()).collect();
    assert!(steps.windows(2).all(|w| w[0] <= w[1]) && steps.contains(&6), "{steps:?}");
    assert!(!std::fs::read_to_string(&log).unwrap().contains("\"loss\":1.0}"), "the killed session's lines were kept");
}

#[test]
fn cameras_write_no_file_unless_asked() {
    let dir = tempfile::tempdir().unwrap();
    golden(dir.path(), "sphere", "scene");
    let o = xtask_in(dir.path(), &["cameras", "--data", "scene"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!dir.path().join("cameras.ply").exists());
    let o = xtask_in(dir.path(), &["cameras", "--data", "scene", "--ply", "frusta.ply"]);
    assert!(o.status.success() && dir.path().join("frusta.ply").is_file(), "{}", stderr(&o));
}

#[test]
fn out_of_range_evaluation_flags_and_degenerate_truth_are_refused_with_the_cause() {
    let dir = tempfile::tempdir().unwrap();
    let mut args = vec!["train", "--out", "run"];
    args.extend_from_slice(TINY);
    assert!(xtask_in(dir.path(), &args).status.success());
    for (args, expect) in [
        (vec!["eval", "--run", "run", "--downscale", "0"], "--downscale"),
        (vec!["eval", "--mesh", "run/mesh.ply", "--gt-mesh", "run/mesh.ply", "--spacing", "0"], "positive"),
        (vec!["eval", "--mesh", "run/mesh.ply", "--gt-mesh", "run/mesh.ply", "--tau=-1"], "positive"),
    ] {
        let o = xtask_in(dir.path(), &args);
        assert!(!o.status.success() && stderr(&o).contains(expect), "{args:?}: {}", stderr(&o));
    }
    // Ground truth of one point.
    let ply = datasets::io::PlyData { positions: vec![glam::Vec3::ZERO], ..Default::default() };
    ply.write(&dir.path().join("one.ply")).unwrap();
    let o = xtask_in(dir.path(), &["eval", "--mesh", "run/mesh.ply", "--gt-points", "one.ply"]);
    assert!(!o.status.success() && stderr(&o).contains("degenerate"), "{}", stderr(&o));
}

#[test]
fn splits_and_downscales_that_leave_nothing_fail_before_training() {
    let dir = tempfile::tempdir().unwrap();
    for (extra, expect) in [
        ("data.holdout_every=1", "data.holdout_every"),
        ("output.validate_downscale=64", "output.validate_downscale"),
        ("--budget=1e3x", "unknown unit"),
    ] {
        let mut args = vec!["train", "--out", "run"];
        args.extend_from_slice(TINY);
        args.push(extra);
        let o = xtask_in(dir.path(), &args);
        assert!(!o.status.success() && stderr(&o).contains(expect), "{extra}: {}", stderr(&o));
        assert!(!dir.path().join("run").exists(), "{extra}: a run folder was made");
    }
    let o = xtask_in(dir.path(), &["train", "--data", "missing"]);
    assert!(!o.status.success() && stderr(&o).contains("no such dataset folder"), "{}", stderr(&o));
}

#[test]
fn the_memory_check_knows_the_scene_before_decoding_it() {
    // What the check sees before loading is what loading makes: the built-in scene and a folder.
    let dir = tempfile::tempdir().unwrap();
    golden(dir.path(), "sphere", "scene");
    let mut config = TrainConfig::default();
    config.data.builtin.width = 40;
    config.data.builtin.views = 5;
    for data in [None, Some(dir.path().join("scene"))] {
        let before = SceneData::size_before_loading(&config, data.as_deref()).unwrap();
        let loaded = SceneData::load(&config, data.as_deref()).unwrap();
        assert_eq!(before, trainer::data::SceneSize::of(&loaded.scene), "{data:?}");
    }
    // A built-in scene too large to render is refused before it is rendered (40 000 × 30 000 ×
    // 49 views would take 176 GB of pixels alone), with the part that is too large named.
    let o = xtask_in(dir.path(), &["train", "--out", "huge", "data.builtin.width=40000"]);
    let err = stderr(&o);
    assert!(!o.status.success() && err.contains("data.downscale") && err.contains("needs about"), "{err}");
    assert!(!dir.path().join("huge").exists());
}

#[test]
fn ctrl_c_during_meshing_stops_with_the_checkpoint_kept_and_resume_finishes() {
    use std::io::BufRead;
    let dir = tempfile::tempdir().unwrap();
    let mut args = vec!["train", "--out", "run"];
    args.extend_from_slice(TINY);
    args.push("output.mesh_resolution=512");
    let mut child = Command::new(env!("CARGO_BIN_EXE_xtask"))
        .current_dir(dir.path())
        .args(&args)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("xtask runs");
    let mut lines = std::io::BufReader::new(child.stderr.take().unwrap()).lines();
    let mut seen = String::new();
    for line in lines.by_ref() {
        let line = line.unwrap();
        seen += &line;
        seen.push('\n');
        if line.contains("] mesh ") {
            let kill = Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap();
            assert!(kill.success());
            break;
        }
    }
    seen.extend(lines.map(|l| l.unwrap() + "\n"));
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130), "{seen}");
    assert!(seen.contains("stopping after this part of meshing") && seen.contains("stopped after training"), "{seen}");
    let run = dir.path().join("run");
    assert!(run.join("checkpoint.safetensors").is_file() && !run.join("mesh.ply").exists() && !run.join("metrics.json").exists(), "{seen}");
    let o = xtask_in(dir.path(), &["train", "--resume", "run"]);
    assert!(o.status.success() && run.join("mesh.ply").is_file() && run.join("metrics.json").is_file(), "{}", stderr(&o));
}

#[test]
fn the_psnr_of_a_run_without_held_out_views_says_so() {
    let dir = tempfile::tempdir().unwrap();
    // With nothing held out, the PSNR is said to be on training views.
    let mut args = vec!["train", "--out", "run"];
    args.extend_from_slice(TINY);
    args.push("data.holdout_every=0");
    let o = xtask_in(dir.path(), &args);
    let err = stderr(&o);
    assert!(o.status.success() && err.contains("training (none held out) view(s)") && !err.contains("held-out view"), "{err}");
}
