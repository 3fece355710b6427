//! Modes of operation (6060h / 6061h), the profile position set-point handshake as two small
//! state machines ([`PpDevice`] on the drive, [`PpMaster`] on the coordinator), and the profile
//! velocity status bits ([`PvMonitor`]).
//!
//! The profile position handshake (TLC5xx §5.4.2, CiA 402): the master writes 607Ah, raises
//! controlword bit 4 "new set-point" (with bit 5 "change set immediately" and bit 6 abs/rel); the
//! device takes the set-point and answers statusword bit 12 "set-point acknowledge" and clears
//! bit 10 "target reached"; the master drops bit 4; the device drops bit 12 once it can take
//! another set-point. With bit 5 = 0 a set-point that arrives while a move runs waits in a
//! one-deep buffer until the running target is reached; bit 12 stays 1 while that buffer is full.
//!
//! ```
//! use drivers::cia402::{TLC5XX, controlword::Controlword, modes::*};
//! let mut drive = PpDevice::new(&TLC5XX, 0);
//! let mut master = PpMaster::new(TLC5XX.abs_rel);
//! master.request(SetPointRequest { target: 1500, relative: true, immediate: false }).unwrap();
//! let cw = master.controlword(Controlword(0x000F));
//! assert_eq!(cw, Controlword(0x001F)); // §5.4.3 trace
//! let objects = PpObjects { target: 1500, velocity: 500, acceleration: 2000, deceleration: 1000 };
//! assert!(matches!(drive.handle_controlword(cw, &objects), Some(PpAction::Start(m)) if m.target == 1500));
//! assert_eq!(drive.status_bits().0, 0x1000);
//! ```

use super::DeviceProfile;
use super::controlword::{AbsRel, Controlword};
use super::statusword::Statusword;
use crate::canopen::AbortCode;
use crate::time::Instant;
use core::time::Duration;
use heapless::Vec;

/// A mode of operation as 6060h / 6061h code it (INTEGER8).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum OperationMode {
    /// 1: profile position (both devices).
    ProfilePosition,
    /// 2: velocity (frequency-converter style; neither reference device).
    Velocity,
    /// 3: profile velocity (TLC5xx; reserved on the MTR-DCI).
    ProfileVelocity,
    /// 4: profile torque (MTR-DCI "power operation").
    ProfileTorque,
    /// 6: homing (both devices).
    Homing,
    /// 7: interpolated position (not supported by the TLC5xx, §1.3).
    InterpolatedPosition,
    /// 8: cyclic synchronous position (offered by neither reference device).
    CyclicSyncPosition,
    /// 9: cyclic synchronous velocity.
    CyclicSyncVelocity,
    /// 10: cyclic synchronous torque.
    CyclicSyncTorque,
    /// −1: the TLC5xx's manufacturer "SIG mode" (sub-mode in 2042h `xMode_act`, started by
    /// writing the sub-mode's start object).
    TlcSigMode,
    /// −2: the MTR-DCI's demo mode (cycles through the records).
    FestoDemo,
}

/// Why a mode code is refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ModeError {
    /// No mode of CiA 402 or of the reference devices has this code.
    #[error("mode of operation {0} is not defined")]
    Unknown(i8),
    /// The mode exists but this device does not offer it.
    #[error("mode of operation {0} is not offered by this device")]
    Unsupported(i8),
}

impl ModeError {
    /// The SDO abort a device answers a write of such a code with (0609 0030h, value range).
    pub const fn abort_code(self) -> AbortCode {
        AbortCode::InvalidValue
    }
}

