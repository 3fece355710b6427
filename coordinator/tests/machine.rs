//! The whole coordinator in virtual time: the embedded default machine (MTR-DCI, EMCA, TLC5xx on
//! the virtual CAN bus, CMMO-ST over Modbus), booted over SDO, enabled, homed; group moves,
//! chains, every fault reaction, determinism.

mod common;

use std::time::Duration;

use coordinator::axis::AxisState;
use coordinator::command::{BufferMode, Command, Rejected, Reply, Target};
use coordinator::config::{Config, EXAMPLE};
use coordinator::cycle::AxisMode;
use coordinator::fault::FaultReason;
use coordinator::records::MAX_GROUP_AXES;
use coordinator::runtime::plan::{MachinePlan, plan};
use coordinator::runtime::run::RunOptions;
use coordinator::runtime::script::Phase;
use coordinator::runtime::virtual_clock::{VirtualRun, run_virtual};
use drivers::can::Bus;
use drivers::can::fault::{FaultRule, IdMatch};

use common::{demo as quiet, example};

/// Runs until the script has enabled and homed every axis (chains off).
fn ready(plan: &MachinePlan) -> VirtualRun<'_> {
    let mut run = VirtualRun::new(plan, &quiet(false)).expect("machine builds");
    let mut out = Vec::new();
    while run.lp.script.phase() != Phase::Running {
        run.step(&mut out);
        assert!(
            run.elapsed() < Duration::from_secs(60),
            "not homed after 60 s: {}",
            String::from_utf8_lossy(&out)
        );
    }
    // A few cycles for the last homing's MC to settle.
    for _ in 0..10 {
        run.step(&mut out);
    }
    let text = String::from_utf8_lossy(&out);
    assert!(run.io.summary.boot_failures.is_empty(), "{text}");
    assert!(run.io.summary.faults.is_empty(), "{text}");
    for a in 0..plan.axes.len() {
        let s = run.stepper.cycle.axis_status(a as u16).unwrap();
        assert_eq!(
            s.feedback.state,
            AxisState::Ready,
            "axis {a}: {s:?}\n{text}"
        );
        assert!(s.feedback.homed, "axis {a} homed: {s:?}\n{text}");
        assert_eq!(s.mode, AxisMode::On, "axis {a}");
    }
    run
}

fn steps(run: &mut VirtualRun<'_>, n: usize) {
    let mut out = Vec::new();
    for _ in 0..n {
        run.step(&mut out);
    }
}

fn latched(r: Reply) -> u64 {
    match r {
        Reply::Latched { cycle } => cycle,
        Reply::Rejected(e) => panic!("rejected: {e}"),
    }
}

#[test]
fn the_default_machine_boots_every_drive_and_homes_every_axis() {
    let plan = example();
    let run = ready(&plan);
    // Four kinds: MTR-DCI (guarded), EMCA (guarded), TLC5xx (heartbeat), CMMO-ST (Modbus).
    assert_eq!(plan.axes.len(), 4);
    assert!(run.booted());
}

#[test]
fn a_group_move_starts_together_and_arrives_in_the_same_cycle() {
    let plan = example();
    let mut run = ready(&plan);
    let g = plan.group("gantry").unwrap() as u16;
    let x = plan.axis("x").unwrap();
    let y = plan.axis("y").unwrap();
    let tx = plan.axes[x].scale.to_inc(150.0).unwrap();
    let ty = plan.axes[y].scale.to_inc(120.0).unwrap();
    let mut positions = [0i64; MAX_GROUP_AXES];
    positions[0] = tx;
    positions[1] = ty;
    let at = latched(run.stepper.cycle.command(&Command::MoveGroup {
        group: g,
        positions,
        velocity_percent: 100,
        buffer: BufferMode::Aborting,
    }));
    let mut started = [None, None];
    let mut arrived = [None, None];
    let mut out = Vec::new();
    for _ in 0..5000 {
        let c = run.stepper.cycle.cycle();
        run.step(&mut out);
        for (i, (axis, target)) in [(x, tx), (y, ty)].into_iter().enumerate() {
            let s = run.stepper.cycle.axis_status(axis as u16).unwrap();
            if started[i].is_none() && s.setpoint_velocity != 0 {
                started[i] = Some(c);
            }
            // Arrived: on the target with the path at rest (a setpoint can round to the target
            // a cycle early while the path still moves).
            if arrived[i].is_none() && s.setpoint == target && s.setpoint_velocity == 0 {
                arrived[i] = Some(c);
            }
        }
        if arrived.iter().all(Option::is_some)
            && run.stepper.cycle.group_status(g).unwrap().motion.is_none()
        {
            break;
        }
    }
    assert_eq!(started[0], started[1], "both start in the same cycle");
    assert_eq!(
        started[0],
        Some(at - 1),
        "the first setpoint goes out in the latching step"
    );
    assert_eq!(arrived[0], arrived[1], "both arrive in the same cycle");
    assert!(arrived[0].is_some());
    // The drives got there too, and report motion complete.
    steps(&mut run, 50);
    for (axis, target) in [(x, tx), (y, ty)] {
        let s = run.stepper.cycle.axis_status(axis as u16).unwrap();
        assert!(s.feedback.motion_complete, "{s:?}");
        assert!(
            (s.feedback.position - target).abs() <= 2,
            "{s:?} vs {target}"
        );
    }
    assert!(
        run.io.summary.faults.is_empty(),
        "{:?}",
        run.io.summary.faults
    );
}

