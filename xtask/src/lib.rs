//! The psneus command line as a library: what the `cargo xtask` commands do beyond training,
//! each on top of the [`trainer`] library (configuration, trainer, run folders, evaluation
//! protocol). The binary (`main.rs`) only parses arguments and calls these modules.
//!
//! - [`train`]: `train`'s arguments → the library's run request.
//! - [`eval`]: a mesh against ground truth, or a run's held-out views.
//! - [`trade`]: the speed/accuracy table over budgets, seeds, scenes and settings.
//! - [`fuzz`]: every parser of user input under mutated bytes.
//! - [`machine`]: the CPU and instruction set named beside every benchmark figure.
//! - [`sample`], [`bench`](mod@bench), [`bench_backbone`], [`bench_memory`], [`bench_overhead`]:
//!   the other commands.
#![deny(missing_docs)]

pub mod bench;
pub mod bench_backbone;
pub mod bench_memory;
pub mod bench_overhead;
pub mod eval;
pub mod fuzz;
pub mod machine;
pub mod sample;
pub mod trade;
pub mod train;
