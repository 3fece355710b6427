//! The cycle on a microcontroller: the `mcu-scenario` machine run by RTIC 2 on a Cortex-M3
//! (QEMU's `mps2-an385`), printing over semihosting what the host's run of the same scenario
//! prints, so that the two can be compared cycle by cycle (`tests/tests/mcu.rs`).
//!
//! - `tick`, bound to SysTick (priority 3), runs every 2 ms of the board's clock: it takes the
//!   drives' answers to the previous cycle, runs the cycle step (`mcu_scenario::cycle_task`)
//!   and sends the frames to the drives' task; it hands the cycle's line to `idle`.
//! - `drive_side` (a software task, priority 2) plays the drives: the project's no_std simulators
//!   answer the frames (`mcu_scenario::drives_task`).
//! - `idle` prints each cycle's line: `C <cycle> <hash> <frames...>` (the frames as candump
//!   writes them, `ID#DATA`), then the outcome and the memory figures (`M name value`), then
//!   ends QEMU with the semihosting exit: success when the scenario reached its end.
//!
//! The two tasks talk through two heapless SPSC queues, as the cycle and the services do on
//! the host. The big values (the cycle, the record table, the simulated drives) live in
//! statics, written once in `init`.

#![no_std]
#![no_main]

mod device;
mod stack;

use core::sync::atomic::{AtomicBool, AtomicU8, AtomicU32, Ordering};

// The reset handler and the vector table of the core's exceptions (RTIC supplies `main`).
use cortex_m_rt as _;

use coordinator::cycle::BusFrame;
use mcu_scenario::controller::TX_CAPACITY;

/// SysTick ticks per cycle: the AN385's 25 MHz processor clock, 2 ms.
const TICKS_PER_CYCLE: u32 = 25_000_000 / 1_000_000 * (mcu_scenario::CYCLE_NS / 1_000);
/// Virtual nanoseconds per SysTick tick (25 MHz); with `-icount shift=0`, instructions.
const NS_PER_TICK: u32 = 40;
/// Lines `tick` may be ahead of `idle`'s printing.
const LINES: usize = 64;
/// Step costs kept for the median (one per cycle of the scenario).
const COSTS: usize = mcu_scenario::MAX_CYCLES as usize;

/// One cycle's line for `idle` to print.
#[derive(Clone, Debug)]
pub struct Line {
    cycle: u64,
    hash: u64,
    /// SysTick ticks the cycle step took.
    cost: u32,
    frames: heapless::Vec<BusFrame, TX_CAPACITY>,
}

/// The scenario ended (reached or failed); `tick` stops stepping.
static FINISHED: AtomicBool = AtomicBool::new(false);
/// 0 running, 1 reached its end, 2 failed; with the reason's text in `FAILURE`.
static OUTCOME: AtomicU8 = AtomicU8::new(0);
/// The most a command of the script cost, SysTick ticks.
static COMMAND_COST: AtomicU32 = AtomicU32::new(0);
/// The deepest the cycle's task went below its entry, bytes.
static TICK_STACK: AtomicU32 = AtomicU32::new(0);
/// A line could not be handed to `idle` (it fell behind by more than [`LINES`]).
static LOST_LINES: AtomicBool = AtomicBool::new(false);

#[rtic::app(device = crate::device, peripherals = false, dispatchers = [UARTRX0, UARTTX0])]
mod app {
    use core::mem::MaybeUninit;
    use core::sync::atomic::Ordering;

    use cortex_m::peripheral::SYST;
    use cortex_m::peripheral::syst::SystClkSource;
    use cortex_m_semihosting::debug;
    use heapless::spsc::{Consumer, Producer, Queue};
    use mcu_scenario::controller::{Controller, Phase, RecordTable, fill_record_table};
    use mcu_scenario::drives::Drives;
    use mcu_scenario::{Link, LinkQueue, cycle_task, drives_task};

    use super::*;

    #[shared]
    struct Shared {}

    #[local]
    struct Local {
        controller: &'static mut Controller<'static>,
        drives: &'static mut Drives,
        to_drives: Producer<'static, Link>,
        from_drives: Consumer<'static, Link>,
        from_cycle: Consumer<'static, Link>,
        to_cycle: Producer<'static, Link>,
        lines_in: Producer<'static, Line>,
        lines_out: Consumer<'static, Line>,
        stack_init: [u32; 2],
    }

