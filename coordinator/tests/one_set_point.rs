//! The MTR-DCI in its CiA 402 profile takes one set-point per move (no "change set
//! immediately", seed 000 §7.9): the coordinator sends each move's end once, with its speed and
//! acceleration on RPDO2, and the drive's own generator runs it beside the path. These tests run
//! the coordinator with its simulated drives in virtual time: a move arrives on time and close to
//! the path, a halted move stays halted when the axis stands (it is dropped, not resumed), a
//! held move resumes, and a feed override cannot change a running move.

use std::time::Duration;

use coordinator::admission::BufferMode;
use coordinator::command::{Command, Reply, Target};
use coordinator::config::Config;
use coordinator::fault::FaultReason;
use coordinator::runtime::plan::{MachinePlan, plan};
use coordinator::runtime::script::Phase;
use coordinator::runtime::synthetic::{self, Kinds, Spec};
use coordinator::runtime::virtual_clock::VirtualRun;
use drivers::can::{Bus, VirtualPort};

/// The MTR-DCI axis of the machine (a0 is a TLC5xx).
const MTR: u16 = 1;

fn machine() -> MachinePlan {
    let spec = Spec {
        axes: 2,
        kinds: Kinds::Cia402,
        group_size: None,
    };
    plan(&Config::parse(&synthetic::config_of(&spec)).unwrap()).unwrap()
}

/// The MTR-DCI's bus and node.
fn bus_node(plan: &MachinePlan) -> (usize, u16) {
    match plan.axes[usize::from(MTR)].setup.transport {
        coordinator::cycle::Transport::Can { bus, node } => (usize::from(bus), u16::from(node)),
        t => panic!("the MTR-DCI is on CAN, not {t:?}"),
    }
}

/// Boots and homes the machine; a monitor on the MTR-DCI's bus.
fn homed(plan: &MachinePlan) -> (VirtualRun<'_>, VirtualPort, Vec<u8>) {
    let mut run = VirtualRun::new(plan, &synthetic::demo_options(false)).unwrap();
    let (bus, _) = bus_node(plan);
    let monitor = run.io.buses[bus].attach_monitor("test");
    let mut out = Vec::new();
    while run.lp.script.phase() != Phase::Running {
        run.step(&mut out);
        assert!(
            run.elapsed() < Duration::from_secs(120),
            "not homed:\n{}",
            String::from_utf8_lossy(&out)
        );
    }
    (run, monitor, out)
}

/// RPDO2 frames (the move's profile) to `node` the monitor saw since the last call.
fn profiles_sent(monitor: &mut VirtualPort, node: u16) -> Vec<[u8; 8]> {
    let mut v = Vec::new();
    while let Ok(Some(f)) = monitor.try_recv() {
        if f.cob_id() == Some(0x300 + node) {
            let mut b = [0u8; 8];
            b.copy_from_slice(f.data());
            v.push(b);
        }
    }
    v
}

fn command(run: &mut VirtualRun<'_>, c: Command) -> Reply {
    run.stepper.cycle.command(&c)
}

