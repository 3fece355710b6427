//! One machine scenario through the `no_std` core, run alike on the host and on a
//! microcontroller (the `mcu/` application on QEMU), so that "the same scenario through the
//! same core" is one piece of code.
//!
//! - The machine ([`controller`]): two axes (x an MTR-DCI, y an EMCA, FHPP over CANopen on one
//!   bus, node guarding), one group, a record chain whose first step is a comparator; the
//!   commissioning a boot would do (SDO writes, NMT start); the script: enable, home, a
//!   synchronised two-axis move, the chain, to its end.
//! - The drives' side ([`drives`]): the project's no_std simulators fed the frames sent.
//! - The hash ([`hash`]): FNV-1a 64 over each cycle's frames and published states, fixed byte
//!   order, the same on every platform.
//!
//! The two sides are two tasks joined by two heapless SPSC queues of [`Link`]s, as the cycle
//! and its services are on the host: [`cycle_task`] (the timer's task on the microcontroller)
//! and [`drives_task`] (a lower-priority task there). [`run`] runs both in turn on one thread.
//!
//! ```
//! let table = mcu_scenario::controller::record_table();
//! let mut hashes = 0;
//! let outcome = mcu_scenario::run(&table, &mut |_, _, _| hashes += 1);
//! assert_eq!(outcome, mcu_scenario::controller::Phase::Done);
//! assert!(hashes > 100);
//! ```

#![no_std]

pub mod controller;
pub mod drives;
pub mod hash;

use coordinator::cycle::BusFrame;
use drivers::time::Instant;
use heapless::spsc::{Consumer, Producer, Queue};

use controller::{Controller, Failure, Phase};
use drives::Drives;

/// Axes of the machine.
pub const AXES: usize = 2;
/// Groups of the machine.
pub const GROUPS: usize = 1;
/// The one CAN bus.
pub const BUS: u8 = 0;
/// The MTR-DCI's node-ID.
pub const X_NODE: u8 = 1;
/// The EMCA's node-ID.
pub const Y_NODE: u8 = 2;
/// The cycle period, ns (the embedded example machine's 2 ms).
pub const CYCLE_NS: u32 = 2_000_000;
/// The scenario fails if it has not ended after this many cycles (60 s of machine time).
pub const MAX_CYCLES: u64 = 30_000;
/// Capacity of each queue between the tasks (a cycle's frames and its end mark).
pub const QUEUE: usize = 64;

/// What travels between the cycle's task and the drives' task.
#[derive(Clone, Copy, Debug)]
pub enum Link {
    /// A frame on the bus (stamped with the instant it was sent).
    Frame(BusFrame),
    /// The end of a cycle's frames; the drives' answer to it ends with one too.
    End(Instant),
}

/// The queue from one task to the other.
pub type LinkQueue = Queue<Link, QUEUE>;

/// The cycle's task, once per period: takes what the drives answered to the previous cycle
/// (all of it, up to its end mark: missing it is an overrun), runs [`Controller::step`], and
/// sends the cycle's frames and the end mark to the drives. Returns the cycle's number, hash
/// and step cost (the difference of `clock` around [`coordinator::cycle::Cycle::step`]).
pub fn cycle_task(
    c: &mut Controller<'_>,
    from_drives: &mut Consumer<'_, Link>,
    to_drives: &mut Producer<'_, Link>,
    clock: &mut impl FnMut() -> u32,
) -> (u64, u64, u32) {
    let first = c.cycle().cycle() == 0;
    let mut ended = first;
    while let Some(m) = from_drives.dequeue() {
        match m {
            Link::Frame(f) => c.receive(f),
            Link::End(_) => {
                ended = true;
                break;
            }
        }
    }
    if !ended {
        c.fail(Failure::Overrun);
    }
    let now = c.now();
    let out = c.step(clock);
    let mut ok = true;
    for f in c.sent() {
        let f = BusFrame::new(f.bus, f.frame.with_timestamp(now));
        ok &= to_drives.enqueue(Link::Frame(f)).is_ok();
    }
    ok &= to_drives.enqueue(Link::End(now)).is_ok();
    if !ok {
        c.fail(Failure::Overflow);
    }
    out
}

