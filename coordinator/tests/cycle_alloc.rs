//! The cycle allocates nothing after start-up: a counting global allocator counts every
//! allocation made on the cycle's thread between the probe's `true` and `false` (the script's
//! commands and the cycle step of each cycle), over boot, enable, homing and group moves, at 1
//! and at 64 axes.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::time::Duration;

use coordinator::command::{BufferMode, Command, GroupId, Reply};
use coordinator::config::Config;
use coordinator::records::MAX_GROUP_AXES;
use coordinator::runtime::plan::plan;
use coordinator::runtime::script::Phase;
use coordinator::runtime::synthetic;
use coordinator::runtime::virtual_clock::VirtualRun;

struct Counting;

// Per thread, so that tests running in parallel do not see each other's allocations.
thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

fn count() {
    if COUNTING.with(|c| c.get()) {
        ALLOCATIONS.with(|a| a.set(a.get() + 1));
    }
}

fn allocations() -> u64 {
    ALLOCATIONS.with(|a| a.get())
}

// SAFETY: every call is forwarded to the system allocator unchanged; the counter only observes.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: the caller's contract for `alloc` is passed on as is.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `System.alloc` with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: the caller's contract for `realloc` is passed on as is.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn probe(on: bool) {
    COUNTING.with(|c| c.set(on));
}

fn allocations_in_the_cycle(axes: usize) -> (u64, u64) {
    allocations_in(axes, None)
}

/// As [`allocations_in_the_cycle`], recording into `record` (the recorder's work on the cycle
/// thread is probed too).
fn allocations_in(axes: usize, record: Option<&std::path::Path>) -> (u64, u64) {
    let text = synthetic::config(axes, 8);
    let cfg = Config::parse(&text).expect("synthetic config parses");
    let plan = plan(&cfg).expect("synthetic machine plans");
    let mut opts = synthetic::demo_options(false);
    opts.record = record.map(|p| coordinator::runtime::run::RecordTo {
        path: p.to_path_buf(),
        config: text.clone(),
    });
    let mut run = VirtualRun::new(&plan, &opts).unwrap();
    run.lp.probe = Some(probe);
    let before = allocations();
    let mut out = Vec::new();
    while run.lp.script.phase() != Phase::Running {
        run.step(&mut out);
        assert!(
            run.elapsed() < Duration::from_secs(120),
            "{}",
            String::from_utf8_lossy(&out)
        );
    }
    for a in 0..plan.axes.len() {
        let s = run.stepper.cycle.axis_status(a as u16).unwrap();
        assert_eq!(
            s.mode,
            coordinator::cycle::AxisMode::On,
            "axis {a}: {s:?}\n{}",
            String::from_utf8_lossy(&out)
        );
    }
    // Group moves: every group to the middle of its members' ranges and back.
    for round in 0..2 {
        for (g, (_, gs, _)) in plan.groups.iter().enumerate() {
            let mut positions = [0i64; MAX_GROUP_AXES];
            for (i, &a) in gs.axes.iter().enumerate() {
                let s = &plan.axes[usize::from(a)].setup;
                positions[i] = if round == 0 {
                    (s.position_min + s.position_max) / 2
                } else {
                    s.position_min + 100
                };
            }
            // Through the loop, as a client's command comes (the recording sees it).
            let tag = run
                .submit(Command::MoveGroup {
                    group: g as GroupId,
                    positions,
                    velocity_percent: 100,
                    buffer: BufferMode::Aborting,
                })
                .expect("room for a command");
            let reply = run.answer_to(tag, 3, &mut out);
            // The moves run, so the steps counted below do the real work.
            assert!(
                matches!(reply, Some(Reply::Latched { .. })),
                "round {round} group {g}: {reply:?}\n{}",
                String::from_utf8_lossy(&out)
            );
        }
        // Until every group's move has arrived (at most 60 s of machine time).
        let t = run.elapsed();
        while (0..plan.groups.len()).any(|g| {
            run.stepper
                .cycle
                .group_status(g as GroupId)
                .is_some_and(|s| s.motion.is_some())
        }) {
            run.step(&mut out);
            assert!(
                run.elapsed() - t < Duration::from_secs(60),
                "moves do not arrive"
            );
        }
    }
    run.shut_down();
    while run.lp.script.phase() != Phase::Done {
        run.step(&mut out);
    }
    let cycles = run.cycles();
    (allocations() - before, cycles)
}

