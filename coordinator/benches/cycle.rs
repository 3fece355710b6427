//! The cycle step at 1, 8, 32 and 128 axes (`cargo bench -p coordinator --bench cycle`).
//!
//! Each machine is the synthetic one of `runtime::synthetic` (the four drive kinds in turn,
//! groups of up to 8), run in virtual time with its simulated drives until every axis is homed
//! and every group is in the middle of a move; then one cycle's state and inputs are captured
//! and the step is measured on copies of them, so every measured step does the same, real
//! work: decode every TPDO and Modbus image, supervise, advance every group's path, run every
//! axis's state machine, encode every RPDO.

// criterion_group! generates an undocumented `pub fn`.
#![allow(missing_docs)]

use std::time::Duration;

use coordinator::axis::Image;
use coordinator::command::{BufferMode, Command, GroupId};
use coordinator::config::Config;
use coordinator::cycle::{BusFrame, CycleInput, CycleOutput};
use coordinator::records::MAX_GROUP_AXES;
use coordinator::runtime::plan::{MachinePlan, plan};
use coordinator::runtime::run::RunOptions;
use coordinator::runtime::script::{Phase, ScriptOptions};
use coordinator::runtime::stepper::Captured;
use coordinator::runtime::synthetic;
use coordinator::runtime::virtual_clock::VirtualRun;
use criterion::{BatchSize, BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use drivers::can::Frame;

fn machine(n: usize) -> MachinePlan {
    plan(&Config::parse(&synthetic::config(n, 8)).expect("parses")).expect("plans")
}

/// Runs the machine until homed, starts a move in every group, runs a while, captures a step.
fn capture(plan: &MachinePlan) -> Captured<'_> {
    let opts = RunOptions {
        duration: None,
        virtual_time: true,
        status_every: None,
        script: ScriptOptions {
            demo: true,
            chains: false,
            home: true,
        },
        shm: None,
        capture: None,
    };
    let mut run = VirtualRun::new(plan, &opts).expect("builds");
    let mut out = Vec::new();
    while run.lp.script.phase() != Phase::Running {
        run.step(&mut out);
        assert!(run.elapsed() < Duration::from_secs(300), "not homed");
    }
    for (g, (_, gs, _)) in plan.groups.iter().enumerate() {
        let mut positions = [0i64; MAX_GROUP_AXES];
        for (i, &a) in gs.axes.iter().enumerate() {
            positions[i] = plan.axes[usize::from(a)].setup.position_max * 3 / 4;
        }
        let reply = run.stepper.cycle.command(&Command::MoveGroup {
            group: g as GroupId,
            positions,
            velocity_percent: 100,
            buffer: BufferMode::Aborting,
        });
        assert!(
            matches!(reply, coordinator::command::Reply::Latched { .. }),
            "group {g}: {reply:?}\n{}",
            String::from_utf8_lossy(&out)
        );
    }
    for _ in 0..20 {
        run.step(&mut out);
    }
    run.lp.capture = true;
    run.step(&mut out);
    let c = run.lp.captured.take().expect("captured");
    assert!(
        (0..plan.groups.len()).all(|g| c
            .cycle
            .group_status(g as GroupId)
            .is_some_and(|s| s.motion.is_some())),
        "every group moves in the captured cycle"
    );
    c
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("cycle step");
    group.measurement_time(Duration::from_secs(3));
    group.warm_up_time(Duration::from_secs(1));
    for n in [1usize, 8, 32, 128] {
        let plan = machine(n);
        let cap = capture(&plan);
        let slots = cap.modbus.len();
        group.throughput(Throughput::Elements(n as u64));
        group.bench_with_input(BenchmarkId::from_parameter(n), &cap, |b, cap| {
            let mut frames = vec![BusFrame::new(0, Frame::std8(0, [0; 8])); 512];
            let mut modbus = vec![Image::default(); slots];
            b.iter_batched_ref(
                || cap.cycle.clone(),
                |cycle| {
                    let mut out = CycleOutput {
                        frames: &mut frames,
                        len: 0,
                        overflow: 0,
                        modbus: &mut modbus,
                    };
                    cycle.step(
                        &CycleInput {
                            now: cap.now,
                            frames: &cap.frames,
                            modbus: &cap.modbus,
                        },
                        &mut out,
                    );
                    out.len
                },
                BatchSize::SmallInput,
            );
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
