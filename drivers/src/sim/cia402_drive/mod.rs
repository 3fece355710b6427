//! A simulated generic CiA 402 drive (`plcopen-and-cia402-csp.md` §6–§10): the CiA 301 device
//! of [`crate::canopen::device`] over the built-in dictionary ([`od`]) or one loaded from an EDS,
//! the CiA 402 state machine and mode handshakes of [`crate::cia402`] with the profile
//! [`crate::cia402::GENERIC`], and the physical axis of [`crate::sim::axis`] stepped in virtual
//! time, one control tick per [`Cia402Config::tick`].
//!
//! Modes: profile position (set-point handshake, change set immediately), profile velocity,
//! homing (the methods of `GENERIC`: 17, 18, 23, 27 with the switches of
//! [`Cia402Config::environment`], 35 and 37), and the cyclic synchronous modes:
//! - Set-points (607Ah + 60B0h, 60FFh + 60B1h, 6071h + 60B2h) are taken at SYNC only, whatever
//!   the RPDO's transmission type; a synchronous RPDO arriving later than the 1007h window after
//!   the SYNC is dropped (CiA 301).
//! - CSP: the drive interpolates linearly from the set-point of SYNC k−1 to that of SYNC k over
//!   one 60C2h period, limited by 607Fh and the drive's acceleration limit; the axis follows
//!   that reference through its position loop. Following error e = p_cmd(k−1) − p_act (60F4h);
//!   statusword bit 13 and Fault (EMCY 8611h) once |e| > 6065h for longer than 6066h ms.
//! - CSV: the velocity reference ramps to 60FFh + 60B1h (clamped by 607Fh) with the drive's
//!   acceleration limit. CST: torque clamp(6071h + 60B2h, ±6072h) ‰ accelerates the load, at
//!   [`Cia402Config::rated_acceleration`] per 1000 ‰, up to 607Fh.
//! - Software limits 607Dh: CSP and PP targets are clipped into them; CSV and CST brake with the
//!   drive's acceleration limit to a stop at them (bit 11 "internal limit active" while cut).
//! - Statusword bit 12 "drive follows the command value" is 1 only while the drive tracks the
//!   set-points: in Operation enabled, not halted, no mode change pending.
//! - Missing SYNC: in a cyclic mode in Operation enabled, once a SYNC has been seen, the last
//!   set-point is held; after [`Cia402Config::sync_loss_periods`] periods without SYNC the drive
//!   faults with EMCY 8700h.
//! - Halt (bit 8): 605Dh ramp, bit 12 = 0, bit 10 = 1 at rest. Quick stop: 605Ah ramp, then
//!   Switch on disabled (0..4) or stay in Quick stop active (5..8). Disable operation and
//!   shutdown follow 605Ch / 605Bh, a fault's reaction 605Eh.
//!
//! Units: positions in increments, velocities in inc/s, accelerations in inc/s² (no factor
//! group), torque in per mille of the rated torque. 6060h values whose 6502h bit is clear are
//! refused with SDO abort 0609 0030h.
//!
//! ```
//! use drivers::sim::cia402_drive::{Cia402Drive, Cia402Config};
//! use drivers::canopen::{endpoint::Endpoint, NodeId};
//! use drivers::time::Instant;
//! let mut drive = Cia402Drive::new(Cia402Config::new(NodeId::new(1).unwrap()), Instant::ZERO).unwrap();
//! let boot = drive.poll_transmit(Instant::ZERO).unwrap();
//! assert_eq!((boot.cob_id(), boot.data()), (Some(0x701), &[0u8][..]));
//! assert_eq!(drive.statusword() & 0x004F, 0x0040); // Switch on disabled
//! ```

pub mod od;

use core::time::Duration;

use crate::can::Frame;
use crate::canopen::device::{Device, DeviceEvent, DeviceHooks};
use crate::canopen::endpoint::Endpoint;
use crate::canopen::nmt::{BootUpStyle, NmtState, ResetKind};
use crate::canopen::od::{EntryDef, OdError, le_u64};
use crate::canopen::{AbortCode, Address, NodeId};
use crate::cia402::controlword::Controlword;
use crate::cia402::homing::{HomingCommand, HomingDevice, HomingMethod as Method};
use crate::cia402::modes::{
    ModeSelector, Move, OperationMode, PpAction, PpDevice, PpObjects, PvMonitor, PvSettings,
};
use crate::cia402::state::{DeviceStateMachine, QuickStopOption, State};
use crate::cia402::statusword::Statusword;
use crate::cia402::{DeviceProfile, GENERIC};
use crate::sim::axis::{self, Axis, Environment, Faults, Mechanics, Switches, WindowTimer};
use crate::sim::homing::{Homing, HomingMethod, HomingParams, HomingState};
use crate::sim::profile::{FRAC_BITS, brake_velocity};
use crate::time::Instant;
use od::{GenericOd, OD_BYTES, OD_ENTRIES};

/// How many dictionary values [`Cia402Drive`] publishes each tick.
const PUBLISHED: usize = 7;

/// The CiA 301 device under the simulator.
pub type GenericDevice = Device<'static, OD_ENTRIES, OD_BYTES, 64, GenericHooks>;

const fn a(index: u16, sub: u8) -> Address {
    Address::new(index, sub)
}

/// Simulator settings: the drive's physics and what CiA 402 leaves to the manufacturer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cia402Config {
    /// Node-ID.
    pub node: NodeId,
    /// Control tick: the axis is stepped, the reference interpolated and the statusword
    /// updated this often.
    pub tick: Duration,
    /// Encoder increments per motor revolution (where the index pulses are).
    pub encoder_increments: u32,
    /// The motor's speed limit, inc/s (607Fh cannot exceed it).
    pub max_velocity: u32,
    /// The drive's acceleration limit, inc/s²: the cyclic modes' reference never accelerates
    /// faster, and no profile ramp either.
    pub max_acceleration: u32,
    /// Acceleration of the load at rated torque (1000 ‰), inc/s²: the inertia of CST, and the
    /// scale of the torque actual value 6077h in the other modes.
    pub rated_acceleration: u32,
    /// Position loop time constant: the axis lags its reference by v·tau.
    pub position_time_constant: Duration,
    /// Limit and reference switches, end stops and index phase, raw increments.
    pub environment: Environment,
    /// Raw position at power-on.
    pub start_position: i64,
    /// SYNC periods without a SYNC, in a cyclic mode, before the drive faults (8700h).
    pub sync_loss_periods: u32,
    /// PV "target reached" window (bit 10), inc/s; "speed = 0" (bit 12) uses a tenth of it.
    pub pv_window: u32,
}

