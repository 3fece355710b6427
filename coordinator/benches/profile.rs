//! Criterion benches of the motion profiles: planning a move and evaluating one cycle.
//!
//! Run: `cargo bench -p coordinator --bench profile`

// criterion_group! generates an undocumented `pub fn`.
#![allow(missing_docs)]

use std::hint::black_box;

use coordinator::profile::{AxisLimits, PathMove, SCurve, Shape, Target, Trapezoid};
use criterion::{Criterion, criterion_group, criterion_main};

const CYCLE_NS: u32 = 1_000_000;

fn limits() -> AxisLimits {
    AxisLimits::new(200_000, 2_000_000, 50_000_000)
}

fn bench(c: &mut Criterion) {
    c.bench_function("plan scurve 1 axis", |b| {
        b.iter(|| SCurve::plan(black_box(0), black_box(123_456), limits(), CYCLE_NS))
    });
    // A short move: the peak velocity is found by bisection, the slowest planning case.
    c.bench_function("plan scurve 1 axis short", |b| {
        b.iter(|| SCurve::plan(black_box(0), black_box(1_234), limits(), CYCLE_NS))
    });
    c.bench_function("plan trapezoid 1 axis", |b| {
        b.iter(|| Trapezoid::plan(black_box(0), black_box(123_456), limits(), CYCLE_NS))
    });
    c.bench_function("plan scurve group of 3", |b| {
        b.iter(|| {
            PathMove::plan(
                [0; 3],
                Target::Relative(black_box([123_456, -50_000, 7_000])),
                &[limits(); 3],
                Shape::SCurve,
                CYCLE_NS,
            )
        })
    });
    if let Ok(m) = SCurve::plan(0, 123_456, limits(), CYCLE_NS) {
        let n = m.duration_cycles();
        let mut k = 0;
        c.bench_function("sample scurve 1 axis", |b| {
            b.iter(|| {
                k = (k + 1) % (n + 1);
                m.sample(black_box(k))
            })
        });
    }
    if let Ok(g) = PathMove::plan(
        [0; 3],
        Target::Relative([123_456, -50_000, 7_000]),
        &[limits(); 3],
        Shape::SCurve,
        CYCLE_NS,
    ) {
        let mut run = g.clone();
        c.bench_function("step scurve group of 3", |b| {
            b.iter(|| {
                if run.state() == coordinator::profile::MoveState::Done {
                    run = g.clone();
                }
                run.step()
            })
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
