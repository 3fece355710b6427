//! Host-side record tables and record chains per axis group, FHPP-style but across axes.
//!
//! A group's [`RecordTable`] holds up to [`RECORDS`] records; its [`Chain`] runs them the way the
//! EMCA and CMMO-ST run their own tables (digests 001 §4.2 and 002 §3.3, mirrored by
//! `drivers::sim::records`), with the group's move in place of one axis's task:
//!
//! - [`Chain::start`] enters a record; its start delay runs first, then the chain asks the cycle
//!   to plan and start the record's group move ([`ChainAction::StartMotion`]).
//! - [`Chain::step`] is called once per cycle. It updates the record's comparators on this
//!   cycle's actual values (also during the start delay, so damping times count from the first
//!   cycle), then evaluates the step condition and the alternative. Conditions are evaluated from
//!   the cycle *after* the motion was started, so `motion_done` always refers to this record's
//!   move.
//! - The first met condition sets RC1 and enters its `next` record on the fly. When the primary
//!   condition and the alternative are met in the same cycle, the primary wins.
//! - When the move arrives (`motion_done` rises), the record is *reached*
//!   ([`ChainStatus::reached`], which other groups' [`StepCondition::RecordReached`] watch).
//!   [`ChainAction::Reached`] is emitted when MC is visible: per `mc_in_chain` inside the chain,
//!   always where the chain ends.
//! - A record with [`StepCondition::End`] ends the chain at its arrival: RCC
//!   ([`ChainAction::Complete`]). A record whose comparator or time condition was not met by its
//!   arrival aborts the chain (the drives' MC = 1, RCC = 0), unless its other condition can still
//!   come after MC (MC, a delay after MC, an input edge, another group's record): then the chain
//!   waits ([`ChainState::Waiting`]).
//!   A record with `End` and an alternative ends at its arrival unless the alternative was met
//!   first (or in that cycle).
//! - [`StepCondition::RecordReached`] is a level: it holds while the other group's `reached` is
//!   that record, which a (re)start of the other group clears. A record's time condition counts
//!   from the record's entry, its start delay included, as on the drives.
//! - Stop ([`Chain::abort`]) aborts; [`Chain::start`] restarts from any record at any time.
//!
//! Everything is `no_std`, allocation-free, and a `step` does a bounded amount of work (at most
//! one record change per call), so a loop of records that step immediately cannot spin.

use core::time::Duration;

use drivers::time::Instant;

use crate::comparator::{self, Comparator, Window};
use crate::event::Event;

pub use crate::comparator::{Edge, Quantity};
pub use crate::ids::MAX_GROUP_AXES;
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

/// Why a record cannot go into a table (each carries the numbers that explain it).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, thiserror::Error)]
pub enum RecordError {
    /// The record number is not below [`RECORDS`].
    #[error("record {record} is outside 0..={max}")]
    OutOfRange {
        /// The number.
        record: u16,
        /// The highest number.
        max: u16,
    },
    /// A share of a limit outside 1..=100 %.
    #[error("record {record}: {field} {value} % is outside 1..=100")]
    Percent {
        /// The record.
        record: u16,
        /// Which share: `"velocity"`, `"acceleration"` or `"jerk"`.
        field: &'static str,
        /// The value.
        value: u8,
    },
    /// A target on an axis index the group does not have.
    #[error("record {record}: a target for axis {axis}, the group has {axes}")]
    TargetAxis {
        /// The record.
        record: u16,
        /// The axis index.
        axis: u8,
        /// The group's size.
        axes: u8,
    },
    /// A comparator on an axis index the group does not have.
    #[error("record {record}: comparator on axis {axis}, the group has {axes}")]
    ComparatorAxis {
        /// The record.
        record: u16,
        /// The axis index.
        axis: u8,
        /// The group's size.
        axes: u8,
    },
    /// An input bit above 31.
    #[error("record {record}: input bit {bit} is outside 0..=31")]
    InputBit {
        /// The record.
        record: u16,
        /// The bit.
        bit: u8,
    },
    /// An alternative whose condition is [`StepCondition::End`] (it could never be taken).
    #[error("record {record}: the alternative has no condition")]
    AlternativeEnd {
        /// The record.
        record: u16,
    },
    /// The step's `next` names a record the table does not hold.
    #[error("record {record}: next record {next} is not in the table")]
    MissingNext {
        /// The record.
        record: u16,
        /// The missing record.
        next: u16,
    },
    /// The alternative's `next` names a record the table does not hold.
    #[error("record {record}: alternative record {next} is not in the table")]
    MissingAlternative {
        /// The record.
        record: u16,
        /// The missing record.
        next: u16,
    },
}

/// One group's record table: numbers `0..RECORDS`, each empty or a [`Record`].
///
/// About 45 KiB: build it once at start-up, boxed (`Box::new(RecordTable::new())`) or in a
/// static, and hand the cycle a reference. [`RecordTable::insert`] checks a record on its own;
/// [`RecordTable::validate`] checks the links between records once all are in (so records can
/// be inserted in any order).
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct RecordTable {
    axes: u8,
    records: [Option<Record>; RECORDS],
}

impl Default for RecordTable {
    fn default() -> Self {
        RecordTable::new()
    }
}

impl RecordTable {
    /// An empty table for a group of [`MAX_GROUP_AXES`] axes.
    pub const fn new() -> RecordTable {
        RecordTable::with_axes(MAX_GROUP_AXES as u8)
    }

    /// An empty table for a group of `axes` axes (clamped to [`MAX_GROUP_AXES`]): targets and
    /// comparators on higher axis indices are refused.
    pub const fn with_axes(axes: u8) -> RecordTable {
        let axes = if axes as usize > MAX_GROUP_AXES {
            MAX_GROUP_AXES as u8
        } else {
            axes
        };
        RecordTable {
            axes,
            records: [None; RECORDS],
        }
    }

    /// The group's size the table was made for.
    pub const fn axes(&self) -> u8 {
        self.axes
    }

    /// Puts `record` at `number` (replacing what was there) after checking it on its own: the
    /// number, the shares 1..=100 %, targets and comparators on the group's axes, input bits,
    /// an alternative with a condition. The links are checked by [`RecordTable::validate`].
    pub fn insert(&mut self, number: u16, record: Record) -> Result<(), RecordError> {
        self.check(number, &record)?;
        let slot = self
            .records
            .get_mut(usize::from(number))
            .ok_or(RecordError::OutOfRange {
                record: number,
                max: RECORDS as u16 - 1,
            })?;
        *slot = Some(record);
        Ok(())
    }

    /// Empties `number`; returns what was there.
    pub fn remove(&mut self, number: u16) -> Option<Record> {
        self.records.get_mut(usize::from(number))?.take()
    }

