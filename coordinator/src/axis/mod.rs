//! Master-side axis state machines: what the coordinator sends a drive each cycle and what it
//! reads back, for the FHPP drives ([`fhpp`]: MTR-DCI, EMCA, CMMO-ST) and the CiA 402 drives
//! ([`cia402`]: TLC5xx, and the MTR-DCI in its 402 profile). What each device offers is
//! `drivers::catalog`'s.
//!
//! The cycle tells each axis what it wants with a [`Demand`] (repeated every cycle until it
//! changes); the axis turns it into this cycle's output image (the RPDO or Modbus register
//! bytes) from the input image that arrived (TPDO or Modbus registers), and reports a
//! [`Feedback`]. The codecs are the drivers' (`drivers::fhpp`, `drivers::cia402`), the same the
//! simulators use. Everything here is `no_std`, allocation-free and bounded: [`DriveAxis::exchange`]
//! may be called from the cycle step.
//!
//! [`pdo_mapping`] says which PDOs the boot configures for each drive (and so which images
//! [`DriveAxis::exchange`] reads and writes); `config::axis_pdos` budgets the same lengths.
//!
//! ```
//! use coordinator::axis::{Demand, DeviceKind, DriveAxis, Image, Profile};
//! let mut axis = DriveAxis::new(DeviceKind::MtrDci, Profile::Fhpp, 2_000_000).unwrap();
//! let mut out = Image::default();
//! // The drive's power-on image (drive blocked, load voltage, MC): the axis enables it.
//! let fb = axis
//!     .exchange(Some(&[0x10, 0x04, 0, 0, 0, 0, 0, 0]), &Demand::Standstill, &mut out)
//!     .unwrap();
//! assert_eq!(out.bytes()[..2], [0x23, 0x01]); // CCON ENABLE | STOP | LOCK, CPOS HALT
//! assert!(!fb.done);
//! ```

pub mod cia402;
pub mod fhpp;

/// The largest process image of one axis, one direction (one PDO or Modbus block), bytes.
pub const IMAGE_BYTES: usize = 8;

/// The bytes of one axis's process image, one direction.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Image {
    /// The bytes; only the first `len` count.
    pub data: [u8; IMAGE_BYTES],
    /// Number of valid bytes.
    pub len: u8,
}

impl Image {
    /// The valid bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.data[..usize::from(self.len).min(IMAGE_BYTES)]
    }
    /// An image holding `bytes`; `None` if longer than [`IMAGE_BYTES`].
    pub fn from_slice(bytes: &[u8]) -> Option<Image> {
        let mut data = [0; IMAGE_BYTES];
        data.get_mut(..bytes.len())?.copy_from_slice(bytes);
        Some(Image {
            data,
            len: bytes.len() as u8,
        })
    }
}

/// The drive on the other end (the configuration's device kind, without std).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DeviceKind {
    /// Festo MTR-DCI (CANopen; FHPP or CiA 402; node guarding only).
    MtrDci,
    /// Festo EMCA (CANopen; FHPP, or CiA 402).
    Emca,
    /// Festo CMMO-ST (Modbus TCP; FHPP).
    CmmoSt,
    /// Schneider TLC5xx (CANopen; CiA 402).
    Tlc5xx,
    /// Any CiA 402 drive (CANopen; its facts from its EDS).
    Cia402,
}

impl DeviceKind {
    /// Every kind, in the catalog's order.
    pub const ALL: [DeviceKind; 5] = [
        DeviceKind::MtrDci,
        DeviceKind::Emca,
        DeviceKind::CmmoSt,
        DeviceKind::Tlc5xx,
        DeviceKind::Cia402,
    ];

    /// The device's facts (`drivers::catalog`).
    pub const fn device(self) -> &'static Device {
        match self {
            DeviceKind::MtrDci => &catalog::MTR_DCI,
            DeviceKind::Emca => &catalog::EMCA,
            DeviceKind::CmmoSt => &catalog::CMMO_ST,
            DeviceKind::Tlc5xx => &catalog::TLC5XX,
            DeviceKind::Cia402 => &catalog::CIA402_GENERIC,
        }
    }

    /// The device's name as its manual writes it.
    pub fn label(self) -> &'static str {
        self.device().name
    }
}

