//! Per-thread scratch buffers, reused across work items and steps: a training step needs tens of
//! megabytes of context per work item, and allocating it fresh each time costs page faults and
//! zeroing of fresh pages (measured ~15 % of a step). A [`Buf`] is taken from the calling
//! thread's pool (zeroed, of the asked length) and goes back to it when dropped; the pool keeps
//! what the largest step needed, so the resident size stays flat after the first step.

use std::cell::RefCell;
use std::ops::{Deref, DerefMut};

/// Buffers of one precision, per thread.
pub trait Pooled: Sized + 'static {
    /// Runs `f` on the calling thread's pool of this precision.
    fn with_pool<T>(f: impl FnOnce(&mut Vec<Vec<Self>>) -> T) -> T;
}

macro_rules! pooled {
    ($t:ty) => {
        impl Pooled for $t {
            fn with_pool<T>(f: impl FnOnce(&mut Vec<Vec<Self>>) -> T) -> T {
                thread_local! {
                    static POOL: RefCell<Vec<Vec<$t>>> = const { RefCell::new(Vec::new()) };
                }
                POOL.with(|p| f(&mut p.borrow_mut()))
            }
        }
    };
}
pooled!(f32);
pooled!(f64);
pooled!(u32);

/// Empties the calling thread's pools (every precision), returning their memory.
pub fn release_thread() {
    f32::with_pool(Vec::clear);
    f64::with_pool(Vec::clear);
    u32::with_pool(Vec::clear);
}

/// Empties the pools of every rayon worker thread and the calling thread: call between phases
/// whose buffers differ in size (training, evaluation renders, meshing), so that the resident
/// size is the largest phase's, not their sum.
pub fn release_all() {
    rayon::broadcast(|_| release_thread());
    release_thread();
}

/// What a [`Buf`] can hold.
pub trait Element: Pooled + Copy + Default {}
impl Element for f32 {}
impl Element for f64 {}
impl Element for u32 {}

/// A zeroed buffer from the thread's pool, returned to the pool of the thread that drops it.
#[derive(Debug)]
pub struct Buf<R: Element>(Vec<R>);

impl<R: Element> Buf<R> {
    /// `len` zeros, reusing a pooled allocation when one is large enough (the smallest such).
    pub fn zeroed(len: usize) -> Buf<R> {
        let mut v = R::with_pool(|pool| {
            let best = pool.iter().enumerate().filter(|(_, b)| b.capacity() >= len).min_by_key(|(_, b)| b.capacity()).map(|(i, _)| i);
            match best {
                Some(i) => pool.swap_remove(i),
                None => pool.pop().unwrap_or_default(),
            }
        });
        v.clear();
        v.resize(len, R::default());
        Buf(v)
    }

    /// The values, as a vector (the allocation leaves the pool for good).
    pub fn into_vec(mut self) -> Vec<R> {
        std::mem::take(&mut self.0)
    }
}

impl<R: Element> Drop for Buf<R> {
    fn drop(&mut self) {
        let v = std::mem::take(&mut self.0);
        if v.capacity() > 0 {
            R::with_pool(|pool| {
                // A handful of buffers per thread is all a step uses.
                if pool.len() < 64 {
                    pool.push(v);
                }
            });
        }
    }
}

impl<R: Element> Deref for Buf<R> {
    type Target = [R];
    fn deref(&self) -> &[R] {
        &self.0
    }
}

impl<R: Element> DerefMut for Buf<R> {
    fn deref_mut(&mut self) -> &mut [R] {
        &mut self.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buffers_are_zeroed_and_reused() {
        let ptr = {
            let mut b = Buf::<f32>::zeroed(1000);
            b[3] = 7.0;
            b.as_ptr()
        };
        let b = Buf::<f32>::zeroed(500);
        assert_eq!(b.as_ptr(), ptr, "the allocation came back");
        assert!(b.iter().all(|v| *v == 0.0) && b.len() == 500);
    }
}