    /// The record at `number`, if any.
    pub fn get(&self, number: u16) -> Option<&Record> {
        self.records.get(usize::from(number))?.as_ref()
    }

    /// How many records the table holds.
    pub fn len(&self) -> usize {
        self.records.iter().filter(|r| r.is_some()).count()
    }

    /// Whether the table holds no record.
    pub fn is_empty(&self) -> bool {
        self.records.iter().all(Option::is_none)
    }

    /// The records in number order.
    pub fn iter(&self) -> impl Iterator<Item = (u16, &Record)> {
        self.records
            .iter()
            .enumerate()
            .filter_map(|(n, r)| Some((n as u16, r.as_ref()?)))
    }

    /// Checks that every step's `next` and every alternative's record exist (the first
    /// failure, in number order). Loops are allowed, as on the drives.
    pub fn validate(&self) -> Result<(), RecordError> {
        for (number, r) in self.iter() {
            if r.step.condition != StepCondition::End && self.get(r.step.next).is_none() {
                return Err(RecordError::MissingNext {
                    record: number,
                    next: r.step.next,
                });
            }
            if let Some(alt) = r.alternative
                && self.get(alt.next).is_none()
            {
                return Err(RecordError::MissingAlternative {
                    record: number,
                    next: alt.next,
                });
            }
        }
        Ok(())
    }

    fn check(&self, number: u16, r: &Record) -> Result<(), RecordError> {
        if usize::from(number) >= RECORDS {
            return Err(RecordError::OutOfRange {
                record: number,
                max: RECORDS as u16 - 1,
            });
        }
        for (field, value) in [
            ("velocity", r.velocity_percent),
            ("acceleration", r.acceleration_percent),
            ("jerk", r.jerk_percent),
        ] {
            if !(1..=100).contains(&value) {
                return Err(RecordError::Percent {
                    record: number,
                    field,
                    value,
                });
            }
        }
        if let Some(axis) = r
            .targets
            .iter()
            .enumerate()
            .skip(usize::from(self.axes))
            .find(|(_, t)| **t != AxisTarget::Keep)
            .map(|(i, _)| i as u8)
        {
            return Err(RecordError::TargetAxis {
                record: number,
                axis,
                axes: self.axes,
            });
        }
        if r.alternative
            .is_some_and(|a| a.condition == StepCondition::End)
        {
            return Err(RecordError::AlternativeEnd { record: number });
        }
        for step in core::iter::once(r.step).chain(r.alternative) {
            match step.condition {
                StepCondition::Comparator { axis, .. } if axis >= self.axes => {
                    return Err(RecordError::ComparatorAxis {
                        record: number,
                        axis,
                        axes: self.axes,
                    });
                }
                StepCondition::Input { bit, .. } if bit > 31 => {
                    return Err(RecordError::InputBit {
                        record: number,
                        bit,
                    });
                }
                _ => {}
            }
        }
        Ok(())
    }
}

/// Why [`Chain::start`] refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, thiserror::Error)]
pub enum ChainError {
    /// The table has no such record.
    #[error("record {0} is not in the table")]
    UnknownRecord(u16),
}

/// What one cycle hands [`Chain::step`]: the time, the group's actual values and the inputs the
/// conditions watch. Slices are in group order; a missing entry reads as "outside every window".
#[derive(Clone, Copy, Debug)]
pub struct ChainInputs<'a> {
    /// This cycle's time (its SYNC).
    pub now: Instant,
    /// This cycle's number.
    pub cycle: u64,
    /// The group's move has arrived and every axis reports MC. It must be about the move the
    /// last [`ChainAction::StartMotion`] started: false from the cycle after that order until
    /// the move arrives (in the order's own cycle it is ignored).
    pub motion_done: bool,
    /// Actual positions, increments.
    pub positions: &'a [i64],
    /// Actual velocities, inc/s.
    pub velocities: &'a [i64],
    /// Actual forces, ‰.
    pub forces: &'a [i32],
    /// The machine's digital input word this cycle.
    pub inputs: u32,
    /// The input word of the previous cycle (edges are between the two).
    pub previous_inputs: u32,
    /// Per group index: the record each group's chain last reached ([`ChainStatus::reached`]).
    pub reached: &'a [Option<u16>],
}

/// Why a chain was aborted.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum AbortReason {
    /// Stop (or a fault reaction) through [`Chain::abort`].
    Stopped,
    /// The record's motion finished before its comparator or time condition was met (the
    /// drives' MC = 1, RCC = 0).
    ConditionNotMet,
    /// A step led to this record, which the table does not hold (or the running record was
    /// removed).
    UnknownRecord(u16),
}

/// What the cycle must do or report after a [`Chain::step`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ChainAction {
    /// Plan and start this record's group move in this cycle (its start delay has elapsed).
    StartMotion {
        /// The record.
        record: u16,
    },
    /// The record's move arrived and MC is visible (per `mc_in_chain`, always at the end).
    Reached {
        /// The record.
        record: u16,
    },
    /// The chain ran to its end (RCC) at this record.
    Complete {
        /// The last record.
        record: u16,
    },
    /// The chain was aborted at this record.
    Aborted {
        /// The record it was at.
        record: u16,
        /// Why.
        reason: AbortReason,
    },
}

impl ChainAction {
    /// The event the cycle reports for this action of group `group` in `cycle`; `None` for
    /// [`ChainAction::StartMotion`], which is an order to the cycle, not news.
    pub const fn event(self, cycle: u64, group: crate::command::GroupId) -> Option<Event> {
        match self {
            ChainAction::StartMotion { .. } => None,
            ChainAction::Reached { record } => Some(Event::RecordReached {
                cycle,
                group,
                record,
            }),
            ChainAction::Complete { record } => Some(Event::ChainComplete {
                cycle,
                group,
                record,
            }),
            ChainAction::Aborted { record, .. } => Some(Event::ChainAborted {
                cycle,
                group,
                record,
            }),
        }
    }
}

/// The actions of one [`Chain::step`], in order. A step yields at most two (`Reached` then one
/// of `StartMotion`, `Complete`, `Aborted`); four leaves room without a failure path.
pub type ChainActions = heapless::Vec<ChainAction, 4>;

/// Where a chain is.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum ChainState {
    /// Never started.
    #[default]
    Idle,
    /// A record is entered and its start delay runs; its motion has not started.
    Delay,
    /// The record's move is running.
    Moving,
    /// The record's move arrived; the chain waits for a condition that can come after MC.
    Waiting,
    /// The chain ended at a record without a step condition (RCC).
    Complete,
    /// The chain was aborted.
    Aborted,
}

