//! A run folder: what makes a folder one (a marker file), the rules for reusing one (a fresh run
//! never writes into a folder it did not make; a run folder is reused only when resumed or
//! explicitly overwritten), the files of a run written through a [`Sink`] (atomic by default),
//! its log, and the record of the data it trained on ([`DataRecord`]: the absolute path and a
//! fingerprint of the loaded cameras and pixels, checked on resume and evaluation).

use crate::bail;
use crate::config::TrainConfig;
use crate::error::{Context, Result};
use crate::trainer::Trainer;
use datasets::Scene;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The file that marks a folder as a run folder of this program.
pub const MARKER: &str = ".psneus-run";

/// The file a process locks while it writes into a run folder (it holds that process's id).
pub const LOCK: &str = ".psneus-lock";

/// A run folder held by this process: while it lives, no other process writes there (train,
/// `--resume`, `--overwrite`, `eval --run`). An advisory lock of the operating system on
/// [`LOCK`]: it ends with the process however the process ends, so the lock of a process that
/// died is free again, and the next run takes it over.
#[derive(Debug)]
pub struct FolderLock {
    _file: std::fs::File,
}

impl FolderLock {
    /// Locks the run folder `dir` (which must exist) for this process, or an error naming the
    /// process that holds it.
    pub fn acquire(dir: &Path) -> Result<FolderLock> {
        use std::io::{Seek, Write};
        let path = dir.join(LOCK);
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .with_context(|| format!("cannot open the lock {}", path.display()))?;
        let mut file = Self::hold(file, dir)?;
        let who = format!("process {} on {}", std::process::id(), std::env::args().collect::<Vec<_>>().join(" "));
        file.set_len(0)
            .and_then(|()| file.rewind())
            .and_then(|()| file.write_all(who.as_bytes()))
            .with_context(|| format!("cannot write {}", path.display()))?;
        Ok(FolderLock { _file: file })
    }

    /// Whether `dir`'s lock is free, changing nothing (no lock file is made, none is written): an
    /// error naming the process that holds it otherwise. A check before the work that precedes
    /// taking the lock (loading data), so that a folder in use is refused at once.
    pub fn check_free(dir: &Path) -> Result<()> {
        let path = dir.join(LOCK);
        if !path.is_file() {
            return Ok(());
        }
        let file =
            std::fs::OpenOptions::new().read(true).write(true).open(&path).with_context(|| format!("cannot open the lock {}", path.display()))?;
        // Dropping the file lets the lock go.
        Self::hold(file, dir).map(drop)
    }

    /// `file` (the lock of `dir`) locked, or an error naming the holder it records.
    fn hold(mut file: std::fs::File, dir: &Path) -> Result<std::fs::File> {
        use std::io::Read;
        match file.try_lock() {
            Ok(()) => Ok(file),
            Err(std::fs::TryLockError::WouldBlock) => {
                let mut holder = String::new();
                let _ = file.read_to_string(&mut holder);
                let holder = holder.trim();
                bail!(
                    Folder,
                    "{} is in use by another run ({}): nothing was changed; wait for it to finish, stop it (Ctrl-C or SIGTERM \
                     writes a checkpoint), or choose another --out",
                    dir.display(),
                    if holder.is_empty() { "a process that has not yet said which" } else { holder }
                );
            }
            Err(std::fs::TryLockError::Error(e)) => Err(e).with_context(|| format!("cannot lock {}", dir.join(LOCK).display())),
        }
    }
}

/// Where a run's files go. The default writes atomically (temporary file + rename); tests inject
/// failures.
pub trait Sink: Send + Sync {
    /// Writes `bytes` to `path` whole, or not at all.
    fn write(&self, path: &Path, bytes: &[u8]) -> std::io::Result<()>;

    /// Writes what `fill` streams to `path` whole, or not at all. Default: collected in memory,
    /// then [`Sink::write`].
    fn write_with(&self, path: &Path, fill: &mut dyn FnMut(&mut dyn std::io::Write) -> std::io::Result<()>) -> std::io::Result<()> {
        let mut bytes = Vec::new();
        fill(&mut bytes)?;
        self.write(path, &bytes)
    }
}

/// Atomic writes to the file system (`datasets::io::write_atomic`).
#[derive(Debug, Clone, Copy, Default)]
pub struct AtomicFiles;

impl Sink for AtomicFiles {
    fn write(&self, path: &Path, bytes: &[u8]) -> std::io::Result<()> {
        self.write_with(path, &mut |w| w.write_all(bytes))
    }
    fn write_with(&self, path: &Path, fill: &mut dyn FnMut(&mut dyn std::io::Write) -> std::io::Result<()>) -> std::io::Result<()> {
        datasets::io::write_atomic_with(path, fill).map_err(|e| match e {
            datasets::DatasetError::Io { source, .. } => std::io::Error::new(source.kind(), source.to_string()),
            other => std::io::Error::other(other.to_string()),
        })
    }
}

