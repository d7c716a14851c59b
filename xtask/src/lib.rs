//! The psneus runner as a library: the trainer ([`trainer::Trainer`]) and everything the
//! `cargo xtask` commands do, so that a training run can be driven from other code as well as
//! from the command line. The binary (`main.rs`) only parses arguments and calls these modules.
//!
//! - [`config`]: the typed training configuration (TOML, overrides, validation).
//! - [`data`]: the scene of a run (built-in golden scene or a dataset folder), its ground truth,
//!   the training/held-out split.
//! - [`trainer`]: [`trainer::Trainer`] — step, checkpoint/restore, renders, mesh.
//! - [`sizing`]: the hash grid sized by the views' pixel footprint (`model.grid = "footprint"`).
//! - [`rays`]: drawn pixels → the backbone's rays (coarse samples, up-sampling, extra points).
//! - [`run`]: the `train` command — [`run::RunRequest`] → [`run::run`]: log, pictures,
//!   checkpoints, resume, stop signal, final mesh and metrics; [`run::open_run`] reopens a run.
//! - [`folder`]: the run folder (marker, reuse rules, atomic files, the data record and its
//!   fingerprint); [`metrics`]: [`metrics::RunMetrics`], the typed `metrics.json`.
//! - [`outputs`], [`progress`], [`draw`]: renders, panels, mesh files and filters, progress;
//!   [`snapshot`]: meshes and metrics at given training times of one run.
//! - [`fuzz`]: every parser of user input under mutated bytes.
//! - [`eval`], [`trade`], [`sample`], [`bench`](mod@bench), [`bench_backbone`], [`bench_memory`], [`bench_overhead`]: the
//!   other commands; [`memory`]: the memory model; [`plot`]: labelled plots.
#![deny(missing_docs)]

pub mod bench;
pub mod bench_backbone;
pub mod bench_memory;
pub mod bench_overhead;
pub mod config;
pub mod data;
pub mod draw;
pub mod eval;
pub mod folder;
pub mod fuzz;
pub mod memory;
pub mod metrics;
pub mod mining;
pub mod outputs;
pub mod plot;
pub mod progress;
pub mod rays;
pub mod run;
pub mod sample;
pub mod sizing;
pub mod snapshot;
pub mod trade;
pub mod trainer;
