//! The profile's fixed-point arithmetic in two forms, to decide between them
//! (docs/decisions.md): our newtypes (`coordinator::profile::{Time, PathPos, PathRate}`) and the
//! `fixed` crate's `FixedI64<U16>` / `FixedI128<U32>` / `FixedI128<U64>`.
//!
//! Both forms run what `PathMove::step_positions` runs each cycle for a group of three (the
//! override ramp, the phase lookup, the constant-jerk polynomial, the time scaling, each axis's
//! position and velocity) and what the plan runs once per move (the peak acceleration and jerk
//! recomputed from the rounded durations). Before timing, both are run over every cycle of a
//! seven-phase S-curve and must agree bit for bit.
//!
//! Run: `cargo bench -p coordinator --bench fixed_point`

// criterion_group! generates an undocumented `pub fn`.
#![allow(missing_docs)]

use std::hint::black_box;

use coordinator::profile::{PathPos, PathRate, Time};
use criterion::{Criterion, criterion_group, criterion_main};
use fixed::types::extra::{U16, U32, U64};
use fixed::{FixedI64, FixedI128, FixedU128};

const CYCLE_NS: u32 = 1_000_000;
const DELTAS: [i64; 3] = [123_456, -50_000, 7_000];

/// Seven constant-jerk phases: (duration in Q16 cycles, jerk in Q32 sub-units per cycle³).
fn specs() -> [(i64, i128); 7] {
    let (tj, ta, tv) = (40 << 16, 25 << 16, 300 << 16);
    let j: i128 = 1 << 40;
    [
        (tj, j),
        (ta, 0),
        (tj, -j),
        (tv, 0),
        (tj, -j),
        (ta, 0),
        (tj, j),
    ]
}

/// Each form: phases built from `specs`, a step, and the plan's peak recomputation.
trait Form {
    type Phase: Copy;
    fn build() -> ([Self::Phase; 7], i64);
    /// One cycle at `tau` with the override's rate `rate` (changed by `dr`): each axis's
    /// position and velocity.
    fn step(phases: &[Self::Phase; 7], tau: i64, rate: i64, dr: i64) -> [(i64, i64); 3];
    /// (acceleration, jerk) from the peak velocity and the rounded ramp durations.
    fn peaks(vq: i128, tj: u128, ta: u128) -> (i128, i128);
}

struct Newtypes;

#[derive(Clone, Copy, Default)]
struct PhaseN {
    t0: Time,
    s0: PathPos,
    v0: PathRate,
    a0: PathRate,
    j: PathRate,
}

fn eval_n(p: &PhaseN, t: Time) -> (PathPos, PathRate, PathRate) {
    let x = p.a0 / 2 + (p.j / 6).mul_time(t);
    let x = p.v0 + x.mul_time(t);
    let s = p.s0.saturating_add(x.over(t));
    let v = p.v0 + (p.a0 + (p.j / 2).mul_time(t)).mul_time(t);
    let a = p.a0 + p.j.mul_time(t);
    (s, v, a)
}

fn phase_at<P>(phases: &[P; 7], t0: impl Fn(&P) -> i64, tau: i64) -> usize {
    let mut i = 0;
    for (k, p) in phases.iter().enumerate() {
        if t0(p) <= tau {
            i = k;
        }
    }
    i
}

impl Form for Newtypes {
    type Phase = PhaseN;
    fn build() -> ([PhaseN; 7], i64) {
        let mut phases = [PhaseN::default(); 7];
        let (mut s, mut v, mut a, mut t) = (PathPos::ZERO, PathRate::ZERO, PathRate::ZERO, 0);
        for (slot, (dur, j)) in phases.iter_mut().zip(specs()) {
            *slot = PhaseN {
                t0: Time::from_raw(t),
                s0: s,
                v0: v,
                a0: a,
                j: PathRate::from_raw(j),
            };
            (s, v, a) = eval_n(slot, Time::from_raw(dur));
            t += dur;
        }
        (phases, t)
    }
    fn step(phases: &[PhaseN; 7], tau: i64, rate: i64, dr: i64) -> [(i64, i64); 3] {
        let p = &phases[phase_at(phases, |p| p.t0.raw(), tau)];
        let (s, v, a) = eval_n(p, Time::from_raw(tau) - p.t0);
        let (r, dr) = (Time::from_raw(rate), Time::from_raw(dr));
        let _a = a.mul_time(r).mul_time(r) + v.mul_time(dr);
        let v = v.mul_time(r);
        DELTAS.map(|d| (s.of(d), v.per_second(d, CYCLE_NS, 1)))
    }
    fn peaks(vq: i128, tj: u128, ta: u128) -> (i128, i128) {
        let v = PathRate::from_raw(vq);
        let a = (v.raw() << Time::BITS) / (tj + ta) as i128;
        let j = (v.raw() << 32) / (tj * (tj + ta)) as i128;
        (a, j)
    }
}

struct Fixed;

type TimeF = FixedI64<U16>;
type TimeWide = FixedI128<U16>;
type RateF = FixedI128<U32>;
type PosF = FixedI128<U64>;

#[derive(Clone, Copy, Default)]
struct PhaseF {
    t0: TimeF,
    s0: PosF,
    v0: RateF,
    a0: RateF,
    j: RateF,
}