impl OperationMode {
    /// The 6060h / 6061h code.
    pub const fn code(self) -> i8 {
        match self {
            OperationMode::ProfilePosition => 1,
            OperationMode::Velocity => 2,
            OperationMode::ProfileVelocity => 3,
            OperationMode::ProfileTorque => 4,
            OperationMode::Homing => 6,
            OperationMode::InterpolatedPosition => 7,
            OperationMode::CyclicSyncPosition => 8,
            OperationMode::CyclicSyncVelocity => 9,
            OperationMode::CyclicSyncTorque => 10,
            OperationMode::TlcSigMode => -1,
            OperationMode::FestoDemo => -2,
        }
    }
    /// The mode of a 6060h / 6061h code.
    pub const fn from_code(code: i8) -> Result<OperationMode, ModeError> {
        Ok(match code {
            1 => OperationMode::ProfilePosition,
            2 => OperationMode::Velocity,
            3 => OperationMode::ProfileVelocity,
            4 => OperationMode::ProfileTorque,
            6 => OperationMode::Homing,
            7 => OperationMode::InterpolatedPosition,
            8 => OperationMode::CyclicSyncPosition,
            9 => OperationMode::CyclicSyncVelocity,
            10 => OperationMode::CyclicSyncTorque,
            -1 => OperationMode::TlcSigMode,
            -2 => OperationMode::FestoDemo,
            other => return Err(ModeError::Unknown(other)),
        })
    }
    /// The mode's bit in 6502h "supported drive modes" (`None` for manufacturer modes).
    pub const fn supported_modes_bit(self) -> Option<u32> {
        let bit = match self {
            OperationMode::ProfilePosition => 0,
            OperationMode::Velocity => 1,
            OperationMode::ProfileVelocity => 2,
            OperationMode::ProfileTorque => 3,
            OperationMode::Homing => 5,
            OperationMode::InterpolatedPosition => 6,
            OperationMode::CyclicSyncPosition => 7,
            OperationMode::CyclicSyncVelocity => 8,
            OperationMode::CyclicSyncTorque => 9,
            OperationMode::TlcSigMode | OperationMode::FestoDemo => return None,
        };
        Some(1 << bit)
    }
}

/// 60C2h "interpolation time period" for a cycle: (sub 1 value, sub 2 index) with
/// period = value × 10^index s, exact. Milliseconds first (index −3: the CiA 402 default, and
/// many drives take no other; this project's simulator takes −6..=−3), then finer units, then
/// coarser ones: 1 ms = (1, −3), 10 ms = (10, −3), 250 µs = (25, −5), 1.5 ms = (15, −4),
/// 4 s = (40, −1). `None` for a period that no value of 1..=255 at an index of −6..=0 gives
/// exactly.
pub const fn interpolation_time_period(period: Duration) -> Option<(u8, i8)> {
    let us = period.as_micros();
    if us == 0 || !period.subsec_nanos().is_multiple_of(1000) {
        return None;
    }
    const ORDER: [i8; 7] = [-3, -4, -5, -6, -2, -1, 0];
    let mut k = 0;
    while k < ORDER.len() {
        let index = ORDER[k];
        // 10^(index + 6) µs per unit.
        let mut unit: u128 = 1;
        let mut e = index + 6;
        while e > 0 {
            unit *= 10;
            e -= 1;
        }
        if us.is_multiple_of(unit) && us / unit <= 255 {
            return Some(((us / unit) as u8, index));
        }
        k += 1;
    }
    None
}

/// The period 60C2h's (value, index) stand for; `None` for an index outside −6..=0 or a zero
/// value.
pub const fn interpolation_period_of(value: u8, index: i8) -> Option<Duration> {
    if value == 0 || index < -6 || index > 0 {
        return None;
    }
    let mut us: u64 = value as u64 * 1_000_000;
    let mut i = index;
    while i < 0 {
        us /= 10;
        i += 1;
    }
    Some(Duration::from_micros(us))
}

impl DeviceProfile {
    /// The 6502h "supported drive modes" value of the device (MTR-DCI: 0x29).
    pub fn supported_drive_modes(&self) -> u32 {
        self.modes
            .iter()
            .filter_map(|m| m.supported_modes_bit())
            .fold(0, |acc, b| acc | b)
    }
}

/// Device side: 6060h takes effect only at standstill ("as soon as the drive has come to a
/// stop", TLC5xx p.9-112); 6061h shows the active mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ModeSelector {
    active: OperationMode,
    requested: Option<OperationMode>,
}

