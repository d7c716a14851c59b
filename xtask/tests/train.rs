//! The runner end to end (the `xtask` binary): resume exactness and bad input.

use std::path::Path;
use std::process::{Command, Output};

mod common;

/// The shared tiny guided run (6 iterations on a 40 × 30 built-in scene), checkpointed only at
/// the end, logging every step, writing every mesh format with vertex colours.
const TINY_HERE: &[&str] =
    &["output.checkpoint_every=0", "output.log_every=1", "output.mesh_formats=[\"ply\", \"obj\", \"glb\"]", "output.vertex_colors=true"];

fn xtask(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_xtask")).args(args).output().expect("xtask runs")
}

fn train(out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["train", "--out", out.to_str().unwrap()];
    args.extend_from_slice(extra);
    args.extend_from_slice(common::TINY);
    args.extend_from_slice(TINY_HERE);
    xtask(&args)
}

/// `output.mesh_resolution = "model"` meshes at the finest level of the run's grid (here sized
/// by the footprint of 40 × 30 views) and the metrics say so, with the floor: the truth's own
/// mesh at that resolution, which the trained mesh does not beat.
#[test]
fn a_mesh_as_fine_as_the_model_is_measured_against_the_truths_own_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    // After the tiny run's own mesh resolution, which it replaces.
    let mut args = vec!["train", "--out", out.to_str().unwrap()];
    args.extend_from_slice(common::TINY);
    args.extend_from_slice(&["model.grid=footprint", "output.mesh_resolution=model"]);
    let o = xtask(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stderr = String::from_utf8_lossy(&o.stderr);
    let finest: u32 = stderr
        .split("→ finest ")
        .nth(1)
        .and_then(|t| t.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .expect("the grid's choice is printed");
    let m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(m["mesh_resolution"].as_u64(), Some(u64::from(finest.max(64))), "{m}");
    let (floor, chamfer) = (m["mesh_floor"].as_f64().expect("a built-in scene has a floor"), m["chamfer"].as_f64().unwrap());
    assert!(floor > 0.0 && floor < chamfer, "floor {floor}, Chamfer {chamfer}");
    assert!(stderr.contains("the truth's own"), "{stderr}");
    // The composite's three parts are measured one by one (the thin ring among them).
    let parts = m["parts"].as_array().expect("per-part figures");
    assert_eq!(parts.len(), 3, "{m}");
    assert!(parts.iter().any(|p| p["part"] == "torus 0.58 × 0.04"), "{m}");
    assert!(parts.iter().all(|p| p["recall"].as_f64().is_some_and(|r| (0.0..=1.0).contains(&r))), "{m}");
    // Over what the training views observe: the foot's underside and what the body hides from
    // the rig above it are left out (measured with its floor), and `eval` measures the same.
    let observed = &m["observed"];
    let share = observed["truth_observed"].as_f64().expect("an analytic truth is measured over what the views observe");
    assert!((0.5..0.99).contains(&share), "{m}");
    assert!(observed["mesh_floor"].as_f64().is_some_and(|f| f > 0.0) && observed["chamfer"].as_f64().is_some(), "{m}");
    assert!(stderr.contains("over what the training views observe"), "{stderr}");
    let mesh = out.join("mesh.ply");
    let protocol = ["--spacing", "0.004", "--max-dist", "0.1", "--tau", "0.01"];
    let mut eval = vec!["eval", "--mesh", mesh.to_str().unwrap(), "--gt-shape", "composite", "--observed-by", out.to_str().unwrap(), "--json"];
    eval.extend_from_slice(&protocol);
    let e = xtask(&eval);
    assert!(e.status.success(), "{}", String::from_utf8_lossy(&e.stderr));
    let again: serde_json::Value = serde_json::from_slice(&e.stdout).unwrap();
    let (run, measured) = (observed["chamfer"].as_f64().unwrap(), again["observed"]["chamfer"].as_f64().unwrap());
    assert!((measured / run - 1.0).abs() < 0.1, "the run's observed Chamfer {run}, eval's {measured} (truth points drawn apart)");
    assert!((again["observed"]["truth_observed"].as_f64().unwrap() - share).abs() < 0.02, "{again}");
    // The normals against the analytic truth's, whole and over what the views observe, alike
    // in the run and in `eval` (a tiny run's mesh: far from 1, but its normals are not random).
    let nc = |v: &serde_json::Value| v["normal_consistency"].as_f64().unwrap_or_else(|| panic!("no normal consistency in {v}"));
    for (run, eval) in [(&m, &again), (observed, &again["observed"])] {
        assert!((0.6..1.0).contains(&nc(run)), "{run}");
        assert!((nc(eval) - nc(run)).abs() < 0.03, "the run's {}, eval's {}", nc(run), nc(eval));
    }
    // The run's pixel footprint too, so that the distances read in the photos' pixels.
    assert!(m["pixel_footprint"].as_f64().is_some_and(|f| f > 0.0), "{m}");
    assert_eq!(again["pixel_footprint"], m["pixel_footprint"], "{again}");
    eval.retain(|a| *a != "--json");
    let printed = xtask(&eval);
    assert!(String::from_utf8_lossy(&printed.stdout).contains(" px (accuracy"), "{}", String::from_utf8_lossy(&printed.stdout));
}

#[test]
fn resumed_run_ends_with_the_same_mesh_as_an_uninterrupted_run() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    let full = train(&a, &[]);
    assert!(full.status.success(), "{}", String::from_utf8_lossy(&full.stderr));
    // Interrupted after 3 iterations (between two grid updates), then resumed.
    let part = train(&b, &["--stop-at", "3"]);
    assert_eq!(part.status.code(), Some(130), "{}", String::from_utf8_lossy(&part.stderr));
    assert!(!b.join("mesh.ply").exists());
    let resumed = xtask(&["train", "--resume", b.to_str().unwrap()]);
    assert!(resumed.status.success(), "{}", String::from_utf8_lossy(&resumed.stderr));
    let (ma, mb) = (std::fs::read(a.join("mesh.ply")).unwrap(), std::fs::read(b.join("mesh.ply")).unwrap());
    // All three formats, with vertex colours in the PLY.
    assert!(String::from_utf8_lossy(&ma[..300.min(ma.len())]).contains("property uchar red"));
    assert!(std::fs::read_to_string(a.join("mesh.obj")).unwrap().lines().any(|l| l.starts_with("f ")));
    assert_eq!(&std::fs::read(a.join("mesh.glb")).unwrap()[..4], b"glTF");
    assert!(ma.len() > 200, "the mesh is empty");
    assert!(ma == mb, "resumed mesh differs from the uninterrupted one");
    // Evaluation: the mesh against itself (Chamfer ≈ 0, F-score 1), and the run's held-out views.
    let mesh = a.join("mesh.ply");
    let e = xtask(&["eval", "--mesh", mesh.to_str().unwrap(), "--gt-mesh", mesh.to_str().unwrap(), "--json"]);
    assert!(e.status.success(), "{}", String::from_utf8_lossy(&e.stderr));
    let m: serde_json::Value = serde_json::from_slice(&e.stdout).unwrap();
    assert!(m["chamfer"].as_f64().unwrap() < 0.01 * m["max_dist"].as_f64().unwrap() && m["f_score"].as_f64().unwrap() > 0.99, "{m}");
    let r = xtask(&["eval", "--run", a.to_str().unwrap(), "--downscale", "4", "--json"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(a.join("eval.json").exists());
    // The logged losses of the last iterations are identical too.
    let last = |p: &Path| -> serde_json::Value {
        serde_json::from_str(std::fs::read_to_string(p.join("log.jsonl")).unwrap().lines().last().unwrap()).unwrap()
    };
    let (la, lb) = (last(&a), last(&b));
    for key in ["step", "loss", "psnr_batch", "s", "lr", "levels"] {
        assert_eq!(la[key], lb[key], "{key}");
    }
}

/// State beyond the parameters goes into the checkpoint and comes back: Adam's bf16 table moments
/// (their stochastic rounding depends on the step, not on the process) and the loss-guided
/// samplers' error map (soft mining's pixels and weights follow it); a grid sized by the views'
/// footprint is sized again alike from the same cameras. A resumed run equals an uninterrupted one.
#[test]
fn resumed_run_with_bf16_moments_an_error_map_or_a_sized_grid_equals_the_uninterrupted_run() {
    for setting in ["optim.table_moments=bf16", "sampler=soft-mining", "model.grid=footprint"] {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a"), dir.path().join("b"));
        let full = train(&a, &[setting]);
        assert!(full.status.success(), "{setting}: {}", String::from_utf8_lossy(&full.stderr));
        let sized = String::from_utf8_lossy(&full.stderr).contains("model: hash grid sized by the footprint");
        assert_eq!(sized, setting == "model.grid=footprint", "{setting}: the grid's choice is printed exactly when it is made");
        let part = train(&b, &["--stop-at", "3", setting]);
        assert_eq!(part.status.code(), Some(130), "{setting}: {}", String::from_utf8_lossy(&part.stderr));
        let resumed = xtask(&["train", "--resume", b.to_str().unwrap()]);
        assert!(resumed.status.success(), "{setting}: {}", String::from_utf8_lossy(&resumed.stderr));
        let (ma, mb) = (std::fs::read(a.join("mesh.ply")).unwrap(), std::fs::read(b.join("mesh.ply")).unwrap());
        assert!(ma.len() > 200 && ma == mb, "{setting}: resumed mesh differs from the uninterrupted one");
    }
}

#[test]
fn bad_input_gives_a_clear_message_and_loses_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    std::fs::create_dir_all(&run).unwrap();
    std::fs::write(run.join("metrics.json"), "precious").unwrap();
    let out = run.to_str().unwrap();
    // Missing data with an --out that could take the run (a folder that cannot is refused first).
    let fresh = dir.path().join("fresh");
    let fresh_out = fresh.to_str().unwrap();
    for (args, expect) in [
        (vec!["train", "--out", out, "guide.scene.partitoin=2"], "partitoin"),
        (vec!["train", "--out", out, "guide.scene.partition=0"], "partition factor F"),
        (vec!["train", "--out", out, "guide.fixed_s=-1"], "guide.fixed_s"),
        (vec!["train", "--out", out, "sampler=soft-mining", "mining.alpha=2"], "mining.alpha"),
        (vec!["train", "--out", out, "model.grid=footprint", "model.preset=neus-cpu"], "model.grid = \"footprint\""),
        (vec!["train", "--out", out, "model.grid=footprint", "model.pixels_per_cell=0"], "model.pixels_per_cell"),
        (vec!["train", "--out", out, "sampler=hard-mining"], "expected one of `guided`, `uniform`, `error-map`, `soft-mining`"),
        (vec!["train", "--out", fresh_out, "--data", "/nonexistent/scan"], "/nonexistent/scan"),
    ] {
        let o = xtask(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} succeeded");
        assert!(err.contains(expect), "{args:?}: message does not name {expect:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
    }
    assert_eq!(std::fs::read_to_string(run.join("metrics.json")).unwrap(), "precious");
    assert!(!fresh.exists(), "a run that failed on its input left a folder");
    // An output folder that cannot be created (a path under a file).
    let blocked = dir.path().join("file");
    std::fs::write(&blocked, "x").unwrap();
    let o = xtask(&["train", "--out", blocked.join("run").to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("run folder"), "{err}");
    assert_eq!(std::fs::read_to_string(&blocked).unwrap(), "x");
}

/// Render fit: the built-in scene (textured backdrop, masks), 12 views of 64 × 48, 400
/// iterations of 256 rays × 64 samples, masked training: the PSNR inside the masks of the
/// training views reaches ≥ 23 dB (the whole-image PSNR is not a fit figure for masked training:
/// the backdrop never enters the colour loss). Over seeds 0–4 in the release build it spans
/// 23.17–25.01 dB (`62922ac`) and 23.28–24.93 dB (§46, whose normals differ by their rounding):
/// the bound sits under that spread, far above a fit that fails (under 20 dB).
#[test]
fn render_fit_reaches_24_db_inside_the_masks_of_the_training_views() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("fit");
    let o = xtask(&[
        "train",
        "--out",
        out.to_str().unwrap(),
        "--json",
        "steps=400",
        "render.rays=256",
        "data.builtin.width=64",
        "data.builtin.views=12",
        "data.holdout_every=0",
        "output.validate_every=0",
        "output.checkpoint_every=0",
        "output.mesh_resolution=32",
        "output.eval_downscale=1",
        "output.eval_views=2",
        "output.eval_train_views=4",
        "output.log_every=50",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value = serde_json::from_slice(o.stdout.split(|&b| b == b'\n').find(|l| l.starts_with(b"{")).unwrap()).unwrap();
    let psnr = summary["metrics"]["psnr_train_masked"].as_f64().unwrap();
    eprintln!("training-view PSNR inside the masks after 400 iterations: {psnr:.2} dB");
    assert!(psnr >= 23.0, "training-view masked PSNR {psnr:.2} dB < 23 dB");
}

/// Validation pictures due every iteration are capped at their share of the training time
/// (`output.validate_share`): on a large scene they would otherwise cost more than training
/// (DTU scan 24: 244 s of pictures in a 120 s budget at the default period).
#[test]
fn validation_pictures_take_at_most_their_share_of_the_training_time() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("pictures");
    let mut args = vec!["train", "--out", out.to_str().unwrap()];
    args.extend_from_slice(common::TINY);
    args.extend_from_slice(TINY_HERE);
    // A picture at full resolution after every iteration: uncapped, the pictures would take
    // most of the run.
    args.extend_from_slice(&["steps=40", "output.validate_every=1", "output.validate_downscale=1", "output.validate_share=0.1"]);
    let o = xtask(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    let (pictures_s, train_s) = (m["validation_s"].as_f64().unwrap(), m["train_s"].as_f64().unwrap());
    // The periodic pictures (the final one, val_000040, is not periodic and always made).
    let taken = std::fs::read_dir(out.join("pictures"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|name| name.starts_with("val_0") && name != "val_000040.png")
        .count();
    assert!(taken >= 1, "the first due picture is taken");
    assert!(taken < 39, "{taken} pictures in 40 iterations: the cap did nothing");
    // At most the last picture's overrun beyond the share (each is taken only while the ones
    // before it fit the share); pictures vary in time, so allow twice the mean for it.
    let one = pictures_s / taken as f64;
    assert!(pictures_s <= 0.1 * train_s + 2.0 * one, "pictures took {pictures_s:.3} s of {train_s:.3} s training ({taken} pictures)");
}

#[test]
fn snapshots_write_a_mesh_and_metrics_at_their_times_outside_the_budget() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let o = train(&out, &["output.snapshots=[0.001, 1e9]"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let snapshot = out.join("snapshots/0.001s");
    for f in ["mesh.ply", "mesh.obj", "mesh.glb", "metrics.json"] {
        assert!(snapshot.join(f).exists(), "no {f} in the snapshot");
    }
    assert!(!out.join("snapshots/1000000000s").exists(), "a snapshot the run never reached");
    let m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(snapshot.join("metrics.json")).unwrap()).unwrap();
    assert!(m["chamfer"].as_f64().is_some_and(f64::is_finite) && m["psnr"].as_f64().is_some(), "{m}");
    assert!(m["step"].as_u64().is_some_and(|s| (1..6).contains(&s)), "{m}");
    let log = std::fs::read_to_string(out.join("log.jsonl")).unwrap();
    assert_eq!(log.lines().filter(|l| l.contains("\"snapshot\"")).count(), 1);
    // The run still trained its 6 steps and wrote its own mesh.
    let metrics: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(metrics["steps"], 6);
}
