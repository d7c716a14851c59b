//! psneus training as a library: the configuration, the trainer, run folders, metrics, snapshots,
//! outputs, the memory model and the evaluation protocol. `cargo xtask` (the command line) and
//! the Python binding drive it; neither the trainer nor a run needs a terminal.
//!
//! The public surface a caller needs:
//! - [`config::TrainConfig`]: the typed training configuration (TOML, `key=value` overrides,
//!   validation, the annotated default).
//! - [`run::run`]: one [`run::RunRequest`] (a fresh run or a resume) with [`run::RunOptions`] and
//!   a stop flag → [`run::Outcome`]: the run folder with its log, pictures, checkpoints, mesh
//!   and metrics; [`run::open_run`] reopens a run at its checkpoint.
//! - [`trainer::Trainer`]: step, checkpoint/restore, renders, mesh — without files.
//! - [`evaluation`]: a mesh against a ground truth (DTU-protocol Chamfer, F-score).
//! - [`Error`]: what went wrong, by kind (configuration, input, run folder, divergence, I/O,
//!   the crates below), with its context as a chain of sources.
//!
//! The rest, by job:
//! - [`data`]: the scene of a run (built-in golden scene or a dataset folder), its ground truth,
//!   the training/held-out split; [`sizing`]: the hash grid sized by the views' pixel footprint.
//! - [`rays`]: drawn pixels → the backbone's rays; [`mining`]: the loss-guided samplers.
//! - [`folder`]: the run folder (marker, lock, reuse rules, atomic files, the data record and its
//!   fingerprint); [`metrics`]: the typed `metrics.json`; [`snapshot`]: meshes and metrics at
//!   given training times of one run.
//! - [`outputs`], [`progress`], [`draw`], [`plot`]: renders, panels, mesh files and filters,
//!   progress, labelled plots; [`memory`]: the memory model.
#![deny(missing_docs)]

pub mod config;
pub mod data;
pub mod draw;
pub mod error;
pub mod evaluation;
pub mod folder;
pub mod memory;
pub mod metrics;
pub mod mining;
pub mod observation;
pub mod outputs;
pub mod plot;
pub mod progress;
pub mod rays;
pub mod run;
pub mod sizing;
pub mod snapshot;
pub mod trainer;

pub use error::{Error, Result};
pub use trainer::{SplitStats, Trainer};
