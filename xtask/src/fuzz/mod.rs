//! `cargo xtask fuzz`: every parser of user input fed mutated bytes — PLY, NPY, NPZ, IDR camera
//! archives, transforms JSON, COLMAP models (binary and text), images and masks, OBJ and
//! glTF/GLB meshes, training configurations and `key=value` overrides, checkpoints. A parser must answer any bytes with a
//! value or an error: a panic, an allocation beyond the memory cap, or a case slower than the
//! time-out is a finding, saved with its input under `OUT/findings/`.
//!
//! Cases are generated, not evolved: case `i` takes a seed input of its target (valid files made
//! in memory) and applies 1–8 mutations drawn from its own RNG stream (`stream_seed(seed, i)`),
//! so any case is reproduced from `(seed, i)` alone, whatever the thread count. Mutations:
//! bit flips, interesting bytes and integers (0, −1, 2³¹, 2³², 2⁶³ …) written over 1/2/4/8
//! bytes, truncation, deletion, insertion, duplication, splicing with another seed, and for text
//! numbers replaced by extreme ones (1e308, NaN, −0, 2⁶⁴ …) and structural characters inserted.
//!
//! The command runs the cases in a worker process under an allocation cap (the binary's global
//! allocator is `cap::Cap`): an allocation over the cap aborts the worker, and a stuck case is
//! ended by a watchdog; each worker thread first writes its case to `OUT/inflight/`, so that
//! the supervisor can name the input that killed the worker and confirm it by replaying it
//! (`--replay FILE`).

use anyhow::{Context, Result, bail};
use datasets::colmap::{ModelEncoding, ModelFiles};
use datasets::io::{MeshFormat, PlyData};
use datasets::npy::{npy_bytes, write_npz};
use datasets::{Format, LoadOptions};
use glam::{DMat3, DMat4, DVec3, Vec3};
use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
use std::cell::RefCell;
use std::io::{BufRead, Cursor, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::time::Instant;

/// Options of `cargo xtask fuzz`.
#[derive(clap::Args, Debug, Clone)]
pub struct FuzzArgs {
    /// Cases in all (targets take turns).
    #[arg(long, default_value_t = 1_000_000)]
    pub cases: u64,
    /// Stop after this long (e.g. 10m) even if cases remain.
    #[arg(long, value_parser = trainer::config::parse_duration)]
    pub time: Option<std::time::Duration>,
    /// Targets (repeat); default all. `--list` names them.
    #[arg(long)]
    pub target: Vec<String>,
    /// List the targets and exit.
    #[arg(long)]
    pub list: bool,
    /// Seed of the case streams.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// First case index (to continue a stream).
    #[arg(long, default_value_t = 0)]
    pub first_case: u64,
    /// Output folder: findings, in-flight cases.
    #[arg(long, default_value = "out/fuzz")]
    pub out: PathBuf,
    /// Allocation cap of the worker (live heap bytes), e.g. 2G, 512M.
    #[arg(long, default_value = "2G")]
    pub max_memory: String,
    /// A case running longer than this is a finding (seconds).
    #[arg(long, default_value_t = 10.0)]
    pub case_timeout: f64,
    /// Replay saved inputs (with --target) instead of fuzzing; exit 0 when each is accepted or
    /// rejected cleanly.
    #[arg(long)]
    pub replay: Vec<PathBuf>,
    /// Internal: run the cases in this process (the supervisor starts workers with it).
    #[arg(long, hide = true)]
    pub worker: bool,
}

/// What a target returns: `Ok` when the bytes were accepted, `Err(message)` when rejected
/// cleanly.
pub type Verdict = std::result::Result<(), String>;

/// A parser under test.
pub struct Target {
    /// Name on the command line.
    pub name: &'static str,
    /// What it drives.
    pub about: &'static str,
    /// Valid inputs the mutations start from.
    pub seeds: fn() -> Vec<Vec<u8>>,
    /// Runs the parser on bytes.
    pub run: fn(&[u8]) -> Verdict,
}

/// Separates the files of a multi-file input (COLMAP's three files, an IDR archive's arrays).
const FILE_MARK: &[u8] = b"\n\0--file--\0\n";

fn split_files(bytes: &[u8]) -> Vec<&[u8]> {
    let mut out = Vec::new();
    let mut rest = bytes;
    while let Some(at) = rest.windows(FILE_MARK.len()).position(|w| w == FILE_MARK) {
        out.push(&rest[..at]);
        rest = &rest[at + FILE_MARK.len()..];
    }
    out.push(rest);
    out
}

fn join_files(files: &[Vec<u8>]) -> Vec<u8> {
    files.join(FILE_MARK)
}

fn verdict<T, E: std::fmt::Display>(r: std::result::Result<T, E>) -> Verdict {
    r.map(|_| ()).map_err(|e| e.to_string())
}

mod cases;
mod mutate;
mod targets;
pub use cases::*;
pub use mutate::*;
pub use targets::*;

/// The command.
pub fn run(args: &FuzzArgs, hooks: &ProcessHooks) -> Result<bool> {
    if args.list {
        for t in targets() {
            println!("{:12} {}", t.name, t.about);
        }
        return Ok(true);
    }
    let targets = select(&args.target)?;
    if !(args.case_timeout.is_finite() && args.case_timeout > 0.0) {
        bail!("--case-timeout {}: expected seconds > 0", args.case_timeout);
    }
    if args.first_case.checked_add(args.cases).is_none() {
        bail!("--first-case {} + --cases {} overflows", args.first_case, args.cases);
    }
    if !args.replay.is_empty() {
        if targets.iter().any(|t| t.name == "checkpoint") {
            prepare_checkpoint_runs(1)?;
        }
        if !(hooks.memory_cap)(trainer::memory::parse_size(&args.max_memory)? as usize) {
            bail!("--max-memory {}: below the heap already in use", args.max_memory);
        }
        return replay(args, &targets, hooks);
    }
    if args.worker {
        return worker(args, &targets, hooks);
    }
    supervise(args, &targets)
}

/// A thread that ends the process (exit 3) when a case has run longer than `timeout` seconds,
/// first writing the thread's slot to `inflight/hung`.
fn start_watchdog(timeout: f64, inflight: Option<PathBuf>, end_process: fn(i32) -> !) {
    let timeout_ms = (timeout * 1000.0) as u64;
    std::thread::spawn(move || {
        loop {
            std::thread::sleep(std::time::Duration::from_millis(200));
            let now = clock_ms();
            let hung = RUNNING.iter().position(|r| {
                let started = r.load(Ordering::Relaxed);
                started != 0 && now.saturating_sub(started) > timeout_ms
            });
            if let Some(slot) = hung {
                eprintln!("fuzz: a case has run for more than {timeout} s");
                if let Some(dir) = &inflight {
                    let _ = std::fs::write(dir.join("hung"), slot.to_string());
                }
                end_process(3);
            }
        }
    });
}

fn replay(args: &FuzzArgs, targets: &[Target], hooks: &ProcessHooks) -> Result<bool> {
    if targets.len() != 1 {
        bail!("--replay needs one --target");
    }
    install_panic_hook();
    start_watchdog(args.case_timeout, None, hooks.end_process);
    let mut clean = true;
    for path in &args.replay {
        let input = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
        QUIET_PANICS.fetch_add(1, Ordering::SeqCst);
        RUNNING[0].store(clock_ms().max(1), Ordering::Relaxed);
        let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| (targets[0].run)(&input)));
        RUNNING[0].store(0, Ordering::Relaxed);
        QUIET_PANICS.fetch_sub(1, Ordering::SeqCst);
        match outcome {
            Ok(Ok(())) => println!("{}: accepted", path.display()),
            Ok(Err(e)) => println!("{}: rejected: {e}", path.display()),
            Err(_) => {
                clean = false;
                println!("{}: PANIC: {}", path.display(), PANIC.with(|p| p.borrow_mut().take()).unwrap_or_default());
            }
        }
    }
    Ok(clean)
}

