//! The hand-over channels between the cycle thread and the threads around it: hand-written
//! lock-free code, kept in this crate of its own (no dependencies) so that it can be checked by
//! itself with miri (`cargo +nightly miri test -p handover`) and model-checked with loom
//! (`RUSTFLAGS="--cfg loom" cargo test -p handover --release`), as `.ci/run` does.
//!
//! - [`triple_buffer`]: a wait-free single-writer, single-reader "latest value" channel.
//!
//! ```
//! let (mut w, mut r) = handover::triple_buffer::triple_buffer(0u32);
//! w.publish(7);
//! assert_eq!(r.read(), (7, true));
//! assert_eq!(r.read(), (7, false));
//! ```

pub mod triple_buffer;

/// The primitives, from std or, in a `cfg(loom)` build, from loom (which then explores every
/// interleaving of the threads and checks every access to an [`sync::UnsafeCell`]).
pub(crate) mod sync {
    #[cfg(loom)]
    pub(crate) use loom::cell::UnsafeCell;
    #[cfg(loom)]
    pub(crate) use loom::sync::Arc;
    #[cfg(loom)]
    pub(crate) use loom::sync::atomic::{AtomicU8, Ordering};

    #[cfg(not(loom))]
    pub(crate) use std::sync::Arc;
    #[cfg(not(loom))]
    pub(crate) use std::sync::atomic::{AtomicU8, Ordering};

    /// std's `UnsafeCell` with loom's access API (`with`, `with_mut`), so the code is the same
    /// in both builds and loom sees every read and write of a slot.
    #[cfg(not(loom))]
    #[derive(Debug)]
    pub(crate) struct UnsafeCell<T>(core::cell::UnsafeCell<T>);

    #[cfg(not(loom))]
    impl<T> UnsafeCell<T> {
        pub(crate) const fn new(value: T) -> UnsafeCell<T> {
            UnsafeCell(core::cell::UnsafeCell::new(value))
        }

        pub(crate) fn with<R>(&self, f: impl FnOnce(*const T) -> R) -> R {
            f(self.0.get())
        }

        pub(crate) fn with_mut<R>(&self, f: impl FnOnce(*mut T) -> R) -> R {
            f(self.0.get())
        }
    }
}
