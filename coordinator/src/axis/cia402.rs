//! CiA 402 master side for the TLC5xx (seed 003 §3.1–3.9, §5; digest sections 2 and 8) and
//! the MTR-DCI in its CiA 402 profile (seed 000 §7.8–7.10): one [`Cia402Axis`] per drive, fed
//! the TPDO1 data once per cycle, producing the RPDO1 data, with the codecs of
//! `drivers::cia402` (controlword, statusword, [`next_controlword`], [`PpMaster`]).
//!
//! The process image ([`Layout`]):
//!
//! | layout | RPDO1 (master → drive) | TPDO1 (drive → master) |
//! |---|---|---|
//! | TLC5xx (mapped by the coordinator, 7 bytes) | 6040h controlword, 607Ah target position, 6060h mode | 6041h statusword, 6064h position actual, 6061h mode display |
//! | MTR-DCI (static, 8 bytes) | 6040h, 2032h:01 record, 6060h, 607Ah | 6041h, 2032h:01, 6061h, 6064h |
//!
//! The mode display is mapped so the axis knows when a 6060h change has taken effect (the
//! TLC5xx switches modes only at standstill, p.9-112) before it raises bit 4.
//!
//! What each [`Demand`] puts on the wire (every demand that needs power first steps the state
//! machine toward Operation enabled with [`next_controlword`], bits 4..8 low on the way; in
//! Fault it sends Disable voltage and waits: only `Acknowledge` makes the bit 7 edge):
//!
//! | demand | 6060h | controlword | done when |
//! |---|---|---|---|
//! | `Disable` | kept | Disable voltage (0000h) | Switch on disabled |
//! | `Standstill` | kept | Enable operation (000Fh), bit 4 low | Operation enabled |
//! | `Acknowledge` | kept | in Fault: bit 7 alternating (a rising edge every second cycle) | not in Fault |
//! | `Home` | 6 | once 6061h = 6: bit 4 low, then high and held | bits 12 + 10 (homing attained, target reached) |
//! | `Follow` | 1 (8 with CSP) | PP: bit 4 set-point handshake with bit 5 "change set immediately" and bit 6 absolute; CSP: 607Ah every cycle | `motion_complete` |
//! | `Jog`, `Velocity` | 1 | streamed PP set-points integrated from the speed (the mapping has no 60FFh) | first set-point acknowledged |
//! | `Halt` | kept | bit 8 set | bit 10 (halted at standstill) |
//! | `QuickStop` | kept | Quick stop (0002h) | Quick stop active (or Switch on disabled) and no motion |
//! | `Force`, `DriveRecord`, `Teach` | – | refused: `AxisError::Unsupported` | – |
//!
//! Streaming: a new set-point is requested whenever the handshake is free (bit 12 seen low
//! after the last acknowledge), so as often as the bus latency allows; each is the path's
//! position as many cycles ahead as the last handshake took (at least [`MIN_LEAD_CYCLES`]),
//! with the drive's profile velocity 6081h (set at boot) as its speed. `motion_complete` comes
//! only when the last acknowledged set-point equals the demanded position and bit 10 "target
//! reached" followed that acknowledge.
//!
//! Feedback: position from 6064h (user units; increments with the TLC5xx's default scaling),
//! velocity from the position change per cycle, `homed` after a completed homing (the TLC5xx
//! statusword has no reference bit; the MTR-DCI's bit 15 "homing performed" is used when set).
//! 603Fh is not in the image: `fault_code` stays 0 (the EMCY carries it).

use drivers::cia402::controlword::{Command, Controlword};
use drivers::cia402::homing::HomingStatus;
use drivers::cia402::modes::{OperationMode, PpEvent, PpMaster, PpMasterState, SetPointRequest};
use drivers::cia402::state::{State, next_controlword};
use drivers::cia402::statusword::Statusword;
use drivers::cia402::{DeviceProfile, GENERIC, MTR_DCI, TLC5XX};

use super::{AxisError, AxisState, CyclicMode, Demand, Feedback, IMAGE_BYTES, Image, PointMove};
use crate::profile::fixed_point::div_i128;

/// The fewest cycles a streamed set-point is placed ahead of the path.
pub const MIN_LEAD_CYCLES: u32 = 2;
/// The most cycles a streamed set-point is placed ahead of the path.
pub const MAX_LEAD_CYCLES: u32 = 8;

/// Cycles over which cyclic synchronous velocity corrects a position error: short enough to
/// hold a path, long enough to stay stable behind the two cycles of transport delay.
pub const CSV_CORRECTION_CYCLES: u32 = 8;

/// Images with bit 4 high before a stale "homing completed" is believed.
const HOMING_STALE_IMAGES: u32 = 3;

/// The PDO layout of the drive's cyclic image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Layout {
    /// TLC5xx: the coordinator's 7-byte mapping (`super::TLC_RPDO1` / `super::TLC_TPDO1`).
    Tlc5xx,
    /// MTR-DCI CiA 402 profile: the static 8-byte PDO1 (§7.4).
    MtrDci,
    /// A generic CiA 402 drive commanded in this mode (`super::pdo_mapping_in`): the TLC5xx's
    /// image with the mode's set-point object in place of 607Ah (60FFh for CSV, 6071h as 2
    /// bytes for CST, so its RPDO is 5 bytes).
    Generic(CyclicMode),
}

impl Layout {
    /// The layout of a `kind` drive commanded in CiA 402 (a generic drive in CSP, its
    /// default mode); `None` for a device the coordinator does not command in CiA 402.
    pub const fn of(kind: super::DeviceKind) -> Option<Layout> {
        use super::DeviceKind;
        match kind {
            DeviceKind::Tlc5xx => Some(Layout::Tlc5xx),
            DeviceKind::MtrDci => Some(Layout::MtrDci),
            DeviceKind::Cia402 => Some(Layout::Generic(CyclicMode::Csp)),
            DeviceKind::Emca | DeviceKind::CmmoSt => None,
        }
    }

    /// Bytes of the input image (TPDO1).
    pub const fn rx_len(self) -> usize {
        match self {
            Layout::Tlc5xx | Layout::Generic(_) => 7,
            Layout::MtrDci => 8,
        }
    }
    /// Bytes of the output image (RPDO1).
    pub const fn tx_len(self) -> usize {
        match self {
            Layout::Generic(CyclicMode::Cst) => 5,
            l => l.rx_len(),
        }
    }
    /// How the device implements CiA 402 (bit 6 polarity, change set immediately).
    pub const fn profile(self) -> DeviceProfile {
        match self {
            Layout::Tlc5xx => TLC5XX,
            Layout::MtrDci => MTR_DCI,
            Layout::Generic(_) => GENERIC,
        }
    }
    /// Bytes of the RPDO's set-point (2 for a CST torque, 4 otherwise).
    const fn setpoint_len(self) -> usize {
        match self {
            Layout::Generic(CyclicMode::Cst) => 2,
            _ => 4,
        }
    }
}

/// The drive's TPDO1, decoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Input {
    /// 6041h.
    pub statusword: Statusword,
    /// 6064h position actual value.
    pub position: i32,
    /// 6061h modes of operation display.
    pub mode: i8,
    /// 2032h:01 record number (MTR-DCI only; 0 on the TLC5xx).
    pub record: u8,
}

/// The master's RPDO1.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Output {
    /// 6040h.
    pub controlword: Controlword,
    /// The set-point: 607Ah target position; a generic drive's 60FFh target velocity in CSV,
    /// 6071h target torque (‰, sent as 16 bits) in CST.
    pub target: i32,
    /// 6060h modes of operation.
    pub mode: i8,
    /// 2032h:01 record number (MTR-DCI only; not sent on the TLC5xx).
    pub record: u8,
}

