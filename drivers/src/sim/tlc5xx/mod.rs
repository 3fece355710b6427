//! A simulated Twin Line TLC5xx positioning controller on CANopen (DS301 / DSP402), digest
//! seed-003: the CiA 301 device of [`crate::canopen::device`] over the TLC5xx dictionary
//! ([`od`]), the DSP402 state machine, modes and handshakes of [`crate::cia402`], and the
//! physical axis of [`crate::sim::axis`] stepped in virtual time, one tick per
//! [`TlcConfig::tick`].
//!
//! What it adds to the generic device, with the manual's section:
//! - DSP402 device control (§3.1–3.3) with the bit-6 polarity and the Fault coding as settings
//!   (errata A1, A2); `driveCtrl` one-shot bits and `driveStat` (§3.4).
//! - Profile position with the set-point handshake, change set immediately and the one-deep
//!   queue (§3.6); profile velocity (§3.7); homing methods 1, 2, 7, 11, 17, 18, 23, 27, 35 with
//!   `p_disHome` and `startSetp` (§3.8); quick stop, halt, fault reaction and reset (§3.9).
//! - The fast PTP of R_PDO4 / T_PDO4 (§2.4, §4.1) and the position lists driving TRIGGER (§4.3).
//! - The 1007h window: a synchronous RPDO arriving after the window waits for the SYNC after
//!   next (§2.5).
//! - Faults raised on request or by the axis (following error, limit switches, supply voltage,
//!   over-temperature, life guarding), reported by statusword bit 3, EMCY, 1001h, 1003h, 603Fh
//!   and 2400h, cleared by a fault-reset edge once the cause is gone (§6).
//! - SDO vetoes with the manual's codes ([`TlcHooks`]).
//!
//! Not simulated (yet): the SIG sub-modes other than PTP (speed 2095h, jog, electronic gear,
//! homing via 20F0h), record processing, teach-in, fast capture, the EEPROM image
//! (eeprSave/default are accepted and ignored), SignEnabl/SignLevel/SignQstop (limit switches
//! always stop, with the 6085h ramp), p_outHome, the heartbeat consumer 1016h (stored, not
//! monitored). T_PDO4 (type 254) is sent on any change of its data, not only of StatePTP, and
//! 1003h keeps the generic device's 8 entries where the manual has 1.
//!
//! ```
//! use drivers::sim::tlc5xx::{Tlc5xx, TlcConfig};
//! use drivers::canopen::{endpoint::Endpoint, NodeId};
//! use drivers::time::Instant;
//! let mut drive = Tlc5xx::new(TlcConfig::new(NodeId::new(1).unwrap()), Instant::ZERO).unwrap();
//! // Power-on: boot-up on the EMCY COB-ID without data (digest §2.2, erratum A4).
//! let boot = drive.poll_transmit(Instant::ZERO).unwrap();
//! assert_eq!((boot.cob_id(), boot.dlc()), (Some(0x81), 0));
//! assert_eq!(drive.statusword(), 0x0040); // Switch on disabled
//! ```

pub mod od;

use core::time::Duration;

use crate::can::Frame;
use crate::canopen::device::{Device, DeviceEvent, DeviceHooks};
use crate::canopen::endpoint::Endpoint;
use crate::canopen::nmt::{BootUpStyle, NmtState, ResetKind};
use crate::canopen::od::{EntryDef, OdError, Resolved, le_u64};
use crate::canopen::{AbortCode, Address, NodeId};
use crate::cia402::controlword::{AbsRel, Controlword};
use crate::cia402::homing::{HomingCommand, HomingDevice, HomingMethod as Method};
use crate::cia402::modes::PvSettings;
use crate::cia402::modes::{
    ModeSelector, Move, OperationMode, PpAction, PpDevice, PpObjects, PvMonitor,
};
use crate::cia402::objects::tlc::SigState;
use crate::cia402::state::{DeviceStateMachine, FaultCoding, State};
use crate::cia402::statusword::Statusword;
use crate::cia402::{DeviceProfile, TLC5XX};
use crate::sim::axis::{self, Axis, Environment, Faults, Mechanics, Switches, WindowTimer};
use crate::sim::homing::{Homing, HomingMethod, HomingParams, HomingState};
use crate::time::Instant;
use od::{OD_BYTES, OD_ENTRIES, TlcOd};

/// How many dictionary values [`Tlc5xx`] publishes each tick.
const PUBLISHED: usize = 23;

/// The objects `Tlc5xx::publish` writes, in the order of its values.
const PUBLISHED_OBJECTS: [(u16, u8); PUBLISHED] = [
    (0x6041, 0),
    (0x6061, 0),
    (0x6063, 0),
    (0x6064, 0),
    (0x2089, 0),
    (0x6069, 0),
    (0x606C, 0),
    (0x208A, 0),
    (0x20EB, 0),
    (0x60F4, 0),
    (0x2073, 0),
    (0x2013, 0),
    (0x208C, 0),
    (0x60FD, 0),
    (0x2048, 0),
    (0x60FE, 1),
    (0x2041, 0),
    (0x2091, 0),
    (0x20F1, 0),
    (0x20B5, 0),
    (0x2062, 0),
    (0x2049, 0),
    (0x603F, 0),
];

/// The CiA 301 device under the simulator (SDO downloads up to 64 bytes: strings are 16 at most).
pub type TlcDevice = Device<'static, OD_ENTRIES, OD_BYTES, 64, TlcHooks>;

const fn a(index: u16, sub: u8) -> Address {
    Address::new(index, sub)
}

/// Simulator settings: what the manual leaves open or the errata make a choice of.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TlcConfig {
    /// Node-ID (factory 127).
    pub node: NodeId,
    /// Boot-up message form (erratum A4): the manual's §3.5 form is 80h+n without data.
    pub boot_up: BootUpStyle,
    /// Controlword bit 6 in profile position (erratum A1): the manual's 0 = relative.
    pub abs_rel: AbsRel,
    /// How Fault shows in the statusword (erratum A2): DSP402 x0xx1000 by default.
    pub fault_coding: FaultCoding,
    /// Motor increments per revolution (AC with Sincoder: 16384, §6.3).
    pub increments_per_rev: u32,
    /// Control tick: the axis is stepped and the statusword updated this often.
    pub tick: Duration,
    /// The motor's speed limit, rpm (60FBh n_max default 6000).
    pub max_speed_rpm: u32,
    /// Position loop time constant of the plant (the following error at speed v is v·tau).
    pub position_time_constant: Duration,
    /// Limit and reference switches, end stops and index phase, raw increments.
    pub environment: Environment,
    /// Raw position at power-on.
    pub start_position: i64,
    /// PV "speed reached" window (bit 10), rpm; "speed = 0" (bit 12) uses 1 rpm.
    pub pv_window_rpm: u32,
    /// PV max slippage (bit 13), rpm; `None` = not monitored.
    pub pv_max_slip_rpm: Option<u32>,
}

impl TlcConfig {
    /// The factory settings for `node`: boot-up as §3.5, bit 6 as printed, DSP402 Fault coding,
    /// 16384 inc/rev, 1 ms tick, no switches and no end stops.
    pub const fn new(node: NodeId) -> Self {
        TlcConfig {
            node,
            boot_up: BootUpStyle::LegacyEmcyEmpty,
            abs_rel: AbsRel::ZeroIsRelative,
            fault_coding: FaultCoding::Dsp402,
            increments_per_rev: 16384,
            tick: Duration::from_millis(1),
            max_speed_rpm: 6000,
            position_time_constant: Duration::from_millis(2),
            environment: Environment {
                travel: None,
                limit_negative: None,
                limit_positive: None,
                reference: None,
                load: axis::Load::None,
                index_phase: 0,
            },
            start_position: 0,
            pv_window_rpm: 2,
            pv_max_slip_rpm: None,
        }
    }
    /// The DSP402 profile these settings describe.
    pub const fn profile(&self) -> DeviceProfile {
        DeviceProfile {
            abs_rel: self.abs_rel,
            fault_coding: self.fault_coding,
            ..TLC5XX
        }
    }
}