/// Runs the cases in this process; prints `progress N` lines and a final JSON report.
fn worker(args: &FuzzArgs, targets: &[Target], hooks: &ProcessHooks) -> Result<bool> {
    let inflight = args.out.join("inflight");
    std::fs::create_dir_all(&inflight).with_context(|| format!("creating {}", inflight.display()))?;
    let deadline = args.time.map(|d| Instant::now() + d);
    // Seeds and the checkpoint target's runs are built before the cap (they train a tiny run).
    let seeds = seeds_of(targets);
    let threads = rayon::current_num_threads();
    if targets.iter().any(|t| t.name == "checkpoint") {
        prepare_checkpoint_runs(threads)?;
    }
    let cap = trainer::memory::parse_size(&args.max_memory)? as usize;
    if !(hooks.memory_cap)(cap) {
        bail!("--max-memory {}: below the heap already in use after building the seeds", args.max_memory);
    }
    start_watchdog(args.case_timeout, Some(inflight.clone()), hooks.end_process);
    let out = std::io::stdout();
    let range = CaseRange { seed: args.seed, first: args.first_case, cases: args.cases, threads };
    let report = run_cases(targets, &seeds, &range, deadline, Some(&inflight), &|n| {
        let mut o = out.lock();
        let _ = writeln!(o, "progress {n}");
        let _ = o.flush();
    });
    let _ = std::fs::remove_dir_all(&inflight);
    let mut saved = Vec::new();
    for f in &report.findings {
        saved.push(save_finding(&args.out, &f.target, "panic", &f.message, &f.input)?.display().to_string());
    }
    let json = serde_json::json!({
        "seconds": report.seconds,
        "tallies": report.tallies.iter().map(|(n, t)| serde_json::json!({"target": n, "cases": t.cases, "accepted": t.accepted, "seconds": t.seconds, "slowest_s": t.slowest})).collect::<Vec<_>>(),
        "findings": report.findings.iter().zip(&saved).map(|(f, p)| serde_json::json!({"target": f.target, "case": f.case, "message": f.message, "saved": p})).collect::<Vec<_>>(),
    });
    println!("report {json}");
    Ok(report.findings.is_empty())
}

