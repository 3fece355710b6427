//! Host-side record tables and record chains per axis group, FHPP-style but across axes.
//!
//! (Types first; the chain runner lands with the records work.)

use crate::comparator::Window;

/// The most axes a group (and so a record) holds.
pub const MAX_GROUP_AXES: usize = 8;
/// Records per group table (numbers 0..RECORDS; 0 is a valid record here, unlike FHPP's homing 0).
pub const RECORDS: usize = 256;

/// Where one axis of a record goes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum AxisTarget {
    /// The axis stays where it is.
    #[default]
    Keep,
    /// To this position, increments.
    Absolute(i64),
    /// By this distance from where the record starts, increments.
    Relative(i64),
}

/// What a record commands.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum RecordMode {
    /// A time-synchronised group move to the targets (the default).
    #[default]
    Position,
    /// Run each axis at `velocity_percent` of its velocity limit, in the direction of the sign
    /// of its target (targets: `Relative(±1)`); the record's move never "arrives".
    Velocity,
    /// Push with `force_permille` (drives that offer force mode), toward the target.
    Force,
}

/// Which actual value a comparator condition watches.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Quantity {
    /// Actual position, increments.
    Position,
    /// Actual velocity, inc/s.
    Velocity,
    /// Actual force, ‰.
    Force,
}

/// Which edge of a digital input.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Edge {
    /// 0 → 1.
    Rising,
    /// 1 → 0.
    Falling,
}

/// When a chain steps from a record to its next (the FHPP step-enabling conditions, plus two
/// for cross-axis coordination).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum StepCondition {
    /// No chaining: the chain ends with this record (RCC at its MC).
    #[default]
    End,
    /// Motion complete: every axis of the group has arrived (and reports MC).
    Mc,
    /// At once, without waiting for MC (on the fly).
    Immediately,
    /// This long after MC, ms.
    Delay(u32),
    /// A comparator on one axis of the group: the value inside the window for its damping time.
    Comparator {
        /// The axis, as an index into the group.
        axis: u8,
        /// Which value.
        quantity: Quantity,
        /// The window (never met where min > max).
        window: Window,
    },
    /// Time since the record started, ms, in `[min, max]` (no damping).
    Time {
        /// Lowest, ms.
        min: u32,
        /// Highest, ms.
        max: u32,
    },
    /// A digital input edge (bit number of the machine's input word).
    Input {
        /// Bit 0..=31.
        bit: u8,
        /// Which edge.
        edge: Edge,
    },
    /// Another group's chain has reached (finished the motion of) a record.
    RecordReached {
        /// The other group's index.
        group: u8,
        /// Its record number.
        record: u16,
    },
}

/// A condition and where it leads.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Step {
    /// When to step.
    pub condition: StepCondition,
    /// The record to step to (ignored for [`StepCondition::End`]).
    pub next: u16,
}

/// One record of a group's table.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Record {
    /// Per axis of the group (index = position in the group).
    pub targets: [AxisTarget; MAX_GROUP_AXES],
    /// What the record does.
    pub mode: RecordMode,
    /// Share of each axis's velocity limit, 1..=100 %.
    pub velocity_percent: u8,
    /// Share of each axis's acceleration limit, 1..=100 %.
    pub acceleration_percent: u8,
    /// Share of each axis's jerk limit, 1..=100 % (S-curve groups).
    pub jerk_percent: u8,
    /// Force for [`RecordMode::Force`], ‰ of nominal.
    pub force_permille: i32,
    /// Delay before the record's motion starts, ms.
    pub delay_ms: u32,
    /// The step condition and the next record.
    pub step: Step,
    /// An alternative: if this condition is met first, step to its record instead (branching).
    pub alternative: Option<Step>,
    /// Whether MC is shown (the group's "record reached") when this record finishes inside a
    /// chain, as FHPP PNU 425; at the chain's end MC is always shown.
    pub mc_in_chain: bool,
}

impl Default for Record {
    fn default() -> Self {
        Record {
            targets: [AxisTarget::Keep; MAX_GROUP_AXES],
            mode: RecordMode::Position,
            velocity_percent: 100,
            acceleration_percent: 100,
            jerk_percent: 100,
            force_permille: 0,
            delay_ms: 0,
            step: Step::default(),
            alternative: None,
            mc_in_chain: true,
        }
    }
}