#[test]
fn one_axis_cycle_allocates_nothing() {
    let (n, cycles) = allocations_in_the_cycle(1);
    assert!(cycles > 100, "{cycles}");
    assert_eq!(n, 0, "{n} allocations in {cycles} cycles");
}

#[test]
fn sixty_four_axis_cycle_allocates_nothing() {
    let (n, cycles) = allocations_in_the_cycle(64);
    assert!(cycles > 100, "{cycles}");
    assert_eq!(n, 0, "{n} allocations in {cycles} cycles");
}

#[test]
fn recording_allocates_nothing_on_the_cycle_thread_and_replays_identically() {
    let path = std::env::temp_dir().join(format!("cycle-alloc-{}.rec", std::process::id()));
    let (n, cycles) = allocations_in(8, Some(&path));
    assert!(cycles > 100, "{cycles}");
    assert_eq!(n, 0, "{n} allocations in {cycles} cycles while recording");
    let mut out = Vec::new();
    let r = coordinator::runtime::record::replay::replay(&path, &mut out);
    let _ = std::fs::remove_file(&path);
    let r = r.unwrap();
    assert_eq!(
        r.outcome,
        coordinator::runtime::record::replay::Outcome::Identical,
        "{r}"
    );
    assert_eq!(r.cycles, cycles);
}

#[test]
fn the_counter_sees_an_allocation() {
    // The test above would pass with a counter that never counts; this one proves it counts.
    let before = allocations();
    probe(true);
    let v: Vec<u64> = Vec::with_capacity(std::hint::black_box(16));
    probe(false);
    drop(v);
    assert!(allocations() > before);
}

/// The cycle thread's side of an EtherCAT bus (what `RealIo` calls each cycle: every
/// subdevice's inputs and state taken, its node report looked for, its outputs put and sent
/// with the unpark) allocates nothing, with exchanges, states out of Op, losses and
/// emergencies coming from the bus's side.
#[test]
fn the_ethercat_hand_over_allocates_nothing_on_the_cycle_thread() {
    use coordinator::runtime::ethercat::{SubState, hand_over};
    use drivers::ethercat::esm::AlState;
    let n = 16;
    let (mut side, mut feed) = hand_over(n, Duration::from_millis(1));
    // The cycle side wakes the bus's thread: here this one (an unpark sets its token).
    side.wake(std::thread::current());
    let mut states = vec![SubState::Op; n];
    let inputs = vec![[0x13u8, 0, 0, 0, 0, 0, 0, 0]; n];
    let mut taken = 0u64;
    let before = allocations();
    for k in 0..2000u64 {
        // The bus's side, not counted: an exchange most cycles, with a subdevice falling back,
        // one lost, and an emergency now and then.
        states[3] = if k % 100 < 10 {
            SubState::NotOp(AlState::SafeOp)
        } else {
            SubState::Op
        };
        states[5] = if k % 250 < 5 {
            SubState::Lost
        } else {
            SubState::Op
        };
        if k % 7 != 0 {
            let emcy = if k % 50 == 0 {
                &[(2usize, 0x8100u16)][..]
            } else {
                &[]
            };
            feed.publish(&states, &inputs, emcy);
        }
        probe(true);
        for i in 0..n {
            let m = side.take(k, i);
            taken += u64::from(m.fresh);
        }
        while side.report().is_some() {}
        for i in 0..n {
            side.put(i, &[k as u8; 8]);
        }
        side.send(k);
        probe(false);
        let _ = feed.outputs();
    }
    assert!(taken > 1000, "{taken}");
    assert_eq!(allocations() - before, 0, "allocations on the cycle's side");
}
