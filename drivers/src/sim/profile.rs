//! The drive-internal setpoint generator: trapezoid position moves, velocity ramps, stops and
//! streamed setpoints, in exact integer arithmetic.
//!
//! Everything here works in *step units*: positions in increments scaled by 2^32 ([`ONE`]),
//! velocities in those units per step, accelerations in those units per step². A [`Scale`]
//! converts the user's inc/s and inc/s² once, when a command is given, so a step costs a few
//! integer operations and a run is identical bit for bit on every machine.

/// Fractional bits of a position: 2^32 sub-units per increment, so that slow velocities and
/// small accelerations at a 250 µs step stay exact enough (1 inc/s² is still ~268 sub-units
/// per step²). The price is a range of ±2^31 increments, the same as the drives' int32.
pub const FRAC_BITS: u32 = 32;
/// One increment in position sub-units.
pub const ONE: i64 = 1 << FRAC_BITS;

const NS_PER_S: i128 = 1_000_000_000;

/// Converts between user units (inc, inc/s, inc/s²) and step units for one step length.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Scale {
    dt_ns: u32,
    /// Steps per second when the step divides a second exactly (250 µs: 4000), else 0: the
    /// conversions to per-second units are then exact multiplications, not 128-bit divisions
    /// (the axis converts its velocity and acceleration every step).
    steps_per_s: u32,
}

fn clamp_i64(v: i128) -> i64 {
    v.clamp(i64::MIN as i128, i64::MAX as i128) as i64
}

impl Scale {
    /// A scale for steps of `dt_ns` nanoseconds (at least 1).
    pub const fn new(dt_ns: u32) -> Self {
        let dt_ns = if dt_ns == 0 { 1 } else { dt_ns };
        let ns_per_s = NS_PER_S as u32;
        Scale {
            dt_ns,
            steps_per_s: if ns_per_s.is_multiple_of(dt_ns) {
                ns_per_s / dt_ns
            } else {
                0
            },
        }
    }
    /// The step length in nanoseconds.
    pub const fn dt_ns(&self) -> u32 {
        self.dt_ns
    }
    /// Increments to position sub-units.
    pub const fn position(&self, inc: i64) -> i64 {
        inc.saturating_mul(ONE)
    }
    /// Position sub-units to whole increments (rounded towards negative infinity).
    pub const fn increments(&self, pos: i64) -> i64 {
        pos >> FRAC_BITS
    }
    /// inc/s to sub-units per step, rounded towards zero (never faster than asked).
    pub fn velocity(&self, inc_per_s: i64) -> i64 {
        clamp_i64((((inc_per_s as i128) * (self.dt_ns as i128)) << FRAC_BITS) / NS_PER_S)
    }
    /// inc/s² to sub-units per step², rounded towards zero but at least 1 for a non-zero
    /// value (a zero rate would never finish a ramp).
    pub fn acceleration(&self, inc_per_s2: u32) -> i64 {
        let dt = self.dt_ns as i128;
        let a = clamp_i64((((inc_per_s2 as i128) * dt * dt) << FRAC_BITS) / (NS_PER_S * NS_PER_S));
        if inc_per_s2 > 0 { a.max(1) } else { 0 }
    }
    /// Sub-units per step to inc/s, rounded towards zero.
    pub fn to_velocity(&self, v: i64) -> i64 {
        if self.steps_per_s != 0 {
            // v·10⁹ / dt is exactly v·(10⁹ / dt): the same quotient without the division.
            return clamp_i64(((v as i128) * self.steps_per_s as i128) >> FRAC_BITS);
        }
        clamp_i64(((v as i128) * NS_PER_S / self.dt_ns as i128) >> FRAC_BITS)
    }
    /// Sub-units per step² to inc/s², rounded towards zero.
    pub fn to_acceleration(&self, a: i64) -> i64 {
        if self.steps_per_s != 0 {
            // dt divides 10⁹, so dt² divides 10¹⁸: an exact quotient, as in `to_velocity`.
            // |a| < 2⁶³ and (10⁹/dt)² ≤ 10¹⁸ < 2⁶⁰: the product fits in an i128.
            let k = self.steps_per_s as i128;
            return clamp_i64(((a as i128) * k * k) >> FRAC_BITS);
        }
        let dt = self.dt_ns as i128;
        clamp_i64(((a as i128) * NS_PER_S * NS_PER_S / (dt * dt)) >> FRAC_BITS)
    }
}

/// The largest velocity (sub-units per step) from which the generator can still stop within
/// `dist` sub-units, braking by `dec` per step (exact for the discrete ramp the generator
/// runs: moving `v`, then `v - dec`, `v - 2 dec`, ... covers `f(v) = (n+1) v - dec n(n+1)/2`
/// with `n = floor(v / dec)`).
pub fn brake_velocity(dist: i64, dec: i64) -> i64 {
    if dist <= 0 {
        return 0;
    }
    if dec <= 0 {
        return dist;
    }
    let (d, a) = (dist as u128, dec as u128);
    let q = d / a;
    // Largest n with n(n+1)/2 <= q, i.e. (2n+1)^2 <= 8q+1.
    let n = ((8 * q + 1).isqrt() - 1) / 2;
    let base = a * n * (n + 1) / 2;
    let v = (d + base) / (n + 1);
    v.min(i64::MAX as u128) as i64
}

