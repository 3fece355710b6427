//! Emergency messages (CiA 301 §7.2.7): the 8-byte EMCY frame, the error register 1001h, the
//! error code classes, the producer (1014h COB-ID, 1015h inhibit time, 1003h pre-defined error
//! field) and the consumer that keeps the last error of every node.
//!
//! ```
//! use drivers::canopen::emcy::EmcyMessage;
//! // seed-003 §8.7: `081: 12 22 00 00 00 00 00 00`.
//! let m = EmcyMessage::from_bytes(&[0x12, 0x22, 0, 0, 0, 0, 0, 0]).unwrap();
//! assert_eq!(m.code, 0x2212);
//! assert_eq!(m.description(), "current inside the device");
//! ```

use super::cob::ids;
use super::{AbortCode, NodeId};
use crate::can::Frame;
use crate::time::Instant;
use core::time::Duration;
use heapless::{Deque, Vec};

/// Why an EMCY frame, object value or request was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EmcyError {
    /// An EMCY has exactly 8 data bytes.
    #[error("an EMCY has DLC 8, not {0}")]
    WrongLength(u8),
    /// A remote frame on an EMCY COB-ID.
    #[error("an EMCY must be a data frame, not a remote frame")]
    Remote,
    /// Code 0000h means "error reset"; it is sent by [`EmcyProducer::clear`], not raised.
    #[error("error code 0000h (error reset) cannot be raised as an error")]
    ZeroCode,
    /// More distinct errors active at once than the producer holds.
    #[error("at most {0} errors can be active at once")]
    TooManyErrors(usize),
    /// The transmit queue is full (the inhibit time holds frames back).
    #[error("the EMCY transmit queue is full ({0} frames)")]
    QueueFull(usize),
    /// 1014h with bit 29 set (29-bit identifier), which this stack does not produce.
    #[error("COB-ID EMCY {0:#010x} selects a 29-bit identifier, which is not supported")]
    ExtendedId(u32),
}

/// One emergency message: `[code lo, code hi, register, manufacturer[0..5]]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct EmcyMessage {
    /// The error code (603Fh on CiA 402 devices).
    pub code: u16,
    /// The error register 1001h at the time.
    pub register: u8,
    /// The manufacturer-specific error field.
    pub manufacturer: [u8; 5],
}

impl EmcyMessage {
    /// The 8 data bytes.
    pub const fn to_bytes(&self) -> [u8; 8] {
        let c = self.code.to_le_bytes();
        let m = self.manufacturer;
        [c[0], c[1], self.register, m[0], m[1], m[2], m[3], m[4]]
    }

    /// Decodes the data bytes; exactly 8 are required.
    pub fn from_bytes(data: &[u8]) -> Result<EmcyMessage, EmcyError> {
        let &[c0, c1, register, m0, m1, m2, m3, m4] = data else {
            return Err(EmcyError::WrongLength(data.len() as u8));
        };
        Ok(EmcyMessage {
            code: u16::from_le_bytes([c0, c1]),
            register,
            manufacturer: [m0, m1, m2, m3, m4],
        })
    }

    /// The frame on COB-ID `cob_id`.
    pub fn to_frame(&self, cob_id: u16) -> Frame {
        Frame::std8(cob_id, self.to_bytes())
    }

    /// Decodes a frame's data (the COB-ID is the caller's business).
    pub fn from_frame(f: &Frame) -> Result<EmcyMessage, EmcyError> {
        if f.is_remote() {
            return Err(EmcyError::Remote);
        }
        Self::from_bytes(f.data())
    }

    /// The class of the error code.
    pub const fn class(&self) -> ErrorClass {
        ErrorClass::of(self.code)
    }

    /// What the error code means.
    pub const fn description(&self) -> &'static str {
        describe(self.code)
    }
}

/// The error register 1001h.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct ErrorRegister(pub u8);