impl Cia402Config {
    /// The defaults for `node`: 250 µs tick, 10 000 inc/rev, 1 000 000 inc/s (6000 rpm),
    /// 50 000 000 inc/s² drive limit, 10 000 000 inc/s² at rated torque, 2 ms position loop, no
    /// switches, no end stops, fault after 3 missing SYNCs.
    pub const fn new(node: NodeId) -> Self {
        Cia402Config {
            node,
            tick: Duration::from_micros(250),
            encoder_increments: 10_000,
            max_velocity: od::MAX_VELOCITY,
            max_acceleration: 50_000_000,
            rated_acceleration: 10_000_000,
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
            sync_loss_periods: 3,
            pv_window: 1000,
        }
    }
}

/// A fault the simulator raises.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Cia402Fault {
    /// |following error| above 6065h for longer than 6066h. EMCY 8611h.
    FollowingError,
    /// No SYNC for [`Cia402Config::sync_loss_periods`] periods in a cyclic mode. EMCY 8700h.
    SyncLost,
    /// A limit switch reached moving towards it. EMCY 8612h (reference limit).
    LimitSwitch,
    /// Life guarding: the master stopped polling. EMCY 8130h.
    LifeGuarding,
}

impl Cia402Fault {
    /// The EMCY error code (also 603Fh).
    pub const fn emcy_code(self) -> u16 {
        match self {
            Cia402Fault::FollowingError => 0x8611,
            Cia402Fault::SyncLost => 0x8700,
            Cia402Fault::LimitSwitch => 0x8612,
            Cia402Fault::LifeGuarding => 0x8130,
        }
    }
}

/// Why an EDS cannot describe a drive this simulator runs.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum EdsRefusal {
    /// The file's entries do not fit the simulator's dictionary (or repeat one).
    #[error("the EDS does not load: {0}")]
    Load(OdError),
    /// 1000h is not a CiA 402 device type.
    #[error("1000h device type {0:08X}h is not a CiA 402 drive (low 16 bits 0192h)")]
    NotCia402(u32),
    /// An object the simulator needs is missing.
    #[error("the EDS has no {index:04X}h sub {sub} ({name}), which {needed_by} needs")]
    Missing {
        /// Index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// What it is.
        name: &'static str,
        /// Who needs it: the drive itself or a mode its 6502h offers.
        needed_by: &'static str,
    },
    /// 6502h offers none of the modes the simulator runs.
    #[error("6502h = {0:08X}h offers none of PP, PV, HM, CSP, CSV, CST")]
    NoMode(u32),
}

/// What every drive needs: (index, sub, name).
const NEEDED: &[Needed] = &[
    (0x1000, 0, "device type"),
    (0x1001, 0, "error register"),
    (0x1018, 1, "vendor-ID"),
    (0x6040, 0, "controlword"),
    (0x6041, 0, "statusword"),
    (0x6060, 0, "modes of operation"),
    (0x6061, 0, "modes of operation display"),
    (0x6064, 0, "position actual value"),
    (0x6502, 0, "supported drive modes"),
];

/// An object the simulator needs: index, sub-index, name.
type Needed = (u16, u8, &'static str);

/// What each mode needs on top: (mode, name, objects).
const MODE_NEEDS: &[(OperationMode, &str, &[Needed])] = &[
    (
        OperationMode::ProfilePosition,
        "profile position",
        &[
            (0x607A, 0, "target position"),
            (0x6081, 0, "profile velocity"),
            (0x6083, 0, "profile acceleration"),
            (0x6084, 0, "profile deceleration"),
        ],
    ),
    (
        OperationMode::ProfileVelocity,
        "profile velocity",
        &[
            (0x60FF, 0, "target velocity"),
            (0x6083, 0, "profile acceleration"),
            (0x6084, 0, "profile deceleration"),
        ],
    ),
    (
        OperationMode::Homing,
        "homing",
        &[
            (0x6098, 0, "homing method"),
            (0x6099, 1, "speed during search for switch"),
            (0x6099, 2, "speed during search for zero"),
        ],
    ),
    (
        OperationMode::CyclicSyncPosition,
        "cyclic synchronous position",
        &[(0x607A, 0, "target position")],
    ),
    (
        OperationMode::CyclicSyncVelocity,
        "cyclic synchronous velocity",
        &[(0x60FF, 0, "target velocity")],
    ),
    (
        OperationMode::CyclicSyncTorque,
        "cyclic synchronous torque",
        &[(0x6071, 0, "target torque")],
    ),
];

/// Checks that `od` has what the simulator needs for the modes its 6502h offers; returns the
/// 6502h modes the simulator runs.
pub fn check_dictionary(od: &GenericOd) -> Result<u32, EdsRefusal> {
    let missing = |(index, sub, name): Needed, needed_by| {
        od.entry(a(index, sub)).err().map(|_| EdsRefusal::Missing {
            index,
            sub,
            name,
            needed_by,
        })
    };
    for &n in NEEDED {
        if let Some(e) = missing(n, "the drive") {
            return Err(e);
        }
    }
    let device_type = od.get_u32(a(0x1000, 0)).unwrap_or(0);
    if device_type & 0xFFFF != 0x0192 {
        return Err(EdsRefusal::NotCia402(device_type));
    }
    let offered = od.get_u32(a(0x6502, 0)).unwrap_or(0);
    let modes = offered & GENERIC.supported_drive_modes();
    if modes == 0 {
        return Err(EdsRefusal::NoMode(offered));
    }
    for &(mode, what, objects) in MODE_NEEDS {
        if mode.supported_modes_bit().is_some_and(|b| modes & b != 0) {
            for &o in objects {
                if let Some(e) = missing(o, what) {
                    return Err(e);
                }
            }
        }
    }
    Ok(modes)
}

/// The SDO write rules beyond the dictionary's own checks: 6060h only the modes of 6502h (and
/// of this simulator), 6098h only the homing methods of `GENERIC`, a PDO's mapping only while
/// the PDO is invalid (CiA 301 §7.4.8: COB-ID bit 31 set; else 0601 0000h, as for the entries
/// while sub 00h ≠ 0).
#[derive(Debug, Clone, Copy)]
pub struct GenericHooks {
    modes: u32,
    /// RPDO 1–4, TPDO 1–4: COB-ID bit 31 clear.
    valid: [bool; 8],
}

/// The slot of [`GenericHooks::valid`] a PDO parameter index belongs to.
const fn pdo_slot(index: u16) -> Option<usize> {
    match index {
        0x1400..=0x1403 => Some((index - 0x1400) as usize),
        0x1600..=0x1603 => Some((index - 0x1600) as usize),
        0x1800..=0x1803 => Some(4 + (index - 0x1800) as usize),
        0x1A00..=0x1A03 => Some(4 + (index - 0x1A00) as usize),
        _ => None,
    }
}

impl GenericHooks {
    fn new(modes: u32, od: &GenericOd) -> Self {
        let mut valid = [false; 8];
        for (k, v) in valid.iter_mut().enumerate() {
            let comm = if k < 4 { 0x1400 } else { 0x1800 - 4 } + k as u16;
            *v = od.get_u32(a(comm, 1)).is_ok_and(|c| c & 0x8000_0000 == 0);
        }
        GenericHooks { modes, valid }
    }

    fn offers(&self, mode: OperationMode) -> bool {
        mode.supported_modes_bit()
            .is_some_and(|b| self.modes & b != 0)
    }
}

impl DeviceHooks for GenericHooks {
    fn check_write(
        &mut self,
        def: &EntryDef<'_>,
        data: &[u8],
        _state: NmtState,
    ) -> Result<(), AbortCode> {
        let v = le_u64(data);
        match (def.addr.index, def.addr.sub) {
            (0x6060, 0) => match OperationMode::from_code(v as u8 as i8) {
                Ok(m) if self.offers(m) => Ok(()),
                _ => Err(AbortCode::InvalidValue),
            },
            (0x6098, 0) => match Method::from_code(v as u8 as i8) {
                Ok(m) if GENERIC.supports_homing(m) => Ok(()),
                _ => Err(AbortCode::InvalidValue),
            },
            (0x1400..=0x1403 | 0x1800..=0x1803, 1) => {
                // Called last before the value is stored: what the PDO's state becomes.
                if let Some(k) = pdo_slot(def.addr.index) {
                    self.valid[k] = v & 0x8000_0000 == 0;
                }
                Ok(())
            }
            (0x1600..=0x1603 | 0x1A00..=0x1A03, _) => match pdo_slot(def.addr.index) {
                Some(k) if self.valid[k] => Err(AbortCode::UnsupportedAccess),
                _ => Ok(()),
            },
            _ => Ok(()),
        }
    }
}

/// The cyclic synchronous modes' reference generator, in the axis' sub-increments
/// (`2^FRAC_BITS` per increment) and control ticks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
struct Cyclic {
    /// Whether the reference drives the axis (bit 12).
    following: bool,
    /// Reference position and velocity (per tick).
    pos: i64,
    vel: i64,
    /// Position set-points of the previous and of the last SYNC, increments.
    cmd_prev: i64,
    cmd: i64,
    /// Ticks since the last SYNC, at most `period`.
    since: u32,
    /// Interpolation period, ticks.
    period: u32,
    /// Velocity set-point, inc/s; torque set-point, ‰ (clamped by 6072h).
    vel_cmd: i64,
    torque_cmd: i64,
    /// The torque the reference applies (0 once at the speed limit), ‰.
    torque: i64,
    /// A limit (607Fh, 607Dh, the acceleration limit) cut the reference this tick.
    limited: bool,
    /// The position set-point interpolated to this tick, increments (the following error's
    /// command side).
    target: i64,
}

/// The objects read every tick, as last written (they change only by SDO or RPDO writes and
/// resets): one dictionary lookup per write instead of several per tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Settings {
    /// 607Fh, within the motor's limit.
    max_velocity: u32,
    /// 6065h.
    fe_window: u32,
    /// 6066h.
    fe_timeout: Duration,
    /// 60C2h, else 1006h (`None`: neither is set).
    sync_period: Option<Duration>,
    /// 607Fh and the drive's acceleration limit in the axis' sub-increments per tick (and
    /// tick²), for the cyclic reference.
    vmax_sub: i64,
    amax_sub: i64,
    /// 607Dh in the axis' sub-increments (min, max): where CSV and CST brake to a stop.
    limits_sub: (i64, i64),
}

