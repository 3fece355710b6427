//! Homing (mode 6): the methods of 6098h as data ([`HomingPlan`]: which signal, which way to
//! search, which edge, whether the index pulse follows), the device side of the bit-4 start
//! ([`HomingDevice`]) and the homing status bits of the statusword ([`HomingStatus`]).
//!
//! This is the one table of method numbers in the crate: the simulators' executor
//! (`sim::homing`) derives its method descriptions from [`HomingMethod::plan`].
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
    /// The first index pulse in the search direction (CiA 402 33, 34).
    IndexPulse,
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
    /// 33: the first index pulse in negative direction.
    IndexNegative,
    /// 34: the first index pulse in positive direction.
    IndexPositive,
    /// 35: the current position is home.
    CurrentPosition,
    /// 37: the current position is home (CiA 402 from 2016 on; same as 35).
    CurrentPosition37,
    /// −35 (Festo FHPP): the current position is home.
    FestoCurrentPosition,
    /// −17 (MTR-DCI): hard stop in negative direction.
    FestoHardStopNegative,
    /// −18 (MTR-DCI): hard stop in positive direction.
    FestoHardStopPositive,
}

/// How a method homes: what an executor (`sim::homing::Homing`) runs.
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
            HomingMethod::IndexNegative => 33,
            HomingMethod::IndexPositive => 34,
            HomingMethod::CurrentPosition => 35,
            HomingMethod::CurrentPosition37 => 37,
            HomingMethod::FestoCurrentPosition => -35,
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
            33 => HomingMethod::IndexNegative,
            34 => HomingMethod::IndexPositive,
            35 => HomingMethod::CurrentPosition,
            37 => HomingMethod::CurrentPosition37,
            -35 => HomingMethod::FestoCurrentPosition,
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
            HomingMethod::IndexNegative => (HomeSignal::IndexPulse, N, N, true),
            HomingMethod::IndexPositive => (HomeSignal::IndexPulse, P, P, true),
            HomingMethod::CurrentPosition
            | HomingMethod::CurrentPosition37
            | HomingMethod::FestoCurrentPosition => (HomeSignal::CurrentPosition, P, P, false),
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

/// What a controlword means for homing (see [`HomingDevice::handle_controlword`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum HomingCommand {
    /// Bit 4 rose (without halt): start the method of 6098h now.
    Start,
    /// Bit 4 fell or halt was set while a run was going on: stop the axis, homing is interrupted.
    Interrupt,
}

/// Device side of homing mode: controlword bit 4 rising starts a run, bit 4 falling or halt
/// (bit 8) interrupts it (CiA 402), and the statusword bits follow [`HomingStatus`]. The run
/// itself is executed by the simulator on its axis (`sim::homing::Homing`), which reports the
/// end with [`HomingDevice::finished`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HomingDevice {
    last_start: bool,
    running: bool,
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
            running: false,
            status: HomingStatus::Interrupted,
        }
    }
    /// A controlword while homing mode is active in Operation enabled: what to do with the run.
    pub fn handle_controlword(&mut self, cw: Controlword) -> Option<HomingCommand> {
        let start = cw.has(Controlword::HOMING_START);
        let rising = start && !self.last_start;
        self.last_start = start;
        if rising && !cw.halt() {
            self.running = true;
            self.status = HomingStatus::InProgress;
            return Some(HomingCommand::Start);
        }
        if (!start || cw.halt()) && self.running {
            self.running = false;
            self.status = HomingStatus::Interrupted;
            return Some(HomingCommand::Interrupt);
        }
        None
    }
    /// The run ended: referenced (`true`) or failed (`false`).
    pub fn finished(&mut self, referenced: bool) {
        self.running = false;
        self.status = if referenced {
            HomingStatus::Completed
        } else {
            HomingStatus::ErrorStopped
        };
    }
    /// Whether a run is going on.
    pub const fn running(&self) -> bool {
        self.running
    }
    /// Forgets a run (mode change, leaving Operation enabled): bits show "interrupted".
    pub fn reset(&mut self) {
        self.running = false;
        self.status = HomingStatus::Interrupted;
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

    #[test]
    fn tlc_methods_are_the_documented_plans() {
        use Direction::{Negative as N, Positive as P};
        // (code, signal, first move, leaving direction, index pulse): digest §3.8.
        let cases = [
            (1, HomeSignal::NegativeLimit, N, P, true),
            (2, HomeSignal::PositiveLimit, P, N, true),
            (7, HomeSignal::HomeSwitch, P, N, true),
            (11, HomeSignal::HomeSwitch, N, P, true),
            (17, HomeSignal::NegativeLimit, N, P, false),
            (18, HomeSignal::PositiveLimit, P, N, false),
            (23, HomeSignal::HomeSwitch, P, N, false),
            (27, HomeSignal::HomeSwitch, N, P, false),
            (35, HomeSignal::CurrentPosition, P, P, false),
        ];
        for (code, signal, search, leave, index_pulse) in cases {
            let m = HomingMethod::from_code(code).unwrap();
            assert!(TLC5XX.supports_homing(m), "{code}");
            let want = HomingPlan {
                signal,
                search,
                leave,
                index_pulse,
            };
            assert_eq!(m.plan(), want, "method {code}");
        }
        assert_eq!(
            HomingMethod::from_code(3),
            Err(HomingError::UnknownMethod(3))
        );
    }

    #[test]
    fn mtr_methods() {
        for m in [
            HomingMethod::FestoHardStopNegative,
            HomingMethod::FestoHardStopPositive,
        ] {
            assert!(MTR_DCI.supports_homing(m));
            assert_eq!(m.plan().signal, HomeSignal::HardStop);
        }
        assert!(!MTR_DCI.supports_homing(HomingMethod::NegativeLimit));
        assert!(!TLC5XX.supports_homing(HomingMethod::IndexNegative));
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
        let mut dev = HomingDevice::new();
        assert_eq!(dev.status(), HomingStatus::Interrupted);
        assert_eq!(
            dev.handle_controlword(Controlword(0x001F)),
            Some(HomingCommand::Start)
        );
        assert_eq!(dev.handle_controlword(Controlword(0x001F)), None); // level, no new edge
        assert_eq!(dev.status().bits(), Statusword(0));
        assert_eq!(
            dev.handle_controlword(Controlword(0x011F)), // halt
            Some(HomingCommand::Interrupt)
        );
        assert_eq!(dev.status(), HomingStatus::Interrupted);
        assert!(!dev.running());
        assert_eq!(dev.handle_controlword(Controlword(0x000F)), None);
        assert_eq!(
            dev.handle_controlword(Controlword(0x001F)),
            Some(HomingCommand::Start)
        );
        dev.finished(true);
        assert_eq!(dev.status().bits(), Statusword(0x1400));
        assert!(Statusword(0x1427).homing_attained());
        assert_eq!(dev.handle_controlword(Controlword(0x000F)), None);
        assert_eq!(dev.status(), HomingStatus::Completed);
        dev.handle_controlword(Controlword(0x001F));
        dev.finished(false);
        assert_eq!(dev.status(), HomingStatus::ErrorStopped);
    }
}