fn le_i32(b: &[u8], at: usize) -> Option<i32> {
    let s = b.get(at..at + 4)?;
    Some(i32::from_le_bytes([s[0], s[1], s[2], s[3]]))
}

fn le_u16(b: &[u8], at: usize) -> Option<u16> {
    let s = b.get(at..at + 2)?;
    Some(u16::from_le_bytes([s[0], s[1]]))
}

fn short(layout: Layout, len: usize) -> AxisError {
    AxisError::Short {
        len,
        need: layout.rx_len(),
    }
}

/// Decodes a TPDO1 of `layout` (little-endian, CiA 301); extra bytes are ignored.
pub fn decode_input(layout: Layout, bytes: &[u8]) -> Result<Input, AxisError> {
    let e = || short(layout, bytes.len());
    let statusword = Statusword(le_u16(bytes, 0).ok_or_else(e)?);
    match layout {
        Layout::Tlc5xx | Layout::Generic(_) => Ok(Input {
            statusword,
            position: le_i32(bytes, 2).ok_or_else(e)?,
            mode: *bytes.get(6).ok_or_else(e)? as i8,
            record: 0,
        }),
        Layout::MtrDci => Ok(Input {
            statusword,
            record: *bytes.get(2).ok_or_else(e)?,
            mode: *bytes.get(3).ok_or_else(e)? as i8,
            position: le_i32(bytes, 4).ok_or_else(e)?,
        }),
    }
}

impl Output {
    /// The RPDO1 data of `layout`.
    pub fn to_image(&self, layout: Layout) -> Image {
        let mut data = [0u8; IMAGE_BYTES];
        let cw = self.controlword.to_bytes();
        let t = self.target.to_le_bytes();
        data[..2].copy_from_slice(&cw);
        match layout {
            Layout::Tlc5xx | Layout::Generic(_) => {
                let n = layout.setpoint_len();
                // A torque is 16 bits: the axis keeps it within i16 (`clamp_i16`).
                data[2..2 + n].copy_from_slice(&t[..n]);
                data[2 + n] = self.mode as u8;
            }
            Layout::MtrDci => {
                data[2] = self.record;
                data[3] = self.mode as u8;
                data[4..8].copy_from_slice(&t);
            }
        }
        Image {
            data,
            len: layout.tx_len() as u8,
        }
    }

    /// Decodes an RPDO1 of `layout` (what a drive receives).
    pub fn from_bytes(layout: Layout, bytes: &[u8]) -> Result<Output, AxisError> {
        let e = || short(layout, bytes.len());
        let controlword = Controlword(le_u16(bytes, 0).ok_or_else(e)?);
        match layout {
            Layout::Tlc5xx
            | Layout::Generic(CyclicMode::Pp | CyclicMode::Csp | CyclicMode::Csv) => Ok(Output {
                controlword,
                target: le_i32(bytes, 2).ok_or_else(e)?,
                mode: *bytes.get(6).ok_or_else(e)? as i8,
                record: 0,
            }),
            Layout::Generic(CyclicMode::Cst) => Ok(Output {
                controlword,
                target: i32::from(le_u16(bytes, 2).ok_or_else(e)? as i16),
                mode: *bytes.get(4).ok_or_else(e)? as i8,
                record: 0,
            }),
            Layout::MtrDci => Ok(Output {
                controlword,
                record: *bytes.get(2).ok_or_else(e)?,
                mode: *bytes.get(3).ok_or_else(e)? as i8,
                target: le_i32(bytes, 4).ok_or_else(e)?,
            }),
        }
    }
}

/// Drive settings the axis needs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Cia402Settings {
    /// In cyclic synchronous position: `motion_complete` once the actual position is within
    /// this many units of the final setpoint (the TLC5xx's p_win default is 10).
    pub position_window: u32,
}

impl Default for Cia402Settings {
    fn default() -> Self {
        Cia402Settings {
            position_window: 10,
        }
    }
}

/// Where a demand with a sequence of its own stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Step {
    /// Starting (power and mode being established).
    Start,
    /// Homing: bit 4 low for one image after the mode is active.
    HomeLow,
    /// Homing: bit 4 high; `images` since, `running` once a not-completed status was seen.
    HomeRaised { images: u32, running: bool },
    /// Acknowledge: fault-reset edges are being sent.
    Resetting,
    /// A cyclic synchronous stream is running (the drive takes a set-point every cycle).
    Running,
    /// Carried out.
    Done,
    /// Failed.
    Failed,
}

/// The master side of one CiA 402 drive.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Cia402Axis {
    layout: Layout,
    cyclic: CyclicMode,
    cycle_ns: u32,
    settings: Cia402Settings,
    input: Option<Input>,
    /// The state the last image's statusword shows (checked when it was taken: a pattern
    /// outside the state machine is refused), decoded once per image.
    state: Option<State>,
    feedback: Feedback,
    cw: Controlword,
    target: i32,
    mode: OperationMode,
    demand: Demand,
    step: Step,
    pp: PpMaster,
    /// The set-point of the running request.
    requested: i32,
    /// The set-point the drive acknowledged last.
    acked: Option<i32>,
    /// Bit 10 came after that acknowledge.
    reached: bool,
    /// Cycles since the last request, and the lead they give.
    since_request: u32,
    lead: u32,
    /// Jog/velocity streaming: the integrated position, units × 1e9.
    jog_nano: Option<Wide>,
    homed: bool,
    /// Cycles since the last image arrived.
    gap: u32,
    /// One set-point per move (see [`Cia402Axis::one_set_point_per_move`]): the move the path
    /// runs, as given this cycle.
    point: Option<PointMove>,
    /// The move whose set-point was sent last.
    point_sent: Option<PointMove>,
    /// The drive holds a set-point it acknowledged and has not reached: halted on its way, it
    /// would resume it when the halt bit drops.
    task_open: bool,
    /// The RPDO2 image to send this cycle.
    profile_pdo: Option<[u8; 8]>,
}

/// An `i128` kept as two 64-bit halves: as a field, an `i128` would align the whole axis state
/// to 16 bytes and pad it, and the cycle reads every axis's state each cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
struct Wide([u64; 2]);

impl Wide {
    const fn new(v: i128) -> Wide {
        Wide([v as u64, (v >> 64) as u64])
    }
    const fn get(self) -> i128 {
        ((self.0[1] as i128) << 64) | self.0[0] as i128
    }
}

impl Cia402Axis {
    /// The master side of a drive with `layout`, exchanged every `cycle_ns`; commanded in the
    /// generic layout's mode, otherwise in profile position (see [`Cia402Axis::with_csp`]).
    pub fn new(layout: Layout, cycle_ns: u32) -> Cia402Axis {
        Cia402Axis {
            layout,
            cyclic: match layout {
                Layout::Generic(m) => m,
                _ => CyclicMode::Pp,
            },
            cycle_ns: cycle_ns.max(1),
            settings: Cia402Settings::default(),
            input: None,
            state: None,
            feedback: Feedback::default(),
            cw: Controlword(0),
            target: 0,
            mode: OperationMode::ProfilePosition,
            demand: Demand::Disable,
            step: Step::Start,
            pp: PpMaster::new(layout.profile().abs_rel),
            requested: 0,
            acked: None,
            reached: false,
            since_request: 0,
            lead: MIN_LEAD_CYCLES,
            jog_nano: None,
            homed: false,
            gap: 0,
            point: None,
            point_sent: None,
            task_open: false,
            profile_pdo: None,
        }
    }