/// What the generator is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Motion {
    /// No motion; the setpoint stays where it is.
    Idle,
    /// A trapezoid move to a position (sub-units).
    Position {
        /// Target position, sub-units.
        target: i64,
        /// Velocity limit, sub-units per step (> 0).
        vmax: i64,
        /// Acceleration, sub-units per step².
        acc: i64,
        /// Deceleration, sub-units per step².
        dec: i64,
    },
    /// Ramp to a velocity and keep it (velocity mode, jog, and with 0 a stop).
    Velocity {
        /// Target velocity, sub-units per step, signed.
        target: i64,
        /// Acceleration (speeding up), sub-units per step².
        acc: i64,
        /// Deceleration (slowing down), sub-units per step².
        dec: i64,
    },
    /// Linear interpolation to a streamed setpoint over the remaining steps of a cycle.
    Stream {
        /// The setpoint to reach, sub-units.
        target: i64,
        /// Steps left until it is reached (at least 1).
        steps: u32,
    },
}

/// The setpoint generator state: setpoint position and velocity plus the running motion.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Generator {
    /// Setpoint position, sub-units.
    pub pos: i64,
    /// Setpoint velocity, sub-units per step.
    pub vel: i64,
    /// The running motion.
    pub motion: Motion,
}

impl Generator {
    /// A generator at rest at `pos`.
    pub const fn new(pos: i64) -> Self {
        Generator {
            pos,
            vel: 0,
            motion: Motion::Idle,
        }
    }

    /// True when the motion is finished: a position move has arrived with zero velocity, a
    /// velocity ramp has reached its target, a stream its setpoint, or nothing runs.
    pub fn done(&self) -> bool {
        match self.motion {
            Motion::Idle => true,
            Motion::Position { target, .. } => self.pos == target && self.vel == 0,
            Motion::Velocity { target, .. } => self.vel == target,
            Motion::Stream { .. } => false,
        }
    }

    /// Advances the setpoint by one step.
    pub fn step(&mut self) {
        match self.motion {
            Motion::Idle => self.vel = 0,
            Motion::Position {
                target,
                vmax,
                acc,
                dec,
            } => self.step_position(target, vmax, acc, dec),
            Motion::Velocity { target, acc, dec } => {
                self.vel = ramp_velocity(self.vel, target, acc, dec);
                self.pos = self.pos.saturating_add(self.vel);
            }
            Motion::Stream { target, steps } => {
                let steps = steps.max(1);
                let delta = (target as i128 - self.pos as i128) / steps as i128;
                self.vel = delta as i64;
                self.pos = self.pos.saturating_add(self.vel);
                if steps == 1 {
                    self.pos = target;
                    self.motion = Motion::Idle;
                } else {
                    self.motion = Motion::Stream {
                        target,
                        steps: steps - 1,
                    };
                }
            }
        }
    }

    fn step_position(&mut self, target: i64, vmax: i64, acc: i64, dec: i64) {
        let diff = target.saturating_sub(self.pos);
        if diff == 0 && self.vel == 0 {
            return;
        }
        // Work in the direction of the target: `v` > 0 means approaching.
        let dir: i64 = if diff != 0 {
            diff.signum()
        } else {
            -self.vel.signum()
        };
        let dist = diff.saturating_abs();
        let v = self.vel.saturating_mul(dir);
        let next = if v < 0 {
            // Moving away: brake before turning round.
            v.saturating_add(dec).min(0)
        } else {
            let cap = vmax.min(brake_velocity(dist, dec));
            if v > cap {
                (v - dec).max(cap)
            } else {
                v.saturating_add(acc).min(cap)
            }
        };
        self.vel = next * dir;
        self.pos = self.pos.saturating_add(self.vel);
    }
}