/// Whether `dir` is a run folder of this program (its marker, or the `config.toml` and
/// `data.json` of a run folder of earlier versions).
pub fn is_run_folder(dir: &Path) -> bool {
    dir.join(MARKER).is_file() || (dir.join("config.toml").is_file() && dir.join("data.json").is_file())
}

/// A run folder and the sink its files go through.
pub struct RunFolder {
    dir: PathBuf,
    sink: Arc<dyn Sink>,
    _lock: FolderLock,
}

impl RunFolder {
    /// Makes the folder of a fresh run and locks it ([`FolderLock`]). `dir` must not exist, or
    /// be empty, or (with `overwrite`) be a run folder of this program that no other process
    /// holds, whose files are then removed; anything else is refused and left as it is. Returns
    /// the folder and whether `dir` was created now.
    pub fn create(dir: &Path, overwrite: bool, sink: Arc<dyn Sink>) -> Result<(RunFolder, bool)> {
        let existed = dir.exists();
        // A folder with a lock is (or is becoming) a run folder: its lock is taken before anything
        // is read or removed, so that a run in progress there refuses this one.
        let early_lock = (dir.join(LOCK).is_file() || is_run_folder(dir)).then(|| FolderLock::acquire(dir)).transpose()?;
        // Everything but the lock, which this process holds.
        for path in Self::refusals(dir, overwrite)? {
            let removed = if path.is_dir() { std::fs::remove_dir_all(&path) } else { std::fs::remove_file(&path) };
            removed.with_context(|| format!("cannot clear the earlier run in {}: {}", dir.display(), path.display()))?;
        }
        std::fs::create_dir_all(dir.join("pictures")).with_context(|| format!("cannot create the run folder {}", dir.display()))?;
        let lock = match early_lock {
            Some(lock) => lock,
            None => FolderLock::acquire(dir)?,
        };
        let folder = RunFolder { dir: dir.to_path_buf(), sink, _lock: lock };
        folder.write(MARKER, b"psneus run folder: written by `cargo xtask train`; `--resume` continues it, `--overwrite` replaces it\n")?;
        Ok((folder, !existed))
    }

    /// The refusals of [`RunFolder::create`], changing nothing: `dir` is a file, a folder of
    /// other files, an earlier run (without `overwrite`), or in use by another process. For a
    /// caller with work to do before it creates the folder (loading the data).
    pub fn check_fresh(dir: &Path, overwrite: bool) -> Result<()> {
        FolderLock::check_free(dir)?;
        Self::refusals(dir, overwrite).map(drop)
    }

    /// The entries of `dir` but the lock (what `overwrite` removes), or why a fresh run may not
    /// go there.
    fn refusals(dir: &Path, overwrite: bool) -> Result<Vec<PathBuf>> {
        if !dir.exists() {
            return Ok(Vec::new());
        }
        let meta = std::fs::symlink_metadata(dir).with_context(|| format!("cannot read {}", dir.display()))?;
        if !meta.is_dir() {
            bail!(Folder, "--out {} exists and is not a folder: choose another --out", dir.display());
        }
        let entries = std::fs::read_dir(dir).with_context(|| format!("cannot read {}", dir.display()))?;
        let contents: Vec<PathBuf> = entries.filter_map(|e| e.ok()).map(|e| e.path()).filter(|p| p.file_name() != Some(LOCK.as_ref())).collect();
        if !contents.is_empty() {
            if !is_run_folder(dir) {
                bail!(
                    Folder,
                    "--out {} is a folder that holds other files (not a run folder of psneus): nothing was written; choose another --out",
                    dir.display()
                );
            }
            if !overwrite {
                bail!(
                    Folder,
                    "--out {} holds an earlier run: continue it with `--resume {0}`, replace it with --overwrite, or choose another --out",
                    dir.display()
                );
            }
        }
        Ok(contents)
    }

