//! Homing (mode 6): the methods of 6098h as data ([`HomingPlan`]: which signal, which way to
//! search, which edge, whether the index pulse follows), a small executor a simulated axis can
//! run ([`HomingRun`]), and the homing status bits of the statusword ([`HomingStatus`]).
//!
//! Home is where the axis leaves the signal's active zone at the chosen edge (and, with an index
//! pulse, the first index pulse beyond that edge). After homing, the position at home equals the
//! home offset 607Ch ([`rebased_position`]).
//!
//! ```
//! use drivers::cia402::homing::{Direction, HomeSignal, HomingMethod};
//! let plan = HomingMethod::from_code(27).unwrap().plan();
//! assert_eq!(plan.signal, HomeSignal::HomeSwitch);
//! assert_eq!(plan.search, Direction::Negative);
//! assert_eq!(plan.leave, Direction::Positive); // REF is where the switch releases on the way back
//! assert!(!plan.index_pulse);
//! ```

use super::controlword::Controlword;
use super::statusword::Statusword;

/// A direction of travel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Increasing position (TLC5xx "clockwise", LIMP side).
    Positive,
    /// Decreasing position (TLC5xx "anticlockwise", LIMN side).
    Negative,
}

impl Direction {
    /// +1 or −1.
    pub const fn sign(self) -> i32 {
        match self {
            Direction::Positive => 1,
            Direction::Negative => -1,
        }
    }
    /// The other direction.
    pub const fn reverse(self) -> Direction {
        match self {
            Direction::Positive => Direction::Negative,
            Direction::Negative => Direction::Positive,
        }
    }
}

/// The signal a homing method references.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum HomeSignal {
    /// The negative limit switch (LIMN).
    NegativeLimit,
    /// The positive limit switch (LIMP).
    PositiveLimit,
    /// The reference / home switch (REF), active over part of the travel.
    HomeSwitch,
    /// A mechanical stop, detected as standstill at the current limit (MTR-DCI −17/−18).
    HardStop,
    /// No signal: the current position is home (method 35, TLC5xx "dimension setting").
    CurrentPosition,
}

/// A homing method of 6098h (INTEGER8).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum HomingMethod {
    /// 1: negative limit switch, then the index pulse.
    NegativeLimitIndex,
    /// 2: positive limit switch, then the index pulse.
    PositiveLimitIndex,
    /// 7: home switch searched in positive direction, home at its negative edge, then the index.
    HomeSwitchPositiveIndex,
    /// 11: home switch searched in negative direction, home at its positive edge, then the index.
    HomeSwitchNegativeIndex,
    /// 17: negative limit switch, no index (TLC5xx, CiA 402).
    NegativeLimit,
    /// 18: positive limit switch, no index (TLC5xx default).
    PositiveLimit,
    /// 23: home switch searched in positive direction, no index (MTR-DCI "switch, positive").
    HomeSwitchPositive,
    /// 27: home switch searched in negative direction, no index (MTR-DCI default).
    HomeSwitchNegative,
    /// 35: the current position is home.
    CurrentPosition,
    /// −17 (MTR-DCI): hard stop in negative direction.
    FestoHardStopNegative,
    /// −18 (MTR-DCI): hard stop in positive direction.
    FestoHardStopPositive,
}

/// How a method homes: what [`HomingRun`] executes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct HomingPlan {
    /// The signal referenced.
    pub signal: HomeSignal,
    /// The first move's direction, at the search speed (6099h:01).
    pub search: Direction,
    /// The direction in which the axis leaves the signal's active zone at the creep speed
    /// (6099h:02); the edge crossed this way is home (or precedes the index pulse).
    pub leave: Direction,
    /// Whether home is the first index pulse after the edge rather than the edge itself.
    pub index_pulse: bool,
}