/// The objects [`Settings`] holds.
const SETTINGS: [u16; 6] = [0x607F, 0x6065, 0x6066, 0x60C2, 0x1006, 0x607D];

const fn is_cyclic(m: OperationMode) -> bool {
    matches!(
        m,
        OperationMode::CyclicSyncPosition
            | OperationMode::CyclicSyncVelocity
            | OperationMode::CyclicSyncTorque
    )
}

/// The simulated generic CiA 402 drive: a CANopen [`Endpoint`].
pub struct Cia402Drive {
    cfg: Cia402Config,
    profile: DeviceProfile,
    dev: GenericDevice,
    axis: Axis,
    fsa: DeviceStateMachine,
    modes: ModeSelector,
    pp: PpDevice,
    homing_dev: HomingDevice,
    homing: Option<Homing>,
    pv: PvMonitor,
    pv_bits: u16,
    halted: bool,
    /// 605Bh/605Ch = 1: the power stage goes off once the ramp has stopped the axis.
    disable_at_rest: bool,
    window: WindowTimer,
    fe_timer: WindowTimer,
    fe_over: bool,
    cs: Cyclic,
    settings: Settings,
    faults: heapless::Vec<Cia402Fault, 4>,
    last_error: u16,
    referenced: bool,
    last_sync: Option<Instant>,
    sync_interval: Option<Duration>,
    sync_armed: bool,
    late_dropped: u32,
    /// The time of the frame or timeout being handled.
    now: Instant,
    next_tick: Instant,
    published: [Option<i64>; PUBLISHED],
}

impl Cia402Drive {
    /// A drive with the built-in dictionary, powered on at `now`: Pre-operational, boot-up
    /// queued, Switch on disabled. Fails only if the dictionary does not fit (a build error).
    pub fn new(cfg: Cia402Config, now: Instant) -> Result<Self, OdError> {
        let od = od::generic_od(cfg.node)?;
        Ok(Self::with_dictionary(cfg, od, od::SUPPORTED_MODES, now))
    }

    /// A drive over the objects and defaults of `eds` (parsed for this node-ID): identity from
    /// its 1018h, modes narrowed by its 6502h. Refused, naming the object, if it lacks what the
    /// simulator needs.
    #[cfg(feature = "std")]
    pub fn from_eds(
        cfg: Cia402Config,
        eds: &'static crate::canopen::eds::Eds,
        now: Instant,
    ) -> Result<Self, EdsRefusal> {
        let mut od = GenericOd::new();
        for e in &eds.entries {
            od.insert(e.to_def()).map_err(EdsRefusal::Load)?;
        }
        let modes = check_dictionary(&od)?;
        Ok(Self::with_dictionary(cfg, od, modes, now))
    }

