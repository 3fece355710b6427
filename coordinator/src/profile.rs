//! Motion profiles in fixed point: trapezoidal and jerk-limited (S-curve) moves, planned once
//! when a segment starts and evaluated in constant time per cycle, and time-synchronised group
//! moves with feed override, hold, resume and quick stop.
//!
//! `core` only: no allocation, no floats, so a run is identical bit for bit on every machine.
//!
//! # How it works
//!
//! Every move, single-axis or group, is one *path*: a normalised path parameter `s` runs from 0
//! to [`PathPos::END`] and axis `i` sits at `start[i] + delta[i] * s / 2^64` (rounded to the
//! nearest increment). All axes share `s`, so they start in the same cycle, stay on the straight
//! line in joint space (within half an increment) and arrive in the same cycle; a single axis is
//! a group of one. The profile of `s` is planned with the tightest per-axis limits converted to
//! path units (`limit[i] * 2^64 / |delta[i]|`), so no axis exceeds its own limits; the
//! group's duration is therefore the slowest axis' duration when one axis is binding, and longer
//! only when different axes bind different limits (no straight-line move can be faster).
//!
//! # Units and fixed point
//!
//! The formats are named types, each written once ([`fixed_point`]):
//!
//! * Positions: increments (`i64`), limited to ±[`MAX_POSITION`].
//! * Time: [`Time`], cycles in Q16 ([`Time::ONE`] = one cycle); phase boundaries need not fall
//!   on cycles.
//! * Path: `s` is a [`PathPos`] in sub-units, [`PathPos::END`] = 2^64 for the whole move; path
//!   velocity, acceleration and jerk are [`PathRate`]s, sub-units per cycle^n with 32
//!   fractional bits. Path limits ([`PathLimits`]) are whole sub-units per cycle^n.
//! * Limits given per axis in inc/s, inc/s², inc/s³ with the cycle in ns.
//!
//! # Limits and exactness
//!
//! Phase durations are rounded *up* to the Q16 time grid and the peak velocity, acceleration
//! and jerk are then recomputed from the rounded durations, which can only lower them: the
//! continuous profile never exceeds a limit. Samples (`Sample`) are the continuous profile at the
//! cycle instants with velocity, acceleration and jerk truncated towards zero, so they never
//! exceed the limits either. Finite differences of the rounded positions differ from the exact
//! ones by the rounding to whole increments (±1 inc per difference). The fixed-point rounding
//! of the plan leaves the computed end within a few sub-units (2^-64 of the move) of the target;
//! from the arrival cycle on the sample is exactly the target.
//!
//! # Feed override, hold, quick stop
//!
//! Override scales the rate of the path's time (`tau += rate` per cycle), ramped by a fixed
//! step per cycle ([`PathMove::set_override_ramp`]; by default a 100 % change takes the plan's
//! `v_max / a_max`). Time scaling multiplies velocity by the rate, acceleration by its square and
//! jerk by its cube: at or below 100 % the limits hold, except that while the rate ramps the
//! `v * dr/dt` term adds up to one more `a_max` with the default ramp (so at most `2 a_max`; the
//! jerk of the ramp's corners is not limited); **above 100 % the limits scale** (up to 2x, 4x, 8x at
//! 200 %). A caller that must never exceed the limits caps the override at 100 %.
//! A hold plans a stop along the path from the current state with the planned deceleration and
//! jerk; resume plans a new move from the stop point to the end with the planned limits. A quick
//! stop does the same as a hold with the quick-stop limits. A hold asked for while the move is
//! already decelerating to its end keeps the plan (it is already stopping).
//!
//! ```
//! use coordinator::profile::{AxisLimits, SCurve};
//! let m = SCurve::plan(0, 10_000, AxisLimits::new(50_000, 500_000, 10_000_000), 1_000_000).unwrap();
//! let n = m.duration_cycles();
//! assert_eq!(m.sample(n).position, 10_000);
//! assert!(m.sample(n / 2).velocity <= 50_000);
//! ```

pub mod fixed_point;

use core::num::NonZeroU128;

pub use fixed_point::{PathPos, PathRate, Time};

/// Fractional bits of time (in cycles), for the planner's raw Q16 durations.
const TIME_BITS: u32 = Time::BITS;
/// Fractional bits of path rates, for the planner's raw Q32 peaks.
const COEF_BITS: u32 = PathRate::BITS;

/// Longest move, in cycles (keeps every product inside `i128`).
pub const MAX_CYCLES: i64 = 1 << 31;
/// Largest position magnitude, increments (keeps `delta * s` inside `i128`).
pub const MAX_POSITION: i64 = 1 << 46;
/// Largest feed override, percent.
pub const MAX_OVERRIDE: u16 = 200;

/// Path limits are capped here so that squares stay inside `u128`.
const LIMIT_CAP: u128 = 1 << 62;
const NS_PER_S: u128 = 1_000_000_000;
const MAX_CYCLE_NS: u32 = 1_000_000_000;

/// The limits of one axis, in increments per second^n.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AxisLimits {
    /// Velocity limit, inc/s.
    pub velocity: u64,
    /// Acceleration limit, inc/s².
    pub acceleration: u64,
    /// Deceleration limit, inc/s².
    pub deceleration: u64,
    /// Jerk limit, inc/s³ (ignored by trapezoids).
    pub jerk: u64,
    /// Quick-stop deceleration, inc/s² (a quick stop uses at least the path's planned
    /// deceleration: it is never gentler than a hold).
    pub quick_stop_deceleration: u64,
    /// Quick-stop jerk, inc/s³ (ignored by trapezoids).
    pub quick_stop_jerk: u64,
}

impl AxisLimits {
    /// Symmetric limits (deceleration = acceleration); the quick stop uses four times the
    /// deceleration and jerk.
    pub const fn new(velocity: u64, acceleration: u64, jerk: u64) -> Self {
        AxisLimits {
            velocity,
            acceleration,
            deceleration: acceleration,
            jerk,
            quick_stop_deceleration: acceleration.saturating_mul(4),
            quick_stop_jerk: jerk.saturating_mul(4),
        }
    }
    /// The same limits with another deceleration.
    pub const fn with_deceleration(mut self, deceleration: u64) -> Self {
        self.deceleration = deceleration;
        self
    }
    /// The same limits with other quick-stop deceleration and jerk.
    pub const fn with_quick_stop(mut self, deceleration: u64, jerk: u64) -> Self {
        self.quick_stop_deceleration = deceleration;
        self.quick_stop_jerk = jerk;
        self
    }
}

/// The profile shape.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    /// Constant acceleration phases (infinite jerk).
    Trapezoid,
    /// Jerk-limited, up to 7 phases.
    SCurve,
}

/// Where a group goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Target<const N: usize> {
    /// Absolute positions, increments.
    Absolute([i64; N]),
    /// Distances from the start, increments.
    Relative([i64; N]),
}

/// Why a move cannot be planned.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum PlanError {
    /// The cycle time is outside 1 ns ..= 1 s.
    #[error("cycle time {0} ns outside 1..=1000000000")]
    BadCycle(u32),
    /// A limit of a moving axis is zero.
    #[error("axis {axis}: {which} limit is zero")]
    ZeroLimit {
        /// Axis index.
        axis: usize,
        /// Which limit.
        which: &'static str,
    },
    /// A start or target position is beyond ±[`MAX_POSITION`].
    #[error("axis {axis}: position {value} beyond ±2^46 increments")]
    PositionRange {
        /// Axis index.
        axis: usize,
        /// The position, increments.
        value: i64,
    },
    /// A limit is so small for the distance that it rounds to zero in path units.
    #[error("axis {axis}: {which} limit too small for a distance of {distance} increments")]
    LimitTooSmall {
        /// Axis index.
        axis: usize,
        /// Which limit.
        which: &'static str,
        /// The axis' distance, increments.
        distance: u64,
    },
    /// The move would take more than [`MAX_CYCLES`] cycles.
    #[error("move takes more than 2^31 cycles (Q16 duration {duration_q16})")]
    TooLong {
        /// The planned duration, Q16 cycles (saturated).
        duration_q16: u128,
    },
}

/// Why a group command was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum CommandError {
    /// Override above [`MAX_OVERRIDE`] percent.
    #[error("override {0} % above 200 %")]
    Override(u16),
    /// Resume needs a group stopped by a hold or quick stop.
    #[error("resume needs a stopped group, state is {0:?}")]
    NotStopped(MoveState),
}