    /// Opens the folder of a run to continue and locks it ([`FolderLock`]); stale temporary
    /// files of a killed writer are removed.
    pub fn open(dir: &Path, sink: Arc<dyn Sink>) -> Result<RunFolder> {
        if !is_run_folder(dir) {
            bail!(Folder, "{} is not a run folder (no {MARKER}, config.toml or data.json)", dir.display());
        }
        let lock = FolderLock::acquire(dir)?;
        std::fs::create_dir_all(dir.join("pictures")).with_context(|| format!("cannot open the run folder {}", dir.display()))?;
        // A killed writer's temporaries: in the folder, its pictures and its snapshots' folders
        // (a snapshot's checkpoint is as large as the run's).
        let snapshots =
            std::fs::read_dir(dir.join("snapshots")).into_iter().flatten().filter_map(|e| e.ok()).map(|e| e.path()).filter(|p| p.is_dir());
        for d in [dir.to_path_buf(), dir.join("pictures")].into_iter().chain(snapshots) {
            datasets::io::remove_stale_temporaries(&d);
        }
        Ok(RunFolder { dir: dir.to_path_buf(), sink, _lock: lock })
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Writes `name` (relative to the folder) whole; the error names the file and the cause.
    pub fn write(&self, name: &str, bytes: &[u8]) -> Result<()> {
        let path = self.dir.join(name);
        self.sink.write(&path, bytes).with_context(|| format!("cannot write {}", path.display()))
    }

    /// Writes `name` from what `fill` streams, whole; the error names the file and the cause.
    pub fn write_with(&self, name: &str, fill: &mut dyn FnMut(&mut dyn std::io::Write) -> std::io::Result<()>) -> Result<()> {
        let path = self.dir.join(name);
        self.sink.write_with(&path, fill).with_context(|| format!("cannot write {}", path.display()))
    }

    /// Writes `data.json`, the record of the data the run trains on.
    pub fn write_data_record(&self, record: &DataRecord) -> Result<()> {
        self.write("data.json", serde_json::to_string_pretty(record)?.as_bytes())
    }

    /// Writes the trainer's checkpoint (streamed).
    pub fn write_checkpoint(&self, trainer: &Trainer) -> Result<()> {
        self.write_with(CHECKPOINT_FILE, &mut |w| trainer.write_checkpoint(w))
    }

    /// Writes the trainer's checkpoint (streamed) into `sub`, a folder of the run (a
    /// snapshot's, [`crate::snapshot::snapshot_dir`]).
    pub fn write_checkpoint_in(&self, sub: &str, trainer: &Trainer) -> Result<()> {
        self.write_with(&format!("{sub}/{CHECKPOINT_FILE}"), &mut |w| trainer.write_checkpoint(w))
    }

    /// Writes a PNG.
    pub fn write_png(&self, name: &str, image: &datasets::RgbImage) -> Result<()> {
        self.write(name, &image.png_bytes().with_context(|| format!("encoding {name}"))?)
    }

    /// Appends one line to `log.jsonl` (a log is appended, not replaced).
    pub fn log(&self, record: &serde_json::Value) -> Result<()> {
        use std::io::Write;
        let path = self.dir.join("log.jsonl");
        let mut f = std::fs::OpenOptions::new().create(true).append(true).open(&path).with_context(|| format!("cannot open {}", path.display()))?;
        writeln!(f, "{record}").with_context(|| format!("cannot write {}", path.display()))
    }

    /// Drops the log lines of iterations after `step` (those of a session that ended after its
    /// last checkpoint), so that a resumed run's log holds each iteration once.
    pub fn trim_log(&self, step: u64) -> Result<()> {
        let path = self.dir.join("log.jsonl");
        let Ok(text) = std::fs::read_to_string(&path) else { return Ok(()) };
        let kept: String = text
            .lines()
            .filter(|l| serde_json::from_str::<serde_json::Value>(l).ok().and_then(|r| r["step"].as_u64()).is_none_or(|s| s <= step))
            .map(|l| format!("{l}\n"))
            .collect();
        if kept.len() != text.len() {
            self.write("log.jsonl", kept.as_bytes())?;
        }
        Ok(())
    }
}

/// The name of a checkpoint file (the run's, and a snapshot's in its folder).
const CHECKPOINT_FILE: &str = "checkpoint.safetensors";

/// The checkpoint file of a run folder (or of a snapshot's folder).
pub fn checkpoint_path(dir: &Path) -> PathBuf {
    dir.join(CHECKPOINT_FILE)
}

/// What a run trained on (`data.json`): the dataset folder as an absolute path (none: the
/// built-in scene, which its configuration describes) and a fingerprint of what was loaded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DataRecord {
    /// The dataset folder, absolute.
    pub path: Option<PathBuf>,
    /// What the loader said it loaded.
    pub description: String,
    /// The loaded views (`None` in run folders of earlier versions).
    #[serde(default)]
    pub fingerprint: Option<Fingerprint>,
}

/// The loaded views, one hash each of the camera, the pixels and the mask.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Fingerprint {
    /// `(name, hash)` per view, in the loader's order.
    pub views: Vec<(String, String)>,
}

/// A 64-bit hash of words (a multiply–rotate mix; not cryptographic, stable across builds and
/// platforms).
struct WordHash(u64);

