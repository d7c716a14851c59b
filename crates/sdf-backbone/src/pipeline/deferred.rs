//! The deferred gradient of a batch: the hash tables' gradient recorded per work item during
//! the backward pass and applied afterwards, table block by table block.

use crate::module::Module;
use crate::real::Real;
use crate::scratch::Buf;

/// A work item's deferred gradient record: its SDF points and the record
/// ([`Module::apply_deferred`]).
pub(crate) type Deferred<R> = Option<(Buf<R>, Buf<R>)>;

/// The deferred gradient of a batch: each work item's SDF points and record, in order.
pub struct DeferredGradient<R: Real> {
    pub(crate) records: Vec<(Buf<R>, Buf<R>)>,
    /// Records of analytic normals ([`Module::backward_tangent_deferring`]): points and
    /// tangents, output and tangent adjoints.
    pub(crate) tangent: bool,
}

impl<R: Real> DeferredGradient<R> {
    /// (points, record) per work item, in order.
    pub fn parts(&self) -> Vec<(&[R], &[R])> {
        self.records.iter().map(|(p, r)| (&p[..], &r[..])).collect()
    }

    /// Adds block `block` of the deferred gradient of `net` to `d_block`
    /// ([`Module::apply_deferred_block`]).
    pub fn apply_block<M: Module<R>>(&self, net: &M, block: usize, d_block: &mut [R]) {
        if self.tangent {
            net.apply_deferred_tangent_block(&self.parts(), block, d_block);
        } else {
            net.apply_deferred_block(&self.parts(), block, d_block);
        }
    }

    /// Every block of the deferred gradient of `net` into `d_deferred` (its first
    /// [`Module::deferred_params`] parameters), in parallel over blocks.
    pub fn apply<M: Module<R> + Sync>(&self, net: &M, d_deferred: &mut [R]) {
        use rayon::prelude::*;
        if !self.tangent {
            return net.apply_deferred(&self.parts(), d_deferred);
        }
        let blocks = crate::module::split_blocks(d_deferred, crate::module::deferred_block_ranges::<R, _>(net));
        blocks.into_par_iter().enumerate().for_each(|(block, d)| self.apply_block(net, block, d));
    }
}