/// Path limits in sub-units per cycle^n (integer part).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PathLimits {
    /// Velocity.
    pub velocity: u128,
    /// Acceleration.
    pub acceleration: u128,
    /// Deceleration.
    pub deceleration: u128,
    /// Jerk (`None` for a trapezoid). Never 0, and so its `Option` has no spare values: an
    /// empty `Option<PathMove>` is told by the move's state, which every cycle reads, not by
    /// this tag, which the cycle leaves out ([`PathMove::for_each_skipped`]).
    pub jerk: Option<NonZeroU128>,
}

/// The path state at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PathSample {
    /// Path parameter (0 ..= [`PathPos::END`]).
    pub s: PathPos,
    /// Path velocity, sub-units per cycle.
    pub v: PathRate,
    /// Path acceleration, sub-units per cycle².
    pub a: PathRate,
    /// Path jerk, sub-units per cycle³.
    pub j: PathRate,
}

/// One axis' setpoint at one cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Sample {
    /// Position, increments (rounded to nearest).
    pub position: i64,
    /// Velocity, inc/s (truncated towards zero).
    pub velocity: i64,
    /// Acceleration, inc/s² (truncated towards zero).
    pub acceleration: i64,
    /// Jerk, inc/s³ (truncated towards zero).
    pub jerk: i64,
}

/// One polynomial piece of a segment: constant jerk from its start time (kept apart, in
/// [`Segment`]'s `t0`). 64 bytes: one cache line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
struct Phase {
    s0: PathPos,
    v0: PathRate,
    a0: PathRate,
    j: PathRate,
}

/// A planned piece of path: up to 7 constant-jerk phases from `start` to `end`.
///
/// Laid out for a cycle that reads one phase: the phases' start times and their count share
/// the first cache line, which finding the running phase reads; each phase is a line of its
/// own after it. So a cycle reads three of the segment's nine lines, not all of them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(C, align(64))]
pub struct Segment {
    /// When each phase starts, path time from the segment's start.
    t0: [Time; 7],
    count: usize,
    phases: [Phase; 7],
    start: PathPos,
    end: PathPos,
    duration: Time,
}

fn ceil_div(a: u128, b: u128) -> u128 {
    if b == 0 { u128::MAX } else { a.div_ceil(b) }
}

fn ceil_sqrt(x: u128) -> u128 {
    let r = x.isqrt();
    if r * r < x { r + 1 } else { r }
}

/// Evaluates a phase `t` after its start: (s, v, a).
fn eval(p: &Phase, t: Time) -> (PathPos, PathRate, PathRate) {
    let x = p.a0 / 2 + (p.j / 6).mul_time(t);
    let x = p.v0 + x.mul_time(t);
    let s = p.s0.saturating_add(x.over(t));
    let v = p.v0 + (p.a0 + (p.j / 2).mul_time(t)).mul_time(t);
    let a = p.a0 + p.j.mul_time(t);
    (s, v, a)
}

/// A phase: duration, jerk, and the acceleration it starts with when it jumps.
type Spec = (Time, PathRate, Option<PathRate>);

impl Segment {
    fn build(
        start: PathPos,
        v0: PathRate,
        a0: PathRate,
        specs: &[Spec],
        end: Option<PathPos>,
    ) -> Segment {
        let mut phases = [Phase::default(); 7];
        let mut t0 = [Time::ZERO; 7];
        let (mut s, mut v, mut a, mut t) = (start, v0, a0, Time::ZERO);
        let mut count = 0;
        for ((slot, start_time), &(dur, j, a_set)) in phases.iter_mut().zip(&mut t0).zip(specs) {
            if let Some(x) = a_set {
                a = x;
            }
            *slot = Phase {
                s0: s,
                v0: v,
                a0: a,
                j,
            };
            *start_time = t;
            (s, v, a) = eval(slot, dur);
            t = t.saturating_add(dur);
            count += 1;
        }
        Segment {
            t0,
            count,
            phases,
            start,
            end: end.unwrap_or(s),
            duration: t,
        }
    }

    /// Duration.
    pub fn duration(&self) -> Time {
        self.duration
    }

    /// Where the segment ends.
    pub fn end(&self) -> PathPos {
        self.end
    }

    /// Index of the phase running at `tau`.
    fn phase_at(&self, tau: Time) -> usize {
        let mut i = 0;
        for (k, &t0) in self.t0[..self.count].iter().enumerate() {
            if t0 <= tau {
                i = k;
            }
        }
        i
    }

    /// The path state `tau` after the segment's start; O(1) (at most 7 phases).
    pub fn at(&self, tau: Time) -> PathSample {
        if tau >= self.duration || self.count == 0 {
            return PathSample {
                s: self.end,
                v: PathRate::ZERO,
                a: PathRate::ZERO,
                j: PathRate::ZERO,
            };
        }
        let tau = tau.max(Time::ZERO);
        let k = self.phase_at(tau);
        let p = &self.phases[k];
        let (s, v, a) = eval(p, tau - self.t0[k]);
        let (lo, hi) = if self.start <= self.end {
            (self.start, self.end)
        } else {
            (self.end, self.start)
        };
        PathSample {
            s: s.clamp(lo, hi),
            v,
            a,
            j: p.j,
        }
    }
}

/// Ramp durations (jerk, constant) in Q16 to reach `v` with acceleration `a` and jerk `j`,
/// rounded up.
fn ramp(v: u128, a: u128, j: Option<u128>) -> (u128, u128) {
    if v == 0 {
        return (0, 0);
    }
    match j {
        None => (0, ceil_div(v << TIME_BITS, a)),
        Some(j) => {
            if v * j >= a * a {
                let tj = ceil_div(a << TIME_BITS, j);
                let total = ceil_div(v << TIME_BITS, a);
                (tj, total.saturating_sub(tj))
            } else {
                (ceil_sqrt(ceil_div(v << (2 * TIME_BITS), j)), 0)
            }
        }
    }
}

/// Plans a rest-to-rest segment over `len` path sub-units from `start`.
fn plan_move(start: PathPos, len: u128, lim: &PathLimits) -> Result<Segment, PlanError> {
    if len == 0 {
        return Ok(Segment::build(
            start,
            PathRate::ZERO,
            PathRate::ZERO,
            &[],
            Some(start),
        ));
    }
    let (am, dm, jm) = (
        lim.acceleration,
        lim.deceleration,
        lim.jerk.map(NonZeroU128::get),
    );
    let len17 = len << (TIME_BITS + 1);
    let twice_ramps = |v: u128| {
        let (tj, ta) = ramp(v, am, jm);
        let (tjd, td) = ramp(v, dm, jm);
        (2 * tj + ta + 2 * tjd + td, (tj, ta, tjd, td))
    };
    let fits = |v: u128| v.checked_mul(twice_ramps(v).0).is_some_and(|x| x <= len17);
    let v = if fits(lim.velocity) {
        lim.velocity
    } else {
        // Distance grows with the peak velocity: bisect for the largest that fits.
        let (mut lo, mut hi) = (0u128, lim.velocity);
        while hi - lo > 1 {
            let mid = lo + (hi - lo) / 2;
            if fits(mid) { lo = mid } else { hi = mid }
        }
        lo.max(1)
    };
    let (ramps, (tj, ta, tjd, td)) = twice_ramps(v);
    let covered = v.saturating_mul(ramps);
    let tv = ceil_div(len17.saturating_sub(covered), 2 * v);
    let t2 = ramps + 2 * tv;
    let duration = 2 * tj + ta + tv + 2 * tjd + td;
    if duration > (MAX_CYCLES as u128) << TIME_BITS {
        return Err(PlanError::TooLong {
            duration_q16: duration,
        });
    }
    // Recompute the peaks from the rounded durations: each can only be lower than planned.
    let vq = (len << (2 * TIME_BITS + 1 + COEF_BITS - TIME_BITS)) / t2;
    let vq = vq as i128;
    let jerk = |tj: u128, ta: u128| -> i128 {
        if tj == 0 {
            0
        } else {
            (vq << 32) / (tj * (tj + ta)) as i128
        }
    };
    let accel = |tj: u128, ta: u128| -> i128 {
        if tj + ta == 0 {
            0
        } else {
            (vq << TIME_BITS) / (tj + ta) as i128
        }
    };
    let (ja, jd) = (jerk(tj, ta), jerk(tjd, td));
    let (aa, ad) = (accel(tj, ta), accel(tjd, td));
    let (ja, jd, aa, ad) = (
        PathRate::from_raw(ja),
        PathRate::from_raw(jd),
        PathRate::from_raw(aa),
        PathRate::from_raw(ad),
    );
    let q16 = |t: u128| Time::from_raw(t as i64);
    let (tj, ta, tv, tjd, td) = (q16(tj), q16(ta), q16(tv), q16(tjd), q16(td));
    let (zero, none) = (Time::ZERO, PathRate::ZERO);
    let specs: [Spec; 7] = if jm.is_some() {
        [
            (tj, ja, Some(none)),
            (ta, none, None),
            (tj, -ja, None),
            (tv, none, Some(none)),
            (tjd, -jd, Some(none)),
            (td, none, None),
            (tjd, jd, None),
        ]
    } else {
        [
            (zero, none, None),
            (ta, none, Some(aa)),
            (zero, none, None),
            (tv, none, Some(none)),
            (zero, none, None),
            (td, none, Some(-ad)),
            (zero, none, None),
        ]
    };
    Ok(Segment::build(
        start,
        PathRate::ZERO,
        PathRate::ZERO,
        &specs,
        Some(PathPos::from_raw(start.raw() + len as i128)),
    ))
}