/// The user-unit scaling of 6093h / 6094h / 6097h (digest §3.10): 1 usr = num/den rev,
/// velocity usr = num/den rpm, acceleration usr = num/den rpm/s. Rounds to the nearest
/// increment, as the drive does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Scaling {
    /// Motor increments per revolution.
    pub increments_per_rev: i64,
    /// 6093h:01 / :02.
    pub position: (i64, i64),
    /// 6094h:01 / :02.
    pub velocity: (i64, i64),
    /// 6097h:01 / :02.
    pub acceleration: (i64, i64),
}

fn div_round(n: i128, d: i128) -> i64 {
    if d == 0 {
        return 0;
    }
    let (num, den) = (2 * n + d.signum() * n.signum() * d.abs(), 2 * d);
    // Both sides fit in 64 bits (every value the drive publishes each tick): the same
    // truncating quotient by a 64-bit division instead of a 128-bit one. i64::MIN / -1 does
    // not fit and takes the general path (which clamps it).
    if let (Ok(a), Ok(b)) = (i64::try_from(num), i64::try_from(den))
        && (a != i64::MIN || b != -1)
    {
        return a / b;
    }
    let q = num / den;
    q.clamp(i64::MIN as i128, i64::MAX as i128) as i64
}

impl Scaling {
    /// User position units to increments.
    pub fn pos_to_inc(&self, usr: i64) -> i64 {
        let (n, d) = self.position;
        div_round(
            usr as i128 * n as i128 * self.increments_per_rev as i128,
            d as i128,
        )
    }
    /// Increments to user position units.
    pub fn inc_to_pos(&self, inc: i64) -> i64 {
        let (n, d) = self.position;
        div_round(
            inc as i128 * d as i128,
            n as i128 * self.increments_per_rev as i128,
        )
    }
    /// User velocity units to inc/s.
    pub fn vel_to_inc(&self, usr: i64) -> i64 {
        let (n, d) = self.velocity;
        div_round(
            usr as i128 * n as i128 * self.increments_per_rev as i128,
            d as i128 * 60,
        )
    }
    /// inc/s to user velocity units.
    pub fn inc_to_vel(&self, inc: i64) -> i64 {
        let (n, d) = self.velocity;
        div_round(
            inc as i128 * d as i128 * 60,
            n as i128 * self.increments_per_rev as i128,
        )
    }
    /// User acceleration units to inc/s².
    pub fn acc_to_inc(&self, usr: i64) -> i64 {
        let (n, d) = self.acceleration;
        div_round(
            usr as i128 * n as i128 * self.increments_per_rev as i128,
            d as i128 * 60,
        )
    }
}

/// A fault the simulator can raise (digest §6). Codes marked \[ASSUMPTION\] in the digest: the
/// manual gives no EMCY table.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TlcFault {
    /// |p_dif| > p_maxDiff (2010h); class from Flt_pDiff (204Fh). EMCY 8611h.
    FollowingError,
    /// Positive limit switch reached moving towards it. EMCY FF01h.
    LimitPositive,
    /// Negative limit switch reached moving towards it. EMCY FF02h.
    LimitNegative,
    /// DC-link undervoltage (supply dropped; the power stage is off). EMCY 3220h.
    Undervoltage,
    /// Power-stage over-temperature. EMCY 4310h.
    OverTemperature,
    /// Life guarding: the master stopped polling (100Ch × 100Dh). EMCY 8130h.
    LifeGuarding,
}

impl TlcFault {
    /// The EMCY error code (also 603Fh).
    pub const fn emcy_code(self) -> u16 {
        match self {
            TlcFault::FollowingError => 0x8611,
            TlcFault::LimitPositive => 0xFF01,
            TlcFault::LimitNegative => 0xFF02,
            TlcFault::Undervoltage => 0x3220,
            TlcFault::OverTemperature => 0x4310,
            TlcFault::LifeGuarding => 0x8130,
        }
    }
    /// The device error number (2400h, SDO abort 0800 xxxxh). The manual's numbers are in the
    /// device manual, not this one: the simulator uses the EMCY code \[ASSUMPTION\].
    pub const fn error_number(self) -> u16 {
        self.emcy_code()
    }
    /// A fault of the device's own monitoring (driveStat bit 5) rather than an external signal
    /// (bit 6: limit switches).
    pub const fn internal(self) -> bool {
        !matches!(self, TlcFault::LimitPositive | TlcFault::LimitNegative)
    }
    const fn flt_sig_bit(self) -> u32 {
        match self {
            TlcFault::FollowingError => 1 << 0,
            TlcFault::LimitPositive => 1 << 1,
            TlcFault::LimitNegative => 1 << 2,
            TlcFault::Undervoltage => 1 << 3,
            TlcFault::OverTemperature => 1 << 4,
            TlcFault::LifeGuarding => 1 << 5,
        }
    }
}

/// The SDO write rules of the TLC5xx beyond the dictionary's own checks (digest §2.3, §9.1).
#[derive(Debug, Clone, Copy)]
pub struct TlcHooks {
    profile: DeviceProfile,
    max_profile_velocity: u32,
    guard_ms: u16,
    life_factor: u8,
    heartbeat_ms: u16,
    drive: State,
    mode: OperationMode,
    fault_number: Option<u16>,
    abort_move: bool,
}

impl TlcHooks {
    fn new(profile: DeviceProfile) -> Self {
        TlcHooks {
            profile,
            max_profile_velocity: 3000,
            guard_ms: 0,
            life_factor: 0,
            heartbeat_ms: 0,
            drive: State::SwitchOnDisabled,
            mode: OperationMode::ProfilePosition,
            fault_number: None,
            abort_move: false,
        }
    }
}

impl DeviceHooks for TlcHooks {
    fn check_write(
        &mut self,
        def: &EntryDef<'_>,
        data: &[u8],
        state: NmtState,
    ) -> Result<(), AbortCode> {
        let v = le_u64(data);
        let pre_op = state == NmtState::PreOperational;
        match (def.addr.index, def.addr.sub) {
            // p.9-116: a profile velocity above 607Fh is refused and the running move aborted.
            (0x6081, 0) if v > self.max_profile_velocity as u64 => {
                self.abort_move = true;
                Err(AbortCode::ValueTooHigh)
            }
            (0x607F, 0) => {
                self.max_profile_velocity = v as u32;
                Ok(())
            }
            (0x6060, 0) => match OperationMode::from_code(v as u8 as i8) {
                Ok(m) if self.profile.supports_mode(m) => Ok(()),
                _ => Err(AbortCode::InvalidValue),
            },
            (0x6098, 0) => match Method::from_code(v as u8 as i8) {
                Ok(m) if self.profile.supports_homing(m) => Ok(()),
                _ => Err(AbortCode::InvalidValue),
            },
            // SYNC settings and PDO COB-IDs change only in Pre-operational (§2.4, §2.5).
            (0x1005, 0) | (0x1400..=0x1403 | 0x1800..=0x1803, 1) if !pre_op => {
                Err(AbortCode::DeviceState)
            }
            // Heartbeat and life guarding exclude each other (§2.7).
            (0x100C, 0) => {
                if v != 0 && self.life_factor != 0 && self.heartbeat_ms != 0 {
                    return Err(AbortCode::ParamIncompatible);
                }
                self.guard_ms = v as u16;
                Ok(())
            }
            (0x100D, 0) => {
                if v != 0 && self.guard_ms != 0 && self.heartbeat_ms != 0 {
                    return Err(AbortCode::ParamIncompatible);
                }
                self.life_factor = v as u8;
                Ok(())
            }
            (0x1017, 0) => {
                if v != 0 && self.guard_ms != 0 && self.life_factor != 0 {
                    return Err(AbortCode::ParamIncompatible);
                }
                self.heartbeat_ms = v as u16;
                Ok(())
            }
            // SIG start objects: refused with the device error number while a fault is active,
            // and with "device state" outside Operation enable in SIG mode.
            (0x2090 | 0x2092 | 0x2093, 0) => {
                if let Some(n) = self.fault_number {
                    Err(AbortCode::Other(0x0800_0000 | n as u32))
                } else if self.drive != State::OperationEnabled
                    || self.mode != OperationMode::TlcSigMode
                {
                    Err(AbortCode::DeviceState)
                } else {
                    Ok(())
                }
            }
            _ => Ok(()),
        }
    }
}

/// A position list being worked through (§4.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct ListRun {
    base: u16,
    next: u16,
    end: u16,
    kind: u16,
}