/// Why homing did not succeed (statusword bit 13; MTR-DCI fault 32 / EMCY 5441h).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum HomingError {
    /// 6098h holds a code no method has.
    #[error("homing method {0} is not defined")]
    UnknownMethod(i8),
    /// The signal was not found: both travel ends reached, or the wrong limit switch hit.
    #[error("homing signal not found (stopped at position {0})")]
    SignalNotFound(i32),
    /// Leaving the switch took longer than allowed (TLC5xx `p_outHome` 20F3h).
    #[error("left the switch over {travelled} > {limit} without finding home")]
    RunOutExceeded {
        /// Distance travelled since the switch was found.
        travelled: u32,
        /// The allowed distance.
        limit: u32,
    },
}

impl HomingMethod {
    /// The 6098h code.
    pub const fn code(self) -> i8 {
        match self {
            HomingMethod::NegativeLimitIndex => 1,
            HomingMethod::PositiveLimitIndex => 2,
            HomingMethod::HomeSwitchPositiveIndex => 7,
            HomingMethod::HomeSwitchNegativeIndex => 11,
            HomingMethod::NegativeLimit => 17,
            HomingMethod::PositiveLimit => 18,
            HomingMethod::HomeSwitchPositive => 23,
            HomingMethod::HomeSwitchNegative => 27,
            HomingMethod::CurrentPosition => 35,
            HomingMethod::FestoHardStopNegative => -17,
            HomingMethod::FestoHardStopPositive => -18,
        }
    }
    /// The method of a 6098h code.
    pub const fn from_code(code: i8) -> Result<HomingMethod, HomingError> {
        Ok(match code {
            1 => HomingMethod::NegativeLimitIndex,
            2 => HomingMethod::PositiveLimitIndex,
            7 => HomingMethod::HomeSwitchPositiveIndex,
            11 => HomingMethod::HomeSwitchNegativeIndex,
            17 => HomingMethod::NegativeLimit,
            18 => HomingMethod::PositiveLimit,
            23 => HomingMethod::HomeSwitchPositive,
            27 => HomingMethod::HomeSwitchNegative,
            35 => HomingMethod::CurrentPosition,
            -17 => HomingMethod::FestoHardStopNegative,
            -18 => HomingMethod::FestoHardStopPositive,
            other => return Err(HomingError::UnknownMethod(other)),
        })
    }
    /// The method as data.
    pub const fn plan(self) -> HomingPlan {
        use Direction::{Negative as N, Positive as P};
        let (signal, search, leave, index_pulse) = match self {
            HomingMethod::NegativeLimitIndex => (HomeSignal::NegativeLimit, N, P, true),
            HomingMethod::PositiveLimitIndex => (HomeSignal::PositiveLimit, P, N, true),
            HomingMethod::HomeSwitchPositiveIndex => (HomeSignal::HomeSwitch, P, N, true),
            HomingMethod::HomeSwitchNegativeIndex => (HomeSignal::HomeSwitch, N, P, true),
            HomingMethod::NegativeLimit => (HomeSignal::NegativeLimit, N, P, false),
            HomingMethod::PositiveLimit => (HomeSignal::PositiveLimit, P, N, false),
            HomingMethod::HomeSwitchPositive => (HomeSignal::HomeSwitch, P, N, false),
            HomingMethod::HomeSwitchNegative => (HomeSignal::HomeSwitch, N, P, false),
            HomingMethod::CurrentPosition => (HomeSignal::CurrentPosition, P, P, false),
            HomingMethod::FestoHardStopNegative => (HomeSignal::HardStop, N, P, false),
            HomingMethod::FestoHardStopPositive => (HomeSignal::HardStop, P, N, false),
        };
        HomingPlan {
            signal,
            search,
            leave,
            index_pulse,
        }
    }
}

/// What the axis senses at one tick of a homing run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct HomingInputs {
    /// Actual position.
    pub position: i32,
    /// LIMN active.
    pub negative_limit: bool,
    /// LIMP active.
    pub positive_limit: bool,
    /// REF active.
    pub home_switch: bool,
    /// An index pulse passed since the previous tick.
    pub index_pulse: bool,
    /// The axis is blocked (standstill at the current limit).
    pub stalled: bool,
}