/// Plans a stop along the path from `now` with deceleration and jerk of `lim`, ending at or
/// before `limit`.
fn plan_stop(now: PathSample, lim: &PathLimits, limit: PathPos) -> Segment {
    // Raw Q16 durations and Q32 rates from here to the phases.
    let vq = now.v.max(PathRate::ZERO).raw();
    let dm = lim.deceleration.max(1);
    let q16 = |t: u128| Time::from_raw(t as i64);
    let q32 = PathRate::from_raw;
    let none = PathRate::ZERO;
    let specs: [Spec; 3] = match lim.jerk.map(NonZeroU128::get) {
        None => {
            let t = ceil_div((vq as u128) << TIME_BITS, dm << COEF_BITS);
            let d = if t == 0 {
                0
            } else {
                (vq << TIME_BITS) / t as i128
            };
            [
                (q16(t), none, Some(q32(-d))),
                (Time::ZERO, none, None),
                (Time::ZERO, none, None),
            ]
        }
        Some(jm) => {
            let jm = jm.max(1);
            let v = (vq >> COEF_BITS) as u128;
            let aq = now.a.raw();
            let a_abs = (aq.unsigned_abs()) >> COEF_BITS;
            let x = jm.saturating_mul(v).saturating_add(a_abs * a_abs / 2);
            let (mut ap, mut t2) = (x.isqrt(), 0u128);
            if ap > dm {
                ap = dm;
                t2 = ceil_div(ceil_div(x - dm * dm, jm) << TIME_BITS, dm);
            }
            if aq < 0 && ap < a_abs {
                ap = a_abs;
            }
            let t1 = if aq >= 0 {
                ceil_div((a_abs + ap) << TIME_BITS, jm)
            } else {
                ceil_div((ap - a_abs) << TIME_BITS, jm)
            };
            let t3 = ceil_div(ap << TIME_BITS, jm);
            let den = (t1 + 2 * t2 + t3) as i128;
            // The peak deceleration that brings the velocity to zero with the rounded durations.
            let apq = if den == 0 {
                0
            } else {
                (2 * (vq << TIME_BITS)).saturating_add(aq.saturating_mul(t1 as i128)) / den
            };
            let j1 = if t1 == 0 {
                0
            } else {
                ((aq + apq) << TIME_BITS) / t1 as i128
            };
            let j3 = if t3 == 0 {
                0
            } else {
                (apq << TIME_BITS) / t3 as i128
            };
            [
                (q16(t1), q32(-j1), Some(q32(aq))),
                (q16(t2), none, Some(q32(-apq))),
                (q16(t3), q32(j3), Some(q32(-apq))),
            ]
        }
    };
    let mut seg = Segment::build(now.s, q32(vq), now.a, &specs, None);
    seg.end = seg.end.clamp(now.s, limit.max(now.s));
    seg
}

/// Converts an axis limit to path units: `lim * 2^64 / dist * (cycle / 1 s)^power`,
/// truncated, capped at 2^62.
fn scale_limit(lim: u64, dist: u128, cycle_ns: u32, power: u32) -> u128 {
    let mut r = (lim as u128).min(LIMIT_CAP) * (PathPos::END.raw() as u128) / dist;
    let c = cycle_ns as u128;
    for _ in 0..power {
        r = r / NS_PER_S * c + (r % NS_PER_S) * c / NS_PER_S;
    }
    r.min(LIMIT_CAP)
}

/// What a group is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MoveState {
    /// Following the move (possibly resumed).
    Moving,
    /// Decelerating along the path after a hold.
    Holding,
    /// Decelerating along the path after a quick stop.
    QuickStopping,
    /// Stopped on the path by a hold or quick stop; can resume.
    Stopped,
    /// Arrived at the target.
    Done,
}

/// A time-synchronised move of `N` axes along a straight line in joint space.
///
/// In declared order ([`PathMove::for_each_skipped`] relies on it): what every cycle reads, then
/// the segment, then the limits, which only planning a stop or a resume reads.
#[derive(Debug, Clone, PartialEq, Eq)]
#[repr(C)]
pub struct PathMove<const N: usize> {
    start: [i64; N],
    delta: [i64; N],
    /// Path time in the current segment.
    tau: Time,
    /// Path time per cycle (the override; `Time::ONE` at 100 %), its target and ramp step.
    rate: Time,
    rate_target: Time,
    rate_step: Time,
    cycle: u64,
    cycle_ns: u32,
    state: MoveState,
    /// The segment running (the plan, or a stop or resume planned since). The plan itself is
    /// not kept: [`PathMove::planned`] recomputes it from the limits, so that the cycle's
    /// swept state does not carry 600 bytes it never reads every cycle.
    seg: Segment,
    limits: PathLimits,
    quick: PathLimits,
}

impl<const N: usize> PathMove<N> {
    /// Plans a move of all axes from `start` to `target`, each within its own `limits`.
    pub fn plan(
        start: [i64; N],
        target: Target<N>,
        limits: &[AxisLimits; N],
        shape: Shape,
        cycle_ns: u32,
    ) -> Result<Self, PlanError> {
        if cycle_ns == 0 || cycle_ns > MAX_CYCLE_NS {
            return Err(PlanError::BadCycle(cycle_ns));
        }
        let mut delta = [0i64; N];
        for axis in 0..N {
            let end = match target {
                Target::Absolute(t) => t[axis],
                Target::Relative(d) => start[axis].saturating_add(d[axis]),
            };
            for value in [start[axis], end] {
                if value.unsigned_abs() > MAX_POSITION as u64 {
                    return Err(PlanError::PositionRange { axis, value });
                }
            }
            delta[axis] = end - start[axis];
        }
        let cap = LIMIT_CAP;
        let scurve = shape == Shape::SCurve;
        let mut lim = [cap; 4];
        let mut quick = [cap; 4];
        for (axis, (l, &d)) in limits.iter().zip(&delta).enumerate() {
            if d == 0 {
                continue;
            }
            let dist = d.unsigned_abs() as u128;
            let all = [
                ("velocity", l.velocity, 1, 0, false),
                ("acceleration", l.acceleration, 2, 1, false),
                ("deceleration", l.deceleration, 2, 2, false),
                ("jerk", l.jerk, 3, 3, false),
                (
                    "quick-stop deceleration",
                    l.quick_stop_deceleration,
                    2,
                    2,
                    true,
                ),
                ("quick-stop jerk", l.quick_stop_jerk, 3, 3, true),
            ];
            for (which, value, power, idx, is_quick) in all {
                if !scurve && power == 3 {
                    continue;
                }
                if value == 0 {
                    return Err(PlanError::ZeroLimit { axis, which });
                }
                let p = scale_limit(value, dist, cycle_ns, power);
                if p == 0 {
                    return Err(PlanError::LimitTooSmall {
                        axis,
                        which,
                        distance: dist as u64,
                    });
                }
                let slot = if is_quick {
                    &mut quick[idx]
                } else {
                    &mut lim[idx]
                };
                *slot = (*slot).min(p);
            }
        }
        let limits = PathLimits {
            velocity: lim[0],
            acceleration: lim[1],
            deceleration: lim[2],
            jerk: NonZeroU128::new(lim[3]).filter(|_| scurve),
        };
        let quick = PathLimits {
            velocity: lim[0],
            acceleration: lim[1],
            deceleration: quick[2].max(lim[2]),
            jerk: NonZeroU128::new(quick[3].max(lim[3])).filter(|_| scurve),
        };
        let len = path_length(&delta);
        let plan = plan_move(PathPos::ZERO, len, &limits)?;
        Ok(PathMove {
            start,
            delta,
            cycle_ns,
            limits,
            quick,
            seg: plan,
            tau: Time::ZERO,
            rate: Time::ONE,
            rate_target: Time::ONE,
            // A 100 % change in v_max / a_max: the v * dr/dt term stays within a_max.
            rate_step: Time::from_raw(
                ((Time::ONE.raw() as u128 * limits.acceleration) / limits.velocity.max(1))
                    .clamp(1, Time::ONE.raw() as u128) as i64,
            ),
            state: if len == 0 {
                MoveState::Done
            } else {
                MoveState::Moving
            },
            cycle: 0,
        })
    }