impl core::fmt::Display for DeviceKind {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.label())
    }
}

/// How a CiA 402 axis is commanded cyclically: the mode of operation its paths, jogs and
/// forces use (`shared/reference/plcopen-and-cia402-csp.md` §7, §8). The configuration's
/// `mode`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum CyclicMode {
    /// Profile position (mode 1): set-points streamed through the handshake of bits 4/12,
    /// as fast as the drive acknowledges them. The only mode of the TLC5xx and the MTR-DCI here.
    #[default]
    Pp,
    /// Cyclic synchronous position (mode 8): 607Ah every cycle, latched at SYNC.
    Csp,
    /// Cyclic synchronous velocity (mode 9): 60FFh every cycle; the coordinator closes the
    /// position loop of a path.
    Csv,
    /// Cyclic synchronous torque (mode 10): 6071h every cycle, from force demands.
    Cst,
}

impl CyclicMode {
    /// Every mode, in the order of their CiA 402 codes.
    pub const ALL: [CyclicMode; 4] = [
        CyclicMode::Pp,
        CyclicMode::Csp,
        CyclicMode::Csv,
        CyclicMode::Cst,
    ];

    /// The name in the configuration.
    pub const fn id(self) -> &'static str {
        match self {
            CyclicMode::Pp => "pp",
            CyclicMode::Csp => "csp",
            CyclicMode::Csv => "csv",
            CyclicMode::Cst => "cst",
        }
    }

    /// The CiA 402 mode of operation (6060h).
    pub const fn operation_mode(self) -> drivers::cia402::modes::OperationMode {
        use drivers::cia402::modes::OperationMode as M;
        match self {
            CyclicMode::Pp => M::ProfilePosition,
            CyclicMode::Csp => M::CyclicSyncPosition,
            CyclicMode::Csv => M::CyclicSyncVelocity,
            CyclicMode::Cst => M::CyclicSyncTorque,
        }
    }

    /// The object the RPDO carries the set-point in, with its bits (607Ah, 60FFh, 6071h).
    pub const fn setpoint_entry(self) -> u32 {
        match self {
            CyclicMode::Pp | CyclicMode::Csp => 0x607A_0020,
            CyclicMode::Csv => 0x60FF_0020,
            CyclicMode::Cst => 0x6071_0010,
        }
    }
}

impl core::fmt::Display for CyclicMode {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            CyclicMode::Pp => "profile position",
            CyclicMode::Csp => "cyclic synchronous position",
            CyclicMode::Csv => "cyclic synchronous velocity",
            CyclicMode::Cst => "cyclic synchronous torque",
        })
    }
}

/// The device profile spoken to a drive (the catalog's).
pub use drivers::catalog::Profile;
use drivers::catalog::{self, Device};

/// What the cycle wants of an axis this cycle. A demand is repeated every cycle until it
/// changes; the axis produces the edges and handshakes it needs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Demand {
    /// Power stage off (FHPP CCON.ENABLE = 0; CiA 402 "disable voltage").
    #[default]
    Disable,
    /// Enabled, standing at the last setpoint (brings the drive to operation enabled).
    Standstill,
    /// Acknowledge a drive fault (the axis makes the edge the drive needs).
    Acknowledge,
    /// Run the drive's homing (FHPP record 0 / CPOS.HOM; CiA 402 mode 6).
    Home,
    /// Jog in one direction (FHPP CPOS.JOGP/JOGN; CiA 402 by the coordinator's setpoints or
    /// profile velocity) at `velocity` inc/s (magnitude).
    Jog {
        /// Positive direction.
        positive: bool,
        /// Speed, inc/s.
        velocity: i64,
    },
    /// Follow the coordinator's interpolated path: this cycle's setpoint (increments) and its
    /// velocity (inc/s). Streamed as FHPP direct-mode targets, CiA 402 profile-position
    /// set-points with "change set immediately", or cyclic synchronous position where offered.
    Follow {
        /// Setpoint, increments.
        position: i64,
        /// Setpoint velocity, inc/s (signed).
        velocity: i64,
    },
    /// Run at a velocity (FHPP direct speed mode; CiA 402 profile velocity), inc/s.
    Velocity {
        /// Velocity, inc/s (signed).
        velocity: i64,
    },
    /// Push with a force (FHPP direct force mode), per mille of the drive's nominal force,
    /// moving no faster than `velocity_limit` inc/s.
    Force {
        /// Force setpoint, ‰ of nominal.
        permille: i32,
        /// Speed limit, inc/s.
        velocity_limit: i64,
    },
    /// Start a record of the drive's own table (FHPP record select, START/ACK/MC handshake).
    DriveRecord {
        /// Record number (1..=the device's table size).
        number: u8,
    },
    /// Teach the actual position into the drive's selected record or target (FHPP CPOS.TEACH).
    Teach,
    /// Decelerate with the drive's ramp and stand, keeping the task (FHPP CPOS.HALT = 0;
    /// CiA 402 controlword bit 8).
    Halt,
    /// Quick stop (FHPP CCON.STOP = 0; CiA 402 quick-stop command).
    QuickStop,
}