    /// Whether `Follow` sends one set-point per move: profile position on a drive without
    /// "change set immediately" (the MTR-DCI, seed 000 §7.9). Such a drive queues a new
    /// set-point behind the running one, so a stream of set-points would stop at each: the axis
    /// sends the move's end once, with its speed and acceleration on RPDO2 (6081h, 6083h) and
    /// controlword bit 15 so that the drive brakes with it too, and the drive runs the move on
    /// its own profile generator (the cycle plans the path as a trapezoid with the same
    /// limits, so the two agree).
    pub fn one_set_point_per_move(&self) -> bool {
        self.cyclic == CyclicMode::Pp && !self.layout.profile().change_set_immediately
    }

    /// The move the path runs this cycle (see [`super::DriveAxis::set_move`]).
    pub fn set_move(&mut self, m: Option<PointMove>) {
        self.point = m;
    }

    /// The RPDO2 image to send this cycle (see [`super::DriveAxis::profile_pdo`]).
    pub fn profile_pdo(&self) -> Option<[u8; 8]> {
        self.profile_pdo
    }

    /// The same axis streaming `Follow` in cyclic synchronous position (mode 8), for a drive
    /// that offers it (neither reference device does).
    pub fn with_csp(mut self) -> Cia402Axis {
        self.cyclic = CyclicMode::Csp;
        self
    }

    /// Replaces the settings (the boot learns them from the drive).
    pub fn set_settings(&mut self, settings: Cia402Settings) {
        *self = self.clone().with_settings(settings);
    }

    /// The same axis with other settings.
    pub fn with_settings(mut self, settings: Cia402Settings) -> Cia402Axis {
        self.settings = settings;
        self
    }

    /// The image layout.
    pub fn layout(&self) -> Layout {
        self.layout
    }

    /// Whether `Follow` uses cyclic synchronous position.
    pub fn csp(&self) -> bool {
        self.cyclic == CyclicMode::Csp
    }

    /// The mode paths, jogs and forces are commanded in.
    pub fn cyclic(&self) -> CyclicMode {
        self.cyclic
    }

    /// What the drive reported last, as the last exchange returned it (kept when an image
    /// could not be decoded).
    pub fn feedback(&self) -> &Feedback {
        &self.feedback
    }

    /// Forgets the drive's state: offline until the next image.
    pub fn reset(&mut self) {
        *self = Cia402Axis {
            cyclic: self.cyclic,
            settings: self.settings,
            ..Cia402Axis::new(self.layout, self.cycle_ns)
        };
    }

    /// One cycle (see [`super::DriveAxis::exchange`]).
    pub fn exchange(
        &mut self,
        input: Option<&[u8]>,
        demand: &Demand,
        out: &mut Image,
    ) -> Result<&Feedback, AxisError> {
        let mut fresh = false;
        self.profile_pdo = None;
        // Cycles since the last image, for the velocity estimate.
        self.gap = self.gap.saturating_add(1);
        if let Some(bytes) = input {
            match decode_input(self.layout, bytes) {
                Ok(i) => match State::from_statusword(i.statusword) {
                    Ok(state) => {
                        self.take_input(i, state);
                        fresh = true;
                    }
                    Err(_) => {
                        self.write_safe(out);
                        return Err(AxisError::Decode("undefined CiA 402 statusword pattern"));
                    }
                },
                Err(e) => {
                    self.write_safe(out);
                    return Err(e);
                }
            }
        }
        if !same_task(&self.demand, demand) {
            self.begin(demand);
        }
        self.demand = *demand;
        if let Err(e) = check(self.cyclic, demand) {
            self.step = Step::Failed;
            self.write_safe(out);
            self.update_feedback();
            return Err(e);
        }
        self.since_request = self.since_request.saturating_add(1);
        self.run(fresh);
        *out = self.output().to_image(self.layout);
        self.update_feedback();
        Ok(&self.feedback)
    }

    fn output(&self) -> Output {
        Output {
            controlword: self.cw,
            target: self.target,
            mode: self.mode.code(),
            record: 0,
        }
    }

    fn take_input(&mut self, i: Input, state: State) {
        let position = i64::from(i.position);
        self.feedback.velocity = match self.input {
            Some(_) => {
                let span = i64::from(self.cycle_ns).saturating_mul(i64::from(self.gap.max(1)));
                (position - self.feedback.position) * 1_000_000_000 / span
            }
            None => 0,
        };
        self.gap = 0;
        self.feedback.position = position;
        if state != State::OperationEnabled {
            // Leaving Operation enabled (quick stop, disable, fault) ends every move.
            self.task_open = false;
        }
        if self.layout == Layout::MtrDci && i.statusword.has(Statusword::MTR_HOMING_PERFORMED) {
            self.homed = true;
        }
        self.input = Some(i);
        self.state = Some(state);
    }

    fn begin(&mut self, demand: &Demand) {
        self.step = Step::Start;
        let streaming = matches!(
            demand,
            Demand::Follow { .. } | Demand::Jog { .. } | Demand::Velocity { .. }
        );
        if !streaming || !matches!(self.demand, Demand::Follow { .. }) {
            // A stream of another kind starts from the actual position.
            self.jog_nano = None;
        }
        if !streaming {
            self.pp.reset();
            self.acked = None;
            self.reached = false;
        }
    }

    /// The safe image: halt (bit 8) with the state command kept, no new set-point.
    fn write_safe(&mut self, out: &mut Image) {
        self.cw = self
            .cw
            .with(Controlword::NEW_SET_POINT, false)
            .with(Controlword::FAULT_RESET, false)
            .with(Controlword::HALT, true);
        *out = self.output().to_image(self.layout);
    }

    fn state(&self) -> Option<State> {
        self.state
    }

    fn sw(&self) -> Statusword {
        self.input.map(|i| i.statusword).unwrap_or(Statusword(0))
    }

    /// Steps toward Operation enabled; `true` once there. On the way the mode bits are low and
    /// a set-point handshake is abandoned.
    fn power(&mut self) -> bool {
        match self.state() {
            Some(State::OperationEnabled) => true,
            Some(State::Fault | State::FaultReactionActive) => {
                // Only `Acknowledge` resets a fault: bit 7 stays low here.
                self.cw = Command::DisableVoltage.controlword();
                self.pp.reset();
                false
            }
            Some(s) => {
                let base = Controlword(self.cw.0 & Controlword::FAULT_RESET);
                self.cw = next_controlword(s, base);
                self.pp.reset();
                false
            }
            None => {
                self.cw = Controlword(0);
                false
            }
        }
    }

    /// Whether the drive shows `self.mode` as active.
    fn mode_active(&self) -> bool {
        self.input.is_some_and(|i| i.mode == self.mode.code())
    }

    fn enable_op() -> Controlword {
        Command::EnableOperation.controlword()
    }