    /// The planned path limits (sub-units per cycle^n).
    pub fn path_limits(&self) -> PathLimits {
        self.limits
    }

    /// Axis `i`'s share of the planned limits at the override aimed at: its speed limit, inc/s,
    /// and acceleration, inc/s² (truncated): the trapezoid a drive with its own profile
    /// generator runs to follow this path, where the path is a trapezoid. 0 for an axis that
    /// does not move.
    pub fn axis_limits(&self, i: usize) -> (u64, u64) {
        let d = self.delta.get(i).copied().unwrap_or(0);
        let rate = |x: u128, power: u32| {
            PathRate::from_int(x)
                .per_second(d, self.cycle_ns, power)
                .unsigned_abs()
        };
        let (v, a) = (
            rate(self.limits.velocity, 1),
            rate(self.limits.acceleration, 2),
        );
        // The override scales velocity by r and acceleration by r² (time scaling).
        let r = self.rate_target.raw().max(0) as u128;
        let one = Time::ONE.raw() as u128;
        let v = (u128::from(v) * r / one).min(u128::from(u64::MAX)) as u64;
        let a = (u128::from(a) * r * r / (one * one)).min(u128::from(u64::MAX)) as u64;
        (v, a)
    }

    /// The arrival cycle of the plan (without override or hold): the first cycle whose sample
    /// is exactly the target.
    pub fn duration_cycles(&self) -> u64 {
        self.planned().duration.ceil_cycles()
    }

    /// The whole move as [`PathMove::plan`] planned it: the same computation from the same
    /// limits, so the same segment.
    fn planned(&self) -> Segment {
        // It succeeded in `plan` with these limits; the running segment stands in otherwise.
        plan_move(PathPos::ZERO, path_length(&self.delta), &self.limits).unwrap_or(self.seg)
    }

    /// The target positions, increments.
    pub fn target(&self) -> [i64; N] {
        core::array::from_fn(|i| self.start[i] + self.delta[i])
    }

    /// The planned path at cycle `k` after the start (no override, no hold); O(1): the plan
    /// is computed again for each call.
    pub fn path_at(&self, k: u64) -> PathSample {
        self.planned()
            .at(Time::cycles(k.min(MAX_CYCLES as u64 + 1) as i64))
    }

    /// The planned setpoints at cycle `k` after the start (no override, no hold); O(1), the
    /// plan computed again for each call.
    pub fn sample(&self, k: u64) -> [Sample; N] {
        self.samples(self.path_at(k))
    }

    /// The axis positions at path parameter `s`.
    pub fn positions(&self, s: PathPos) -> [i64; N] {
        core::array::from_fn(|i| self.position(i, s))
    }

    fn position(&self, i: usize, s: PathPos) -> i64 {
        self.start[i] + s.of(self.delta[i])
    }

    fn samples(&self, p: PathSample) -> [Sample; N] {
        core::array::from_fn(|i| {
            let d = self.delta[i];
            Sample {
                position: self.position(i, p.s),
                velocity: p.v.per_second(d, self.cycle_ns, 1),
                acceleration: p.a.per_second(d, self.cycle_ns, 2),
                jerk: p.j.per_second(d, self.cycle_ns, 3),
            }
        })
    }

    /// What the group is doing.
    pub fn state(&self) -> MoveState {
        self.state
    }

    /// Cycles stepped so far.
    pub fn cycle(&self) -> u64 {
        self.cycle
    }

    /// The current path state (in the current segment's time, before time scaling).
    pub fn path(&self) -> PathSample {
        self.seg.at(self.tau)
    }

    /// Sets the feed override, 0..=200 %; the rate ramps to it (see the module docs for what
    /// happens above 100 %).
    pub fn set_override(&mut self, percent: u16) -> Result<(), CommandError> {
        if percent > MAX_OVERRIDE {
            return Err(CommandError::Override(percent));
        }
        self.rate_target = Time::from_raw(percent as i64 * Time::ONE.raw() / 100);
        Ok(())
    }

    /// Sets how many cycles the override takes to ramp by 100 % (at least 1; default: the
    /// plan's `v_max / a_max`).
    pub fn set_override_ramp(&mut self, cycles: u32) {
        self.rate_step = Time::from_raw((Time::ONE.raw() / cycles.max(1) as i64).max(1));
    }

    /// Decelerates along the path to a stop with the planned deceleration and jerk.
    pub fn hold(&mut self) {
        if self.state == MoveState::Moving && self.seg.phase_at(self.tau) < 4 {
            self.seg = plan_stop(self.path(), &self.limits, PathPos::END);
            self.tau = Time::ZERO;
            self.state = MoveState::Holding;
        }
    }

    /// Decelerates along the path to a stop with the quick-stop deceleration and jerk.
    pub fn quick_stop(&mut self) {
        if matches!(
            self.state,
            MoveState::Moving | MoveState::Holding | MoveState::QuickStopping
        ) {
            self.seg = plan_stop(self.path(), &self.quick, PathPos::END);
            self.tau = Time::ZERO;
            self.state = MoveState::QuickStopping;
        }
    }

    /// Resumes a stopped group: a new move from the stop point to the target on the same line.
    pub fn resume(&mut self) -> Result<(), CommandError> {
        if self.state != MoveState::Stopped {
            return Err(CommandError::NotStopped(self.state));
        }
        let s = self.seg.end;
        let len = (PathPos::END - s).raw().max(0) as u128;
        // A resumed move is never longer than the whole plan, so this cannot fail.
        self.seg = plan_move(s, len, &self.limits).unwrap_or(self.seg);
        self.tau = Time::ZERO;
        self.state = MoveState::Moving;
        Ok(())
    }

    /// Advances one cycle (override ramp, path time, state) and returns the setpoints.
    pub fn step(&mut self) -> [Sample; N] {
        let p = self.advance();
        self.samples(p)
    }

    /// As [`PathMove::step`], but only the positions and velocities of the first `out.len()` axes
    /// (what a cycle streaming setpoints needs; the acceleration and jerk conversions are the
    /// costly part of a sample).
    pub fn step_positions(&mut self, out: &mut [(i64, i64)]) {
        let p = self.advance();
        for (i, o) in out.iter_mut().enumerate().take(N) {
            *o = (
                self.position(i, p.s),
                p.v.per_second(self.delta[i], self.cycle_ns, 1),
            );
        }
    }

    /// The parts of `motion` that the cycle does not read, each handed to `f` as its first
    /// byte and its length (at most three), so that it need not ask for them ahead of its
    /// step. Of a move, [`PathMove::step_positions`] does not read the segment's phases other
    /// than the running one and the next, nor the limits (only planning a stop or a resume
    /// does). Of no move, only the move's own fields are read: the move's state is the
    /// `Option`'s only niche, so it tells that there is none.
    pub fn for_each_skipped(motion: &Option<Self>, f: &mut impl FnMut(*const u8, usize)) {
        let Some(m) = motion else {
            let from = core::mem::offset_of!(Self, seg);
            let at = (motion as *const Option<Self>).cast::<u8>();
            f(
                at.wrapping_add(from),
                core::mem::size_of::<Option<Self>>() - from,
            );
            return;
        };
        let k = m.seg.phase_at(m.tau);
        let (before, rest) = m.seg.phases.split_at(k);
        let after = &rest[rest.len().min(m.seg.count.saturating_sub(k).min(2))..];
        for part in [before, after] {
            f(part.as_ptr().cast(), core::mem::size_of_val(part));
        }
        // The limits to the end of the move (`repr(C)`: they come last, then padding).
        let from = core::mem::offset_of!(Self, limits);
        f(
            (&m.limits as *const PathLimits).cast(),
            core::mem::size_of::<Self>() - from,
        );
    }

