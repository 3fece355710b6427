//! The names every part of the cycle shares — axis and group indices and the size of a group —
//! in a leaf module that imports nothing of the crate, so `command`, `event`, `records`,
//! `comparator` and `cycle` depend on it and not on each other.

/// Index of an axis in the machine (configuration order).
pub type AxisId = u16;
/// Index of a group in the machine (configuration order).
pub type GroupId = u16;
/// Axes in one group at most.
pub const MAX_GROUP_AXES: usize = 8;
