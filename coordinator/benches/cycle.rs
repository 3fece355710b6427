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
use coordinator::config::Config;
use coordinator::cycle::{BusFrame, CycleInput, CycleOutput};
use coordinator::runtime::plan::{MachinePlan, plan};
use coordinator::runtime::stepper::Captured;
use coordinator::runtime::synthetic;
use criterion::{BatchSize, BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use drivers::can::Frame;

fn machine(n: usize) -> MachinePlan {
    plan(&Config::parse(&synthetic::config(n, 8)).expect("parses")).expect("plans")
}

/// Runs the machine until homed, starts a move in every group, runs a while, captures a step
/// (`synthetic::capture_moving`, which `timing step` replays too).
fn capture(plan: &MachinePlan) -> Captured<'_> {
    synthetic::capture_moving(plan, true).expect("every group moves in the captured cycle")
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("cycle step");
    group.measurement_time(Duration::from_secs(3));
    group.warm_up_time(Duration::from_secs(1));
    for n in [1usize, 8, 32, 128] {
        let plan = machine(n);
        let cap = capture(&plan);
        let slots = cap.images.len();
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
                        images: &mut modbus,
                    };
                    cycle.step(
                        &CycleInput {
                            now: cap.now,
                            frames: &cap.frames,
                            images: &cap.images,
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
