//! Running cases: findings, tallies, the panic hook, in-flight records, case ranges.

use super::*;

/// A case that panicked (in-process findings; aborts and hangs are found by the supervisor).
#[derive(Debug, Clone)]
pub struct Finding {
    /// Target name.
    pub target: String,
    /// Case index.
    pub case: u64,
    /// The panic message and location.
    pub message: String,
    /// The input.
    pub input: Vec<u8>,
}

/// Counts per target.
#[derive(Debug, Clone, Default)]
pub struct Tally {
    /// Cases run.
    pub cases: u64,
    /// Cases the parser accepted (the rest were rejected with an error).
    pub accepted: u64,
    /// Time spent in the parser, seconds (all threads).
    pub seconds: f64,
    /// The slowest case, seconds.
    pub slowest: f64,
}

/// What a fuzzing run found.
#[derive(Debug, Default)]
pub struct Report {
    /// Per target, in the order given.
    pub tallies: Vec<(String, Tally)>,
    /// Panics, first per (target, location).
    pub findings: Vec<Finding>,
    /// Wall time of the cases.
    pub seconds: f64,
    /// Order-free digest of every case's input and verdict (the same for any thread count).
    pub digest: u64,
}

thread_local! {
    pub(super) static PANIC: RefCell<Option<String>> = const { RefCell::new(None) };
}

/// How many fuzz runs are under way in this process (panics are recorded, not printed, while > 0).
pub(super) static QUIET_PANICS: AtomicUsize = AtomicUsize::new(0);

/// Per worker thread: when its running case started ([`clock_ms`], ≥ 1), 0 when idle.
pub(super) static RUNNING: [AtomicU64; 64] = [const { AtomicU64::new(0) }; 64];

/// Milliseconds on a monotonic clock (from the first call).
pub(super) fn clock_ms() -> u64 {
    static ORIGIN: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();
    ORIGIN.get_or_init(Instant::now).elapsed().as_millis() as u64
}

/// Installs (once) a panic hook that records panics of fuzz cases instead of printing them.
pub(super) fn install_panic_hook() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let default = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if QUIET_PANICS.load(Ordering::SeqCst) > 0 {
                let location = info.location().map_or("?".into(), |l| format!("{}:{}", l.file(), l.line()));
                let payload = info.payload();
                let message =
                    payload.downcast_ref::<&str>().map(|s| s.to_string()).or_else(|| payload.downcast_ref::<String>().cloned()).unwrap_or_default();
                PANIC.with(|p| *p.borrow_mut() = Some(format!("{message} at {location}")));
            } else {
                default(info);
            }
        }));
    });
}

/// Writes a worker's case to its in-flight file before running it (target index, case index,
/// bytes); the file is emptied when the case returns, so a non-empty file after the worker died
/// is the case it died on.
pub(super) fn write_inflight(file: &mut std::fs::File, target: usize, case: u64, input: &[u8]) {
    use std::os::unix::fs::FileExt;
    let mut head = [0u8; 16];
    head[..8].copy_from_slice(&(target as u64).to_le_bytes());
    head[8..].copy_from_slice(&case.to_le_bytes());
    let _ = file.write_all_at(input, 16);
    let _ = file.write_all_at(&head, 0);
    let _ = file.set_len(16 + input.len() as u64);
}

/// A run of cases: where, how many, on how many threads.
#[derive(Debug, Clone)]
pub struct CaseRange {
    /// Seed of the case streams.
    pub seed: u64,
    /// First case index.
    pub first: u64,
    /// Number of cases.
    pub cases: u64,
    /// Worker threads (each takes chunks of 256 cases in turn).
    pub threads: usize,
}

