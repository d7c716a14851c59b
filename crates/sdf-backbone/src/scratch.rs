//! Scratch buffers, reused across work items and steps: a training step needs tens of megabytes
//! of context per work item, and allocating it fresh each time costs page faults and zeroing of
//! fresh pages (measured ~15 % of a step). A [`Buf`] is taken from the process's pool of its
//! element type (of the asked length, the smallest pooled allocation that fits; zeroed, or as it
//! was for a pass that overwrites it: [`Buf::to_overwrite`]) and goes back to it when dropped,
//! whichever thread drops it, so the pool holds what the largest step had live at once and the
//! resident size stays flat after the first steps.
//!
//! The pool is shared by all threads on purpose: a work item's deferred records are made on a
//! worker and dropped by the thread that sums the batch. With one pool per thread they piled up
//! in the summing thread's pool (never reused there) while the workers allocated fresh ones —
//! measured, the resident size of the default run grew from 0.27 GB at 12 iterations to 0.45 GB
//! at 600 (regression test `scratch_buffers_dropped_on_another_thread_are_reused`).

use std::ops::{Deref, DerefMut};
use std::sync::Mutex;

/// Buffers of one element type, shared by all threads.
pub trait Pooled: Sized + 'static {
    /// Runs `f` on this element type's pool.
    fn with_pool<T>(f: impl FnOnce(&mut Vec<Vec<Self>>) -> T) -> T;
}

macro_rules! pooled {
    ($t:ty) => {
        impl Pooled for $t {
            fn with_pool<T>(f: impl FnOnce(&mut Vec<Vec<Self>>) -> T) -> T {
                static POOL: Mutex<Vec<Vec<$t>>> = Mutex::new(Vec::new());
                // A panic while the lock was held leaves only spare buffers behind: keep going.
                let mut pool = POOL.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
                f(&mut pool)
            }
        }
    };
}
pooled!(f32);
pooled!(f64);
pooled!(u32);

/// Empties the pools (every element type), returning their memory: call between phases whose
/// buffers differ in size (training, evaluation renders, meshing), so that the resident size is
/// the largest phase's, not their sum.
pub fn release_all() {
    f32::with_pool(Vec::clear);
    f64::with_pool(Vec::clear);
    u32::with_pool(Vec::clear);
}

/// What a [`Buf`] can hold.
pub trait Element: Pooled + Copy + Default {}
impl Element for f32 {}
impl Element for f64 {}
impl Element for u32 {}

/// A buffer from the pool (its first `len` values), returned to it when dropped. The allocation
/// keeps every value it ever held initialised (its vector's length only grows), so a buffer
/// taken again is zeroed once, or not at all ([`Buf::to_overwrite`]), never twice.
#[derive(Debug)]
pub struct Buf<R: Element> {
    values: Vec<R>,
    len: usize,
}

impl<R: Element> Buf<R> {
    /// `len` zeros, reusing a pooled allocation when one is large enough (the smallest such).
    pub fn zeroed(len: usize) -> Buf<R> {
        // Taken out of the lock before zeroing: threads do not wait on each other's memset.
        let mut values = Self::pooled(len);
        let held = values.len().min(len);
        values[..held].fill(R::default());
        if values.len() < len {
            values.resize(len, R::default());
        }
        Buf { values, len }
    }

    /// `len` values that the caller overwrites, every one, before it reads any: a pooled
    /// allocation keeps what it last held (no memset; only a part beyond all it ever held is
    /// zeroed, once in the allocation's life). For the outputs and contexts that a module's
    /// passes write in full ([`crate::Module::forward`], a product that does not accumulate):
    /// zeroing them was 6–13 % of a training step's and of a render's time.
    pub fn to_overwrite(len: usize) -> Buf<R> {
        let mut values = Self::pooled(len);
        if values.len() < len {
            values.resize(len, R::default());
        }
        Buf { values, len }
    }

