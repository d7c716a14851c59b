//! A run stopped by SIGTERM (what batch schedulers, `timeout`, `docker stop` and systemd send)
//! ends as Ctrl-C does: a checkpoint of its last iteration, a message, exit 128 + 15; and a run
//! folder in use by one process is refused to every other (train, `--overwrite`, `--resume`,
//! `eval --run`), while the lock of a process that has ended is taken over.
#![cfg(unix)]

use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

mod common;
use common::TINY;

fn xtask(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_xtask")).args(args).output().expect("xtask runs")
}

/// The tiny run's overrides with `steps` replaced.
fn tiny_with_steps(steps: &str) -> Vec<String> {
    TINY.iter()
        .map(|s| if s.starts_with("steps=") { steps.to_string() } else { s.to_string() })
        .chain(["output.checkpoint_every=1000000".into()])
        .collect()
}

/// A training process that would run for hours, into `out`, started and seen training (its log
/// has a line).
fn long_run(out: &Path) -> Child {
    let mut args = vec!["train".to_string(), "--out".into(), out.display().to_string()];
    args.extend(tiny_with_steps("steps=100000000"));
    let child = Command::new(env!("CARGO_BIN_EXE_xtask")).args(&args).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("xtask starts");
    let started = Instant::now();
    while !std::fs::read_to_string(out.join("log.jsonl")).is_ok_and(|l| l.lines().count() >= 2) {
        assert!(started.elapsed() < Duration::from_secs(120), "the run did not start training within 2 minutes");
        std::thread::sleep(Duration::from_millis(50));
    }
    child
}

fn terminate(child: &Child) {
    let status = Command::new("kill").args(["-TERM", &child.id().to_string()]).status().expect("kill runs");
    assert!(status.success());
}

/// The step a stopped run's message names.
fn stopped_step(stderr: &str) -> u64 {
    let at = stderr.find("stopped at step ").unwrap_or_else(|| panic!("no stop message in:\n{stderr}"));
    stderr[at + "stopped at step ".len()..].split(|c: char| !c.is_ascii_digit()).next().unwrap().parse().unwrap()
}

#[test]
fn sigterm_during_training_writes_a_checkpoint_of_the_last_iteration_and_exits_143() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let child = long_run(&out);
    terminate(&child);
    let output = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(143), "{stderr}");
    assert!(stderr.contains("SIGTERM: stopping after this iteration"), "{stderr}");
    let step = stopped_step(&stderr);
    assert!(step >= 1);
    // The only checkpoint is the stop's (periodic ones are off): it holds that very iteration.
    let trainer = trainer::run::open_run(&out, None).unwrap();
    assert_eq!(trainer.state().step, step);
}

#[test]
fn a_run_folder_in_use_is_refused_to_other_processes_and_the_lock_of_an_ended_one_is_taken_over() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let out_arg = out.display().to_string();
    let first = long_run(&out);
    let config = std::fs::read(out.join("config.toml")).unwrap();
    let data = std::fs::read(out.join("data.json")).unwrap();

    let mut overwrite = vec!["train", "--out", &out_arg, "--overwrite"];
    overwrite.extend(TINY);
    let eval = ["eval", "--run", &out_arg];
    // A fresh run is refused before it loads its data (here: none there to load).
    let missing = dir.path().join("no-such-scene").display().to_string();
    let early = ["train", "--out", &out_arg, "--overwrite", "--data", &missing];
    for args in [&overwrite[..], &["train", "--resume", &out_arg], &eval, &early] {
        let refused = xtask(args);
        let stderr = String::from_utf8_lossy(&refused.stderr);
        assert!(!refused.status.success(), "{args:?} went ahead in a folder in use");
        assert!(stderr.contains("is in use by another run") && stderr.contains(&format!("process {}", first.id())), "{args:?}: {stderr}");
    }
    // The first run's folder is as it was, and it is still training.
    assert_eq!(std::fs::read(out.join("config.toml")).unwrap(), config);
    assert_eq!(std::fs::read(out.join("data.json")).unwrap(), data);
    assert!(!out.join("eval.json").exists());
    let lines = std::fs::read_to_string(out.join("log.jsonl")).unwrap().lines().count();
    let started = Instant::now();
    while std::fs::read_to_string(out.join("log.jsonl")).unwrap().lines().count() == lines {
        assert!(started.elapsed() < Duration::from_secs(60), "the first run stopped training");
        std::thread::sleep(Duration::from_millis(20));
    }
    terminate(&first);
    let ended = first.wait_with_output().unwrap();
    assert_eq!(ended.status.code(), Some(143), "{}", String::from_utf8_lossy(&ended.stderr));

    // Its process has ended, so its lock is free: the next run takes the folder over.
    let replaced = xtask(&overwrite);
    assert!(replaced.status.success(), "{}", String::from_utf8_lossy(&replaced.stderr));
    assert!(out.join("mesh.ply").is_file());
}