impl ModeSelector {
    /// Power-on: `initial` active (both devices: profile position).
    pub const fn new(initial: OperationMode) -> Self {
        ModeSelector {
            active: initial,
            requested: None,
        }
    }
    /// A 6060h write of `code`: accepted (it takes effect at the next standstill) or refused.
    pub fn request(&mut self, code: i8, profile: &DeviceProfile) -> Result<(), ModeError> {
        let mode = OperationMode::from_code(code)?;
        if !profile.supports_mode(mode) {
            return Err(ModeError::Unsupported(code));
        }
        // The last write wins; writing the active mode again (a master that maps 6060h in its
        // RPDO writes it every cycle) asks for no change.
        self.requested = (mode != self.active).then_some(mode);
        Ok(())
    }
    /// Applies a pending request if the axis is at a standstill; returns the newly active mode.
    pub fn update(&mut self, standstill: bool) -> Option<OperationMode> {
        match self.requested {
            Some(m) if standstill => {
                self.requested = None;
                let changed = m != self.active;
                self.active = m;
                changed.then_some(m)
            }
            _ => None,
        }
    }
    /// The active mode (6061h).
    pub const fn active(&self) -> OperationMode {
        self.active
    }
    /// The mode written but not yet active.
    pub const fn pending(&self) -> Option<OperationMode> {
        self.requested
    }
}

/// The profile position objects latched at the new set-point edge: 607Ah, 6081h, 6083h, 6084h.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PpObjects {
    /// 607Ah target position (absolute or relative per bit 6).
    pub target: i32,
    /// 6081h profile velocity.
    pub velocity: u32,
    /// 6083h profile acceleration.
    pub acceleration: u32,
    /// 6084h profile deceleration.
    pub deceleration: u32,
}

/// A move the axis is to run: the absolute target and the profile latched with it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Move {
    /// The absolute target (a relative set-point is resolved against the last target).
    pub target: i32,
    /// Profile velocity.
    pub velocity: u32,
    /// Acceleration.
    pub acceleration: u32,
    /// Deceleration.
    pub deceleration: u32,
}

/// What the device does with a controlword in profile position mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PpAction {
    /// Run this move now (the axis was idle, or change set immediately replaced the running move).
    Start(Move),
    /// The move waits until the running target is reached.
    Queued(Move),
    /// A new set-point edge while the one-deep buffer is full: not taken, not acknowledged.
    Refused,
}

/// Device side of the profile position handshake. It does not move the axis: the simulator runs
/// the [`Move`]s it returns and reports back with [`PpDevice::move_finished`] and
/// [`PpDevice::set_standstill`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PpDevice {
    polarity: AbsRel,
    honour_immediate: bool,
    last_new_set_point: bool,
    acknowledged: bool,
    active: Option<Move>,
    queued: Option<Move>,
    last_target: i32,
    target_reached: bool,
    halt: bool,
    standstill: bool,
}

impl PpDevice {
    /// The handshake of a device with `profile`, axis at rest at `position`.
    pub const fn new(profile: &DeviceProfile, position: i32) -> Self {
        PpDevice {
            polarity: profile.abs_rel,
            honour_immediate: profile.change_set_immediately,
            last_new_set_point: false,
            acknowledged: false,
            active: None,
            queued: None,
            last_target: position,
            // At rest with nothing to do the target counts as reached (TLC5xx trace 0421h).
            target_reached: true,
            halt: false,
            standstill: true,
        }
    }

    /// Drops every move (mode change, leaving Operation enabled, quick stop, fault); relative
    /// set-points count from `position` from now on.
    pub fn reset(&mut self, position: i32) {
        self.active = None;
        self.queued = None;
        self.acknowledged = false;
        self.last_target = position;
        self.target_reached = true;
    }

    /// A controlword while the mode is active and the drive in Operation enabled. `objects` are
    /// the current 607Ah/6081h/6083h/6084h, latched if bit 4 rose.
    pub fn handle_controlword(&mut self, cw: Controlword, objects: &PpObjects) -> Option<PpAction> {
        let rising = cw.new_set_point() && !self.last_new_set_point;
        self.last_new_set_point = cw.new_set_point();
        self.halt = cw.halt();
        if !cw.new_set_point() {
            // The master saw the acknowledge; bit 12 now only shows a full buffer.
            self.acknowledged = false;
        }
        if !rising {
            return None;
        }
        let immediate = self.honour_immediate && cw.change_set_immediately();
        if self.queued.is_some() && !immediate {
            return Some(PpAction::Refused);
        }
        let target = if cw.is_relative(self.polarity) {
            // The running (or last) target is the base, so a relative move during motion adds
            // to it (TLC5xx §5.4.2, MTR-DCI E13); the 32-bit register wraps like the device's.
            self.last_target.wrapping_add(objects.target)
        } else {
            objects.target
        };
        self.last_target = target;
        let m = Move {
            target,
            velocity: objects.velocity,
            acceleration: objects.acceleration,
            deceleration: objects.deceleration,
        };
        self.acknowledged = true;
        self.target_reached = false;
        if self.active.is_none() || immediate {
            self.queued = None;
            self.active = Some(m);
            Some(PpAction::Start(m))
        } else {
            self.queued = Some(m);
            Some(PpAction::Queued(m))
        }
    }

