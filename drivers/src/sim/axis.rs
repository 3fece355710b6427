//! The simulated physical axis: setpoint generator, first-order position loop, current
//! limit, loads, switches, index pulse and injectable faults, stepped in virtual time.
//!
//! Positions are kept internally in *raw* sub-increments (see [`super::profile::ONE`]): the
//! physical coordinate the environment (switches, stops, index pulses) is placed in. The
//! positions the drive reports and is commanded in are raw + an origin that
//! [`Axis::set_actual_position`] (homing) moves.

use core::time::Duration;

use super::profile::{FRAC_BITS, Generator, Motion, ONE, Scale, ramp_velocity};
use crate::time::Instant;

/// Largest raw position magnitude in increments; positions are kept well inside the ±2^31
/// that the sub-increment representation allows so sums never overflow.
pub const MAX_POSITION: i64 = 1 << 30;

/// A raw position in whole increments to sub-increments, clamped to the modelled range
/// (configuration values beyond it cannot overflow the arithmetic).
fn sub(inc: i64) -> i64 {
    inc.clamp(-MAX_POSITION, MAX_POSITION) * ONE
}

/// A direction of motion (one type with the CiA 402 homing tables).
pub use crate::cia402::homing::Direction;

/// Encoder, gear and feed: the conversion between increments and the output (written once).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Mechanics {
    /// Encoder increments per motor revolution (after quadrature evaluation).
    pub encoder_increments: u32,
    /// Gear ratio numerator (motor revolutions ...).
    pub gear_num: u32,
    /// ... per `gear_den` output revolutions.
    pub gear_den: u32,
    /// Feed per output revolution in µm (linear axes; for rotary axes use 360_000 for
    /// millidegrees).
    pub feed_um: u32,
}

impl Mechanics {
    /// Increments per output revolution as a fraction (numerator, denominator).
    pub const fn increments_per_output_rev(&self) -> (u64, u64) {
        (
            self.encoder_increments as u64 * self.gear_num as u64,
            self.gear_den as u64,
        )
    }
    /// µm of travel to increments, rounded towards zero.
    pub fn um_to_increments(&self, um: i64) -> i64 {
        let num = um as i128 * self.encoder_increments as i128 * self.gear_num as i128;
        let den = (self.gear_den as i128 * self.feed_um as i128).max(1);
        (num / den) as i64
    }
    /// Increments to µm of travel, rounded towards zero.
    pub fn increments_to_um(&self, inc: i64) -> i64 {
        let num = inc as i128 * self.gear_den as i128 * self.feed_um as i128;
        let den = (self.encoder_increments as i128 * self.gear_num as i128).max(1);
        (num / den) as i64
    }
}

/// A switch's active zone in raw increments, half-open: active for `from <= x < to`. The
/// edges lie exactly at `from` and `to`, whichever way the axis crosses them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SwitchZone {
    /// First active position.
    pub from: i64,
    /// First inactive position above the zone.
    pub to: i64,
}

impl SwitchZone {
    /// Active below `edge` (a negative limit switch).
    pub const fn below(edge: i64) -> Self {
        SwitchZone {
            from: i64::MIN,
            to: edge,
        }
    }
    /// Active from `edge` upwards (a positive limit switch).
    pub const fn above(edge: i64) -> Self {
        SwitchZone {
            from: edge,
            to: i64::MAX,
        }
    }
    /// Active on `from..to` (a cam, e.g. a reference switch).
    pub const fn cam(from: i64, to: i64) -> Self {
        SwitchZone { from, to }
    }
    /// Whether the switch is active at raw position `x`.
    pub const fn contains(&self, x: i64) -> bool {
        self.from <= x && x < self.to
    }
}

/// A load that pushes back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Load {
    /// Free motion.
    None,
    /// A rigid stop: the axis cannot pass `position` (raw increments) in `side` direction;
    /// pressing against it raises the current to the limit.
    FixedStop {
        /// Contact position.
        position: i64,
        /// Which side of the axis the stop is on.
        side: Direction,
    },
    /// A spring that starts at `contact` and needs `stiffness_ma_per_inc` mA more current per
    /// increment of compression.
    Spring {
        /// Contact position.
        contact: i64,
        /// Which side the spring is on.
        side: Direction,
        /// mA per increment of compression (at least 1).
        stiffness_ma_per_inc: u32,
    },
}

/// Where the environment sits, in raw increments.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Environment {
    /// Mechanical end stops (negative, positive); `None` for an endless (rotary) axis.
    pub travel: Option<(i64, i64)>,
    /// Negative limit switch.
    pub limit_negative: Option<SwitchZone>,
    /// Positive limit switch.
    pub limit_positive: Option<SwitchZone>,
    /// Reference (home) switch.
    pub reference: Option<SwitchZone>,
    /// An extra load (fixed stop or spring).
    pub load: Load,
    /// Raw position of one index pulse; the others follow every motor revolution.
    pub index_phase: i64,
}

/// Everything that does not change while the axis runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Config {
    /// Simulation step (sub-cycle), e.g. 250 µs.
    pub step: Duration,
    /// Encoder, gear and feed.
    pub mechanics: Mechanics,
    /// Velocity limit, inc/s.
    pub max_velocity: u32,
    /// Acceleration limit, inc/s².
    pub max_acceleration: u32,
    /// Deceleration limit, inc/s².
    pub max_deceleration: u32,
    /// Quick-stop deceleration, inc/s².
    pub quick_stop_deceleration: u32,
    /// Deceleration of the unpowered axis (friction, brake), inc/s².
    pub coast_deceleration: u32,
    /// Rated current, mA (force commands in ‰ of it are the device's conversion).
    pub rated_current_ma: u32,
    /// Current limit, mA.
    pub current_limit_ma: u32,
    /// Force (or torque) per current, mN (mNm) per A.
    pub force_constant_mn_per_a: u32,
    /// Lumped mass/inertia: mA needed per 1000 inc/s² of acceleration.
    pub inertia_ma_per_kinc_s2: u32,
    /// Time constant of the position loop (1/Kv): the following error at constant velocity
    /// `v` is `v * tau`.
    pub position_time_constant: Duration,
    /// Following-error limit, increments; 0 = not monitored.
    pub following_error_limit: u32,
    /// Standstill: |velocity| at most this (inc/s) ...
    pub standstill_velocity: u32,
    /// ... for at least this long.
    pub standstill_time: Duration,
    /// Quick stop and flag a fault when a limit switch is reached moving towards it.
    pub stop_on_limit_switch: bool,
    /// Where the environment is.
    pub environment: Environment,
}

