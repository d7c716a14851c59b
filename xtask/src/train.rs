//! `cargo xtask train`'s command line: [`TrainArgs`], typed by clap, and the one place they
//! become the library's [`RunRequest`] and [`RunOptions`]; [`train`] runs them.

use anyhow::{Result, bail};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;
use trainer::config::{Budget, SamplerKind, TrainConfig, parse_duration};
use trainer::folder::{AtomicFiles, Sink};
use trainer::run::{DEFAULT_OUT, Outcome, RunOptions, RunRequest, free_default_out, run};

/// Options of `cargo xtask train`: the command line, typed by clap; [`TrainArgs::request`] is the
/// one place they become the library's [`RunRequest`].
#[derive(clap::Args, Debug, Clone, Default)]
pub struct TrainArgs {
    /// Dataset folder (IDR/NeuS/DTU, NeRF-synthetic, instant-ngp, COLMAP). Default: the
    /// built-in scene. With --resume: the run's data at a new place (checked against the run's
    /// fingerprint of it).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// TOML configuration (unknown keys are errors).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// guided (the paper) or uniform (the plain backbone, same rays and samples).
    #[arg(long, value_enum)]
    pub sampler: Option<SamplerKind>,
    /// Train for this long: `90s`, `10m`, `1.5h` (the schedules follow the fraction of the
    /// budget spent; replaces the configuration's budget).
    #[arg(long, value_parser = parse_duration)]
    pub budget: Option<Duration>,
    /// Run folder (config, log, pictures, checkpoints, mesh, metrics); it must not exist or be
    /// empty. Default `out/train`, or `out/train-2`, `-3`, … when that holds an earlier run.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Replace the earlier run in --out (only a run folder of psneus is ever replaced).
    #[arg(long, conflicts_with = "resume")]
    pub overwrite: bool,
    /// Continue the run in this folder from its checkpoint, with its own configuration and data
    /// (same result as an uninterrupted run for step budgets; the rest of the budget for time
    /// budgets).
    #[arg(long, conflicts_with_all = ["config", "sampler", "seed", "budget", "out"])]
    pub resume: Option<PathBuf>,
    /// Seed of every random stream.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Stop after this many iterations as if interrupted (checkpoint written), for testing resume.
    #[arg(long, hide = true)]
    pub stop_at: Option<u64>,
    /// Print one JSON summary line at the end.
    #[arg(long)]
    pub json: bool,
    /// The memory limit (e.g. `8G`); by default the memory the system has available. A run whose
    /// estimated peak exceeds it is refused before it starts, with what to change.
    #[arg(long, value_parser = trainer::memory::parse_size)]
    pub max_memory: Option<f64>,
    /// Print the default configuration as TOML, every key with its description, and exit.
    #[arg(long, exclusive = true)]
    pub print_config: bool,
    /// Configuration overrides `key=value` (e.g. `steps=500 guide.scene.partition=1`).
    pub overrides: Vec<String>,
}

impl TrainArgs {
    /// The typed request and options of these arguments.
    pub fn request(&self) -> Result<(RunRequest, RunOptions)> {
        let options = RunOptions { max_memory: self.max_memory, stop_at: self.stop_at, json: self.json };
        if let Some(dir) = &self.resume {
            if !self.overrides.is_empty() {
                bail!("--resume continues a run with its own configuration; overrides ({}) are not allowed", self.overrides.join(" "));
            }
            return Ok((RunRequest::Resume { dir: dir.clone(), data: self.data.clone() }, options));
        }
        let mut config = TrainConfig::load(self.config.as_deref(), &self.overrides)?;
        if let Some(sampler) = self.sampler {
            config.sampler = sampler;
        }
        if let Some(seed) = self.seed {
            config.seed = seed;
        }
        if let Some(budget) = self.budget {
            config.budget = Budget::Time(budget);
        }
        config.validate()?;
        let out = match &self.out {
            Some(out) => out.clone(),
            None if self.overwrite => PathBuf::from(DEFAULT_OUT),
            None => free_default_out(),
        };
        Ok((RunRequest::Fresh { config: Box::new(config), data: self.data.clone(), out, overwrite: self.overwrite }, options))
    }
}

/// Runs `cargo xtask train` with atomic file writes; `stop` ends the run early with a checkpoint.
pub fn train(args: &TrainArgs, stop: &AtomicBool) -> Result<Outcome> {
    train_with(args, stop, Arc::new(AtomicFiles))
}

/// [`train`] with the files going through `sink`.
pub fn train_with(args: &TrainArgs, stop: &AtomicBool, sink: Arc<dyn Sink>) -> Result<Outcome> {
    let (request, options) = args.request()?;
    Ok(run(&request, &options, stop, sink)?)
}