/// The move a drive that takes one set-point per move runs (see
/// [`DriveAxis::one_set_point_per_move`]): given by the cycle every cycle its path runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct PointMove {
    /// The path's end for this axis, increments.
    pub end: i64,
    /// The path's speed limit for this axis, inc/s (6081h).
    pub velocity: u32,
    /// The path's acceleration for this axis, inc/s² (6083h; the drive brakes with it too).
    pub acceleration: u32,
    /// The path is holding or stopped on its way: the drive halts (controlword bit 8), keeping
    /// the move to resume.
    pub halt: bool,
}

impl PointMove {
    /// The RPDO2 image of a drive with a profile RPDO2 (6081h, 6083h, little-endian).
    pub fn profile_bytes(&self) -> [u8; 8] {
        let mut b = [0u8; 8];
        b[..4].copy_from_slice(&self.velocity.to_le_bytes());
        b[4..].copy_from_slice(&self.acceleration.to_le_bytes());
        b
    }

    /// The same move as far as the drive is concerned (end and profile; not the halt).
    pub fn same_move(&self, other: &PointMove) -> bool {
        (self.end, self.velocity, self.acceleration)
            == (other.end, other.velocity, other.acceleration)
    }
}

/// Whether a `kind` drive in `profile` commanded in `mode` takes one set-point per move: profile
/// position on a drive without "change set immediately" (the MTR-DCI, seed 000 §7.9), which
/// queues a new set-point behind the running one instead of taking it over, so that a stream
/// of set-points would stop at each.
pub fn takes_one_set_point_per_move(kind: DeviceKind, profile: Profile, mode: CyclicMode) -> bool {
    profile == Profile::Cia402
        && mode == CyclicMode::Pp
        && cia402::Layout::of(kind).is_some_and(|l| !l.profile().change_set_immediately)
}

/// Where an axis is, as the coordinator sees it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum AxisState {
    /// No image received yet (or the drive stopped answering).
    #[default]
    Offline,
    /// Power stage off.
    Disabled,
    /// Being brought to operation enabled.
    Enabling,
    /// Operation enabled, standing.
    Ready,
    /// Homing running.
    Homing,
    /// A task or setpoint stream is moving the axis.
    Moving,
    /// Halt or quick stop active.
    Stopping,
    /// The drive reports a fault.
    Fault,
}

impl AxisState {
    /// The state in words, for people.
    pub fn name(self) -> &'static str {
        match self {
            AxisState::Offline => "offline",
            AxisState::Disabled => "disabled",
            AxisState::Enabling => "enabling",
            AxisState::Ready => "ready",
            AxisState::Homing => "homing",
            AxisState::Moving => "moving",
            AxisState::Stopping => "stopping",
            AxisState::Fault => "fault",
        }
    }
}

impl core::fmt::Display for AxisState {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.name())
    }
}