    /// The smallest pooled allocation of at least `len` values (else any, else a new one), with
    /// what it held.
    fn pooled(len: usize) -> Vec<R> {
        R::with_pool(|pool| {
            let best = pool.iter().enumerate().filter(|(_, b)| b.capacity() >= len).min_by_key(|(_, b)| b.capacity()).map(|(i, _)| i);
            match best {
                Some(i) => pool.swap_remove(i),
                None => pool.pop().unwrap_or_default(),
            }
        })
    }

    /// The values, leaving this buffer empty (its allocation moves with them).
    pub fn take(&mut self) -> Buf<R> {
        Buf { values: std::mem::take(&mut self.values), len: std::mem::take(&mut self.len) }
    }

    /// The values, as a vector (the allocation leaves the pool for good).
    pub fn into_vec(mut self) -> Vec<R> {
        let mut values = std::mem::take(&mut self.values);
        values.truncate(self.len);
        values
    }
}

impl<R: Element> Drop for Buf<R> {
    fn drop(&mut self) {
        let v = std::mem::take(&mut self.values);
        if v.capacity() > 0 {
            R::with_pool(|pool| {
                // A few buffers per work item in flight is all a step uses.
                if pool.len() < 256 {
                    pool.push(v);
                }
            });
        }
    }
}

impl<R: Element> Deref for Buf<R> {
    type Target = [R];
    fn deref(&self) -> &[R] {
        &self.values[..self.len]
    }
}

impl<R: Element> DerefMut for Buf<R> {
    fn deref_mut(&mut self) -> &mut [R] {
        &mut self.values[..self.len]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    // The pools are process-wide and tests run in parallel: each test has an element type of
    // its own, which the library never pools.
    pooled!(u8);
    pooled!(u16);
    pooled!(i32);
    impl Element for u8 {}
    impl Element for u16 {}
    impl Element for i32 {}

    #[test]
    fn buffers_are_zeroed_and_reused() {
        let ptr = {
            let mut b = Buf::<u8>::zeroed(1000);
            b[3] = 7;
            b.as_ptr()
        };
        let b = Buf::<u8>::zeroed(500);
        assert_eq!(b.as_ptr(), ptr, "the allocation came back");
        assert!(b.iter().all(|v| *v == 0) && b.len() == 500);
    }

    #[test]
    fn a_buffer_to_overwrite_reuses_an_allocation_without_zeroing_it() {
        let ptr = {
            let mut b = Buf::<i32>::zeroed(1000);
            b.fill(9);
            b.as_ptr()
        };
        let b = Buf::<i32>::to_overwrite(600);
        assert_eq!((b.as_ptr(), b.len()), (ptr, 600), "the allocation came back, at the length asked");
        assert!(b.iter().all(|v| *v == 9), "what it held is left for the caller to overwrite");
        drop(b);
        // Longer than it was taken last: every value it held (never zeroed again).
        let longer = Buf::<i32>::to_overwrite(900);
        assert_eq!((longer.as_ptr(), longer.len()), (ptr, 900));
        assert!(longer.iter().all(|v| *v == 9));
        drop(longer);
        let zeroed = Buf::<i32>::zeroed(800);
        assert_eq!((zeroed.as_ptr(), zeroed.len()), (ptr, 800));
        assert!(zeroed.iter().all(|v| *v == 0));
        drop(zeroed);
        // Beyond what the allocation ever held: zeros there.
        let beyond = Buf::<i32>::to_overwrite(2000);
        assert!(beyond[..800].iter().all(|v| *v == 0) && beyond[800..1000].iter().all(|v| *v == 9) && beyond[1000..].iter().all(|v| *v == 0));
    }

    #[test]
    fn scratch_buffers_dropped_on_another_thread_are_reused() {
        // Made here, dropped on another thread (as a work item's record is dropped by the thread
        // that sums the batch): the next buffer made here is the same allocation.
        let b = Buf::<u16>::zeroed(1000);
        let ptr = b.as_ptr() as usize;
        std::thread::spawn(move || drop(b)).join().unwrap();
        let again = Buf::<u16>::zeroed(500);
        assert_eq!(again.as_ptr() as usize, ptr, "a buffer dropped on another thread went back to the shared pool");
    }
}