    /// A drive over `od` (checked with [`check_dictionary`], which gives `modes`).
    pub fn with_dictionary(cfg: Cia402Config, od: GenericOd, modes: u32, now: Instant) -> Self {
        // The quick stop's exit is decided here from 605Ah (it can change at run time), so the
        // state machine itself always stays in Quick stop active.
        let profile = DeviceProfile {
            quick_stop: QuickStopOption::StayInQuickStop,
            ..GENERIC
        };
        let hooks = GenericHooks::new(modes, &od);
        let mut dev = Device::new(cfg.node, od, BootUpStyle::Ds301, hooks);
        dev.power_on(now);
        let mut ac = axis::Config {
            step: cfg.tick,
            mechanics: Mechanics {
                encoder_increments: cfg.encoder_increments.max(1),
                gear_num: 1,
                gear_den: 1,
                feed_um: 1000,
            },
            max_velocity: cfg.max_velocity,
            max_acceleration: cfg.max_acceleration,
            max_deceleration: cfg.max_acceleration,
            quick_stop_deceleration: cfg.max_acceleration,
            following_error_limit: 0,
            stop_on_limit_switch: true,
            position_time_constant: cfg.position_time_constant,
            environment: cfg.environment,
            ..axis::Config::default()
        };
        ac.standstill_velocity = ac.standstill_velocity.max(1);
        let mut axis = Axis::new(ac, cfg.start_position);
        axis.set_clock(now);
        let mut fsa = DeviceStateMachine::new(profile);
        fsa.set_self_test_done(true);
        let pv = PvMonitor::new(PvSettings {
            velocity_window: cfg.pv_window,
            velocity_window_time: Duration::ZERO,
            velocity_threshold: cfg.pv_window / 10,
            velocity_threshold_time: Duration::ZERO,
            max_slippage: None,
        });
        let initial = OperationMode::from_code(dev.od().get_i8(a(0x6060, 0)).unwrap_or(1))
            .ok()
            .filter(|m| m.supported_modes_bit().is_some_and(|b| modes & b != 0))
            .unwrap_or(OperationMode::ProfilePosition);
        let mut d = Cia402Drive {
            cfg,
            profile,
            dev,
            axis,
            fsa,
            modes: ModeSelector::new(initial),
            pp: PpDevice::new(&profile, 0),
            homing_dev: HomingDevice::new(),
            homing: None,
            pv,
            pv_bits: 0,
            halted: false,
            disable_at_rest: false,
            window: WindowTimer::new(),
            fe_timer: WindowTimer::new(),
            fe_over: false,
            cs: Cyclic::default(),
            settings: Settings {
                max_velocity: cfg.max_velocity,
                fe_window: u32::MAX,
                fe_timeout: Duration::ZERO,
                sync_period: None,
                vmax_sub: 0,
                amax_sub: 1,
                limits_sub: (i64::MIN, i64::MAX),
            },
            faults: heapless::Vec::new(),
            last_error: 0,
            referenced: false,
            last_sync: None,
            sync_interval: None,
            sync_armed: false,
            late_dropped: 0,
            now,
            next_tick: now + cfg.tick,
            published: [None; PUBLISHED],
        };
        let _ = d.dev.od_mut().set_i8(a(0x6061, 0), initial.code());
        d.settings = d.read_settings();
        let p = d.actual();
        d.pp.reset(p);
        d.publish();
        d
    }

    // ---- observation ---------------------------------------------------------------------