/// What the axis does next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HomingStep {
    /// Run at this velocity (signed, search or creep speed).
    Run(i32),
    /// Home found at this actual position; stop (see [`rebased_position`]).
    Done(i32),
    /// Homing failed; stop.
    Failed(HomingError),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    Search {
        direction: Direction,
        reversed: bool,
    },
    Leave {
        from: i32,
    },
    Index {
        from: i32,
    },
    Finished(HomingStep),
}

/// A speed object (U32) as a signed velocity, saturated at `i32::MAX`.
const fn saturate(v: u32) -> i32 {
    if v > i32::MAX as u32 {
        i32::MAX
    } else {
        v as i32
    }
}

/// Executes a [`HomingPlan`] against an axis model, one tick at a time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HomingRun {
    plan: HomingPlan,
    search_speed: i32,
    creep_speed: i32,
    max_run_out: Option<u32>,
    phase: Phase,
}

impl HomingRun {
    /// A run of `plan` at the search speed 6099h:01 and creep speed 6099h:02 (saturated to
    /// `i32::MAX`), with an optional limit on the distance travelled after the switch was found.
    pub const fn new(
        plan: HomingPlan,
        search_speed: u32,
        creep_speed: u32,
        max_run_out: Option<u32>,
    ) -> Self {
        HomingRun {
            plan,
            search_speed: saturate(search_speed),
            creep_speed: saturate(creep_speed),
            max_run_out,
            phase: Phase::Search {
                direction: plan.search,
                reversed: false,
            },
        }
    }

    /// Whether the run has ended (done or failed).
    pub const fn finished(&self) -> bool {
        matches!(self.phase, Phase::Finished(_))
    }

    fn signal_active(&self, i: &HomingInputs) -> bool {
        match self.plan.signal {
            HomeSignal::NegativeLimit => i.negative_limit,
            HomeSignal::PositiveLimit => i.positive_limit,
            HomeSignal::HomeSwitch => i.home_switch,
            HomeSignal::HardStop => i.stalled,
            HomeSignal::CurrentPosition => true,
        }
    }

    fn finish(&mut self, step: HomingStep) -> HomingStep {
        self.phase = Phase::Finished(step);
        step
    }

    /// One tick: the inputs sensed now, the command for the axis.
    pub fn step(&mut self, i: &HomingInputs) -> HomingStep {
        let leave = self.creep_speed.saturating_mul(self.plan.leave.sign());
        match self.phase {
            Phase::Finished(step) => step,
            Phase::Search { .. } if matches!(self.plan.signal, HomeSignal::CurrentPosition) => {
                self.finish(HomingStep::Done(i.position))
            }
            Phase::Search { .. }
                if matches!(self.plan.signal, HomeSignal::HardStop) && i.stalled =>
            {
                self.finish(HomingStep::Done(i.position))
            }
            // Found (or started on it): leave it at the creep speed toward the wanted edge.
            Phase::Search { .. } if self.signal_active(i) => {
                self.phase = Phase::Leave { from: i.position };
                HomingStep::Run(leave)
            }
            Phase::Search {
                direction,
                reversed,
            } => {
                let limit_ahead = match direction {
                    Direction::Positive => i.positive_limit,
                    Direction::Negative => i.negative_limit,
                };
                // Only a home-switch search cares about a limit switch ahead: a limit method
                // has just found its signal, a hard-stop method runs until blocked.
                let limit_ahead = limit_ahead && matches!(self.plan.signal, HomeSignal::HomeSwitch);
                if limit_ahead && !reversed {
                    // The home switch lies behind us: reverse at the limit (CiA 402 methods 7..14).
                    let direction = direction.reverse();
                    self.phase = Phase::Search {
                        direction,
                        reversed: true,
                    };
                    HomingStep::Run(self.search_speed.saturating_mul(direction.sign()))
                } else if limit_ahead {
                    self.finish(HomingStep::Failed(HomingError::SignalNotFound(i.position)))
                } else {
                    HomingStep::Run(self.search_speed.saturating_mul(direction.sign()))
                }
            }
            Phase::Leave { from } | Phase::Index { from } => {
                let travelled = (i64::from(i.position) - i64::from(from)).unsigned_abs();
                if let Some(limit) = self.max_run_out
                    && travelled > u64::from(limit)
                {
                    let travelled = u32::try_from(travelled).unwrap_or(u32::MAX);
                    return self.finish(HomingStep::Failed(HomingError::RunOutExceeded {
                        travelled,
                        limit,
                    }));
                }
                match self.phase {
                    Phase::Leave { .. } if self.signal_active(i) => HomingStep::Run(leave),
                    Phase::Leave { .. } if self.plan.index_pulse => {
                        self.phase = Phase::Index { from };
                        HomingStep::Run(leave)
                    }
                    Phase::Index { .. } if !i.index_pulse => HomingStep::Run(leave),
                    _ => self.finish(HomingStep::Done(i.position)),
                }
            }
        }
    }
}