    fn run(&mut self, fresh: bool) {
        let keeps_task = matches!(
            self.demand,
            Demand::Follow { .. }
                | Demand::Halt
                | Demand::QuickStop
                | Demand::Disable
                | Demand::Acknowledge
        );
        if self.task_open && !keeps_task && self.clear_open_task() {
            self.step = Step::Start;
            return;
        }
        match self.demand {
            Demand::Disable => {
                self.cw = Command::DisableVoltage.controlword();
                self.pp.reset();
                if matches!(
                    self.state(),
                    Some(State::SwitchOnDisabled | State::NotReadyToSwitchOn)
                ) {
                    self.step = Step::Done;
                }
            }
            Demand::Standstill => {
                if self.power() {
                    self.cw = Self::enable_op();
                    self.pp.reset();
                    self.step = Step::Done;
                }
            }
            Demand::Acknowledge => match self.state() {
                Some(s @ (State::Fault | State::FaultReactionActive)) => {
                    let base = Controlword(self.cw.0 & Controlword::FAULT_RESET);
                    self.cw = next_controlword(s, base);
                    self.step = Step::Resetting;
                }
                Some(_) => {
                    self.cw = self.cw.with(Controlword::FAULT_RESET, false);
                    self.step = Step::Done;
                }
                None => {}
            },
            Demand::Home => self.home(fresh),
            Demand::Follow { position, velocity } => match self.cyclic {
                CyclicMode::Csp => self.csp_follow(position, velocity),
                CyclicMode::Csv => self.csv_follow(position, velocity),
                // Refused by `check`.
                CyclicMode::Cst => {}
                CyclicMode::Pp if self.one_set_point_per_move() => self.point_follow(fresh),
                CyclicMode::Pp => {
                    self.mode = OperationMode::ProfilePosition;
                    self.stream(fresh, position, velocity, Some(position));
                }
            },
            Demand::Jog { positive, velocity } => {
                let v = if positive {
                    velocity.saturating_abs()
                } else {
                    -velocity.saturating_abs()
                };
                self.jog(fresh, v);
            }
            Demand::Velocity { velocity } => self.jog(fresh, velocity),
            Demand::Force {
                permille,
                velocity_limit,
            } if self.cyclic == CyclicMode::Cst => {
                self.cst_force(permille, velocity_limit);
            }
            Demand::Halt => {
                self.cw = self
                    .cw
                    .with(Controlword::NEW_SET_POINT, false)
                    .with(Controlword::FAULT_RESET, false);
                if self.state() == Some(State::OperationEnabled) {
                    self.cw = self
                        .cw
                        .with(Controlword::HALT, true)
                        .with(Controlword::FAULT_RESET, false);
                    if fresh && self.sw().target_reached() {
                        self.step = Step::Done;
                    }
                }
            }
            Demand::QuickStop => {
                self.cw = Command::QuickStop.controlword();
                self.pp.reset();
                let stopped = matches!(
                    self.state(),
                    Some(State::QuickStopActive | State::SwitchOnDisabled)
                );
                if fresh && stopped && self.feedback.velocity == 0 {
                    self.step = Step::Done;
                }
            }
            // Refused by `check`.
            Demand::Force { .. } | Demand::DriveRecord { .. } | Demand::Teach => {}
        }
    }

    /// Homing: mode 6, bit 4 low then high once 6061h shows 6; done on bits 12 + 10.
    fn home(&mut self, fresh: bool) {
        self.mode = OperationMode::Homing;
        if !self.power() {
            self.step = Step::Start;
            return;
        }
        if !self.mode_active() {
            self.cw = Self::enable_op();
            self.step = Step::Start;
            return;
        }
        let status = HomingStatus::from_statusword(self.sw());
        self.step = match self.step {
            Step::Start => Step::HomeLow,
            Step::HomeLow if fresh => Step::HomeRaised {
                images: 0,
                running: false,
            },
            Step::HomeRaised { images, running } if fresh => {
                let images = images + 1;
                let running = running
                    || !matches!(
                        status,
                        Some(HomingStatus::Completed | HomingStatus::ErrorStopped)
                    );
                let believed = running || images >= HOMING_STALE_IMAGES;
                match status {
                    Some(HomingStatus::Completed) if believed => {
                        self.homed = true;
                        Step::Done
                    }
                    Some(HomingStatus::ErrorStopped | HomingStatus::ErrorMoving) if believed => {
                        Step::Failed
                    }
                    _ => Step::HomeRaised { images, running },
                }
            }
            s => s,
        };
        // Bit 4 stays high after the end: its fall would only matter during a run.
        let start = matches!(
            self.step,
            Step::HomeRaised { .. } | Step::Done | Step::Failed
        );
        self.cw = Self::enable_op().with(Controlword::HOMING_START, start);
    }

    /// `position` moved on by `lead` cycles at `velocity`.
    fn ahead(&self, position: i64, velocity: i64, lead: u32) -> i32 {
        let ns = i128::from(lead) * i128::from(self.cycle_ns);
        let p = i128::from(position) + div_i128(i128::from(velocity) * ns, 1_000_000_000);
        p.clamp(i128::from(i32::MIN), i128::from(i32::MAX)) as i32
    }

    /// Jog and velocity: PP set-points streamed from an integrated position; in CSP that
    /// position every cycle; in CSV the velocity itself.
    fn jog(&mut self, fresh: bool, velocity: i64) {
        if self.cyclic == CyclicMode::Csv {
            self.csv_velocity(velocity);
            if self.step == Step::Start && self.power() && self.mode_active() {
                self.step = Step::Done;
            }
            return;
        }
        self.mode = OperationMode::ProfilePosition;
        let start = self.feedback.position;
        let moving = self.state() == Some(State::OperationEnabled);
        let mut nano = self
            .jog_nano
            .map_or(i128::from(start) * 1_000_000_000, Wide::get);
        if moving {
            nano += i128::from(velocity) * i128::from(self.cycle_ns);
        }
        self.jog_nano = Some(Wide::new(nano));
        let here = div_i128(nano, 1_000_000_000) as i64;
        if self.cyclic == CyclicMode::Csp {
            self.csp_follow(here, velocity);
            self.step = if self.mode_active() && moving {
                Step::Done
            } else {
                Step::Start
            };
            return;
        }
        self.stream(fresh, here, velocity, None);
        if self.acked.is_some() {
            self.step = Step::Done;
        }
    }

    /// The profile-position set-point stream: a new set-point whenever the handshake is free,
    /// `position` placed as many cycles ahead at `velocity` as the last handshake took; `last`
    /// is the path's end to compare for `motion_complete` (`None` for jog).
    fn stream(&mut self, fresh: bool, position: i64, velocity: i64, last: Option<i64>) {
        if !self.pp_ready() {
            self.target = self.ahead(position, velocity, self.lead);
            return;
        }
        self.handshake(fresh);
        let lead = self.since_request.clamp(MIN_LEAD_CYCLES, MAX_LEAD_CYCLES);
        let target = self.ahead(position, velocity, lead);
        if self.pp.state() == PpMasterState::Idle && self.acked != Some(target) {
            let r = SetPointRequest {
                target,
                relative: false,
                immediate: self.layout.profile().change_set_immediately,
            };
            if self.pp.request(r).is_ok() {
                self.lead = lead;
                self.since_request = 0;
                self.requested = target;
                self.reached = false;
            }
        }
        self.target = self.pp.target().unwrap_or(target);
        self.cw = self.pp.controlword(Self::enable_op());
        if let Some(end) = last {
            let arrived = self.pp.state() == PpMasterState::Idle
                && self.acked == Some(clamp_i32(end))
                && self.reached
                && self.sw().target_reached();
            self.step = if arrived { Step::Done } else { Step::Start };
        }
    }

    /// Toward Operation enabled with profile position active: `true` once there. On the way
    /// (bit 4 low, the handshake abandoned) the step starts over.
    fn pp_ready(&mut self) -> bool {
        if self.power() && self.mode_active() {
            return true;
        }
        if self.state() == Some(State::OperationEnabled) {
            self.cw = Self::enable_op();
            self.pp.reset();
        }
        self.step = Step::Start;
        false
    }