    /// The axis reached the active target: the queued move, if any, starts now.
    pub fn move_finished(&mut self) -> Option<Move> {
        self.active = self.queued.take();
        if self.active.is_none() {
            self.target_reached = true;
        }
        self.active
    }

    /// Whether the axis stands still (bit 10 is also set when halted at standstill).
    pub fn set_standstill(&mut self, standstill: bool) {
        self.standstill = standstill;
    }

    /// Whether controlword bit 8 "halt" is set: the axis brakes on the profile deceleration and
    /// keeps the move, resuming when the bit drops.
    pub const fn halted(&self) -> bool {
        self.halt
    }
    /// The move the axis runs.
    pub const fn active(&self) -> Option<Move> {
        self.active
    }
    /// The move waiting in the buffer.
    pub const fn queued(&self) -> Option<Move> {
        self.queued
    }

    /// Bits 10 (target reached) and 12 (set-point acknowledge) for the statusword.
    pub const fn status_bits(&self) -> Statusword {
        let reached = self.target_reached || (self.halt && self.standstill);
        let ack = self.acknowledged || self.queued.is_some();
        Statusword(
            if reached {
                Statusword::TARGET_REACHED
            } else {
                0
            } | if ack {
                Statusword::SET_POINT_ACKNOWLEDGE
            } else {
                0
            },
        )
    }
}

/// A set-point the master wants to send.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SetPointRequest {
    /// The value for 607Ah.
    pub target: i32,
    /// Relative to the last target (bit 6, with the device's polarity).
    pub relative: bool,
    /// Change set immediately (bit 5).
    pub immediate: bool,
}

/// Why the master cannot send a set-point now.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum PpError {
    /// The previous handshake has not finished (bit 12 must drop first).
    #[error("the previous set-point handshake is still running")]
    Busy,
}

/// Where the master's handshake stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PpMasterState {
    /// Free: a set-point may be requested.
    Idle,
    /// Bit 4 is high, waiting for bit 12.
    Requested,
    /// Bit 12 seen, bit 4 low, waiting for bit 12 to drop.
    Acknowledged,
}

/// What the master learnt from a statusword.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PpEvent {
    /// The device took the set-point (bit 12 rose).
    Acknowledged,
    /// The device can take the next set-point (bit 12 dropped).
    Ready,
    /// The last target acknowledged is reached (bit 10 after the acknowledge).
    TargetReached,
}

/// Master side of the profile position handshake.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PpMaster {
    polarity: AbsRel,
    state: PpMasterState,
    request: Option<SetPointRequest>,
    awaiting_target: bool,
}

impl PpMaster {
    /// A master for a device with bit 6 `polarity`.
    pub const fn new(polarity: AbsRel) -> Self {
        PpMaster {
            polarity,
            state: PpMasterState::Idle,
            request: None,
            awaiting_target: false,
        }
    }
    /// Where the handshake stands.
    pub const fn state(&self) -> PpMasterState {
        self.state
    }
    /// Starts a handshake; the caller sends 607Ah = [`PpMaster::target`] with (or before) the
    /// next [`PpMaster::controlword`].
    pub fn request(&mut self, r: SetPointRequest) -> Result<(), PpError> {
        if self.state != PpMasterState::Idle {
            return Err(PpError::Busy);
        }
        self.request = Some(r);
        self.state = PpMasterState::Requested;
        Ok(())
    }
    /// The 607Ah value of the current request.
    pub fn target(&self) -> Option<i32> {
        self.request.map(|r| r.target)
    }
    /// `base` (the device-control command, halt) with bits 4, 5, 6 for this moment.
    pub const fn controlword(&self, base: Controlword) -> Controlword {
        let mut cw = base.with(Controlword::NEW_SET_POINT, false);
        if let Some(r) = self.request {
            cw = cw
                .with(Controlword::CHANGE_SET_IMMEDIATELY, r.immediate)
                .with_relative(r.relative, self.polarity);
        }
        cw.with(
            Controlword::NEW_SET_POINT,
            matches!(self.state, PpMasterState::Requested),
        )
    }
    /// Abandons the handshake (the device left Operation enabled or the mode changed).
    pub fn reset(&mut self) {
        self.state = PpMasterState::Idle;
        self.request = None;
        self.awaiting_target = false;
    }
    /// A statusword arrived. Bit 12 is only looked at during a handshake, so a late 1427h
    /// (TLC5xx trace, erratum A12) is harmless.
    pub fn handle_statusword(&mut self, sw: Statusword) -> Vec<PpEvent, 2> {
        let mut events = Vec::new();
        // Cannot fail below: at most two pushes into two slots.
        match self.state {
            PpMasterState::Requested if sw.set_point_acknowledge() => {
                self.state = PpMasterState::Acknowledged;
                self.awaiting_target = true;
                let _ = events.push(PpEvent::Acknowledged);
                // The acknowledging statusword still shows the old move's bit 10.
                return events;
            }
            PpMasterState::Acknowledged if !sw.set_point_acknowledge() => {
                self.state = PpMasterState::Idle;
                let _ = events.push(PpEvent::Ready);
            }
            _ => {}
        }
        if self.awaiting_target && sw.target_reached() && self.state != PpMasterState::Requested {
            self.awaiting_target = false;
            let _ = events.push(PpEvent::TargetReached);
        }
        events
    }
}