impl Default for Config {
    /// A Festo MTR-DCI-42-G7 on a DMES-25 (2000 inc, 27/4, 2.5 mm feed: 5.4 inc/µm), 100 mm
    /// of travel; controller and load values are illustrative.
    fn default() -> Self {
        Config {
            step: Duration::from_micros(250),
            mechanics: Mechanics {
                encoder_increments: 2000,
                gear_num: 27,
                gear_den: 4,
                feed_um: 2500,
            },
            max_velocity: 100_000,
            max_acceleration: 480_000,
            max_deceleration: 480_000,
            quick_stop_deceleration: 960_000,
            coast_deceleration: 200_000,
            rated_current_ma: 2_300,
            current_limit_ma: 3_450,
            force_constant_mn_per_a: 50_000,
            inertia_ma_per_kinc_s2: 2,
            position_time_constant: Duration::from_millis(5),
            following_error_limit: 5_000,
            standstill_velocity: 100,
            standstill_time: Duration::from_millis(10),
            stop_on_limit_switch: false,
            environment: Environment {
                travel: Some((-2_000, 542_000)),
                limit_negative: None,
                limit_positive: None,
                reference: None,
                load: Load::None,
                index_phase: 0,
            },
        }
    }
}

/// A move profile: velocity, acceleration, deceleration (clamped to the configured limits).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Profile {
    /// inc/s.
    pub velocity: u32,
    /// inc/s².
    pub acceleration: u32,
    /// inc/s².
    pub deceleration: u32,
}

/// A force (current) command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ForceCommand {
    /// Current to push with, mA; the sign gives the direction.
    pub current_ma: i32,
    /// Speed limit while not in contact, inc/s.
    pub speed_limit: u32,
    /// Acceleration towards the speed limit, inc/s².
    pub acceleration: u32,
    /// Path from the start position after which the drive stops; `None` = not monitored.
    pub stroke_limit: Option<u32>,
}

/// What the axis is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AxisMotion {
    /// Power stage off.
    Disabled,
    /// Enabled, holding the setpoint.
    Idle,
    /// A profile position move.
    Position,
    /// Velocity mode (includes jog).
    Velocity,
    /// Force (current) mode.
    Force,
    /// Decelerating with the profile deceleration (or stopped after it).
    Hold,
    /// Decelerating with the quick-stop deceleration (or stopped after it).
    QuickStop,
    /// Following setpoints streamed every cycle.
    Stream,
}

macro_rules! flags {
    ($(#[$m:meta])* $name:ident { $($(#[$fm:meta])* $f:ident = $v:expr;)* }) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
        pub struct $name(pub u8);
        impl $name {
            $($(#[$fm])* pub const $f: $name = $name($v);)*
            /// No flag set.
            pub const NONE: $name = $name(0);
            /// Whether every flag of `other` is set.
            pub const fn contains(self, other: $name) -> bool { self.0 & other.0 == other.0 }
            /// Whether any flag is set.
            pub const fn any(self) -> bool { self.0 != 0 }
            /// `self` with the flags of `other` set or cleared.
            pub const fn with(self, other: $name, on: bool) -> $name {
                if on { $name(self.0 | other.0) } else { $name(self.0 & !other.0) }
            }
        }
    };
}

flags!(
    /// Switch states (and, in [`Status`], their rising and falling edges).
    Switches {
        /// Negative limit switch.
        LIMIT_NEGATIVE = 1;
        /// Positive limit switch.
        LIMIT_POSITIVE = 2;
        /// Reference switch.
        REFERENCE = 4;
    }
);

flags!(
    /// Latched fault flags; [`Axis::clear_faults`] clears those whose cause is gone.
    Faults {
        /// The following error exceeded [`Config::following_error_limit`].
        FOLLOWING_ERROR = 1;
        /// The supply voltage dropped; the power stage is off.
        SUPPLY_VOLTAGE = 2;
        /// Over-temperature (injected).
        OVER_TEMPERATURE = 4;
        /// The negative limit switch was reached (with [`Config::stop_on_limit_switch`]).
        LIMIT_NEGATIVE = 8;
        /// The positive limit switch was reached (with [`Config::stop_on_limit_switch`]).
        LIMIT_POSITIVE = 16;
        /// Force mode ended at its stroke limit.
        STROKE_LIMIT = 32;
    }
);

/// The outputs of one step. Positions are reported increments (raw + origin).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Status {
    /// Virtual time at the end of the step.
    pub time: Instant,
    /// What the axis is doing.
    pub mode: AxisMotion,
    /// Actual position, inc.
    pub position: i64,
    /// Actual velocity, inc/s.
    pub velocity: i64,
    /// Actual acceleration, inc/s².
    pub acceleration: i64,
    /// Motor current, mA (signed).
    pub current_ma: i32,
    /// Force (torque), mN (mNm).
    pub force_mn: i64,
    /// Generator setpoint, inc.
    pub setpoint: i64,
    /// Generator velocity, inc/s.
    pub setpoint_velocity: i64,
    /// Setpoint - actual position, inc.
    pub following_error: i64,
    /// The generator finished its motion.
    pub generator_done: bool,
    /// |velocity| stayed within the standstill window for the standstill time.
    pub standstill: bool,
    /// The axis pushed against a stop or spring at the current limit this step.
    pub blocked: bool,
    /// Force mode: the speed limit is reached (FHPP SDIR.VLIM).
    pub speed_limited: bool,
    /// Switch states.
    pub switches: Switches,
    /// Switches that became active this step.
    pub rising: Switches,
    /// Switches that became inactive this step.
    pub falling: Switches,
    /// Position of the index pulse crossed this step, if any (the first in the direction of
    /// motion).
    pub index_pulse: Option<i64>,
    /// Latched fault flags.
    pub faults: Faults,
}

/// Why a command was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum AxisError {
    /// The power stage is off.
    #[error("the power stage is off")]
    Disabled,
    /// The supply voltage is down, the power stage cannot be switched on.
    #[error("the supply voltage is down")]
    SupplyVoltage,
    /// A profile value of zero would never finish.
    #[error(
        "profile value is zero: velocity {velocity}, acceleration {acceleration}, deceleration {deceleration}"
    )]
    InvalidProfile {
        /// inc/s.
        velocity: u32,
        /// inc/s².
        acceleration: u32,
        /// inc/s².
        deceleration: u32,
    },
    /// A position outside what the model represents.
    #[error("position {position} inc (raw {raw}) is outside ±{limit}")]
    OutOfRange {
        /// The commanded position, inc.
        position: i64,
        /// The same in raw increments.
        raw: i64,
        /// [`MAX_POSITION`].
        limit: i64,
    },
}

/// Time spent inside a window: the building block for "in the position window for the
/// settling time" (MC) and similar device-level rules.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WindowTimer {
    since: Option<Instant>,
}