    /// The set-point handshake's news in a fresh image: the request acknowledged (`true`), its
    /// target reached since.
    fn handshake(&mut self, fresh: bool) -> bool {
        let mut acknowledged = false;
        if fresh {
            for e in self.pp.handle_statusword(self.sw()) {
                match e {
                    PpEvent::Acknowledged => {
                        self.acked = Some(self.requested);
                        self.reached = false;
                        acknowledged = true;
                    }
                    PpEvent::TargetReached => self.reached = true,
                    PpEvent::Ready => {}
                }
            }
        }
        acknowledged
    }

    /// One set-point per move: the move's end, once, with its profile on RPDO2 and bit 15;
    /// bit 8 while the path holds; done once the drive acknowledged the end and reached it.
    fn point_follow(&mut self, fresh: bool) {
        self.mode = OperationMode::ProfilePosition;
        if !self.pp_ready() {
            return;
        }
        if self.handshake(fresh) {
            self.task_open = true;
        }
        let Some(m) = self.point else {
            // No path: stand where the drive is.
            self.cw = self.point_controlword(false);
            self.step = Step::Start;
            return;
        };
        let end = clamp_i32(m.end);
        let halt = m.halt;
        if self.reached && !halt && self.sw().target_reached() {
            self.task_open = false;
        }
        if (m.velocity == 0 || m.acceleration == 0) && !self.task_open {
            // A group member that does not move: no set-point (a task with v = 0 is not
            // executable on the MTR-DCI, seed 000 §5.6.4), done where it stands.
            self.cw = self.point_controlword(halt);
            self.step = if !halt && self.sw().target_reached() {
                Step::Done
            } else {
                Step::Start
            };
            return;
        }
        let new_move = !self.point_sent.is_some_and(|s| s.same_move(&m));
        if new_move && self.task_open {
            // The drive would queue the new end behind the one it holds: the old one goes
            // first, halted (the path stood still before it changed), then dropped.
            if halt || self.feedback.velocity != 0 || !self.sw().target_reached() {
                self.cw = self.cw.with(Controlword::HALT, true);
            } else {
                self.clear_open_task();
            }
            self.step = Step::Start;
            return;
        }
        if new_move && !halt && self.pp.state() == PpMasterState::Idle {
            let r = SetPointRequest {
                target: end,
                relative: false,
                immediate: false,
            };
            if self.pp.request(r).is_ok() {
                self.requested = end;
                self.acked = None;
                self.reached = false;
                self.point_sent = Some(m);
                // Taken as it arrives, so it is in place when the set-point is applied at the
                // next SYNC.
                self.profile_pdo = Some(m.profile_bytes());
            }
        }
        self.target = self.pp.target().unwrap_or(end);
        self.cw = self.point_controlword(halt);
        let arrived = !halt
            && self.pp.state() == PpMasterState::Idle
            && self.acked == Some(end)
            && self.reached
            && self.sw().target_reached();
        self.step = if arrived { Step::Done } else { Step::Start };
    }

    /// One set-point per move: the handshake's bits, bit 15 (the drive brakes with 6083h),
    /// bit 8 while `halt`.
    fn point_controlword(&self, halt: bool) -> Controlword {
        self.pp
            .controlword(Self::enable_op())
            .with(Controlword::MTR_SYMMETRICAL_RAMP, true)
            .with(Controlword::HALT, halt)
    }

    /// Drops a move the drive holds unfinished (see `task_open`) with a quick stop, which keeps
    /// the power stage on (the drive leaves Operation enabled, which ends every move; the
    /// demand then brings it back, transition 16). `true` while under way.
    fn clear_open_task(&mut self) -> bool {
        if self.state() == Some(State::OperationEnabled) {
            self.cw = Command::QuickStop.controlword();
            self.pp.reset();
            self.point_sent = None;
            return true;
        }
        self.task_open = false;
        false
    }

    /// Cyclic synchronous position: the setpoint every cycle, no handshake.
    fn csp_follow(&mut self, position: i64, velocity: i64) {
        self.target = clamp_i32(position);
        if !self.cyclic_ready(OperationMode::CyclicSyncPosition) {
            return;
        }
        let near =
            self.feedback.position.abs_diff(position) <= u64::from(self.settings.position_window);
        self.step = if velocity == 0 && near {
            Step::Done
        } else {
            Step::Start
        };
    }

    /// A cyclic synchronous mode: asks for `mode`, steps toward Operation enabled; `true` once
    /// the drive is there with the mode active (the controlword then enables operation and the
    /// caller's set-point is taken), `false` while on the way (the step starts over).
    fn cyclic_ready(&mut self, mode: OperationMode) -> bool {
        self.mode = mode;
        if !self.power() || !self.mode_active() {
            if self.state() == Some(State::OperationEnabled) {
                self.cw = Self::enable_op();
            }
            self.step = Step::Start;
            return false;
        }
        self.cw = Self::enable_op();
        true
    }

    /// Cyclic synchronous velocity following a path: the path's velocity plus a correction
    /// of the position error over [`CSV_CORRECTION_CYCLES`], so the position loop closed here
    /// keeps the following error bounded (the drive closes only the velocity loop).
    fn csv_follow(&mut self, position: i64, velocity: i64) {
        let error = i128::from(position) - i128::from(self.feedback.position);
        let span = i128::from(CSV_CORRECTION_CYCLES) * i128::from(self.cycle_ns);
        let correction = div_i128(error * 1_000_000_000, span.max(1));
        let v =
            (i128::from(velocity) + correction).clamp(i128::from(i32::MIN), i128::from(i32::MAX));
        self.csv_velocity(v as i64);
        if self.step == Step::Start {
            return;
        }
        let near =
            self.feedback.position.abs_diff(position) <= u64::from(self.settings.position_window);
        self.step = if velocity == 0 && near {
            Step::Done
        } else {
            Step::Running
        };
    }

    /// Cyclic synchronous velocity: 60FFh every cycle, no handshake.
    fn csv_velocity(&mut self, velocity: i64) {
        // The first set-point the drive takes is a standstill.
        self.target = 0;
        if !self.cyclic_ready(OperationMode::CyclicSyncVelocity) {
            return;
        }
        self.target = clamp_i32(velocity);
        if self.step == Step::Start {
            self.step = Step::Running;
        }
    }

    /// Cyclic synchronous torque: 6071h (‰ of the rated torque) every cycle; no torque that
    /// drives the axis further once it runs at `velocity_limit` (inc/s) in that direction, as
    /// FHPP's force mode limits its speed.
    fn cst_force(&mut self, permille: i32, velocity_limit: i64) {
        self.target = 0;
        if !self.cyclic_ready(OperationMode::CyclicSyncTorque) {
            return;
        }
        let v = self.feedback.velocity;
        let too_fast = v.signum() == i64::from(permille.signum())
            && v.saturating_abs() >= velocity_limit.saturating_abs();
        if !too_fast {
            self.target = permille.clamp(i32::from(i16::MIN), i32::from(i16::MAX));
        }
        self.step = Step::Done;
    }