/// StatePTP / stateHome / stateList bits (§4.1, §4.3).
const X_END: u16 = SigState::X_END;
const X_ERR: u16 = SigState::X_ERR;
const X_ADD_INFO: u16 = SigState::X_ADD_INFO;
/// 60FEh bit 22: Alarm/TRIGGER.
pub const TRIGGER: u32 = 1 << 22;

/// The simulated TLC5xx: a CANopen [`Endpoint`].
pub struct Tlc5xx {
    cfg: TlcConfig,
    profile: DeviceProfile,
    dev: TlcDevice,
    axis: Axis,
    fsa: DeviceStateMachine,
    modes: ModeSelector,
    pp: PpDevice,
    homing_dev: HomingDevice,
    homing: Option<Homing>,
    pv: PvMonitor,
    pv_bits: u16,
    halted: bool,
    window: WindowTimer,
    ptp: Option<i64>,
    ptp_window: WindowTimer,
    state_ptp: u16,
    state_home: u16,
    list: Option<ListRun>,
    state_list: u16,
    trigger: bool,
    faults: heapless::Vec<TlcFault, 8>,
    supply_down: bool,
    over_temperature: bool,
    referenced: bool,
    dif_peak: u32,
    last_error: u16,
    prev_position: i64,
    last_sync: Option<Instant>,
    late: [Option<Frame>; 4],
    next_tick: Instant,
    /// The values `publish` last wrote, in its order (`None`: write it next time).
    published: [Option<i64>; PUBLISHED],
    /// `publish`'s objects ([`PUBLISHED_OBJECTS`]), found once in the dictionary.
    publish_at: [Resolved; PUBLISHED],
    /// 6093h/6094h/6097h as last read (they change only by SDO or RPDO writes and resets).
    scaling: Scaling,
    /// The settings a tick and every frame read, as last read (the same way).
    settings: Settings,
}

/// Objects the drive reads every tick or every frame, kept out of the dictionary's lookups:
/// they change only by SDO or RPDO writes ([`Tlc5xx::written`]) and resets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
struct Settings {
    /// 2010h p_maxDiff: the following-error limit, increments.
    max_diff: u32,
    /// 2011h p_winDiff: the position window, increments.
    p_win: u64,
    /// 6068h position window time.
    win_time: Duration,
    /// 1005h's COB-ID of the SYNC.
    sync_cob: u16,
    /// 1007h the synchronous window, µs (0: none).
    sync_window_us: u32,
}

impl Settings {
    /// The objects whose writes change the settings.
    const OBJECTS: [(u16, u8); 5] = [
        (0x2010, 0),
        (0x2011, 0),
        (0x6068, 0),
        (0x1005, 0),
        (0x1007, 0),
    ];
}

/// The objects whose writes [`Tlc5xx::written`] acts on, one bit each.
struct Watched;

impl Watched {
    const SCALING: u32 = 1 << 0;
    const SETTINGS: u32 = 1 << 1;
    const MODE: u32 = 1 << 2;
    const LIMIT_MIN: u32 = 1 << 3;
    const LIMIT_MAX: u32 = 1 << 4;
    const LIMIT_MIN_TLC: u32 = 1 << 5;
    const LIMIT_MAX_TLC: u32 = 1 << 6;
    const DIF_PEAK: u32 = 1 << 7;
    const DRIVE_CTRL: u32 = 1 << 8;
    const CONTROLWORD: u32 = 1 << 9;
    const PV_TARGET: u32 = 1 << 10;
    const PTP: u32 = 1 << 11;
    const PTP_ADD: u32 = 1 << 12;
    const PTP_REL: u32 = 1 << 13;
    const LIST_START: u32 = 1 << 14;

    /// The bit of object `index`/`sub` (0: none the drive acts on).
    fn of(index: u16, sub: u8) -> u32 {
        match (index, sub) {
            // Position factor, velocity factor, feed constant: every sub-index.
            (0x6093 | 0x6094 | 0x6097, _) => Self::SCALING,
            (0x6060, 0) => Self::MODE,
            (0x607D, 1) => Self::LIMIT_MIN,
            (0x607D, 2) => Self::LIMIT_MAX,
            (0x2053, 0) => Self::LIMIT_MIN_TLC,
            (0x2052, 0) => Self::LIMIT_MAX_TLC,
            (0x2013, 0) => Self::DIF_PEAK,
            (0x2040, 0) => Self::DRIVE_CTRL,
            (0x6040, 0) => Self::CONTROLWORD,
            (0x60FF, 0) => Self::PV_TARGET,
            (0x2090, 0) => Self::PTP,
            (0x20E8, 0) => Self::PTP_ADD,
            (0x2092, 0) => Self::PTP_REL,
            (0x20B4, 0) => Self::LIST_START,
            x if Settings::OBJECTS.contains(&x) => Self::SETTINGS,
            _ => 0,
        }
    }
}

impl Tlc5xx {
    /// A drive powered on at `now`: Pre-operational, boot-up message queued, DSP402 in Switch on
    /// disabled. Fails only if the dictionary does not fit its capacity (a build error).
    pub fn new(cfg: TlcConfig, now: Instant) -> Result<Self, OdError> {
        let profile = cfg.profile();
        let od = od::tlc_od(cfg.node, cfg.boot_up)?;
        let mut dev = Device::new(cfg.node, od, cfg.boot_up, TlcHooks::new(profile));
        dev.power_on(now);
        let ipr = cfg.increments_per_rev.max(1);
        let per_rpm = |rpm: u64| (rpm * ipr as u64 / 60).min(u32::MAX as u64) as u32;
        let mut ac = axis::Config {
            step: cfg.tick,
            mechanics: Mechanics {
                encoder_increments: ipr,
                gear_num: 1,
                gear_den: 1,
                feed_um: 1000,
            },
            max_velocity: per_rpm(cfg.max_speed_rpm as u64),
            max_acceleration: per_rpm(2_000_000),
            max_deceleration: per_rpm(2_000_000),
            quick_stop_deceleration: per_rpm(2_000_000),
            following_error_limit: 0,
            stop_on_limit_switch: true,
            position_time_constant: cfg.position_time_constant,
            environment: cfg.environment,
            ..axis::Config::default()
        };
        ac.standstill_velocity = ac.standstill_velocity.max(1);
        let axis = Axis::new(ac, cfg.start_position);
        let mut fsa = DeviceStateMachine::new(profile);
        fsa.set_self_test_done(true);
        let pv = PvMonitor::new(PvSettings {
            velocity_window: per_rpm(cfg.pv_window_rpm as u64),
            velocity_window_time: Duration::ZERO,
            velocity_threshold: per_rpm(1),
            velocity_threshold_time: Duration::ZERO,
            max_slippage: cfg.pv_max_slip_rpm.map(|r| per_rpm(r as u64)),
        });
        let publish_at = PUBLISHED_OBJECTS.map(|(i, sub)| dev.od().resolve(a(i, sub)));
        let mut t = Tlc5xx {
            cfg,
            profile,
            dev,
            axis,
            fsa,
            modes: ModeSelector::new(OperationMode::ProfilePosition),
            pp: PpDevice::new(&profile, 0),
            homing_dev: HomingDevice::new(),
            homing: None,
            pv,
            pv_bits: 0,
            halted: false,
            window: WindowTimer::new(),
            ptp: None,
            ptp_window: WindowTimer::new(),
            state_ptp: X_END,
            state_home: 0,
            list: None,
            state_list: 0,
            trigger: false,
            faults: heapless::Vec::new(),
            supply_down: false,
            over_temperature: false,
            referenced: false,
            dif_peak: 0,
            last_error: 0,
            prev_position: cfg.start_position,
            last_sync: None,
            late: [None; 4],
            next_tick: now + cfg.tick,
            published: [None; PUBLISHED],
            publish_at,
            scaling: Scaling {
                increments_per_rev: 1,
                position: (1, 1),
                velocity: (1, 1),
                acceleration: (1, 1),
            },
            // Read below, once the dictionary is there.
            settings: Settings::default(),
        };
        t.scaling = t.compute_scaling();
        t.settings = t.read_settings();
        let p = t.actual_usr();
        t.pp.reset(p);
        t.publish();
        Ok(t)
    }