    /// The settings.
    pub fn config(&self) -> &Cia402Config {
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
    /// The CiA 402 state.
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
    pub fn od(&self) -> &GenericOd {
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
    pub fn faults(&self) -> &[Cia402Fault] {
        &self.faults
    }
    /// Whether homing succeeded since power-on.
    pub fn referenced(&self) -> bool {
        self.referenced
    }
    /// The actual position, increments (6064h).
    pub fn actual(&self) -> i32 {
        self.axis
            .status()
            .position
            .clamp(i32::MIN as i64, i32::MAX as i64) as i32
    }
    /// Synchronous RPDOs dropped for arriving after the 1007h window.
    pub fn late_rpdos_dropped(&self) -> u32 {
        self.late_dropped
    }

    // ---- faults --------------------------------------------------------------------------

    /// Raises `f`: EMCY, 1001h, 1003h, 603Fh, then Fault reaction active with the 605Eh
    /// reaction (0 coast, 1 6084h ramp, 2 6085h ramp, 3/4 the drive's limit), Fault once the
    /// axis is at rest.
    pub fn raise_fault(&mut self, f: Cia402Fault) {
        if self.faults.contains(&f) || self.faults.push(f).is_err() {
            return;
        }
        self.dev.raise_emcy(f.emcy_code(), [0; 5]);
        self.last_error = f.emcy_code();
        let was_powered = self.axis.is_enabled();
        self.fsa.set_fault(true);
        self.drop_commands();
        self.cs.following = false;
        if was_powered {
            let option = self.od_i16(0x605E, 2);
            self.stop_with_option(option, false);
        }
        self.publish();
    }

    /// The fault-reset edge: every fault here is latched, so all clear.
    fn fault_reset(&mut self) {
        self.axis.clear_faults();
        for f in self.faults.clone().iter() {
            self.dev.clear_emcy(f.emcy_code());
        }
        self.faults.clear();
        self.fsa.set_fault(false);
        self.last_error = 0;
        self.fe_timer.reset();
        self.fe_over = false;
        self.sync_armed = false;
    }

    // ---- commands ------------------------------------------------------------------------

    fn od_u16(&self, i: u16, s: u8) -> u16 {
        self.dev.od().get_u16(a(i, s)).unwrap_or(0)
    }
    fn od_u32(&self, i: u16, s: u8, default: u32) -> u32 {
        self.dev.od().get_u32(a(i, s)).unwrap_or(default)
    }
    fn od_i32(&self, i: u16, s: u8) -> i32 {
        self.dev.od().get_i32(a(i, s)).unwrap_or(0)
    }
    fn od_i16(&self, i: u16, default: i16) -> i16 {
        self.dev.od().get_i16(a(i, 0)).unwrap_or(default)
    }
    fn acc(&self, index: u16) -> u32 {
        self.od_u32(index, 0, self.cfg.max_acceleration)
            .clamp(1, self.cfg.max_acceleration.max(1))
    }
    fn max_velocity(&self) -> u32 {
        self.settings.max_velocity
    }

    fn read_settings(&self) -> Settings {
        let od = self.dev.od();
        let value = od.get_u8(a(0x60C2, 1)).unwrap_or(0) as u64;
        let index = od.get_i8(a(0x60C2, 2)).unwrap_or(-3);
        let sync_period = if value != 0 && (-9..=0).contains(&index) {
            Some(Duration::from_nanos(value * 10u64.pow((9 + index) as u32)))
        } else {
            match self.od_u32(0x1006, 0, 0) {
                0 => None,
                us => Some(Duration::from_micros(us as u64)),
            }
        };
        let max_velocity = self
            .od_u32(0x607F, 0, self.cfg.max_velocity)
            .min(self.cfg.max_velocity);
        let sc = self.axis.scale();
        Settings {
            max_velocity,
            vmax_sub: sc.velocity(max_velocity as i64),
            amax_sub: sc.acceleration(self.cfg.max_acceleration).max(1),
            fe_window: self.od_u32(0x6065, 0, u32::MAX),
            fe_timeout: Duration::from_millis(self.od_u16(0x6066, 0) as u64),
            sync_period,
            limits_sub: {
                let lo = od.get_i32(a(0x607D, 1)).unwrap_or(i32::MIN) as i64;
                let hi = od.get_i32(a(0x607D, 2)).unwrap_or(i32::MAX) as i64;
                // Crossed limits bound nothing (as `clip` treats them).
                if lo <= hi {
                    (lo << FRAC_BITS, hi << FRAC_BITS)
                } else {
                    (i64::MIN, i64::MAX)
                }
            },
        }
    }

    /// Brings the axis to rest per an option code of 605Ah / 605Dh / 605Eh: 0 coasts (power
    /// stage off; not for a halt, which keeps the drive enabled), 1 and 5 the 6084h ramp, 2 and 6
    /// the 6085h ramp, 3, 4, 7, 8 the drive's own limit (current and voltage limit are not
    /// modelled apart).
    fn stop_with_option(&mut self, option: i16, halt: bool) {
        if !self.axis.is_enabled() {
            return;
        }
        self.cs.following = false;
        let dec = match option {
            0 if !halt => {
                self.axis.disable();
                return;
            }
            1 | 5 => self.acc(0x6084),
            2 | 6 => self.acc(0x6085),
            _ => self.cfg.max_acceleration,
        };
        let _ = self.axis.run_velocity(0, dec, dec);
    }

    /// Forgets every command (fault, leaving Operation enabled, mode change).
    fn drop_commands(&mut self) {
        let p = self.actual();
        self.pp.reset(p);
        if self.homing.take().is_some() {
            self.homing_dev.reset();
        }
        self.halted = false;
        self.window.reset();
    }

    /// Whether 605Ah leaves Quick stop active once stopped (0..4) rather than stay (5..8).
    fn quick_stop_leaves(&self) -> bool {
        matches!(
            QuickStopOption::from_code(self.od_i16(0x605A, 2)),
            Some(QuickStopOption::ToSwitchOnDisabled) | None
        )
    }

    fn device_control(&mut self, cw: Controlword) {
        if cw.fault_reset() && !self.fsa.controlword().fault_reset() {
            self.fault_reset();
        }
        let before = self.fsa.state();
        // Transition 16 exists only for 605Ah = 5..8; with 0..4 the stop runs to its end.
        let cw = if before == State::QuickStopActive && self.quick_stop_leaves() {
            Controlword((cw.0 & !Controlword::COMMAND_MASK) | 0x0002)
        } else {
            cw
        };
        self.fsa.handle_controlword(cw);
        let after = self.fsa.state();
        self.follow_state(before, after);
    }

    fn follow_state(&mut self, before: State, after: State) {
        use State::*;
        if after == before {
            return;
        }
        let powered = |s| matches!(s, OperationEnabled | QuickStopActive);
        if after == OperationEnabled {
            self.disable_at_rest = false;
            let _ = self.axis.enable();
            if before == QuickStopActive {
                self.resume();
            } else {
                self.drop_commands();
                self.seed_cyclic(true);
                if self.modes.active() == OperationMode::ProfileVelocity {
                    self.pv_start();
                }
            }
        } else if after == QuickStopActive {
            self.cs.following = false;
            let option = self.od_i16(0x605A, 2);
            self.stop_with_option(option, false);
        } else if powered(before) && after != FaultReactionActive {
            self.drop_commands();
            self.cs.following = false;
            self.sync_armed = false;
            // Transitions 5 and 8 may ramp down first (605Ch / 605Bh = 1); 9 and 12 cut power.
            let option = match (before, after) {
                (OperationEnabled, SwitchedOn) => self.od_i16(0x605C, 1),
                (OperationEnabled, ReadyToSwitchOn) => self.od_i16(0x605B, 0),
                _ => 0,
            };
            if option == 1 && self.axis.is_enabled() {
                let dec = self.acc(0x6084);
                let _ = self.axis.run_velocity(0, dec, dec);
                self.disable_at_rest = true;
            } else {
                self.axis.disable();
            }
        }
    }

    /// Restarts the mode's command after halt or quick stop (transition 16).
    fn resume(&mut self) {
        match self.modes.active() {
            OperationMode::ProfilePosition => {
                if let Some(m) = self.pp.active() {
                    self.run_move(m);
                }
            }
            OperationMode::ProfileVelocity => self.pv_start(),
            // The cyclic reference starts again from where the axis is, next tick.
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
                    velocity: self.od_u32(0x6081, 0, 0),
                    acceleration: self.od_u32(0x6083, 0, 0),
                    deceleration: self.od_u32(0x6084, 0, 0),
                };
                let action = self.pp.handle_controlword(cw, &objects);
                self.halt(cw.halt());
                if let Some(PpAction::Start(m)) = action
                    && !self.halted
                {
                    self.run_move(m);
                }
            }
            OperationMode::Homing => match self.homing_dev.handle_controlword(cw) {
                Some(HomingCommand::Start) => self.start_homing(),
                Some(HomingCommand::Interrupt) => {
                    self.homing = None;
                    let option = self.od_i16(0x605D, 1);
                    self.stop_with_option(option, true);
                }
                None => {}
            },
            _ => self.halt(cw.halt()),
        }
    }

    /// Halt (bit 8): the 605Dh ramp, the command kept; released, the command goes on.
    fn halt(&mut self, on: bool) {
        if on && !self.halted {
            self.halted = true;
            let option = self.od_i16(0x605D, 1);
            self.stop_with_option(option, true);
        } else if !on && self.halted {
            self.halted = false;
            self.resume();
        }
    }

    /// 607Dh: a position target clipped into the software limits.
    fn clip(&self, target: i64) -> i64 {
        let lo = self.dev.od().get_i32(a(0x607D, 1)).unwrap_or(i32::MIN) as i64;
        let hi = self.dev.od().get_i32(a(0x607D, 2)).unwrap_or(i32::MAX) as i64;
        if lo <= hi {
            target.clamp(lo, hi)
        } else {
            target
        }
    }

    fn run_move(&mut self, m: Move) {
        let clamp = |v: u32| v.max(1);
        let p = axis::Profile {
            velocity: clamp(m.velocity.min(self.max_velocity())),
            acceleration: clamp(m.acceleration),
            deceleration: clamp(m.deceleration),
        };
        self.window.reset();
        let target = self.clip(m.target as i64);
        let _ = self.axis.move_to(target, p);
    }

