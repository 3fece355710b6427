//! Commands mean what they say: the operator's scenarios of issue 11 on the embedded default
//! machine in virtual time. Each of them went wrong before the admission table: a stop the
//! demonstration undid, a hold a chain step ignored, an acknowledge that stopped a healthy move,
//! home and jog taking an axis out of a group move, an override a single-axis move ignored, a
//! jog past its limits, a move on a moving axis refused.

mod common;

use std::time::Duration;

use coordinator::admission::{AxisActivity, GroupActivity, Refusal};
use coordinator::command::{BufferMode, Command, Rejected, Reply, Target};
use coordinator::records::MAX_GROUP_AXES;
use coordinator::runtime::plan::MachinePlan;
use coordinator::runtime::script::Phase;
use coordinator::runtime::virtual_clock::VirtualRun;

use common::{demo as options, example};

/// Steps until `done` holds (at most `limit` of machine time); false if it never did.
fn run_until(
    run: &mut VirtualRun<'_>,
    limit: Duration,
    mut done: impl FnMut(&VirtualRun<'_>) -> bool,
) -> bool {
    let end = run.elapsed() + limit;
    let mut out = Vec::new();
    while run.elapsed() < end {
        run.step(&mut out);
        out.clear();
        if done(run) {
            return true;
        }
    }
    false
}

fn steps(run: &mut VirtualRun<'_>, n: usize) {
    let mut out = Vec::new();
    for _ in 0..n {
        run.step(&mut out);
        out.clear();
    }
}

/// Every axis enabled and homed by the demonstration (chains as given).
fn ready(plan: &MachinePlan, chains: bool) -> VirtualRun<'_> {
    let mut run = VirtualRun::new(plan, &options(chains)).expect("machine builds");
    assert!(
        run_until(&mut run, Duration::from_secs(60), |r| r.lp.script.phase()
            == Phase::Running),
        "not homed after 60 s"
    );
    steps(&mut run, 10);
    run
}

fn latched(r: Reply) -> u64 {
    match r {
        Reply::Latched { cycle } => cycle,
        Reply::Rejected(e) => panic!("rejected: {e}"),
    }
}

fn refused(r: Reply, why: Refusal) {
    assert_eq!(r, Reply::Rejected(Rejected::WrongState(why.text())));
}

fn axis(run: &VirtualRun<'_>, a: usize) -> coordinator::cycle::AxisStatus {
    run.stepper.cycle.axis_status(a as u16).unwrap()
}

fn group_targets(plan: &MachinePlan, units: &[(usize, f64)]) -> [i64; MAX_GROUP_AXES] {
    let mut p = [0i64; MAX_GROUP_AXES];
    for (i, &(a, u)) in units.iter().enumerate() {
        p[i] = plan.axes[a].scale.to_inc(u).unwrap();
    }
    p
}

fn inc(plan: &MachinePlan, a: usize, units: f64) -> i64 {
    plan.axes[a].scale.to_inc(units).unwrap()
}

#[test]
fn stop_all_is_sticky_and_ends_the_demonstration() {
    let plan = example();
    let mut run = ready(&plan, true);
    let n = plan.axes.len();
    assert!(
        run_until(&mut run, Duration::from_secs(5), |r| (0..n).any(|a| axis(
            r, a
        )
        .setpoint_velocity
            != 0)),
        "the demonstration moves something"
    );
    latched(run.stepper.cycle.command(&Command::Stop(Target::All)));
    // The ramps end within a second; from then on nothing moves, for good.
    steps(&mut run, 500);
    let still: Vec<i64> = (0..n).map(|a| axis(&run, a).setpoint).collect();
    for _ in 0..5 {
        steps(&mut run, 500);
        for (a, &at) in still.iter().enumerate() {
            let s = axis(&run, a);
            assert_eq!(s.setpoint_velocity, 0, "axis {a} moves again: {s:?}");
            assert_eq!(s.setpoint, at, "axis {a} moved after the stop");
        }
    }
    assert_eq!(run.lp.script.phase(), Phase::Stopped);
    // A new motion command moves again: the stop was sticky, not a lock.
    let y = plan.axis("y").unwrap();
    latched(run.stepper.cycle.command(&Command::MoveAxis {
        axis: y as u16,
        position: inc(&plan, y, 50.0),
        velocity_percent: 50,
        buffer: BufferMode::Aborting,
    }));
    assert!(run_until(&mut run, Duration::from_secs(10), |r| {
        (axis(r, y).setpoint - inc(&plan, y, 50.0)).abs() <= 1
    }));
}