/// What an axis reported this cycle, decoded from its input image.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Feedback {
    /// The state.
    pub state: AxisState,
    /// Actual position, increments.
    pub position: i64,
    /// Actual velocity, inc/s (0 where the image does not carry it).
    pub velocity: i64,
    /// Actual force, ‰ of nominal (0 where the image does not carry it).
    pub force: i32,
    /// The drive is referenced (homed).
    pub homed: bool,
    /// Motion complete / target reached: the last task or setpoint stream has arrived.
    pub motion_complete: bool,
    /// The drive signals a warning.
    pub warning: bool,
    /// The drive's fault number (FHPP diagnosis / CiA 402 603Fh), 0 if none is known.
    pub fault_code: u16,
    /// Raw status bits for display: FHPP SCON | SPOS << 8; CiA 402 statusword.
    pub status: u16,
    /// The last demand has been carried out (enable reached, homing done, record done, teach
    /// taken, acknowledge done), so the cycle may move on.
    pub done: bool,
    /// The last demand failed and will not complete by itself (the drive refused or faulted
    /// during a handshake, homing ended with an error, a phase timed out). Cleared when the
    /// demand changes.
    pub failed: bool,
}

/// Why an input image could not be used.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum AxisError {
    /// The image is shorter than the mapping.
    #[error("input image of {len} bytes, {need} expected")]
    Short {
        /// Bytes received.
        len: usize,
        /// Bytes expected.
        need: usize,
    },
    /// The demand cannot be carried out by this drive (for example force on a CiA 402 drive).
    #[error("the drive cannot do {0}")]
    Unsupported(&'static str),
    /// The image has the right length but cannot be decoded (an FHPP reserved operating mode,
    /// an undefined CiA 402 statusword pattern); the last feedback is kept.
    #[error("input image not decodable: {0}")]
    Decode(&'static str),
}

/// One axis's drive on the master side: the profile's state machine behind one interface.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DriveAxis {
    /// An FHPP drive.
    Fhpp(fhpp::FhppAxis),
    /// A CiA 402 drive.
    Cia402(cia402::Cia402Axis),
}

impl DriveAxis {
    /// The master side for a `kind` drive spoken to in `profile`, exchanged every `cycle_ns`
    /// nanoseconds (used to extrapolate streamed targets and to integrate jog positions).
    /// Refuses a profile the catalog does not offer for the device (the TLC5xx in FHPP, the
    /// CMMO-ST and EMCA in CiA 402), and a zero cycle.
    pub fn new(kind: DeviceKind, profile: Profile, cycle_ns: u32) -> Result<DriveAxis, AxisError> {
        use drivers::fhpp::Variant;
        if cycle_ns == 0 {
            return Err(AxisError::Unsupported("a cycle of 0 ns"));
        }
        let unsupported = AxisError::Unsupported(match profile {
            Profile::Fhpp => "the FHPP profile",
            Profile::Cia402 => "the CiA 402 profile",
        });
        if !kind.device().offers(profile) {
            return Err(unsupported);
        }
        match (kind, profile) {
            (DeviceKind::MtrDci, Profile::Fhpp) => Ok(DriveAxis::Fhpp(fhpp::FhppAxis::new(
                Variant::MtrDci,
                cycle_ns,
            ))),
            (DeviceKind::Emca, Profile::Fhpp) => Ok(DriveAxis::Fhpp(fhpp::FhppAxis::new(
                Variant::Emca,
                cycle_ns,
            ))),
            (DeviceKind::CmmoSt, Profile::Fhpp) => Ok(DriveAxis::Fhpp(fhpp::FhppAxis::new(
                Variant::CmmoSt,
                cycle_ns,
            ))),
            (k, Profile::Cia402) => match cia402::Layout::of(k) {
                Some(l) => Ok(DriveAxis::Cia402(cia402::Cia402Axis::new(l, cycle_ns))),
                // Offered by the catalog without a master side here: refused the same way
                // (`images_match_the_catalog_pdo1` keeps this arm unreachable).
                None => Err(unsupported),
            },
            // FHPP on a device that does not speak it: `offers` refused it above.
            _ => Err(unsupported),
        }
    }