    fn pv_start(&mut self) {
        if self.modes.active() != OperationMode::ProfileVelocity
            || self.fsa.state() != State::OperationEnabled
            || self.halted
        {
            return;
        }
        let vmax = self.max_velocity() as i64;
        let v = (self.od_i32(0x60FF, 0) as i64).clamp(-vmax, vmax);
        let (acc, dec) = (self.acc(0x6083), self.acc(0x6084));
        let _ = self.axis.run_velocity(v as i32, acc, dec);
    }

    fn start_homing(&mut self) {
        let code = self.dev.od().get_i8(a(0x6098, 0)).unwrap_or(35);
        let Ok(method) = Method::from_code(code) else {
            self.homing_dev.finished(false);
            return;
        };
        let plan = method.plan();
        let vmax = self.max_velocity();
        let speed = |s: u8| self.od_u32(0x6099, s, 0).clamp(1, vmax.max(1));
        let (search, crawl) = (speed(1), speed(2));
        let home_position = self.od_i32(0x607C, 0) as i64;
        let params = HomingParams {
            search_velocity: search,
            crawl_velocity: crawl,
            travel_velocity: search,
            acceleration: self.acc(0x609A),
            offset: 0,
            travel_to_offset: false,
            home_position,
            stop_current_ma: self.axis.config().current_limit_ma,
            stop_time: Duration::from_millis(20),
            max_search: None,
        };
        let mut h = Homing::new(HomingMethod::from_plan(plan), params);
        match h.update(&mut self.axis) {
            HomingState::Running => self.homing = Some(h),
            s => self.homing_finished(s),
        }
    }

    fn homing_finished(&mut self, s: HomingState) {
        let ok = matches!(s, HomingState::Done { .. });
        self.homing_dev.finished(ok);
        self.homing = None;
        if ok {
            self.referenced = true;
            let p = self.actual();
            self.pp.reset(p);
        }
    }

    /// Objects written by SDO or an RPDO: act on them (all of one RPDO at once).
    fn written(&mut self, addrs: &[Address]) {
        let has = |i: u16| addrs.iter().any(|x| x.index == i);
        if SETTINGS.iter().any(|&i| has(i)) {
            self.settings = self.read_settings();
        }
        if has(0x6060) {
            // An RPDO bypasses the SDO check: a mode outside 6502h is ignored here too.
            let code = self.dev.od().get_i8(a(0x6060, 0)).unwrap_or(1);
            if OperationMode::from_code(code).is_ok_and(|m| self.dev.hooks().offers(m)) {
                let _ = self.modes.request(code, &self.profile);
            }
        }
        if has(0x6040) {
            self.controlword();
        }
        // Profile velocity follows 60FFh at once; the cyclic modes take it at SYNC.
        if has(0x60FF) && self.modes.active() == OperationMode::ProfileVelocity {
            self.pv_start();
        }
    }

    fn update_mode(&mut self) {
        // 6061h follows 6060h at the next tick, moving or not: the cyclic modes take over the
        // motion where it is; PP and HM stop theirs with the running deceleration.
        let Some(m) = self.modes.update(true) else {
            return;
        };
        self.drop_commands();
        self.homing_dev.reset();
        self.cs.following = false;
        if !is_cyclic(m) {
            self.sync_armed = false;
        }
        if self.fsa.state() == State::OperationEnabled {
            if is_cyclic(m) {
                self.seed_cyclic(true);
            } else if m == OperationMode::ProfileVelocity {
                self.pv_start();
            } else {
                self.axis.hold();
            }
        }
    }

    fn reset_application(&mut self) {
        self.axis.disable();
        self.fsa = DeviceStateMachine::new(self.profile);
        self.fsa.set_self_test_done(true);
        let initial = OperationMode::from_code(self.dev.od().get_i8(a(0x6060, 0)).unwrap_or(1))
            .unwrap_or(OperationMode::ProfilePosition);
        self.modes = ModeSelector::new(initial);
        self.homing_dev = HomingDevice::new();
        self.drop_commands();
        self.faults.clear();
        self.axis.clear_faults();
        self.last_error = 0;
        self.cs = Cyclic::default();
        self.disable_at_rest = false;
        self.fe_timer.reset();
        self.fe_over = false;
    }

    fn drain(&mut self) {
        let mut changed = false;
        while let Some(e) = self.dev.poll_event() {
            match e {
                DeviceEvent::SdoWritten { addr } => {
                    changed = true;
                    self.written(&[addr]);
                }
                DeviceEvent::RpdoApplied { pdo } => {
                    changed = true;
                    let map = 0x15FF + pdo as u16;
                    let n = self.dev.od().get_u8(a(map, 0)).unwrap_or(0).min(8);
                    let mut addrs = heapless::Vec::<Address, 8>::new();
                    for s in 1..=n {
                        let raw = self.od_u32(map, s, 0);
                        let _ = addrs.push(a((raw >> 16) as u16, (raw >> 8) as u8));
                    }
                    self.written(&addrs);
                }
                DeviceEvent::Sync { .. } => {
                    changed = true;
                    self.on_sync();
                }
                DeviceEvent::Reset(kind) => {
                    changed = true;
                    self.published = [None; PUBLISHED];
                    self.last_sync = None;
                    self.sync_interval = None;
                    self.sync_armed = false;
                    if kind == ResetKind::Node {
                        self.reset_application();
                    }
                    self.settings = self.read_settings();
                    let modes = self.dev.hooks().modes;
                    *self.dev.hooks_mut() = GenericHooks::new(modes, self.dev.od());
                }
                DeviceEvent::LifeGuardingLost => self.raise_fault(Cia402Fault::LifeGuarding),
                _ => {}
            }
        }
        if changed {
            self.publish();
        }
    }

    // ---- the cyclic synchronous modes -------------------------------------------------

    /// The SYNC period: 60C2h (value × 10^index s), else 1006h, else the last SYNC interval.
    fn sync_period(&self) -> Option<Duration> {
        self.settings.sync_period.or(self.sync_interval)
    }

    /// The set-points as they are in the dictionary now, clipped and clamped.
    fn read_setpoints(&mut self) {
        let p = self.od_i32(0x607A, 0) as i64 + self.od_i32(0x60B0, 0) as i64;
        self.cs.cmd = self.clip(p);
        self.cs.vel_cmd = self.od_i32(0x60FF, 0) as i64 + self.od_i32(0x60B1, 0) as i64;
        let t = self.dev.od().get_i16(a(0x6071, 0)).unwrap_or(0) as i64
            + self.dev.od().get_i16(a(0x60B2, 0)).unwrap_or(0) as i64;
        let tmax = self.od_u16(0x6072, 0) as i64;
        self.cs.torque_cmd = t.clamp(-tmax, tmax);
    }