    // ---- observation ---------------------------------------------------------------------

    /// The settings.
    pub fn config(&self) -> &TlcConfig {
        &self.cfg
    }
    /// The node-ID.
    pub fn node(&self) -> NodeId {
        self.cfg.node
    }
    /// The NMT state.
    pub fn nmt_state(&self) -> NmtState {
        self.dev.state()
    }
    /// The DSP402 state.
    pub fn drive_state(&self) -> State {
        self.fsa.state()
    }
    /// The active mode of operation (6061h).
    pub fn mode(&self) -> OperationMode {
        self.modes.active()
    }
    /// The statusword 6041h as sent.
    pub fn statusword(&self) -> u16 {
        self.dev.od().get_u16(a(0x6041, 0)).unwrap_or(0)
    }
    /// The dictionary.
    pub fn od(&self) -> &TlcOd {
        self.dev.od()
    }
    /// The axis model.
    pub fn axis(&self) -> &Axis {
        &self.axis
    }
    /// The axis model, to move switches or inject a blocked mechanism.
    pub fn axis_mut(&mut self) -> &mut Axis {
        &mut self.axis
    }
    /// The active faults, oldest first.
    pub fn faults(&self) -> &[TlcFault] {
        &self.faults
    }
    /// Whether homing succeeded since power-on.
    pub fn referenced(&self) -> bool {
        self.referenced
    }
    /// The current user-unit scaling.
    pub fn scaling(&self) -> Scaling {
        self.scaling
    }

    /// Reads [`Settings`] from the dictionary (at the start, after a write to one of its
    /// objects or a reset).
    fn read_settings(&self) -> Settings {
        Settings {
            max_diff: self.od_u32(0x2010, 0),
            p_win: u64::from(self.od_u16(0x2011, 0)),
            win_time: Duration::from_millis(u64::from(self.od_u16(0x6068, 0))),
            sync_cob: (self.od_u32(0x1005, 0) & 0x7FF) as u16,
            sync_window_us: self.od_u32(0x1007, 0),
        }
    }

    /// Reads the scaling objects again (after a write to 6093h/6094h/6097h or a reset).
    fn compute_scaling(&self) -> Scaling {
        let od = self.dev.od();
        let pair = |i| {
            (
                od.get_i32(a(i, 1)).unwrap_or(1).max(1) as i64,
                od.get_i32(a(i, 2)).unwrap_or(1).max(1) as i64,
            )
        };
        Scaling {
            increments_per_rev: self.cfg.increments_per_rev.max(1) as i64,
            position: pair(0x6093),
            velocity: pair(0x6094),
            acceleration: pair(0x6097),
        }
    }
    /// The actual position in user units (6064h).
    pub fn actual_usr(&self) -> i32 {
        let p = self.scaling().inc_to_pos(self.axis.status().position);
        p.clamp(i32::MIN as i64, i32::MAX as i64) as i32
    }

    // ---- fault injection -----------------------------------------------------------------

    /// Drops (`false`) or restores the supply: undervoltage, power stage off at once.
    pub fn set_supply_ok(&mut self, ok: bool) {
        self.supply_down = !ok;
        self.axis.inject_supply_drop(!ok);
    }
    /// Over-temperature of the power stage while `on`.
    pub fn set_over_temperature(&mut self, on: bool) {
        self.over_temperature = on;
        self.axis.inject_over_temperature(on);
    }
    /// Jams the mechanism (the following error grows while the drive pushes).
    pub fn inject_block(&mut self, on: bool) {
        self.axis.inject_block(on);
    }

    /// Raises `f` as the manual reports a fault: EMCY, 1001h, 1003h, 603Fh, 2400h, then the
    /// reaction of its class (1: quick stop, stay enabled, warning; 2: quick stop, then Fault;
    /// 3: power stage off, then Fault — classes are \[ASSUMPTION\], §3.9).
    pub fn raise_fault(&mut self, f: TlcFault) {
        if self.faults.contains(&f) {
            return;
        }
        if self.faults.push(f).is_err() {
            return; // every kind is at most once in the list: cannot happen with 8 slots
        }
        let class = self.class(f);
        self.dev.raise_emcy(f.emcy_code(), [class, 0, 0, 0, 0]);
        self.record_error(f.emcy_code());
        match class {
            1 => {
                self.stop_motion(true);
                self.drop_commands();
            }
            _ => {
                self.fsa.set_fault(true);
                if class >= 3 {
                    self.axis.disable();
                } else {
                    self.stop_motion(true);
                }
                self.drop_commands();
            }
        }
        self.publish();
    }

    fn class(&self, f: TlcFault) -> u8 {
        match f {
            TlcFault::FollowingError => {
                self.dev.od().get_u16(a(0x204F, 0)).unwrap_or(3).clamp(1, 3) as u8
            }
            TlcFault::Undervoltage => 3,
            _ => 2,
        }
    }

    fn cause_present(&self, f: TlcFault) -> bool {
        match f {
            TlcFault::Undervoltage => self.supply_down,
            TlcFault::OverTemperature => self.over_temperature,
            // Latched: the cause is the event itself (the reset re-arms the monitoring).
            _ => false,
        }
    }

    fn record_error(&mut self, code: u16) {
        let od = self.dev.od_mut();
        for sub in (2..=20u8).rev() {
            let v = od.get_u16(a(0x2400, sub - 1)).unwrap_or(0);
            let _ = od.set_u16(a(0x2400, sub), v);
        }
        let _ = od.set_u16(a(0x2400, 1), code);
        self.last_error = code;
    }

    /// A target outside the software limits: no motion, EMCY FF22h (p.9-115).
    fn invalid_position(&mut self) {
        self.dev.raise_emcy(0xFF22, [0; 5]);
        self.dev.clear_emcy(0xFF22);
        self.record_error(0xFF22);
    }

    /// The fault-reset edge (cw bit 7, driveCtrl bit 3): faults whose cause is gone clear.
    fn fault_reset(&mut self) {
        self.axis.clear_faults();
        let mut kept = heapless::Vec::<TlcFault, 8>::new();
        for &f in self.faults.clone().iter() {
            if self.cause_present(f) {
                let _ = kept.push(f);
            } else {
                self.dev.clear_emcy(f.emcy_code());
            }
        }
        self.faults = kept;
        let fault = self.faults.iter().any(|&f| self.class(f) >= 2);
        self.fsa.set_fault(fault);
        if self.faults.is_empty() {
            self.last_error = 0;
        }
    }

    // ---- commands ------------------------------------------------------------------------

    fn od_u16(&self, i: u16, s: u8) -> u16 {
        self.dev.od().get_u16(a(i, s)).unwrap_or(0)
    }
    fn od_u32(&self, i: u16, s: u8) -> u32 {
        self.dev.od().get_u32(a(i, s)).unwrap_or(0)
    }
    fn od_i32(&self, i: u16, s: u8) -> i32 {
        self.dev.od().get_i32(a(i, s)).unwrap_or(0)
    }

    /// Stops the axis: quick stop (6085h) or the running command's deceleration.
    fn stop_motion(&mut self, quick: bool) {
        if !self.axis.is_enabled() {
            return;
        }
        if quick {
            let sc = self.scaling();
            let d = sc
                .acc_to_inc(self.od_u32(0x6085, 0) as i64)
                .clamp(1, u32::MAX as i64) as u32;
            let _ = self.axis.run_velocity(0, d, d);
        } else {
            self.axis.hold();
        }
    }

    /// Forgets every command (fault, leaving Operation enable, mode change).
    fn drop_commands(&mut self) {
        let p = self.actual_usr();
        self.pp.reset(p);
        if self.homing.take().is_some() {
            self.homing_dev.reset();
        }
        if self.ptp.take().is_some() {
            self.state_ptp = X_END | X_ERR;
        }
        self.halted = false;
    }

    /// A controlword for the state machine only (6040h, or driveCtrl translated).
    fn device_control(&mut self, cw: Controlword) {
        if cw.fault_reset() && !self.fsa.controlword().fault_reset() {
            self.fault_reset();
        }
        let before = self.fsa.state();
        self.fsa.handle_controlword(cw);
        let after = self.fsa.state();
        self.follow_state(before, after);
    }