    /// The master side of a `kind` drive in `profile` commanded in `mode` (see
    /// [`DriveAxis::new`]); refuses a mode the device does not take cyclically: the TLC5xx and
    /// the MTR-DCI stream profile position only, FHPP has no such modes.
    pub fn in_mode(
        kind: DeviceKind,
        profile: Profile,
        mode: CyclicMode,
        cycle_ns: u32,
    ) -> Result<DriveAxis, AxisError> {
        let axis = DriveAxis::new(kind, profile, cycle_ns)?;
        match (kind, profile, mode) {
            (DeviceKind::Cia402, Profile::Cia402, m) => Ok(DriveAxis::Cia402(
                cia402::Cia402Axis::new(cia402::Layout::Generic(m), cycle_ns),
            )),
            (_, _, CyclicMode::Pp) => Ok(axis),
            _ => Err(AxisError::Unsupported(
                "a cyclic synchronous mode on a drive that offers profile position only",
            )),
        }
    }

    /// One cycle: `input` is this cycle's image from the drive (`None` if none arrived: the
    /// last feedback is kept and `out` still written), `demand` what the cycle wants, `out`
    /// receives the bytes to send. On an error `out` holds a safe image (halt / hold).
    pub fn exchange(
        &mut self,
        input: Option<&[u8]>,
        demand: &Demand,
        out: &mut Image,
    ) -> Result<&Feedback, AxisError> {
        match self {
            DriveAxis::Fhpp(a) => a.exchange(input, demand, out),
            DriveAxis::Cia402(a) => a.exchange(input, demand, out),
        }
    }

    /// Bytes of the input image (TPDO / Modbus input registers) the axis expects.
    pub fn rx_len(&self) -> usize {
        match self {
            DriveAxis::Fhpp(_) => fhpp::IMAGE_LEN,
            DriveAxis::Cia402(a) => a.layout().rx_len(),
        }
    }

    /// Bytes of the output image (RPDO / Modbus output registers) the axis writes.
    pub fn tx_len(&self) -> usize {
        match self {
            DriveAxis::Fhpp(_) => fhpp::IMAGE_LEN,
            DriveAxis::Cia402(a) => a.layout().tx_len(),
        }
    }

    /// The same axis streaming `Follow` in cyclic synchronous position (CiA 402 mode 8) for a
    /// drive that offers it; an FHPP axis is returned unchanged.
    pub fn with_csp(self) -> DriveAxis {
        match self {
            DriveAxis::Cia402(a) => DriveAxis::Cia402(a.with_csp()),
            f => f,
        }
    }

    /// What the drive reported last: what the last [`DriveAxis::exchange`] returned, or the
    /// feedback before it when that exchange could not decode its image (a refused demand
    /// reports `failed`). The cycle keeps no copy of its own.
    pub fn feedback(&self) -> &Feedback {
        match self {
            DriveAxis::Fhpp(a) => a.feedback(),
            DriveAxis::Cia402(a) => a.feedback(),
        }
    }

    /// Whether the drive takes one set-point per move (see
    /// [`takes_one_set_point_per_move`]): `Follow` then sends the move's end once, with its
    /// profile on RPDO2, and the cycle gives the move with [`DriveAxis::set_move`].
    pub fn one_set_point_per_move(&self) -> bool {
        match self {
            DriveAxis::Fhpp(_) => false,
            DriveAxis::Cia402(a) => a.one_set_point_per_move(),
        }
    }

    /// The move the path runs this cycle, for a drive that takes one set-point per move
    /// (ignored otherwise); `None` while no path runs.
    pub fn set_move(&mut self, m: Option<PointMove>) {
        if let DriveAxis::Cia402(a) = self {
            a.set_move(m);
        }
    }

    /// The RPDO2 image (6081h, 6083h) to send this cycle, before the set-point it belongs to
    /// is applied at the next SYNC (the drive takes RPDO2 as it arrives); `None` in most
    /// cycles.
    pub fn profile_pdo(&self) -> Option<[u8; 8]> {
        match self {
            DriveAxis::Fhpp(_) => None,
            DriveAxis::Cia402(a) => a.profile_pdo(),
        }
    }

    /// Forgets everything learnt from the drive (after a drive reset or a lost connection):
    /// the axis is offline until the next image.
    pub fn reset(&mut self) {
        match self {
            DriveAxis::Fhpp(a) => a.reset(),
            DriveAxis::Cia402(a) => a.reset(),
        }
    }
}