impl ErrorRegister {
    /// Bit 0: generic error, set while any error is active.
    pub const GENERIC: u8 = 1 << 0;
    /// Bit 1: current.
    pub const CURRENT: u8 = 1 << 1;
    /// Bit 2: voltage.
    pub const VOLTAGE: u8 = 1 << 2;
    /// Bit 3: temperature.
    pub const TEMPERATURE: u8 = 1 << 3;
    /// Bit 4: communication error (overrun, error state).
    pub const COMMUNICATION: u8 = 1 << 4;
    /// Bit 5: device profile specific.
    pub const DEVICE_PROFILE: u8 = 1 << 5;
    /// Bit 7: manufacturer specific.
    pub const MANUFACTURER: u8 = 1 << 7;

    /// Whether every bit of `mask` is set.
    pub const fn contains(self, mask: u8) -> bool {
        self.0 & mask == mask
    }
}

/// The classes of CiA 301 error codes (Table 21), by the code's leading digits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ErrorClass {
    /// 00xxh: error reset or no error.
    NoError,
    /// 1xxxh: generic error.
    Generic,
    /// 2xxxh: current.
    Current,
    /// 3xxxh: voltage.
    Voltage,
    /// 4xxxh: temperature.
    Temperature,
    /// 5xxxh: device hardware.
    DeviceHardware,
    /// 6xxxh: device software.
    DeviceSoftware,
    /// 7xxxh: additional modules.
    AdditionalModules,
    /// 8xxxh: monitoring (81xxh communication, 82xxh protocol errors among them).
    Monitoring,
    /// 9xxxh: external error.
    External,
    /// F0xxh: additional functions.
    AdditionalFunctions,
    /// FFxxh: device specific.
    DeviceSpecific,
    /// A range CiA 301 reserves (Axxxh..Exxxh, F1xxh..FExxh).
    Reserved,
}

impl ErrorClass {
    /// The class of `code`.
    pub const fn of(code: u16) -> ErrorClass {
        match code >> 12 {
            0x0 if code >> 8 == 0 => ErrorClass::NoError,
            0x1 => ErrorClass::Generic,
            0x2 => ErrorClass::Current,
            0x3 => ErrorClass::Voltage,
            0x4 => ErrorClass::Temperature,
            0x5 => ErrorClass::DeviceHardware,
            0x6 => ErrorClass::DeviceSoftware,
            0x7 => ErrorClass::AdditionalModules,
            0x8 => ErrorClass::Monitoring,
            0x9 => ErrorClass::External,
            0xF if code >> 8 == 0xF0 => ErrorClass::AdditionalFunctions,
            0xF if code >> 8 == 0xFF => ErrorClass::DeviceSpecific,
            _ => ErrorClass::Reserved,
        }
    }
}

/// The error register bits (besides the generic bit) an active error with `code` sets.
pub const fn register_bits(code: u16) -> u8 {
    match ErrorClass::of(code) {
        ErrorClass::NoError => 0,
        ErrorClass::Current => ErrorRegister::GENERIC | ErrorRegister::CURRENT,
        ErrorClass::Voltage => ErrorRegister::GENERIC | ErrorRegister::VOLTAGE,
        ErrorClass::Temperature => ErrorRegister::GENERIC | ErrorRegister::TEMPERATURE,
        // 81xxh communication and 82xxh protocol errors are communication errors.
        ErrorClass::Monitoring if code >> 8 == 0x81 || code >> 8 == 0x82 => {
            ErrorRegister::GENERIC | ErrorRegister::COMMUNICATION
        }
        ErrorClass::DeviceSpecific => ErrorRegister::GENERIC | ErrorRegister::MANUFACTURER,
        _ => ErrorRegister::GENERIC,
    }
}