impl WindowTimer {
    /// A timer outside the window.
    pub const fn new() -> Self {
        WindowTimer { since: None }
    }
    /// Feeds whether the value is inside the window at `now`; returns the time spent inside
    /// without a break (zero when outside).
    pub fn update(&mut self, inside: bool, now: Instant) -> Duration {
        if inside {
            now - *self.since.get_or_insert(now)
        } else {
            self.since = None;
            Duration::ZERO
        }
    }
    /// Forgets the time spent inside.
    pub fn reset(&mut self) {
        self.since = None;
    }
}

/// The simulated axis.
#[derive(Debug, Clone)]
pub struct Axis {
    cfg: Config,
    scale: Scale,
    /// Position-loop gain per step, Q32 fraction (dt / tau, at most 1).
    alpha: i64,
    now: Instant,
    generator: Generator,
    /// Raw actual position, sub-increments.
    x: i64,
    /// Actual velocity, sub-increments per step.
    v: i64,
    /// Actual acceleration, sub-increments per step².
    a: i64,
    /// Reported = raw + origin (increments).
    origin: i64,
    enabled: bool,
    mode: AxisMotion,
    hold_dec: i64,
    force: Option<ActiveForce>,
    current_override: Option<u32>,
    fe_monitoring: bool,
    limit_stop: bool,
    block_injected: bool,
    supply_down: bool,
    over_temperature: bool,
    faults: Faults,
    switches: Switches,
    index_latch: Option<i64>,
    index_armed: bool,
    still: WindowTimer,
    status: Status,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct ActiveForce {
    current_ma: i32,
    stroke_limit: Option<u32>,
    start: i64,
    speed: i64,
}

impl Axis {
    /// An axis at rest at raw position `raw_position` (increments), power stage off, origin 0.
    pub fn new(cfg: Config, raw_position: i64) -> Self {
        let scale = Scale::new(cfg.step.as_nanos().min(u32::MAX as u128) as u32);
        let tau = cfg.position_time_constant.as_nanos().max(1);
        let alpha = ((scale.dt_ns() as u128) << FRAC_BITS) / tau;
        let alpha = alpha.min(1 << FRAC_BITS) as i64;
        let x = raw_position.clamp(-MAX_POSITION, MAX_POSITION) * ONE;
        let mut axis = Axis {
            cfg,
            scale,
            alpha,
            now: Instant::ZERO,
            generator: Generator::new(x),
            x,
            v: 0,
            a: 0,
            origin: 0,
            enabled: false,
            mode: AxisMotion::Disabled,
            hold_dec: scale.acceleration(cfg.max_deceleration),
            force: None,
            current_override: None,
            fe_monitoring: true,
            limit_stop: cfg.stop_on_limit_switch,
            block_injected: false,
            supply_down: false,
            over_temperature: false,
            faults: Faults::NONE,
            switches: Switches::NONE,
            index_latch: None,
            index_armed: false,
            still: WindowTimer::new(),
            status: Status {
                time: Instant::ZERO,
                mode: AxisMotion::Disabled,
                position: raw_position,
                velocity: 0,
                acceleration: 0,
                current_ma: 0,
                force_mn: 0,
                setpoint: raw_position,
                setpoint_velocity: 0,
                following_error: 0,
                generator_done: true,
                standstill: false,
                blocked: false,
                speed_limited: false,
                switches: Switches::NONE,
                rising: Switches::NONE,
                falling: Switches::NONE,
                index_pulse: None,
                faults: Faults::NONE,
            },
        };
        axis.switches = axis.switch_states(raw_position);
        axis.status.switches = axis.switches;
        axis
    }

    /// The configuration.
    pub fn config(&self) -> &Config {
        &self.cfg
    }
    /// The environment, to move switches and loads while running.
    pub fn environment_mut(&mut self) -> &mut Environment {
        &mut self.cfg.environment
    }
    /// The step-unit conversions of this axis.
    pub fn scale(&self) -> Scale {
        self.scale
    }
    /// Virtual time of the last step.
    pub fn now(&self) -> Instant {
        self.now
    }
    /// Moves the axis' clock to `now` without stepping (at power-on: a drive created on the
    /// monotonic clock starts there, not at its epoch).
    pub fn set_clock(&mut self, now: Instant) {
        self.now = now;
    }
    /// The outputs of the last step.
    pub fn status(&self) -> &Status {
        &self.status
    }
    /// Reported = raw + origin.
    pub fn origin(&self) -> i64 {
        self.origin
    }
    /// The raw actual position, whole increments.
    pub fn raw_position(&self) -> i64 {
        self.x >> FRAC_BITS
    }
    /// Whether the power stage is on.
    pub fn is_enabled(&self) -> bool {
        self.enabled
    }
    /// Whether the actual position is within `window` increments of `target`.
    pub fn in_window(&self, target: i64, window: u32) -> bool {
        self.status.position.abs_diff(target) <= window as u64
    }

    // ---- commands ------------------------------------------------------------------------

    /// Switches the power stage on; the setpoint starts at the actual position.
    pub fn enable(&mut self) -> Result<(), AxisError> {
        if self.supply_down {
            return Err(AxisError::SupplyVoltage);
        }
        if !self.enabled {
            self.enabled = true;
            self.generator = Generator::new(self.x);
            self.mode = AxisMotion::Idle;
        }
        Ok(())
    }

    /// Switches the power stage off: the axis coasts to standstill with the coast
    /// deceleration; its position is still measured.
    pub fn disable(&mut self) {
        self.enabled = false;
        self.force = None;
        self.mode = AxisMotion::Disabled;
    }

    /// A command changed the motion: the status says so before the next step, so that a
    /// loop waiting for `generator_done` does not see the previous motion's.
    fn commanded(&mut self, mode: AxisMotion) {
        self.mode = mode;
        self.status.mode = mode;
        self.status.generator_done = self.generator.done();
    }

    fn check_enabled(&self) -> Result<(), AxisError> {
        if self.enabled {
            Ok(())
        } else {
            Err(AxisError::Disabled)
        }
    }

    fn raw_target(&self, position: i64) -> Result<i64, AxisError> {
        let raw = position.saturating_sub(self.origin);
        if raw.abs() > MAX_POSITION {
            return Err(AxisError::OutOfRange {
                position,
                raw,
                limit: MAX_POSITION,
            });
        }
        Ok(raw * ONE)
    }

    /// Starts a trapezoid move to the absolute position `target` (increments) with the
    /// drive's own generator.
    pub fn move_to(&mut self, target: i64, profile: Profile) -> Result<(), AxisError> {
        self.check_enabled()?;
        if profile.velocity == 0 || profile.acceleration == 0 || profile.deceleration == 0 {
            return Err(AxisError::InvalidProfile {
                velocity: profile.velocity,
                acceleration: profile.acceleration,
                deceleration: profile.deceleration,
            });
        }
        let target = self.raw_target(target)?;
        let s = self.scale;
        let dec = s.acceleration(profile.deceleration.min(self.cfg.max_deceleration));
        self.generator.motion = Motion::Position {
            target,
            vmax: s
                .velocity(profile.velocity.min(self.cfg.max_velocity) as i64)
                .max(1),
            acc: s.acceleration(profile.acceleration.min(self.cfg.max_acceleration)),
            dec,
        };
        self.hold_dec = dec;
        self.force = None;
        self.commanded(AxisMotion::Position);
        Ok(())
    }