    /// A SYNC: the set-points are latched (after this SYNC's RPDOs were applied).
    fn on_sync(&mut self) {
        let now = self.now;
        if let Some(last) = self.last_sync {
            self.sync_interval = Some(now.saturating_duration_since(last));
        }
        self.last_sync = Some(now);
        if !is_cyclic(self.modes.active()) {
            return;
        }
        self.cs.cmd_prev = self.cs.cmd;
        self.read_setpoints();
        self.cs.since = 0;
        let tick = self.cfg.tick.as_nanos().max(1);
        let period = self
            .sync_period()
            .map_or(1, |p| p.as_nanos().div_ceil(tick));
        self.cs.period = period.clamp(1, u32::MAX as u128) as u32;
        if self.fsa.state() == State::OperationEnabled {
            self.sync_armed = true;
        }
    }

    /// Starts the reference from the axis' setpoint and velocity; `fresh` also takes the
    /// set-points from the dictionary as they are (no interpolation pending).
    fn seed_cyclic(&mut self, fresh: bool) {
        if !is_cyclic(self.modes.active()) {
            return;
        }
        let st = *self.axis.status();
        let sc = self.axis.scale();
        self.cs.pos = st.setpoint << FRAC_BITS;
        self.cs.vel = sc.velocity(st.setpoint_velocity);
        if fresh {
            self.read_setpoints();
            self.cs.cmd_prev = self.cs.cmd;
            self.cs.since = self.cs.period.max(1);
        }
        self.cs.target = self.cs.cmd;
        self.cs.following = false;
    }

    /// One tick of the cyclic reference, before the axis steps.
    fn cyclic_step(&mut self) {
        let mode = self.modes.active();
        let follow = is_cyclic(mode)
            && self.fsa.state() == State::OperationEnabled
            && !self.halted
            && self.modes.pending().is_none()
            && self.axis.is_enabled();
        if !follow {
            self.cs.following = false;
            return;
        }
        if !self.cs.following {
            self.seed_cyclic(false);
            self.cs.following = true;
        }
        let sc = self.axis.scale();
        let (amax, vmax) = (self.settings.amax_sub, self.settings.vmax_sub);
        let c = &mut self.cs;
        c.limited = false;
        let v_want = match mode {
            OperationMode::CyclicSyncPosition => {
                let n = c.period.max(1) as i128;
                let at = |k: u32| {
                    let d = ((c.cmd - c.cmd_prev) as i128) << FRAC_BITS;
                    ((c.cmd_prev as i128) << FRAC_BITS) + d * k as i128 / n
                };
                let before = at(c.since);
                c.since = (c.since + 1).min(c.period.max(1));
                let after = at(c.since);
                c.target = (after >> FRAC_BITS) as i64;
                let v_ff = (after - before) as i64;
                // Behind the path (a limit cut it): catch up no faster than the braking curve
                // allows, so the reference does not overshoot.
                let lag = (before as i64).saturating_sub(c.pos);
                let catch = lag.signum() * lag.abs().min(brake_velocity(lag.abs(), amax));
                v_ff.saturating_add(catch)
            }
            OperationMode::CyclicSyncVelocity => {
                let target = sc.velocity(c.vel_cmd);
                let step = target.saturating_sub(c.vel).clamp(-amax, amax);
                c.vel.saturating_add(step)
            }
            _ => {
                let acc = c.torque_cmd * self.cfg.rated_acceleration as i64 / 1000;
                let dv = sc.acceleration(acc.unsigned_abs().min(u32::MAX as u64) as u32);
                c.vel.saturating_add(dv * acc.signum())
            }
        };
        let mut v = v_want.clamp(-vmax, vmax);
        if mode != OperationMode::CyclicSyncTorque {
            v = v.clamp(c.vel - amax, c.vel + amax);
        }
        if mode != OperationMode::CyclicSyncPosition {
            // 607Dh: CSV and CST brake to a stop at a software limit (CSP's set-points are
            // clipped into them instead); away from it the axis moves freely.
            let (lo, hi) = self.settings.limits_sub;
            if v > 0 {
                v = v.min(brake_velocity(hi.saturating_sub(c.pos), amax));
            } else if v < 0 {
                v = v.max(-brake_velocity(c.pos.saturating_sub(lo), amax));
            }
        }
        c.limited = v != v_want;
        c.torque = if mode == OperationMode::CyclicSyncTorque && !c.limited {
            c.torque_cmd
        } else {
            0
        };
        c.vel = v;
        c.pos = c.pos.saturating_add(v);
        let inc = (c.pos + (1 << (FRAC_BITS - 1))) >> FRAC_BITS;
        if mode != OperationMode::CyclicSyncPosition {
            c.target = inc;
        }
        let _ = self.axis.stream_setpoint(inc, self.cfg.tick);
    }

    // ---- time ----------------------------------------------------------------------------

    /// Steps the axis up to `now`, one tick at a time.
    fn catch_up(&mut self, now: Instant) {
        self.now = now;
        let mut ticked = false;
        while self.next_tick <= now {
            self.cyclic_step();
            self.axis.step();
            self.tick(self.next_tick);
            self.next_tick += self.cfg.tick;
            ticked = true;
        }
        if ticked {
            self.publish();
        }
    }

    /// The following error the drive monitors: p_cmd(k−1) interpolated to now − p_act in CSP,
    /// setpoint − actual otherwise.
    fn following_error(&self) -> i64 {
        let st = self.axis.status();
        if self.modes.active() == OperationMode::CyclicSyncPosition && self.cs.following {
            self.cs.target - st.position
        } else {
            st.following_error
        }
    }