impl WordHash {
    fn word(&mut self, w: u64) {
        self.0 = (self.0 ^ w).wrapping_mul(0x9E37_79B9_7F4A_7C15).rotate_left(29);
    }
    fn bytes(&mut self, bytes: &[u8]) {
        let mut chunks = bytes.chunks_exact(8);
        for c in &mut chunks {
            self.word(u64::from_le_bytes(c.try_into().expect("8 bytes")));
        }
        let mut last = [0u8; 8];
        last[..chunks.remainder().len()].copy_from_slice(chunks.remainder());
        self.word(u64::from_le_bytes(last));
        self.word(bytes.len() as u64);
    }
}

impl Fingerprint {
    /// The fingerprint of a loaded scene.
    pub fn of(scene: &Scene) -> Fingerprint {
        let views = scene
            .views
            .iter()
            .map(|v| {
                let mut h = WordHash(0x51_7c_c1_b7_27_22_0a_95);
                h.bytes(&serde_json::to_vec(&v.camera).expect("a camera serialises"));
                h.bytes(&v.image.data);
                if let Some(m) = &v.mask {
                    h.word(u64::from(m.width) << 32 | u64::from(m.height));
                    m.as_words().iter().for_each(|&w| h.word(w));
                }
                (v.name.clone(), format!("{:016x}", h.0))
            })
            .collect();
        Fingerprint { views }
    }

    /// `None` when equal, else what differs first (for messages).
    pub fn difference(&self, now: &Fingerprint) -> Option<String> {
        if self.views.len() != now.views.len() {
            return Some(format!("the run trained on {} views, the data now has {}", self.views.len(), now.views.len()));
        }
        let changed: Vec<&str> = self.views.iter().zip(&now.views).filter(|(a, b)| a != b).map(|(_, b)| b.0.as_str()).collect();
        match changed.as_slice() {
            [] => None,
            [one] => Some(format!("view {one:?} differs (its camera, image or mask)")),
            [first, ..] => Some(format!("{} views differ (the first: {first:?})", changed.len())),
        }
    }
}

impl DataRecord {
    /// The record of `scene` loaded from `path` (relative paths made absolute).
    pub fn new(path: Option<&Path>, description: &str, scene: &Scene) -> Result<DataRecord> {
        let path = path.map(|p| std::path::absolute(p).with_context(|| format!("cannot resolve {}", p.display()))).transpose()?;
        Ok(DataRecord { path, description: description.to_string(), fingerprint: Some(Fingerprint::of(scene)) })
    }

    /// Checks that `scene`, loaded for the run in `dir`, is the data the run trained on: an
    /// error naming the difference, or (a run folder of an earlier version, which kept no
    /// fingerprint) an error unless `repointed` (the user named the data explicitly).
    pub fn verify(&self, dir: &Path, scene: &Scene, repointed: bool) -> Result<()> {
        let now = Fingerprint::of(scene);
        match &self.fingerprint {
            Some(then) => {
                if let Some(difference) = then.difference(&now) {
                    bail!(
                        Input,
                        "the data of {} ({}) is not what the run trained on: {difference}; point --data at the run's own data",
                        dir.display(),
                        self.path.as_ref().map_or("the built-in scene".into(), |p| p.display().to_string())
                    );
                }
            }
            None if !repointed && self.path.as_ref().is_some_and(|p| p.is_relative()) => bail!(
                Input,
                "{} was made by an earlier version that kept its data path ({}) relative and no fingerprint: \
                 name the run's data with --data to continue",
                dir.display(),
                self.path.as_ref().map_or(String::new(), |p| p.display().to_string())
            ),
            None => {}
        }
        Ok(())
    }
}

/// A run folder's configuration and data record; errors name the file at fault.
pub fn read_run_config(dir: &Path) -> Result<(TrainConfig, DataRecord)> {
    let config_path = dir.join("config.toml");
    let text = std::fs::read_to_string(&config_path).with_context(|| format!("{} is not a run folder (no config.toml)", dir.display()))?;
    let config = TrainConfig::from_toml(&text).with_context(|| format!("{}", config_path.display()))?;
    let data_path = dir.join("data.json");
    let bytes = std::fs::read(&data_path).with_context(|| format!("{} is not a run folder (no data.json)", dir.display()))?;
    let record: DataRecord = serde_json::from_slice(&bytes).with_context(|| format!("{} is not a run's data record", data_path.display()))?;
    Ok((config, record))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two holders of one folder's lock (two open files: what two processes are) cannot both
    /// have it; the second is told who has it, and the lock is free once the first lets go.
    #[test]
    fn a_folder_lock_is_held_by_one_holder_at_a_time_and_names_it() {
        let dir = tempfile::tempdir().unwrap();
        let first = FolderLock::acquire(dir.path()).unwrap();
        let refused = FolderLock::acquire(dir.path()).unwrap_err().to_string();
        assert!(refused.contains("in use by another run") && refused.contains(&format!("process {}", std::process::id())), "{refused}");
        drop(first);
        FolderLock::acquire(dir.path()).unwrap();
    }
}