    /// Starts a move by `delta` increments from the current setpoint.
    pub fn move_by(&mut self, delta: i64, profile: Profile) -> Result<(), AxisError> {
        let from = match self.generator.motion {
            Motion::Position { target, .. } => target,
            _ => self.generator.pos,
        };
        let start = (from >> FRAC_BITS) + self.origin;
        self.move_to(start.saturating_add(delta), profile)
    }

    /// Ramps to `velocity` inc/s (signed) and keeps it.
    pub fn run_velocity(
        &mut self,
        velocity: i32,
        acceleration: u32,
        deceleration: u32,
    ) -> Result<(), AxisError> {
        self.check_enabled()?;
        if acceleration == 0 || deceleration == 0 {
            return Err(AxisError::InvalidProfile {
                velocity: velocity.unsigned_abs(),
                acceleration,
                deceleration,
            });
        }
        let s = self.scale;
        let v = (velocity as i64).clamp(
            -(self.cfg.max_velocity as i64),
            self.cfg.max_velocity as i64,
        );
        let dec = s.acceleration(deceleration.min(self.cfg.max_deceleration));
        self.generator.motion = Motion::Velocity {
            target: s.velocity(v),
            acc: s.acceleration(acceleration.min(self.cfg.max_acceleration)),
            dec,
        };
        self.hold_dec = dec;
        self.force = None;
        self.commanded(AxisMotion::Velocity);
        Ok(())
    }

    /// Jogs in `dir` at `velocity` inc/s with the maximum acceleration; end it with
    /// [`Axis::hold`].
    pub fn jog(&mut self, dir: Direction, velocity: u32) -> Result<(), AxisError> {
        let v = velocity.min(i32::MAX as u32) as i32 * dir.sign();
        self.run_velocity(v, self.cfg.max_acceleration, self.cfg.max_deceleration)
    }

    /// Force (current) mode: accelerates in the direction of the current's sign up to the
    /// speed limit and pushes with the commanded current against whatever it meets.
    pub fn force(&mut self, cmd: ForceCommand) -> Result<(), AxisError> {
        self.check_enabled()?;
        if cmd.acceleration == 0 {
            return Err(AxisError::InvalidProfile {
                velocity: cmd.speed_limit,
                acceleration: 0,
                deceleration: self.cfg.max_deceleration,
            });
        }
        let s = self.scale;
        let speed = s.velocity(cmd.speed_limit.min(self.cfg.max_velocity) as i64);
        let dec = s.acceleration(self.cfg.max_deceleration);
        self.generator.motion = Motion::Velocity {
            target: speed * cmd.current_ma.signum() as i64,
            acc: s.acceleration(cmd.acceleration.min(self.cfg.max_acceleration)),
            dec,
        };
        self.hold_dec = dec;
        self.force = Some(ActiveForce {
            current_ma: cmd.current_ma,
            stroke_limit: cmd.stroke_limit,
            start: self.x >> FRAC_BITS,
            speed,
        });
        self.commanded(AxisMotion::Force);
        Ok(())
    }

    /// Decelerates to standstill with the deceleration of the running command.
    pub fn hold(&mut self) {
        self.stop_with(self.hold_dec, AxisMotion::Hold);
    }

    /// Decelerates to standstill with the quick-stop deceleration.
    pub fn quick_stop(&mut self) {
        let dec = self.scale.acceleration(self.cfg.quick_stop_deceleration);
        self.stop_with(dec, AxisMotion::QuickStop);
    }

    fn stop_with(&mut self, dec: i64, mode: AxisMotion) {
        self.force = None;
        if !self.enabled {
            return;
        }
        self.generator.motion = Motion::Velocity {
            target: 0,
            acc: dec,
            dec,
        };
        self.commanded(mode);
    }

    /// Makes the actual position the setpoint at once (no ramp): what a drive does when it
    /// has detected a stop it pushed against.
    pub fn stop_at_actual(&mut self) {
        self.generator = Generator::new(self.x);
        self.force = None;
        if self.enabled {
            self.mode = AxisMotion::Idle;
        }
    }

    /// Interpolated modes: a new setpoint (increments) to reach linearly by the end of the
    /// next `cycle`.
    pub fn stream_setpoint(&mut self, position: i64, cycle: Duration) -> Result<(), AxisError> {
        self.check_enabled()?;
        let target = self.raw_target(position)?;
        let steps = (cycle.as_nanos() / self.scale.dt_ns() as u128).clamp(1, u32::MAX as u128);
        self.generator.motion = Motion::Stream {
            target,
            steps: steps as u32,
        };
        self.force = None;
        self.commanded(AxisMotion::Stream);
        Ok(())
    }

    /// Sets the reference: the actual position becomes `value`; the setpoint and latched
    /// positions move with it.
    pub fn set_actual_position(&mut self, value: i64) {
        let old = self.origin;
        self.origin = value.saturating_sub(self.x >> FRAC_BITS);
        if let Some(l) = self.index_latch.as_mut() {
            *l += self.origin - old;
        }
        self.refresh_positions();
    }

    /// Sets the reference so that raw position `raw` reads `value`.
    pub fn set_reference(&mut self, raw: i64, value: i64) {
        let old = self.origin;
        self.origin = value.saturating_sub(raw);
        if let Some(l) = self.index_latch.as_mut() {
            *l += self.origin - old;
        }
        self.refresh_positions();
    }

    fn refresh_positions(&mut self) {
        self.status.position = (self.x >> FRAC_BITS) + self.origin;
        self.status.setpoint = (self.generator.pos >> FRAC_BITS) + self.origin;
        self.status.following_error = self.status.setpoint - self.status.position;
    }

    /// Arms the index latch: the next index pulse crossed is latched.
    pub fn arm_index_latch(&mut self) {
        self.index_armed = true;
        self.index_latch = None;
    }
    /// The latched index position (reported increments), once a pulse was seen after arming.
    pub fn index_latch(&self) -> Option<i64> {
        self.index_latch
    }

    /// Overrides the current limit (homing against a stop uses a lower one); `None` restores
    /// the configured limit.
    pub fn set_current_limit(&mut self, limit_ma: Option<u32>) {
        self.current_override = limit_ma;
    }
    /// Switches following-error monitoring on or off (stop homing pushes on purpose).
    pub fn set_following_error_monitoring(&mut self, on: bool) {
        self.fe_monitoring = on;
    }
    /// Switches the limit-switch stop reaction on or off (limit-switch homing needs it off).
    pub fn set_limit_switch_stop(&mut self, on: bool) {
        self.limit_stop = on;
    }