    /// Advances the path by one cycle (override ramp, phase, state) and returns its
    /// time-scaled state.
    fn advance(&mut self) -> PathSample {
        self.cycle += 1;
        let before = self.rate;
        if self.rate < self.rate_target {
            self.rate = (self.rate + self.rate_step).min(self.rate_target);
        } else if self.rate > self.rate_target {
            self.rate = (self.rate - self.rate_step).max(self.rate_target);
        }
        self.tau = self.tau.saturating_add(self.rate);
        let mut p = self.seg.at(self.tau);
        if self.tau >= self.seg.duration {
            self.state = match self.state {
                MoveState::Holding | MoveState::QuickStopping => MoveState::Stopped,
                MoveState::Moving => {
                    if self.seg.end >= PathPos::END {
                        MoveState::Done
                    } else {
                        MoveState::Stopped
                    }
                }
                s => s,
            };
        }
        // Time scaling: v * r, a * r² + v * dr, j * r³ (r = rate per cycle).
        let (r, dr) = (self.rate, self.rate - before);
        p.a = p.a.mul_time(r).mul_time(r) + p.v.mul_time(dr);
        p.j = p.j.mul_time(r).mul_time(r).mul_time(r);
        p.v = p.v.mul_time(r);
        p
    }
}

/// The length of a move's path in sub-units: all of [`PathPos::END`], or none when no axis
/// moves.
fn path_length<const N: usize>(delta: &[i64; N]) -> u128 {
    if delta.iter().all(|&d| d == 0) {
        0
    } else {
        PathPos::END.raw() as u128
    }
}

/// A single-axis trapezoidal move.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Trapezoid(PathMove<1>);

/// A single-axis jerk-limited (S-curve) move.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SCurve(PathMove<1>);

macro_rules! single_axis {
    ($t:ident, $shape:expr) => {
        impl $t {
            /// Plans a move from `start` to `target` (increments) within `limits`.
            pub fn plan(
                start: i64,
                target: i64,
                limits: AxisLimits,
                cycle_ns: u32,
            ) -> Result<Self, PlanError> {
                PathMove::plan(
                    [start],
                    Target::Absolute([target]),
                    &[limits],
                    $shape,
                    cycle_ns,
                )
                .map($t)
            }
            /// The setpoint at cycle `k` after the start; O(1).
            pub fn sample(&self, k: u64) -> Sample {
                self.0.sample(k)[0]
            }
            /// The arrival cycle: the first whose sample is exactly the target.
            pub fn duration_cycles(&self) -> u64 {
                self.0.duration_cycles()
            }
            /// The move as a group of one (for override, hold and quick stop).
            pub fn into_group(self) -> PathMove<1> {
                self.0
            }
        }
    };
}