/// What an error code means: the specific CiA 301 (and common CiA 402) codes first, then the
/// class.
pub const fn describe(code: u16) -> &'static str {
    match code {
        0x0000 => "error reset or no error",
        0x1000 => "generic error",
        0x2100 => "current, device input side",
        0x2200 => "current inside the device",
        0x2300 => "current, device output side",
        0x2310 => "continuous over-current",
        0x3100 => "mains voltage",
        0x3200 => "voltage inside the device",
        0x3210 => "DC link over-voltage",
        0x3220 => "DC link under-voltage",
        0x3300 => "output voltage",
        0x4100 => "ambient temperature",
        0x4200 => "device temperature",
        0x4310 => "drive temperature",
        0x6100 => "internal software",
        0x6200 => "user software",
        0x6300 => "data set",
        0x7320 => "position sensor",
        0x8100 => "communication",
        0x8110 => "CAN overrun (objects lost)",
        0x8120 => "CAN in error passive mode",
        0x8130 => "life guard error or heartbeat error",
        0x8140 => "recovered from bus off",
        0x8150 => "CAN-ID collision",
        0x8200 => "protocol error",
        0x8210 => "PDO not processed due to length error",
        0x8220 => "PDO length exceeded",
        0x8240 => "unexpected SYNC data length",
        0x8250 => "RPDO timeout",
        0x8611 => "following error",
        _ => match ErrorClass::of(code) {
            ErrorClass::NoError => "error reset or no error",
            ErrorClass::Generic => "generic error",
            ErrorClass::Current if code >> 8 == 0x22 => "current inside the device",
            ErrorClass::Current => "current",
            ErrorClass::Voltage => "voltage",
            ErrorClass::Temperature => "temperature",
            ErrorClass::DeviceHardware => "device hardware",
            ErrorClass::DeviceSoftware => "device software",
            ErrorClass::AdditionalModules => "additional modules",
            ErrorClass::Monitoring if code >> 8 == 0x81 => "communication",
            ErrorClass::Monitoring if code >> 8 == 0x82 => "protocol error",
            ErrorClass::Monitoring => "monitoring",
            ErrorClass::External => "external error",
            ErrorClass::AdditionalFunctions => "additional functions",
            ErrorClass::DeviceSpecific => "device specific",
            ErrorClass::Reserved => "reserved error code",
        },
    }
}

/// The value of 1014h, COB-ID EMCY.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct EmcyCobId {
    /// Bit 31 clear: the EMCY object exists and is sent.
    pub valid: bool,
    /// Bits 10..0.
    pub id: u16,
}

impl EmcyCobId {
    /// The pre-defined connection set entry, valid, 80h + node.
    pub const fn for_node(node: NodeId) -> EmcyCobId {
        EmcyCobId {
            valid: true,
            id: ids::EMCY + node.get() as u16,
        }
    }

    /// Decodes 1014h. Bit 30 is reserved and ignored: the TLC5xx prints its default as
    /// 4000_0080h + n (erratum A14), so both forms are accepted.
    pub const fn from_u32(raw: u32) -> Result<EmcyCobId, EmcyError> {
        if raw & (1 << 29) != 0 {
            return Err(EmcyError::ExtendedId(raw));
        }
        Ok(EmcyCobId {
            valid: raw & (1 << 31) == 0,
            id: (raw & 0x7FF) as u16,
        })
    }

    /// Encodes 1014h.
    pub const fn to_u32(self) -> u32 {
        ((!self.valid as u32) << 31) | (self.id & 0x7FF) as u32
    }
}

/// The EMCY producer of a device. `N` bounds the errors active at once, the depth of the
/// pre-defined error field 1003h and the frames waiting for the inhibit time.
///
/// It only builds frames; the device calls [`EmcyProducer::poll_transmit`] only in NMT states
/// that allow EMCY (not in Stopped).
#[derive(Debug)]
pub struct EmcyProducer<const N: usize> {
    cob: EmcyCobId,
    inhibit: Duration,
    /// Active codes with the register bits each sets.
    active: Vec<(u16, u8), N>,
    history: Vec<u32, N>,
    pending: Deque<EmcyMessage, N>,
    last_sent: Option<Instant>,
}