    // ---- fault injection -----------------------------------------------------------------

    /// Blocks the axis where it is (a jammed mechanism); the current rises to the limit and
    /// the following error grows.
    pub fn inject_block(&mut self, on: bool) {
        self.block_injected = on;
    }
    /// A supply-voltage drop: the power stage goes off at once and stays off while `on`.
    pub fn inject_supply_drop(&mut self, on: bool) {
        self.supply_down = on;
        if on {
            self.faults = self.faults.with(Faults::SUPPLY_VOLTAGE, true);
            self.disable();
        }
    }
    /// Over-temperature of the power stage.
    pub fn inject_over_temperature(&mut self, on: bool) {
        self.over_temperature = on;
        if on {
            self.faults = self.faults.with(Faults::OVER_TEMPERATURE, true);
        }
    }
    /// Clears the latched faults whose cause is gone.
    pub fn clear_faults(&mut self) {
        let mut f = Faults::NONE;
        f = f.with(Faults::SUPPLY_VOLTAGE, self.supply_down);
        f = f.with(Faults::OVER_TEMPERATURE, self.over_temperature);
        self.faults = f;
        self.status.faults = f;
    }

    // ---- the step --------------------------------------------------------------------------

    /// The current limit in effect, mA.
    fn current_limit(&self) -> u32 {
        let lim = self
            .current_override
            .unwrap_or(self.cfg.current_limit_ma)
            .min(self.cfg.current_limit_ma);
        match self.force {
            Some(f) => lim.min(f.current_ma.unsigned_abs()),
            None => lim,
        }
    }

    /// Lowest and highest raw positions (sub-increments) the axis can reach pushing with
    /// `limit_ma`.
    fn bounds(&self, limit_ma: u32) -> (i64, i64) {
        let env = &self.cfg.environment;
        let (mut lo, mut hi) = (-MAX_POSITION * ONE, MAX_POSITION * ONE);
        if let Some((a, b)) = env.travel {
            lo = lo.max(sub(a));
            hi = hi.min(sub(b));
        }
        match env.load {
            Load::None => {}
            Load::FixedStop { position, side } => match side {
                Direction::Positive => hi = hi.min(sub(position)),
                Direction::Negative => lo = lo.max(sub(position)),
            },
            Load::Spring {
                contact,
                side,
                stiffness_ma_per_inc,
            } => {
                let give = (((limit_ma as i128) << FRAC_BITS) / stiffness_ma_per_inc.max(1) as i128)
                    as i64;
                match side {
                    Direction::Positive => hi = hi.min(sub(contact).saturating_add(give)),
                    Direction::Negative => lo = lo.max(sub(contact).saturating_sub(give)),
                }
            }
        }
        if self.block_injected {
            lo = lo.max(self.x.min(hi));
            hi = hi.min(self.x.max(lo));
        }
        (lo, hi.max(lo))
    }

    /// Current the load needs at raw sub-increment position `x`, mA.
    fn load_current(&self, x: i64) -> i64 {
        if let Load::Spring {
            contact,
            side,
            stiffness_ma_per_inc,
        } = self.cfg.environment.load
        {
            let c = sub(contact);
            let k = stiffness_ma_per_inc as i128;
            match side {
                Direction::Positive if x > c => return (((x - c) as i128 * k) >> FRAC_BITS) as i64,
                Direction::Negative if x < c => {
                    return -(((c - x) as i128 * k) >> FRAC_BITS) as i64;
                }
                _ => {}
            }
        }
        0
    }

    fn switch_states(&self, raw: i64) -> Switches {
        let env = &self.cfg.environment;
        let on = |z: Option<SwitchZone>| z.is_some_and(|z| z.contains(raw));
        Switches::NONE
            .with(Switches::LIMIT_NEGATIVE, on(env.limit_negative))
            .with(Switches::LIMIT_POSITIVE, on(env.limit_positive))
            .with(Switches::REFERENCE, on(env.reference))
    }

    /// The first index pulse crossed going from raw `old` to raw `new` (whole increments).
    /// A pulse at `p` sits between `p - 1` and `p`.
    fn index_crossed(&self, old: i64, new: i64) -> Option<i64> {
        let n = self.cfg.mechanics.encoder_increments as i64;
        if n == 0 || old == new {
            return None;
        }
        let phase = self.cfg.environment.index_phase.rem_euclid(n);
        if new > old {
            let p = old + 1 + (phase - (old + 1)).rem_euclid(n);
            (p <= new).then_some(p)
        } else {
            let p = old - (old - phase).rem_euclid(n);
            (p > new).then_some(p)
        }
    }