single_axis!(Trapezoid, Shape::Trapezoid);
single_axis!(SCurve, Shape::SCurve);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plan_answers_the_same_after_holds_and_stops() {
        // The plan is computed again for each query: from the planning limits, never from a
        // stop's (quick-stop) limits or the running segment.
        let limits = [
            AxisLimits::new(50_000, 200_000, 4_000_000).with_quick_stop(9_000_000, 90_000_000),
            AxisLimits::new(20_000, 900_000, 1_000_000),
        ];
        let target = Target::Relative([40_000, -7_000]);
        let mut m = PathMove::plan([0, 10], target, &limits, Shape::SCurve, 2_000_000).unwrap();
        let n = m.duration_cycles();
        // The plan's samples are the path the move runs untouched.
        let mut untouched = m.clone();
        let run: std::vec::Vec<_> = (1..=n + 5).map(|_| untouched.step()).collect();
        for k in 1..=n + 5 {
            assert_eq!(m.sample(k), run[k as usize - 1], "cycle {k}");
        }
        let ks = [0, 1, n / 3, n / 2, n - 1, n, n + 5];
        let before: std::vec::Vec<_> = ks.iter().map(|&k| m.sample(k)).collect();
        for k in 0..n / 2 {
            if k == 50 {
                m.hold();
            }
            if k == 200 {
                m.quick_stop();
            }
            let _ = m.step();
        }
        assert_ne!(m.state(), MoveState::Moving);
        assert_eq!(m.duration_cycles(), n);
        let after: std::vec::Vec<_> = ks.iter().map(|&k| m.sample(k)).collect();
        assert_eq!(before, after);
        assert_eq!(after[0][1].position, 10);
        assert_eq!(after[ks.len() - 1][0].position, 40_000);
    }

    #[test]
    fn a_cycle_asks_for_the_running_phase_and_not_the_limits() {
        // What `for_each_skipped` hands out, the cycle does not ask for ahead of its step: it
        // must leave out nothing `step_positions` reads at the next step (the running phase,
        // the segment's times and ends, the move's own fields) and leave out the limits and
        // at least four of the seven phases.
        let limits = [AxisLimits::new(50_000, 200_000, 4_000_000); 2];
        let target = Target::Relative([40_000, -7_000]);
        let plan = PathMove::plan([0, 10], target, &limits, Shape::SCurve, 2_000_000).unwrap();
        let n = plan.duration_cycles();
        let mut motion = Some(plan);
        let addr = |p: *const u8| p as usize;
        let mut seen_phases = std::collections::BTreeSet::new();
        for _ in 0..n + 2 {
            let mut skipped = std::vec::Vec::new();
            PathMove::for_each_skipped(&motion, &mut |p, len| {
                skipped.push((addr(p), addr(p) + len))
            });
            let m = motion.as_mut().unwrap();
            let asked = |p: usize, len: usize| skipped.iter().all(|&(a, b)| p + len <= a || b <= p);
            let tau = m.tau.saturating_add(m.rate);
            let k = m.seg.phase_at(tau);
            if tau < m.seg.duration {
                assert!(
                    asked(addr((&m.seg.phases[k] as *const Phase).cast()), 64),
                    "phase {k}"
                );
                seen_phases.insert(k);
            }
            assert!(asked(addr((&m.seg.t0 as *const [Time; 7]).cast()), 64));
            assert!(asked(addr((&m.seg.end as *const PathPos).cast()), 16));
            assert!(asked(addr((&m.tau as *const Time).cast()), 8));
            assert!(asked(addr((&m.delta as *const [i64; 2]).cast()), 16));
            let left_out =
                |p: usize, len: usize| skipped.iter().any(|&(a, b)| a <= p && p + len <= b);
            let lim = core::mem::size_of::<PathLimits>();
            assert!(left_out(addr((&m.limits as *const PathLimits).cast()), lim));
            assert!(left_out(addr((&m.quick as *const PathLimits).cast()), lim));
            let bytes: usize = skipped.iter().map(|&(a, b)| b - a).sum();
            assert!(bytes >= 4 * 64 + 2 * lim, "{bytes} bytes");
            let mut out = [(0, 0); 2];
            m.step_positions(&mut out);
        }
        // An S-curve runs through all seven phases, and each was asked for in its turn.
        assert_eq!(seen_phases.len(), 7);
        // No move: its own fields are asked for (its state tells `None`), not its segment.
        // The state is the `Option`'s only niche: no tag of its own.
        assert_eq!(
            core::mem::size_of::<Option<PathMove<2>>>(),
            core::mem::size_of::<PathMove<2>>()
        );
        let none: Option<PathMove<2>> = None;
        let at = addr((&none as *const Option<PathMove<2>>).cast());
        let mut skipped = std::vec::Vec::new();
        PathMove::for_each_skipped(&none, &mut |p, len| skipped.push((addr(p) - at, len)));
        let seg = core::mem::offset_of!(PathMove<2>, seg);
        assert_eq!(skipped, [(seg, core::mem::size_of::<PathMove<2>>() - seg)]);
        assert!(core::mem::offset_of!(PathMove<2>, state) < seg);
    }

    #[test]
    fn step_positions_matches_step() {
        let limits = [AxisLimits::new(50_000, 200_000, 4_000_000); 3];
        let start = [0, 100, -5000];
        let target = Target::Absolute([40_000, -20_000, 3]);
        let mut a = PathMove::plan(start, target, &limits, Shape::SCurve, 2_000_000).unwrap();
        let mut b = a.clone();
        let _ = a.set_override(70);
        let _ = b.set_override(70);
        for k in 0..2000 {
            if k == 300 {
                a.hold();
                b.hold();
            }
            if k == 600 {
                let _ = a.resume();
                let _ = b.resume();
            }
            let full = a.step();
            let mut pv = [(0, 0); 2];
            b.step_positions(&mut pv);
            for i in 0..2 {
                assert_eq!(
                    pv[i],
                    (full[i].position, full[i].velocity),
                    "cycle {k} axis {i}"
                );
            }
            assert_eq!(a.state(), b.state());
        }
    }
    use proptest::prelude::*;

    const MS: u32 = 1_000_000;

    fn lim(v: u64, a: u64, j: u64) -> AxisLimits {
        AxisLimits::new(v, a, j)
    }

    /// Checks every planned sample of a group against the limits and the arrival rules.
    fn check_plan<const N: usize>(g: &PathMove<N>, limits: &[AxisLimits; N], shape: Shape, c: u32) {
        let n = g.duration_cycles();
        let target = g.target();
        let mut prev: Option<[Sample; N]> = None;
        // Last three positions per axis, for the second and third differences.
        let mut hist = [[0i64; 3]; N];
        let mut prev_s = PathPos::from_raw(-1);
        for k in 0..=n + 3 {
            let p = g.path_at(k);
            assert!(p.s >= prev_s, "path goes back at cycle {k}");
            assert!(p.s <= PathPos::END);
            prev_s = p.s;
            let smp = g.sample(k);
            for i in 0..N {
                let (l, x) = (&limits[i], smp[i]);
                assert!(x.velocity.unsigned_abs() <= l.velocity, "v {x:?} cycle {k}");
                let amax = l.acceleration.max(l.deceleration);
                assert!(x.acceleration.unsigned_abs() <= amax, "a {x:?} cycle {k}");
                if shape == Shape::SCurve {
                    assert!(x.jerk.unsigned_abs() <= l.jerk, "j {x:?} cycle {k}");
                } else {
                    assert_eq!(x.jerk, 0);
                }
                if let Some(q) = prev {
                    // The motion between samples agrees with the velocity limit (±1 inc of
                    // rounding to whole increments).
                    let step = (x.position - q[i].position).unsigned_abs() as u128;
                    let bound = l.velocity as u128 * c as u128 / 1_000_000_000 + 1;
                    assert!(
                        step <= bound,
                        "axis {i} moved {step} > {bound} at cycle {k}"
                    );
                }
                // Differences of samples of a continuous profile are weighted means of its
                // derivatives, so they obey the limits too, up to the rounding of each position
                // to whole increments (±1/2): 2 for the second difference, 4 for the third.
                let h = hist[i];
                let c = c as u128;
                if k >= 2 {
                    let d2 = (x.position - 2 * h[2] + h[1]).unsigned_abs() as u128;
                    let amax = l.acceleration.max(l.deceleration) as u128;
                    let bound = amax * c * c / 1_000_000_000_000_000_000 + 2;
                    assert!(
                        d2 <= bound,
                        "axis {i} 2nd difference {d2} > {bound} at cycle {k}"
                    );
                }
                if k >= 3 && shape == Shape::SCurve {
                    let d3 = (x.position - 3 * h[2] + 3 * h[1] - h[0]).unsigned_abs() as u128;
                    let jc = (l.jerk as u128 * c / 1_000_000_000) * c / 1_000_000_000 * c;
                    let bound = jc / 1_000_000_000 + 4;
                    assert!(
                        d3 <= bound,
                        "axis {i} 3rd difference {d3} > {bound} at cycle {k}"
                    );
                }
                hist[i] = [h[1], h[2], x.position];
                if k >= n {
                    assert_eq!(x.position, target[i], "not on target at cycle {k} >= {n}");
                    assert_eq!((x.velocity, x.acceleration), (0, 0));
                }
            }
            if k + 1 == n && n > 0 {
                assert!(
                    g.path_at(k).s < PathPos::END,
                    "arrives before its arrival cycle"
                );
            }
            prev = Some(smp);
        }
    }

    #[test]
    fn scurve_long_move_reaches_all_limits_and_target() {
        let l = lim(100_000, 1_000_000, 20_000_000);
        let m = SCurve::plan(1_000, 101_000, l, MS).unwrap();
        let g = m.clone().into_group();
        check_plan(&g, &[l], Shape::SCurve, MS);
        let peak_v = (0..m.duration_cycles()).map(|k| m.sample(k).velocity).max();
        let peak_a = (0..m.duration_cycles())
            .map(|k| m.sample(k).acceleration)
            .max();
        // Within 1 % of the limits: the plan uses them (rounding only lowers them a little).
        assert!(peak_v.unwrap() > 99_000, "{peak_v:?}");
        assert!(peak_a.unwrap() > 990_000, "{peak_a:?}");
        // Continuous time: 1.15 s (2 (v/a + a/j) + (d - 15_000) / v = 0.3 + 0.85).
        assert!(
            (1_150..=1_152).contains(&m.duration_cycles()),
            "{}",
            m.duration_cycles()
        );
    }

    #[test]
    fn trapezoid_and_triangle() {
        let l = lim(100_000, 1_000_000, 1);
        let m = Trapezoid::plan(0, -100_000, l, MS).unwrap();
        check_plan(&m.clone().into_group(), &[l], Shape::Trapezoid, MS);
        // 0.1 s ramps + 0.9 s cruise.
        assert!((1_100..=1_101).contains(&m.duration_cycles()));
        assert!(m.sample(500).velocity <= -99_999);
        // Short move: triangle, never reaching v_max: 2 * sqrt(1000 / 1e6) s = 63.2 ms.
        let t = Trapezoid::plan(0, 1_000, l, MS).unwrap();
        check_plan(&t.clone().into_group(), &[l], Shape::Trapezoid, MS);
        assert!(
            (64..=65).contains(&t.duration_cycles()),
            "{}",
            t.duration_cycles()
        );
        let peak = (0..70).map(|k| t.sample(k).velocity).max().unwrap();
        assert!(peak < 35_000 && peak > 30_000, "{peak}");
    }

    #[test]
    fn scurve_degenerates_for_short_moves() {
        let l = lim(100_000, 1_000_000, 20_000_000);
        for d in [1, 2, 3, 10, 100, 499, 500, 501, 5_000] {
            let m = SCurve::plan(0, d, l, MS).unwrap();
            check_plan(&m.clone().into_group(), &[l], Shape::SCurve, MS);
            assert_eq!(m.sample(m.duration_cycles()).position, d);
        }
        // Very short: no constant-acceleration phase, acceleration stays below a_max:
        // a_peak = (d j² / 2)^(1/3) = (100 * 4e14 / 2)^(1/3) ~ 271_000.
        let m = SCurve::plan(0, 100, l, MS).unwrap();
        let peak = (0..=m.duration_cycles())
            .map(|k| m.sample(k).acceleration)
            .max();
        assert!((250_000..=275_000).contains(&peak.unwrap()), "{peak:?}");
    }

    #[test]
    fn asymmetric_deceleration() {
        let l = lim(50_000, 1_000_000, 50_000_000).with_deceleration(250_000);
        for shape in [Shape::SCurve, Shape::Trapezoid] {
            let g = PathMove::plan([0], Target::Relative([40_000]), &[l], shape, MS).unwrap();
            check_plan(&g, &[l], shape, MS);
            let n = g.duration_cycles();
            let min_a = (0..=n).map(|k| g.sample(k)[0].acceleration).min().unwrap();
            assert!((-250_000..=-240_000).contains(&min_a), "{shape:?} {min_a}");
        }
    }

    fn three_axes() -> ([i64; 3], [i64; 3], [AxisLimits; 3]) {
        (
            [100, -2_000, 7],
            [40_000, -70_000, 3_000],
            [
                lim(80_000, 400_000, 8_000_000),
                lim(150_000, 900_000, 30_000_000),
                lim(5_000, 300_000, 2_000_000),
            ],
        )
    }

    #[test]
    fn group_arrives_in_one_cycle_on_a_straight_line() {
        let (start, d, l) = three_axes();
        for shape in [Shape::SCurve, Shape::Trapezoid] {
            let g = PathMove::plan(start, Target::Relative(d), &l, shape, MS).unwrap();
            check_plan(&g, &l, shape, MS);
            let n = g.duration_cycles();
            let target = g.target();
            assert_eq!(g.sample(n), g.sample(n + 100));
            assert!((0..3).all(|i| g.sample(n)[i].position == target[i]));
            // Slower than every axis alone, but not by more than the straight line needs.
            let alone: [u64; 3] = core::array::from_fn(|i| {
                PathMove::plan([start[i]], Target::Relative([d[i]]), &[l[i]], shape, MS)
                    .unwrap()
                    .duration_cycles()
            });
            assert!(alone.iter().all(|&t| t <= n), "{alone:?} {n}");
            for k in 0..=n {
                let p = g.sample(k);
                for i in 1..3 {
                    // Distance from the line, scaled: |e_i d_0 - e_0 d_i| <= (|d_0| + |d_i|)/2.
                    let cross = (p[i].position - start[i]) as i128 * d[0] as i128
                        - (p[0].position - start[0]) as i128 * d[i] as i128;
                    let bound = (d[0].abs() + d[i].abs()) as i128 / 2 + 1;
                    assert!(
                        cross.abs() <= bound,
                        "off the line at {k}: {cross} > {bound}"
                    );
                }
            }
        }
    }

    #[test]
    fn group_takes_the_slowest_axis_duration_when_it_binds() {
        // Same limits: the longest axis binds every limit, the group takes exactly its time.
        let l = [lim(100_000, 1_000_000, 20_000_000); 2];
        let g = PathMove::plan(
            [0, 0],
            Target::Absolute([80_000, -30_000]),
            &l,
            Shape::SCurve,
            MS,
        )
        .unwrap();
        let alone = SCurve::plan(0, 80_000, l[0], MS).unwrap();
        assert_eq!(g.duration_cycles(), alone.duration_cycles());
        // The short axis runs slower than its limit.
        let v = (0..g.duration_cycles())
            .map(|k| g.sample(k)[1].velocity)
            .min()
            .unwrap();
        assert!((-38_000..=-37_000).contains(&v), "{v}");
    }

    fn run<const N: usize>(g: &mut PathMove<N>, cycles: u64) -> ([Sample; N], u64) {
        let mut last = [Sample::default(); N];
        for _ in 0..cycles {
            last = g.step();
        }
        (last, g.cycle())
    }

    #[test]
    fn step_follows_the_plan_at_full_override() {
        let (start, d, l) = three_axes();
        let mut g = PathMove::plan(start, Target::Relative(d), &l, Shape::SCurve, MS).unwrap();
        let plan = g.clone();
        let n = plan.duration_cycles();
        for k in 1..=n + 2 {
            assert_eq!(g.step(), plan.sample(k), "cycle {k}");
        }
        assert_eq!(g.state(), MoveState::Done);
    }

    #[test]
    fn override_scales_time() {
        let l = lim(100_000, 1_000_000, 20_000_000);
        let plan = SCurve::plan(0, 50_000, l, MS).unwrap().into_group();
        let n = plan.duration_cycles();
        for (pct, lo, hi) in [(50u16, 2 * n - 2, 2 * n + 2), (200, n / 2, n / 2 + 2)] {
            let mut g = plan.clone();
            g.set_override_ramp(1);
            g.set_override(pct).unwrap();
            let mut k = 0;
            let mut peak = 0;
            while g.state() != MoveState::Done && k < 10 * n {
                let s = g.step()[0];
                peak = peak.max(s.velocity);
                k += 1;
            }
            assert!((lo..=hi).contains(&k), "{pct} %: {k} cycles, plan {n}");
            assert_eq!(g.step()[0].position, 50_000);
            // Velocity scales with the override: capped at half, or up to twice, v_max.
            let vmax = 100_000 * pct as i64 / 100;
            assert!(peak <= vmax && peak > vmax * 98 / 100, "{pct} %: {peak}");
        }
        // With the default ramp, slowing from 100 % to 30 % in the cruise stays within 2 a_max.
        let mut g = plan.clone();
        run(&mut g, n / 2);
        g.set_override(30).unwrap();
        for _ in 0..n {
            let s = g.step()[0];
            assert!(s.acceleration.abs() <= 2_000_000, "{s:?}");
        }
        let mut g = plan.clone();
        assert_eq!(g.set_override(201), Err(CommandError::Override(201)));
        // 0 % halts the path: the position stays.
        g.set_override_ramp(1);
        run(&mut g, 300);
        g.set_override(0).unwrap();
        let (a, _) = run(&mut g, 2);
        let (b, _) = run(&mut g, 500);
        assert_eq!(a[0].position, b[0].position);
        assert_eq!(b[0].velocity, 0);
        assert_eq!(g.state(), MoveState::Moving);
    }

    /// Steps until the state leaves `from`, checking limits and the line; returns samples seen.
    fn stop_and_check(
        g: &mut PathMove<3>,
        from: MoveState,
        l: &[AxisLimits; 3],
        quick: bool,
    ) -> u64 {
        let (start, d, _) = three_axes();
        let mut k = 0;
        while g.state() == from {
            let p = g.step();
            k += 1;
            assert!(k < 100_000);
            for i in 0..3 {
                let dec = if quick {
                    l[i].quick_stop_deceleration
                } else {
                    l[i].deceleration
                };
                let jerk = if quick {
                    l[i].quick_stop_jerk
                } else {
                    l[i].jerk
                };
                assert!(p[i].velocity.unsigned_abs() <= l[i].velocity);
                // One part in 10^4 of rounding in the re-planned stop.
                assert!(
                    p[i].acceleration.unsigned_abs() <= dec + dec / 10_000,
                    "{p:?}"
                );
                assert!(p[i].jerk.unsigned_abs() <= jerk + jerk / 10_000, "{p:?}");
                let cross = (p[i].position - start[i]) as i128 * d[0] as i128
                    - (p[0].position - start[0]) as i128 * d[i] as i128;
                assert!(cross.abs() <= (d[0].abs() + d[i].abs()) as i128 / 2 + 1);
            }
        }
        k
    }

    #[test]
    fn hold_resume_and_quick_stop() {
        let (start, d, l) = three_axes();
        let plan = PathMove::plan(start, Target::Relative(d), &l, Shape::SCurve, MS).unwrap();
        let n = plan.duration_cycles();
        let mut g = plan.clone();
        run(&mut g, n / 3);
        let mut q = g.clone();
        g.hold();
        assert_eq!(g.state(), MoveState::Holding);
        let hold_cycles = stop_and_check(&mut g, MoveState::Holding, &l, false);
        assert_eq!(g.state(), MoveState::Stopped);
        let (at, _) = run(&mut g, 50);
        let (again, _) = run(&mut g, 50);
        assert_eq!(at, again, "a stopped group stays");
        assert!(at.iter().all(|s| s.velocity == 0));
        assert_ne!(at[0].position, g.target()[0]);
        assert_eq!(g.hold(), ());
        g.resume().unwrap();
        assert_eq!(g.resume(), Err(CommandError::NotStopped(MoveState::Moving)));
        stop_and_check(&mut g, MoveState::Moving, &l, false);
        assert_eq!(g.state(), MoveState::Done);
        let end = g.step();
        assert!((0..3).all(|i| end[i].position == g.target()[i]));

        q.quick_stop();
        let quick_cycles = stop_and_check(&mut q, MoveState::QuickStopping, &l, true);
        assert!(
            quick_cycles < hold_cycles,
            "{quick_cycles} >= {hold_cycles}"
        );
        assert_eq!(q.state(), MoveState::Stopped);
        q.resume().unwrap();
        run(&mut q, 10 * n);
        assert_eq!(q.state(), MoveState::Done);
        assert_eq!(q.step().map(|s| s.position), q.target());
    }

    #[test]
    fn hold_while_decelerating_keeps_the_plan() {
        let l = lim(100_000, 1_000_000, 20_000_000);
        let plan = SCurve::plan(0, 50_000, l, MS).unwrap().into_group();
        let n = plan.duration_cycles();
        let mut g = plan.clone();
        run(&mut g, n - 20);
        g.hold();
        assert_eq!(g.state(), MoveState::Moving);
        assert_eq!(g.step(), plan.sample(n - 19));
    }

    #[test]
    fn trapezoid_hold_and_resume() {
        let l = [lim(10_000, 100_000, 1); 2];
        let plan = PathMove::plan(
            [0, 0],
            Target::Relative([20_000, 5_000]),
            &l,
            Shape::Trapezoid,
            MS,
        )
        .unwrap();
        let mut g = plan.clone();
        run(&mut g, 1_000);
        g.hold();
        let mut k = 0;
        while g.state() == MoveState::Holding {
            let p = g.step();
            assert!(p[0].acceleration.abs() <= 100_000);
            k += 1;
        }
        // 10_000 inc/s at 100_000 inc/s² stops in 100 ms.
        assert!((100..=101).contains(&k), "{k}");
        g.resume().unwrap();
        run(&mut g, 5_000);
        assert_eq!(g.step().map(|s| s.position), [20_000, 5_000]);
    }

    #[test]
    fn deterministic_bit_for_bit() {
        let (start, d, l) = three_axes();
        let script = |g: &mut PathMove<3>| {
            let mut out = [0i64; 4];
            for k in 0..6_000u64 {
                match k {
                    200 => g.set_override(150).unwrap(),
                    400 => g.hold(),
                    700 => {
                        let _ = g.resume();
                    }
                    800 => g.set_override(37).unwrap(),
                    900 => g.quick_stop(),
                    1_500 => {
                        let _ = g.resume();
                    }
                    _ => {}
                }
                for s in g.step() {
                    // A simple order-sensitive digest of every field.
                    for (o, x) in
                        out.iter_mut()
                            .zip([s.position, s.velocity, s.acceleration, s.jerk])
                    {
                        *o = o.wrapping_mul(1_000_003).wrapping_add(x);
                    }
                }
            }
            out
        };
        let g = PathMove::plan(start, Target::Relative(d), &l, Shape::SCurve, MS).unwrap();
        let (mut a, mut b) = (g.clone(), g.clone());
        assert_eq!(script(&mut a), script(&mut b));
        assert_eq!(a, b);
        assert_eq!(a.state(), MoveState::Done);
    }

    #[test]
    fn errors_and_zero_moves() {
        let l = lim(1_000, 1_000, 1_000);
        assert_eq!(SCurve::plan(0, 1, l, 0).err(), Some(PlanError::BadCycle(0)));
        assert_eq!(
            SCurve::plan(0, 1, lim(0, 1, 1), MS).err(),
            Some(PlanError::ZeroLimit {
                axis: 0,
                which: "velocity"
            })
        );
        assert!(matches!(
            Trapezoid::plan(0, 1 << 47, l, MS),
            Err(PlanError::PositionRange { axis: 0, .. })
        ));
        // A jerk limit this small cannot move 2^40 increments in path units.
        assert!(matches!(
            SCurve::plan(0, 1 << 40, lim(1, 1, 1), MS),
            Err(PlanError::LimitTooSmall { .. } | PlanError::TooLong { .. })
        ));
        // Trapezoids ignore the jerk.
        assert!(Trapezoid::plan(0, 10, lim(10, 10, 0), MS).is_ok());
        let mut g = PathMove::plan(
            [5, 6],
            Target::Relative([0, 0]),
            &[lim(0, 0, 0); 2],
            Shape::SCurve,
            MS,
        )
        .unwrap();
        assert_eq!(g.state(), MoveState::Done);
        assert_eq!(g.duration_cycles(), 0);
        assert_eq!(g.step().map(|s| s.position), [5, 6]);
    }

    /// Any limit, with small and large ones as likely as the rest.
    fn wide() -> impl Strategy<Value = u64> {
        prop_oneof![any::<u64>(), 1u64..1_000, 1u64..10_000_000_000]
    }

    fn limits_strategy() -> impl Strategy<Value = AxisLimits> {
        (
            1_000u64..2_000_000,
            10_000u64..50_000_000,
            1_000u64..50_000,
            100_000u64..5_000_000_000,
        )
            .prop_map(|(v, a, d_permille, j)| {
                AxisLimits::new(v, a, j).with_deceleration((a * d_permille / 10_000).max(1_000))
            })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(96))]

        #[test]
        fn single_axis_never_exceeds_limits(
            start in -1_000_000i64..1_000_000,
            dist in -2_000_000i64..2_000_000,
            l in limits_strategy(),
            cycle in prop::sample::select(vec![250_000u32, 1_000_000, 4_000_000]),
            scurve in any::<bool>(),
        ) {
            let shape = if scurve { Shape::SCurve } else { Shape::Trapezoid };
            let g = PathMove::plan([start], Target::Relative([dist]), &[l], shape, cycle);
            prop_assert!(g.is_ok(), "{:?}", g);
            if let Ok(g) = g {
                prop_assume!(g.duration_cycles() < 20_000);
                check_plan(&g, &[l], shape, cycle);
            }
        }

        #[test]
        fn groups_arrive_together_within_limits(
            dist in prop::array::uniform3(-500_000i64..500_000),
            l in prop::array::uniform3(limits_strategy()),
            scurve in any::<bool>(),
        ) {
            let shape = if scurve { Shape::SCurve } else { Shape::Trapezoid };
            let g = PathMove::plan([0; 3], Target::Relative(dist), &l, shape, MS);
            prop_assert!(g.is_ok(), "{:?}", g);
            if let Ok(g) = g {
                prop_assume!(g.duration_cycles() < 20_000);
                check_plan(&g, &l, shape, MS);
            }
        }

        #[test]
        fn hold_or_quick_stop_anywhere_then_resume(
            dist in prop::array::uniform2(-300_000i64..300_000),
            l in prop::array::uniform2(limits_strategy()),
            at_permille in 0u64..1_000,
            quick in any::<bool>(),
            scurve in any::<bool>(),
        ) {
            let shape = if scurve { Shape::SCurve } else { Shape::Trapezoid };
            let g = PathMove::plan([0; 2], Target::Relative(dist), &l, shape, MS);
            prop_assert!(g.is_ok(), "{:?}", g);
            let Ok(mut g) = g else { return Ok(()) };
            let n = g.duration_cycles();
            prop_assume!(n < 20_000);
            run(&mut g, n * at_permille / 1_000);
            if quick { g.quick_stop() } else { g.hold() }
            let mut k = 0;
            while matches!(g.state(), MoveState::Holding | MoveState::QuickStopping) {
                let p = g.step();
                k += 1;
                prop_assert!(k <= n + 2, "a stop takes longer than the move");
                for i in 0..2 {
                    let (dec, jerk) = if quick {
                        // A quick stop is never gentler than a hold.
                        (
                            l[i].quick_stop_deceleration.max(l[i].deceleration),
                            l[i].quick_stop_jerk.max(l[i].jerk),
                        )
                    } else {
                        (l[i].deceleration, l[i].jerk)
                    };
                    let amax = dec.max(l[i].acceleration);
                    prop_assert!(p[i].velocity.unsigned_abs() <= l[i].velocity);
                    prop_assert!(p[i].acceleration.unsigned_abs() <= amax + amax / 1_000 + 1, "{:?}", p);
                    if scurve {
                        prop_assert!(p[i].jerk.unsigned_abs() <= jerk + jerk / 1_000 + 1, "{:?}", p);
                    }
                }
            }
            if g.state() == MoveState::Stopped {
                let a = g.step();
                prop_assert_eq!(a, g.step());
                prop_assert!(g.resume().is_ok());
            }
            run(&mut g, 2 * n + 10);
            prop_assert_eq!(g.state(), MoveState::Done);
            prop_assert_eq!(g.step().map(|s| s.position), g.target());
        }

        #[test]
        fn never_panics_on_any_input(
            start in -MAX_POSITION..=MAX_POSITION,
            dist in prop_oneof![-(1i64 << 47)..(1 << 47), -100i64..100],
            v in wide(), a in wide(), d in wide(), j in wide(),
            cycle in prop_oneof![any::<u32>(), 1u32..10_000_000],
            ks in prop::array::uniform4(any::<u64>()),
            scurve in any::<bool>(),
        ) {
            let shape = if scurve { Shape::SCurve } else { Shape::Trapezoid };
            let l = AxisLimits::new(v, a, j).with_deceleration(d);
            if let Ok(mut g) = PathMove::plan([start, 0], Target::Relative([dist, 1]), &[l; 2], shape, cycle) {
                for k in ks {
                    g.sample(k);
                    g.sample(k % 10_000);
                }
                let n = g.duration_cycles();
                g.sample(n);
                g.set_override(200).unwrap();
                g.step();
                g.hold();
                g.step();
                g.quick_stop();
                for _ in 0..50 {
                    g.step();
                }
                let _ = g.resume();
                g.step();
            }
        }
    }
}