    fn update_feedback(&mut self) {
        let state = self.state();
        let f = &mut self.feedback;
        f.done = self.step == Step::Done;
        f.failed = self.step == Step::Failed;
        f.homed = self.homed;
        let (Some(i), Some(state)) = (self.input, state) else {
            f.state = AxisState::Offline;
            return;
        };
        let sw = i.statusword;
        f.status = sw.0;
        f.warning = sw.warning();
        f.motion_complete = match self.demand {
            Demand::Follow { .. } | Demand::Home => f.done,
            Demand::Jog { .. } | Demand::Velocity { .. } => false,
            _ => sw.target_reached(),
        };
        let wants_power = !matches!(self.demand, Demand::Disable | Demand::Acknowledge);
        f.state = match state {
            State::Fault | State::FaultReactionActive => AxisState::Fault,
            State::QuickStopActive => AxisState::Stopping,
            State::NotReadyToSwitchOn
            | State::SwitchOnDisabled
            | State::ReadyToSwitchOn
            | State::SwitchedOn => {
                if wants_power {
                    AxisState::Enabling
                } else {
                    AxisState::Disabled
                }
            }
            State::OperationEnabled => match self.demand {
                Demand::Halt if !sw.target_reached() || f.velocity != 0 => AxisState::Stopping,
                Demand::Home if !f.done && !f.failed => AxisState::Homing,
                Demand::Jog { .. } | Demand::Velocity { .. } => AxisState::Moving,
                _ if f.velocity != 0 => AxisState::Moving,
                _ if i.mode == OperationMode::ProfilePosition.code() && !sw.target_reached() => {
                    AxisState::Moving
                }
                _ => AxisState::Ready,
            },
        };
    }
}

/// Refuses what CiA 402 (as mapped here, in `cyclic`) cannot do.
fn check(cyclic: CyclicMode, demand: &Demand) -> Result<(), AxisError> {
    match demand {
        Demand::Force { .. } if cyclic == CyclicMode::Cst => Ok(()),
        Demand::Force { .. } => Err(AxisError::Unsupported(
            "force on a CiA 402 drive outside cyclic synchronous torque",
        )),
        Demand::Follow { .. } | Demand::Jog { .. } | Demand::Velocity { .. }
            if cyclic == CyclicMode::Cst =>
        {
            Err(AxisError::Unsupported(
                "a path, jog or velocity on a cyclic synchronous torque axis",
            ))
        }
        Demand::DriveRecord { .. } => Err(AxisError::Unsupported("drive records in CiA 402")),
        Demand::Teach => Err(AxisError::Unsupported("teach in CiA 402")),
        _ => Ok(()),
    }
}

/// Whether `new` continues `old`'s task: streams stay one stream, jogs one direction.
fn same_task(old: &Demand, new: &Demand) -> bool {
    match (old, new) {
        (Demand::Follow { .. }, Demand::Follow { .. }) => true,
        (Demand::Jog { positive: a, .. }, Demand::Jog { positive: b, .. }) => a == b,
        (Demand::Velocity { .. }, Demand::Velocity { .. }) => true,
        _ => old == new,
    }
}

fn clamp_i32(v: i64) -> i32 {
    v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
}

#[cfg(test)]
mod tests {
    use super::*;

    const CYCLE: u32 = 1_000_000;

    /// A TLC5xx TPDO1: statusword, position, mode display.
    fn tpdo(sw: u16, pos: i32, mode: i8) -> [u8; 7] {
        let s = sw.to_le_bytes();
        let p = pos.to_le_bytes();
        [s[0], s[1], p[0], p[1], p[2], p[3], mode as u8]
    }

    fn ex(a: &mut Cia402Axis, input: &[u8], d: Demand) -> (Output, Feedback) {
        let mut out = Image::default();
        let fb = *a.exchange(Some(input), &d, &mut out).unwrap();
        assert_eq!(usize::from(out.len), a.layout().tx_len());
        (Output::from_bytes(a.layout(), out.bytes()).unwrap(), fb)
    }

    fn axis() -> Cia402Axis {
        Cia402Axis::new(Layout::Tlc5xx, CYCLE)
    }

    /// The MTR-DCI's 8-byte TPDO1: statusword, record, mode display, position.
    fn mtr_tpdo(sw: u16, pos: i32) -> [u8; 8] {
        let s = sw.to_le_bytes();
        let p = pos.to_le_bytes();
        [s[0], s[1], 0, 1, p[0], p[1], p[2], p[3]]
    }

    fn follow() -> Demand {
        Demand::Follow {
            position: 0,
            velocity: 0,
        }
    }

    #[test]
    fn wide_keeps_every_i128() {
        for v in [
            0i128,
            1,
            -1,
            i128::MAX,
            i128::MIN,
            1 << 64,
            -(1 << 64) - 7,
            123_456_789_000_000_000_000,
        ] {
            assert_eq!(Wide::new(v).get(), v);
        }
    }

    #[test]
    fn one_set_point_per_move_on_the_mtr_dci() {
        // Operation enabled: target reached; set-point acknowledged; moving.
        let (ready, acked, moving) = (0x0637, 0x1237, 0x0237);
        let mut a = Cia402Axis::new(Layout::MtrDci, CYCLE);
        assert!(a.one_set_point_per_move());
        assert!(!axis().one_set_point_per_move());
        let m = PointMove {
            end: 5_000,
            velocity: 12_000,
            acceleration: 80_000,
            halt: false,
        };
        a.set_move(Some(m));
        let (o, _) = ex(&mut a, &mtr_tpdo(ready, 0), follow());
        // The end with bit 4, absolute (bit 6 = 0 on the MTR-DCI), bit 15, no bit 5; the profile
        // on RPDO2 in the same cycle.
        assert_eq!(o.target, 5_000);
        assert_eq!(o.controlword.0 & 0x8170, 0x8010, "{:04X}", o.controlword.0);
        assert_eq!(a.profile_pdo(), Some(m.profile_bytes()));
        // Acknowledged: bit 4 falls, nothing is sent again while the move runs.
        let (o, _) = ex(&mut a, &mtr_tpdo(acked, 100), follow());
        assert_eq!(o.controlword.0 & 0x0010, 0);
        for pos in [1_000, 3_000] {
            let (o, fb) = ex(&mut a, &mtr_tpdo(moving, pos), follow());
            assert_eq!(o.controlword.0 & 0x0110, 0, "no new set-point, no halt");
            assert_eq!(a.profile_pdo(), None);
            assert!(!fb.motion_complete);
        }
        // Held: bit 8 only.
        a.set_move(Some(PointMove { halt: true, ..m }));
        let (o, _) = ex(&mut a, &mtr_tpdo(moving, 3_500), follow());
        assert_eq!(o.controlword.0 & 0x0110, 0x0100);
        // Stopped there, the move dropped: a standstill demand first quick-stops (0002h) to end
        // the drive's held move instead of releasing the halt into it.
        a.set_move(None);
        let (o, _) = ex(&mut a, &mtr_tpdo(0x0637, 3_600), Demand::Standstill);
        assert_eq!(o.controlword.0 & 0x000F, 0x0002, "{:04X}", o.controlword.0);
        // Quick stop active (bits 0..2 without bit 5): enabled again, transition 16.
        let (o, _) = ex(&mut a, &mtr_tpdo(0x0217, 3_600), Demand::Standstill);
        assert_eq!(o.controlword.0 & 0x000F, 0x000F);
        // A member that does not move: no set-point at all, done at once.
        let mut b = Cia402Axis::new(Layout::MtrDci, CYCLE);
        b.set_move(Some(PointMove {
            end: 0,
            velocity: 0,
            acceleration: 0,
            halt: false,
        }));
        let (o, fb) = ex(&mut b, &mtr_tpdo(ready, 0), follow());
        assert_eq!(o.controlword.0 & 0x0010, 0);
        assert_eq!(b.profile_pdo(), None);
        assert!(fb.motion_complete);
    }