    /// Advances the axis by one step and returns its outputs.
    pub fn step(&mut self) -> &Status {
        // The scale's step (at least 1 ns) rather than the configured one, so a zero step
        // cannot stall `run_until`.
        self.now += Duration::from_nanos(self.scale.dt_ns() as u64);
        let (x_old, v_old) = (self.x, self.v);
        let limit = self.current_limit();
        let (lo, hi) = self.bounds(if self.enabled { limit } else { 0 });

        let x_des = if self.enabled {
            self.generator.step();
            let e = self.generator.pos.saturating_sub(self.x);
            let mut corr = ((e as i128 * self.alpha as i128) >> FRAC_BITS) as i64;
            if corr == 0 || (e > 0 && corr > e) || (e < 0 && corr < e) {
                // Below one sub-unit of correction the loop has settled: snap, so the
                // following error really vanishes at standstill.
                corr = e;
            }
            self.x.saturating_add(corr)
        } else {
            let dec = self.scale.acceleration(self.cfg.coast_deceleration);
            self.x + ramp_velocity(self.v, 0, dec, dec)
        };
        let x_new = x_des.clamp(lo, hi);
        let blocked = x_new != x_des;
        self.x = x_new;
        self.v = x_new - x_old;
        self.a = self.v - v_old;
        if !self.enabled {
            // The drive's setpoint tracks the actual position so enabling is bumpless.
            self.generator = Generator::new(x_new);
        }

        let (old_i, new_i) = (x_old >> FRAC_BITS, x_new >> FRAC_BITS);
        let mut speed_limited = false;
        if let Some(f) = self.force {
            if blocked {
                // Current-regulated: the drive does not wind up against the load.
                self.generator = Generator {
                    pos: x_new,
                    vel: 0,
                    motion: self.generator.motion,
                };
            }
            speed_limited = self.v.abs() >= f.speed && f.speed > 0;
            if let Some(stroke) = f.stroke_limit
                && new_i.abs_diff(f.start) >= stroke as u64
            {
                self.faults = self.faults.with(Faults::STROKE_LIMIT, true);
                self.quick_stop();
            }
        }

        // Current: inertia plus load, or the limit when pushing against something.
        let current = if !self.enabled {
            0
        } else if blocked {
            limit as i64 * (x_des - x_new).signum()
        } else {
            let acc = self.scale.to_acceleration(self.a);
            let inertia = acc * self.cfg.inertia_ma_per_kinc_s2 as i64 / 1000;
            (inertia + self.load_current(x_new)).clamp(-(limit as i64), limit as i64)
        };

        // Switches, edges, index pulse.
        let sw = self.switch_states(new_i);
        let rising = Switches(sw.0 & !self.switches.0);
        let falling = Switches(self.switches.0 & !sw.0);
        self.switches = sw;
        let index = self.index_crossed(old_i, new_i).map(|p| p + self.origin);
        if self.index_armed
            && let Some(p) = index
        {
            self.index_latch = Some(p);
            self.index_armed = false;
        }

        // Faults.
        let setpoint = (self.generator.pos >> FRAC_BITS) + self.origin;
        let position = new_i + self.origin;
        let fe = setpoint - position;
        let fe_limit = self.cfg.following_error_limit;
        if self.enabled && self.fe_monitoring && fe_limit > 0 && fe.unsigned_abs() > fe_limit as u64
        {
            self.faults = self.faults.with(Faults::FOLLOWING_ERROR, true);
        }
        if self.enabled && self.limit_stop {
            let towards_pos = self.generator.vel > 0 && sw.contains(Switches::LIMIT_POSITIVE);
            let towards_neg = self.generator.vel < 0 && sw.contains(Switches::LIMIT_NEGATIVE);
            if towards_pos {
                self.faults = self.faults.with(Faults::LIMIT_POSITIVE, true);
            }
            if towards_neg {
                self.faults = self.faults.with(Faults::LIMIT_NEGATIVE, true);
            }
            if (towards_pos || towards_neg) && self.mode != AxisMotion::QuickStop {
                self.quick_stop();
            }
        }

        let velocity = self.scale.to_velocity(self.v);
        let standstill = self.still.update(
            velocity.unsigned_abs() <= self.cfg.standstill_velocity as u64,
            self.now,
        ) >= self.cfg.standstill_time;

        self.status = Status {
            time: self.now,
            mode: self.mode,
            position,
            velocity,
            acceleration: self.scale.to_acceleration(self.a),
            current_ma: current as i32,
            force_mn: current * self.cfg.force_constant_mn_per_a as i64 / 1000,
            setpoint,
            setpoint_velocity: self.scale.to_velocity(self.generator.vel),
            following_error: fe,
            generator_done: self.generator.done(),
            standstill,
            blocked,
            speed_limited,
            switches: sw,
            rising,
            falling,
            index_pulse: index,
            faults: self.faults,
        };
        &self.status
    }