fn eval_f(p: &PhaseF, t: TimeF) -> (PosF, RateF, RateF) {
    let t = TimeWide::from_num(t);
    let mul = |x: RateF| x.saturating_mul_add(t, RateF::ZERO);
    let x = p.a0 / 2 + mul(p.j / 6);
    let x = p.v0 + mul(x);
    // A Q32 distance in sub-units; the path is 2^64 of them, so the bits are the same.
    let s =
        p.s0.saturating_add(PosF::from_bits(mul(x).floor().to_bits() >> 32));
    let v = p.v0 + mul(p.a0 + mul(p.j / 2));
    let a = p.a0 + mul(p.j);
    (s, v, a)
}

/// `delta · rate / 2^96` per second, truncated towards zero, with `fixed`'s types.
fn per_second_f(v: RateF, delta: i64) -> i64 {
    let neg = (delta < 0) != v.is_negative();
    let q16 = FixedU128::<U16>::from_bits(v.unsigned_abs().to_bits() >> 16);
    let r: FixedU128<U16> = q16.saturating_mul_int(u128::from(delta.unsigned_abs())) >> 64u32;
    let r = r.saturating_mul_int(1_000_000_000) / u128::from(CYCLE_NS);
    let r = r.to_num::<u128>().min(i64::MAX as u128) as i64;
    if neg { -r } else { r }
}

impl Form for Fixed {
    type Phase = PhaseF;
    fn build() -> ([PhaseF; 7], i64) {
        let mut phases = [PhaseF::default(); 7];
        let (mut s, mut v, mut a, mut t) = (PosF::ZERO, RateF::ZERO, RateF::ZERO, TimeF::ZERO);
        for (slot, (dur, j)) in phases.iter_mut().zip(specs()) {
            *slot = PhaseF {
                t0: t,
                s0: s,
                v0: v,
                a0: a,
                j: RateF::from_bits(j),
            };
            (s, v, a) = eval_f(slot, TimeF::from_bits(dur));
            t += TimeF::from_bits(dur);
        }
        (phases, t.to_bits())
    }
    fn step(phases: &[PhaseF; 7], tau: i64, rate: i64, dr: i64) -> [(i64, i64); 3] {
        let p = &phases[phase_at(phases, |p| p.t0.to_bits(), tau)];
        let (s, v, a) = eval_f(p, TimeF::from_bits(tau) - p.t0);
        let (r, dr) = (
            TimeWide::from_bits(rate.into()),
            TimeWide::from_bits(dr.into()),
        );
        let mul = |x: RateF, t: TimeWide| x.saturating_mul_add(t, RateF::ZERO);
        let _a = mul(mul(a, r), r) + mul(v, dr);
        let v = mul(v, r);
        // delta · s rounded to nearest, ties towards +∞: + 1/2, then floor.
        let half = PosF::from_bits(1 << 63);
        DELTAS.map(|d| {
            let p = (s.saturating_mul_int(d.into()) + half).floor();
            (p.to_num::<i64>(), per_second_f(v, d))
        })
    }
    fn peaks(vq: i128, tj: u128, ta: u128) -> (i128, i128) {
        let v = RateF::from_bits(vq);
        let a = v / RateF::from_bits(((tj + ta) << 16) as i128);
        let j = v / RateF::from_bits((tj * (tj + ta)) as i128);
        (a.to_bits(), j.to_bits())
    }
}

/// The cycles of the S-curve at 80 % override, ramping from 100 %.
fn run<F: Form>(phases: &[F::Phase; 7], duration: i64, mut out: impl FnMut([(i64, i64); 3])) {
    let (mut tau, mut rate) = (0i64, 1 << 16);
    while tau < duration {
        let before = rate;
        rate = (rate - 300).max(52_429);
        tau += rate;
        out(F::step(phases, tau.min(duration - 1), rate, rate - before));
    }
}

fn same_results() {
    let (pn, dn) = Newtypes::build();
    let (pf, df) = Fixed::build();
    assert_eq!(dn, df);
    let (mut a, mut b) = (Vec::new(), Vec::new());
    run::<Newtypes>(&pn, dn, |x| a.push(x));
    run::<Fixed>(&pf, df, |x| b.push(x));
    assert_eq!(a, b, "the two forms differ");
    assert!(a.len() > 500);
    for (vq, tj, ta) in [(1i128 << 60, 40u128 << 16, 25u128 << 16), (12_345, 3, 0)] {
        assert_eq!(Newtypes::peaks(vq, tj, ta), Fixed::peaks(vq, tj, ta));
    }
}

fn bench_form<F: Form>(c: &mut Criterion, name: &str) {
    let (phases, duration) = F::build();
    let mut tau = 0i64;
    c.bench_function(&format!("{name}: step, group of 3"), |b| {
        b.iter(|| {
            tau = (tau + 52_429) % duration;
            F::step(&phases, black_box(tau), black_box(52_429), black_box(-300))
        })
    });
    c.bench_function(&format!("{name}: plan peaks"), |b| {
        b.iter(|| F::peaks(black_box(1 << 60), black_box(40 << 16), black_box(25 << 16)))
    });
}

fn bench(c: &mut Criterion) {
    same_results();
    bench_form::<Newtypes>(c, "newtypes");
    bench_form::<Fixed>(c, "fixed");
}

criterion_group!(benches, bench);
criterion_main!(benches);