/// A chain's status (the FHPP RSB bits and byte 3, for a group).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct ChainStatus {
    /// The running record (in [`ChainState::Delay`], `Moving` or `Waiting`).
    pub active: Option<u16>,
    /// The record the chain is at or ended at (FHPP status byte 3); `None` before the first
    /// start.
    pub record: Option<u16>,
    /// RC1: a step condition was met since the chain started.
    pub rc1: bool,
    /// RCC: the chain ran to its end.
    pub rcc: bool,
    /// Where the chain is.
    pub state: ChainState,
    /// The last record whose move arrived since the chain started, whether or not MC was
    /// visible there (other groups' [`StepCondition::RecordReached`] watch it).
    pub reached: Option<u16>,
    /// When the chain entered its current state.
    pub since: Instant,
}

/// One group's record chain. `Copy`, no heap, a few hundred bytes.
///
/// In declared order, the comparators last: [`Chain::for_each_skipped`] leaves out the end of
/// the chain from them on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[repr(C)]
pub struct Chain {
    /// When the record was entered: the time base of its time condition and start delay.
    entered: Instant,
    since: Instant,
    /// When the record's move arrived.
    arrived: Option<Instant>,
    record: Option<u16>,
    reached: Option<u16>,
    state: ChainState,
    rc1: bool,
    rcc: bool,
    /// The comparators of the step condition and of the alternative (never active where the
    /// condition is not a comparator).
    comparators: [Comparator; 2],
}

/// Pushes onto a step's actions; a step pushes at most two, so the capacity of four is never
/// exceeded (a `debug_assert` keeps that honest in tests).
fn push(out: &mut ChainActions, action: ChainAction) {
    let pushed = out.push(action);
    debug_assert!(pushed.is_ok(), "a chain step yields at most two actions");
}

/// Whether a condition can still become true after the record's move arrived (so the chain
/// waits rather than aborts).
const fn lives_after_mc(c: StepCondition) -> bool {
    matches!(
        c,
        StepCondition::Mc
            | StepCondition::Delay(_)
            | StepCondition::Input { .. }
            | StepCondition::RecordReached { .. }
    )
}

impl Chain {
    /// An idle chain.
    pub const fn new() -> Chain {
        Chain {
            state: ChainState::Idle,
            record: None,
            entered: Instant::ZERO,
            arrived: None,
            comparators: [Comparator::new(Window::NEVER); 2],
            rc1: false,
            rcc: false,
            reached: None,
            since: Instant::ZERO,
        }
    }

    /// Starts (or restarts, from whatever state) the chain at `record` at `now`: RC1, RCC and
    /// `reached` clear; the record's start delay runs from `now`, and the first
    /// [`Chain::step`] at or after its end yields [`ChainAction::StartMotion`]. A running chain
    /// is replaced without an `Aborted` action (the caller asked for it).
    pub fn start(
        &mut self,
        table: &RecordTable,
        record: u16,
        now: Instant,
    ) -> Result<(), ChainError> {
        let r = table.get(record).ok_or(ChainError::UnknownRecord(record))?;
        self.rc1 = false;
        self.rcc = false;
        self.reached = None;
        self.enter(record, r, now);
        self.set_state(ChainState::Delay, now);
        Ok(())
    }

    /// Aborts a running chain (stop, fault reaction): returns the `Aborted` action to report,
    /// or `None` if no chain was running.
    pub fn abort(&mut self, now: Instant) -> Option<ChainAction> {
        self.abort_with(AbortReason::Stopped, now)
    }

    /// Aborts a running chain for `reason`; see [`Chain::abort`].
    pub fn abort_with(&mut self, reason: AbortReason, now: Instant) -> Option<ChainAction> {
        if !self.is_running() {
            return None;
        }
        self.rcc = false;
        self.set_state(ChainState::Aborted, now);
        Some(ChainAction::Aborted {
            record: self.record.unwrap_or_default(),
            reason,
        })
    }

    /// Whether a record is entered and not finished (delay, moving or waiting).
    pub const fn is_running(&self) -> bool {
        matches!(
            self.state,
            ChainState::Delay | ChainState::Moving | ChainState::Waiting
        )
    }

    /// The status.
    pub const fn status(&self) -> ChainStatus {
        ChainStatus {
            active: if self.is_running() { self.record } else { None },
            record: self.record,
            rc1: self.rc1,
            rcc: self.rcc,
            state: self.state,
            reached: self.reached,
            since: self.since,
        }
    }

    /// The part of the chain that its step does not read while no record runs (the
    /// comparators), handed to `f` as its first byte and its length, so that the cycle need
    /// not ask for it ahead of its step then.
    pub fn for_each_skipped(&self, f: &mut impl FnMut(*const u8, usize)) {
        if !self.is_running() {
            // From the comparators to the end of the chain (`repr(C)`: they come last).
            let from = core::mem::offset_of!(Chain, comparators);
            f(
                self.comparators.as_ptr().cast(),
                core::mem::size_of::<Chain>() - from,
            );
        }
    }

    /// Whether the running record's comparators (step condition, alternative) are active, as of
    /// the last step.
    pub const fn comparators_active(&self) -> [bool; 2] {
        [
            self.comparators[0].is_active(),
            self.comparators[1].is_active(),
        ]
    }

    /// One cycle; see the module documentation for the rules. Returns what the cycle must do
    /// (start the next record's move) and report (reached, complete, aborted), in order.
    pub fn step(&mut self, table: &RecordTable, inputs: &ChainInputs<'_>) -> ChainActions {
        let mut out = ChainActions::new();
        if !self.is_running() {
            return out;
        }
        let now = inputs.now;
        let number = self.record.unwrap_or_default();
        let Some(record) = table.get(number).copied() else {
            if let Some(a) = self.abort_with(AbortReason::UnknownRecord(number), now) {
                push(&mut out, a);
            }
            return out;
        };
        self.update_comparators(&record, inputs);

        if self.state == ChainState::Delay {
            let delay = Duration::from_millis(u64::from(record.delay_ms));
            if now.saturating_duration_since(self.entered) >= delay {
                push(&mut out, ChainAction::StartMotion { record: number });
                self.set_state(ChainState::Moving, now);
            }
            // Conditions wait for the next cycle, when `motion_done` is about this move.
            return out;
        }

        let arriving = inputs.motion_done && self.arrived.is_none();
        if arriving {
            self.arrived = Some(now);
            self.reached = Some(number);
        }
        let primary = self.met(&record.step, 0, inputs);
        let alternative = record.alternative.filter(|alt| self.met(alt, 1, inputs));
        let taken = if primary {
            Some(record.step.next)
        } else {
            alternative.map(|a| a.next)
        };
        let ends = taken.is_none()
            && self.arrived.is_some()
            && (record.step.condition == StepCondition::End
                || !(lives_after_mc(record.step.condition)
                    || record
                        .alternative
                        .is_some_and(|a| lives_after_mc(a.condition))));
        if arriving && (record.mc_in_chain || ends) {
            push(&mut out, ChainAction::Reached { record: number });
        }
        if let Some(next) = taken {
            self.rc1 = true;
            match table.get(next) {
                Some(r) => {
                    self.enter(next, r, now);
                    if r.delay_ms == 0 {
                        push(&mut out, ChainAction::StartMotion { record: next });
                        self.set_state(ChainState::Moving, now);
                    } else {
                        self.set_state(ChainState::Delay, now);
                    }
                }
                None => {
                    self.record = Some(next);
                    if let Some(a) = self.abort_with(AbortReason::UnknownRecord(next), now) {
                        push(&mut out, a);
                    }
                }
            }
        } else if ends {
            if record.step.condition == StepCondition::End {
                self.rcc = true;
                self.set_state(ChainState::Complete, now);
                push(&mut out, ChainAction::Complete { record: number });
            } else if let Some(a) = self.abort_with(AbortReason::ConditionNotMet, now) {
                push(&mut out, a);
            }
        } else if self.arrived.is_some() && self.state != ChainState::Waiting {
            self.set_state(ChainState::Waiting, now);
        }
        out
    }

