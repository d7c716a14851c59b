//! The deferred gradient of a batch: the hash tables' gradient recorded per work item during
//! the backward pass and applied afterwards, table block by table block.

use super::analytic::ApplyTangentBlockFn;
use crate::module::DeferringModule;
use crate::real::Real;
use crate::scratch::Buf;

/// A work item's deferred gradient record: its SDF points and the record
/// ([`DeferringModule::apply_deferred`]).
pub(crate) type Deferred<R> = Option<(Buf<R>, Buf<R>)>;

/// The deferred gradient of a batch for the SDF network `S`: each work item's SDF points and
/// record, in order.
pub struct DeferredGradient<S, R: Real> {
    pub(crate) records: Vec<(Buf<R>, Buf<R>)>,
    /// How records of analytic normals are applied
    /// ([`crate::module::DeferringTangentModule::apply_deferred_tangent_block`]: their points
    /// and tangents, output and tangent adjoints); None for records of values only.
    pub(crate) tangent: Option<ApplyTangentBlockFn<S, R>>,
}

impl<S: DeferringModule<R>, R: Real> DeferredGradient<S, R> {
    /// (points, record) per work item, in order.
    pub fn parts(&self) -> Vec<(&[R], &[R])> {
        self.records.iter().map(|(p, r)| (&p[..], &r[..])).collect()
    }

    /// Adds block `block` of the deferred gradient of `net` to `d_block`
    /// ([`DeferringModule::apply_deferred_block`]).
    pub fn apply_block(&self, net: &S, block: usize, d_block: &mut [R]) {
        match self.tangent {
            Some(apply) => apply(net, &self.parts(), block, d_block),
            None => net.apply_deferred_block(&self.parts(), block, d_block),
        }
    }

    /// Every block of the deferred gradient of `net` into `d_deferred` (its first
    /// [`DeferringModule::deferred_params`] parameters), in parallel over blocks.
    pub fn apply(&self, net: &S, d_deferred: &mut [R]) {
        use rayon::prelude::*;
        if self.tangent.is_none() {
            return net.apply_deferred(&self.parts(), d_deferred);
        }
        let blocks = crate::module::split_blocks(d_deferred, crate::module::deferred_block_ranges::<R, _>(net));
        blocks.into_par_iter().enumerate().for_each(|(block, d)| self.apply_block(net, block, d));
    }
}