impl<const N: usize> EmcyProducer<N> {
    /// A producer from 1014h and 1015h (inhibit time in 100 µs units, 0 = none).
    pub fn new(cob: EmcyCobId, inhibit_100us: u16) -> Self {
        EmcyProducer {
            cob,
            inhibit: Duration::from_micros(inhibit_100us as u64 * 100),
            active: Vec::new(),
            history: Vec::new(),
            pending: Deque::new(),
            last_sent: None,
        }
    }

    /// Rewrites 1014h.
    pub fn set_cob_id(&mut self, cob: EmcyCobId) {
        self.cob = cob;
    }

    /// Rewrites 1015h (100 µs units).
    pub fn set_inhibit(&mut self, inhibit_100us: u16) {
        self.inhibit = Duration::from_micros(inhibit_100us as u64 * 100);
    }

    /// The error register 1001h: the generic bit while any error is active, plus each active
    /// error's class bit.
    pub fn register(&self) -> ErrorRegister {
        ErrorRegister(self.active.iter().fold(0, |r, &(_, b)| r | b))
    }

    /// Whether `code` is active.
    pub fn is_active(&self, code: u16) -> bool {
        self.active.iter().any(|&(c, _)| c == code)
    }

    /// An error occurred: records it in 1001h and 1003h and queues its EMCY. Raising an error
    /// that is already active does nothing (one EMCY per occurrence). On `Err` nothing changed.
    pub fn raise(&mut self, code: u16, manufacturer: [u8; 5]) -> Result<(), EmcyError> {
        self.raise_with_register(code, register_bits(code), manufacturer)
    }

    /// As [`EmcyProducer::raise`], with the 1001h bits the device's manual names for this code
    /// instead of those of its CiA 301 class (the generic bit is always added).
    pub fn raise_with_register(
        &mut self,
        code: u16,
        register: u8,
        manufacturer: [u8; 5],
    ) -> Result<(), EmcyError> {
        if code == 0 {
            return Err(EmcyError::ZeroCode);
        }
        if self.is_active(code) {
            return Ok(());
        }
        if self.active.is_full() {
            return Err(EmcyError::TooManyErrors(N));
        }
        if self.pending.is_full() {
            return Err(EmcyError::QueueFull(N));
        }
        let _ = self.active.push((code, register | ErrorRegister::GENERIC)); // room checked above
        if N > 0 {
            if self.history.is_full() {
                // 1003h keeps the newest N: the oldest falls off.
                self.history.pop();
            }
            let _ = self.history.insert(0, code as u32);
        }
        let msg = EmcyMessage {
            code,
            register: self.register().0,
            manufacturer,
        };
        let _ = self.pending.push_back(msg); // room checked above
        Ok(())
    }

    /// An active error is reported again (the EMCA repeats a fault's EMCY when an acknowledge
    /// is refused): queues its EMCY and records it in 1003h; 1001h is unchanged. An error that
    /// is not active is raised with its class bits.
    pub fn repeat(&mut self, code: u16, manufacturer: [u8; 5]) -> Result<(), EmcyError> {
        if !self.is_active(code) {
            return self.raise(code, manufacturer);
        }
        if self.pending.is_full() {
            return Err(EmcyError::QueueFull(N));
        }
        if N > 0 {
            if self.history.is_full() {
                self.history.pop();
            }
            let _ = self.history.insert(0, code as u32);
        }
        let msg = EmcyMessage {
            code,
            register: self.register().0,
            manufacturer,
        };
        let _ = self.pending.push_back(msg); // room checked above
        Ok(())
    }

    /// An error went away. When it was the last one, queues the error-reset EMCY (code 0000h,
    /// register 00h). Clearing an error that is not active does nothing.
    pub fn clear(&mut self, code: u16) -> Result<(), EmcyError> {
        let Some(pos) = self.active.iter().position(|&(c, _)| c == code) else {
            return Ok(());
        };
        if self.active.len() == 1 && self.pending.is_full() {
            return Err(EmcyError::QueueFull(N));
        }
        self.active.swap_remove(pos);
        if self.active.is_empty() {
            let reset = EmcyMessage {
                code: 0,
                register: 0,
                manufacturer: [0; 5],
            };
            let _ = self.pending.push_back(reset); // room checked above
        }
        Ok(())
    }

