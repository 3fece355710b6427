//! Cost of one simulated axis step: during a trapezoid move (generator, position loop,
//! switches, index) and pushing against a fixed stop in force mode, and one step plus a
//! homing-executor update.
//!
//! Run: `cargo bench -p drivers --no-default-features --features std --bench axis`

// criterion_group! generates an undocumented `pub fn`.
#![allow(missing_docs)]

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use drivers::sim::axis::{Axis, Config, Direction, ForceCommand, Load, Profile, SwitchZone};
use drivers::sim::homing::{Homing, HomingMethod, HomingParams, HomingState};

fn config() -> Config {
    let mut cfg = Config::default();
    cfg.environment.travel = None;
    cfg.environment.limit_negative = Some(SwitchZone::below(-1_000_000));
    cfg.environment.limit_positive = Some(SwitchZone::above(1_000_000));
    cfg.environment.reference = Some(SwitchZone::cam(40_000, 41_000));
    cfg
}

const P: Profile = Profile {
    velocity: 100_000,
    acceleration: 480_000,
    deceleration: 480_000,
};

fn bench(c: &mut Criterion) {
    // A long back-and-forth move so nearly every step accelerates, cruises or brakes.
    let mut axis = Axis::new(config(), 0);
    axis.enable().unwrap();
    let mut target = 500_000;
    c.bench_function("axis_step_position_move", |b| {
        b.iter(|| {
            let s = axis.step();
            if s.generator_done {
                target = -target;
                axis.move_to(target, P).unwrap();
            }
            black_box(axis.status().position)
        })
    });

    let mut cfg = config();
    cfg.environment.load = Load::FixedStop {
        position: 1_000,
        side: Direction::Positive,
    };
    let mut axis = Axis::new(cfg, 0);
    axis.enable().unwrap();
    axis.force(ForceCommand {
        current_ma: 2_000,
        speed_limit: 20_000,
        acceleration: 200_000,
        stroke_limit: None,
    })
    .unwrap();
    c.bench_function("axis_step_force_against_stop", |b| {
        b.iter(|| black_box(axis.step().current_ma))
    });

    let params = HomingParams {
        search_velocity: 20_000,
        crawl_velocity: 1_000,
        travel_velocity: 20_000,
        acceleration: 400_000,
        offset: 0,
        travel_to_offset: false,
        home_position: 0,
        stop_current_ma: 1_500,
        stop_time: core::time::Duration::from_millis(20),
        max_search: None,
    };
    let method = HomingMethod::from_number(11).unwrap();
    let mut axis = Axis::new(config(), 60_000);
    axis.enable().unwrap();
    let mut homing = Homing::new(method, params);
    c.bench_function("axis_step_plus_homing_update", |b| {
        b.iter(|| {
            axis.step();
            if homing.update(&mut axis) != HomingState::Running {
                // Run it again from where it ended (above the cam, method 11 searches down).
                homing = Homing::new(method, params);
            }
            black_box(axis.status().position)
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