    fn follow_state(&mut self, before: State, after: State) {
        use State::*;
        let powered = |s| matches!(s, OperationEnabled | QuickStopActive);
        if after == OperationEnabled && before != OperationEnabled {
            if self.axis.enable().is_err() {
                self.raise_fault(TlcFault::Undervoltage);
                return;
            }
            if before == QuickStopActive {
                // Tr.16 continues the interrupted command (§3.1).
                self.resume();
            } else {
                self.drop_commands();
            }
        } else if after == QuickStopActive && before == OperationEnabled {
            self.stop_motion(true);
        } else if powered(before) && !powered(after) && after != FaultReactionActive {
            // Tr.5, 8, 9, 12: amplifier off, the movement is aborted.
            self.axis.disable();
            self.drop_commands();
        }
    }

    /// Restarts the mode's command after halt or quick stop.
    fn resume(&mut self) {
        match self.modes.active() {
            OperationMode::ProfilePosition => {
                if let Some(m) = self.pp.active() {
                    self.run_move(m);
                }
            }
            OperationMode::ProfileVelocity => self.pv_start(),
            OperationMode::TlcSigMode => {
                if let Some(t) = self.ptp {
                    let (v, acc, dec) = self.ptp_profile(false);
                    self.ptp_move(t, v, acc, dec);
                }
            }
            _ => {}
        }
    }

    fn controlword(&mut self) {
        let cw = Controlword(self.od_u16(0x6040, 0));
        self.device_control(cw);
        if self.fsa.state() != State::OperationEnabled {
            return;
        }
        match self.modes.active() {
            OperationMode::ProfilePosition => {
                let objects = PpObjects {
                    target: self.od_i32(0x607A, 0),
                    velocity: self.od_u32(0x6081, 0),
                    acceleration: self.od_u32(0x6083, 0),
                    deceleration: self.od_u32(0x6084, 0),
                };
                let action = self.pp.handle_controlword(cw, &objects);
                self.halt(cw.halt());
                if let Some(PpAction::Start(m)) = action {
                    self.pp_start(m);
                }
            }
            OperationMode::Homing => match self.homing_dev.handle_controlword(cw) {
                Some(HomingCommand::Start) => self.start_homing(),
                Some(HomingCommand::Interrupt) => {
                    self.homing = None;
                    self.axis.hold();
                }
                None => {}
            },
            OperationMode::ProfileVelocity | OperationMode::TlcSigMode => self.halt(cw.halt()),
            _ => {}
        }
    }

    /// Halt (cw bit 8, §3.9): brake on the command's ramp, keep it, resume on release.
    fn halt(&mut self, on: bool) {
        if on && !self.halted {
            self.halted = true;
            self.axis.hold();
        } else if !on && self.halted {
            self.halted = false;
            self.resume();
        }
    }

    fn limits_allow(&self, target_usr: i64) -> bool {
        let en = self.od_u16(0x2054, 0);
        let over = en & (1 << 5) != 0 && target_usr > self.od_i32(0x2052, 0) as i64;
        let under = en & (1 << 6) != 0 && target_usr < self.od_i32(0x2053, 0) as i64;
        !over && !under
    }

    fn pp_start(&mut self, m: Move) {
        if !self.limits_allow(m.target as i64) {
            self.invalid_position();
            let p = self.actual_usr();
            self.pp.reset(p);
            return;
        }
        if !self.halted {
            self.run_move(m);
        }
    }

    fn run_move(&mut self, m: Move) {
        let sc = self.scaling();
        let vmax = self.od_u32(0x607F, 0);
        let clamp = |v: i64| v.clamp(1, u32::MAX as i64) as u32;
        let p = axis::Profile {
            velocity: clamp(sc.vel_to_inc(m.velocity.min(vmax) as i64)),
            acceleration: clamp(sc.acc_to_inc(m.acceleration as i64)),
            deceleration: clamp(sc.acc_to_inc(m.deceleration as i64)),
        };
        self.window.reset();
        let _ = self.axis.move_to(sc.pos_to_inc(m.target as i64), p);
    }

    fn pv_start(&mut self) {
        if self.modes.active() != OperationMode::ProfileVelocity
            || self.fsa.state() != State::OperationEnabled
            || self.halted
        {
            return;
        }
        let sc = self.scaling();
        let vmax = sc.vel_to_inc(self.od_u32(0x607F, 0) as i64);
        let v = sc
            .vel_to_inc(self.od_i32(0x60FF, 0) as i64)
            .clamp(-vmax, vmax);
        let clamp = |v: i64| v.clamp(1, u32::MAX as i64) as u32;
        let acc = clamp(sc.acc_to_inc(self.od_u32(0x6083, 0) as i64));
        let dec = clamp(sc.acc_to_inc(self.od_u32(0x6084, 0) as i64));
        let _ = self.axis.run_velocity(v as i32, acc, dec);
    }

    fn start_homing(&mut self) {
        let code = self.dev.od().get_i8(a(0x6098, 0)).unwrap_or(18);
        let Ok(method) = Method::from_code(code) else {
            self.homing_dev.finished(false);
            return;
        };
        let plan = method.plan();
        let sc = self.scaling();
        let speed = |s: u8| {
            let v = self.dev.od().get_i32(a(0x6099, s)).unwrap_or(60) as i64;
            sc.vel_to_inc(v).clamp(1, u32::MAX as i64) as u32
        };
        let (search, crawl) = (speed(1), speed(2));
        let acc = sc
            .acc_to_inc(self.od_u32(0x6083, 0) as i64)
            .clamp(1, u32::MAX as i64) as u32;
        let current_position = matches!(
            plan.signal,
            crate::cia402::homing::HomeSignal::CurrentPosition
        );
        // p_disHome: from the switching edge on into the travel, away from the switch.
        let offset = if current_position {
            0
        } else {
            sc.pos_to_inc(self.od_u32(0x20F4, 0) as i64) * plan.leave.sign() as i64
        };
        let home_position = if current_position {
            sc.pos_to_inc(self.od_i32(0x20F6, 0) as i64)
        } else {
            0
        };
        let params = HomingParams {
            search_velocity: search,
            crawl_velocity: crawl,
            travel_velocity: search,
            acceleration: acc,
            offset,
            travel_to_offset: offset != 0,
            home_position,
            stop_current_ma: self.axis.config().current_limit_ma,
            stop_time: Duration::from_millis(20),
            max_search: None,
        };
        let mut h = Homing::new(HomingMethod::from_plan(plan), params);
        self.state_home = 0;
        match h.update(&mut self.axis) {
            HomingState::Running => self.homing = Some(h),
            s => self.homing_finished(s),
        }
    }

    fn homing_finished(&mut self, s: HomingState) {
        let ok = matches!(s, HomingState::Done { .. });
        self.homing_dev.finished(ok);
        self.homing = None;
        self.state_home = if ok { X_END } else { X_END | X_ERR };
        if ok {
            self.referenced = true;
            let p = self.actual_usr();
            self.pp.reset(p);
        }
    }

    /// Velocity and ramps of a SIG PTP move: R_PDO4 (`fast`) carries v_tar16 and ramp; an SDO
    /// start uses v_tarPTP (or v_target0 if never set) and acc/dec.
    fn ptp_profile(&self, fast: bool) -> (i64, i64, i64) {
        if fast {
            let r = self.od_u16(0x20E9, 0).max(60) as i64;
            (self.od_u16(0x20E8, 0) as i64, r, r)
        } else {
            let v = match self.od_i32(0x2094, 0) {
                0 => self.od_u32(0x205C, 0) as i64,
                v => v as i64,
            };
            (
                v,
                self.od_u32(0x205E, 0) as i64,
                self.od_u32(0x205F, 0) as i64,
            )
        }
    }

    fn ptp_move(&mut self, target_inc: i64, v: i64, acc: i64, dec: i64) {
        let sc = self.scaling();
        let clamp = |v: i64| v.clamp(1, u32::MAX as i64) as u32;
        let p = axis::Profile {
            velocity: clamp(sc.vel_to_inc(v.abs())),
            acceleration: clamp(sc.acc_to_inc(acc)),
            deceleration: clamp(sc.acc_to_inc(dec)),
        };
        self.ptp_window.reset();
        if self.axis.move_to(target_inc, p).is_ok() {
            self.ptp = Some(target_inc);
            self.state_ptp = 0;
        } else {
            self.state_ptp = X_END | X_ERR;
        }
    }

