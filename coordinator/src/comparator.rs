//! Comparators: a window `[min, max]` held for a damping time, never active where `min > max`.
//! The semantics are the drives' (`drivers::sim::comparator`, EMCA/CMMO-ST): one truth, used by
//! the simulated drives and by the coordinator's host-side chains.

pub use drivers::sim::comparator::{Comparator, Window};