/// One PDO the coordinator configures at boot for an axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PdoSpec {
    /// The PDO number, 1..=4 (communication object 1400h/1800h + number − 1).
    pub number: u8,
    /// The COB-ID function (`Rpdo(n)` / `Tpdo(n)`); the COB-ID is its base + node-ID.
    pub function: drivers::canopen::FunctionCode,
    /// The mapping entries in order (index << 16 | sub << 8 | bits), as 1600h/1A00h hold them.
    pub mapping: &'static [u32],
    /// Whether the device lets the master write the mapping. `false`: static mapping (Festo
    /// §5.4.4): the boot only reads it back and compares.
    pub remappable: bool,
    /// The transmission type to write (1 = synchronous, every SYNC).
    pub transmission: u8,
}

impl PdoSpec {
    /// Data bytes of the mapped objects.
    pub fn len(&self) -> usize {
        self.mapping.iter().map(|m| usize::from(*m as u8) / 8).sum()
    }
    /// Whether nothing is mapped.
    pub fn is_empty(&self) -> bool {
        self.mapping.is_empty()
    }
}

/// The cyclic PDOs of one axis, each way; both `None` for a Modbus drive (the CMMO-ST's image
/// is registers 0..3 / 4..7, not PDOs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PdoMap {
    /// Master → drive (the output image).
    pub rpdo: Option<PdoSpec>,
    /// Drive → master (the input image).
    pub tpdo: Option<PdoSpec>,
}

/// TLC5xx PDO1 as the coordinator maps it (7 bytes each way), from the catalog.
pub use drivers::catalog::{TLC_RPDO1, TLC_TPDO1};

/// The parameter-channel PDOs (PDO2) of a drive in `profile`, where the catalog has them (the
/// Festo drives in FHPP over CANopen); `None` for the others (the CMMO-ST's 8-byte Modbus
/// profile and CiA 402 have none).
pub fn fpc_mapping(kind: DeviceKind, profile: Profile) -> Option<PdoMap> {
    use drivers::canopen::FunctionCode;
    let pair = kind.device().profile(profile)?.fpc_pdo2?;
    let pdo = |function, mapping| PdoSpec {
        number: 2,
        function,
        mapping,
        remappable: false,
        transmission: 1,
    };
    Some(PdoMap {
        rpdo: Some(pdo(FunctionCode::Rpdo(2), pair.rpdo)),
        tpdo: Some(pdo(FunctionCode::Tpdo(2), pair.tpdo)),
    })
}

/// The RPDO2 mapping that carries each move's profile (6081h, 6083h) to a drive that takes one
/// set-point per move ([`takes_one_set_point_per_move`]), from the catalog; `None` for every
/// other drive.
pub fn profile_rpdo2_mapping(
    kind: DeviceKind,
    profile: Profile,
    mode: CyclicMode,
) -> Option<&'static [u32]> {
    if !takes_one_set_point_per_move(kind, profile, mode) {
        return None;
    }
    kind.device().profile(profile)?.profile_rpdo2
}

/// The parameter-channel codec of a Festo drive (classic FPC on the MTR-DCI, EFPC on the EMCA,
/// little-endian on CANopen).
pub fn fpc_codec(kind: DeviceKind) -> Option<drivers::fhpp::fpc::Codec> {
    use drivers::fhpp::{ByteOrder, Variant, fpc::Codec};
    let v = match kind {
        DeviceKind::MtrDci => Variant::MtrDci,
        DeviceKind::Emca => Variant::Emca,
        _ => return None,
    };
    Some(Codec::new(v.parameter_channel(), ByteOrder::Little))
}