    /// p_absPTP / p_relPTP written (R_PDO4 or SDO): a SIG PTP move (§4.1).
    fn sig_ptp(&mut self, relative: bool, fast: bool) {
        let active = self.fsa.state() == State::OperationEnabled
            && self.modes.active() == OperationMode::TlcSigMode
            && !self.faults.iter().any(|&f| self.class(f) >= 2);
        if !active {
            // A PDO start outside SIG mode is not executed (the SDO path was refused already).
            self.state_ptp |= X_ERR;
            return;
        }
        let sc = self.scaling();
        let (index, base) = if relative {
            let base = self.ptp.unwrap_or(self.axis.status().setpoint);
            (0x2092, base)
        } else {
            (0x2090, 0)
        };
        let target_usr = sc.inc_to_pos(base) * relative as i64 + self.od_i32(index, 0) as i64;
        if !self.limits_allow(target_usr) {
            self.invalid_position();
            self.state_ptp = X_END | X_ERR;
            return;
        }
        let (v, acc, dec) = self.ptp_profile(fast);
        self.ptp_move(sc.pos_to_inc(target_usr), v, acc, dec);
    }

    /// driveCtrl 2040h: one-shot bits, cleared after the write (§3.4).
    fn drive_ctrl(&mut self) {
        let v = self.od_u16(0x2040, 0);
        let _ = self.dev.od_mut().set_u16(a(0x2040, 0), 0);
        let last = self.fsa.controlword().0 & !Controlword::COMMAND_MASK;
        let cw = |bits: u16| Controlword(last | bits);
        if v & 8 != 0 {
            self.device_control(cw(0x0000));
            self.device_control(cw(0x0080));
        }
        if v & 1 != 0 {
            self.device_control(cw(0x0000));
        }
        if v & 2 != 0 {
            self.device_control(cw(0x0006));
            self.device_control(cw(0x000F));
        }
        if v & 4 != 0 {
            self.device_control(cw(0x0002));
        }
    }

    /// startList 20B4h (§4.3): 0 stops, 1/2 starts that list at bgnList.
    fn start_list(&mut self) {
        self.list = None;
        let which = self.od_u16(0x20B4, 0);
        let (base, cnt, bgn, end, act) = match which {
            1 => (0x2200, 0x20B7, 0x20B8, 0x20B9, 0x20BA),
            2 => (0x2300, 0x20BD, 0x20BE, 0x20BF, 0x20C0),
            _ => {
                self.state_list = 0;
                return;
            }
        };
        let (cnt, bgn, end) = (
            self.od_u16(cnt, 0),
            self.od_u16(bgn, 0),
            self.od_u16(end, 0),
        );
        let _ = self.dev.od_mut().set_i16(a(act, 0), -1);
        if bgn > end || end >= cnt {
            self.state_list = X_ERR;
            return;
        }
        // [ASSUMPTION] the list type is taken from the first entry of the Type array.
        let kind = self.od_u16(base, 1);
        self.list = Some(ListRun {
            base,
            next: bgn,
            end,
            kind,
        });
        self.state_list = 1 << (which - 1);
    }

    /// One tick of the running list: fire every entry the axis crossed since the last tick.
    fn list_tick(&mut self, prev: i64, now_pos: i64) {
        let Some(mut l) = self.list else { return };
        if prev == now_pos {
            return; // only during motion
        }
        let sc = self.scaling();
        while l.next <= l.end {
            let sub = l.next as u8 + 1;
            let p = sc.pos_to_inc(self.od_i32(l.base + 1, sub) as i64);
            let crossed = (prev < p && now_pos >= p) || (prev > p && now_pos <= p);
            if !crossed {
                break;
            }
            if l.kind == 2 {
                self.list_speed(self.od_i32(l.base + 3, sub) as i64);
            } else {
                self.trigger = self.od_u16(l.base + 2, sub) != 0;
            }
            let act = if l.base == 0x2200 { 0x20BA } else { 0x20C0 };
            let _ = self.dev.od_mut().set_i16(a(act, 0), l.next as i16);
            l.next += 1;
        }
        if l.next > l.end {
            self.list = None;
            self.state_list = 1 << 14; // list_quit
        } else {
            self.list = Some(l);
        }
    }

    /// A position/speed list entry: the running move continues at `v` usr.
    fn list_speed(&mut self, v: i64) {
        match self.modes.active() {
            OperationMode::ProfilePosition => {
                if let Some(mut m) = self.pp.active() {
                    m.velocity = v.clamp(1, u32::MAX as i64) as u32;
                    self.run_move(m);
                }
            }
            OperationMode::ProfileVelocity => {
                let _ = self.dev.od_mut().set_i32(
                    a(0x60FF, 0),
                    v.clamp(i32::MIN as i64, i32::MAX as i64) as i32,
                );
                self.pv_start();
            }
            _ => {}
        }
    }

    /// Objects written by SDO or an RPDO: act on them (all of one RPDO at once).
    fn written(&mut self, addrs: &[Address]) {
        // One pass over the list: each object the drive reacts to sets its bit.
        let w = addrs.iter().fold(0, |m, x| m | Watched::of(x.index, x.sub));
        let has = |bit: u32| w & bit != 0;
        if has(Watched::SCALING) {
            self.scaling = self.compute_scaling();
        }
        if has(Watched::SETTINGS) {
            self.settings = self.read_settings();
        }
        if has(Watched::MODE) {
            let code = self.dev.od().get_i8(a(0x6060, 0)).unwrap_or(1);
            let _ = self.modes.request(code, &self.profile);
            self.update_mode();
        }
        let od = self.dev.od_mut();
        // The software limits are one setting under two names (607Dh and 2052h/2053h).
        for (bx, x, by, y) in [
            (
                Watched::LIMIT_MIN,
                a(0x607D, 1),
                Watched::LIMIT_MIN_TLC,
                a(0x2053, 0),
            ),
            (
                Watched::LIMIT_MAX,
                a(0x607D, 2),
                Watched::LIMIT_MAX_TLC,
                a(0x2052, 0),
            ),
        ] {
            if has(bx) {
                let v = od.get_i32(x).unwrap_or(0);
                let _ = od.set_i32(y, v);
            } else if has(by) {
                let v = od.get_i32(y).unwrap_or(0);
                let _ = od.set_i32(x, v);
            }
        }
        if has(Watched::DIF_PEAK) {
            self.dif_peak = 0;
        }
        if has(Watched::DRIVE_CTRL) {
            self.drive_ctrl();
        }
        if has(Watched::CONTROLWORD) {
            self.controlword();
        }
        if has(Watched::PV_TARGET) {
            self.pv_start();
        }
        if has(Watched::PTP) {
            self.sig_ptp(false, has(Watched::PTP_ADD));
        }
        if has(Watched::PTP_REL) {
            self.sig_ptp(true, false);
        }
        if has(Watched::LIST_START) {
            self.start_list();
        }
        // 2008h/2009h (EEPROM store/restore): no EEPROM image is simulated, the write is
        // accepted and has no effect.
    }

    fn update_mode(&mut self) {
        let st = self.axis.status();
        // At rest with nothing to do counts as stopped at once (no settling time needed).
        let still =
            st.standstill || !self.axis.is_enabled() || (st.generator_done && st.velocity == 0);
        if self.modes.update(still).is_some() {
            self.drop_commands();
            self.homing_dev.reset();
        }
    }

    fn reset_application(&mut self) {
        self.axis.disable();
        self.fsa = DeviceStateMachine::new(self.profile);
        self.fsa.set_self_test_done(true);
        self.modes = ModeSelector::new(OperationMode::ProfilePosition);
        self.homing_dev = HomingDevice::new();
        self.drop_commands();
        self.faults.clear();
        self.axis.clear_faults();
        self.list = None;
        self.state_list = 0;
        self.trigger = false;
        self.state_ptp = X_END;
        self.state_home = 0;
        self.last_error = 0;
        *self.dev.hooks_mut() = TlcHooks::new(self.profile);
    }

