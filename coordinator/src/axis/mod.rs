//! Master-side axis state machines: what the coordinator sends a drive each cycle and what it
//! reads back, for the FHPP drives ([`fhpp`]: MTR-DCI, EMCA, CMMO-ST) and the CiA 402 drives
//! ([`cia402`]: TLC5xx, and the MTR-DCI/EMCA in their 402 profile).
//!
//! The cycle tells each axis what it wants with a [`Demand`] (repeated every cycle until it
//! changes); the axis turns it into this cycle's output image (the RPDO or Modbus register
//! bytes) from the input image that arrived (TPDO or Modbus registers), and reports a
//! [`Feedback`]. The codecs are the drivers' (`drivers::fhpp`, `drivers::cia402`), the same the
//! simulators use. Everything here is `no_std`, allocation-free and bounded.

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
}

/// One axis's drive on the master side: the profile's state machine behind one interface.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DriveAxis {
    /// An FHPP drive.
    Fhpp(fhpp::FhppAxis),
    /// A CiA 402 drive.
    Cia402(cia402::Cia402Axis),
}