/// The drives' task, once per cycle: every frame the cycle sent, delivered at its instant, up
/// to the end mark; then the drives run until the next SYNC and their frames and an end mark
/// go back. Returns `false` when a queue overflowed (the cycle's task then misses the mark).
pub fn drives_task(
    d: &mut Drives,
    from_cycle: &mut Consumer<'_, Link>,
    to_cycle: &mut Producer<'_, Link>,
) -> bool {
    let mut ok = true;
    while let Some(m) = from_cycle.dequeue() {
        match m {
            Link::Frame(f) => d.receive(&f, f.frame.timestamp()),
            Link::End(now) => {
                let until = now + core::time::Duration::from_nanos(u64::from(CYCLE_NS));
                d.run(now, until, &mut |f| {
                    ok &= to_cycle.enqueue(Link::Frame(f)).is_ok();
                });
                ok &= to_cycle.enqueue(Link::End(now)).is_ok();
                break;
            }
        }
    }
    ok
}

/// The whole scenario on one thread: the cycle's task and the drives' task in turn, through
/// the same queues, until the scenario ends. `each` gets every cycle's number, hash and the
/// frames it sent. Returns the phase it ended in ([`Phase::Done`] or [`Phase::Failed`]).
pub fn run(table: &controller::RecordTable, each: &mut impl FnMut(u64, u64, &[BusFrame])) -> Phase {
    let mut c = Controller::new(table);
    let mut d = Drives::new();
    let mut down = LinkQueue::new();
    let mut up = LinkQueue::new();
    let (mut to_drives, mut from_cycle) = down.split();
    let (mut to_cycle, mut from_drives) = up.split();
    loop {
        let (n, h, _) = cycle_task(&mut c, &mut from_drives, &mut to_drives, &mut || 0);
        each(n, h, c.sent());
        if c.finished() {
            return c.phase();
        }
        if !drives_task(&mut d, &mut from_cycle, &mut to_cycle) {
            c.fail(Failure::Overflow);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use coordinator::axis::AxisState;

    /// The scenario runs to its end: commissioned, enabled, homed, the group's move and the
    /// chain done, no fault, both axes standing where the chain ends.
    #[test]
    fn the_scenario_reaches_its_end() {
        let table = controller::record_table();
        let mut cycles = 0u64;
        let phase = run(&table, &mut |_, _, _| cycles += 1);
        assert_eq!(
            phase.name(),
            "done",
            "ended in {}",
            match phase {
                Phase::Failed(f) => f.text(),
                p => p.name(),
            }
        );
        // Run it again to look at the end state (`run` keeps nothing).
        let mut c = Controller::new(&table);
        let mut d = Drives::new();
        let mut down = LinkQueue::new();
        let mut up = LinkQueue::new();
        let (mut td, mut fc) = down.split();
        let (mut tc, mut fd) = up.split();
        while !c.finished() {
            cycle_task(&mut c, &mut fd, &mut td, &mut || 0);
            drives_task(&mut d, &mut fc, &mut tc);
        }
        assert_eq!(c.phase(), Phase::Done);
        assert_eq!(c.end_cycle() + 1, cycles);
        for (a, end) in controller::CHAIN_END.iter().enumerate() {
            let s = c.cycle().axis_status(a as u16).unwrap();
            assert_eq!(s.feedback.state, AxisState::Ready);
            assert!(s.feedback.homed);
            assert!(
                (s.feedback.position - end).abs() <= 2,
                "axis {a} at {}",
                s.feedback.position
            );
        }
        let g = c.cycle().group_status(0).unwrap();
        assert!(g.chain.rcc);
        assert_eq!(g.chain.record, Some(12));
    }
}