/// The actual position to set after homing so that the home point found at `home` reads as the
/// home offset 607Ch, for an axis now at `position` (wrapping like a 32-bit register).
pub const fn rebased_position(position: i32, home: i32, home_offset: i32) -> i32 {
    position.wrapping_sub(home).wrapping_add(home_offset)
}

/// The homing state shown by statusword bits 13 (homing error), 12 (homing attained) and 10
/// (target reached), per CiA 402.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum HomingStatus {
    /// 0 0 0: homing in progress.
    InProgress,
    /// 0 0 1: homing interrupted (halt) or not started.
    Interrupted,
    /// 0 1 0: home found, target not reached yet.
    AttainedNotReached,
    /// 0 1 1: homing completed.
    Completed,
    /// 1 0 0: homing error, axis still moving.
    ErrorMoving,
    /// 1 0 1: homing error, axis at standstill.
    ErrorStopped,
}

impl HomingStatus {
    /// The statusword bits 10, 12, 13.
    pub const fn bits(self) -> Statusword {
        Statusword(match self {
            HomingStatus::InProgress => 0,
            HomingStatus::Interrupted => Statusword::TARGET_REACHED,
            HomingStatus::AttainedNotReached => Statusword::HOMING_ATTAINED,
            HomingStatus::Completed => Statusword::HOMING_ATTAINED | Statusword::TARGET_REACHED,
            HomingStatus::ErrorMoving => Statusword::HOMING_ERROR,
            HomingStatus::ErrorStopped => Statusword::HOMING_ERROR | Statusword::TARGET_REACHED,
        })
    }
    /// The homing state a statusword shows; `None` for the reserved pattern (bits 12 and 13 set).
    pub const fn from_statusword(sw: Statusword) -> Option<HomingStatus> {
        Some(
            match (sw.homing_error(), sw.homing_attained(), sw.target_reached()) {
                (false, false, false) => HomingStatus::InProgress,
                (false, false, true) => HomingStatus::Interrupted,
                (false, true, false) => HomingStatus::AttainedNotReached,
                (false, true, true) => HomingStatus::Completed,
                (true, false, false) => HomingStatus::ErrorMoving,
                (true, false, true) => HomingStatus::ErrorStopped,
                (true, true, _) => return None,
            },
        )
    }
}

/// The homing parameters latched when homing starts (6098h, 6099h:01/02, TLC5xx `p_outHome`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HomingParams {
    /// 6098h.
    pub method: HomingMethod,
    /// 6099h:01 speed during search for the switch.
    pub search_speed: u32,
    /// 6099h:02 speed during search for zero (leaving the switch, index search).
    pub creep_speed: u32,
    /// Maximum travel after the switch was found (TLC5xx 20F3h; `None` = off).
    pub max_run_out: Option<u32>,
}

/// Device side of homing mode: controlword bit 4 rising starts a run, bit 4 falling or halt
/// (bit 8) interrupts it (CiA 402), and the statusword bits follow [`HomingStatus`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HomingDevice {
    last_start: bool,
    run: Option<HomingRun>,
    status: HomingStatus,
}

impl Default for HomingDevice {
    fn default() -> Self {
        Self::new()
    }
}