    /// 1003h sub00: how many errors the history holds.
    pub fn history_len(&self) -> u8 {
        self.history.len() as u8
    }

    /// 1003h sub01..: entry `sub` (1 = newest), bits 15..0 the error code.
    pub fn history_entry(&self, sub: u8) -> Option<u32> {
        self.history.get((sub as usize).checked_sub(1)?).copied()
    }

    /// A write to 1003h sub00: 0 clears the history, anything else is refused (CiA 301).
    pub fn write_history_len(&mut self, value: u8) -> Result<(), AbortCode> {
        if value != 0 {
            return Err(AbortCode::InvalidValue);
        }
        self.history.clear();
        Ok(())
    }

    /// When the next EMCY may go out, if one is waiting (a time in the past means now). Nothing
    /// waits while 1014h is invalid.
    pub fn poll_timeout(&self) -> Option<Instant> {
        if !self.cob.valid || self.pending.is_empty() {
            return None;
        }
        Some(self.last_sent.map_or(Instant::ZERO, |t| t + self.inhibit))
    }

    /// The next EMCY frame, once the inhibit time since the previous one has passed. While
    /// 1014h is invalid the EMCY object does not exist: waiting frames are discarded (1001h and
    /// 1003h still record the errors).
    pub fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        if !self.cob.valid {
            self.pending.clear();
            return None;
        }
        if now < self.poll_timeout()? {
            return None;
        }
        let msg = self.pending.pop_front()?;
        self.last_sent = Some(now);
        Some(msg.to_frame(self.cob.id))
    }
}

/// An EMCY received from a node.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct EmcyEvent {
    /// The sender (from the COB-ID, 80h + node).
    pub node: NodeId,
    /// The error code (0000h: the node's errors are all cleared).
    pub code: u16,
    /// The node's error register.
    pub register: u8,
    /// The manufacturer-specific field.
    pub manufacturer: [u8; 5],
    /// What the code means.
    pub description: &'static str,
}

/// The master's EMCY consumer: decodes EMCY frames from every node on the pre-defined
/// COB-IDs 81h..FFh and keeps each node's last error (a fixed table of 127 entries, so it is
/// never full).
#[derive(Debug, Clone)]
pub struct EmcyConsumer {
    accept_legacy_boot_up: bool,
    last_error: [Option<EmcyMessage>; 127],
    in_error: [bool; 127],
}

impl EmcyConsumer {
    /// A consumer. With `accept_legacy_boot_up`, frames of DLC 0 or 1 on 80h+n are the
    /// TLC5xx's boot-up message (handled by the NMT master) and are skipped instead of being
    /// reported as malformed EMCYs.
    pub fn new(accept_legacy_boot_up: bool) -> Self {
        EmcyConsumer {
            accept_legacy_boot_up,
            last_error: [None; 127],
            in_error: [false; 127],
        }
    }

    /// Feeds a frame. Frames that are not on 81h..FFh give `Ok(None)`; a malformed EMCY a
    /// typed error.
    pub fn handle_frame(&mut self, f: &Frame) -> Result<Option<EmcyEvent>, EmcyError> {
        let Some(cob) = f.cob_id() else {
            return Ok(None);
        };
        if cob & !0x7F != ids::EMCY {
            return Ok(None);
        }
        let Some(node) = NodeId::new((cob & 0x7F) as u8) else {
            return Ok(None); // 080h is SYNC
        };
        if self.accept_legacy_boot_up && !f.is_remote() && f.dlc() <= 1 {
            return Ok(None);
        }
        let msg = EmcyMessage::from_frame(f)?;
        let i = node.get() as usize - 1;
        if let (Some(last), Some(flag)) = (self.last_error.get_mut(i), self.in_error.get_mut(i)) {
            *flag = msg.code != 0;
            if msg.code != 0 {
                *last = Some(msg);
            }
        }
        Ok(Some(EmcyEvent {
            node,
            code: msg.code,
            register: msg.register,
            manufacturer: msg.manufacturer,
            description: msg.description(),
        }))
    }

