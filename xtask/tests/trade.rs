//! `cargo xtask trade` end to end (the `xtask` binary): the quality-against-time table.

use std::process::Command;

mod common;

/// `--snapshots` trains one run per seed to the longest budget and reads the shorter budget's
/// row from that run's snapshot: no run folder of the shorter budget, its row labelled as a
/// snapshot with the snapshot's own figures; each row names the machine.
#[test]
fn trade_with_snapshots_trains_each_seed_once_and_reads_the_shorter_budget_from_its_snapshot() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("trade");
    let mut args =
        vec!["trade", "--snapshots", "--budget", "1s", "--budget", "3s", "--seeds", "1", "--variant", "guided", "--out", out.to_str().unwrap()];
    // The tiny run without its step budget: trade gives every run its wall-time budget.
    args.extend(common::TINY.iter().filter(|o| !o.starts_with("steps=")));
    let o = Command::new(env!("CARGO_BIN_EXE_xtask")).args(&args).output().expect("xtask runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let run = out.join("builtin-composite/guided");
    assert!(run.join("b3/s0/metrics.json").is_file());
    assert!(!run.join("b1").exists(), "the shorter budget was trained on its own");
    let snapshot: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(run.join("b3/s0/snapshots/1s/metrics.json")).unwrap()).unwrap();
    assert!(!run.join("b3/s0/snapshots/1s/checkpoint.safetensors").exists(), "a sweep's snapshot keeps no checkpoint unless asked");
    let table = std::fs::read_to_string(out.join("trade.md")).unwrap();
    let row = table.lines().find(|l| l.starts_with("| 1 s (snapshot of 3 s) | guided | 1 |")).unwrap_or_else(|| panic!("no snapshot row:\n{table}"));
    let steps = snapshot["step"].as_u64().unwrap();
    assert!(row.contains(&format!("| {steps} ± 0 |")), "the row's iterations are the snapshot's {steps}: {row}");
    assert!(table.lines().any(|l| l.starts_with("| 3 s | guided | 1 |")), "{table}");
    // Every row names the machine its runs trained on (the CPU and the kernels' instruction set),
    // and measures the mesh over what the views observe too.
    let machine = std::fs::read_to_string(run.join("b3/s0/trade_machine.txt")).unwrap();
    assert!(machine.contains("kernels ") && machine.contains("threads"), "{machine}");
    for row in table.lines().filter(|l| l.starts_with("| 1 s") || l.starts_with("| 3 s")) {
        assert!(row.trim_end().ends_with(&format!("| {machine} |")), "{row}");
    }
    assert!(table.contains("Chamfer over what the views observe"), "{table}");
    // And the normals against the truth's: the snapshot's own figure in its row.
    let nc = snapshot["normal_consistency"].as_f64().expect("a snapshot measures its normals");
    assert!(table.contains("normal consistency over what the views observe ↑") && row.contains(&format!("| {nc:.4} ± 0.0000 |")), "{nc}: {row}");
    // The sweep's default (no snapshot checkpoints) comes before the overrides: asked for, they
    // are kept.
    let kept = dir.path().join("kept");
    let mut args: Vec<&str> = args.iter().map(|a| if *a == out.to_str().unwrap() { kept.to_str().unwrap() } else { a }).collect();
    args.push("output.snapshot_checkpoints=true");
    let o = Command::new(env!("CARGO_BIN_EXE_xtask")).args(&args).output().expect("xtask runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(kept.join("builtin-composite/guided/b3/s0/snapshots/1s/checkpoint.safetensors").is_file(), "the override wins over the sweep's default");
}
