//! The FHPP drive simulator core, shared by the MTR-DCI, EMCA and CMMO-ST simulators: everything
//! between "8 bytes of FHPP output data arrive" and "8 bytes of FHPP input data go back", the
//! parameter channel, and the physics (an [`Axis`]). Transport-independent: the CANopen adapters
//! feed PDO1/PDO2 and SDO 2000h + PNU, the Modbus TCP server feeds registers 0..3 / 4..7.
//!
//! Timing model: the drive runs an internal cycle (MTR-DCI 1 ms, digest 000 E20; EMCA 5 ms,
//! digest 002 §8; CMMO-ST 2 ms, digest 001 §8 decision). At every cycle boundary it samples
//! the latest control image and parameter request, steps the FHPP state machine once, carries
//! out the command, and computes the status image the next [`FhppDrive::exchange`] returns.
//! So a control image takes effect at the first boundary after it arrived, and its effect is
//! visible from that boundary on. The axis is stepped in its own fixed sub-cycle up to the time
//! asked for. Everything is integer arithmetic in virtual time: the same calls at the same
//! times give the same bytes.
//!
//! Positions are in the axis' increments, which are the interface units (MTR-DCI inc,
//! EMCA/CMMO-ST SINC with a factor group of 1).
//!
//! ```
//! use drivers::fhpp::Variant;
//! use drivers::sim::fhpp_drive::{DriveConfig, FhppDrive};
//! use drivers::time::Instant;
//! let mut d = FhppDrive::new(DriveConfig::new(Variant::MtrDci)).unwrap();
//! // Power-on: drive blocked, load voltage, MC = 1 (digest 000 §2.5).
//! let input = d.exchange(&[0; 8], Instant::from_millis(1));
//! assert_eq!(&input[..2], &[0x10, 0x04]);
//! ```

pub mod diag;

use core::time::Duration;

use heapless::{Deque, Vec};

use crate::canopen::AbortCode;
use crate::fhpp::control::{Cdir, OutputImage, OutputPayload};
use crate::fhpp::fpc::{self, Codec, ErrorKind, Param, Parameters, Value};
use crate::fhpp::pnu::{ParamDef, ParamError, ParamStore, Rcb1, record_subindex};
use crate::fhpp::state::{
    Actions, Command, Conditions, Control, Direction as JogDir, FaultClass, Machine, Refusal,
    StartCondition, State, Sub, Transition,
};
use crate::fhpp::status::{InputImage, InputPayload, Rsb, Sdir};
use crate::fhpp::units::{force_to_milliamps, percent_from, percent_of};
use crate::fhpp::{ByteOrder, ControlMode, Opm, Variant};
use crate::time::Instant;

use super::axis::{
    self, Axis, Environment, Faults, ForceCommand, Load, Profile, SwitchZone, WindowTimer,
};
use super::comparator::{ComparatorParams, ComparatorSet, DIRECT_BASE, Sample};
use super::homing::{Homing, HomingMethod, HomingParams, HomingState};
use super::records::{Chain, Record, RecordError, Verdict};

pub use diag::{DiagInfo, FaultKind, Severity};

/// Values the parameter store holds; enough for every variant's table (the EMCA's, with the
/// 200-entry diagnostic memory and 64 records, is the largest).
pub const STORE_CAPACITY: usize = 4096;

/// The PNU store of a simulated drive.
pub type Store = ParamStore<STORE_CAPACITY>;

/// How many faults and warnings can be active at once.
pub const MAX_ACTIVE: usize = 8;

/// EMCY messages kept for the transport until polled (the oldest is dropped beyond that and
/// counted in [`FhppDrive::emcy_overflows`]).
pub const EMCY_QUEUE: usize = 16;

/// Everything that does not change while the drive runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DriveConfig {
    /// Which device.
    pub variant: Variant,
    /// Byte order of the cyclic image (CANopen little-endian, Modbus big-endian).
    pub byte_order: ByteOrder,
    /// Byte order of the parameter channel (MTR-DCI erratum E2: little-endian on CANopen).
    pub fpc_byte_order: ByteOrder,
    /// The drive's internal cycle.
    pub cycle: Duration,
    /// The physical axis.
    pub axis: axis::Config,
    /// Raw position of the axis at power-on, increments.
    pub start_position: i64,
    /// SPOS.MOV threshold, inc/s (unspecified by the manuals; MTR-DCI E19 suggests 1 % of max).
    pub mov_threshold: u32,
    /// Following-error window where no PNU gives one (MTR-DCI PNU 1026/8 has no default),
    /// increments; 0 = not monitored.
    pub following_error_window: u32,
    /// MTR-DCI stop detection time for homing on a fixed stop (unspecified; PNU 1017 on the
    /// others).
    pub homing_stop_time: Duration,
}

impl DriveConfig {
    /// The defaults of `variant`: the axis of [`axis::Config::default`] (an MTR-DCI-42-G7 on a
    /// DMES-25, 2000 inc/rev) with a reference switch at the negative end (active below 5400
    /// inc = 1 mm), no limit-switch stop, and the drive's own following-error check.
    pub fn new(variant: Variant) -> DriveConfig {
        let mut a = axis::Config {
            environment: Environment {
                travel: Some((-2_000, 542_000)),
                limit_negative: None,
                limit_positive: None,
                reference: Some(SwitchZone::below(5_400)),
                load: Load::None,
                index_phase: 0,
            },
            ..axis::Config::default()
        };
        // The drive monitors the following error itself, with the device's windows.
        let fe = a.following_error_limit;
        a.following_error_limit = 0;
        let cycle = match variant {
            Variant::MtrDci => Duration::from_millis(1),
            Variant::Emca => Duration::from_millis(5),
            Variant::CmmoSt => Duration::from_millis(2),
        };
        DriveConfig {
            variant,
            byte_order: variant.default_byte_order(),
            fpc_byte_order: variant.default_byte_order(),
            cycle,
            axis: a,
            start_position: 100_000,
            mov_threshold: a.max_velocity / 100,
            following_error_window: fe,
            homing_stop_time: Duration::from_millis(100),
        }
    }
}

/// The profile the MTR-DCI's CiA 402 face gives a direct-mode positioning (seed 000 §7.4,
/// §7.9): the FHPP image has only a speed byte in per cent of PNU 502 and no ramp.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DirectProfile {
    /// 6081h profile velocity, inc/s (at most PNU 502); `None`: the speed byte.
    pub velocity: Option<u32>,
    /// 6083h profile acceleration, inc/s² (at most PNU 503), also for braking (controlword bit
    /// 15 "symmetrical ramp via PDO"); `None`: the stored ramp.
    pub acceleration: Option<u32>,
}

/// Why a drive could not be built.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum DriveError {
    /// The parameter table does not fit [`STORE_CAPACITY`].
    #[error(transparent)]
    Capacity(#[from] crate::fhpp::pnu::CapacityError),
    /// The internal cycle is zero.
    #[error("the internal cycle must be longer than zero")]
    ZeroCycle,
}

/// A refused SDO/Modbus parameter access, with the device's answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum PnuError {
    /// Refused by the table (existence, access, type, range, rw2).
    #[error(transparent)]
    Param(#[from] ParamError),
    /// The fieldbus does not hold device control (PNU 125 = 0 / FCT in control).
    #[error("PNU {pnu}: the fieldbus does not hold device control")]
    NoControl {
        /// The PNU.
        pnu: u16,
    },
}

impl PnuError {
    /// The FPC error kind.
    pub const fn kind(&self) -> ErrorKind {
        match self {
            PnuError::Param(e) => e.kind(),
            PnuError::NoControl { .. } => ErrorKind::NoControl,
        }
    }
    /// The SDO abort code a CANopen adapter answers with (CiA 301; EMCA digest §5.1).
    pub const fn abort_code(&self) -> AbortCode {
        match self {
            PnuError::Param(ParamError::NoSuchPnu { .. }) => AbortCode::NoObject,
            PnuError::Param(ParamError::BadSubindex { .. }) => AbortCode::NoSubIndex,
            PnuError::Param(ParamError::ReadOnly { .. }) => AbortCode::ReadOnly,
            PnuError::Param(ParamError::WriteOnly { .. }) => AbortCode::WriteOnly,
            PnuError::Param(ParamError::WrongType { .. }) => AbortCode::TypeMismatch,
            PnuError::Param(ParamError::OutOfRange { .. }) => AbortCode::InvalidValue,
            PnuError::Param(ParamError::StageOn { .. }) => AbortCode::DeviceState,
            PnuError::NoControl { .. } => AbortCode::LocalControl,
        }
    }
    /// The number the device's parameter channel answers with.
    pub const fn fpc_number(&self, variant: Variant) -> u16 {
        self.kind().number(variant.parameter_channel())
    }
}

/// An emergency message for the CANopen adapters (8 bytes: code LE, register, 5 × 0).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Emcy {
    /// The error code: the manual's, 0x1000 (generic) where it prints none, 0x0000 on an
    /// acknowledge ("error reset").
    pub code: u16,
    /// Error register 1001h (bit 0 generic set with any fault).
    pub register: u8,
    /// The device's fault number (0 for the reset message).
    pub number: u16,
}