    fn set_state(&mut self, state: ChainState, now: Instant) {
        if self.state != state {
            self.since = now;
        }
        self.state = state;
    }

    /// Makes `number` the running record: new time base, new comparators, not arrived.
    fn enter(&mut self, number: u16, r: &Record, now: Instant) {
        self.record = Some(number);
        self.entered = now;
        self.arrived = None;
        let window = |s: Option<Step>| match s.map(|s| s.condition) {
            Some(StepCondition::Comparator { window, .. }) => window,
            _ => Window::NEVER,
        };
        self.comparators = [
            Comparator::new(window(Some(r.step))),
            Comparator::new(window(r.alternative)),
        ];
    }

    fn update_comparators(&mut self, r: &Record, inputs: &ChainInputs<'_>) {
        for (c, step) in self
            .comparators
            .iter_mut()
            .zip([Some(r.step), r.alternative])
        {
            let Some(StepCondition::Comparator { axis, quantity, .. }) = step.map(|s| s.condition)
            else {
                continue;
            };
            match comparator::actual(
                quantity,
                usize::from(axis),
                inputs.positions,
                inputs.velocities,
                inputs.forces,
            ) {
                Some(v) => {
                    c.update(v, inputs.now);
                }
                // No value this cycle: outside the window, the damping restarts.
                None => c.reset(),
            }
        }
    }

