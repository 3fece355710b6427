//! Master-side axis state machines: what the coordinator sends a drive each cycle and what it
//! reads back, for the FHPP drives ([`fhpp`]: MTR-DCI, EMCA, CMMO-ST) and the CiA 402 drives
//! ([`cia402`]: TLC5xx, and the MTR-DCI/EMCA in their 402 profile).
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
}

impl DeviceKind {
    /// The device's name as its manual writes it.
    pub fn label(self) -> &'static str {
        match self {
            DeviceKind::MtrDci => "MTR-DCI",
            DeviceKind::Emca => "EMCA",
            DeviceKind::CmmoSt => "CMMO-ST",
            DeviceKind::Tlc5xx => "TLC5xx",
        }
    }
}

impl core::fmt::Display for DeviceKind {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.label())
    }
}

/// The device profile spoken to a drive.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Profile {
    /// Festo Handling and Positioning Profile.
    Fhpp,
    /// CiA 402 drives and motion control.
    Cia402,
}

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
    /// Refuses a combination no simulator or manual offers: the TLC5xx in FHPP, the CMMO-ST
    /// in CiA 402, and the EMCA in CiA 402 (its 402 firmware is not modelled), and a zero cycle.
    pub fn new(kind: DeviceKind, profile: Profile, cycle_ns: u32) -> Result<DriveAxis, AxisError> {
        use drivers::fhpp::Variant;
        if cycle_ns == 0 {
            return Err(AxisError::Unsupported("a cycle of 0 ns"));
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
            (DeviceKind::Tlc5xx, Profile::Cia402) => Ok(DriveAxis::Cia402(
                cia402::Cia402Axis::new(cia402::Layout::Tlc5xx, cycle_ns),
            )),
            (DeviceKind::MtrDci, Profile::Cia402) => Ok(DriveAxis::Cia402(
                cia402::Cia402Axis::new(cia402::Layout::MtrDci, cycle_ns),
            )),
            (DeviceKind::Tlc5xx, Profile::Fhpp) => Err(AxisError::Unsupported("FHPP on a TLC5xx")),
            (DeviceKind::CmmoSt, Profile::Cia402) => {
                Err(AxisError::Unsupported("CiA 402 on a CMMO-ST"))
            }
            (DeviceKind::Emca, Profile::Cia402) => {
                Err(AxisError::Unsupported("CiA 402 on an EMCA (not modelled)"))
            }
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
    ) -> Result<Feedback, AxisError> {
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

/// The Festo FHPP objects on PDO1 (MTR-DCI §7.4, EMCA §5.1; `sim::mtr_dci`): CCON, CPOS,
/// CDIR/record, value 1, value 2.
const FHPP_RPDO1: &[u32] = &[
    0x3000_0008,
    0x3001_0008,
    0x3002_0008,
    0x3003_0008,
    0x3004_0020,
];
/// SCON, SPOS, SDIR/record, RSB/value 1, value 2.
const FHPP_TPDO1: &[u32] = &[
    0x3020_0008,
    0x3021_0008,
    0x3022_0008,
    0x3023_0008,
    0x3024_0020,
];
/// MTR-DCI CiA 402 static PDO1 (§7.4): controlword, record number 2032h:01, 6060h, 607Ah.
const MTR_402_RPDO1: &[u32] = &[0x6040_0010, 0x2032_0108, 0x6060_0008, 0x607A_0020];
/// Statusword, record number, 6061h, 6064h.
const MTR_402_TPDO1: &[u32] = &[0x6041_0010, 0x2032_0108, 0x6061_0008, 0x6064_0020];
/// TLC5xx RPDO1 as the coordinator maps it (7 bytes): controlword, target position 607Ah,
/// modes of operation 6060h.
pub const TLC_RPDO1: &[u32] = &[0x6040_0010, 0x607A_0020, 0x6060_0008];
/// TLC5xx TPDO1 (7 bytes): statusword, position actual value 6064h, modes display 6061h.
pub const TLC_TPDO1: &[u32] = &[0x6041_0010, 0x6064_0020, 0x6061_0008];

/// The Festo parameter channel on PDO2 (MTR-DCI §7.4, EMCA §5.1; static): FPC byte 1, sub-index,
/// PKE/PNU, PWE each way.
const FPC_RPDO2: &[u32] = &[0x3010_0008, 0x3011_0008, 0x3012_0010, 0x3013_0020];
/// The drive's reply.
const FPC_TPDO2: &[u32] = &[0x3030_0008, 0x3031_0008, 0x3032_0010, 0x3033_0020];

/// The parameter-channel PDOs (PDO2) of a Festo drive in FHPP over CANopen; `None` for the
/// others (the CMMO-ST's 8-byte Modbus profile and CiA 402 have none).
pub fn fpc_mapping(kind: DeviceKind, profile: Profile) -> Option<PdoMap> {
    use drivers::canopen::FunctionCode;
    let pdo = |function, mapping| PdoSpec {
        number: 2,
        function,
        mapping,
        remappable: false,
        transmission: 1,
    };
    match (kind, profile) {
        (DeviceKind::MtrDci | DeviceKind::Emca, Profile::Fhpp) => Some(PdoMap {
            rpdo: Some(pdo(FunctionCode::Rpdo(2), FPC_RPDO2)),
            tpdo: Some(pdo(FunctionCode::Tpdo(2), FPC_TPDO2)),
        }),
        _ => None,
    }
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

/// The cyclic PDOs the coordinator configures for a `kind` drive in `profile` (see
/// [`DriveAxis::rx_len`] for the image lengths they produce). Combinations
/// [`DriveAxis::new`] refuses get no PDOs.
pub fn pdo_mapping(kind: DeviceKind, profile: Profile) -> PdoMap {
    use drivers::canopen::FunctionCode;
    let pdo = |function, mapping, remappable| PdoSpec {
        number: 1,
        function,
        mapping,
        remappable,
        transmission: 1,
    };
    let pair = |r, t, remappable| PdoMap {
        rpdo: Some(pdo(FunctionCode::Rpdo(1), r, remappable)),
        tpdo: Some(pdo(FunctionCode::Tpdo(1), t, remappable)),
    };
    match (kind, profile) {
        (DeviceKind::MtrDci | DeviceKind::Emca, Profile::Fhpp) => {
            pair(FHPP_RPDO1, FHPP_TPDO1, false)
        }
        (DeviceKind::MtrDci, Profile::Cia402) => pair(MTR_402_RPDO1, MTR_402_TPDO1, false),
        (DeviceKind::Tlc5xx, Profile::Cia402) => pair(TLC_RPDO1, TLC_TPDO1, true),
        _ => PdoMap {
            rpdo: None,
            tpdo: None,
        },
    }
}