/// Steps until `done` or `max` cycles; returns the worst |setpoint − actual| seen meanwhile.
fn run_until(
    run: &mut VirtualRun<'_>,
    out: &mut Vec<u8>,
    max: u64,
    done: impl Fn(&VirtualRun<'_>) -> bool,
) -> i64 {
    let mut worst = 0;
    for _ in 0..max {
        run.step(out);
        let s = run.stepper.cycle.axis_status(MTR).unwrap();
        assert_eq!(
            s.fault,
            FaultReason::None,
            "{}",
            String::from_utf8_lossy(out)
        );
        if s.moving {
            worst = worst.max((s.setpoint - s.feedback.position).abs());
        }
        if done(run) {
            return worst;
        }
    }
    panic!(
        "not done within {max} cycles: {:?}\n{}",
        run.stepper.cycle.axis_status(MTR),
        String::from_utf8_lossy(out)
    );
}

/// The MTR-DCI's actual position.
fn position(run: &VirtualRun<'_>) -> i64 {
    run.stepper
        .cycle
        .axis_status(MTR)
        .unwrap()
        .feedback
        .position
}

fn standing_at(run: &VirtualRun<'_>, target: i64) -> bool {
    let s = run.stepper.cycle.axis_status(MTR).unwrap();
    !s.moving && s.feedback.motion_complete && (s.feedback.position - target).abs() <= 2
}

#[test]
fn a_move_is_one_set_point_and_follows_the_path() {
    let plan = machine();
    let (mut run, mut monitor, mut out) = homed(&plan);
    let setup = &plan.axes[usize::from(MTR)].setup;
    let target = setup.position_max * 3 / 4;
    let limit = setup.following_error;
    let from = position(&run);
    let (_, node) = bus_node(&plan);
    profiles_sent(&mut monitor, node);
    let r = command(
        &mut run,
        Command::MoveAxis {
            axis: MTR,
            position: target,
            velocity_percent: 80,
            buffer: BufferMode::Aborting,
        },
    );
    assert!(matches!(r, Reply::Latched { .. }), "{r:?}");
    let start = run.cycles();
    let worst = run_until(&mut run, &mut out, 20_000, |r| standing_at(r, target));
    let took = run.cycles() - start;
    // The path: a trapezoid at 80 % of 100 mm/s (400 inc/mm), 800 mm/s²; streamed set-points
    // used to crawl here and fault on the following error.
    let mm = (target - from) as f64 / 400.0;
    let ideal_ms = mm / 80.0 * 1000.0 + 80.0 / 800.0 * 1000.0;
    assert!(
        (took as f64) < ideal_ms * 1.2 + 100.0,
        "{took} cycles for a move planned at about {ideal_ms:.0} ms"
    );
    assert!(
        worst < limit / 4,
        "following error up to {worst} inc (limit {limit})"
    );
    let sent = profiles_sent(&mut monitor, node);
    assert_eq!(sent.len(), 1, "one profile per move: {sent:?}");
    let v = u32::from_le_bytes(sent[0][..4].try_into().unwrap());
    let a = u32::from_le_bytes(sent[0][4..].try_into().unwrap());
    // 80 mm/s and 800 mm/s² at 400 inc/mm.
    assert!((31_990..=32_000).contains(&v), "6081h {v}");
    assert!((319_990..=320_000).contains(&a), "6083h {a}");
}

#[test]
fn a_halted_move_is_dropped_not_resumed_and_a_held_one_resumes() {
    let plan = machine();
    let (mut run, _monitor, mut out) = homed(&plan);
    let max = plan.axes[usize::from(MTR)].setup.position_max;
    let mv = |position| Command::MoveAxis {
        axis: MTR,
        position,
        velocity_percent: 100,
        buffer: BufferMode::Aborting,
    };
    // Hold half-way, stand, resume: the drive's move goes on to the end.
    let first = max * 3 / 4;
    assert!(matches!(
        command(&mut run, mv(first)),
        Reply::Latched { .. }
    ));
    run_until(&mut run, &mut out, 5_000, |r| position(r) > max / 4);
    assert!(matches!(
        command(&mut run, Command::Hold(Target::Axis(MTR))),
        Reply::Latched { .. }
    ));
    run_until(&mut run, &mut out, 5_000, |r| {
        r.stepper.cycle.axis_status(MTR).unwrap().feedback.velocity == 0
    });
    let held_at = position(&run);
    assert!(held_at < first - 1000, "held at {held_at}");
    assert!(matches!(
        command(&mut run, Command::Resume(Target::Axis(MTR))),
        Reply::Latched { .. }
    ));
    run_until(&mut run, &mut out, 20_000, |r| standing_at(r, first));
    // Back, halted half-way with a stop: the drive must not finish that move afterwards.
    let second = max / 4;
    assert!(matches!(
        command(&mut run, mv(second)),
        Reply::Latched { .. }
    ));
    run_until(&mut run, &mut out, 5_000, |r| position(r) < max / 2);
    assert!(matches!(
        command(&mut run, Command::Stop(Target::Axis(MTR))),
        Reply::Latched { .. }
    ));
    run_until(&mut run, &mut out, 5_000, |r| {
        let s = r.stepper.cycle.axis_status(MTR).unwrap();
        !s.moving && s.feedback.velocity == 0
    });
    let stopped_at = position(&run);
    assert!(stopped_at > second + 1000, "stopped at {stopped_at}");
    for _ in 0..3000 {
        run.step(&mut out);
    }
    let s = run.stepper.cycle.axis_status(MTR).unwrap();
    assert!(
        (s.feedback.position - stopped_at).abs() <= 2,
        "the stopped move went on: {stopped_at} → {}",
        s.feedback.position
    );
    assert_eq!(s.fault, FaultReason::None);
    // And a new move from there arrives.
    assert!(matches!(
        command(&mut run, mv(first)),
        Reply::Latched { .. }
    ));
    run_until(&mut run, &mut out, 20_000, |r| standing_at(r, first));
}

#[test]
fn a_running_move_keeps_its_speed_and_says_why() {
    let plan = machine();
    let (mut run, _monitor, mut out) = homed(&plan);
    let max = plan.axes[usize::from(MTR)].setup.position_max;
    let slower = Command::SetOverride {
        target: Target::Axis(MTR),
        percent: 50,
    };
    assert!(matches!(command(&mut run, slower), Reply::Latched { .. }));
    assert!(matches!(
        command(
            &mut run,
            Command::MoveAxis {
                axis: MTR,
                position: max / 2,
                velocity_percent: 100,
                buffer: BufferMode::Aborting,
            },
        ),
        Reply::Latched { .. }
    ));
    run.step(&mut out);
    match command(&mut run, slower) {
        Reply::Rejected(why) => {
            let text = why.to_string();
            assert!(text.contains("one set-point per move"), "{text}");
        }
        r => panic!("an override change during the move: {r:?}"),
    }
    // The move runs at the override it started with (50 %), and arrives.
    let worst = run_until(&mut run, &mut out, 40_000, |r| standing_at(r, max / 2));
    let limit = plan.axes[usize::from(MTR)].setup.following_error;
    assert!(worst < limit / 4, "following error up to {worst} inc");
}