#[test]
fn a_hold_is_kept_across_the_chains_steps_until_resume() {
    let plan = example();
    let mut run = ready(&plan, false);
    let g = plan.group("gantry").unwrap() as u16;
    let x = plan.axis("x").unwrap();
    latched(run.stepper.cycle.command(&Command::StartChain {
        group: g,
        record: 10,
    }));
    // Record 10 takes x towards 200 mm; its step (x inside 150..210 mm) starts record 11 on the
    // fly. Hold before the window, where the step would come true during the ramp.
    assert!(run_until(&mut run, Duration::from_secs(10), |r| {
        axis(r, x).setpoint > inc(&plan, x, 140.0)
    }));
    latched(run.stepper.cycle.command(&Command::Hold(Target::Group(g))));
    steps(&mut run, 500);
    let held = axis(&run, x).setpoint;
    assert!(
        held > inc(&plan, x, 150.0),
        "held inside the window: {held}"
    );
    assert_eq!(
        run.stepper.cycle.group_status(g).unwrap().activity,
        GroupActivity::Held
    );
    for _ in 0..4 {
        steps(&mut run, 500);
        let s = axis(&run, x);
        assert_eq!(s.setpoint, held, "the next record started during the hold");
        assert_eq!(s.setpoint_velocity, 0);
    }
    latched(
        run.stepper
            .cycle
            .command(&Command::Resume(Target::Group(g))),
    );
    assert!(
        run_until(&mut run, Duration::from_secs(5), |r| axis(r, x).setpoint
            != held),
        "resume moves on"
    );
}

#[test]
fn acknowledge_without_a_fault_changes_nothing() {
    let plan = example();
    let mut run = ready(&plan, false);
    let g = plan.group("gantry").unwrap() as u16;
    let (x, y) = (plan.axis("x").unwrap(), plan.axis("y").unwrap());
    latched(run.stepper.cycle.command(&Command::MoveGroup {
        group: g,
        positions: group_targets(&plan, &[(x, 350.0), (y, 200.0)]),
        velocity_percent: 50,
        buffer: BufferMode::Aborting,
    }));
    steps(&mut run, 200);
    latched(
        run.stepper
            .cycle
            .command(&Command::Acknowledge(Target::All)),
    );
    steps(&mut run, 20);
    let s = axis(&run, x);
    assert_ne!(s.setpoint_velocity, 0, "the move goes on: {s:?}");
    assert_eq!(s.activity, AxisActivity::Synchronized);
    assert!(run_until(&mut run, Duration::from_secs(20), |r| {
        axis(r, x).setpoint == inc(&plan, x, 350.0) && axis(r, y).setpoint == inc(&plan, y, 200.0)
    }));
}

#[test]
fn home_jog_and_a_single_move_are_refused_in_a_group_move() {
    let plan = example();
    let mut run = ready(&plan, false);
    let g = plan.group("gantry").unwrap() as u16;
    let (x, y) = (plan.axis("x").unwrap(), plan.axis("y").unwrap());
    latched(run.stepper.cycle.command(&Command::MoveGroup {
        group: g,
        positions: group_targets(&plan, &[(x, 300.0), (y, 200.0)]),
        velocity_percent: 30,
        buffer: BufferMode::Aborting,
    }));
    steps(&mut run, 50);
    let c = &mut run.stepper.cycle;
    refused(
        c.command(&Command::Home(Target::Axis(y as u16))),
        Refusal::InGroupMove,
    );
    refused(
        c.command(&Command::Jog {
            axis: y as u16,
            permille: 500,
        }),
        Refusal::InGroupMove,
    );
    refused(
        c.command(&Command::MoveAxis {
            axis: y as u16,
            position: 0,
            velocity_percent: 50,
            buffer: BufferMode::Aborting,
        }),
        Refusal::InGroupMove,
    );
    // Both arrive together: nobody left the synchronised move.
    assert!(run_until(&mut run, Duration::from_secs(30), |r| {
        axis(r, x).setpoint == inc(&plan, x, 300.0) && axis(r, y).setpoint == inc(&plan, y, 200.0)
    }));
}