impl HomingDevice {
    /// Not started yet (bits 13/12/10 = 0/0/1).
    pub const fn new() -> Self {
        HomingDevice {
            last_start: false,
            run: None,
            status: HomingStatus::Interrupted,
        }
    }
    /// A controlword while homing mode is active in Operation enabled; `true` if a run started.
    pub fn handle_controlword(&mut self, cw: Controlword, params: &HomingParams) -> bool {
        let start = cw.has(Controlword::HOMING_START);
        let rising = start && !self.last_start;
        self.last_start = start;
        if (!start || cw.halt()) && self.run.is_some() {
            self.run = None;
            self.status = HomingStatus::Interrupted;
        }
        if rising && !cw.halt() {
            self.run = Some(HomingRun::new(
                params.method.plan(),
                params.search_speed,
                params.creep_speed,
                params.max_run_out,
            ));
            self.status = HomingStatus::InProgress;
            return true;
        }
        false
    }
    /// One tick of the running homing; `None` when none runs (the axis holds still).
    pub fn step(&mut self, inputs: &HomingInputs) -> Option<HomingStep> {
        let step = self.run.as_mut()?.step(inputs);
        match step {
            HomingStep::Run(_) => {}
            HomingStep::Done(_) => {
                self.run = None;
                self.status = HomingStatus::Completed;
            }
            HomingStep::Failed(_) => {
                self.run = None;
                self.status = HomingStatus::ErrorStopped;
            }
        }
        Some(step)
    }
    /// The homing state for statusword bits 10, 12, 13.
    pub const fn status(&self) -> HomingStatus {
        self.status
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cia402::{MTR_DCI, TLC5XX};

    /// A one-dimensional axis with LIMN below `limn`, LIMP above `limp`, REF on `ref_lo..=ref_hi`,
    /// index pulses every `index_every` increments, moved by the run's velocity each tick.
    struct Axis {
        pos: i32,
        limn: i32,
        limp: i32,
        ref_lo: i32,
        ref_hi: i32,
        index_every: i32,
    }

    impl Axis {
        fn run(&mut self, method: HomingMethod) -> HomingStep {
            let mut run = HomingRun::new(method.plan(), 10, 1, Some(500));
            let mut prev = self.pos;
            for _ in 0..10_000 {
                let crossed_index =
                    prev.div_euclid(self.index_every) != self.pos.div_euclid(self.index_every);
                let i = HomingInputs {
                    position: self.pos,
                    negative_limit: self.pos <= self.limn,
                    positive_limit: self.pos >= self.limp,
                    home_switch: (self.ref_lo..=self.ref_hi).contains(&self.pos),
                    index_pulse: crossed_index,
                    stalled: self.pos <= self.limn - 5 || self.pos >= self.limp + 5,
                };
                prev = self.pos;
                match run.step(&i) {
                    HomingStep::Run(v) => {
                        self.pos = (self.pos + v).clamp(self.limn - 5, self.limp + 5)
                    }
                    done => return done,
                }
            }
            panic!("homing did not end");
        }
    }

    fn axis(pos: i32) -> Axis {
        Axis {
            pos,
            limn: -1000,
            limp: 1000,
            ref_lo: 200,
            ref_hi: 300,
            index_every: 64,
        }
    }

    #[test]
    fn every_tlc_method_finds_the_documented_point() {
        // (method, start, expected home)
        let cases = [
            (17, 0, -999),  // LIMN released moving positive
            (18, 0, 999),   // LIMP released moving negative
            (1, 0, -960),   // first index above -999 (the pulse between -961 and -960)
            (2, 0, 959),    // first index below 999 (the pulse between 960 and 959)
            (23, 0, 199),   // REF lower edge, approached from above
            (27, 500, 301), // REF upper edge, approached from below
            (23, 500, 199), // starts beyond REF: reverses at LIMP, finds REF from above
            (27, 250, 301), // starts on REF: leaves it in the leave direction
            (7, 0, 191),    // lower edge then the index below it (crossing 192 → 191)
            (11, 500, 320), // upper edge then the index above it
            (35, 42, 42),
        ];
        for (code, start, home) in cases {
            let m = HomingMethod::from_code(code).unwrap();
            assert!(TLC5XX.supports_homing(m), "{code}");
            assert_eq!(
                axis(start).run(m),
                HomingStep::Done(home),
                "method {code} from {start}"
            );
        }
    }

    #[test]
    fn mtr_hard_stop_methods_home_at_the_stop() {
        for (m, home) in [
            (HomingMethod::FestoHardStopNegative, -1005),
            (HomingMethod::FestoHardStopPositive, 1005),
        ] {
            assert!(MTR_DCI.supports_homing(m));
            assert_eq!(axis(0).run(m), HomingStep::Done(home));
        }
        assert!(!MTR_DCI.supports_homing(HomingMethod::NegativeLimit));
    }

    #[test]
    fn failures_are_reported() {
        let mut no_ref = axis(0);
        no_ref.ref_lo = 5000;
        no_ref.ref_hi = 5000;
        assert_eq!(
            no_ref.run(HomingMethod::HomeSwitchPositive),
            HomingStep::Failed(HomingError::SignalNotFound(-1000))
        );
        let mut wide = axis(0);
        wide.ref_hi = 2000; // REF never releases upward: run-out exceeded
        assert!(matches!(
            wide.run(HomingMethod::HomeSwitchNegative),
            HomingStep::Failed(HomingError::RunOutExceeded { limit: 500, .. })
        ));
        assert_eq!(
            HomingMethod::from_code(3),
            Err(HomingError::UnknownMethod(3))
        );
    }

    #[test]
    fn codes_round_trip_and_status_bits_invert() {
        for code in i8::MIN..=i8::MAX {
            if let Ok(m) = HomingMethod::from_code(code) {
                assert_eq!(m.code(), code);
            }
        }
        for s in [
            HomingStatus::InProgress,
            HomingStatus::Interrupted,
            HomingStatus::AttainedNotReached,
            HomingStatus::Completed,
            HomingStatus::ErrorMoving,
            HomingStatus::ErrorStopped,
        ] {
            assert_eq!(
                HomingStatus::from_statusword(Statusword(0x0027 | s.bits().0)),
                Some(s)
            );
        }
        assert_eq!(HomingStatus::from_statusword(Statusword(0x3000)), None);
        assert_eq!(rebased_position(-999, -999, 10), 10);
        assert_eq!(rebased_position(i32::MIN, 1, 0), i32::MAX);
    }

    #[test]
    fn homing_device_starts_on_bit4_and_interrupts_on_its_fall_or_halt() {
        let params = HomingParams {
            method: HomingMethod::HomeSwitchNegative,
            search_speed: 10,
            creep_speed: 1,
            max_run_out: None,
        };
        let mut dev = HomingDevice::new();
        assert_eq!(dev.status(), HomingStatus::Interrupted);
        assert!(dev.handle_controlword(Controlword(0x001F), &params));
        assert!(!dev.handle_controlword(Controlword(0x001F), &params)); // level, no new edge
        let mut i = HomingInputs {
            position: 500,
            ..HomingInputs::default()
        };
        assert_eq!(dev.step(&i), Some(HomingStep::Run(-10)));
        assert_eq!(dev.status().bits(), Statusword(0));
        dev.handle_controlword(Controlword(0x011F), &params); // halt
        assert_eq!(dev.status(), HomingStatus::Interrupted);
        assert_eq!(dev.step(&i), None);
        dev.handle_controlword(Controlword(0x000F), &params);
        assert!(dev.handle_controlword(Controlword(0x001F), &params));
        i.home_switch = true;
        assert_eq!(dev.step(&i), Some(HomingStep::Run(1)));
        i.home_switch = false;
        i.position = 301;
        assert_eq!(dev.step(&i), Some(HomingStep::Done(301)));
        assert_eq!(dev.status().bits(), Statusword(0x1400));
        assert!(Statusword(0x1427).homing_attained());
    }
}