    #[init(local = [
        table_mem: RecordTable = RecordTable::with_axes(2),
        controller_mem: MaybeUninit<Controller<'static>> = MaybeUninit::uninit(),
        drives_mem: MaybeUninit<Drives> = MaybeUninit::uninit(),
        down: LinkQueue = LinkQueue::new(),
        up: LinkQueue = LinkQueue::new(),
        lines: Queue<Line, LINES> = Queue::new(),
    ])]
    fn init(cx: init::Context) -> (Shared, Local) {
        // The stack building the core's values takes, then the simulators'.
        // Built in functions of their own, so that init's frame stays small and the paint
        // reaches up to where the tasks' stack begins.
        stack::paint();
        let controller = build_core(cx.local.table_mem, cx.local.controller_mem);
        let stack_core = stack::used();
        stack::paint();
        let drives = build_drives(cx.local.drives_mem);
        let stack_drives = stack::used();
        let (to_drives, from_cycle) = cx.local.down.split();
        let (to_cycle, from_drives) = cx.local.up.split();
        let (lines_in, lines_out) = cx.local.lines.split();
        // A fresh paint for the run's own figure.
        stack::paint();
        let mut syst = cx.core.SYST;
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(TICKS_PER_CYCLE - 1);
        syst.clear_current();
        syst.enable_interrupt();
        syst.enable_counter();
        (
            Shared {},
            Local {
                controller,
                drives,
                to_drives,
                from_drives,
                from_cycle,
                to_cycle,
                lines_in,
                lines_out,
                stack_init: [stack_core, stack_drives],
            },
        )
    }

    /// The record table and the controller (the cycle) in their statics.
    #[inline(never)]
    fn build_core(
        table: &'static mut RecordTable,
        controller: &'static mut MaybeUninit<Controller<'static>>,
    ) -> &'static mut Controller<'static> {
        // Filled where it lies: the 60 KB table never passes through the stack.
        fill_record_table(table);
        controller.write(Controller::new(table))
    }

    /// The simulated drives in their static.
    #[inline(never)]
    fn build_drives(drives: &'static mut MaybeUninit<Drives>) -> &'static mut Drives {
        drives.write(Drives::new())
    }

    /// The cycle, every SysTick.
    #[task(binds = SysTick, priority = 3, local = [controller, to_drives, from_drives, lines_in])]
    fn tick(cx: tick::Context) {
        if FINISHED.load(Ordering::Relaxed) {
            return;
        }
        let c = &mut **cx.local.controller;
        // SysTick counts down; the complement counts up within a period.
        let mut clock = || 0x00FF_FFFF - SYST::get_current();
        let sp = stack::paint_window();
        let (cycle, hash, cost) =
            cycle_task(c, cx.local.from_drives, cx.local.to_drives, &mut clock);
        let depth = stack::window_used(sp);
        TICK_STACK.fetch_max(depth, Ordering::Relaxed);
        let mut frames = heapless::Vec::new();
        let _ = frames.extend_from_slice(c.sent());
        if cx
            .local
            .lines_in
            .enqueue(Line {
                cycle,
                hash,
                cost,
                frames,
            })
            .is_err()
        {
            LOST_LINES.store(true, Ordering::Relaxed);
        }
        COMMAND_COST.store(c.command_cost(), Ordering::Relaxed);
        if c.finished() {
            let outcome = match c.phase() {
                Phase::Done => 1,
                Phase::Failed(f) => {
                    super::set_failure(f.text());
                    2
                }
                _ => 2,
            };
            OUTCOME.store(outcome, Ordering::Relaxed);
            FINISHED.store(true, Ordering::Release);
        } else if drive_side::spawn().is_err() {
            // Still running from the last cycle: the next tick finds its answer missing.
        }
    }

    /// The drives' side, once per cycle.
    #[task(priority = 2, local = [drives, from_cycle, to_cycle])]
    async fn drive_side(cx: drive_side::Context) {
        // An overflow shows as a missing end mark in the next tick (an overrun).
        let _ = drives_task(cx.local.drives, cx.local.from_cycle, cx.local.to_cycle);
    }

    /// Prints the lines, then the figures, then ends the run.
    #[idle(local = [lines_out, stack_init, costs: super::Costs = super::Costs::new()])]
    fn idle(cx: idle::Context) -> ! {
        let costs = cx.local.costs;
        loop {
            while let Some(line) = cx.local.lines_out.dequeue() {
                costs.add(line.cost);
                super::print_line(&line);
            }
            if FINISHED.load(Ordering::Acquire) && !cx.local.lines_out.ready() {
                break;
            }
            cortex_m::asm::wfi();
        }
        let ok = super::report(costs, *cx.local.stack_init);
        debug::exit(if ok {
            debug::EXIT_SUCCESS
        } else {
            debug::EXIT_FAILURE
        });
        loop {
            cortex_m::asm::wfi();
        }
    }
}