/// Starts a worker, follows its progress, and names the input of a worker that died.
fn supervise(args: &FuzzArgs, targets: &[Target]) -> Result<bool> {
    let exe = std::env::current_exe().context("locating the xtask binary")?;
    let inflight = args.out.join("inflight");
    let _ = std::fs::remove_dir_all(&inflight);
    let mut command = std::process::Command::new(&exe);
    command.arg("fuzz").arg("--worker").args(["--cases", &args.cases.to_string(), "--seed", &args.seed.to_string()]);
    command.args(["--first-case", &args.first_case.to_string(), "--max-memory", &args.max_memory, "--case-timeout", &args.case_timeout.to_string()]);
    command.arg("--out").arg(&args.out);
    if let Some(t) = args.time {
        // The worker is another process: its command line is text.
        command.args(["--time", &format!("{}s", t.as_secs_f64())]);
    }
    for t in targets {
        command.args(["--target", t.name]);
    }
    eprintln!(
        "fuzz: {} cases over {} targets ({}), seed {}, allocation cap {}, case time-out {} s",
        args.cases,
        targets.len(),
        targets.iter().map(|t| t.name).collect::<Vec<_>>().join(", "),
        args.seed,
        args.max_memory,
        args.case_timeout
    );
    let mut child = command.stdout(std::process::Stdio::piped()).spawn().context("starting the fuzz worker")?;
    let bar = indicatif::ProgressBar::new(args.cases);
    bar.set_style(indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} cases, {per_sec}, {eta} left").expect("a valid template"));
    let mut report = None;
    for line in std::io::BufReader::new(child.stdout.take().expect("piped")).lines() {
        let line = line?;
        if let Some(n) = line.strip_prefix("progress ") {
            bar.set_position(n.parse().unwrap_or(0));
        } else if let Some(json) = line.strip_prefix("report ") {
            report = Some(serde_json::from_str::<serde_json::Value>(json)?);
        }
    }
    let status = child.wait()?;
    bar.finish_and_clear();
    if let Some(r) = &report {
        let seconds = r["seconds"].as_f64().unwrap_or(0.0);
        let total: u64 = r["tallies"].as_array().map_or(0, |a| a.iter().filter_map(|t| t["cases"].as_u64()).sum());
        println!("{total} cases in {seconds:.1} s ({:.0} cases/s)", total as f64 / seconds.max(1e-9));
        println!("| target | cases | accepted | rejected cleanly | µs / case | slowest case (ms) |\n|---|---|---|---|---|---|");
        for t in r["tallies"].as_array().into_iter().flatten() {
            let (c, a) = (t["cases"].as_u64().unwrap_or(0), t["accepted"].as_u64().unwrap_or(0));
            let per = t["seconds"].as_f64().unwrap_or(0.0) / c.max(1) as f64 * 1e6;
            let slowest = t["slowest_s"].as_f64().unwrap_or(0.0) * 1e3;
            println!("| {} | {c} | {a} | {} | {per:.1} | {slowest:.1} |", t["target"].as_str().unwrap_or("?"), c - a);
        }
        for f in r["findings"].as_array().into_iter().flatten() {
            println!("FINDING {} case {}: {} (input: {})", f["target"], f["case"], f["message"], f["saved"]);
        }
    }
    if let Some(r) = &report {
        return Ok(status.success() && r["findings"].as_array().is_some_and(|f| f.is_empty()));
    }
    // The worker died (allocation over the cap, a hang, an abort): the in-flight cases (only
    // the stuck thread's after a hang).
    let hung = std::fs::read_to_string(inflight.join("hung")).ok();
    let mut named = false;
    for e in std::fs::read_dir(&inflight).into_iter().flatten().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(slot) = name.strip_prefix("thread-").and_then(|n| n.strip_suffix(".case")) else { continue };
        if hung.as_deref().is_some_and(|h| h.trim() != slot) {
            continue;
        }
        let bytes = std::fs::read(e.path())?;
        if bytes.len() < 16 {
            continue;
        }
        let t = u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes")) as usize;
        let case = u64::from_le_bytes(bytes[8..16].try_into().expect("8 bytes"));
        let Some(target) = targets.get(t) else { continue };
        let kind = if hung.is_some() { "hang" } else { "died" };
        let path = save_finding(&args.out, target.name, kind, &format!("case {case}: worker exit {status}"), &bytes[16..])?;
        // Confirm in a fresh process: does this input alone kill it?
        let replay = std::process::Command::new(&exe)
            .args(["fuzz", "--target", target.name, "--max-memory", &args.max_memory, "--case-timeout", &args.case_timeout.to_string(), "--replay"])
            .arg(&path)
            .output()?;
        let verdict = if replay.status.success() { "does not reproduce alone" } else { "reproduces" };
        println!("FINDING {} case {case}: worker {kind} ({status}); in-flight input {} — replayed: {verdict}", target.name, path.display());
        named = true;
    }
    if !named {
        println!("the worker died ({status}) with no case in flight");
    }
    Ok(false)
}