    /// Steps until virtual time reaches `until` (at least once if it is later than now).
    pub fn run_until(&mut self, until: Instant) -> &Status {
        while self.now < until {
            self.step();
        }
        &self.status
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: Profile = Profile {
        velocity: 40_000,
        acceleration: 400_000,
        deceleration: 400_000,
    };

    /// An enabled axis without end stops.
    fn axis_at(raw: i64) -> Axis {
        let mut cfg = Config::default();
        cfg.environment.travel = None;
        let mut a = Axis::new(cfg, raw);
        a.enable().unwrap();
        a
    }

    /// Steps until `done` holds, at most `max` steps.
    fn run(a: &mut Axis, max: u32, mut done: impl FnMut(&Status) -> bool) -> Status {
        for _ in 0..max {
            let s = *a.step();
            if done(&s) {
                return s;
            }
        }
        panic!("not done after {max} steps: {:?}", a.status());
    }

    fn settled(s: &Status) -> bool {
        s.generator_done && s.following_error == 0 && s.standstill
    }

    #[test]
    fn move_reaches_target_exactly_and_actual_velocity_stays_in_limit() {
        let mut a = axis_at(1_000);
        a.move_to(-12_345, P).unwrap();
        let mut peak = 0;
        let s = run(&mut a, 100_000, settled);
        assert_eq!(s.position, -12_345);
        assert_eq!(s.setpoint, -12_345);
        // The actual velocity is a filtered setpoint velocity: never beyond the profile.
        a.move_to(20_000, P).unwrap();
        while !settled(a.step()) {
            peak = peak.max(a.status().velocity.abs());
        }
        assert!(peak <= 40_000 && peak > 39_000, "peak {peak}");
        assert_eq!(a.status().position, 20_000);
    }

    #[test]
    fn commands_need_the_power_stage_and_a_valid_profile() {
        let mut a = Axis::new(Config::default(), 0);
        assert_eq!(a.move_to(10, P), Err(AxisError::Disabled));
        a.enable().unwrap();
        let bad = Profile { velocity: 0, ..P };
        assert!(matches!(
            a.move_to(10, bad),
            Err(AxisError::InvalidProfile { velocity: 0, .. })
        ));
        assert!(matches!(
            a.move_to(i64::MAX, P),
            Err(AxisError::OutOfRange { .. })
        ));
    }

    #[test]
    fn following_error_grows_with_speed_and_vanishes_at_standstill() {
        // tau = 5 ms: at constant velocity v the lag is v * (tau - dt) after the step's
        // correction (the discrete first-order loop), 250 µs less than v * tau.
        let mut a = axis_at(0);
        let mut lag_at = |v: i32| {
            a.run_velocity(v, 400_000, 400_000).unwrap();
            for _ in 0..1_000 {
                a.step();
            }
            a.status().following_error
        };
        let slow = lag_at(10_000);
        let fast = lag_at(40_000);
        assert!((slow - 47).abs() <= 1, "slow {slow}");
        assert!((fast - 190).abs() <= 1, "fast {fast}");
        a.hold();
        let s = run(&mut a, 10_000, settled);
        assert_eq!(s.following_error, 0);
        assert_eq!(s.velocity, 0);
    }

    #[test]
    fn hold_and_quick_stop_distances_match_v2_over_2a_within_one_step() {
        for quick in [false, true] {
            let mut a = axis_at(0);
            a.run_velocity(40_000, 400_000, 300_000).unwrap();
            run(&mut a, 10_000, |s| s.generator_done);
            let from = a.status().setpoint;
            let decel: i64 = if quick { 960_000 } else { 300_000 };
            if quick {
                a.quick_stop();
            } else {
                a.hold();
            }
            let s = run(&mut a, 10_000, |s| s.generator_done);
            let dist = s.setpoint - from;
            let expect = 40_000i64 * 40_000 / (2 * decel);
            let one_step = 40_000 / 4_000; // v * 250 µs
            assert!(
                (dist - expect).abs() <= one_step,
                "{quick}: {dist} vs {expect}"
            );
            assert_eq!(
                s.mode,
                if quick {
                    AxisMotion::QuickStop
                } else {
                    AxisMotion::Hold
                }
            );
        }
    }

    #[test]
    fn force_mode_stops_at_a_fixed_stop_with_the_commanded_force() {
        let mut cfg = Config::default();
        cfg.environment.load = Load::FixedStop {
            position: 20_000,
            side: Direction::Positive,
        };
        let mut a = Axis::new(cfg, 0);
        a.enable().unwrap();
        a.force(ForceCommand {
            current_ma: 2_000,
            speed_limit: 20_000,
            acceleration: 200_000,
            stroke_limit: None,
        })
        .unwrap();
        let mut saw_vlim = false;
        let s = run(&mut a, 40_000, |s| {
            saw_vlim |= s.speed_limited;
            s.blocked && s.standstill
        });
        assert!(saw_vlim);
        assert_eq!(s.position, 20_000);
        assert_eq!(s.current_ma, 2_000);
        assert_eq!(s.force_mn, 100_000); // 2 A * 50 N/A
        assert!(!s.faults.any(), "no following-error wind-up in force mode");
        for _ in 0..100 {
            assert_eq!(a.step().current_ma, 2_000);
        }
    }

    #[test]
    fn force_mode_compresses_a_spring_to_equilibrium() {
        let mut cfg = Config::default();
        cfg.environment.load = Load::Spring {
            contact: -5_000,
            side: Direction::Negative,
            stiffness_ma_per_inc: 2,
        };
        cfg.environment.travel = None;
        let mut a = Axis::new(cfg, 0);
        a.enable().unwrap();
        a.force(ForceCommand {
            current_ma: -1_000,
            speed_limit: 10_000,
            acceleration: 200_000,
            stroke_limit: None,
        })
        .unwrap();
        let s = run(&mut a, 40_000, |s| s.blocked && s.standstill);
        assert_eq!(s.position, -5_500);
        assert_eq!(s.current_ma, -1_000);
    }

    #[test]
    fn force_mode_ends_at_the_stroke_limit() {
        let mut a = axis_at(0);
        a.force(ForceCommand {
            current_ma: 1_000,
            speed_limit: 10_000,
            acceleration: 200_000,
            stroke_limit: Some(3_000),
        })
        .unwrap();
        let s = run(&mut a, 40_000, |s| s.faults.contains(Faults::STROKE_LIMIT));
        assert_eq!(s.mode, AxisMotion::QuickStop);
        let s = run(&mut a, 40_000, settled);
        // Quick stop from 10000 inc/s at 960000 inc/s² is ~52 inc plus the lag.
        assert!((3_000..3_200).contains(&s.position), "{}", s.position);
    }

    #[test]
    fn blocking_raises_current_to_the_limit_and_a_following_error() {
        let mut a = axis_at(0);
        a.move_to(100_000, P).unwrap();
        for _ in 0..200 {
            a.step();
        }
        a.inject_block(true);
        let at = a.status().position;
        let s = run(&mut a, 10_000, |s| {
            s.faults.contains(Faults::FOLLOWING_ERROR)
        });
        assert_eq!(s.position, at);
        assert!(s.blocked);
        assert_eq!(s.current_ma, 3_450);
        assert!(s.following_error > 5_000);
        a.inject_block(false);
        a.clear_faults();
        assert!(!a.status().faults.any());
    }

    #[test]
    fn disable_coasts_to_standstill_and_keeps_measuring() {
        let mut a = axis_at(0);
        a.run_velocity(20_000, 400_000, 400_000).unwrap();
        run(&mut a, 10_000, |s| s.velocity == 20_000);
        a.disable();
        let from = a.status().position;
        let s = run(&mut a, 10_000, |s| s.standstill);
        assert_eq!(s.mode, AxisMotion::Disabled);
        assert_eq!(s.current_ma, 0);
        // Coasting at 200000 inc/s² from 20000 inc/s: ~1000 inc.
        assert!(
            (s.position - from - 1_000).abs() <= 10,
            "{}",
            s.position - from
        );
        assert_eq!(
            s.setpoint, s.position,
            "the setpoint tracks the actual position"
        );
        assert_eq!(a.move_to(0, P), Err(AxisError::Disabled));
    }

    #[test]
    fn supply_drop_switches_the_power_stage_off_and_latches() {
        let mut a = axis_at(0);
        a.inject_supply_drop(true);
        assert!(!a.is_enabled());
        assert_eq!(a.enable(), Err(AxisError::SupplyVoltage));
        a.clear_faults();
        assert!(a.step().faults.contains(Faults::SUPPLY_VOLTAGE));
        a.inject_supply_drop(false);
        a.inject_over_temperature(true);
        a.clear_faults();
        let f = a.step().faults;
        assert!(!f.contains(Faults::SUPPLY_VOLTAGE) && f.contains(Faults::OVER_TEMPERATURE));
        a.enable().unwrap();
    }

    #[test]
    fn switches_are_reported_at_their_positions_with_edges() {
        let mut cfg = Config::default();
        cfg.environment.limit_negative = Some(SwitchZone::below(-1_000));
        cfg.environment.limit_positive = Some(SwitchZone::above(30_000));
        cfg.environment.reference = Some(SwitchZone::cam(10_000, 11_000));
        let mut a = Axis::new(cfg, 0);
        a.enable().unwrap();
        a.set_actual_position(500); // reported = raw + 500; switches stay where they are
        let mut rises = heapless::Vec::<(Switches, i64, i64), 8>::new();
        let mut falls = heapless::Vec::<(Switches, i64, i64), 8>::new();
        let mut check = |a: &mut Axis, target: i64| {
            a.move_to(target, P).unwrap();
            loop {
                let s = *a.step();
                let raw = s.position - 500;
                assert_eq!(s.switches.contains(Switches::LIMIT_NEGATIVE), raw < -1_000);
                assert_eq!(s.switches.contains(Switches::LIMIT_POSITIVE), raw >= 30_000);
                assert_eq!(
                    s.switches.contains(Switches::REFERENCE),
                    (10_000..11_000).contains(&raw)
                );
                if s.rising.any() {
                    rises.push((s.rising, raw, s.velocity)).unwrap();
                }
                if s.falling.any() {
                    falls.push((s.falling, raw, s.velocity)).unwrap();
                }
                if settled(&s) {
                    break;
                }
            }
        };
        check(&mut a, 31_500);
        check(&mut a, -1_500);
        let names: heapless::Vec<Switches, 8> = rises.iter().map(|r| r.0).collect();
        assert_eq!(
            names.as_slice(),
            [
                Switches::REFERENCE,
                Switches::LIMIT_POSITIVE,
                Switches::REFERENCE,
                Switches::LIMIT_NEGATIVE
            ]
        );
        // Each edge shows up in the step that crosses it: within one step's travel.
        for &(_, raw, v) in rises.iter().chain(falls.iter()) {
            let edges = [-1_000i64, 30_000, 10_000, 11_000];
            let step = v.abs() / 4_000 + 1;
            assert!(
                edges.iter().any(|e| (raw - e).abs() <= step),
                "edge at {raw}"
            );
        }
    }

    #[test]
    fn index_pulse_once_per_motor_revolution() {
        let mut cfg = Config::default();
        cfg.environment.index_phase = 77;
        cfg.environment.travel = None;
        let mut a = Axis::new(cfg, 0);
        a.enable().unwrap();
        a.set_actual_position(1_000_000);
        a.run_velocity(-90_000, 480_000, 480_000).unwrap();
        let mut pulses = heapless::Vec::<i64, 16>::new();
        while pulses.len() < 10 {
            if let Some(p) = a.step().index_pulse {
                pulses.push(p - 1_000_000).unwrap();
            }
        }
        for w in pulses.windows(2) {
            assert_eq!(w[0] - w[1], 2_000);
        }
        // The first pulse at or below raw 0 with phase 77.
        assert_eq!(pulses[0], -1_923);
        a.arm_index_latch();
        let s = run(&mut a, 10_000, |s| s.index_pulse.is_some());
        assert_eq!(a.index_latch(), s.index_pulse);
    }

    #[test]
    fn streamed_setpoints_are_interpolated_over_the_cycle() {
        let mut a = axis_at(0);
        let cycle = Duration::from_millis(1);
        for k in 1..=50i64 {
            a.stream_setpoint(k * 40, cycle).unwrap();
            let mut last = None;
            for _ in 0..4 {
                let s = *a.step();
                if let Some(l) = last {
                    assert_eq!(s.setpoint - l, 10);
                }
                last = Some(s.setpoint);
            }
            assert_eq!(a.status().setpoint, k * 40);
        }
        assert_eq!(a.status().setpoint_velocity, 40_000);
        let fe = a.status().following_error;
        assert!((fe - 190).abs() <= 1, "{fe}");
    }

    #[test]
    fn window_helpers() {
        let mut a = axis_at(0);
        a.move_to(1_000, P).unwrap();
        let mut t = WindowTimer::new();
        let mut inside_for = Duration::ZERO;
        for _ in 0..2_000 {
            a.step();
            inside_for = t.update(a.in_window(1_000, 5), a.now());
        }
        assert!(inside_for > Duration::from_millis(100));
        assert!(!a.in_window(1_010, 5) && a.in_window(1_005, 5));
        assert_eq!(t.update(false, a.now()), Duration::ZERO);
    }

    #[test]
    fn mechanics_convert_increments_and_micrometres() {
        let m = Config::default().mechanics;
        assert_eq!(m.um_to_increments(1_000), 5_400); // 5.4 inc/µm
        assert_eq!(m.increments_to_um(5_400), 1_000);
        assert_eq!(m.increments_per_output_rev(), (54_000, 4));
    }

    #[test]
    fn limit_switch_stop_reaction() {
        let mut cfg = Config {
            stop_on_limit_switch: true,
            ..Config::default()
        };
        cfg.environment.limit_positive = Some(SwitchZone::above(5_000));
        let mut a = Axis::new(cfg, 0);
        a.enable().unwrap();
        a.move_to(50_000, P).unwrap();
        let s = run(&mut a, 20_000, |s| {
            s.faults.contains(Faults::LIMIT_POSITIVE)
        });
        assert_eq!(s.mode, AxisMotion::QuickStop);
        let s = run(&mut a, 20_000, settled);
        // Seen at 5000 when the setpoint leads by the lag (200), then 833 inc of quick stop.
        assert!((6_000..6_100).contains(&s.position), "{}", s.position);
        // Moving away is allowed.
        a.clear_faults();
        a.move_to(0, P).unwrap();
        let s = run(&mut a, 40_000, settled);
        assert_eq!(s.position, 0);
        assert!(!s.faults.any());
    }

    /// A scripted scenario's full output, twice: identical.
    #[test]
    fn runs_are_deterministic() {
        fn scenario() -> u64 {
            let mut cfg = Config::default();
            cfg.environment.reference = Some(SwitchZone::cam(3_000, 4_000));
            cfg.environment.load = Load::Spring {
                contact: 30_000,
                side: Direction::Positive,
                stiffness_ma_per_inc: 3,
            };
            let mut a = Axis::new(cfg, 17);
            a.enable().unwrap();
            let mut h: u64 = 0xcbf2_9ce4_8422_2325;
            let mut mix = |s: &Status| {
                for v in [
                    s.position,
                    s.velocity,
                    s.acceleration,
                    s.current_ma as i64,
                    s.setpoint,
                    s.following_error,
                    s.switches.0 as i64,
                    s.index_pulse.unwrap_or(-1),
                ] {
                    h = (h ^ v as u64).wrapping_mul(0x100_0000_01b3);
                }
            };
            a.move_to(25_000, P).unwrap();
            for _ in 0..3_000 {
                mix(a.step());
            }
            a.force(ForceCommand {
                current_ma: 1_500,
                speed_limit: 30_000,
                acceleration: 300_000,
                stroke_limit: None,
            })
            .unwrap();
            for _ in 0..3_000 {
                mix(a.step());
            }
            a.run_velocity(-50_000, 100_000, 200_000).unwrap();
            for _ in 0..3_000 {
                mix(a.step());
            }
            a.quick_stop();
            for _ in 0..1_000 {
                mix(a.step());
            }
            h
        }
        assert_eq!(scenario(), scenario());
    }

    mod props {
        use super::*;
        use proptest::prelude::*;

        proptest! {
            #![proptest_config(ProptestConfig::with_cases(48))]
            /// Random moves with random limits: the actual position ends exactly on the
            /// target and the actual velocity never exceeds the profile velocity.
            #[test]
            fn random_moves_land_exactly(
                start in -50_000i64..50_000,
                target in -50_000i64..50_000,
                velocity in 1_000u32..100_000,
                acceleration in 50_000u32..480_000,
                deceleration in 50_000u32..480_000,
            ) {
                let mut a = axis_at(start);
                a.move_to(target, Profile { velocity, acceleration, deceleration }).unwrap();
                let mut steps = 0;
                loop {
                    let s = *a.step();
                    prop_assert!(s.velocity.abs() <= velocity as i64);
                    prop_assert!(s.setpoint_velocity.abs() <= velocity as i64);
                    if settled(&s) {
                        prop_assert_eq!(s.position, target);
                        break;
                    }
                    steps += 1;
                    prop_assert!(steps < 1_000_000);
                }
            }
        }
    }
}