    #[test]
    fn layouts_round_trip_and_short_images_are_refused() {
        let o = Output {
            controlword: Controlword(0x005F),
            target: -5,
            mode: 6,
            record: 3,
        };
        let img = o.to_image(Layout::MtrDci);
        assert_eq!(img.bytes(), &[0x5F, 0, 3, 6, 0xFB, 0xFF, 0xFF, 0xFF]);
        assert_eq!(Output::from_bytes(Layout::MtrDci, img.bytes()), Ok(o));
        let img = o.to_image(Layout::Tlc5xx);
        assert_eq!(img.bytes(), &[0x5F, 0, 0xFB, 0xFF, 0xFF, 0xFF, 6]);
        assert_eq!(
            decode_input(Layout::Tlc5xx, &[0x27, 0x04, 1, 0, 0]),
            Err(AxisError::Short { len: 5, need: 7 })
        );
        let i = decode_input(Layout::MtrDci, &[0x37, 0x86, 2, 1, 10, 0, 0, 0]).unwrap();
        assert_eq!(
            (i.statusword.0, i.record, i.mode, i.position),
            (0x8637, 2, 1, 10)
        );
    }

    #[test]
    fn enable_walks_the_state_machine() {
        let mut a = axis();
        let d = Demand::Standstill;
        let (o, fb) = ex(&mut a, &tpdo(0x0040, 0, 1), d);
        assert_eq!(o.controlword.0, 0x0006, "Shutdown from Switch on disabled");
        assert_eq!(o.mode, 1);
        assert_eq!(fb.state, AxisState::Enabling);
        let (o, _) = ex(&mut a, &tpdo(0x0421, 0, 1), d);
        assert_eq!(o.controlword.0, 0x000F);
        let (o, fb) = ex(&mut a, &tpdo(0x0427, 0, 1), d);
        assert_eq!(o.controlword.0, 0x000F);
        assert!(fb.done);
        assert_eq!(fb.state, AxisState::Ready);
    }

    #[test]
    fn follow_streams_pp_set_points_with_bits_4_5_6_and_the_lead() {
        let mut a = axis();
        let d = |p| Demand::Follow {
            position: p,
            velocity: 100_000,
        };
        // Operation enabled, PP active, target reached.
        let (o, _) = ex(&mut a, &tpdo(0x0427, 0, 1), d(0));
        // New set-point (4), change set immediately (5), absolute (6 = 1 on the TLC5xx).
        assert_eq!(o.controlword.0, 0x007F);
        assert_eq!(o.target, 200, "two cycles ahead at 100 000 units/s");
        let (o, _) = ex(&mut a, &tpdo(0x1027, 5, 1), d(100));
        assert_eq!(o.controlword.0 & 0x10, 0, "acknowledged: bit 4 low");
        assert_eq!(o.target, 200);
        let (o, fb) = ex(&mut a, &tpdo(0x0027, 60, 1), d(200));
        assert_eq!(
            o.controlword.0 & 0x10,
            0x10,
            "bit 12 low: the next set-point"
        );
        assert_eq!(o.target, 400);
        assert!(!fb.motion_complete);
        // A slow drive (4 cycles per handshake) gets a longer lead.
        ex(&mut a, &tpdo(0x0027, 100, 1), d(300));
        ex(&mut a, &tpdo(0x1027, 150, 1), d(400));
        ex(&mut a, &tpdo(0x1027, 200, 1), d(500));
        let (o, _) = ex(&mut a, &tpdo(0x0027, 250, 1), d(600));
        assert_eq!(o.target, 600 + 400, "four cycles ahead");
    }

    #[test]
    fn follow_is_complete_only_on_the_final_set_point_with_bit_10() {
        let mut a = axis();
        let d = Demand::Follow {
            position: 1000,
            velocity: 0,
        };
        let (o, _) = ex(&mut a, &tpdo(0x0427, 0, 1), d);
        assert_eq!(o.target, 1000);
        // Old bit 10 with the acknowledge: not complete.
        let (_, fb) = ex(&mut a, &tpdo(0x1427, 0, 1), d);
        assert!(!fb.motion_complete);
        let (o, fb) = ex(&mut a, &tpdo(0x0027, 500, 1), d);
        assert_eq!(o.controlword.0 & 0x10, 0, "no new set-point: same target");
        assert!(!fb.motion_complete);
        let (_, fb) = ex(&mut a, &tpdo(0x0427, 1000, 1), d);
        assert!(fb.motion_complete && fb.done);
    }

    #[test]
    fn mode_change_waits_for_the_display_before_homing_starts() {
        let mut a = axis();
        let (o, _) = ex(&mut a, &tpdo(0x0427, 0, 1), Demand::Home);
        assert_eq!((o.mode, o.controlword.0), (6, 0x000F));
        let (o, _) = ex(&mut a, &tpdo(0x0427, 0, 1), Demand::Home);
        assert_eq!(o.controlword.0, 0x000F, "6061h still 1");
        let (o, _) = ex(&mut a, &tpdo(0x0427, 0, 6), Demand::Home);
        assert_eq!(o.controlword.0, 0x000F, "bit 4 low first");
        let (o, fb) = ex(&mut a, &tpdo(0x0427, 0, 6), Demand::Home);
        assert_eq!(o.controlword.0, 0x001F, "bit 4 rises");
        assert_eq!(fb.state, AxisState::Homing);
        let (_, fb) = ex(&mut a, &tpdo(0x0027, 40, 6), Demand::Home);
        assert!(!fb.done);
        let (o, fb) = ex(&mut a, &tpdo(0x1427, 0, 6), Demand::Home);
        assert_eq!(o.controlword.0, 0x001F);
        assert!(fb.done && fb.homed && fb.motion_complete);
    }

    #[test]
    fn homing_error_fails_the_demand() {
        let mut a = axis();
        for sw in [0x0427, 0x0427, 0x0427, 0x0027, 0x2427] {
            ex(&mut a, &tpdo(sw, 0, 6), Demand::Home);
        }
        let (_, fb) = ex(&mut a, &tpdo(0x2427, 0, 6), Demand::Home);
        assert!(fb.failed && !fb.done && !fb.homed);
    }

    #[test]
    fn fault_reset_edge_halt_and_quick_stop() {
        let mut a = axis();
        let (o1, fb) = ex(&mut a, &tpdo(0x0008, 0, 1), Demand::Acknowledge);
        assert_eq!(fb.state, AxisState::Fault);
        let (o2, _) = ex(&mut a, &tpdo(0x0008, 0, 1), Demand::Acknowledge);
        assert_ne!(
            o1.controlword.0 & 0x80,
            o2.controlword.0 & 0x80,
            "bit 7 toggles"
        );
        let (o3, fb) = ex(&mut a, &tpdo(0x0040, 0, 1), Demand::Acknowledge);
        assert_eq!(o3.controlword.0 & 0x80, 0);
        assert!(fb.done);
        assert_eq!(fb.state, AxisState::Disabled);
        ex(&mut a, &tpdo(0x0027, 0, 1), Demand::Standstill);
        let (o, fb) = ex(&mut a, &tpdo(0x0027, 30, 1), Demand::Halt);
        assert_eq!(o.controlword.0, 0x010F);
        assert_eq!(fb.state, AxisState::Stopping);
        let (_, fb) = ex(&mut a, &tpdo(0x0427, 30, 1), Demand::Halt);
        assert!(fb.done);
        let (o, _) = ex(&mut a, &tpdo(0x0427, 30, 1), Demand::QuickStop);
        assert_eq!(o.controlword.0, 0x0002);
        let (_, fb) = ex(&mut a, &tpdo(0x0007, 30, 1), Demand::QuickStop);
        assert!(fb.done);
        assert_eq!(fb.state, AxisState::Stopping);
    }