/// The highest |setpoint velocity| of axis `a` while `until` is false (at most `limit`).
fn peak_velocity(
    run: &mut VirtualRun<'_>,
    a: usize,
    limit: Duration,
    mut until: impl FnMut(&VirtualRun<'_>) -> bool,
) -> i64 {
    let mut peak = 0;
    run_until(run, limit, |r| {
        peak = peak.max(axis(r, a).setpoint_velocity.abs());
        until(r)
    });
    peak
}

#[test]
fn the_override_slows_a_single_axis_move() {
    let plan = example();
    let mut run = ready(&plan, false);
    let z = plan.axis("z").unwrap();
    let to = inc(&plan, z, 110.0);
    latched(run.stepper.cycle.command(&Command::MoveAxis {
        axis: z as u16,
        position: to,
        velocity_percent: 100,
        buffer: BufferMode::Aborting,
    }));
    // Cruise at the full velocity limit, then half of it once overridden.
    steps(&mut run, 600);
    let full = axis(&run, z).setpoint_velocity;
    latched(run.stepper.cycle.command(&Command::SetOverride {
        target: Target::Axis(z as u16),
        percent: 50,
    }));
    steps(&mut run, 300);
    let half = axis(&run, z).setpoint_velocity;
    assert!(full > 0 && half > 0, "{full} {half}");
    let ratio = half as f64 / full as f64;
    assert!((0.45..=0.55).contains(&ratio), "{half} / {full} = {ratio}");
    assert!(run_until(&mut run, Duration::from_secs(30), |r| axis(r, z)
        .setpoint
        == to));
}

#[test]
fn a_jog_keeps_the_velocity_limit_and_stops_exactly_at_the_software_limit() {
    let plan = example();
    let mut run = ready(&plan, false);
    let a = plan.axis("gripper").unwrap();
    let setup = plan.axes[a].setup;
    // Even at the full jog speed with a 200 % override.
    latched(run.stepper.cycle.command(&Command::SetOverride {
        target: Target::Axis(a as u16),
        percent: 200,
    }));
    latched(run.stepper.cycle.command(&Command::Jog {
        axis: a as u16,
        permille: 1000,
    }));
    let max = setup.position_max;
    let peak = peak_velocity(&mut run, a, Duration::from_secs(20), |r| {
        axis(r, a).setpoint_velocity == 0 && axis(r, a).setpoint == max
    });
    assert!(
        peak as u64 <= setup.limits.velocity,
        "peak {peak} inc/s over the limit {}",
        setup.limits.velocity
    );
    steps(&mut run, 200);
    let s = axis(&run, a);
    assert_eq!(s.setpoint, max, "stopped exactly at the limit");
    assert!(
        s.feedback.position <= max,
        "the drive stays within: {}",
        s.feedback.position
    );
    // Back, released half-way: it ramps down, and the setpoint is where the axis is.
    latched(run.stepper.cycle.command(&Command::Jog {
        axis: a as u16,
        permille: -500,
    }));
    assert!(run_until(&mut run, Duration::from_secs(20), |r| axis(r, a)
        .setpoint
        < max / 2));
    latched(run.stepper.cycle.command(&Command::Jog {
        axis: a as u16,
        permille: 0,
    }));
    steps(&mut run, 500);
    let s = axis(&run, a);
    assert_eq!(s.setpoint_velocity, 0);
    assert_eq!(s.activity, AxisActivity::Standstill);
    assert!(
        (s.setpoint - s.feedback.position).abs() <= 2,
        "setpoint {} vs position {}",
        s.setpoint,
        s.feedback.position
    );
}

#[test]
fn a_move_on_a_moving_axis_aborts_or_waits_as_asked() {
    let plan = example();
    let mut run = ready(&plan, false);
    let z = plan.axis("z").unwrap() as u16;
    let zi = usize::from(z);
    let mv = |position, buffer| Command::MoveAxis {
        axis: z,
        position,
        velocity_percent: 100,
        buffer,
    };
    let (far, near, mid) = (
        inc(&plan, zi, 110.0),
        inc(&plan, zi, 20.0),
        inc(&plan, zi, 60.0),
    );
    // Aborting: the new target is taken on the way, the first one is never reached.
    latched(run.stepper.cycle.command(&mv(far, BufferMode::Aborting)));
    steps(&mut run, 300);
    latched(run.stepper.cycle.command(&mv(near, BufferMode::Aborting)));
    let mut highest = 0;
    assert!(run_until(&mut run, Duration::from_secs(30), |r| {
        highest = highest.max(axis(r, zi).setpoint);
        axis(r, zi).setpoint == near && axis(r, zi).activity == AxisActivity::Standstill
    }));
    assert!(
        highest < far,
        "the aborted target was not reached: {highest}"
    );
    // Buffered: the first arrives, then the second starts.
    latched(run.stepper.cycle.command(&mv(far, BufferMode::Aborting)));
    steps(&mut run, 100);
    latched(run.stepper.cycle.command(&mv(mid, BufferMode::Buffered)));
    let mut reached_far = false;
    assert!(run_until(&mut run, Duration::from_secs(30), |r| {
        reached_far |= axis(r, zi).setpoint == far;
        axis(r, zi).setpoint == mid && axis(r, zi).activity == AxisActivity::Standstill
    }));
    assert!(
        reached_far,
        "the buffered move waited for the first to arrive"
    );
}

#[test]
fn a_configured_machine_starts_nothing_on_its_own() {
    // `coordinator run --config FILE` without `--demo`: the drives are booted and wait.
    let plan = example();
    let mut opts = options(true);
    opts.script.demo = false;
    let mut run = VirtualRun::new(&plan, &opts).expect("machine builds");
    let n = plan.axes.len();
    assert!(
        run_until(&mut run, Duration::from_secs(30), |r| (0..n)
            .all(|a| axis(r, a).online)),
        "every drive booted"
    );
    steps(&mut run, 2500);
    assert_eq!(run.lp.script.phase(), Phase::Idle);
    for a in 0..n {
        let s = axis(&run, a);
        assert_eq!(s.activity, AxisActivity::Disabled, "axis {a}: {s:?}");
        assert_eq!(s.setpoint_velocity, 0);
    }
    // The operator enables one axis; it stands still.
    latched(run.stepper.cycle.command(&Command::Enable(Target::Axis(0))));
    steps(&mut run, 500);
    assert_eq!(axis(&run, 0).activity, AxisActivity::Standstill);
}