    fn tick(&mut self, now: Instant) {
        let st = *self.axis.status();
        if st.faults.contains(Faults::LIMIT_POSITIVE) || st.faults.contains(Faults::LIMIT_NEGATIVE)
        {
            self.raise_fault(Cia402Fault::LimitSwitch);
        }
        // Following error: position modes only, not while homing (stop methods push on
        // purpose) and not on a ramp the drive runs itself.
        let mode = self.modes.active();
        let monitored = self.fsa.state() == State::OperationEnabled
            && !self.halted
            && match mode {
                OperationMode::ProfilePosition => true,
                OperationMode::CyclicSyncPosition => self.cs.following,
                _ => false,
            };
        let window = self.settings.fe_window;
        let over = monitored
            && window != u32::MAX
            && self.following_error().unsigned_abs() > window as u64;
        let timeout = self.settings.fe_timeout;
        if self.fe_timer.update(over, now) > timeout {
            self.fe_over = true;
            self.raise_fault(Cia402Fault::FollowingError);
        }
        // Missing SYNCs in a cyclic mode: hold the set-point, then fault.
        if self.sync_armed
            && is_cyclic(mode)
            && self.fsa.state() == State::OperationEnabled
            && let (Some(last), Some(period)) = (self.last_sync, self.sync_period())
            && now.saturating_duration_since(last) > period * self.cfg.sync_loss_periods.max(1)
        {
            self.raise_fault(Cia402Fault::SyncLost);
        }
        let stopped = st.standstill || !self.axis.is_enabled();
        match self.fsa.state() {
            State::FaultReactionActive if stopped => {
                self.axis.disable();
                self.fsa.set_fault(false);
                self.fsa.set_fault_reaction_done();
            }
            State::QuickStopActive if stopped && self.quick_stop_leaves() => {
                // Transition 12 once the ramp has stopped the axis (605Ah = 0..4).
                self.fsa.handle_controlword(Controlword(0));
                self.axis.disable();
            }
            _ => {}
        }
        if self.disable_at_rest && stopped {
            self.disable_at_rest = false;
            self.axis.disable();
        }
        self.update_mode();
        if let Some(mut h) = self.homing.take() {
            match h.update(&mut self.axis) {
                HomingState::Running => self.homing = Some(h),
                s => self.homing_finished(s),
            }
        }
        if let Some(m) = self.pp.active()
            && !self.halted
            && st.generator_done
        {
            let target = self.clip(m.target as i64);
            let inside = st.position.abs_diff(target) <= self.od_u32(0x6067, 0, 10) as u64;
            let win_time = Duration::from_millis(self.od_u16(0x6068, 0) as u64);
            if self.window.update(inside, now) >= win_time {
                self.window.reset();
                if let Some(next) = self.pp.move_finished()
                    && !self.halted
                {
                    self.run_move(next);
                }
            }
        }
        self.pp.set_standstill(st.standstill);
        if mode == OperationMode::ProfileVelocity {
            let target = if self.fsa.state() == State::OperationEnabled && !self.halted {
                let vmax = self.max_velocity() as i64;
                (self.od_i32(0x60FF, 0) as i64).clamp(-vmax, vmax)
            } else {
                0
            };
            let clamp = |v: i64| v.clamp(i32::MIN as i64, i32::MAX as i64) as i32;
            self.pv_bits = self.pv.update(clamp(target), clamp(st.velocity), now).0;
        }
    }

    /// Writes the actual values and the statusword into the dictionary (what TPDOs and SDO
    /// uploads read).
    fn publish(&mut self) {
        let st = *self.axis.status();
        let i32c = |v: i64| v.clamp(i32::MIN as i64, i32::MAX as i64);
        let i16c = |v: i64| v.clamp(i16::MIN as i64, i16::MAX as i64);
        let fe = self.faults.contains(&Cia402Fault::FollowingError) || self.fe_over;
        let state = self.fsa.state();
        let mode = self.modes.active();
        let mode_bits = match mode {
            OperationMode::ProfilePosition => {
                self.pp.status_bits().0 | if fe { Statusword::FOLLOWING_ERROR } else { 0 }
            }
            OperationMode::ProfileVelocity => self.pv_bits,
            OperationMode::Homing => self.homing_dev.status().bits().0,
            _ => {
                let follows = self.cs.following && state == State::OperationEnabled;
                let at_rest = self.halted && st.standstill;
                (if follows { Statusword::BIT12 } else { 0 })
                    | (if fe && mode == OperationMode::CyclicSyncPosition {
                        Statusword::BIT13
                    } else {
                        0
                    })
                    | (if at_rest {
                        Statusword::TARGET_REACHED
                    } else {
                        0
                    })
            }
        };
        let limit = st.switches.contains(Switches::LIMIT_POSITIVE)
            || st.switches.contains(Switches::LIMIT_NEGATIVE)
            || (self.cs.following && self.cs.limited);
        let dynamic = mode_bits
            | if limit {
                Statusword::INTERNAL_LIMIT_ACTIVE
            } else {
                0
            };
        let sw = self.profile.statusword(state, Statusword(dynamic)).0;
        let torque = if mode == OperationMode::CyclicSyncTorque && self.cs.following {
            self.cs.torque
        } else if self.axis.is_enabled() {
            st.acceleration * 1000 / self.cfg.rated_acceleration.max(1) as i64
        } else {
            0
        };
        let values: [(u16, i64); PUBLISHED] = [
            (0x6041, sw as i64),
            (0x6061, mode.code() as i64),
            (0x6064, i32c(st.position)),
            (0x606C, i32c(st.velocity)),
            (0x6077, i16c(torque)),
            (0x60F4, i32c(self.following_error())),
            (0x603F, self.last_error as i64),
        ];
        // Most change rarely: write only what differs from the last publish.
        let od = self.dev.od_mut();
        for (k, &(i, v)) in values.iter().enumerate() {
            if self.published[k] != Some(v) {
                let _ = od.set_int(a(i, 0), v);
                self.published[k] = Some(v);
            }
        }
    }

    // ---- the 1007h window ----------------------------------------------------------------

    /// Whether `frame` is a synchronous RPDO of this drive arriving after the 1007h window.
    fn late_rpdo(&self, frame: &Frame, now: Instant) -> bool {
        if self.dev.state() != NmtState::Operational || frame.is_remote() {
            return false;
        }
        let window = self.od_u32(0x1007, 0, 0);
        let Some(last) = self.last_sync else {
            return false;
        };
        if window == 0
            || now.saturating_duration_since(last) <= Duration::from_micros(window as u64)
        {
            return false;
        }
        let Some(id) = frame.cob_id() else {
            return false;
        };
        (0..4u16).any(|k| {
            let cob = self.od_u32(0x1400 + k, 1, 0x8000_0000);
            let t = self.dev.od().get_u8(a(0x1400 + k, 2)).unwrap_or(255);
            cob & 0x8000_0000 == 0 && (cob & 0x7FF) as u16 == id && t <= 240
        })
    }
}

impl Endpoint for Cia402Drive {
    /// The device's identifiers only: another node's frame does not make the drive catch up.
    fn accepts(&self, frame: &Frame) -> bool {
        self.dev.accepts(frame)
    }

    fn handle_frame(&mut self, frame: &Frame, now: Instant) {
        self.catch_up(now);
        // CiA 301: a synchronous PDO outside the window is discarded.
        if self.late_rpdo(frame, now) {
            self.late_dropped = self.late_dropped.saturating_add(1);
            return;
        }
        self.dev.handle_frame(frame, now);
        self.drain();
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