/// Profile velocity thresholds (CiA 402 606Dh/606Eh velocity window, 606Fh/6070h velocity
/// threshold, 60F8h max slippage). The TLC5xx documents the bits but not these objects: its
/// values are simulator settings there.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PvSettings {
    /// |target − actual| at or below this counts as "target reached" (bit 10).
    pub velocity_window: u32,
    /// How long it must hold.
    pub velocity_window_time: Duration,
    /// |actual| at or below this counts as "speed = 0" (bit 12).
    pub velocity_threshold: u32,
    /// How long it must hold.
    pub velocity_threshold_time: Duration,
    /// |target − actual| above this sets "max slippage error" (bit 13); `None` disables it.
    pub max_slippage: Option<u32>,
}

/// Device side: the profile velocity statusword bits 10, 12 and 13 from target and actual
/// velocity, over time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PvMonitor {
    settings: PvSettings,
    in_window_since: Option<Instant>,
    below_threshold_since: Option<Instant>,
}

impl PvMonitor {
    /// A monitor with `settings`.
    pub const fn new(settings: PvSettings) -> Self {
        PvMonitor {
            settings,
            in_window_since: None,
            below_threshold_since: None,
        }
    }
    /// The bits for target velocity `target` (60FFh) and actual velocity `actual` at `now`.
    pub fn update(&mut self, target: i32, actual: i32, now: Instant) -> Statusword {
        let s = self.settings;
        let slip = (i64::from(target) - i64::from(actual)).unsigned_abs();
        let speed = i64::from(actual).unsigned_abs();
        let held = |since: &mut Option<Instant>, cond: bool, time: Duration| -> bool {
            if !cond {
                *since = None;
                return false;
            }
            let t0 = *since.get_or_insert(now);
            now.saturating_duration_since(t0) >= time
        };
        let reached = held(
            &mut self.in_window_since,
            slip <= u64::from(s.velocity_window),
            s.velocity_window_time,
        );
        let zero = held(
            &mut self.below_threshold_since,
            speed <= u64::from(s.velocity_threshold),
            s.velocity_threshold_time,
        );
        let slipping = s.max_slippage.is_some_and(|m| slip > u64::from(m));
        Statusword(0)
            .with(Statusword::TARGET_REACHED, reached)
            .with(Statusword::SPEED_ZERO, zero)
            .with(Statusword::MAX_SLIPPAGE, slipping)
    }
}

#[cfg(test)]
mod tests {