impl Emcy {
    /// The EMCY frame's 8 data bytes.
    pub const fn to_bytes(&self) -> [u8; 8] {
        let c = self.code.to_le_bytes();
        [c[0], c[1], self.register, 0, 0, 0, 0, 0]
    }
}

/// Conditions a test can switch on and off from outside.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Injection {
    /// Load-voltage drop: the power stage goes off, SCON.VLOAD = 0, fault 70 / 1Bh.
    SupplyDrop,
    /// Output-stage over-temperature (fault 101 / 15h).
    OverTemperature,
    /// I²t overload (fault 100 / 0Eh).
    I2t,
    /// The mechanics jam: a move builds a following error.
    Block,
    /// Panel emergency stop (MTR-DCI 106).
    MotorStop,
    /// Hardware/EEPROM fault (MTR-DCI 52, EMCA/CMMO-ST 0Ah).
    Hardware,
    /// STO requested (EMCA/CMMO-ST): no enable, fault 34h.
    Sto,
    /// CANopen life guarding lost: the master stopped polling (MTR-DCI digest §7.6, EMCA 1Ch).
    LifeGuarding,
}

/// A fault or warning the drive holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ActiveDiag {
    /// The cause.
    pub kind: FaultKind,
    /// How the device reports it.
    pub info: DiagInfo,
    /// When it came, virtual time.
    pub since: Instant,
}

/// A task's setpoints as taken over at START.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Job {
    Position {
        target: i64,
        profile: Profile,
    },
    Speed {
        velocity: i64,
        acceleration: u32,
        stroke: Option<u32>,
    },
    Force {
        current_ma: i32,
        speed_limit: u32,
        stroke: Option<u32>,
        window_ma: u32,
        settle: Duration,
    },
    /// Record 0 in record select.
    Homing,
}

impl Job {
    const fn mode(&self) -> ControlMode {
        match self {
            Job::Position { .. } | Job::Homing => ControlMode::Position,
            Job::Speed { .. } => ControlMode::Speed,
            Job::Force { .. } => ControlMode::Force,
        }
    }
}

/// A task ready to start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Prepared {
    job: Job,
    record: Option<Record>,
    delay: Duration,
    start_condition: StartCondition,
    relative: bool,
}

/// What the axis is doing for the drive.
#[derive(Debug, Clone, Copy)]
enum Activity {
    Idle,
    Task {
        job: Job,
        /// Motion begins at this time (start delay PNU 426/582).
        begin: Instant,
        begun: bool,
        start_position: i64,
        halted: bool,
    },
    Homing(Homing),
    Jog {
        dir: JogDir,
        since: Instant,
        fast: bool,
    },
}

/// The step decided for the next record / queued task, handed to the state machine as TA5.
#[derive(Debug, Clone, Copy)]
enum Follow {
    Record(u8),
    /// The task in `FhppDrive::queued`.
    Queued,
}

/// A parameter access recorder around the store, so side effects run after the FPC server.
struct Tap<'a> {
    store: &'a mut Store,
    read: Option<Param>,
    written: Option<Param>,
}

impl Parameters for Tap<'_> {
    fn read(&mut self, param: Param) -> Result<Value, ErrorKind> {
        let v = self.store.read(param)?;
        self.read = Some(param);
        Ok(v)
    }
    fn write(&mut self, param: Param, value: Value) -> Result<(), ErrorKind> {
        // PNU 125 itself must stay writable, or the bus could never take control back.
        let keep = self.store.fieldbus_control;
        if param.pnu == 125 {
            self.store.fieldbus_control = true;
        }
        let r = self.store.write(param, value);
        self.store.fieldbus_control = keep;
        r?;
        self.written = Some(param);
        Ok(())
    }
}

/// The simulated FHPP drive.
#[derive(Debug, Clone)]
pub struct FhppDrive {
    cfg: DriveConfig,
    variant: Variant,
    axis: Axis,
    machine: Machine,
    store: Store,
    fpc: fpc::Server,
    control: [u8; 8],
    fpc_request: [u8; 8],
    input: [u8; 8],
    fpc_reply: [u8; 8],
    next_cycle: Instant,
    /// The MTR-DCI's CiA 402 face: the profile of the direct-mode positionings it starts
    /// (6081h; 6083h with controlword bit 15), instead of the speed byte's per cent and the
    /// stored ramp.
    direct_profile: DirectProfile,
    activity: Activity,
    chain: Option<Chain>,
    direct_cmp: ComparatorSet,
    task_started: Instant,
    follow: Option<Follow>,
    queued: Option<Prepared>,
    prepared: Option<Result<Prepared, FaultKind>>,
    mc_timer: WindowTimer,
    fe_timer: WindowTimer,
    still_timer: WindowTimer,
    referenced: bool,
    last_nominal: i64,
    record_number: u8,
    record_relative: bool,
    task_mode: ControlMode,
    xlim: bool,
    dev: bool,
    still_armed: bool,
    still: bool,
    mc_pulse: bool,
    disable_when_still: bool,
    active: Vec<ActiveDiag, MAX_ACTIVE>,
    new_fault: Option<FaultClass>,
    emcy: Deque<Emcy, EMCY_QUEUE>,
    emcy_overflows: u32,
    injected: [bool; 8],
    fct_control: bool,
    sample_level: bool,
    sample_unread: [bool; 2],
}

const fn injection_index(i: Injection) -> usize {
    match i {
        Injection::SupplyDrop => 0,
        Injection::OverTemperature => 1,
        Injection::I2t => 2,
        Injection::Block => 3,
        Injection::MotorStop => 4,
        Injection::Hardware => 5,
        Injection::Sto => 6,
        Injection::LifeGuarding => 7,
    }
}

fn clamp_u32(v: i64) -> u32 {
    v.clamp(0, u32::MAX as i64) as u32
}

fn ms(v: i64) -> Duration {
    Duration::from_millis(v.max(0) as u64)
}

impl FhppDrive {
    /// A drive at power-on (S1, MC = 1, not referenced) with the variant's parameter defaults
    /// and the configuration's values in the PNUs that depend on the mechanics.
    pub fn new(cfg: DriveConfig) -> Result<FhppDrive, DriveError> {
        if cfg.cycle.is_zero() {
            return Err(DriveError::ZeroCycle);
        }
        let variant = cfg.variant;
        let store = Store::new(variant)?;
        let axis = Axis::new(cfg.axis, cfg.start_position);
        let codec = Codec::new(variant.parameter_channel(), cfg.fpc_byte_order);
        let fpc = fpc::Server::new(codec);
        let mut d = FhppDrive {
            cfg,
            variant,
            axis,
            machine: Machine::power_on(),
            store,
            fpc,
            control: [0; 8],
            fpc_request: codec.encode_request(fpc::Request::NoTask),
            input: [0; 8],
            fpc_reply: fpc.reply(),
            next_cycle: Instant::ZERO,
            direct_profile: DirectProfile::default(),
            activity: Activity::Idle,
            chain: None,
            direct_cmp: ComparatorSet::default(),
            task_started: Instant::ZERO,
            follow: None,
            queued: None,
            prepared: None,
            mc_timer: WindowTimer::new(),
            fe_timer: WindowTimer::new(),
            still_timer: WindowTimer::new(),
            referenced: false,
            last_nominal: 0,
            record_number: 0,
            record_relative: false,
            task_mode: ControlMode::Position,
            xlim: false,
            dev: false,
            still_armed: false,
            still: false,
            mc_pulse: false,
            disable_when_still: false,
            active: Vec::new(),
            new_fault: None,
            emcy: Deque::new(),
            emcy_overflows: 0,
            injected: [false; 8],
            fct_control: false,
            sample_level: false,
            sample_unread: [false; 2],
        };
        d.load_config_defaults();
        d.last_nominal = d.axis.status().position;
        d.refresh_live();
        d.input = d.build_input();
        Ok(d)
    }

    /// Writes the values that follow from the configuration where the table has no usable
    /// default (EMCA/CMMO-ST ship most of them as 0; the MTR-DCI ones match the default axis).
    fn load_config_defaults(&mut self) {
        let a = self.cfg.axis;
        let (vmax, amax, dmax) = (
            i64::from(a.max_velocity),
            i64::from(a.max_acceleration),
            i64::from(a.max_deceleration),
        );
        let rated = i64::from(a.rated_current_ma);
        let mtr = self.variant == Variant::MtrDci;
        let set = |d: &mut FhppDrive, pnu: u16, sub: u8, v: i64| {
            let _ = d.store.set(Param::new(pnu, sub), v);
        };
        if mtr {
            set(self, 502, 0, vmax);
            set(self, 503, 0, amax);
            set(self, 1035, 0, rated);
            return;
        }
        for (pnu, v) in [
            (502, vmax),
            (503, amax),
            (540, vmax),
            (541, amax),
            (542, dmax),
            (560, amax),
            (1029, i64::from(a.quick_stop_deceleration)),
            (1022, 500),
            (1023, 20),
            (1042, 500),
            (1043, 200),
            (1045, 10),
            (549, i64::from(self.cfg.following_error_window)),
            (538, i64::from(self.cfg.following_error_window)),
            (530, 5_000),
            (531, 20_000),
            (532, 200_000),
            (534, 500),
            (552, 50),
            (555, rated),
            (561, 1_000),
            (1013, 200_000),
            (1015, 1000),
            (1016, 1_000),
            (1017, 50),
        ] {
            set(self, pnu, 1, v);
        }
        set(self, 1012, 1, 20_000);
        set(self, 1012, 2, 20_000);
        set(self, 1012, 3, 5_000);
    }