    /// The last error (non-zero code) the node reported, kept after it is cleared.
    pub fn last_error(&self, node: NodeId) -> Option<EmcyMessage> {
        *self.last_error.get(node.get() as usize - 1)?
    }

    /// Whether the node's latest EMCY reported an error (not the 0000h reset).
    pub fn in_error(&self, node: NodeId) -> bool {
        self.in_error
            .get(node.get() as usize - 1)
            .copied()
            .unwrap_or(false)
    }
}

impl Default for EmcyConsumer {
    fn default() -> Self {
        Self::new(true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::str::FromStr;

    fn f(s: &str) -> Frame {
        Frame::from_str(s).unwrap()
    }
    fn n(id: u8) -> NodeId {
        NodeId::new(id).unwrap()
    }

    #[test]
    fn manual_example_decodes() {
        // seed-003 §8.7.
        let fr = f("081#1222000000000000");
        let m = EmcyMessage::from_frame(&fr).unwrap();
        assert_eq!(m.code, 0x2212);
        assert_eq!(m.register, 0);
        assert_eq!(m.class(), ErrorClass::Current);
        assert_eq!(m.to_frame(0x081), fr);
        let m = EmcyMessage {
            code: 0x8130,
            register: 0x11,
            manufacturer: [1, 2, 3, 4, 5],
        };
        assert_eq!(m.to_bytes(), [0x30, 0x81, 0x11, 1, 2, 3, 4, 5]);
        assert_eq!(EmcyMessage::from_bytes(&m.to_bytes()), Ok(m));
    }

    #[test]
    fn short_frames_are_typed_errors() {
        assert_eq!(
            EmcyMessage::from_frame(&f("081#12220000")),
            Err(EmcyError::WrongLength(4))
        );
        assert_eq!(
            EmcyMessage::from_frame(&f("081#R8")),
            Err(EmcyError::Remote)
        );
    }

    #[test]
    fn classes_and_descriptions() {
        assert_eq!(describe(0x0000), "error reset or no error");
        assert_eq!(describe(0x8110), "CAN overrun (objects lost)");
        assert_eq!(describe(0x8120), "CAN in error passive mode");
        assert_eq!(describe(0x8130), "life guard error or heartbeat error");
        assert_eq!(describe(0x8140), "recovered from bus off");
        assert_eq!(describe(0x5123), "device hardware");
        assert_eq!(describe(0xF001), "additional functions");
        assert_eq!(describe(0xFF22), "device specific");
        assert_eq!(describe(0x9000), "external error");
        assert_eq!(ErrorClass::of(0x6310), ErrorClass::DeviceSoftware);
        assert_eq!(ErrorClass::of(0x7320), ErrorClass::AdditionalModules);
        assert_eq!(ErrorClass::of(0x1000), ErrorClass::Generic);
        assert_eq!(ErrorClass::of(0xA000), ErrorClass::Reserved);
        assert_eq!(ErrorClass::of(0xF100), ErrorClass::Reserved);
        assert_eq!(register_bits(0x4310), 0x09);
        assert_eq!(register_bits(0x8130), 0x11);
        assert_eq!(register_bits(0x8611), 0x01);
        assert_eq!(register_bits(0xFF22), 0x81);
    }

    #[test]
    fn cob_id_object() {
        assert_eq!(
            EmcyCobId::from_u32(0x4000_0081),
            Ok(EmcyCobId::for_node(n(1)))
        );
        assert_eq!(
            EmcyCobId::from_u32(0x0000_0081),
            Ok(EmcyCobId::for_node(n(1)))
        );
        assert!(!EmcyCobId::from_u32(0x8000_0081).unwrap().valid);
        assert_eq!(EmcyCobId::for_node(n(1)).to_u32(), 0x81);
        assert_eq!(
            EmcyCobId::from_u32(0x2000_0081),
            Err(EmcyError::ExtendedId(0x2000_0081))
        );
    }

    #[test]
    fn manual_register_bits_and_repeat() {
        let mut p: EmcyProducer<4> = EmcyProducer::new(EmcyCobId::for_node(n(1)), 0);
        // 6310h is "device software" in CiA 301 (generic only); the MTR-DCI sets bit 5.
        p.raise_with_register(0x6310, 0x20, [0; 5]).unwrap();
        let t = Instant::from_millis(1);
        assert_eq!(p.poll_transmit(t), Some(f("081#1063210000000000")));
        // Repeated while active: sent and logged again, 1001h unchanged.
        p.repeat(0x6310, [0; 5]).unwrap();
        assert_eq!(p.poll_transmit(t), Some(f("081#1063210000000000")));
        assert_eq!(p.history_len(), 2);
        assert_eq!(p.register(), ErrorRegister(0x21));
        p.clear(0x6310).unwrap();
        assert_eq!(p.poll_transmit(t), Some(f("081#0000000000000000")));
        // Repeating an inactive error raises it with its class bits.
        p.repeat(0x2310, [0; 5]).unwrap();
        assert_eq!(p.poll_transmit(t), Some(f("081#1023030000000000")));
    }

    #[test]
    fn producer_respects_inhibit_time() {
        // 1015h = 10 -> 1 ms between EMCYs.
        let mut p: EmcyProducer<4> = EmcyProducer::new(EmcyCobId::for_node(n(1)), 10);
        assert_eq!(p.poll_timeout(), None);
        p.raise(0x2310, [0; 5]).unwrap();
        p.raise(0x4310, [0; 5]).unwrap();
        let t0 = Instant::from_millis(100);
        assert_eq!(p.poll_transmit(t0), Some(f("081#1023030000000000")));
        // The second waits out the inhibit time, then carries the register as it was raised.
        assert_eq!(p.poll_timeout(), Some(Instant::from_micros(101_000)));
        assert_eq!(p.poll_transmit(Instant::from_micros(100_999)), None);
        assert_eq!(
            p.poll_transmit(Instant::from_micros(101_000)),
            Some(f("081#10430B0000000000"))
        );
        assert_eq!(p.poll_transmit(Instant::from_millis(200)), None);
        assert_eq!(p.register(), ErrorRegister(0x0B));
        // Raising an active error again sends nothing.
        p.raise(0x2310, [0; 5]).unwrap();
        assert_eq!(p.poll_timeout(), None);
    }

    #[test]
    fn producer_sends_reset_when_last_error_clears() {
        let mut p: EmcyProducer<4> = EmcyProducer::new(EmcyCobId::for_node(n(4)), 0);
        p.raise(0x8130, [0; 5]).unwrap();
        p.raise(0x3210, [9, 0, 0, 0, 0]).unwrap();
        assert!(p.poll_transmit(Instant::ZERO).is_some());
        assert_eq!(
            p.poll_transmit(Instant::ZERO),
            Some(f("084#1032150900000000"))
        );
        p.clear(0x8130).unwrap();
        assert_eq!(p.poll_transmit(Instant::ZERO), None);
        assert_eq!(p.register(), ErrorRegister(0x05));
        p.clear(0x3210).unwrap();
        assert_eq!(p.register(), ErrorRegister(0));
        assert_eq!(
            p.poll_transmit(Instant::ZERO),
            Some(f("084#0000000000000000"))
        );
        // Clearing again does nothing.
        p.clear(0x3210).unwrap();
        assert_eq!(p.poll_transmit(Instant::ZERO), None);
        assert_eq!(p.raise(0, [0; 5]), Err(EmcyError::ZeroCode));
    }

    #[test]
    fn producer_keeps_1003h_history_newest_first() {
        let mut p: EmcyProducer<3> = EmcyProducer::new(EmcyCobId::for_node(n(1)), 0);
        for code in [0x1000, 0x2310, 0x3210] {
            p.raise(code, [0; 5]).unwrap();
            assert!(p.poll_transmit(Instant::ZERO).is_some());
        }
        assert_eq!(p.history_len(), 3);
        assert_eq!(p.history_entry(1), Some(0x3210));
        assert_eq!(p.history_entry(3), Some(0x1000));
        assert_eq!(p.history_entry(0), None);
        assert_eq!(p.history_entry(4), None);
        // A fourth error while three are active: refused, nothing changed.
        assert_eq!(p.raise(0x4310, [0; 5]), Err(EmcyError::TooManyErrors(3)));
        assert_eq!(p.history_len(), 3);
        p.clear(0x1000).unwrap();
        p.raise(0x4310, [0; 5]).unwrap();
        // The oldest falls off.
        assert_eq!(p.history_entry(1), Some(0x4310));
        assert_eq!(p.history_entry(3), Some(0x2310));
        assert_eq!(p.write_history_len(2), Err(AbortCode::InvalidValue));
        assert_eq!(p.history_len(), 3);
        p.write_history_len(0).unwrap();
        assert_eq!(p.history_len(), 0);
        assert_eq!(p.history_entry(1), None);
        // The history clear does not clear the active errors.
        assert_eq!(p.register(), ErrorRegister(0x0F));
    }

    #[test]
    fn producer_queue_is_bounded_and_invalid_cob_sends_nothing() {
        let mut p: EmcyProducer<2> = EmcyProducer::new(EmcyCobId::for_node(n(1)), 0);
        p.raise(0x1000, [0; 5]).unwrap();
        p.raise(0x2310, [0; 5]).unwrap();
        p.clear(0x1000).unwrap();
        // Clearing the last error needs a queue slot for the reset EMCY.
        assert_eq!(p.clear(0x2310), Err(EmcyError::QueueFull(2)));
        assert!(p.is_active(0x2310));
        p.set_cob_id(EmcyCobId {
            valid: false,
            id: 0x81,
        });
        assert_eq!(p.poll_timeout(), None);
        assert_eq!(p.poll_transmit(Instant::ZERO), None);
        p.set_cob_id(EmcyCobId::for_node(n(1)));
        assert_eq!(p.poll_transmit(Instant::ZERO), None);
    }

    #[test]
    fn consumer_keeps_last_error_per_node() {
        let mut c = EmcyConsumer::new(true);
        assert_eq!(c.handle_frame(&f("080#")), Ok(None));
        assert_eq!(c.handle_frame(&f("181#0000")), Ok(None));
        // Legacy boot-ups are skipped.
        assert_eq!(c.handle_frame(&f("0FF#")), Ok(None));
        assert_eq!(c.handle_frame(&f("0FF#00")), Ok(None));
        let e = c.handle_frame(&f("081#1222000000000000")).unwrap().unwrap();
        assert_eq!(e.node, n(1));
        assert_eq!(e.code, 0x2212);
        assert_eq!(e.register, 0);
        assert_eq!(e.description, "current inside the device");
        assert!(c.in_error(n(1)));
        assert!(!c.in_error(n(2)));
        let e = c.handle_frame(&f("0FF#30811100000000AA")).unwrap().unwrap();
        assert_eq!(e.node, n(127));
        assert_eq!(e.manufacturer, [0, 0, 0, 0, 0xAA]);
        let e = c.handle_frame(&f("081#0000000000000000")).unwrap().unwrap();
        assert_eq!(e.description, "error reset or no error");
        assert!(!c.in_error(n(1)));
        assert_eq!(c.last_error(n(1)).map(|m| m.code), Some(0x2212));
        assert_eq!(c.last_error(n(127)).map(|m| m.code), Some(0x8130));
        assert_eq!(
            c.handle_frame(&f("082#122200")),
            Err(EmcyError::WrongLength(3))
        );
        let mut strict = EmcyConsumer::new(false);
        assert_eq!(
            strict.handle_frame(&f("0FF#")),
            Err(EmcyError::WrongLength(0))
        );
    }
}