    /// Whether `step`'s condition holds this cycle; `slot` is its comparator.
    fn met(&self, step: &Step, slot: usize, inputs: &ChainInputs<'_>) -> bool {
        match step.condition {
            StepCondition::End => false,
            StepCondition::Mc => self.arrived.is_some(),
            StepCondition::Immediately => true,
            StepCondition::Delay(ms) => self.arrived.is_some_and(|t| {
                inputs.now.saturating_duration_since(t) >= Duration::from_millis(u64::from(ms))
            }),
            StepCondition::Comparator { .. } => self
                .comparators
                .get(slot)
                .is_some_and(Comparator::is_active),
            StepCondition::Time { min, max } => comparator::in_time_window(
                inputs.now.saturating_duration_since(self.entered),
                min,
                max,
            ),
            StepCondition::Input { bit, edge } => {
                comparator::edge(inputs.previous_inputs, inputs.inputs, bit, edge)
            }
            StepCondition::RecordReached { group, record } => {
                inputs.reached.get(usize::from(group)).copied().flatten() == Some(record)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::boxed::Box;
    use std::vec::Vec;

    use ChainAction::{Aborted, Complete, Reached, StartMotion};

    const MS: Duration = Duration::from_millis(1);

    fn step(condition: StepCondition, next: u16) -> Step {
        Step { condition, next }
    }

    fn rec(condition: StepCondition, next: u16) -> Record {
        Record {
            targets: [
                AxisTarget::Absolute(1000),
                AxisTarget::Relative(-50),
                AxisTarget::Keep,
                AxisTarget::Keep,
                AxisTarget::Keep,
                AxisTarget::Keep,
                AxisTarget::Keep,
                AxisTarget::Keep,
            ],
            step: step(condition, next),
            ..Record::default()
        }
    }

    fn table(records: &[(u16, Record)]) -> Box<RecordTable> {
        let mut t = Box::new(RecordTable::with_axes(2));
        for &(n, r) in records {
            t.insert(n, r).unwrap();
        }
        t.validate().unwrap();
        t
    }

    fn position(axis: u8, min: i64, max: i64, damping_ms: u64) -> StepCondition {
        StepCondition::Comparator {
            axis,
            quantity: Quantity::Position,
            window: Window::new(min, max, Duration::from_millis(damping_ms)),
        }
    }

    #[test]
    fn an_idle_chain_leaves_out_its_comparators_and_a_running_one_nothing() {
        let t = table(&[
            (0, rec(StepCondition::End, 0)),
            (1, rec(position(0, 900, 1100, 0), 0)),
        ]);
        let mut c = Chain::new();
        let skipped = |c: &Chain| {
            let at = (c as *const Chain) as usize;
            let mut out = Vec::new();
            c.for_each_skipped(&mut |p, len| out.push((p as usize - at, len)));
            out
        };
        // The comparators to the end: everything the step does not read while idle.
        let from = core::mem::offset_of!(Chain, comparators);
        assert_eq!(skipped(&c), [(from, core::mem::size_of::<Chain>() - from)]);
        assert!(
            from <= 64,
            "the rest of the chain fits a line: {from} bytes"
        );
        c.start(&t, 1, Instant::ZERO).unwrap();
        assert_eq!(skipped(&c), []);
    }

    /// One group in virtual time: 1 ms cycles, scripted actual values and inputs.
    struct Rig {
        chain: Chain,
        table: Box<RecordTable>,
        cycle: u64,
        done: bool,
        positions: [i64; 2],
        velocities: [i64; 2],
        forces: [i32; 2],
        inputs: u32,
        previous: u32,
        reached: [Option<u16>; 2],
    }

    impl Rig {
        /// Started at record `first` at t = 0; the first `tick` is cycle 0 at t = 0.
        fn new(table: Box<RecordTable>, first: u16) -> Rig {
            let mut chain = Chain::new();
            chain.start(&table, first, Instant::ZERO).unwrap();
            Rig {
                chain,
                table,
                cycle: 0,
                done: false,
                positions: [0; 2],
                velocities: [0; 2],
                forces: [0; 2],
                inputs: 0,
                previous: 0,
                reached: [None; 2],
            }
        }

        fn now(&self) -> Instant {
            Instant::from_millis(self.cycle)
        }

        /// One cycle; a `StartMotion` clears `done` (the new move has not arrived).
        fn tick(&mut self) -> Vec<ChainAction> {
            let inputs = ChainInputs {
                now: self.now(),
                cycle: self.cycle,
                motion_done: self.done,
                positions: &self.positions,
                velocities: &self.velocities,
                forces: &self.forces,
                inputs: self.inputs,
                previous_inputs: self.previous,
                reached: &self.reached,
            };
            let out = self.chain.step(&self.table, &inputs);
            self.previous = self.inputs;
            self.cycle += 1;
            if out.iter().any(|a| matches!(a, StartMotion { .. })) {
                self.done = false;
            }
            out.to_vec()
        }

        /// Ticks until something happens (at most `limit` cycles); returns the cycle and what.
        fn until_action(&mut self, limit: u64) -> (u64, Vec<ChainAction>) {
            for _ in 0..limit {
                let c = self.cycle;
                let out = self.tick();
                if !out.is_empty() {
                    return (c, out);
                }
            }
            panic!("nothing happened within {limit} cycles");
        }

        fn state(&self) -> ChainState {
            self.chain.status().state
        }
    }

    #[test]
    fn mc_steps_in_the_arrival_cycle_and_the_last_record_completes() {
        let t = table(&[
            (0, rec(StepCondition::Mc, 1)),
            (1, rec(StepCondition::End, 0)),
        ]);
        let mut r = Rig::new(t, 0);
        assert_eq!(r.chain.status().active, Some(0));
        assert_eq!(r.state(), ChainState::Delay);
        assert_eq!(r.tick(), [StartMotion { record: 0 }]);
        assert_eq!(r.state(), ChainState::Moving);
        for _ in 1..5 {
            assert_eq!(r.tick(), []);
        }
        r.done = true;
        assert_eq!(r.tick(), [Reached { record: 0 }, StartMotion { record: 1 }]);
        let s = r.chain.status();
        assert!(s.rc1 && !s.rcc);
        assert_eq!((s.active, s.reached), (Some(1), Some(0)));
        assert_eq!(r.tick(), []);
        r.done = true;
        assert_eq!(
            r.until_action(5),
            (7, vec![Reached { record: 1 }, Complete { record: 1 }])
        );
        let s = r.chain.status();
        assert_eq!(s.state, ChainState::Complete);
        assert!(s.rc1 && s.rcc);
        assert_eq!((s.active, s.record, s.reached), (None, Some(1), Some(1)));
        assert_eq!(s.since, Instant::from_millis(7));
        // Nothing more happens once complete.
        assert_eq!(r.tick(), []);
    }

    #[test]
    fn motion_done_of_the_previous_move_is_ignored_in_the_start_cycle() {
        let t = table(&[
            (0, rec(StepCondition::Mc, 1)),
            (1, rec(StepCondition::End, 0)),
        ]);
        let mut r = Rig::new(t, 0);
        // The group still reports the previous move as arrived when the chain starts.
        r.done = true;
        let mut chain = r.chain;
        let inputs = ChainInputs {
            now: Instant::ZERO,
            cycle: 0,
            motion_done: true,
            positions: &[],
            velocities: &[],
            forces: &[],
            inputs: 0,
            previous_inputs: 0,
            reached: &[],
        };
        assert_eq!(
            chain.step(&r.table, &inputs).as_slice(),
            [StartMotion { record: 0 }]
        );
        assert_eq!(chain.status().reached, None);
    }

    #[test]
    fn start_delay_holds_the_motion_and_counts_in_the_time_base() {
        let mut first = rec(StepCondition::Time { min: 12, max: 14 }, 1);
        first.delay_ms = 10;
        let mut second = rec(StepCondition::End, 0);
        second.delay_ms = 3;
        let mut r = Rig::new(table(&[(0, first), (1, second)]), 0);
        assert_eq!(r.until_action(20), (10, vec![StartMotion { record: 0 }]));
        // The time window counts from the record's start (its delay included), as the drives.
        r.tick();
        assert_eq!(r.state(), ChainState::Moving);
        // Entering a record with a start delay is silent; its motion starts 3 ms later.
        assert_eq!(r.tick(), []);
        assert_eq!(r.state(), ChainState::Delay);
        assert!(r.chain.status().rc1);
        assert_eq!(r.chain.status().active, Some(1));
        assert_eq!(r.until_action(20), (15, vec![StartMotion { record: 1 }]));
    }

    #[test]
    fn immediately_steps_the_cycle_after_the_motion_started() {
        let t = table(&[
            (0, rec(StepCondition::Immediately, 1)),
            (1, rec(StepCondition::End, 0)),
        ]);
        let mut r = Rig::new(t, 0);
        assert_eq!(r.tick(), [StartMotion { record: 0 }]);
        assert_eq!(r.tick(), [StartMotion { record: 1 }]);
        assert!(r.chain.status().rc1);
        assert_eq!(r.chain.status().reached, None);
    }

    #[test]
    fn delay_after_mc_waits_then_steps() {
        let t = table(&[
            (0, rec(StepCondition::Delay(5), 1)),
            (1, rec(StepCondition::End, 0)),
        ]);
        let mut r = Rig::new(t, 0);
        r.tick();
        r.tick();
        r.done = true;
        assert_eq!(r.tick(), [Reached { record: 0 }]);
        assert_eq!(r.state(), ChainState::Waiting);
        assert_eq!(r.until_action(20), (7, vec![StartMotion { record: 1 }]));
    }

    #[test]
    fn comparators_step_on_the_fly_after_their_damping() {
        for quantity in [Quantity::Position, Quantity::Velocity, Quantity::Force] {
            let c = StepCondition::Comparator {
                axis: 1,
                quantity,
                window: Window::new(100, 200, 3 * MS),
            };
            let t = table(&[(0, rec(c, 1)), (1, rec(StepCondition::End, 0))]);
            let mut r = Rig::new(t, 0);
            r.tick();
            // Axis 1 ramps 40 per cycle: inside from cycle 3 (120); axis 0 is far outside.
            let mut fired = None;
            for _ in 1..20 {
                let v = 40 * r.cycle as i64;
                match quantity {
                    Quantity::Position => r.positions = [5000, v],
                    Quantity::Velocity => r.velocities = [5000, v.min(160)],
                    Quantity::Force => r.forces = [5000, v.min(160) as i32],
                }
                let c = r.cycle;
                if r.tick() == [StartMotion { record: 1 }] {
                    fired = Some(c);
                    break;
                }
            }
            // Inside at cycle 3 (120), held for 3 ms: active at cycle 6 (position leaves
            // the window at 240 after cycle 5, so it must be the damping that decides).
            match quantity {
                Quantity::Position => assert_eq!(fired, None, "left the window at cycle 6"),
                _ => assert_eq!(fired, Some(6), "{quantity:?}"),
            }
            assert_eq!(r.chain.status().reached, None);
        }
        // Position with a wider window fires after the damping.
        let c = position(1, 100, 1000, 3);
        let t = table(&[(0, rec(c, 1)), (1, rec(StepCondition::End, 0))]);
        let mut r = Rig::new(t, 0);
        r.tick();
        let mut fired = None;
        for _ in 1..20 {
            r.positions = [0, 40 * r.cycle as i64];
            let c = r.cycle;
            if !r.tick().is_empty() {
                fired = Some(c);
                break;
            }
        }
        assert_eq!(fired, Some(6));
        assert!(r.chain.status().rc1);
    }

    #[test]
    fn comparator_damping_restarts_and_counts_during_the_start_delay() {
        let mut first = rec(position(0, 10, 20, 4), 1);
        first.delay_ms = 3;
        let t = table(&[(0, first), (1, rec(StepCondition::End, 0))]);
        let mut r = Rig::new(t, 0);
        r.positions = [15, 0];
        // Inside from cycle 0; the motion starts at cycle 3; active at cycle 4.
        assert_eq!(r.until_action(10), (3, vec![StartMotion { record: 0 }]));
        assert_eq!(r.until_action(10), (4, vec![StartMotion { record: 1 }]));

        // Leaving the window restarts the damping.
        let t = table(&[
            (0, rec(position(0, 10, 20, 4), 1)),
            (1, rec(StepCondition::End, 0)),
        ]);
        let mut r = Rig::new(t, 0);
        for (c, p) in [
            (0, 15),
            (1, 15),
            (2, 15),
            (3, 25),
            (4, 15),
            (5, 15),
            (6, 15),
            (7, 15),
        ] {
            r.positions = [p, 0];
            assert_eq!(r.cycle, c);
            let out = r.tick();
            assert_eq!(out.is_empty(), c != 0, "cycle {c}: {out:?}");
        }
        r.positions = [15, 0];
        assert_eq!(r.tick(), [StartMotion { record: 1 }]);
        assert_eq!(r.cycle, 9);
    }

    #[test]
    fn input_edge_steps_once() {
        let edge_rec = rec(
            StepCondition::Input {
                bit: 3,
                edge: Edge::Rising,
            },
            1,
        );
        let t = table(&[(0, edge_rec), (1, rec(StepCondition::End, 0))]);
        let mut r = Rig::new(t, 0);
        r.inputs = 1 << 3; // already high at the start: no edge while it stays high
        r.tick();
        for _ in 0..4 {
            assert_eq!(r.tick(), []);
        }
        r.done = true;
        assert_eq!(r.tick(), [Reached { record: 0 }]);
        assert_eq!(r.state(), ChainState::Waiting);
        r.inputs = 0;
        assert_eq!(r.tick(), []);
        r.inputs = 1 << 3 | 1;
        assert_eq!(r.tick(), [StartMotion { record: 1 }]);

        // Falling edge.
        let fall = rec(
            StepCondition::Input {
                bit: 0,
                edge: Edge::Falling,
            },
            1,
        );
        let mut r = Rig::new(table(&[(0, fall), (1, rec(StepCondition::End, 0))]), 0);
        r.inputs = 1;
        r.tick();
        r.tick();
        r.inputs = 0;
        assert_eq!(r.until_action(3), (2, vec![StartMotion { record: 1 }]));
    }

    #[test]
    fn another_groups_record_reached_releases_the_chain() {
        // Group 0 "gantry" waits at record 1 for group 1 "lift" to reach its record 7.
        let gantry = table(&[
            (
                0,
                rec(
                    StepCondition::RecordReached {
                        group: 1,
                        record: 7,
                    },
                    1,
                ),
            ),
            (1, rec(StepCondition::End, 0)),
        ]);
        let lift = table(&[
            (6, rec(StepCondition::Mc, 7)),
            (7, rec(StepCondition::End, 0)),
        ]);
        let mut g = Rig::new(gantry, 0);
        let mut l = Rig::new(lift, 6);
        let mut released = None;
        for c in 0..30u64 {
            // The lift's moves take 5 cycles each.
            if c % 5 == 4 {
                l.done = true;
            }
            g.done = c >= 3;
            l.tick();
            let reached = [g.chain.status().reached, l.chain.status().reached];
            g.reached = reached;
            if g.tick().contains(&StartMotion { record: 1 }) {
                released = Some(c);
                break;
            }
        }
        // Lift: record 6 arrives at cycle 4, record 7 at cycle 9.
        assert_eq!(released, Some(9));
        assert_eq!(l.chain.status().state, ChainState::Complete);
    }

    #[test]
    fn branch_takes_the_condition_met_first_and_the_primary_on_a_tie() {
        let mut branch = rec(position(0, 100, 200, 0), 1);
        branch.alternative = Some(step(
            StepCondition::Input {
                bit: 2,
                edge: Edge::Rising,
            },
            2,
        ));
        let t = table(&[
            (0, branch),
            (1, rec(StepCondition::End, 0)),
            (2, rec(StepCondition::End, 0)),
        ]);
        // The input first: the alternative.
        let mut r = Rig::new(t.clone(), 0);
        r.tick();
        r.tick();
        r.inputs = 1 << 2;
        assert_eq!(r.tick(), [StartMotion { record: 2 }]);
        assert!(r.chain.status().rc1);
        // The comparator first: the primary.
        let mut r = Rig::new(t.clone(), 0);
        r.tick();
        r.positions = [150, 0];
        assert_eq!(r.tick(), [StartMotion { record: 1 }]);
        // Both in one cycle: the primary wins.
        let mut r = Rig::new(t, 0);
        r.tick();
        r.positions = [150, 0];
        r.inputs = 1 << 2;
        assert_eq!(r.tick(), [StartMotion { record: 1 }]);
    }

    #[test]
    fn a_comparator_never_met_by_mc_aborts_with_mc_and_without_rcc() {
        // min > max: never active, whatever the position.
        for window in [position(0, 100, 200, 0), position(0, 200, 100, 0)] {
            let t = table(&[(0, rec(window, 1)), (1, rec(StepCondition::End, 0))]);
            let mut r = Rig::new(t, 0);
            r.positions = [
                if window == position(0, 100, 200, 0) {
                    50
                } else {
                    150
                },
                0,
            ];
            r.tick();
            r.tick();
            r.done = true;
            assert_eq!(
                r.tick(),
                [
                    Reached { record: 0 },
                    Aborted {
                        record: 0,
                        reason: AbortReason::ConditionNotMet
                    }
                ]
            );
            let s = r.chain.status();
            assert_eq!(s.state, ChainState::Aborted);
            assert!(!s.rcc && !s.rc1);
            assert_eq!(s.reached, Some(0));
        }
        // Time windows too.
        let t = table(&[
            (0, rec(StepCondition::Time { min: 50, max: 60 }, 1)),
            (1, rec(StepCondition::End, 0)),
        ]);
        let mut r = Rig::new(t, 0);
        r.tick();
        r.done = true;
        assert!(r.tick().contains(&Aborted {
            record: 0,
            reason: AbortReason::ConditionNotMet
        }));
        // But a comparator met in the arrival cycle steps.
        let t = table(&[
            (0, rec(position(0, 100, 200, 0), 1)),
            (1, rec(StepCondition::End, 0)),
        ]);
        let mut r = Rig::new(t, 0);
        r.tick();
        r.done = true;
        r.positions = [150, 0];
        assert_eq!(r.tick(), [Reached { record: 0 }, StartMotion { record: 1 }]);
    }

    #[test]
    fn an_alternative_that_can_come_after_mc_keeps_the_chain_waiting() {
        let mut r0 = rec(position(0, 100, 200, 0), 1);
        r0.alternative = Some(step(StepCondition::Delay(4), 2));
        let t = table(&[
            (0, r0),
            (1, rec(StepCondition::End, 0)),
            (2, rec(StepCondition::End, 0)),
        ]);
        let mut r = Rig::new(t, 0);
        r.tick();
        r.done = true;
        assert_eq!(r.tick(), [Reached { record: 0 }]);
        assert_eq!(r.state(), ChainState::Waiting);
        // A timeout branch: the comparator did not come within 4 ms of MC.
        assert_eq!(r.until_action(10), (5, vec![StartMotion { record: 2 }]));
    }

    #[test]
    fn mc_in_chain_hides_intermediate_reached_but_not_the_end() {
        let mut hidden = rec(StepCondition::Mc, 1);
        hidden.mc_in_chain = false;
        let mut last = rec(StepCondition::End, 0);
        last.mc_in_chain = false;
        let mut r = Rig::new(table(&[(0, hidden), (1, last)]), 0);
        r.tick();
        r.done = true;
        assert_eq!(r.tick(), [StartMotion { record: 1 }]);
        // Still reached for the other groups.
        assert_eq!(r.chain.status().reached, Some(0));
        r.done = true;
        assert_eq!(r.tick(), [Reached { record: 1 }, Complete { record: 1 }]);
    }

    #[test]
    fn stop_aborts_and_a_restart_runs_from_any_record() {
        let t = table(&[
            (0, rec(StepCondition::Mc, 1)),
            (1, rec(StepCondition::Mc, 2)),
            (2, rec(StepCondition::End, 0)),
        ]);
        let mut r = Rig::new(t, 0);
        r.tick();
        r.done = true;
        r.tick();
        assert_eq!(
            r.chain.abort(r.now()),
            Some(Aborted {
                record: 1,
                reason: AbortReason::Stopped
            })
        );
        let s = r.chain.status();
        assert_eq!(
            (s.state, s.active, s.record, s.rc1, s.rcc),
            (ChainState::Aborted, None, Some(1), true, false)
        );
        r.done = true;
        assert_eq!(r.tick(), []);
        assert_eq!(r.chain.abort(r.now()), None);
        // Restart in the middle: RC1 and reached clear.
        r.chain.start(&r.table, 2, r.now()).unwrap();
        let s = r.chain.status();
        assert_eq!(
            (s.state, s.active, s.rc1, s.reached),
            (ChainState::Delay, Some(2), false, None)
        );
        assert_eq!(r.tick(), [StartMotion { record: 2 }]);
        // Restart while running, and a refused start leaves the chain as it was.
        r.chain.start(&r.table, 0, r.now()).unwrap();
        assert_eq!(
            r.chain.start(&r.table, 9, r.now()),
            Err(ChainError::UnknownRecord(9))
        );
        assert_eq!(r.chain.status().active, Some(0));
        assert_eq!(r.tick(), [StartMotion { record: 0 }]);
        // Idle chains never act.
        let mut idle = Chain::new();
        assert!(idle.abort(Instant::ZERO).is_none());
    }

    #[test]
    fn a_missing_record_at_run_time_aborts() {
        let mut t = table(&[
            (0, rec(StepCondition::Mc, 1)),
            (1, rec(StepCondition::End, 0)),
        ]);
        let mut r = Rig::new(t.clone(), 0);
        r.tick();
        t.remove(1);
        r.table = t.clone();
        r.done = true;
        assert_eq!(
            r.tick(),
            [
                Reached { record: 0 },
                Aborted {
                    record: 1,
                    reason: AbortReason::UnknownRecord(1)
                }
            ]
        );
        assert!(r.chain.status().rc1);
        // The running record removed.
        let mut r = Rig::new(t.clone(), 0);
        t.remove(0);
        r.table = t;
        assert_eq!(
            r.tick(),
            [Aborted {
                record: 0,
                reason: AbortReason::UnknownRecord(0)
            }]
        );
    }

    #[test]
    fn a_full_table_loops_and_each_step_does_bounded_work() {
        let mut t = Box::new(RecordTable::with_axes(2));
        for n in 0..RECORDS as u16 {
            let next = (n + 1) % RECORDS as u16;
            t.insert(n, rec(StepCondition::Immediately, next)).unwrap();
        }
        assert_eq!(t.len(), RECORDS);
        t.validate().unwrap();
        assert_eq!(
            t.insert(256, Record::default()),
            Err(RecordError::OutOfRange {
                record: 256,
                max: 255
            })
        );
        let mut r = Rig::new(t, 250);
        // One record per cycle, wrapping from 255 to 0: the loop never spins within a step.
        let mut seen = Vec::new();
        for _ in 0..12 {
            let out = r.tick();
            assert_eq!(out.len(), 1);
            if let [StartMotion { record }] = out.as_slice() {
                seen.push(*record);
            }
        }
        assert_eq!(seen, [250, 251, 252, 253, 254, 255, 0, 1, 2, 3, 4, 5]);
    }

    #[test]
    fn a_loop_of_mc_records_runs_round() {
        let t = table(&[
            (3, rec(StepCondition::Mc, 4)),
            (4, rec(StepCondition::Mc, 3)),
        ]);
        let mut r = Rig::new(t, 3);
        let mut starts = Vec::new();
        for c in 0..40 {
            if c % 4 == 3 {
                r.done = true;
            }
            for a in r.tick() {
                if let StartMotion { record } = a {
                    starts.push(record);
                }
            }
        }
        assert_eq!(starts.len(), 11);
        assert!(
            starts
                .chunks(2)
                .all(|p| p[0] == 3 && p.get(1).is_none_or(|&x| x == 4))
        );
        assert!(r.chain.is_running());
    }

    #[test]
    fn actions_map_to_the_cycles_events() {
        assert_eq!(StartMotion { record: 3 }.event(9, 1), None);
        assert_eq!(
            Reached { record: 3 }.event(9, 1),
            Some(Event::RecordReached {
                cycle: 9,
                group: 1,
                record: 3
            })
        );
        assert_eq!(
            Complete { record: 4 }.event(10, 0),
            Some(Event::ChainComplete {
                cycle: 10,
                group: 0,
                record: 4
            })
        );
        let aborted = Aborted {
            record: 5,
            reason: AbortReason::Stopped,
        };
        assert_eq!(
            aborted.event(11, 2),
            Some(Event::ChainAborted {
                cycle: 11,
                group: 2,
                record: 5
            })
        );
    }

    #[test]
    fn bad_records_are_refused_with_their_numbers() {
        let mut t = RecordTable::with_axes(2);
        let mut r = Record {
            velocity_percent: 0,
            ..Record::default()
        };
        assert_eq!(
            t.insert(5, r),
            Err(RecordError::Percent {
                record: 5,
                field: "velocity",
                value: 0
            })
        );
        r.velocity_percent = 100;
        r.jerk_percent = 101;
        assert_eq!(
            t.insert(5, r),
            Err(RecordError::Percent {
                record: 5,
                field: "jerk",
                value: 101
            })
        );
        let mut r = Record::default();
        r.targets[2] = AxisTarget::Absolute(1);
        assert_eq!(
            t.insert(1, r),
            Err(RecordError::TargetAxis {
                record: 1,
                axis: 2,
                axes: 2
            })
        );
        let r = rec(position(2, 0, 1, 0), 0);
        assert_eq!(
            t.insert(1, r),
            Err(RecordError::ComparatorAxis {
                record: 1,
                axis: 2,
                axes: 2
            })
        );
        let mut r = rec(StepCondition::Mc, 0);
        r.alternative = Some(step(
            StepCondition::Input {
                bit: 32,
                edge: Edge::Rising,
            },
            0,
        ));
        assert_eq!(
            t.insert(1, r),
            Err(RecordError::InputBit { record: 1, bit: 32 })
        );
        r.alternative = Some(step(StepCondition::End, 0));
        assert_eq!(
            t.insert(1, r),
            Err(RecordError::AlternativeEnd { record: 1 })
        );
        assert!(t.is_empty());
        t.insert(1, rec(StepCondition::Mc, 2)).unwrap();
        assert_eq!(
            t.validate(),
            Err(RecordError::MissingNext { record: 1, next: 2 })
        );
        let mut r2 = rec(StepCondition::End, 77);
        r2.alternative = Some(step(StepCondition::Mc, 9));
        t.insert(2, r2).unwrap();
        assert_eq!(
            t.validate(),
            Err(RecordError::MissingAlternative { record: 2, next: 9 })
        );
        t.insert(9, rec(StepCondition::End, 0)).unwrap();
        // An End record's `next` is ignored.
        assert_eq!(t.validate(), Ok(()));
        assert_eq!(t.iter().map(|(n, _)| n).collect::<Vec<_>>(), [1, 2, 9]);
        assert_eq!(RecordTable::with_axes(40).axes(), MAX_GROUP_AXES as u8);
    }

    fn any_condition() -> impl Strategy<Value = StepCondition> {
        prop_oneof![
            Just(StepCondition::End),
            Just(StepCondition::Mc),
            Just(StepCondition::Immediately),
            (0u32..20).prop_map(StepCondition::Delay),
            (0u8..4, 0u8..3, -50i64..50, -50i64..50, 0u64..5).prop_map(|(axis, q, min, max, d)| {
                StepCondition::Comparator {
                    axis,
                    quantity: [Quantity::Position, Quantity::Velocity, Quantity::Force]
                        [usize::from(q)],
                    window: Window::new(min, max, Duration::from_millis(d)),
                }
            }),
            (0u32..30, 0u32..30).prop_map(|(min, max)| StepCondition::Time { min, max }),
            (0u8..40, any::<bool>()).prop_map(|(bit, rising)| StepCondition::Input {
                bit,
                edge: if rising { Edge::Rising } else { Edge::Falling }
            }),
            (0u8..4, 0u16..8)
                .prop_map(|(group, record)| StepCondition::RecordReached { group, record }),
        ]
    }

    proptest! {
        #[test]
        fn step_never_panics_and_keeps_its_invariants(
            records in proptest::collection::vec(
                (0u16..8, any_condition(), 0u16..10, proptest::option::of((any_condition(), 0u16..10)), 0u32..5, any::<bool>()),
                1..10,
            ),
            first in 0u16..8,
            cycles in proptest::collection::vec(
                (any::<bool>(), proptest::collection::vec(-60i64..60, 0..4), any::<u32>(), proptest::option::of(0u16..8), 0u64..3, any::<bool>()),
                1..80,
            ),
        ) {
            // Unvalidated tables on purpose: dangling links must abort, not panic.
            let mut t = Box::new(RecordTable::with_axes(4));
            for (n, c, next, alt, delay, mc) in records {
                let mut r = rec(c, next);
                r.alternative = alt.map(|(c, n)| step(c, n));
                r.delay_ms = delay;
                r.mc_in_chain = mc;
                let _ = t.insert(n, r);
            }
            let mut chain = Chain::new();
            let _ = chain.start(&t, first, Instant::ZERO);
            let (mut now, mut previous) = (Instant::ZERO, 0u32);
            for (cycle, (done, values, inputs, reached, dt, stop)) in cycles.into_iter().enumerate() {
                now += Duration::from_millis(dt);
                let forces: Vec<i32> = values.iter().map(|&v| v as i32).collect();
                let reached = [reached, None];
                let i = ChainInputs {
                    now,
                    cycle: cycle as u64,
                    motion_done: done,
                    positions: &values,
                    velocities: &values,
                    forces: &forces,
                    inputs,
                    previous_inputs: previous,
                    reached: &reached,
                };
                previous = inputs;
                let before = chain.status();
                let out = chain.step(&t, &i);
                prop_assert!(out.len() <= 2);
                let s = chain.status();
                if !matches!(before.state, ChainState::Delay | ChainState::Moving | ChainState::Waiting) {
                    prop_assert!(out.is_empty());
                }
                prop_assert_eq!(s.rcc, s.state == ChainState::Complete);
                prop_assert_eq!(s.active.is_some(), chain.is_running());
                if stop {
                    let a = chain.abort(now);
                    prop_assert_eq!(a.is_some(), s.active.is_some());
                }
            }
        }
    }
}