/// The failure's text, for the report.
static mut FAILURE: &str = "";

fn set_failure(text: &'static str) {
    // SAFETY: written once by `tick` before FINISHED is released, read by `idle` after.
    unsafe { FAILURE = text };
}

/// The step costs of the run, for min, median and max.
struct Costs {
    all: heapless::Vec<u32, COSTS>,
}

impl Costs {
    const fn new() -> Costs {
        Costs {
            all: heapless::Vec::new(),
        }
    }
    fn add(&mut self, ticks: u32) {
        let _ = self.all.push(ticks);
    }
    /// Min, median, max, in ticks.
    fn figures(&mut self) -> (u32, u32, u32) {
        self.all.sort_unstable();
        match (self.all.first(), self.all.last()) {
            (Some(&lo), Some(&hi)) => (lo, self.all[self.all.len() / 2], hi),
            _ => (0, 0, 0),
        }
    }
}

/// Writes to the host's standard output through semihosting.
fn out(s: &str) {
    use core::fmt::Write;
    if let Ok(mut o) = cortex_m_semihosting::hio::hstdout() {
        let _ = o.write_str(s);
    }
}

fn print_line(l: &Line) {
    use core::fmt::Write;
    let mut s: heapless::String<640> = heapless::String::new();
    let _ = write!(s, "C {} {:016x}", l.cycle, l.hash);
    for f in &l.frames {
        let _ = write!(s, " {}", f.frame);
    }
    let _ = s.push('\n');
    out(&s);
}

/// The outcome and the memory figures; whether the run succeeded.
fn report(costs: &mut Costs, stack_init: [u32; 2]) -> bool {
    use core::fmt::Write;
    use core::mem::size_of;
    let outcome = OUTCOME.load(Ordering::Relaxed);
    let lost = LOST_LINES.load(Ordering::Relaxed);
    let mut s: heapless::String<2048> = heapless::String::new();
    match outcome {
        1 if !lost => {
            let _ = writeln!(s, "DONE reached");
        }
        1 => {
            let _ = writeln!(s, "DONE failed: idle fell behind and lines were lost");
        }
        // SAFETY: see `set_failure`.
        _ => {
            let _ = writeln!(s, "DONE failed: {}", unsafe { FAILURE });
        }
    }
    let (lo, med, hi) = costs.figures();
    let m = |s: &mut heapless::String<2048>, k: &str, v: u64| {
        let _ = writeln!(s, "M {k} {v}");
    };
    m(&mut s, "cycles", costs.all.len() as u64);
    m(&mut s, "step_instructions_min", u64::from(lo * NS_PER_TICK));
    m(
        &mut s,
        "step_instructions_median",
        u64::from(med * NS_PER_TICK),
    );
    m(&mut s, "step_instructions_max", u64::from(hi * NS_PER_TICK));
    m(
        &mut s,
        "command_instructions_max",
        u64::from(COMMAND_COST.load(Ordering::Relaxed) * NS_PER_TICK),
    );
    m(
        &mut s,
        "size_cycle",
        size_of::<
            coordinator::cycle::Cycle<'static, { mcu_scenario::AXES }, { mcu_scenario::GROUPS }>,
        >() as u64,
    );
    m(
        &mut s,
        "size_controller",
        size_of::<mcu_scenario::controller::Controller<'static>>() as u64,
    );
    m(
        &mut s,
        "size_record_table",
        size_of::<mcu_scenario::controller::RecordTable>() as u64,
    );
    m(
        &mut s,
        "size_queues",
        2 * size_of::<mcu_scenario::LinkQueue>() as u64,
    );
    m(
        &mut s,
        "size_drives",
        size_of::<mcu_scenario::drives::Drives>() as u64,
    );
    let sec = stack::sections();
    m(&mut s, "ram_data", u64::from(sec.data));
    m(&mut s, "ram_bss", u64::from(sec.bss));
    m(&mut s, "ram_uninit", u64::from(sec.uninit));
    m(&mut s, "flash_text", u64::from(sec.text));
    m(&mut s, "flash_rodata", u64::from(sec.rodata));
    m(&mut s, "stack_init_core", u64::from(stack_init[0]));
    m(&mut s, "stack_init_drives", u64::from(stack_init[1]));
    m(&mut s, "stack_run", u64::from(stack::used()));
    m(
        &mut s,
        "stack_cycle_task",
        u64::from(TICK_STACK.load(Ordering::Relaxed)),
    );
    out(&s);
    outcome == 1 && !lost
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    use core::fmt::Write;
    let mut s: heapless::String<512> = heapless::String::new();
    let _ = writeln!(s, "DONE failed: panic: {}", info.message());
    out(&s);
    cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}