    #[test]
    fn enabling_never_resets_a_fault() {
        let mut a = axis();
        for _ in 0..3 {
            let (o, fb) = ex(
                &mut a,
                &tpdo(0x0008, 0, 1),
                Demand::Follow {
                    position: 5,
                    velocity: 0,
                },
            );
            assert_eq!(o.controlword.0, 0x0000);
            assert_eq!(fb.state, AxisState::Fault);
        }
    }

    #[test]
    fn csp_sends_the_setpoint_every_cycle_without_handshake() {
        let mut a = axis().with_csp();
        let (o, _) = ex(
            &mut a,
            &tpdo(0x0027, 0, 8),
            Demand::Follow {
                position: 10,
                velocity: 10_000,
            },
        );
        assert_eq!((o.mode, o.controlword.0, o.target), (8, 0x000F, 10));
        let (o, _) = ex(
            &mut a,
            &tpdo(0x0027, 10, 8),
            Demand::Follow {
                position: 20,
                velocity: 0,
            },
        );
        assert_eq!((o.controlword.0, o.target), (0x000F, 20));
        let (_, fb) = ex(
            &mut a,
            &tpdo(0x0027, 20, 8),
            Demand::Follow {
                position: 20,
                velocity: 0,
            },
        );
        assert!(fb.motion_complete);
    }

    #[test]
    fn generic_layouts_carry_the_mode_setpoint() {
        let o = Output {
            controlword: Controlword(0x000F),
            target: -300,
            mode: 10,
            record: 0,
        };
        let cst = Layout::Generic(CyclicMode::Cst);
        let img = o.to_image(cst);
        assert_eq!(img.bytes(), &[0x0F, 0, 0xD4, 0xFE, 10]);
        assert_eq!(Output::from_bytes(cst, img.bytes()), Ok(o));
        let csv = Layout::Generic(CyclicMode::Csv);
        let o = Output { mode: 9, ..o };
        assert_eq!(
            o.to_image(csv).bytes(),
            &[0x0F, 0, 0xD4, 0xFE, 0xFF, 0xFF, 9]
        );
        assert_eq!(Output::from_bytes(csv, o.to_image(csv).bytes()), Ok(o));
        // The input image is the TLC5xx's in every mode.
        let i = decode_input(cst, &tpdo(0x1637, 5, 10)).unwrap();
        assert_eq!((i.position, i.mode), (5, 10));
    }

    #[test]
    fn csv_follows_a_path_with_a_position_correction() {
        let mut a = Cia402Axis::new(Layout::Generic(CyclicMode::Csv), CYCLE);
        let follow = |position, velocity| Demand::Follow { position, velocity };
        // Mode 9 requested; until the drive shows it, the set-point is a standstill.
        let (o, _) = ex(&mut a, &tpdo(0x0637, 0, 1), follow(0, 1000));
        assert_eq!((o.mode, o.target), (9, 0));
        // At the path: the path's velocity.
        let (o, _) = ex(&mut a, &tpdo(0x1637, 0, 9), follow(0, 1000));
        assert_eq!((o.controlword.0, o.target), (0x000F, 1000));
        // 80 increments behind: corrected over 8 cycles of 1 ms, +10 000 inc/s.
        let (o, fb) = ex(&mut a, &tpdo(0x1637, 20, 9), follow(100, 1000));
        assert_eq!(o.target, 11_000);
        assert!(!fb.motion_complete);
        // At rest at the end.
        let (o, fb) = ex(&mut a, &tpdo(0x1637, 100, 9), follow(100, 0));
        assert_eq!(o.target, 0);
        assert!(fb.motion_complete);
    }

    #[test]
    fn cst_takes_forces_and_refuses_paths() {
        let mut a = Cia402Axis::new(Layout::Generic(CyclicMode::Cst), CYCLE);
        let force = Demand::Force {
            permille: 40_000,
            velocity_limit: 100,
        };
        let (o, _) = ex(&mut a, &tpdo(0x0637, 0, 1), force);
        assert_eq!((o.mode, o.target), (10, 0));
        // Clamped to the 16 bits of 6071h.
        let (o, fb) = ex(&mut a, &tpdo(0x1637, 0, 10), force);
        assert_eq!((o.controlword.0, o.target), (0x000F, i32::from(i16::MAX)));
        assert!(fb.done);
        // 1000 increments in a 1 ms cycle: 1 000 000 inc/s, past the 100 inc/s limit in the
        // force's direction: no more torque that way.
        let (o, _) = ex(&mut a, &tpdo(0x1637, 1000, 10), force);
        assert_eq!(o.target, 0);
        let mut out = Image::default();
        let e = a.exchange(
            Some(&tpdo(0x1637, 0, 10)),
            &Demand::Follow {
                position: 5,
                velocity: 0,
            },
            &mut out,
        );
        assert!(matches!(e, Err(AxisError::Unsupported(_))));
        // A profile-position axis still refuses forces.
        let mut pp = axis();
        let e = pp.exchange(Some(&tpdo(0x0027, 0, 1)), &force, &mut out);
        assert!(matches!(e, Err(AxisError::Unsupported(_))));
    }

    #[test]
    fn an_undefined_statusword_is_refused_and_the_state_before_it_stays() {
        let mut a = axis();
        let (_, fb) = ex(&mut a, &tpdo(0x0027, 40, 1), Demand::Standstill);
        assert_ne!(fb.state, AxisState::Offline);
        let before = a.state();
        assert_eq!(before, Some(State::OperationEnabled));
        let mut out = Image::default();
        // xxxx xxxx x0xx 0001: no state of the CiA 402 machine.
        let e = a.exchange(Some(&tpdo(0x0001, 50, 1)), &Demand::Standstill, &mut out);
        assert!(matches!(e, Err(AxisError::Decode(_))));
        assert_eq!(out.data[1] & 0x01, 0x01, "bit 8 halt");
        assert_eq!(a.state(), before);
        assert_eq!(a.feedback().position, 40);
        // The next good image is taken again, its state with it.
        let (_, fb) = ex(&mut a, &tpdo(0x0040, 60, 1), Demand::Disable);
        assert_eq!(a.state(), Some(State::SwitchOnDisabled));
        assert_eq!(fb.position, 60);
    }

    #[test]
    fn force_teach_and_records_are_refused_with_halt() {
        let mut a = axis();
        ex(&mut a, &tpdo(0x0027, 0, 1), Demand::Standstill);
        let mut out = Image::default();
        let e = a.exchange(
            None,
            &Demand::Force {
                permille: 100,
                velocity_limit: 1,
            },
            &mut out,
        );
        assert!(matches!(e, Err(AxisError::Unsupported(_))));
        assert_eq!(out.data[1] & 0x01, 0x01, "bit 8 halt");
        let e = a.exchange(None, &Demand::Teach, &mut out);
        assert!(matches!(e, Err(AxisError::Unsupported(_))));
    }

    #[test]
    fn jog_streams_integrated_positions() {
        let mut a = axis();
        let d = Demand::Jog {
            positive: false,
            velocity: 50_000,
        };
        let (o, fb) = ex(&mut a, &tpdo(0x0427, 1000, 1), d);
        // 1000 − 50 (one cycle) − 100 (two cycles of lead).
        assert_eq!(o.target, 850);
        assert_eq!(o.controlword.0 & 0x10, 0x10);
        assert!(!fb.done);
        let (_, fb) = ex(&mut a, &tpdo(0x1027, 990, 1), d);
        assert!(fb.done);
        assert_eq!(fb.state, AxisState::Moving);
    }
}