    #[test]
    fn interpolation_time_period_is_exact_and_round_trips() {
        let us = Duration::from_micros;
        assert_eq!(interpolation_time_period(us(1000)), Some((1, -3)));
        assert_eq!(interpolation_time_period(us(2000)), Some((2, -3)));
        assert_eq!(interpolation_time_period(us(250)), Some((25, -5)));
        assert_eq!(interpolation_time_period(us(255)), Some((255, -6)));
        assert_eq!(interpolation_time_period(us(1500)), Some((15, -4)));
        assert_eq!(interpolation_time_period(us(4_000_000)), Some((40, -1)));
        // Milliseconds before coarser units: 10 ms is (10, −3), not (1, −2).
        assert_eq!(interpolation_time_period(us(10_000)), Some((10, -3)));
        assert_eq!(interpolation_time_period(us(100_000)), Some((100, -3)));
        assert_eq!(interpolation_time_period(us(500_000)), Some((50, -2)));
        // 257 µs: no value of 1..=255 gives it exactly.
        assert_eq!(interpolation_time_period(us(257)), None);
        assert_eq!(interpolation_time_period(Duration::from_nanos(1500)), None);
        assert_eq!(interpolation_time_period(Duration::ZERO), None);
        for p in [1u64, 125, 250, 500, 1000, 1500, 2000, 4000, 10_000, 100_000] {
            let (v, i) = interpolation_time_period(us(p)).unwrap();
            assert_eq!(interpolation_period_of(v, i), Some(us(p)), "{p} µs");
        }
        assert_eq!(interpolation_period_of(0, -3), None);
        assert_eq!(interpolation_period_of(1, -7), None);
    }
    use super::*;
    use crate::cia402::{MTR_DCI, TLC5XX};

    const OBJ: PpObjects = PpObjects {
        target: 1500,
        velocity: 500,
        acceleration: 2000,
        deceleration: 1000,
    };

    fn sw(state_bits: u16, pp: &PpDevice) -> Statusword {
        Statusword(state_bits | pp.status_bits().0)
    }

    #[test]
    fn tlc_profile_position_handshake_of_section_8_5() {
        let mut drive = PpDevice::new(&TLC5XX, 0);
        let mut master = PpMaster::new(TLC5XX.abs_rel);
        master
            .request(SetPointRequest {
                target: 1500,
                relative: true,
                immediate: false,
            })
            .unwrap();
        // 301: 1F 00 DC 05 00 00 — cw 001Fh, 607Ah = 1500 (relative with the manual's polarity).
        let cw = master.controlword(Controlword(0x000F));
        assert_eq!(cw.to_bytes(), [0x1F, 0x00]);
        assert_eq!(
            master.target().unwrap().to_le_bytes(),
            [0xDC, 0x05, 0x00, 0x00]
        );
        let started = drive.handle_controlword(cw, &OBJ);
        assert_eq!(
            started,
            Some(PpAction::Start(Move {
                target: 1500,
                velocity: 500,
                acceleration: 2000,
                deceleration: 1000
            }))
        );
        // 181: 27 10 — set-point acknowledge, target not reached.
        let s = sw(0x0027, &drive);
        assert_eq!(s.to_bytes(), [0x27, 0x10]);
        assert_eq!(
            master.handle_statusword(s).as_slice(),
            &[PpEvent::Acknowledged]
        );
        // 201: 0F 00 — bit 4 cleared.
        let cw = master.controlword(Controlword(0x000F));
        assert_eq!(cw.to_bytes(), [0x0F, 0x00]);
        assert_eq!(drive.handle_controlword(cw, &OBJ), None);
        // 181: 27 00 — acknowledge cleared.
        let s = sw(0x0027, &drive);
        assert_eq!(s.to_bytes(), [0x27, 0x00]);
        assert_eq!(master.handle_statusword(s).as_slice(), &[PpEvent::Ready]);
        // Target reached: 0427h (the manual prints 1427h, erratum A12).
        assert_eq!(drive.move_finished(), None);
        let s = sw(0x0027, &drive);
        assert_eq!(s.to_bytes(), [0x27, 0x04]);
        assert_eq!(
            master.handle_statusword(s).as_slice(),
            &[PpEvent::TargetReached]
        );
        // The printed 1427h does not confuse an idle master.
        assert!(master.handle_statusword(Statusword(0x1427)).is_empty());
    }