#[test]
fn a_bad_group_move_is_refused_whole_and_nothing_moves() {
    let plan = example();
    let mut run = ready(&plan);
    let g = plan.group("gantry").unwrap() as u16;
    let x = plan.axis("x").unwrap() as u16;
    let before = run.stepper.cycle.axis_status(x).unwrap().setpoint;
    let mut positions = [0i64; MAX_GROUP_AXES];
    positions[0] = plan.axes[x as usize].scale.to_inc(100.0).unwrap();
    positions[1] = 10_000_000; // y far beyond its 250 mm
    let r = run.stepper.cycle.command(&Command::MoveGroup {
        group: g,
        positions,
        velocity_percent: 50,
        buffer: BufferMode::Aborting,
    });
    assert!(
        matches!(
            r,
            Reply::Rejected(Rejected::OutOfRange {
                value: 10_000_000,
                ..
            })
        ),
        "{r:?}"
    );
    steps(&mut run, 20);
    assert_eq!(run.stepper.cycle.axis_status(x).unwrap().setpoint, before);
    assert!(matches!(
        run.stepper.cycle.command(&Command::MoveGroup {
            group: 9,
            positions,
            velocity_percent: 50,
            buffer: BufferMode::Aborting,
        }),
        Reply::Rejected(Rejected::UnknownGroup(9))
    ));
}