/// Cases `first .. first + cases` over `targets` (case `i` → target `i mod n`, its input from
/// `seeds` of that target) on `range.threads` worker threads of our own — not rayon's pool, so
/// that a parser's own parallel work can never run another case on the same thread — until
/// `deadline`. `inflight`: folder where each worker writes its case before running it and
/// clears it after (supervised workers); `progress(done)` is called about every 4096 cases.
pub fn run_cases(
    targets: &[Target],
    seeds: &[Vec<Vec<u8>>],
    range: &CaseRange,
    deadline: Option<Instant>,
    inflight: Option<&Path>,
    progress: &(dyn Fn(u64) + Sync),
) -> Report {
    install_panic_hook();
    // Per target: cases, accepted, nanoseconds, slowest case (ns).
    let tallies: Vec<[AtomicU64; 4]> = targets.iter().map(|_| std::array::from_fn(|_| AtomicU64::new(0))).collect();
    let findings: Mutex<Vec<Finding>> = Mutex::new(Vec::new());
    let digest = AtomicU64::new(0);
    let next_chunk = AtomicU64::new(0);
    let done = AtomicU64::new(0);
    let started = Instant::now();
    QUIET_PANICS.fetch_add(1, Ordering::SeqCst);
    const CHUNK: u64 = 256;
    let chunks = range.cases.div_ceil(CHUNK);
    let threads = range.threads.clamp(1, RUNNING.len());
    std::thread::scope(|scope| {
        for worker in 0..threads {
            let (tallies, findings, digest, next_chunk, done) = (&tallies, &findings, &digest, &next_chunk, &done);
            scope.spawn(move || {
                let mut inflight_file = inflight.and_then(|dir| std::fs::File::create(dir.join(format!("thread-{worker}.case"))).ok());
                let mut input = Vec::new();
                loop {
                    let chunk = next_chunk.fetch_add(1, Ordering::Relaxed);
                    if chunk >= chunks || deadline.is_some_and(|d| Instant::now() >= d) {
                        break;
                    }
                    let end = ((chunk + 1) * CHUNK).min(range.cases);
                    for offset in chunk * CHUNK..end {
                        let case = range.first + offset;
                        let t = (case % targets.len() as u64) as usize;
                        let mut rng = Xoshiro256PlusPlus::seed_from_u64(view_sampler::stream_seed(range.seed, case, 0xF022));
                        let pool = &seeds[t];
                        let base = rng.random_range(0..pool.len());
                        mutate(&mut rng, &pool[base], pool, &mut input);
                        if let Some(file) = inflight_file.as_mut() {
                            write_inflight(file, t, case, &input);
                        }
                        let begun = Instant::now();
                        RUNNING[worker].store(clock_ms().max(1), Ordering::Relaxed);
                        let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| (targets[t].run)(&input)));
                        RUNNING[worker].store(0, Ordering::Relaxed);
                        if let Some(file) = inflight_file.as_mut() {
                            let _ = file.set_len(0);
                        }
                        let ns = begun.elapsed().as_nanos() as u64;
                        tallies[t][0].fetch_add(1, Ordering::Relaxed);
                        tallies[t][2].fetch_add(ns, Ordering::Relaxed);
                        tallies[t][3].fetch_max(ns, Ordering::Relaxed);
                        let verdict = match outcome {
                            Ok(Ok(())) => {
                                tallies[t][1].fetch_add(1, Ordering::Relaxed);
                                1
                            }
                            Ok(Err(_)) => 2,
                            Err(_) => {
                                let message = PANIC.with(|p| p.borrow_mut().take()).unwrap_or_else(|| "panic".into());
                                let mut f = findings.lock().expect("findings lock");
                                let location = message.rsplit(" at ").next().unwrap_or("").to_string();
                                if !f.iter().any(|x| x.target == targets[t].name && x.message.ends_with(&location)) {
                                    f.push(Finding { target: targets[t].name.into(), case, message, input: input.clone() });
                                }
                                3
                            }
                        };
                        // Order-free digest of (case, input, verdict): equal for any thread count.
                        digest.fetch_add(view_sampler::stream_seed(fnv1a(&input), case, verdict), Ordering::Relaxed);
                    }
                    let n = done.fetch_add(end - chunk * CHUNK, Ordering::Relaxed) + (end - chunk * CHUNK);
                    if n % 4096 < CHUNK {
                        progress(n);
                    }
                }
            });
        }
    });
    QUIET_PANICS.fetch_sub(1, Ordering::SeqCst);
    Report {
        tallies: targets
            .iter()
            .zip(&tallies)
            .map(|(t, [c, a, ns, max])| {
                let tally = Tally {
                    cases: c.load(Ordering::Relaxed),
                    accepted: a.load(Ordering::Relaxed),
                    seconds: ns.load(Ordering::Relaxed) as f64 * 1e-9,
                    slowest: max.load(Ordering::Relaxed) as f64 * 1e-9,
                };
                (t.name.to_string(), tally)
            })
            .collect(),
        findings: findings.into_inner().expect("findings lock"),
        seconds: started.elapsed().as_secs_f64(),
        digest: digest.load(Ordering::Relaxed),
    }
}

/// FNV-1a of bytes (names saved inputs and feeds the run digest).
pub(super) fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ *b as u64).wrapping_mul(0x100_0000_01b3))
}

/// The seed inputs of `targets`.
pub fn seeds_of(targets: &[Target]) -> Vec<Vec<Vec<u8>>> {
    targets.iter().map(|t| (t.seeds)()).collect()
}

/// The targets named (all when none).
pub fn select(names: &[String]) -> Result<Vec<Target>> {
    let all = targets();
    if names.is_empty() {
        return Ok(all);
    }
    let known: Vec<&str> = all.iter().map(|t| t.name).collect();
    for n in names {
        if !known.contains(&n.as_str()) {
            bail!("unknown fuzz target {n:?}; targets: {}", known.join(", "));
        }
    }
    Ok(all.into_iter().filter(|t| names.iter().any(|n| n == t.name)).collect())
}

pub(super) fn save_finding(out: &Path, target: &str, kind: &str, message: &str, input: &[u8]) -> Result<PathBuf> {
    let dir = out.join("findings");
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let path = dir.join(format!("{target}-{kind}-{:016x}.bin", fnv1a(input)));
    datasets::io::write_atomic(&path, input)?;
    datasets::io::write_atomic(&path.with_extension("txt"), format!("target {target}\n{kind}: {message}\n").as_bytes())?;
    Ok(path)
}

/// What only the binary may do: cap its heap, and end the process (a hung case cannot be
/// unwound).
pub struct ProcessHooks {
    /// Sets the allocation cap (bytes); false when the heap in use already exceeds it.
    pub memory_cap: fn(usize) -> bool,
    /// Ends the process with this code.
    pub end_process: fn(i32) -> !,
}
