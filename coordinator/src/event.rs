//! What the cycle tells the services: state changes, faults, chain completion. Queued by the
//! cycle (fixed capacity, no allocation) and taken by the non-real-time side, which reports
//! them (console, `motion/events`).

use crate::axis::AxisState;
use crate::fault::FaultReason;
use crate::ids::{AxisId, GroupId};

/// One event of the cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Event {
    /// The coordinator itself missed cycles (the host stalled it): supervision did not count
    /// them against the drives; the configured reaction was applied.
    Overrun {
        /// The first cycle after the stall.
        cycle: u64,
        /// Cycles skipped.
        skipped: u64,
        /// How long the coordinator was away, µs (the wake-up's lateness).
        late_us: u64,
    },
    /// An axis changed state.
    AxisState {
        /// The cycle.
        cycle: u64,
        /// The axis.
        axis: AxisId,
        /// Its new state.
        state: AxisState,
    },
    /// An axis faulted.
    Fault {
        /// The cycle in which it was detected (and the group reacted).
        cycle: u64,
        /// The axis.
        axis: AxisId,
        /// Why.
        reason: FaultReason,
    },
    /// An axis's fault was acknowledged.
    Acknowledged {
        /// The cycle.
        cycle: u64,
        /// The axis.
        axis: AxisId,
    },
    /// A group's chain reached a record (its motion finished).
    RecordReached {
        /// The cycle.
        cycle: u64,
        /// The group.
        group: GroupId,
        /// The record.
        record: u16,
    },
    /// A group's chain completed (RCC).
    ChainComplete {
        /// The cycle.
        cycle: u64,
        /// The group.
        group: GroupId,
        /// The last record.
        record: u16,
    },
    /// A group's chain was aborted (stop, fault, or a condition never met at MC).
    ChainAborted {
        /// The cycle.
        cycle: u64,
        /// The group.
        group: GroupId,
        /// The record it was at.
        record: u16,
    },
    /// The Modbus answer of an earlier cycle arrived late (and was used in this one).
    LateModbus {
        /// The cycle.
        cycle: u64,
        /// The axis.
        axis: AxisId,
        /// How many cycles late.
        cycles: u32,
    },
    /// A parameter-channel task ended: the value read or written, or the drive's error
    /// number (or 0xFFFF when no reply came in time).
    Parameter {
        /// The cycle.
        cycle: u64,
        /// The axis.
        axis: AxisId,
        /// The parameter number.
        pnu: u16,
        /// The sub-index.
        sub: u8,
        /// The value, or the error number.
        result: Result<u32, u16>,
    },
}

impl Event {
    /// The cycle the event happened in.
    pub fn cycle(&self) -> u64 {
        match *self {
            Event::Overrun { cycle, .. }
            | Event::AxisState { cycle, .. }
            | Event::Fault { cycle, .. }
            | Event::Acknowledged { cycle, .. }
            | Event::RecordReached { cycle, .. }
            | Event::ChainComplete { cycle, .. }
            | Event::ChainAborted { cycle, .. }
            | Event::LateModbus { cycle, .. }
            | Event::Parameter { cycle, .. } => cycle,
        }
    }
}

impl core::fmt::Display for Event {
    /// The event in words, axes and groups by number (the runtime, which knows their names,
    /// writes its own lines).
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            Event::Overrun {
                cycle,
                skipped,
                late_us,
            } => write!(
                f,
                "cycle {cycle}: overrun: the coordinator was away {}.{} ms ({skipped} cycle(s) \
                 skipped)",
                late_us / 1000,
                late_us % 1000 / 100
            ),
            Event::AxisState { cycle, axis, state } => {
                write!(f, "cycle {cycle}: axis {axis} {state}")
            }
            Event::Fault {
                cycle,
                axis,
                reason,
            } => write!(f, "cycle {cycle}: axis {axis} faulted: {reason}"),
            Event::Acknowledged { cycle, axis } => {
                write!(f, "cycle {cycle}: axis {axis}: fault acknowledged")
            }
            Event::RecordReached {
                cycle,
                group,
                record,
            } => write!(f, "cycle {cycle}: group {group} reached record {record}"),
            Event::ChainComplete {
                cycle,
                group,
                record,
            } => write!(
                f,
                "cycle {cycle}: group {group} chain complete at record {record}"
            ),
            Event::ChainAborted {
                cycle,
                group,
                record,
            } => write!(
                f,
                "cycle {cycle}: group {group} chain aborted at record {record}"
            ),
            Event::LateModbus {
                cycle,
                axis,
                cycles,
            } => write!(
                f,
                "cycle {cycle}: axis {axis}: Modbus answer {cycles} cycle(s) late"
            ),
            Event::Parameter {
                cycle,
                axis,
                pnu,
                sub,
                result,
            } => match result {
                Ok(v) => write!(f, "cycle {cycle}: axis {axis}: PNU {pnu}:{sub} = {v}"),
                Err(0xFFFF) => write!(f, "cycle {cycle}: axis {axis}: PNU {pnu}:{sub}: no reply"),
                Err(n) => write!(
                    f,
                    "cycle {cycle}: axis {axis}: PNU {pnu}:{sub} refused: error {n}"
                ),
            },
        }
    }
}