    #[test]
    fn second_set_point_is_queued_and_third_refused() {
        let mut drive = PpDevice::new(&TLC5XX, 100);
        let abs = Controlword(0x005F); // bit 6 = 1: absolute on the TLC5xx
        assert!(matches!(
            drive.handle_controlword(abs, &PpObjects { target: 1000, ..OBJ }),
            Some(PpAction::Start(m)) if m.target == 1000
        ));
        drive.handle_controlword(Controlword(0x004F), &OBJ);
        assert_eq!(drive.status_bits(), Statusword(0));
        // Relative while running: added to the running target, queued (bit 5 = 0).
        let rel = Controlword(0x001F);
        assert!(matches!(
            drive.handle_controlword(rel, &PpObjects { target: 50, ..OBJ }),
            Some(PpAction::Queued(m)) if m.target == 1050
        ));
        drive.handle_controlword(Controlword(0x000F), &OBJ);
        // Bit 12 stays set while the buffer is full, even with bit 4 low.
        assert_eq!(
            drive.status_bits(),
            Statusword(Statusword::SET_POINT_ACKNOWLEDGE)
        );
        assert_eq!(drive.handle_controlword(rel, &OBJ), Some(PpAction::Refused));
        drive.handle_controlword(Controlword(0x000F), &OBJ);
        // First target reached: the queued move starts, bit 12 drops, bit 10 stays low.
        assert_eq!(drive.move_finished().map(|m| m.target), Some(1050));
        assert_eq!(drive.status_bits(), Statusword(0));
        assert_eq!(drive.move_finished(), None);
        assert_eq!(drive.status_bits(), Statusword(Statusword::TARGET_REACHED));
    }

    #[test]
    fn change_set_immediately_replaces_the_running_move_where_supported() {
        let mut tlc = PpDevice::new(&TLC5XX, 0);
        tlc.handle_controlword(Controlword(0x005F), &OBJ);
        tlc.handle_controlword(Controlword(0x004F), &OBJ);
        let immediate = Controlword(0x007F); // absolute, change set immediately
        assert!(matches!(
            tlc.handle_controlword(immediate, &PpObjects { target: -7, ..OBJ }),
            Some(PpAction::Start(m)) if m.target == -7
        ));
        // The MTR-DCI has no change set immediately: bit 5 is ignored, the set-point waits.
        let mut mtr = PpDevice::new(&MTR_DCI, 0);
        mtr.handle_controlword(Controlword(0x001F), &OBJ); // bit 6 = 0: absolute on the MTR-DCI
        mtr.handle_controlword(Controlword(0x000F), &OBJ);
        assert!(matches!(
            mtr.handle_controlword(Controlword(0x003F), &PpObjects { target: -7, ..OBJ }),
            Some(PpAction::Queued(m)) if m.target == -7
        ));
    }

    #[test]
    fn halt_at_standstill_reports_target_reached() {
        let mut drive = PpDevice::new(&TLC5XX, 0);
        drive.handle_controlword(Controlword(0x005F), &OBJ);
        drive.set_standstill(false);
        drive.handle_controlword(Controlword(0x014F), &OBJ);
        assert!(drive.halted());
        assert!(!drive.status_bits().target_reached());
        drive.set_standstill(true);
        assert!(drive.status_bits().target_reached());
        // Releasing halt resumes: the move is still active, target not reached.
        drive.handle_controlword(Controlword(0x004F), &OBJ);
        assert!(!drive.status_bits().target_reached());
        assert!(drive.active().is_some());
    }

    #[test]
    fn relative_targets_wrap_instead_of_panicking() {
        let mut drive = PpDevice::new(&TLC5XX, i32::MAX);
        let m = drive.handle_controlword(Controlword(0x001F), &PpObjects { target: 1, ..OBJ });
        assert!(matches!(m, Some(PpAction::Start(m)) if m.target == i32::MIN));
    }

    #[test]
    fn master_refuses_a_second_request_until_ready() {
        let mut master = PpMaster::new(AbsRel::ZeroIsAbsolute);
        let r = SetPointRequest {
            target: 1,
            relative: false,
            immediate: true,
        };
        master.request(r).unwrap();
        assert_eq!(master.request(r), Err(PpError::Busy));
        assert_eq!(master.controlword(Controlword(0x000F)), Controlword(0x003F));
        master.handle_statusword(Statusword(0x1027));
        assert_eq!(master.request(r), Err(PpError::Busy));
        master.handle_statusword(Statusword(0x0027));
        assert_eq!(master.request(r), Ok(()));
    }