    fn drain(&mut self) {
        // Frames that change nothing (other nodes' traffic, a SYNC) need no new publish: the
        // dictionary already holds the values of the last tick.
        let mut changed = false;
        while let Some(e) = self.dev.poll_event() {
            changed |= !matches!(e, DeviceEvent::Sync { .. });
            match e {
                DeviceEvent::SdoWritten { addr } => self.written(&[addr]),
                DeviceEvent::RpdoApplied { pdo } => {
                    let mut addrs = heapless::Vec::<Address, 8>::new();
                    for e in self.dev.rpdo_mapping(pdo).map_or(&[][..], |m| m.entries()) {
                        let _ = addrs.push(e.addr);
                    }
                    self.written(&addrs);
                }
                DeviceEvent::Reset(kind) => {
                    // The dictionary holds its defaults again: publish everything anew.
                    self.published = [None; PUBLISHED];
                    self.scaling = self.compute_scaling();
                    self.settings = self.read_settings();
                    self.last_sync = None;
                    self.late = [None; 4];
                    if kind == ResetKind::Node {
                        self.reset_application();
                    } else {
                        let h = self.dev.hooks_mut();
                        (h.guard_ms, h.life_factor, h.heartbeat_ms) = (0, 0, 0);
                    }
                }
                DeviceEvent::LifeGuardingLost => self.raise_fault(TlcFault::LifeGuarding),
                _ => {}
            }
        }
        if core::mem::take(&mut self.dev.hooks_mut().abort_move)
            && self.modes.active() == OperationMode::ProfilePosition
            && self.pp.active().is_some()
        {
            let p = self.actual_usr();
            self.pp.reset(p);
            self.axis.hold();
            changed = true;
        }
        if changed {
            self.publish();
        }
    }

    // ---- time ----------------------------------------------------------------------------

    /// Steps the axis up to `now`, one tick at a time.
    fn catch_up(&mut self, now: Instant) {
        let mut ticked = false;
        while self.next_tick <= now {
            self.axis.step();
            self.tick(self.next_tick);
            self.next_tick += self.cfg.tick;
            ticked = true;
        }
        if ticked {
            self.publish();
        }
    }

    fn tick(&mut self, now: Instant) {
        let st = *self.axis.status();
        // Monitoring (§6): what the axis flags, and the following error against p_maxDiff.
        for (flag, f) in [
            (Faults::SUPPLY_VOLTAGE, TlcFault::Undervoltage),
            (Faults::OVER_TEMPERATURE, TlcFault::OverTemperature),
            (Faults::LIMIT_POSITIVE, TlcFault::LimitPositive),
            (Faults::LIMIT_NEGATIVE, TlcFault::LimitNegative),
        ] {
            if st.faults.contains(flag) {
                self.raise_fault(f);
            }
        }
        let dif = st.following_error.unsigned_abs().min(u32::MAX as u64) as u32;
        self.dif_peak = self.dif_peak.max(dif);
        if self.axis.is_enabled() && self.homing.is_none() && dif > self.settings.max_diff {
            self.raise_fault(TlcFault::FollowingError);
        }
        // Fault reaction: once stopped (or unpowered), the power stage goes off: Tr.14.
        if self.fsa.state() == State::FaultReactionActive
            && (st.standstill || !self.axis.is_enabled())
        {
            self.axis.disable();
            let persistent = self.faults.iter().any(|&f| self.cause_present(f));
            self.fsa.set_fault(persistent);
            self.fsa.set_fault_reaction_done();
        }
        self.update_mode();
        if let Some(mut h) = self.homing.take() {
            match h.update(&mut self.axis) {
                HomingState::Running => self.homing = Some(h),
                s => self.homing_finished(s),
            }
        }
        let Settings {
            p_win, win_time, ..
        } = self.settings;
        if let Some(m) = self.pp.active()
            && !self.halted
            && st.generator_done
        {
            let target = self.scaling().pos_to_inc(m.target as i64);
            let inside = st.position.abs_diff(target) <= p_win;
            if self.window.update(inside, now) >= win_time {
                self.window.reset();
                if let Some(next) = self.pp.move_finished() {
                    self.pp_start(next);
                }
            }
        }
        self.pp.set_standstill(st.standstill);
        if let Some(t) = self.ptp
            && st.generator_done
        {
            let inside = st.position.abs_diff(t) <= p_win;
            if self.ptp_window.update(inside, now) >= win_time {
                self.ptp = None;
                self.state_ptp = X_END | X_ADD_INFO;
            }
        }
        if self.modes.active() == OperationMode::ProfileVelocity {
            let target = if self.fsa.state() == State::OperationEnabled && !self.halted {
                self.scaling().vel_to_inc(self.od_i32(0x60FF, 0) as i64)
            } else {
                0
            };
            let clamp = |v: i64| v.clamp(i32::MIN as i64, i32::MAX as i64) as i32;
            self.pv_bits = self.pv.update(clamp(target), clamp(st.velocity), now).0;
        }
        self.list_tick(self.prev_position, st.position);
        self.prev_position = st.position;
    }

    /// Writes the actual values and status objects into the dictionary (what TPDOs and SDO
    /// uploads read).
    fn publish(&mut self) {
        let st = *self.axis.status();
        let sc = self.scaling();
        let i32c = |v: i64| v.clamp(i32::MIN as i64, i32::MAX as i64) as i32;
        let limit_hit = st.switches.contains(Switches::LIMIT_POSITIVE)
            || st.switches.contains(Switches::LIMIT_NEGATIVE);
        let class1 = self.faults.iter().any(|&f| self.class(f) == 1);
        let fe = self.faults.contains(&TlcFault::FollowingError);
        let mode_bits = match self.modes.active() {
            OperationMode::ProfilePosition => {
                self.pp.status_bits().0 | if fe { Statusword::FOLLOWING_ERROR } else { 0 }
            }
            OperationMode::ProfileVelocity => self.pv_bits,
            OperationMode::Homing => self.homing_dev.status().bits().0,
            OperationMode::TlcSigMode if self.state_ptp & X_END != 0 => Statusword::TARGET_REACHED,
            _ => 0,
        };
        let dynamic = mode_bits
            | if class1 { Statusword::WARNING } else { 0 }
            | if limit_hit {
                Statusword::INTERNAL_LIMIT_ACTIVE
            } else {
                0
            };
        let state = self.fsa.state();
        let sw = self.profile.statusword(state, Statusword(dynamic)).0;
        let limits = (st.switches.contains(Switches::LIMIT_POSITIVE) as u16)
            | (st.switches.contains(Switches::LIMIT_NEGATIVE) as u16) << 1
            | (st.switches.contains(Switches::REFERENCE) as u16) << 2;
        let internal = self.faults.iter().any(|f| f.internal());
        let external = self.faults.iter().any(|f| !f.internal());
        let sig = match self.modes.active() {
            OperationMode::TlcSigMode => self.state_ptp,
            OperationMode::Homing => self.state_home,
            _ => 0,
        };
        let drive_stat = state.drive_stat_code()
            | (internal as u16) << 5
            | (external as u16) << 6
            | (class1 as u16) << 7
            | sig & (X_ADD_INFO | X_END | X_ERR);
        let inputs = (st.switches.contains(Switches::LIMIT_NEGATIVE) as u32)
            | (st.switches.contains(Switches::LIMIT_POSITIVE) as u32) << 1
            | (st.switches.contains(Switches::REFERENCE) as u32) << 2;
        let flt_sig = self.faults.iter().fold(0, |m, f| m | f.flt_sig_bit());
        let mode = self.modes.active().code();
        let velocity = sc.inc_to_vel(st.velocity);
        let position = sc.inc_to_pos(st.position);
        let remaind = st.position - sc.pos_to_inc(position);
        let int_sig = if self.axis.is_enabled() { 0 } else { 1 << 15 };
        let outputs = (self.od_u32(0x60FE, 1) & !TRIGGER) | if self.trigger { TRIGGER } else { 0 };
        let (state_ptp, state_home, state_list) = (
            self.state_ptp | limits,
            self.state_home | limits,
            self.state_list,
        );
        let error_code = self.last_error;
        let peak = self.dif_peak;
        let h = self.dev.hooks_mut();
        h.drive = state;
        h.mode = self.modes.active();
        h.fault_number = self.faults.first().map(|f| f.error_number());
        // In the order of PUBLISHED_OBJECTS (plain values: a list of (object, value) pairs
        // is built in memory on every call, 1 % of a simulated cycle).
        let values: [i64; PUBLISHED] = [
            sw as i64,                                           // 6041h
            mode as i64,                                         // 6061h
            i32c(st.position) as i64,                            // 6063h
            i32c(position) as i64,                               // 6064h
            i32c(position) as i64,                               // 2089h
            i32c(st.velocity) as i64,                            // 6069h
            i32c(velocity) as i64,                               // 606Ch
            i32c(velocity) as i64,                               // 208Ah
            velocity.unsigned_abs().min(u16::MAX as u64) as i64, // 20EBh
            i32c(sc.inc_to_pos(st.following_error)) as i64,      // 60F4h
            i32c(st.following_error) as i64,                     // 2073h
            peak as i64,                                         // 2013h
            i32c(remaind) as i64,                                // 208Ch
            inputs as i64,                                       // 60FDh
            limits as i64,                                       // 2048h
            outputs as i64,                                      // 60FEh/01
            drive_stat as i64,                                   // 2041h
            state_ptp as i64,                                    // 2091h
            state_home as i64,                                   // 20F1h
            state_list as i64,                                   // 20B5h
            int_sig as i64,                                      // 2062h
            flt_sig as i64,                                      // 2049h
            error_code as i64,                                   // 603Fh
        ];
        // Most of these change rarely: write only what differs from the last publish (a tick
        // would otherwise cost two dozen dictionary writes per drive).
        let od = self.dev.od_mut();
        for ((&v, last), &at) in values
            .iter()
            .zip(self.published.iter_mut())
            .zip(&self.publish_at)
        {
            if *last != Some(v) {
                let _ = od.set_int(at, v);
                *last = Some(v);
            }
        }
    }