/// Starts a gantry move, runs a few cycles, then lets `inject` break something and checks the
/// reaction: the fault `expect`ed on `axis`, every gantry member quick-stopped in the fault's
/// cycle, moves refused until the acknowledge, and back to normal afterwards (`heal` first).
fn fault_reaction(
    axis: &str,
    inject: impl FnOnce(&mut VirtualRun<'_>),
    heal: impl FnOnce(&mut VirtualRun<'_>),
    expect: impl Fn(FaultReason) -> bool,
) {
    let plan = example();
    let mut run = ready(&plan);
    let g = plan.group("gantry").unwrap() as u16;
    let mut positions = [0i64; MAX_GROUP_AXES];
    positions[0] = plan.axes[plan.axis("x").unwrap()]
        .scale
        .to_inc(300.0)
        .unwrap();
    positions[1] = plan.axes[plan.axis("y").unwrap()]
        .scale
        .to_inc(200.0)
        .unwrap();
    latched(run.stepper.cycle.command(&Command::MoveGroup {
        group: g,
        positions,
        velocity_percent: 50,
        buffer: BufferMode::Aborting,
    }));
    steps(&mut run, 30);
    inject(&mut run);
    let a = plan.axis(axis).unwrap() as u16;
    let mut out = Vec::new();
    for _ in 0..2000 {
        run.step(&mut out);
        if run.stepper.cycle.axis_status(a).unwrap().fault != FaultReason::None {
            break;
        }
    }
    let text = String::from_utf8_lossy(&out).to_string();
    let st = run.stepper.cycle.axis_status(a).unwrap();
    assert!(expect(st.fault), "{axis}: {:?}\n{text}", st.fault);
    // Same cycle: the whole group is quick-stopped and its move dropped.
    if let Some(gi) = plan
        .groups
        .iter()
        .position(|(_, gs, _)| gs.axes.contains(&a))
    {
        for &m in &plan.groups[gi].1.axes {
            assert_eq!(
                run.stepper.cycle.axis_status(m).unwrap().mode,
                AxisMode::QuickStopped,
                "member {m}"
            );
        }
        assert!(
            run.stepper
                .cycle
                .group_status(gi as u16)
                .unwrap()
                .motion
                .is_none()
        );
        assert!(matches!(
            run.stepper.cycle.command(&Command::MoveGroup {
                group: gi as u16,
                positions,
                velocity_percent: 50,
                buffer: BufferMode::Aborting,
            }),
            Reply::Rejected(_)
        ));
    }
    assert!(text.contains("FAULT"), "{text}");
    heal(&mut run);
    steps(&mut run, 200);
    // A drive the cycle lost is waited for and configured again when it answers; it comes back
    // into the cycle still faulted, for the operator to acknowledge.
    for _ in 0..3000 {
        if run.stepper.cycle.axis_status(a).unwrap().online {
            break;
        }
        run.step(&mut out);
    }
    let text = String::from_utf8_lossy(&out).to_string();
    let st = run.stepper.cycle.axis_status(a).unwrap();
    assert!(st.online && expect(st.fault), "{st:?}\n{text}");
    steps(&mut run, 20);
    latched(
        run.stepper
            .cycle
            .command(&Command::Acknowledge(Target::All)),
    );
    steps(&mut run, 300);
    let st = run.stepper.cycle.axis_status(a).unwrap();
    assert_eq!(st.fault, FaultReason::None, "{st:?}");
    assert_eq!(st.mode, AxisMode::On, "{st:?}");
    latched(run.stepper.cycle.command(&Command::Enable(Target::All)));
}

#[test]
fn guarding_loss_quick_stops_the_group_until_acknowledged() {
    fault_reaction(
        "x",
        |run| {
            let port = run.io.drive_mut("x").unwrap().port();
            run.io.buses[0].set_disconnected(port, true);
        },
        |run| {
            let port = run.io.drive_mut("x").unwrap().port();
            run.io.buses[0].set_disconnected(port, false);
        },
        |r| matches!(r, FaultReason::GuardingLost | FaultReason::LateTpdo(_)),
    );
}

#[test]
fn a_late_tpdo_faults_the_axis() {
    fault_reaction(
        "y",
        |run| {
            // EMCA node 2 on can1: drop its TPDO1 (182h).
            run.io.buses[1].add_fault(FaultRule::drop(IdMatch::Exact(0x182)));
        },
        |run| run.io.buses[1].clear_faults(),
        |r| r == FaultReason::LateTpdo(3),
    );
}

#[test]
fn heartbeat_loss_faults_the_tlc5xx() {
    fault_reaction(
        "z",
        |run| {
            // Heartbeats only (703h): the TPDOs still arrive.
            run.io.buses[0].add_fault(FaultRule::drop(IdMatch::Exact(0x703)));
        },
        |run| run.io.buses[0].clear_faults(),
        |r| r == FaultReason::HeartbeatLost,
    );
}

#[test]
fn a_drive_fault_and_its_emcy_fault_the_axis() {
    fault_reaction(
        "y",
        |run| {
            let d = run.io.drive_mut("y").unwrap().fhpp_mut().unwrap();
            d.inject(drivers::sim::fhpp_drive::Injection::OverTemperature, true);
        },
        |run| {
            let d = run.io.drive_mut("y").unwrap().fhpp_mut().unwrap();
            d.inject(drivers::sim::fhpp_drive::Injection::OverTemperature, false);
        },
        |r| matches!(r, FaultReason::Emcy(_) | FaultReason::DriveFault(_)),
    );
}

#[test]
fn a_following_error_faults_the_axis() {
    fault_reaction(
        "x",
        |run| {
            let d = run.io.drive_mut("x").unwrap().fhpp_mut().unwrap();
            d.inject(drivers::sim::fhpp_drive::Injection::Block, true);
        },
        |run| {
            let d = run.io.drive_mut("x").unwrap().fhpp_mut().unwrap();
            d.inject(drivers::sim::fhpp_drive::Injection::Block, false);
        },
        |r| {
            matches!(
                r,
                FaultReason::FollowingError { .. }
                    | FaultReason::DriveFault(_)
                    | FaultReason::Emcy(_)
            )
        },
    );
}

#[test]
fn a_modbus_timeout_faults_the_cmmo_st() {
    fault_reaction(
        "gripper",
        |run| run.io.cmmo[0].1.set_silent(true),
        |run| run.io.cmmo[0].1.set_silent(false),
        |r| r == FaultReason::ModbusTimeout,
    );
}

#[test]
fn two_runs_of_the_demo_send_the_same_frames() {
    let plan = example();
    let opts = RunOptions {
        duration: Some(Duration::from_secs(8)),
        ..quiet(true)
    };
    let a = run_virtual(&plan, &opts, &mut Vec::new()).unwrap();
    let b = run_virtual(&plan, &opts, &mut Vec::new()).unwrap();
    assert_eq!(a.frame_hash, b.frame_hash);
    assert_eq!(a.frames_on_bus, b.frames_on_bus);
    assert!(a.frames_on_bus > 1000, "{a}");
}

#[test]
fn the_demo_runs_its_chain_and_ends_with_the_drives_disabled() {
    let plan = example();
    let opts = RunOptions {
        duration: Some(Duration::from_secs(30)),
        ..quiet(true)
    };
    let mut out = Vec::new();
    let s = run_virtual(&plan, &opts, &mut out).unwrap();
    let text = String::from_utf8_lossy(&out);
    assert!(s.boot_failures.is_empty(), "{s}\n{text}");
    assert!(s.faults.is_empty(), "{s}\n{text}");
    assert!(s.laps >= 1, "{s}\n{text}");
    assert!(s.records_reached >= 3, "{s}\n{text}");
    assert_eq!(s.phase, Some(Phase::Done));
    for (name, _, _, state) in &s.axes {
        assert_eq!(*state, AxisState::Disabled, "{name}: {s}");
    }
}

/// Runs until `pred` holds for an event, returning the event's cycle.
fn until_event(
    run: &mut VirtualRun<'_>,
    max_cycles: usize,
    pred: impl Fn(&coordinator::event::Event) -> bool,
    events: &mut Vec<coordinator::event::Event>,
) -> Option<u64> {
    // The run drains the cycle's events into its summary; watch them through the core instead.
    let mut out = Vec::new();
    for _ in 0..max_cycles {
        run.step_with_events(&mut out, events);
        if let Some(e) = events.iter().find(|e| pred(e)) {
            return Some(event_cycle(e));
        }
    }
    None
}

fn event_cycle(e: &coordinator::event::Event) -> u64 {
    use coordinator::event::Event as E;
    match *e {
        E::AxisState { cycle, .. }
        | E::Fault { cycle, .. }
        | E::Acknowledged { cycle, .. }
        | E::RecordReached { cycle, .. }
        | E::ChainComplete { cycle, .. }
        | E::ChainAborted { cycle, .. }
        | E::LateModbus { cycle, .. }
        | E::Parameter { cycle, .. }
        | E::Overrun { cycle, .. } => cycle,
    }
}

#[test]
fn the_gantry_chain_steps_on_its_comparator_then_waits_for_the_lift() {
    use coordinator::event::Event as E;
    let plan = example();
    let mut run = ready(&plan);
    let gantry = plan.group("gantry").unwrap() as u16;
    let lift = plan.group("lift").unwrap() as u16;
    let x = plan.axis("x").unwrap();
    latched(run.stepper.cycle.command(&Command::StartChain {
        group: gantry,
        record: 10,
    }));
    let mut events = Vec::new();
    // Record 10 steps on the fly once x stayed in [150, 210] mm for 10 ms: before it arrives
    // at 200 mm, so x is inside the window, short of 200, when record 11 begins.
    let mut out = Vec::new();
    let mut stepped_at = None;
    for _ in 0..5000 {
        run.step_with_events(&mut out, &mut events);
        let st = run.stepper.cycle.group_status(gantry).unwrap();
        if st.chain.record == Some(11) {
            let pos = run
                .stepper
                .cycle
                .axis_status(x as u16)
                .unwrap()
                .feedback
                .position;
            let pos = plan.axes[x].scale.to_units(pos);
            stepped_at = Some(pos);
            assert!(st.chain.rc1, "RC1 once the first step condition is met");
            break;
        }
    }
    let pos = stepped_at.expect("record 10 stepped to 11");
    assert!(
        (150.0..200.0).contains(&pos),
        "x at {pos} mm when the comparator stepped"
    );
    // Record 12 waits at its target until the lift has reached its record 1.
    let reached12 = until_event(
        &mut run,
        10_000,
        |e| matches!(e, E::RecordReached { group, record: 12, .. } if *group == gantry),
        &mut events,
    );
    assert!(
        reached12.is_none()
            || run.stepper.cycle.group_status(gantry).unwrap().chain.record == Some(12)
    );
    assert!(
        run.stepper
            .cycle
            .group_status(gantry)
            .unwrap()
            .chain
            .active
            .is_some(),
        "still waiting for the lift"
    );
    latched(run.stepper.cycle.command(&Command::StartChain {
        group: lift,
        record: 0,
    }));
    let lift_done = until_event(
        &mut run,
        20_000,
        |e| matches!(e, E::ChainComplete { group, record: 1, .. } if *group == lift),
        &mut events,
    )
    .expect("lift chain completes");
    let gantry_done = until_event(
        &mut run,
        20_000,
        |e| matches!(e, E::ChainComplete { group, record: 13, .. } if *group == gantry),
        &mut events,
    )
    .expect("gantry chain completes at 13");
    assert!(
        gantry_done > lift_done,
        "the gantry went on only after the lift reached record 1"
    );
    let st = run.stepper.cycle.group_status(gantry).unwrap();
    assert!(st.chain.rcc && st.chain.rc1, "{st:?}");
    assert!(
        run.io.summary.faults.is_empty(),
        "{:?}",
        run.io.summary.faults
    );
}

#[test]
fn an_input_edge_takes_the_alternative_branch() {
    use coordinator::event::Event as E;
    let plan = example();
    let mut run = ready(&plan);
    let gantry = plan.group("gantry").unwrap() as u16;
    latched(run.stepper.cycle.command(&Command::StartChain {
        group: gantry,
        record: 10,
    }));
    let mut events = Vec::new();
    let mut out = Vec::new();
    // Wait for record 11, then raise input 0 during its move: the alternative (13) wins over
    // the primary (12, at MC).
    for _ in 0..5000 {
        run.step_with_events(&mut out, &mut events);
        if run.stepper.cycle.group_status(gantry).unwrap().chain.record == Some(11) {
            break;
        }
    }
    steps(&mut run, 40);
    latched(run.stepper.cycle.command(&Command::SetInput {
        bit: 0,
        value: true,
    }));
    let mut seen = Vec::new();
    for _ in 0..20_000 {
        run.step_with_events(&mut out, &mut events);
        let r = run.stepper.cycle.group_status(gantry).unwrap().chain.record;
        if seen.last() != Some(&r) {
            seen.push(r);
        }
        if events
            .iter()
            .any(|e| matches!(e, E::ChainComplete { group, .. } if *group == gantry))
        {
            break;
        }
    }
    assert!(seen.contains(&Some(13)), "{seen:?}");
    assert!(
        !seen.contains(&Some(12)),
        "the primary branch was not taken: {seen:?}"
    );
}

#[test]
fn stop_aborts_the_chain_and_the_axes_stand() {
    use coordinator::event::Event as E;
    let plan = example();
    let mut run = ready(&plan);
    let gantry = plan.group("gantry").unwrap() as u16;
    latched(run.stepper.cycle.command(&Command::StartChain {
        group: gantry,
        record: 10,
    }));
    steps(&mut run, 100);
    let mut events = Vec::new();
    latched(
        run.stepper
            .cycle
            .command(&Command::Stop(Target::Group(gantry))),
    );
    let aborted = until_event(
        &mut run,
        10,
        |e| matches!(e, E::ChainAborted { group, record: 10, .. } if *group == gantry),
        &mut events,
    );
    assert!(aborted.is_some(), "{events:?}");
    // The move decelerates on its path and is dropped; the setpoints then stay put.
    steps(&mut run, 1000);
    let st = run.stepper.cycle.group_status(gantry).unwrap();
    assert!(
        st.motion.is_none() && st.chain.active.is_none() && !st.chain.rcc,
        "{st:?}"
    );
    let x = plan.axis("x").unwrap() as u16;
    let before = run.stepper.cycle.axis_status(x).unwrap().setpoint;
    steps(&mut run, 100);
    assert_eq!(run.stepper.cycle.axis_status(x).unwrap().setpoint, before);
    // Restart from any record: 13 directly.
    latched(run.stepper.cycle.command(&Command::StartChain {
        group: gantry,
        record: 13,
    }));
    let done = until_event(
        &mut run,
        20_000,
        |e| matches!(e, E::ChainComplete { group, record: 13, .. } if *group == gantry),
        &mut events,
    );
    assert!(done.is_some());
}

#[test]
fn hold_and_resume_continue_the_move_to_its_target() {
    let plan = example();
    let mut run = ready(&plan);
    let g = plan.group("gantry").unwrap() as u16;
    let x = plan.axis("x").unwrap();
    let mut positions = [0i64; MAX_GROUP_AXES];
    positions[0] = plan.axes[x].scale.to_inc(350.0).unwrap();
    positions[1] = plan.axes[plan.axis("y").unwrap()]
        .scale
        .to_inc(200.0)
        .unwrap();
    latched(run.stepper.cycle.command(&Command::MoveGroup {
        group: g,
        positions,
        velocity_percent: 100,
        buffer: BufferMode::Aborting,
    }));
    steps(&mut run, 300);
    latched(run.stepper.cycle.command(&Command::Hold(Target::Group(g))));
    steps(&mut run, 400);
    let held = run.stepper.cycle.axis_status(x as u16).unwrap();
    assert_eq!(held.setpoint_velocity, 0, "stopped on the path: {held:?}");
    assert!(held.setpoint < positions[0]);
    steps(&mut run, 100);
    assert_eq!(
        run.stepper.cycle.axis_status(x as u16).unwrap().setpoint,
        held.setpoint
    );
    latched(run.stepper.cycle.command(&Command::SetOverride {
        target: Target::Group(g),
        percent: 150,
    }));
    latched(
        run.stepper
            .cycle
            .command(&Command::Resume(Target::Group(g))),
    );
    let mut out = Vec::new();
    for _ in 0..10_000 {
        run.step(&mut out);
        if run.stepper.cycle.group_status(g).unwrap().motion.is_none() {
            break;
        }
    }
    let s = run.stepper.cycle.axis_status(x as u16).unwrap();
    assert_eq!(s.setpoint, positions[0]);
    assert!(
        run.io.summary.faults.is_empty(),
        "{:?}",
        run.io.summary.faults
    );
    assert!(matches!(
        run.stepper.cycle.command(&Command::SetOverride {
            target: Target::Group(g),
            percent: 201
        }),
        Reply::Rejected(Rejected::OutOfRange { max: 200, .. })
    ));
}

#[test]
fn in_sync_consumer_mode_the_cycle_follows_the_received_sync() {
    // A SYNC consumer bus must be the only bus: the EMCA joins can0, without its parameter
    // channel (which would not fit there beside the other two drives).
    let text = EXAMPLE
        .replace("sync = \"producer\"", "sync = \"consumer\"")
        .replace("[[buses]]\nname = \"can1\"\nkind = \"simulated\"", "")
        .replace("bus = \"can1\"\nnode = 2", "bus = \"can0\"\nnode = 2")
        .replace("fpc = true  ", "fpc = false ");
    assert_eq!(text.matches("[[buses]]").count(), 1);
    assert!(text.contains("fpc = false"));
    let plan = plan(&Config::parse(&text).unwrap()).unwrap();
    assert!(!plan.cycle.sync_producer);
    let opts = RunOptions {
        duration: Some(Duration::from_secs(20)),
        ..quiet(true)
    };
    let mut run = VirtualRun::new(&plan, &opts).unwrap();
    let mut out = Vec::new();
    while run.lp.script.phase() != Phase::Done {
        if run.elapsed() >= Duration::from_secs(20) && run.lp.script.phase() == Phase::Running {
            run.shut_down();
        }
        run.step(&mut out);
        assert!(
            run.elapsed() < Duration::from_secs(40),
            "{}",
            String::from_utf8_lossy(&out)
        );
    }
    let cycles = run.cycles();
    let (synced, missed) = (run.io.synced, run.io.missed_syncs);
    let s = run.finish(Duration::ZERO);
    let text = String::from_utf8_lossy(&out);
    // Every cycle was started by a received SYNC, and every SYNC on the bus is the external
    // producer's: the coordinator sent none.
    assert_eq!(synced, cycles, "{s}");
    assert_eq!(missed, 0);
    assert!(
        s.syncs_on_bus >= cycles && s.syncs_on_bus <= cycles + 2,
        "{s}"
    );
    assert!(
        s.faults.is_empty() && s.boot_failures.is_empty(),
        "{s}\n{text}"
    );
    assert!(s.laps >= 1 && s.records_reached >= 3, "{s}\n{text}");
}

#[test]
fn a_missing_drive_is_waited_for_and_booted_when_it_appears_while_the_others_run() {
    let plan = example();
    let mut run = VirtualRun::new(&plan, &quiet(false)).unwrap();
    // The TLC5xx (node 3) is not on the bus yet.
    let port = run.io.drive_mut("z").unwrap().port();
    run.io.buses[0].set_disconnected(port, true);
    let mut out = Vec::new();
    while run.lp.script.phase() != Phase::Running {
        run.step(&mut out);
        assert!(
            run.elapsed() < Duration::from_secs(60),
            "{}",
            String::from_utf8_lossy(&out)
        );
    }
    steps(&mut run, 10);
    let text = String::from_utf8_lossy(&out).to_string();
    // Reported once, by name, bus and kind; not a failure, not a fault.
    assert_eq!(
        text.matches("waiting for node 3 (TLC5xx \"z\") on can0 (simulated)")
            .count(),
        1,
        "{text}"
    );
    assert!(run.io.summary.boot_failures.is_empty(), "{text}");
    assert_eq!(run.io.summary.waiting.len(), 1, "{text}");
    let z = plan.axis("z").unwrap() as u16;
    let st = run.stepper.cycle.axis_status(z).unwrap();
    assert!(!st.online && st.fault == FaultReason::None, "{st:?}");
    // The others run: enabled and homed; the gantry moves.
    for name in ["x", "y", "gripper"] {
        let s = run
            .stepper
            .cycle
            .axis_status(plan.axis(name).unwrap() as u16)
            .unwrap();
        assert!(
            s.feedback.homed && s.mode == AxisMode::On,
            "{name}: {s:?}\n{text}"
        );
    }
    // The lift cannot move; the gantry can.
    assert!(matches!(
        run.stepper.cycle.command(&Command::StartChain {
            group: plan.group("lift").unwrap() as u16,
            record: 0
        }),
        Reply::Rejected(_)
    ));
    latched(run.stepper.cycle.command(&Command::StartChain {
        group: plan.group("gantry").unwrap() as u16,
        record: 13,
    }));
    // The drive is switched on: the coordinator's next probe finds it, configures it, and the
    // axis can be enabled and homed.
    run.io.buses[0].set_disconnected(port, false);
    for _ in 0..2000 {
        if run.stepper.cycle.axis_status(z).unwrap().online {
            break;
        }
        run.step(&mut out);
    }
    let text = String::from_utf8_lossy(&out).to_string();
    assert!(run.stepper.cycle.axis_status(z).unwrap().online, "{text}");
    assert!(
        text.contains("drive ready: node 3 (TLC5xx \"z\") on can0 (simulated)"),
        "{text}"
    );
    latched(run.stepper.cycle.command(&Command::Enable(Target::Axis(z))));
    steps(&mut run, 200);
    latched(run.stepper.cycle.command(&Command::Home(Target::Axis(z))));
    for _ in 0..3000 {
        run.step(&mut out);
        if run.stepper.cycle.axis_status(z).unwrap().feedback.homed {
            break;
        }
    }
    let st = run.stepper.cycle.axis_status(z).unwrap();
    assert!(
        st.feedback.homed && st.fault == FaultReason::None,
        "{st:?}\n{}",
        String::from_utf8_lossy(&out)
    );
}

#[test]
fn a_drive_that_resets_itself_is_faulted_configured_again_and_usable_after_acknowledge() {
    let plan = example();
    let mut run = ready(&plan);
    let x = plan.axis("x").unwrap() as u16;
    let y = plan.axis("y").unwrap() as u16;
    // Another master on can1 resets node 2 (the EMCA) as a power cycle would: it sends its
    // boot-up and comes back pre-operational, its PDO settings at their defaults.
    let mut other = run.io.buses[1].attach("other-master");
    other
        .send(&drivers::can::Frame::new_std(0x000, &[0x81, 2]).unwrap())
        .unwrap();
    let mut out = Vec::new();
    for _ in 0..50 {
        run.step(&mut out);
        if run.stepper.cycle.axis_status(y).unwrap().fault != FaultReason::None {
            break;
        }
    }
    let st = run.stepper.cycle.axis_status(y).unwrap();
    assert_eq!(st.fault, FaultReason::DriveReset, "{st:?}");
    // Its group quick-stops with it.
    assert_eq!(
        run.stepper.cycle.axis_status(x).unwrap().mode,
        AxisMode::QuickStopped
    );
    // Configured again and back in the cycle, still faulted until acknowledged.
    for _ in 0..2000 {
        run.step(&mut out);
        if run.stepper.cycle.axis_status(y).unwrap().online {
            break;
        }
    }
    let text = String::from_utf8_lossy(&out).to_string();
    assert!(text.contains("drive reset: node 2 (EMCA \"y\")"), "{text}");
    assert_eq!(
        text.matches("drive ready: node 2 (EMCA \"y\")").count(),
        1,
        "{text}"
    );
    let st = run.stepper.cycle.axis_status(y).unwrap();
    assert!(st.online && st.fault == FaultReason::DriveReset, "{st:?}");
    steps(&mut run, 20);
    latched(
        run.stepper
            .cycle
            .command(&Command::Acknowledge(Target::All)),
    );
    steps(&mut run, 300);
    let st = run.stepper.cycle.axis_status(y).unwrap();
    assert_eq!(
        (st.fault, st.mode),
        (FaultReason::None, AxisMode::On),
        "{st:?}"
    );
    latched(run.stepper.cycle.command(&Command::Home(Target::Axis(y))));
}

#[test]
fn the_parameter_channel_reads_and_writes_drive_parameters() {
    use coordinator::event::Event as E;
    // x (MTR-DCI, classic FPC) and y (EMCA, EFPC, as in the example) with the parameter
    // channel on PDO2.
    let text = EXAMPLE.replace(
        "guard_time_ms = 100      # node guarding",
        "fpc = true\nguard_time_ms = 100      # node guarding",
    );
    let plan = plan(&Config::parse(&text).unwrap()).unwrap();
    let mut run = ready(&plan);
    let x = plan.axis("x").unwrap() as u16;
    let y = plan.axis("y").unwrap() as u16;
    let mut events = Vec::new();
    let param = |run: &mut VirtualRun<'_>, events: &mut Vec<E>, cmd: Command| {
        // The channel takes one task at a time and needs a "no task"/"no reply" exchange
        // between two: Busy until then.
        let mut tries = 0;
        while run.stepper.cycle.command(&cmd) == Reply::Rejected(Rejected::Busy) {
            tries += 1;
            assert!(tries < 20, "still busy");
            steps(run, 1);
        }
        events.clear();
        until_event(run, 500, |e| matches!(e, E::Parameter { .. }), events).expect("an answer");
        events
            .iter()
            .find_map(|e| match *e {
                E::Parameter {
                    axis,
                    pnu,
                    sub,
                    result,
                    ..
                } => Some((axis, pnu, sub, result)),
                _ => None,
            })
            .unwrap()
    };
    // Write then read back the EMCA's PNU 583 (direct start condition; the boot set it to 1).
    let (a, pnu, sub, r) = param(
        &mut run,
        &mut events,
        Command::ReadParameter {
            axis: y,
            pnu: 583,
            sub: 1,
        },
    );
    assert_eq!((a, pnu, sub, r), (y, 583, 1, Ok(1)));
    let (_, _, _, r) = param(
        &mut run,
        &mut events,
        Command::WriteParameter {
            axis: y,
            pnu: 583,
            sub: 1,
            value: 2,
        },
    );
    assert_eq!(r, Ok(2));
    let (_, _, _, r) = param(
        &mut run,
        &mut events,
        Command::ReadParameter {
            axis: y,
            pnu: 583,
            sub: 1,
        },
    );
    assert_eq!(r, Ok(2));
    // A parameter the MTR-DCI does not have: its error number comes back.
    let (a, _, _, r) = param(
        &mut run,
        &mut events,
        Command::ReadParameter {
            axis: x,
            pnu: 2000,
            sub: 0,
        },
    );
    assert_eq!(a, x);
    assert!(r.is_err(), "{r:?}");
    // One task at a time; no channel on the TLC5xx.
    steps(&mut run, 5);
    latched(run.stepper.cycle.command(&Command::ReadParameter {
        axis: x,
        pnu: 502,
        sub: 0,
    }));
    assert_eq!(
        run.stepper.cycle.command(&Command::ReadParameter {
            axis: x,
            pnu: 502,
            sub: 0
        }),
        Reply::Rejected(Rejected::Busy)
    );
    let z = plan.axis("z").unwrap() as u16;
    assert!(matches!(
        run.stepper.cycle.command(&Command::ReadParameter {
            axis: z,
            pnu: 1,
            sub: 0
        }),
        Reply::Rejected(Rejected::WrongState(_))
    ));
}