/// One step of a velocity ramp from `v` towards `target`: speeding up by `acc`, slowing down
/// (including through zero on a reversal) by `dec`.
pub fn ramp_velocity(v: i64, target: i64, acc: i64, dec: i64) -> i64 {
    if v == target {
        v
    } else if v > 0 && target < v {
        (v - dec).max(target.max(0))
    } else if v < 0 && target > v {
        (v + dec).min(target.min(0))
    } else if target > v {
        v.saturating_add(acc).min(target)
    } else {
        v.saturating_sub(acc).max(target)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_step_conversions_match_the_division() {
        // The multiplication shortcut of a step that divides a second against the division it
        // replaces, over signs, magnitudes and the clamp.
        let slow_v = |dt: i128, v: i64| clamp_i64(((v as i128) * NS_PER_S / dt) >> FRAC_BITS);
        let slow_a = |dt: i128, a: i64| {
            clamp_i64(((a as i128) * NS_PER_S * NS_PER_S / (dt * dt)) >> FRAC_BITS)
        };
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        for dt in [
            1u32,
            1000,
            125_000,
            250_000,
            500_000,
            1_000_000,
            4_000_000,
            1_000_000_000,
        ] {
            let s = Scale::new(dt);
            assert_ne!(s.steps_per_s, 0);
            let mut values = vec![0, 1, -1, i64::MAX, i64::MIN, ONE, -ONE, ONE - 1, 1 - ONE];
            for _ in 0..2000 {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                values.push((x as i64) >> (x % 64));
            }
            for &v in &values {
                assert_eq!(s.to_velocity(v), slow_v(dt as i128, v), "dt {dt} v {v}");
                assert_eq!(s.to_acceleration(v), slow_a(dt as i128, v), "dt {dt} a {v}");
            }
        }
        assert_eq!(Scale::new(300_000).steps_per_s, 0);
    }

    /// The distance the discrete ramp covers braking from `v`, by brute force.
    fn brake_distance(mut v: i64, dec: i64) -> i64 {
        let mut d = 0;
        while v > 0 {
            d += v;
            v -= dec;
        }
        d
    }

    #[test]
    fn brake_velocity_is_the_exact_discrete_inverse() {
        for dec in [1i64, 3, 7, 1000] {
            for dist in 0..5000i64 {
                let v = brake_velocity(dist, dec);
                assert!(
                    brake_distance(v, dec) <= dist,
                    "dist {dist} dec {dec} v {v}"
                );
                assert!(
                    brake_distance(v + 1, dec) > dist,
                    "dist {dist} dec {dec} v {v}"
                );
            }
        }
    }

    #[test]
    fn scale_round_trips_user_units() {
        let s = Scale::new(250_000);
        assert_eq!(s.to_velocity(s.velocity(10_000)), 10_000);
        // Not representable exactly: rounds down, never faster than asked.
        assert_eq!(s.to_velocity(s.velocity(10_001)), 10_000);
        assert_eq!(s.velocity(4_000), ONE);
        assert_eq!(s.acceleration(0), 0);
        assert!(s.acceleration(1) >= 1);
        let a = s.acceleration(100_000);
        assert!((s.to_acceleration(a) - 100_000).abs() <= 1);
    }

    #[test]
    fn velocity_ramp_reverses_through_zero_with_the_deceleration() {
        let mut v = 10;
        let mut seen = [0i64; 8];
        for s in seen.iter_mut() {
            v = ramp_velocity(v, -4, 1, 5);
            *s = v;
        }
        assert_eq!(seen, [5, 0, -1, -2, -3, -4, -4, -4]);
    }

    #[test]
    fn position_move_lands_exactly() {
        let mut g = Generator::new(0);
        g.motion = Motion::Position {
            target: 1_000_003,
            vmax: 5_000,
            acc: 7,
            dec: 11,
        };
        let mut steps = 0;
        while !g.done() {
            let before = g.vel;
            g.step();
            assert!(g.vel <= 5_000 && g.vel >= 0);
            assert!(g.vel - before <= 7 && before - g.vel <= 11);
            steps += 1;
            assert!(steps < 10_000);
        }
        assert_eq!(g.pos, 1_000_003);
    }
}

#[cfg(test)]
mod proptests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// Any move from any start lands exactly on the target and never exceeds the
        /// velocity, acceleration or deceleration it was given, in user units and in step
        /// units.
        #[test]
        fn moves_land_exactly_within_limits(
            dt_us in prop::sample::select(vec![100u32, 250, 500, 1000]),
            start in -200_000i64..200_000,
            target in -200_000i64..200_000,
            v_user in 500u32..120_000,
            a_user in 5_000u32..1_000_000,
            d_user in 5_000u32..1_000_000,
            v0_user in -50_000i64..50_000,
        ) {
            let s = Scale::new(dt_us * 1000);
            let (vmax, acc, dec) = (s.velocity(v_user as i64).max(1), s.acceleration(a_user), s.acceleration(d_user));
            prop_assert!(s.to_velocity(vmax) <= v_user as i64);
            prop_assert!(s.to_acceleration(acc) <= a_user as i64);
            let mut g = Generator::new(s.position(start));
            // Start in motion (a new target while moving), within the limit.
            g.vel = s.velocity(v0_user.clamp(-(v_user as i64), v_user as i64));
            g.motion = Motion::Position { target: s.position(target), vmax, acc, dec };
            let mut steps = 0u64;
            while !g.done() {
                let before = g.vel;
                g.step();
                prop_assert!(g.vel.abs() <= vmax.max(before.abs()));
                let dv = g.vel - before;
                // Speeding up uses acc, slowing down dec; a reversal only brakes.
                if g.vel.abs() > before.abs() && g.vel.signum() * before.signum() >= 0 {
                    prop_assert!(dv.abs() <= acc, "acc {} > {}", dv.abs(), acc);
                } else {
                    prop_assert!(dv.abs() <= dec, "dec {} > {}", dv.abs(), dec);
                }
                steps += 1;
                prop_assert!(steps < 50_000_000);
            }
            prop_assert_eq!(g.pos, s.position(target));
            prop_assert_eq!(g.vel, 0);
        }
    }
}
