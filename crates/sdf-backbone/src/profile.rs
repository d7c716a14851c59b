//! Where a training step's or a render's time goes: CPU time per stage (hash-grid gathers,
//! scatters and tangents, MLP passes, the pipeline's own per-ray work, Adam, a render's
//! up-sampling and pass, the learned background), summed over threads.
//!
//! The kernels run inside one runtime-dispatched function ([`crate::kernels::dispatch`]) into
//! which everything is inlined, so a sampling profiler cannot tell them apart; these counters
//! can. They cost one relaxed atomic load per module call while disabled (the default), and two
//! clock reads per call while enabled — calls are per work item (thousands of rows), not per row.
//! The counters are process-wide: everything that runs while they are enabled adds to them.
//! `cargo xtask bench backbone --preset P --profile` prints a step's module stages,
//! `cargo xtask eval --run RUN --profile` every stage of a run's renders.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Instant;

/// A stage of a training step or a render. Stages do not nest, except those that hold the
/// module stages run inside them — [`Stage::LossPass`] (the pipeline's own work is the
/// difference), a render's [`Stage::Upsample`] and [`Stage::RenderPass`] — and
/// [`Stage::Background`], inside a loss or render pass and holding its own modules.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// The hash grid's feature gathers (trilinear interpolation of every level).
    HashForward,
    /// The hash grid's tangents (analytic normals), forward.
    HashTangents,
    /// Forward passes of the MLPs (SDF and colour): products, bias, activation, stored slopes.
    MlpForward,
    /// Tangent passes of the MLPs (analytic normals), forward and backward.
    MlpTangents,
    /// Backward passes of the MLPs: weight and input gradients.
    MlpBackward,
    /// The whole forward + backward pass of a work item ([`crate::Pipeline`]'s loss), modules
    /// included.
    LossPass,
    /// The hash grid's table gradient: the scatter of the recorded rows into each level.
    HashScatter,
    /// The hash grid's tangents' part of the table gradient (analytic normals), a scatter.
    HashTangentScatter,
    /// Adam's update of every parameter (with clipping on, the norm's own pass over the table
    /// gradient counts as [`Stage::HashScatter`]).
    Adam,
    /// A render's up-sampling and trim (modules included): the SDF at every depth.
    Upsample,
    /// A render's forward-only pass ([`crate::Pipeline::render_known`], modules included).
    RenderPass,
    /// The learned background's forward pass ([`crate::BackgroundModel::forward`], in a render
    /// [`crate::BackgroundModel::render`]; its modules included), inside a render's pass or a
    /// loss pass: what the rays' background costs.
    Background,
}

/// Every stage, in report order (the enum's order: a stage's index is its discriminant).
pub const STAGES: [Stage; 12] = [
    Stage::HashForward,
    Stage::HashTangents,
    Stage::MlpForward,
    Stage::MlpTangents,
    Stage::MlpBackward,
    Stage::LossPass,
    Stage::HashScatter,
    Stage::HashTangentScatter,
    Stage::Adam,
    Stage::Upsample,
    Stage::RenderPass,
    Stage::Background,
];

static ENABLED: AtomicBool = AtomicBool::new(false);
static NANOS: [AtomicU64; STAGES.len()] = [const { AtomicU64::new(0) }; STAGES.len()];

impl Stage {
    /// The stage's name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Stage::HashForward => "hash grid: gathers",
            Stage::HashScatter => "hash grid: gradient scatter",
            Stage::HashTangents => "hash grid: tangents",
            Stage::HashTangentScatter => "hash grid: tangent scatter",
            Stage::MlpForward => "MLPs: forward",
            Stage::MlpBackward => "MLPs: backward",
            Stage::MlpTangents => "MLPs: tangents",
            Stage::LossPass => "loss pass (modules included)",
            Stage::Adam => "Adam",
            Stage::Upsample => "render: up-sampling (modules included)",
            Stage::RenderPass => "render: forward pass (modules included)",
            Stage::Background => "background: forward (modules included; inside the passes)",
        }
    }
    fn index(self) -> usize {
        self as usize
    }
}

/// Starts or stops collecting (collected times are kept; [`take`] reads and clears them).
pub fn enable(on: bool) {
    ENABLED.store(on, Ordering::Relaxed);
}

/// The CPU seconds of every stage since the last call, summed over threads; clears them.
pub fn take() -> Vec<(Stage, f64)> {
    STAGES.iter().map(|s| (*s, NANOS[s.index()].swap(0, Ordering::Relaxed) as f64 * 1e-9)).collect()
}

/// A running stage: its time is added when it is dropped.
pub struct Span {
    stage: Stage,
    start: Option<Instant>,
}

impl Drop for Span {
    fn drop(&mut self) {
        if let Some(start) = self.start {
            NANOS[self.stage.index()].fetch_add(start.elapsed().as_nanos() as u64, Ordering::Relaxed);
        }
    }
}

/// Times `stage` until the returned span is dropped (nothing while collection is off).
#[inline]
pub fn span(stage: Stage) -> Span {
    Span { stage, start: ENABLED.load(Ordering::Relaxed).then(Instant::now) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stages_are_listed_in_their_discriminant_order() {
        // `Stage::index` is the discriminant: STAGES must list the variants in declaration order.
        assert!(STAGES.iter().enumerate().all(|(i, s)| s.index() == i));
    }

    #[test]
    fn spans_count_only_while_enabled() {
        // One test owns the global counters (other tests of this crate do not enable them).
        take();
        drop(span(Stage::Adam));
        assert!(take().iter().all(|(_, t)| *t == 0.0), "disabled spans must not count");
        enable(true);
        {
            let _s = span(Stage::Adam);
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        enable(false);
        let t = take();
        let adam = t.iter().find(|(s, _)| *s == Stage::Adam).map(|(_, t)| *t).unwrap_or(0.0);
        assert!(adam >= 0.004, "the span's time is counted: {adam}");
    }
}