    // ---- the 1007h window ----------------------------------------------------------------

    /// Whether `frame` is a SYNC on the COB-ID 1005h names.
    fn is_sync(&self, frame: &Frame) -> bool {
        !frame.is_remote() && frame.cob_id() == Some(self.settings.sync_cob)
    }

    /// The synchronous RPDO `frame` is for, if it arrives after the 1007h window.
    fn late_rpdo(&self, frame: &Frame, now: Instant) -> Option<usize> {
        if self.dev.state() != NmtState::Operational || frame.is_remote() {
            return None;
        }
        let window = self.settings.sync_window_us;
        let last = self.last_sync?;
        if window == 0
            || now.saturating_duration_since(last) <= Duration::from_micros(window as u64)
        {
            return None;
        }
        let id = frame.cob_id()?;
        (0..4).find(|&k| {
            let cob = self.od_u32(0x1400 + k as u16, 1);
            let t = self.dev.od().get_u8(a(0x1400 + k as u16, 2)).unwrap_or(255);
            cob & 0x8000_0000 == 0 && (cob & 0x7FF) as u16 == id && t <= 240
        })
    }
}

impl Endpoint for Tlc5xx {
    /// The device's identifiers only: another node's frame does not make the drive catch up.
    /// The SYNC also when the device's own SYNC consumer is not configured: the deferral of
    /// late PDOs counts from it regardless.
    fn accepts(&self, frame: &Frame) -> bool {
        self.dev.accepts(frame) || self.is_sync(frame)
    }

    fn handle_frame(&mut self, frame: &Frame, now: Instant) {
        self.catch_up(now);
        // "If a synchronous PDO arrives later [than the window], it cannot be evaluated until
        // the next but one SYNC" (1007h): it is handed to the device after the next SYNC.
        if let Some(k) = self.late_rpdo(frame, now)
            && let Some(slot) = self.late.get_mut(k)
        {
            *slot = Some(*frame);
            return;
        }
        let sync = self.is_sync(frame);
        self.dev.handle_frame(frame, now);
        self.drain();
        if sync && self.dev.state() == NmtState::Operational {
            self.last_sync = Some(now);
            for k in 0..4 {
                if let Some(f) = self.late[k].take() {
                    self.dev.handle_frame(&f, now);
                }
            }
            self.drain();
        }
    }

    fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        self.dev.poll_transmit(now)
    }

    fn poll_timeout(&self) -> Option<Instant> {
        Some(match self.dev.poll_timeout() {
            Some(t) => t.min(self.next_tick),
            None => self.next_tick,
        })
    }

    fn handle_timeout(&mut self, now: Instant) {
        self.catch_up(now);
        self.dev.handle_timeout(now);
        self.drain();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounding_division_is_the_same_in_64_bits() {
        // The 64-bit shortcut of `div_round` against the 128-bit formula it stands for.
        let wide = |n: i128, d: i128| {
            let q = (2 * n + d.signum() * n.signum() * d.abs()) / (2 * d);
            q.clamp(i64::MIN as i128, i64::MAX as i128) as i64
        };
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        let mut cases: Vec<(i128, i128)> = vec![
            (0, 1),
            (1, 2),
            (-1, 2),
            (3, -2),
            (i64::MAX as i128, 1),
            (i64::MIN as i128 / 2, -1),
            (i64::MIN as i128 / 2, 1),
            (i64::MAX as i128 * 60, 7),
        ];
        for _ in 0..5000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let n = ((x as i64) >> (x % 64)) as i128 * ((x >> 40) % 70_000) as i128;
            let d =
                (((x >> 8) as i64) >> (x % 61)).max(1) as i128 * if x & 1 == 0 { 1 } else { -1 };
            cases.push((n, d));
        }
        for (n, d) in cases {
            assert_eq!(div_round(n, d), wide(n, d), "{n} / {d}");
        }
    }

    #[test]
    fn scaling_rounds_to_the_nearest_increment() {
        let s = Scaling {
            increments_per_rev: 16384,
            position: (1, 16384),
            velocity: (1, 1),
            acceleration: (1, 1),
        };
        assert_eq!(s.pos_to_inc(1500), 1500);
        assert_eq!(s.vel_to_inc(133), 36318); // 133 rpm = 36317.9 inc/s
        assert_eq!(s.inc_to_vel(36318), 133);
        assert_eq!(s.inc_to_vel(-36318), -133);
        let coarse = Scaling {
            position: (1, 1000),
            ..s
        };
        assert_eq!(coarse.pos_to_inc(1), 16); // 16.384 -> 16
        assert_eq!(coarse.inc_to_pos(-17), -1); // -1.04 -> -1
    }

    #[test]
    fn hooks_refuse_what_the_manual_refuses() {
        let mut h = TlcHooks::new(TLC5XX);
        let def = |i, s| {
            EntryDef::new(
                a(i, s),
                "x",
                crate::canopen::od::DataType::Unsigned32,
                crate::canopen::od::AccessType::Rw,
            )
        };
        let pre = NmtState::PreOperational;
        assert_eq!(
            h.check_write(&def(0x6081, 0), &3001u32.to_le_bytes(), pre),
            Err(AbortCode::ValueTooHigh)
        );
        assert!(h.abort_move);
        assert_eq!(
            h.check_write(&def(0x6060, 0), &[2], pre),
            Err(AbortCode::InvalidValue)
        );
        assert_eq!(h.check_write(&def(0x6060, 0), &[0xFF], pre), Ok(()));
        assert_eq!(
            h.check_write(&def(0x6098, 0), &[33], pre),
            Err(AbortCode::InvalidValue)
        );
        assert_eq!(
            h.check_write(
                &def(0x1401, 1),
                &0x301u32.to_le_bytes(),
                NmtState::Operational
            ),
            Err(AbortCode::DeviceState)
        );
        assert_eq!(h.check_write(&def(0x1017, 0), &[100, 0], pre), Ok(()));
        assert_eq!(h.check_write(&def(0x100C, 0), &[100, 0], pre), Ok(()));
        assert_eq!(
            h.check_write(&def(0x100D, 0), &[3], pre),
            Err(AbortCode::ParamIncompatible)
        );
        assert_eq!(
            h.check_write(&def(0x2090, 0), &[0; 4], pre),
            Err(AbortCode::DeviceState)
        );
        h.fault_number = Some(0x8611);
        assert_eq!(
            h.check_write(&def(0x2090, 0), &[0; 4], pre),
            Err(AbortCode::Other(0x0800_8611))
        );
    }
}