    // ---- the transport's API ------------------------------------------------------------------

    /// The device.
    pub const fn variant(&self) -> Variant {
        self.variant
    }

    /// The configuration.
    pub const fn config(&self) -> &DriveConfig {
        &self.cfg
    }

    /// The cyclic process data: takes the master's 8 output bytes (CCON, CPOS, CDIR/record,
    /// payload) received at `now`, returns the 8 input bytes (SCON, SPOS, SDIR/record, RSB or
    /// actual values) as of the last internal cycle. The output takes effect at the next cycle.
    pub fn exchange(&mut self, output: &[u8; 8], now: Instant) -> [u8; 8] {
        self.step_to(now);
        self.control = *output;
        self.input
    }

    /// When the next internal cycle runs: a transport reports it as its deadline so the drive
    /// advances in virtual time even while no frame arrives.
    pub const fn next_cycle(&self) -> Instant {
        self.next_cycle
    }

    /// The parameter-channel reply as of the last internal cycle, without sending a request.
    pub const fn fpc_reply(&self) -> [u8; 8] {
        self.fpc_reply
    }

    /// The status image as of the last internal cycle, without sending anything.
    pub const fn input(&self) -> [u8; 8] {
        self.input
    }

    /// Starts the drive's clock at `now` (power-on at that instant): a drive created on the
    /// monotonic clock would otherwise simulate every internal cycle since the clock's epoch.
    pub fn start_at(&mut self, now: Instant) {
        self.axis.set_clock(now);
        self.next_cycle = now;
    }

    /// The MTR-DCI's CiA 402 face: the profile of the direct-mode positionings started from now
    /// on (see [`DirectProfile`]).
    pub fn set_direct_profile(&mut self, profile: DirectProfile) {
        self.direct_profile = profile;
    }

    /// Advances the internal cycle and the axis to `now` (never backwards).
    pub fn step_to(&mut self, now: Instant) {
        while self.next_cycle <= now {
            let t = self.next_cycle;
            self.advance_axis(t);
            self.cycle(t);
            self.next_cycle = t + self.cfg.cycle;
        }
        self.advance_axis(now);
    }

    /// The parameter channel (PDO2 / registers 4..7): takes the 8 request bytes received at
    /// `now`, returns the reply held since the last internal cycle. The drive executes a task
    /// once and keeps its reply while the task repeats ("no task in between").
    pub fn parameter(&mut self, request: &[u8; 8], now: Instant) -> [u8; 8] {
        self.step_to(now);
        self.fpc_request = *request;
        self.fpc_reply
    }

    /// Reads a parameter for SDO (2000h + PNU) or Modbus: the same store as the FPC.
    pub fn read_pnu(&mut self, pnu: u16, sub: u8) -> Result<i64, PnuError> {
        let p = Param::new(pnu, sub);
        self.store.table().check_read(p)?;
        let v = self.store.get(p)?;
        self.after_read(p);
        Ok(v)
    }

    /// Writes a parameter for SDO or Modbus, with the device's checks (access, range, rw2 with
    /// the output stage on, device control).
    pub fn write_pnu(&mut self, pnu: u16, sub: u8, value: i64) -> Result<(), PnuError> {
        let p = Param::new(pnu, sub);
        if pnu != 125 && !self.store.fieldbus_control {
            return Err(PnuError::NoControl { pnu });
        }
        let d = self.store.table().lookup(p)?;
        if value < d.dtype.min() || value > d.dtype.max() {
            return Err(ParamError::OutOfRange {
                pnu,
                sub,
                value,
                min: d.min,
                max: d.max,
            }
            .into());
        }
        let raw = d.dtype.encode(value, self.variant.parameter_channel());
        let (_, v) = self
            .store
            .table()
            .check_write(p, raw, self.store.stage_on)?;
        self.store.set(p, v)?;
        self.after_write(p);
        Ok(())
    }