/// The cyclic PDOs for a `kind` drive in `profile` commanded in `mode`: [`pdo_mapping`], with
/// a generic CiA 402 drive's RPDO carrying the mode's set-point object (the catalog's
/// `CIA402_*_RPDO1`).
pub fn pdo_mapping_in(kind: DeviceKind, profile: Profile, mode: CyclicMode) -> PdoMap {
    use drivers::catalog::{CIA402_CSP_RPDO1, CIA402_CST_RPDO1, CIA402_CSV_RPDO1};
    let mut map = pdo_mapping(kind, profile);
    if kind == DeviceKind::Cia402
        && let Some(r) = &mut map.rpdo
    {
        r.mapping = match mode {
            CyclicMode::Pp | CyclicMode::Csp => CIA402_CSP_RPDO1,
            CyclicMode::Csv => CIA402_CSV_RPDO1,
            CyclicMode::Cst => CIA402_CST_RPDO1,
        };
    }
    map
}

/// The cyclic PDOs the coordinator configures for a `kind` drive in `profile`: the catalog's
/// PDO1 (see [`DriveAxis::rx_len`] for the image lengths they produce). Profiles the device does
/// not offer, and Modbus drives, get no PDOs.
pub fn pdo_mapping(kind: DeviceKind, profile: Profile) -> PdoMap {
    use drivers::canopen::FunctionCode;
    let facts = kind.device().profile(profile);
    let Some((pair, remappable)) = facts.and_then(|f| Some((f.pdo1?, !f.pdo1_static))) else {
        return PdoMap {
            rpdo: None,
            tpdo: None,
        };
    };
    let pdo = |function, mapping| PdoSpec {
        number: 1,
        function,
        mapping,
        remappable,
        transmission: 1,
    };
    PdoMap {
        rpdo: Some(pdo(FunctionCode::Rpdo(1), pair.rpdo)),
        tpdo: Some(pdo(FunctionCode::Tpdo(1), pair.tpdo)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// In every cyclic mode the generic drive's image is as long as the mapping the boot writes;
    /// the seed devices take profile position only.
    #[test]
    fn cyclic_modes_match_their_mapping() {
        for mode in CyclicMode::ALL {
            let axis =
                DriveAxis::in_mode(DeviceKind::Cia402, Profile::Cia402, mode, 1_000_000).unwrap();
            let map = pdo_mapping_in(DeviceKind::Cia402, Profile::Cia402, mode);
            assert_eq!(map.rpdo.map(|p| p.len()), Some(axis.tx_len()), "{mode}");
            assert_eq!(map.tpdo.map(|p| p.len()), Some(axis.rx_len()), "{mode}");
            assert_eq!(
                map.rpdo.map(|p| p.mapping[1]),
                Some(mode.setpoint_entry()),
                "{mode}"
            );
            let seed_ok = mode == CyclicMode::Pp;
            for kind in [DeviceKind::Tlc5xx, DeviceKind::MtrDci] {
                let a = DriveAxis::in_mode(kind, Profile::Cia402, mode, 1_000_000);
                assert_eq!(a.is_ok(), seed_ok, "{kind} {mode}");
            }
        }
    }

    /// The codecs' image lengths are the catalog's PDO1 lengths, for every profile offered.
    #[test]
    fn images_match_the_catalog_pdo1() {
        for kind in DeviceKind::ALL {
            for facts in kind.device().profiles {
                let axis = DriveAxis::new(kind, facts.profile, 1_000_000).unwrap();
                let map = pdo_mapping(kind, facts.profile);
                match facts.pdo1 {
                    Some(pdo1) => {
                        assert_eq!(axis.tx_len(), pdo1.rpdo_bytes(), "{kind}");
                        assert_eq!(axis.rx_len(), pdo1.tpdo_bytes(), "{kind}");
                        assert_eq!(map.rpdo.map(|p| p.len()), Some(axis.tx_len()));
                        assert_eq!(map.tpdo.map(|p| p.len()), Some(axis.rx_len()));
                    }
                    None => assert_eq!((map.rpdo, map.tpdo), (None, None)),
                }
                assert_eq!(
                    fpc_mapping(kind, facts.profile).is_some(),
                    facts.fpc_pdo2.is_some()
                );
            }
            for p in [Profile::Fhpp, Profile::Cia402] {
                if !kind.device().offers(p) {
                    assert!(DriveAxis::new(kind, p, 1_000_000).is_err(), "{kind} {p:?}");
                    assert_eq!(pdo_mapping(kind, p).rpdo, None);
                }
            }
        }
    }
}