    #[test]
    fn mode_selector_waits_for_standstill_and_checks_the_device() {
        let mut sel = ModeSelector::new(OperationMode::ProfilePosition);
        assert_eq!(sel.request(3, &TLC5XX), Ok(()));
        assert_eq!(sel.update(false), None);
        assert_eq!(sel.active(), OperationMode::ProfilePosition);
        assert_eq!(sel.update(true), Some(OperationMode::ProfileVelocity));
        assert_eq!(sel.request(3, &MTR_DCI), Err(ModeError::Unsupported(3)));
        assert_eq!(sel.request(5, &TLC5XX), Err(ModeError::Unknown(5)));
        assert_eq!(sel.request(-1, &TLC5XX), Ok(()));
        assert_eq!(MTR_DCI.supported_drive_modes(), 0x29);
        for code in i8::MIN..=i8::MAX {
            if let Ok(m) = OperationMode::from_code(code) {
                assert_eq!(m.code(), code);
            }
        }
    }

    #[test]
    fn profile_velocity_bits_follow_windows_and_times() {
        let mut pv = PvMonitor::new(PvSettings {
            velocity_window: 10,
            velocity_window_time: Duration::from_millis(5),
            velocity_threshold: 2,
            velocity_threshold_time: Duration::from_millis(5),
            max_slippage: Some(100),
        });
        let t = Instant::from_millis;
        // At rest with target 0: speed = 0 after the threshold time.
        assert_eq!(pv.update(0, 0, t(0)), Statusword(0));
        assert_eq!(
            pv.update(0, 0, t(5)),
            Statusword(Statusword::TARGET_REACHED | Statusword::SPEED_ZERO)
        );
        // New target 133: slipping while accelerating, no speed = 0.
        assert_eq!(
            pv.update(133, 0, t(6)),
            Statusword(Statusword::MAX_SLIPPAGE | Statusword::SPEED_ZERO)
        );
        assert_eq!(pv.update(133, 130, t(7)), Statusword(0));
        assert_eq!(
            pv.update(133, 131, t(12)),
            Statusword(Statusword::TARGET_REACHED)
        );
        assert!(pv.update(i32::MIN, i32::MAX, t(13)).max_slippage());
    }

    proptest::proptest! {
        /// Master and device driven together, with moves finishing at random ticks: every
        /// set-point the master sends is taken exactly once, the device never refuses one, and
        /// the last target is reported reached.
        #[test]
        fn master_and_device_handshake_never_loses_a_set_point(
            requests in proptest::collection::vec((-1000i32..1000, proptest::bool::ANY, proptest::bool::ANY), 1..12),
            finish in proptest::collection::vec(proptest::bool::ANY, 64),
            tlc in proptest::bool::ANY,
        ) {
            let profile = if tlc { TLC5XX } else { MTR_DCI };
            let mut drive = PpDevice::new(&profile, 0);
            let mut master = PpMaster::new(profile.abs_rel);
            let mut pending = requests.iter();
            let mut taken = 0usize;
            let mut reached = false;
            let mut expected_last = 0i32;
            let mut sent_all = false;
            for tick in 0..2000usize {
                if master.state() == PpMasterState::Idle {
                    match pending.next() {
                        Some(&(target, relative, immediate)) => {
                            master.request(SetPointRequest { target, relative, immediate }).unwrap();
                            reached = false;
                        }
                        None => sent_all = true,
                    }
                }
                let objects = PpObjects { target: master.target().unwrap_or(0), ..OBJ };
                match drive.handle_controlword(master.controlword(Controlword(0x000F)), &objects) {
                    Some(PpAction::Start(m)) | Some(PpAction::Queued(m)) => {
                        taken += 1;
                        expected_last = m.target;
                    }
                    Some(PpAction::Refused) => proptest::prop_assert!(false, "refused at {tick}"),
                    None => {}
                }
                if finish[tick % finish.len()] || sent_all {
                    drive.move_finished();
                }
                for e in master.handle_statusword(Statusword(0x0027 | drive.status_bits().0)) {
                    reached |= e == PpEvent::TargetReached;
                }
                if sent_all && reached {
                    break;
                }
            }
            proptest::prop_assert_eq!(taken, requests.len());
            proptest::prop_assert!(reached);
            proptest::prop_assert_eq!(drive.active(), None);
            // Relative targets resolve against the last target, so the final one is known.
            let mut last = 0i32;
            for &(t, rel, _) in &requests {
                last = if rel { last.wrapping_add(t) } else { t };
            }
            proptest::prop_assert_eq!(expected_last, last);
        }
    }
}