    /// The definition of a parameter (type and width for the SDO layer).
    pub fn pnu_def(&self, pnu: u16, sub: u8) -> Result<&'static ParamDef, PnuError> {
        Ok(self.store.table().lookup(Param::new(pnu, sub))?)
    }

    /// The parameter store, read-only (tests, FHPP+ mapping).
    pub const fn store(&self) -> &Store {
        &self.store
    }

    /// Sets a parameter from the device side (commissioning before power-up, FCT), bypassing
    /// access checks; the value is limited to the type.
    pub fn set_pnu(&mut self, pnu: u16, sub: u8, value: i64) -> Result<(), PnuError> {
        let p = Param::new(pnu, sub);
        self.store.set(p, value)?;
        self.after_write(p);
        Ok(())
    }

    /// The EMCY code of the most important active fault (none for warnings).
    pub fn emcy(&self) -> Option<Emcy> {
        self.top_fault().map(|a| Self::emcy_of(&a))
    }

    /// The next EMCY to send: one per new fault, one on a refused acknowledge (EMCA), and
    /// 0x0000 on a successful acknowledge.
    pub fn poll_emcy(&mut self) -> Option<Emcy> {
        self.emcy.pop_front()
    }

    /// EMCYs dropped because the queue was full.
    pub const fn emcy_overflows(&self) -> u32 {
        self.emcy_overflows
    }

    /// The active faults and warnings, oldest first.
    pub fn active(&self) -> &[ActiveDiag] {
        &self.active
    }

    /// The fault number the device reports now (MTR-DCI fault number, EMCA/CMMO-ST PNU 205),
    /// `None` without a fault.
    pub fn fault_number(&self) -> Option<u16> {
        self.top_fault().map(|a| a.info.number)
    }

    /// Switches an injected condition on or off; it is noticed at the next internal cycle.
    pub fn inject(&mut self, what: Injection, on: bool) {
        self.injected[injection_index(what)] = on;
        match what {
            Injection::SupplyDrop => self.axis.inject_supply_drop(on),
            Injection::OverTemperature => self.axis.inject_over_temperature(on),
            Injection::Block => self.axis.inject_block(on),
            _ => {}
        }
    }

    /// Whether FCT/HMI holds device control (then the fieldbus does not: PNU 125).
    pub const fn fct_control(&self) -> bool {
        self.fct_control
    }

    /// The fieldbus connection was lost (the CMMO-ST's Modbus node guard expired, the EMCA's
    /// EtherCAT outputs stopped): raises 47h/48h or 50h/51h at `now`; a fault stops the axis
    /// through the state machine.
    pub fn fieldbus_lost(&mut self, master_control: bool, now: Instant) {
        self.step_to(now);
        self.raise(FaultKind::FieldbusLost { master_control }, now);
    }

    /// A fieldbus client connected again: the 48h warning clears itself (the 47h fault waits
    /// for an acknowledge).
    pub fn fieldbus_restored(&mut self, now: Instant) {
        self.step_to(now);
        self.clear_kind(
            FaultKind::FieldbusLost {
                master_control: false,
            },
            now,
        );
    }

    /// FCT/HMI asks for device control (`true`) or gives it back. Refused while the master
    /// holds CCON.LOCK = 1; returns whether FCT holds control afterwards.
    pub fn set_fct_control(&mut self, on: bool) -> bool {
        let lock = Control::from_bytes(self.control[0], self.control[1])
            .ccon
            .lock;
        if on && lock {
            return self.fct_control;
        }
        self.fct_control = on;
        self.fct_control
    }

    /// The EMCA's sample input (flying measurement, PNU 350..352) at `now`: an edge latches the
    /// actual position into PNU 350 (rising) / 351 (falling) if PNU 352 enables that edge (bit 0
    /// rising, bit 1 falling; the manual's codes are cut off) and the previous value was read.
    pub fn set_sample_input(&mut self, level: bool, now: Instant) {
        self.step_to(now);
        if level == self.sample_level {
            return;
        }
        self.sample_level = level;
        if self.variant != Variant::Emca {
            return;
        }
        let mode = self.store.get(Param::new(352, 1)).unwrap_or(0);
        let (pnu, slot, bit) = if level { (350, 0, 1) } else { (351, 1, 2) };
        if mode & bit != 0 && !self.sample_unread[slot] {
            let pos = self.axis.status().position;
            let _ = self.store.set(Param::new(pnu, 1), pos);
            self.sample_unread[slot] = true;
        }
    }

    /// The axis (position, velocity, current, switches).
    pub const fn axis(&self) -> &Axis {
        &self.axis
    }

    /// The axis' environment (switches, stops, loads), to move things while running.
    pub fn environment_mut(&mut self) -> &mut Environment {
        self.axis.environment_mut()
    }

    /// The FHPP state machine.
    pub const fn machine(&self) -> &Machine {
        &self.machine
    }

    /// Whether the drive is referenced (SPOS.REF).
    pub const fn is_referenced(&self) -> bool {
        self.referenced
    }

    // ---- the internal cycle ----------------------------------------------------------------

    fn advance_axis(&mut self, until: Instant) {
        while self.axis.now() < until {
            self.axis.step();
            if let Activity::Homing(h) = &mut self.activity {
                h.update(&mut self.axis);
            }
        }
    }

    /// One internal cycle at `t`.
    fn cycle(&mut self, t: Instant) {
        self.store.stage_on = self.axis.is_enabled();
        self.store.fieldbus_control =
            !self.fct_control && self.store.get(self.var(125)).unwrap_or(1) == 1;
        self.parameter_cycle();

        let control = Control::from_bytes(self.control[0], self.control[1]);
        let image = OutputImage::from_bytes(&self.control, self.cfg.byte_order).ok();
        self.timers(t);
        self.monitor(t);
        let start_rise = control.cpos.start && !self.machine.last.cpos.start;
        self.prepared = if start_rise {
            Some(self.prepare(image))
        } else {
            None
        };
        let cond = self.conditions(t, image);
        let was = self.machine.state;
        let (m, actions) = self.machine.step(self.variant, control, &cond);
        self.machine = m;
        self.mc_pulse = false;
        self.apply(was, &actions, image, t);
        if self.disable_when_still && self.axis.status().standstill {
            self.axis.disable();
            self.disable_when_still = false;
        }
        self.refresh_live();
        self.input = self.build_input();
    }

    fn parameter_cycle(&mut self) {
        let mut tap = Tap {
            store: &mut self.store,
            read: None,
            written: None,
        };
        self.fpc_reply = self.fpc.handle(&self.fpc_request, &mut tap);
        let (read, written) = (tap.read, tap.written);
        if let Some(p) = read {
            self.after_read(p);
        }
        if let Some(p) = written {
            self.after_write(p);
        }
    }

    fn after_read(&mut self, p: Param) {
        match p.pnu {
            350 => self.sample_unread[0] = false,
            351 => self.sample_unread[1] = false,
            _ => {}
        }
    }

    fn after_write(&mut self, p: Param) {
        match p.pnu {
            // A new method, AZ offset or polarity invalidates the reference (MTR-DCI §3.4).
            1011 => {
                self.referenced = false;
                if self.variant == Variant::MtrDci {
                    let _ = self.store.set(Param::new(1010, 0), 0);
                }
            }
            1010 | 1000 => self.referenced = false,
            204 if p.sub == 3 && self.store.get(p).unwrap_or(0) == 1 => {
                self.clear_diag_memory();
                let _ = self.store.set(p, 0);
            }
            _ => {}
        }
    }

    /// The parameter address of a simple variable (sub-index 0 on the MTR-DCI, 1 elsewhere).
    fn var(&self, pnu: u16) -> Param {
        Param::new(
            pnu,
            if self.variant == Variant::MtrDci {
                0
            } else {
                1
            },
        )
    }

    fn pget(&self, pnu: u16) -> i64 {
        self.store.get(self.var(pnu)).unwrap_or(0)
    }

    fn pget2(&self, pnu: u16, sub: u8) -> i64 {
        self.store.get(Param::new(pnu, sub)).unwrap_or(0)
    }

    fn mtr(&self) -> bool {
        self.variant == Variant::MtrDci
    }

    /// Software end positions in PZ coordinates (PNU 501 is relative to AZ, positions to PZ =
    /// AZ + PNU 500); `None` when both are 0 (off) or not referenced.
    fn soft_limits(&self) -> Option<(i64, i64)> {
        let (lo, hi) = (self.pget2(501, 1), self.pget2(501, 2));
        if (lo == 0 && hi == 0) || !self.referenced {
            return None;
        }
        let pz = self.pget(500);
        Some((lo - pz, hi - pz))
    }

    fn limit_check(&self, target: i64) -> Result<(), FaultKind> {
        match self.soft_limits() {
            Some((lo, _)) if target < lo => Err(FaultKind::TargetOutOfLimit { positive: false }),
            Some((_, hi)) if target > hi => Err(FaultKind::TargetOutOfLimit { positive: true }),
            _ => Ok(()),
        }
    }

    fn force_base_ma(&self) -> i64 {
        if self.mtr() {
            self.pget(1035)
        } else {
            self.pget(555)
        }
        .max(1)
    }

    /// The task a START would take over now, or the device's reason to refuse it.
    fn prepare(&self, image: Option<OutputImage>) -> Result<Prepared, FaultKind> {
        let Some(image) = image else {
            return Err(FaultKind::InvalidSetpoint);
        };
        let max_v = clamp_u32(self.pget(502)).max(1);
        let max_a = clamp_u32(self.pget(503)).max(1);
        let actual = self.axis.status().position;
        match image.payload {
            OutputPayload::Record { record: 0 } => Ok(Prepared {
                job: Job::Homing,
                record: None,
                delay: Duration::ZERO,
                start_condition: StartCondition::Ignore,
                relative: false,
            }),
            OutputPayload::Record { record } => {
                let r = Record::load(&self.store, self.variant, record).map_err(|e| match e {
                    RecordError::OutOfRange { .. } => FaultKind::RecordNumber,
                    _ => FaultKind::InvalidRecord,
                })?;
                let job = self.record_job(&r, actual, max_v, max_a)?;
                Ok(Prepared {
                    job,
                    record: Some(r),
                    delay: Duration::from_millis(r.delay_ms),
                    start_condition: r.start_condition,
                    relative: r.rcb1.relative,
                })
            }
            OutputPayload::Direct(sp) => {
                let job = self.direct_job(sp.cdir, sp.value1, sp.value2, actual, max_v, max_a)?;
                let (delay, sc) = if self.mtr() {
                    // Digest 000 E7: a START while moving retargets.
                    (Duration::ZERO, StartCondition::Interrupt)
                } else {
                    (
                        ms(self.pget(582)),
                        StartCondition::from_bits(self.pget(583) as u8),
                    )
                };
                Ok(Prepared {
                    job,
                    record: None,
                    delay,
                    start_condition: sc,
                    relative: sp.cdir.abs,
                })
            }
        }
    }

    fn record_job(
        &self,
        r: &Record,
        actual: i64,
        max_v: u32,
        max_a: u32,
    ) -> Result<Job, FaultKind> {
        let stroke = |limit: i64| {
            if r.rcb1.xlim_off || limit == 0 {
                None
            } else {
                Some(clamp_u32(limit.abs()))
            }
        };
        match r.rcb1.com {
            ControlMode::Position => {
                let target = if r.rcb1.relative {
                    let base = if r.rcb1.rel_to_actual {
                        actual
                    } else {
                        self.last_nominal
                    };
                    base.saturating_add(r.target)
                } else {
                    r.target
                };
                self.limit_check(target)?;
                let acc = clamp_u32(r.acceleration);
                let acc = if acc == 0 { max_a } else { acc };
                let dec = clamp_u32(r.deceleration);
                Ok(Job::Position {
                    target,
                    profile: Profile {
                        velocity: clamp_u32(r.velocity).min(max_v),
                        acceleration: acc,
                        deceleration: if dec == 0 { acc } else { dec },
                    },
                })
            }
            ControlMode::Speed => {
                let v = if r.speed_setpoint != 0 {
                    r.speed_setpoint
                } else {
                    r.final_speed
                };
                let acc = clamp_u32(r.acceleration);
                Ok(Job::Speed {
                    velocity: v.clamp(-i64::from(max_v), i64::from(max_v)),
                    acceleration: if acc == 0 { max_a } else { acc },
                    stroke: stroke(r.stroke_limit),
                })
            }
            ControlMode::Force => {
                let base = self.force_base_ma();
                Ok(Job::Force {
                    current_ma: (r.force_setpoint * base / 1000) as i32,
                    speed_limit: clamp_u32(r.velocity).min(max_v),
                    stroke: stroke(r.stroke_limit),
                    window_ma: clamp_u32(self.pget(552) * base / 1000),
                    settle: ms(self.pget(1023)),
                })
            }
            ControlMode::Reserved => Err(FaultKind::InvalidRecord),
        }
    }

    fn direct_job(
        &self,
        cdir: Cdir,
        value1: u8,
        value2: i32,
        actual: i64,
        max_v: u32,
        max_a: u32,
    ) -> Result<Job, FaultKind> {
        if !self.variant.supports(cdir.com) {
            return Err(FaultKind::InvalidSetpoint);
        }
        let mtr = self.mtr();
        let base_v = if mtr {
            max_v
        } else {
            clamp_u32(self.pget(540))
        };
        let stroke = |pnu: u16| {
            let l = self.pget(pnu);
            if cdir.xlim || l == 0 {
                None
            } else {
                Some(clamp_u32(l.abs()))
            }
        };
        match cdir.com {
            ControlMode::Position => {
                let v = match self.direct_profile.velocity {
                    Some(v) if mtr => v.min(max_v),
                    _ => percent_of(base_v, value1).min(max_v),
                };
                if v == 0 {
                    return Err(FaultKind::InvalidSetpoint);
                }
                let target = if cdir.abs {
                    let base = if !mtr && self.pget(524) & 1 == 1 {
                        actual
                    } else {
                        self.last_nominal
                    };
                    base.saturating_add(i64::from(value2))
                } else {
                    i64::from(value2)
                };
                self.limit_check(target)?;
                let acc = clamp_u32(self.pget(541));
                let acc = if acc == 0 { max_a } else { acc };
                let acc = match self.direct_profile.acceleration {
                    Some(r) if mtr && r > 0 => r.min(max_a),
                    _ => acc,
                };
                let dec = if mtr {
                    acc
                } else {
                    match clamp_u32(self.pget(542)) {
                        0 => acc,
                        d => d,
                    }
                };
                Ok(Job::Position {
                    target,
                    profile: Profile {
                        velocity: v,
                        acceleration: acc,
                        deceleration: dec,
                    },
                })
            }
            ControlMode::Speed => {
                let acc = percent_of(clamp_u32(self.pget(560)), value1);
                if acc == 0 {
                    return Err(FaultKind::InvalidSetpoint);
                }
                Ok(Job::Speed {
                    velocity: i64::from(value2).clamp(-i64::from(max_v), i64::from(max_v)),
                    acceleration: acc,
                    stroke: stroke(566),
                })
            }
            ControlMode::Force => {
                let base = self.force_base_ma();
                let current = force_to_milliamps(self.variant, value2, clamp_u32(base));
                let (speed_limit, settle) = if mtr {
                    // E18: PNU 554 is the limit; a non-zero byte 4 narrows it.
                    let l = clamp_u32(self.pget(554));
                    let l = if value1 != 0 {
                        l.min(percent_of(max_v, value1))
                    } else {
                        l
                    };
                    (l, ms(self.pget(553)))
                } else {
                    let l = percent_of(base_v, value1);
                    if l == 0 {
                        return Err(FaultKind::InvalidSetpoint);
                    }
                    (l, ms(self.pget(1023)))
                };
                Ok(Job::Force {
                    current_ma: current.clamp(i32::MIN as i64, i32::MAX as i64) as i32,
                    speed_limit: speed_limit.min(max_v),
                    stroke: stroke(510),
                    window_ma: clamp_u32(self.pget(552) * base / 1000),
                    settle,
                })
            }
            ControlMode::Reserved => Err(FaultKind::InvalidSetpoint),
        }
    }

    /// The monitors, once per cycle before the state machine: faults from the axis and the
    /// injections, following error, standstill, stroke and software limits.
    fn monitor(&mut self, t: Instant) {
        let st = *self.axis.status();
        // Injected conditions.
        for (i, kind) in [
            (0, FaultKind::LoadVoltage),
            (1, FaultKind::OverTemperature),
            (2, FaultKind::I2t),
            (4, FaultKind::MotorStop),
            (5, FaultKind::Hardware),
            (6, FaultKind::Sto),
            (7, FaultKind::LifeGuarding),
        ] {
            if self.injected[i] && !self.is_active(kind) {
                self.raise(kind, t);
            }
        }
        // Axis flags: limit switches (with the stop reaction on) and the force stroke limit.
        if st.faults.contains(Faults::STROKE_LIMIT) {
            self.xlim = true;
        }
        if st.faults.contains(Faults::LIMIT_POSITIVE) {
            self.raise(FaultKind::SoftwareLimit { positive: true }, t);
        }
        if st.faults.contains(Faults::LIMIT_NEGATIVE) {
            self.raise(FaultKind::SoftwareLimit { positive: false }, t);
        }
        if st.faults.any() {
            self.axis.clear_faults();
        }
        // Speed task: the drive's own stroke monitoring (PNU 427 / 566).
        if let Activity::Task {
            job: Job::Speed {
                stroke: Some(limit),
                ..
            },
            start_position,
            begun: true,
            ..
        } = self.activity
            && !self.xlim
            && st.position.abs_diff(start_position) >= u64::from(limit)
        {
            self.xlim = true;
            self.axis.quick_stop();
        }
        // Speed/force task at a software end position.
        if let (
            Some((lo, hi)),
            Activity::Task {
                job, begun: true, ..
            },
        ) = (self.soft_limits(), self.activity)
            && matches!(job, Job::Speed { .. } | Job::Force { .. })
            && !self.xlim
            && ((st.position <= lo && st.setpoint_velocity < 0)
                || (st.position >= hi && st.setpoint_velocity > 0))
        {
            let positive = st.position >= hi;
            self.axis.quick_stop();
            self.xlim = true;
            if !self.mtr() {
                self.raise(FaultKind::SoftwareLimit { positive }, t);
            }
        }
        // Following error with the context's window and delay.
        let window = self.fe_window();
        let over = window > 0
            && self.axis.is_enabled()
            && st.following_error.unsigned_abs() > u64::from(window);
        let delay = if self.mtr() {
            Duration::ZERO
        } else {
            ms(self.pget(1045))
        };
        let outside = self.fe_timer.update(over, t);
        if over && outside >= delay {
            if !self.dev {
                self.dev = true;
                self.raise(FaultKind::FollowingError, t);
            }
        } else if !over {
            self.dev = false;
        }
        // Standstill monitoring after MC (window 0 = off).
        let sw = self.pget(1042);
        if self.still_armed && sw > 0 {
            let outside = st.position.abs_diff(st.setpoint) > sw.unsigned_abs();
            let time = self.still_timer.update(outside, t);
            if outside && time >= ms(self.pget(1043)) && !self.still {
                self.still = true;
                self.raise(FaultKind::Standstill, t);
            } else if !outside && self.still {
                self.still = false;
                self.clear_kind(FaultKind::Standstill, t);
            }
        }
        // Homing finished or failed.
        if let Activity::Homing(h) = self.activity {
            match h.state() {
                HomingState::Done { .. } => {
                    self.referenced = true;
                    self.last_nominal = self.axis.status().position;
                }
                HomingState::Failed(_) => self.raise(FaultKind::HomingError, t),
                HomingState::Running => {}
            }
        }
    }

    fn fe_window(&self) -> u32 {
        let fallback = self.cfg.following_error_window;
        if self.mtr() {
            return fallback;
        }
        let w = match (&self.activity, &self.chain) {
            (Activity::Jog { .. }, _) => self.pget(538),
            (Activity::Task { .. }, Some(c)) if c.record().max_deviation > 0 => {
                c.record().max_deviation
            }
            (Activity::Task { .. }, None) => self.pget(549),
            _ => i64::from(fallback),
        };
        clamp_u32(w)
    }

    /// Whether the running task's own motion-complete condition holds (window for the
    /// settling time, homing done, standstill after a stop).
    fn own_mc(&mut self, t: Instant) -> bool {
        let st = *self.axis.status();
        match self.activity {
            Activity::Idle | Activity::Jog { .. } => st.standstill,
            Activity::Homing(h) => !matches!(h.state(), HomingState::Running),
            Activity::Task { begun: false, .. } => false,
            Activity::Task { job, .. } => {
                if self.xlim {
                    return st.standstill;
                }
                let (inside, settle) = match job {
                    Job::Position { target, .. } => (
                        st.generator_done
                            && self.axis.in_window(target, clamp_u32(self.pget(1022))),
                        ms(self.pget(1023)),
                    ),
                    Job::Speed { velocity, .. } => (
                        st.velocity.abs_diff(velocity) <= clamp_u32(self.pget(561)).into(),
                        ms(self.pget(1023)),
                    ),
                    Job::Force {
                        current_ma,
                        window_ma,
                        settle,
                        ..
                    } => (
                        i64::from(st.current_ma).abs_diff(i64::from(current_ma))
                            <= u64::from(window_ma),
                        settle,
                    ),
                    Job::Homing => (false, Duration::ZERO),
                };
                self.mc_timer.update(inside, t) >= settle && inside
            }
        }
    }

    fn conditions(&mut self, t: Instant, image: Option<OutputImage>) -> Conditions {
        let st = *self.axis.status();
        // Record 0 (homing) started by START runs as a task: its MC is the homing's.
        let own = self.own_mc(t);
        let mut motion_complete = own;
        let mut chain_continues = false;
        self.follow = None;
        let positioning = matches!(
            self.machine.state,
            State::OperationEnabled(Sub::Positioning)
        );
        let sample = Sample {
            position: st.position,
            velocity: st.velocity,
            force_permille: i64::from(st.current_ma) * 1000 / self.force_base_ma(),
            elapsed_ms: t.saturating_duration_since(self.task_started).as_millis() as i64,
        };
        if positioning && let Some(chain) = self.chain.as_mut() {
            match chain.evaluate(self.variant, own, sample, t) {
                Verdict::Running => motion_complete = false,
                Verdict::Next(n) => {
                    motion_complete = true;
                    chain_continues = true;
                    self.follow = Some(Follow::Record(n));
                }
                Verdict::End { .. } => motion_complete = true,
            }
        } else if let Some(chain) = self.chain.as_mut() {
            // Halted or after the end: PNU 312 keeps following the values.
            chain.observe(sample, t);
        } else {
            self.direct_cmp.update(&sample, t);
        }
        if positioning && own && self.follow.is_none() && self.queued.is_some() {
            chain_continues = true;
            self.follow = Some(Follow::Queued);
        }
        let referenced = self.referenced
            || matches!(
                image.map(|i| i.payload),
                Some(OutputPayload::Record { record: 0 })
            );
        let start_condition = match self.prepared {
            Some(Ok(p)) => p.start_condition,
            _ => StartCondition::Ignore,
        };
        Conditions {
            new_fault: self.new_fault.take(),
            fault_cause_present: self.fault_cause_present(),
            reaction_done: st.standstill || (!self.axis.is_enabled() && st.velocity == 0),
            load_voltage: !self.injected[0],
            fieldbus_control: self.store.fieldbus_control,
            enable_permitted: !self.injected[6] && (self.mtr() || self.pget(280) & 0b11 == 0b11),
            referenced,
            motion_complete,
            task_valid: matches!(self.prepared, Some(Ok(_))),
            chain_continues,
            start_condition,
            task_mode: self.task_mode,
        }
    }

    fn apply(&mut self, was: State, a: &Actions, image: Option<OutputImage>, t: Instant) {
        if let Some(r) = a.refusal {
            let kind = match (r, self.prepared) {
                (Refusal::NotReferenced, _) => FaultKind::NotReferenced,
                (Refusal::SimultaneousStarts, _) => FaultKind::TwoEdges,
                (Refusal::InvalidTask, Some(Err(k))) => k,
                (Refusal::InvalidTask, _) => FaultKind::InvalidRecord,
            };
            self.raise(kind, t);
        }
        if a.teach_capture {
            self.teach(image, t);
        }
        if a.acknowledge {
            self.acknowledge(was, t);
        }
        if a.transition == Some(Transition::T11) {
            // EMCA: an EMCY also on a refused acknowledge.
            if self.variant == Variant::Emca
                && let Some(top) = self.top_fault()
            {
                self.push_emcy(Self::emcy_of(&top));
            }
        }
        if a.transition == Some(Transition::T8) && self.machine.fault_class == FaultClass::Serious {
            self.axis.disable();
        }
        let Some(cmd) = a.command else {
            if matches!(a.transition, Some(Transition::TA2)) {
                self.finish_task();
            }
            if matches!(a.transition, Some(Transition::TA8)) {
                self.activity = Activity::Idle;
                self.still_armed = true;
            }
            return;
        };
        match cmd {
            Command::Enable => {
                self.disable_when_still = false;
                if self.axis.enable().is_err() {
                    self.raise(FaultKind::LoadVoltage, t);
                }
            }
            Command::Disable => {
                self.cancel();
                self.axis.quick_stop();
                self.disable_when_still = true;
            }
            Command::QuickStop | Command::FaultReaction => {
                self.cancel();
                self.axis.quick_stop();
            }
            Command::StartTask => {
                if let Some(Ok(p)) = self.prepared {
                    self.start(p, t, true);
                }
            }
            Command::QueueTask => {
                if let Some(Ok(p)) = self.prepared {
                    self.queued = Some(p);
                }
            }
            Command::NextRecord => match self.follow.take() {
                Some(Follow::Queued) => {
                    if let Some(p) = self.queued.take() {
                        self.start(p, t, true);
                    }
                }
                Some(Follow::Record(n)) => self.next_record(n, t),
                None => {}
            },
            Command::Halt => match self.activity {
                Activity::Task {
                    job: Job::Position { .. },
                    ..
                } => {
                    self.axis.hold();
                    if let Activity::Task { halted, .. } = &mut self.activity {
                        *halted = true;
                    }
                }
                Activity::Homing(_) => {
                    self.axis.hold();
                    self.activity = Activity::Idle;
                    if self.mtr() {
                        // MTR-DCI: an aborted run is a homing error; the old reference stays.
                        self.raise(FaultKind::HomingError, t);
                    }
                }
                _ => {
                    self.axis.hold();
                    self.finish_task();
                }
            },
            Command::Resume => {
                if let Activity::Task {
                    job, halted: true, ..
                } = self.activity
                {
                    if let Activity::Task { halted, .. } = &mut self.activity {
                        *halted = false;
                    }
                    self.mc_timer.reset();
                    self.command_job(job);
                }
            }
            Command::Clear => {
                self.cancel();
                self.last_nominal = self.axis.status().setpoint;
            }
            Command::StartHoming => self.start_homing(t),
            Command::StartJog(dir) => {
                self.cancel();
                self.still_armed = false;
                self.activity = Activity::Jog {
                    dir,
                    since: t,
                    fast: false,
                };
                self.command_jog(dir, false);
            }
            Command::StopJog => {
                self.axis.hold();
                self.activity = Activity::Idle;
                self.still_armed = true;
                self.last_nominal = self.axis.status().setpoint;
            }
        }
    }

    /// Drops the task, the chain and the queue (STOP, disable, fault, CLEAR).
    fn cancel(&mut self) {
        self.activity = Activity::Idle;
        self.chain = None;
        self.queued = None;
        self.follow = None;
        self.still_armed = false;
        self.task_mode = ControlMode::Position;
    }

    /// TA2: the task is complete; standstill monitoring arms for position tasks.
    fn finish_task(&mut self) {
        match self.activity {
            Activity::Task { job, .. } => {
                self.still_armed = matches!(job, Job::Position { .. });
                self.activity = Activity::Idle;
            }
            Activity::Homing(_) => {
                self.still_armed = true;
                self.activity = Activity::Idle;
            }
            _ => {}
        }
        if !self.xlim && matches!(self.task_mode, ControlMode::Force | ControlMode::Speed) {
            // Force and speed control go on after MC (MTR-DCI §3.7, EMCA §2.5): keep the
            // mode echo; a new task or STOP ends them.
            return;
        }
        self.task_mode = ControlMode::Position;
    }

    fn start(&mut self, p: Prepared, t: Instant, first: bool) {
        if let Job::Homing = p.job {
            self.record_number = 0;
            self.start_homing(t);
            return;
        }
        self.still_armed = false;
        self.still = false;
        self.clear_kind(FaultKind::Standstill, t);
        self.xlim = false;
        self.mc_timer.reset();
        self.task_started = t;
        if let Some(r) = p.record {
            self.record_number = r.number;
            self.chain = Some(if first {
                Chain::start(r, t)
            } else {
                match self.chain {
                    Some(mut c) => {
                        c.advance(r, t);
                        c
                    }
                    None => Chain::start(r, t),
                }
            });
        } else {
            self.chain = None;
            self.direct_cmp = ComparatorSet::new(ComparatorParams::from_pnus(DIRECT_BASE, |pnu| {
                self.store.get(Param::new(pnu, 1)).ok()
            }));
        }
        self.record_relative = p.relative;
        self.task_mode = p.job.mode();
        if let Job::Position { target, .. } = p.job {
            self.last_nominal = target;
        }
        let begun = p.delay.is_zero();
        self.activity = Activity::Task {
            job: p.job,
            begin: t + p.delay,
            begun,
            start_position: self.axis.status().position,
            halted: false,
        };
        if begun {
            self.command_job(p.job);
        } else if matches!(
            self.axis.status().mode,
            axis::AxisMotion::Position | axis::AxisMotion::Velocity
        ) {
            // Waiting for the start delay: the previous motion is stopped first.
            self.axis.hold();
        }
    }

    fn next_record(&mut self, n: u8, t: Instant) {
        let mc_pulse = self.chain.map(|c| c.record().mc_in_chain).unwrap_or(false);
        let actual = self.axis.status().position;
        let max_v = clamp_u32(self.pget(502)).max(1);
        let max_a = clamp_u32(self.pget(503)).max(1);
        let r = Record::load(&self.store, self.variant, n).map_err(|e| match e {
            RecordError::OutOfRange { .. } => FaultKind::RecordNumber,
            _ => FaultKind::InvalidRecord,
        });
        let job = r.and_then(|r| self.record_job(&r, actual, max_v, max_a).map(|j| (r, j)));
        match job {
            Ok((r, job)) => {
                self.mc_pulse = mc_pulse;
                let p = Prepared {
                    job,
                    record: Some(r),
                    delay: Duration::from_millis(r.delay_ms),
                    start_condition: r.start_condition,
                    relative: r.rcb1.relative,
                };
                self.start(p, t, false);
            }
            Err(k) => self.raise(k, t),
        }
    }

    fn command_job(&mut self, job: Job) {
        let r = match job {
            Job::Position { target, profile } => self.axis.move_to(target, profile),
            Job::Speed {
                velocity,
                acceleration,
                ..
            } => {
                let dec = clamp_u32(self.pget(1029)).max(acceleration);
                self.axis.run_velocity(
                    velocity.clamp(i32::MIN as i64, i32::MAX as i64) as i32,
                    acceleration,
                    dec,
                )
            }
            Job::Force {
                current_ma,
                speed_limit,
                stroke,
                ..
            } => self.axis.force(ForceCommand {
                current_ma,
                speed_limit,
                acceleration: self.cfg.axis.max_acceleration,
                stroke_limit: stroke,
            }),
            Job::Homing => Ok(()),
        };
        if r.is_err() {
            // The task cannot run on this axis (power stage off or a zero profile value).
            self.activity = Activity::Idle;
        }
    }

    fn jog_speeds(&self) -> (u32, u32, u32, u32) {
        if self.mtr() {
            // Phase 1 is unspecified (E19): 10 % of phase 2; brake with the max deceleration.
            let fast = clamp_u32(self.pget(531));
            let acc = clamp_u32(self.pget(532)).max(1);
            (fast / 10, fast, acc, clamp_u32(self.pget(503)).max(acc))
        } else {
            let acc = clamp_u32(self.pget(532)).max(1);
            (
                clamp_u32(self.pget(530)),
                clamp_u32(self.pget(531)),
                acc,
                acc,
            )
        }
    }

    fn command_jog(&mut self, dir: JogDir, fast: bool) {
        let (slow_v, fast_v, acc, dec) = self.jog_speeds();
        let v = if fast { fast_v } else { slow_v }.max(1);
        let r = match self.soft_limits() {
            // Referenced: the jog stops at the software end position without passing it.
            Some((lo, hi)) => self.axis.move_to(
                if dir == JogDir::Positive { hi } else { lo },
                Profile {
                    velocity: v,
                    acceleration: acc,
                    deceleration: dec,
                },
            ),
            None => {
                let s = if dir == JogDir::Positive { 1 } else { -1 };
                self.axis
                    .run_velocity(v.min(i32::MAX as u32) as i32 * s, acc, dec)
            }
        };
        if r.is_err() {
            self.activity = Activity::Idle;
        }
    }

    fn homing_params(&self) -> HomingParams {
        let mtr = self.mtr();
        let base = self.force_base_ma();
        let (search, travel, crawl, acc, current, stop_time) = if mtr {
            let s = clamp_u32(self.pget2(1012, 1)).max(1);
            (
                s,
                clamp_u32(self.pget2(1012, 2)).max(1),
                (s / 4).max(1),
                clamp_u32(self.pget(503)).max(1),
                clamp_u32(self.pget(1015) * base / 100),
                self.cfg.homing_stop_time,
            )
        } else {
            (
                clamp_u32(self.pget2(1012, 1)).max(1),
                clamp_u32(self.pget2(1012, 2)).max(1),
                clamp_u32(self.pget2(1012, 3)).max(1),
                clamp_u32(self.pget(1013)).max(1),
                clamp_u32(self.pget(1015) * base / 1000),
                ms(self.pget(1017)),
            )
        };
        HomingParams {
            search_velocity: search,
            crawl_velocity: crawl,
            travel_velocity: travel,
            acceleration: acc,
            offset: self.pget(1010),
            travel_to_offset: true,
            // AZ reads 0 - PZ offset (MTR-DCI §3.4 step 3).
            home_position: -self.pget(500),
            stop_current_ma: current.max(1),
            stop_time,
            max_search: None,
        }
    }

    fn start_homing(&mut self, t: Instant) {
        self.cancel();
        self.xlim = false;
        self.task_started = t;
        let method = self.pget(1011) as i8;
        let supported = match self.variant {
            Variant::MtrDci => matches!(method, 27 | 23 | -17 | -18),
            Variant::CmmoSt => matches!(method, -35 | -17 | -18 | 23 | 27 | 11),
            Variant::Emca => true,
        };
        match HomingMethod::from_number(method).filter(|_| supported) {
            Some(m) => {
                let mut h = Homing::new(m, self.homing_params());
                h.update(&mut self.axis);
                self.activity = Activity::Homing(h);
            }
            None => {
                self.raise(FaultKind::HomingMethod, t);
            }
        }
    }

    fn teach(&mut self, image: Option<OutputImage>, t: Instant) {
        let value = self.axis.status().position;
        let target = self.pget(520);
        let record = match image.map(|i| i.payload) {
            Some(OutputPayload::Record { record }) => record,
            _ if self.mtr() => self.pget(400) as u8,
            _ => self.pget2(400, 1) as u8,
        };
        let rec_sub = record_subindex(self.variant, record);
        let param = match target {
            1 | 6 | 7 => {
                let Some(sub) = rec_sub else {
                    self.raise(FaultKind::TeachFailed, t);
                    return;
                };
                if !self.mtr() {
                    // Only absolute position records can be taught (warning 40h).
                    let rcb1 = Rcb1::from_byte(self.pget2(401, sub) as u8, self.variant);
                    if target == 1 && (rcb1.relative || rcb1.com != ControlMode::Position) {
                        self.raise(FaultKind::TeachFailed, t);
                        return;
                    }
                }
                let pnu = match target {
                    1 => 404,
                    6 => 430,
                    _ => 431,
                };
                Param::new(pnu, sub)
            }
            2 => self.var(1010),
            3 => self.var(500),
            4 => Param::new(501, 1),
            _ => Param::new(501, 2),
        };
        let _ = self.store.set(param, value);
    }

    // ---- diagnosis -------------------------------------------------------------------------

    fn is_active(&self, kind: FaultKind) -> bool {
        self.active.iter().any(|a| a.kind == kind)
    }

    fn top_fault(&self) -> Option<ActiveDiag> {
        let faults = || {
            self.active
                .iter()
                .filter(|a| a.info.severity == Severity::Fault)
        };
        faults()
            .find(|a| a.info.serious)
            .or_else(|| faults().next())
            .copied()
    }

    fn emcy_of(a: &ActiveDiag) -> Emcy {
        Emcy {
            code: a.info.emcy.unwrap_or(0x1000),
            register: a.info.register | 1,
            number: a.info.number,
        }
    }

    fn push_emcy(&mut self, e: Emcy) {
        if self.emcy.is_full() {
            self.emcy.pop_front();
            self.emcy_overflows += 1;
        }
        let _ = self.emcy.push_back(e);
    }

    /// Raises a fault or warning (once while active); faults go to the state machine (T7) at
    /// the next cycle and send an EMCY.
    fn raise(&mut self, kind: FaultKind, t: Instant) {
        let Some(info) = kind.info(self.variant) else {
            return;
        };
        if self.is_active(kind) {
            return;
        }
        let a = ActiveDiag {
            kind,
            info,
            since: t,
        };
        if self.active.push(a).is_err() {
            // Full: the oldest warning makes room; faults are never dropped silently.
            if let Some(i) = self
                .active
                .iter()
                .position(|x| x.info.severity == Severity::Warning)
            {
                self.active.remove(i);
                let _ = self.active.push(a);
            }
        }
        // Event 1 = incoming fault (MTR-DCI: any message), 5 = warning (EMCA/CMMO-ST).
        let event = if info.severity == Severity::Warning && !self.mtr() {
            5
        } else {
            1
        };
        self.log_diag(event, info.number, t);
        if info.severity == Severity::Fault {
            let class = if info.serious {
                FaultClass::Serious
            } else {
                FaultClass::Simple
            };
            self.new_fault = Some(match self.new_fault {
                Some(FaultClass::Serious) => FaultClass::Serious,
                _ => class,
            });
            self.push_emcy(Self::emcy_of(&a));
        }
    }

    fn clear_kind(&mut self, kind: FaultKind, t: Instant) {
        if let Some(i) = self.active.iter().position(|a| a.kind == kind) {
            let a = self.active.remove(i);
            self.log_outgoing(&a, t);
        }
    }

    fn cause_present(&self, kind: FaultKind) -> bool {
        let i = &self.injected;
        match kind {
            FaultKind::LoadVoltage => i[0],
            FaultKind::OverTemperature => i[1],
            FaultKind::I2t => i[2],
            FaultKind::MotorStop => i[4],
            FaultKind::Hardware => i[5],
            FaultKind::Sto => i[6],
            FaultKind::LifeGuarding => i[7],
            _ => false,
        }
    }

    fn fault_cause_present(&self) -> bool {
        self.active.iter().any(|a| {
            a.info.severity == Severity::Fault
                && a.info.needs_cause_gone
                && self.cause_present(a.kind)
        })
    }

    /// RESET (or the MTR-DCI's ENABLE falling edge): in S6 the faults (the machine only
    /// acknowledges when no cause is left), outside S6 the warnings.
    fn acknowledge(&mut self, was: State, t: Instant) {
        let in_fault = matches!(was, State::Fault);
        let mut i = 0;
        let mut cleared_fault = false;
        while i < self.active.len() {
            let a = self.active[i];
            let take = match a.info.severity {
                Severity::Fault => in_fault && !self.cause_present(a.kind),
                // Warnings of a present cause stay (standstill clears by itself).
                Severity::Warning => a.kind != FaultKind::Standstill || !self.still,
            };
            if take {
                self.active.remove(i);
                self.log_outgoing(&a, t);
                cleared_fault |= a.info.severity == Severity::Fault;
            } else {
                i += 1;
            }
        }
        if cleared_fault {
            self.axis.clear_faults();
            self.xlim = false;
            self.dev = false;
            self.fe_timer.reset();
            self.push_emcy(Emcy {
                code: 0,
                register: 0,
                number: 0,
            });
        }
    }

    fn diag_capacity(&self) -> u8 {
        if self.mtr() { 16 } else { 200 }
    }

    fn log_diag(&mut self, event: i64, number: u16, t: Instant) {
        let cap = self.diag_capacity();
        let mtr = self.mtr();
        let last = if mtr { 202 } else { 203 };
        for pnu in 200..=last {
            for sub in (1..cap).rev() {
                let v = self.pget2(pnu, sub);
                let _ = self.store.set(Param::new(pnu, sub + 1), v);
            }
        }
        let ms = (t.as_nanos() / 1_000_000) as i64;
        // MTR-DCI PNU 204/2: 1 = 10 ms resolution (default), 2 = 1 ms.
        let stamp = if mtr && self.pget2(204, 2) != 2 {
            ms / 10
        } else {
            ms
        };
        let _ = self.store.set(Param::new(200, 1), event);
        let _ = self.store.set(Param::new(201, 1), i64::from(number));
        let _ = self.store.set(Param::new(202, 1), stamp);
        if !mtr {
            let _ = self.store.set(Param::new(203, 1), 0);
        }
        let n = (self.pget2(204, 4) + 1).min(i64::from(cap));
        let _ = self.store.set(Param::new(204, 4), n);
    }

    fn log_outgoing(&mut self, a: &ActiveDiag, t: Instant) {
        // MTR-DCI PNU 204/1 = 1: outgoing events (2) are recorded too.
        if self.mtr() && self.pget2(204, 1) == 1 {
            self.log_diag(2, a.info.number, t);
        }
    }

    fn clear_diag_memory(&mut self) {
        let cap = self.diag_capacity();
        let last = if self.mtr() { 202 } else { 203 };
        for pnu in 200..=last {
            for sub in 1..=cap {
                let _ = self.store.set(Param::new(pnu, sub), 0);
            }
        }
        let _ = self.store.set(Param::new(204, 4), 0);
        if !self.mtr() {
            // EMCA/CMMO-ST log the start-up event 3Dh on a clear.
            self.log_diag(7, 0x3D, self.axis.now());
        }
    }

    // ---- outputs ---------------------------------------------------------------------------

    /// Live values into their PNUs, once per cycle.
    fn refresh_live(&mut self) {
        let st = *self.axis.status();
        let mtr = self.mtr();
        let set = |d: &mut FhppDrive, p: Param, v: i64| {
            let _ = d.store.set(p, v);
        };
        set(self, self.var(1040), st.setpoint);
        set(self, self.var(1041), st.position);
        if mtr {
            let bits = self
                .active
                .iter()
                .fold(0i64, |b, a| b | i64::from(a.info.device_bit));
            set(self, Param::new(205, 0), bits);
            set(self, Param::new(400, 0), i64::from(self.record_number));
            return;
        }
        let base = self.force_base_ma();
        let force = i64::from(st.current_ma) * 1000 / base;
        set(self, Param::new(300, 1), st.position);
        set(self, Param::new(300, 2), st.setpoint);
        set(self, Param::new(300, 3), st.following_error);
        set(self, Param::new(301, 1), force);
        set(self, Param::new(310, 1), st.velocity);
        set(self, Param::new(310, 2), st.setpoint_velocity);
        set(self, Param::new(310, 3), st.setpoint_velocity - st.velocity);
        let cmp = match &self.chain {
            Some(c) => c.comparators().status(),
            None => self.direct_cmp.status(),
        };
        set(self, Param::new(312, 1), i64::from(cmp.to_byte()));
        set(self, Param::new(400, 2), i64::from(self.record_number));
        let top = self.top_fault();
        set(
            self,
            Param::new(205, 1),
            top.map_or(0xFFFF, |a| i64::from(a.info.number)),
        );
        let ack = match top {
            None => 0xFF,
            Some(a) if a.info.needs_cause_gone && self.cause_present(a.kind) => 1,
            Some(_) => 2,
        };
        set(self, Param::new(230, 1), ack);
        let mut faults = [0u32; 8];
        let mut warns = [0u32; 8];
        for a in &self.active {
            let n = usize::from(a.info.number);
            let words = if a.info.severity == Severity::Fault {
                &mut faults
            } else {
                &mut warns
            };
            if let Some(w) = words.get_mut(n / 32) {
                *w |= 1 << (n % 32);
            }
        }
        for (i, (f, w)) in faults.iter().zip(warns.iter()).enumerate() {
            set(self, Param::new(220, i as u8 + 1), i64::from(*f));
            set(self, Param::new(221, i as u8 + 1), i64::from(*w));
        }
    }

    fn control_mode_echo(&self) -> ControlMode {
        if self.xlim {
            // After the stroke limit the drive holds position-controlled (Tab. 5/14 7.6).
            return ControlMode::Position;
        }
        self.task_mode
    }

    fn build_input(&self) -> [u8; 8] {
        let st = self.axis.status();
        let v = self.variant;
        let warn = self
            .active
            .iter()
            .any(|a| a.info.severity == Severity::Warning);
        let scon = self
            .machine
            .scon(v, warn, !self.injected[0], !self.store.fieldbus_control);
        let mov = st.velocity.unsigned_abs() >= u64::from(self.cfg.mov_threshold.max(1));
        let mut spos = self
            .machine
            .spos(mov, self.dev, self.still, self.referenced);
        if self.mc_pulse {
            spos.mc = true;
        }
        if v == Variant::Emca && (self.sample_unread[0] || self.sample_unread[1]) {
            spos.teach = true;
        }
        let vlim = st.speed_limited && self.task_mode == ControlMode::Force;
        let com = self.control_mode_echo();
        let payload = match self.machine.opm {
            Opm::Direct => {
                let cdir = Cdir::from_byte(self.control[2]);
                let base = if self.mtr() {
                    self.pget(502)
                } else {
                    self.pget(540)
                };
                let speed = percent_from(clamp_u32(st.velocity.abs()), clamp_u32(base));
                let (value1, value2) = match com {
                    ControlMode::Force => {
                        let f = percent_from(
                            st.current_ma.unsigned_abs(),
                            clamp_u32(self.force_base_ma()),
                        );
                        (f, st.position)
                    }
                    ControlMode::Speed => (0, st.velocity.abs()),
                    _ => (speed, st.position),
                };
                InputPayload::Direct {
                    sdir: Sdir {
                        abs: cdir.abs,
                        com,
                        cont: false,
                        vlim,
                        xlim: self.xlim,
                        fast: false,
                        func: false,
                    },
                    value1,
                    value2: value2.clamp(i32::MIN as i64, i32::MAX as i64) as i32,
                }
            }
            _ => InputPayload::Record {
                record: self.record_number,
                rsb: Rsb {
                    rc1: self.chain.is_some_and(|c| c.rc1()),
                    rcc: self.chain.is_some_and(|c| c.rcc()) && spos.mc,
                    abs: self.record_relative,
                    com,
                    vlim,
                    xlim: self.xlim,
                },
                position: st.position.clamp(i32::MIN as i64, i32::MAX as i64) as i32,
            },
        };
        InputImage {
            scon,
            spos,
            payload,
        }
        .to_bytes(v, self.cfg.byte_order)
    }

    /// Advances a running jog (phase 1 → phase 2) and a delayed task start; called by the
    /// cycle before the monitors.
    fn timers(&mut self, t: Instant) {
        match self.activity {
            Activity::Jog {
                dir,
                since,
                fast: false,
            } if t.saturating_duration_since(since) >= ms(self.pget(534)) => {
                self.activity = Activity::Jog {
                    dir,
                    since,
                    fast: true,
                };
                self.command_jog(dir, true);
            }
            Activity::Task {
                job,
                begin,
                begun: false,
                ..
            } if t >= begin => {
                if let Activity::Task {
                    begun,
                    start_position,
                    ..
                } = &mut self.activity
                {
                    *begun = true;
                    *start_position = self.axis.status().position;
                }
                self.task_started = t;
                self.command_job(job);
            }
            _ => {}
        }
    }
}
