//! PDO communication parameters (1400h.. for RPDOs, 1800h.. for TPDOs): COB-ID, transmission
//! type, inhibit time, event timer, SYNC start value.

use core::time::Duration;

use crate::can::Frame;
use crate::canopen::od::ObjectDictionary;
use crate::canopen::{AbortCode, Address, FunctionCode, NodeId};

/// Sub-index of the COB-ID (UNSIGNED32).
pub const SUB_COB_ID: u8 = 1;
/// Sub-index of the transmission type (UNSIGNED8).
pub const SUB_TRANSMISSION_TYPE: u8 = 2;
/// Sub-index of the inhibit time (UNSIGNED16, 100 µs).
pub const SUB_INHIBIT_TIME: u8 = 3;
/// Sub-index of the event timer (UNSIGNED16, ms).
pub const SUB_EVENT_TIMER: u8 = 5;
/// Sub-index of the SYNC start value (UNSIGNED8, TPDOs only).
pub const SUB_SYNC_START: u8 = 6;

/// Bit 31 of the COB-ID entry: 1 = the PDO does not exist (is switched off).
pub const COB_ID_INVALID: u32 = 1 << 31;
/// Bit 30: 1 = no RTR is allowed on this PDO.
pub const COB_ID_NO_RTR: u32 = 1 << 30;
/// Bit 29: 1 = 29-bit (extended) CAN identifier.
pub const COB_ID_EXTENDED: u32 = 1 << 29;

/// Why communication parameters are refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum CommError {
    /// Transmission types 241..=251 are reserved.
    #[error("transmission type {0} is reserved (241..=251)")]
    ReservedType(u8),
    /// A parameter could not be read from the dictionary.
    #[error("{addr} could not be read: {code}")]
    Od {
        /// The entry.
        addr: Address,
        /// Why.
        code: AbortCode,
    },
    /// The identifier does not fit the frame type (above 7FFh for 11 bits, 1FFF FFFFh for 29).
    #[error("CAN identifier {id:#x} does not fit a {} identifier", if *extended { "29-bit" } else { "11-bit" })]
    IdOutOfRange {
        /// The identifier.
        id: u32,
        /// Whether bit 29 asks for a 29-bit identifier.
        extended: bool,
    },
}

/// The COB-ID entry (sub01) of a PDO.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct CobId {
    /// The CAN identifier (11 or 29 bits).
    pub id: u32,
    /// Bit 31 clear: the PDO exists and runs.
    pub valid: bool,
    /// Bit 30 clear: remote frames may request it.
    pub rtr_allowed: bool,
    /// Bit 29 set: 29-bit identifier.
    pub extended: bool,
}

impl CobId {
    /// A valid 11-bit COB-ID with RTR allowed.
    pub const fn standard(id: u16) -> CobId {
        CobId {
            id: id as u32,
            valid: true,
            rtr_allowed: true,
            extended: false,
        }
    }
    /// The same COB-ID with bit 31 set (switched off).
    pub const fn invalid(self) -> CobId {
        CobId {
            valid: false,
            ..self
        }
    }
    /// Decodes the 32-bit entry value. Bits 28..11 of an 11-bit COB-ID must be 0: they are kept
    /// in `id` so that [`CobId::check`] refuses them.
    pub const fn from_u32(v: u32) -> CobId {
        let extended = v & COB_ID_EXTENDED != 0;
        CobId {
            id: v & 0x1FFF_FFFF,
            valid: v & COB_ID_INVALID == 0,
            rtr_allowed: v & COB_ID_NO_RTR == 0,
            extended,
        }
    }
    /// The 32-bit entry value.
    pub const fn to_u32(self) -> u32 {
        let mut v = self.id;
        if !self.valid {
            v |= COB_ID_INVALID;
        }
        if !self.rtr_allowed {
            v |= COB_ID_NO_RTR;
        }
        if self.extended {
            v |= COB_ID_EXTENDED;
        }
        v
    }
    /// Checks the identifier fits the frame type.
    pub const fn check(self) -> Result<(), CommError> {
        let max = if self.extended { 0x1FFF_FFFF } else { 0x7FF };
        if self.id > max {
            Err(CommError::IdOutOfRange {
                id: self.id,
                extended: self.extended,
            })
        } else {
            Ok(())
        }
    }
    /// Whether `frame` carries this identifier (data or remote).
    pub fn matches(self, frame: &Frame) -> bool {
        frame.is_extended() == self.extended && frame.raw_id() == self.id
    }
    /// Whether the PDO is valid and `frame` carries its identifier: what its engine accepts.
    pub fn accepts(self, frame: &Frame) -> bool {
        self.valid && self.matches(frame)
    }
    /// A data frame with this identifier, `None` if the identifier or length is out of range.
    pub fn data_frame(self, data: &[u8]) -> Option<Frame> {
        if self.extended {
            Frame::new_ext(self.id, data).ok()
        } else {
            Frame::new_std(self.id as u16, data).ok()
        }
    }
    /// A remote frame requesting this PDO (`dlc` = the mapped length).
    pub fn remote_frame(self, dlc: u8) -> Option<Frame> {
        let id = if self.extended {
            embedded_can::Id::Extended(embedded_can::ExtendedId::new(self.id)?)
        } else {
            embedded_can::Id::Standard(embedded_can::StandardId::new(self.id as u16)?)
        };
        Frame::new_remote(id, dlc).ok()
    }
}

/// When a PDO is sent (TPDO) or applied (RPDO): sub02.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TransmissionType {
    /// 0: synchronous, acyclic. TPDO: sent at the SYNC after its data changed. RPDO: applied at
    /// the next SYNC.
    SyncAcyclic,
    /// 1..=240: synchronous, cyclic. TPDO: sent every n-th SYNC. RPDO: applied at the next SYNC.
    /// Build it with [`TransmissionType::from_u8`], which keeps n in range.
    SyncCyclic(u8),
    /// 252: data sampled at SYNC, sent on RTR.
    SyncRtr,
    /// 253: sent on RTR with the data of that moment.
    AsyncRtr,
    /// 254: event-driven, event defined by the manufacturer.
    EventManufacturer,
    /// 255: event-driven, event defined by the device profile.
    EventProfile,
}

impl TransmissionType {
    /// Decodes sub02; 241..=251 are reserved.
    pub const fn from_u8(v: u8) -> Result<TransmissionType, CommError> {
        Ok(match v {
            0 => TransmissionType::SyncAcyclic,
            1..=240 => TransmissionType::SyncCyclic(v),
            252 => TransmissionType::SyncRtr,
            253 => TransmissionType::AsyncRtr,
            254 => TransmissionType::EventManufacturer,
            255 => TransmissionType::EventProfile,
            _ => return Err(CommError::ReservedType(v)),
        })
    }
    /// The sub02 value.
    pub const fn to_u8(self) -> u8 {
        match self {
            TransmissionType::SyncAcyclic => 0,
            TransmissionType::SyncCyclic(n) => n,
            TransmissionType::SyncRtr => 252,
            TransmissionType::AsyncRtr => 253,
            TransmissionType::EventManufacturer => 254,
            TransmissionType::EventProfile => 255,
        }
    }
    /// Whether the PDO is tied to SYNC (0..=240 and 252).
    pub const fn is_synchronous(self) -> bool {
        matches!(
            self,
            TransmissionType::SyncAcyclic
                | TransmissionType::SyncCyclic(_)
                | TransmissionType::SyncRtr
        )
    }
    /// Whether the PDO is sent on a change of its data or its event timer (254, 255).
    pub const fn is_event_driven(self) -> bool {
        matches!(
            self,
            TransmissionType::EventManufacturer | TransmissionType::EventProfile
        )
    }
    /// Whether the PDO is only sent on request (252, 253).
    pub const fn is_rtr_only(self) -> bool {
        matches!(self, TransmissionType::SyncRtr | TransmissionType::AsyncRtr)
    }
}

/// The communication parameters of one PDO.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct CommParams {
    /// sub01.
    pub cob_id: CobId,
    /// sub02.
    pub transmission: TransmissionType,
    /// sub03: the minimum time between two transmissions of an event-driven TPDO, in 100 µs.
    pub inhibit_100us: u16,
    /// sub05: an event-driven TPDO is also sent when this many ms passed since the last one;
    /// 0 = off.
    pub event_timer_ms: u16,
    /// sub06: a cyclic TPDO starts at the SYNC whose counter equals this; 0 = at the first SYNC.
    pub sync_start: u8,
}

impl CommParams {
    /// Parameters with no inhibit time, no event timer and no SYNC start value.
    pub const fn new(cob_id: CobId, transmission: TransmissionType) -> CommParams {
        CommParams {
            cob_id,
            transmission,
            inhibit_100us: 0,
            event_timer_ms: 0,
            sync_start: 0,
        }
    }
    /// The predefined connection set's TPDO `k` (1..=4) of `node`, event-driven (255), valid.
    pub const fn default_tpdo(k: u8, node: NodeId) -> CommParams {
        CommParams::new(
            CobId::standard(FunctionCode::Tpdo(k).cob_id(node)),
            TransmissionType::EventProfile,
        )
    }
    /// The predefined connection set's RPDO `k` (1..=4) of `node`, event-driven (255), valid.
    pub const fn default_rpdo(k: u8, node: NodeId) -> CommParams {
        CommParams::new(
            CobId::standard(FunctionCode::Rpdo(k).cob_id(node)),
            TransmissionType::EventProfile,
        )
    }
    /// The inhibit time.
    pub const fn inhibit_time(&self) -> Duration {
        Duration::from_micros(self.inhibit_100us as u64 * 100)
    }
    /// The event timer period, `None` when off.
    pub const fn event_timer(&self) -> Option<Duration> {
        if self.event_timer_ms == 0 {
            None
        } else {
            Some(Duration::from_millis(self.event_timer_ms as u64))
        }
    }
    /// Decodes the sub-index values; checks the type and the identifier.
    pub const fn from_od_values(
        cob_id: u32,
        transmission_type: u8,
        inhibit_100us: u16,
        event_timer_ms: u16,
        sync_start: u8,
    ) -> Result<CommParams, CommError> {
        let cob_id = CobId::from_u32(cob_id);
        if let Err(e) = cob_id.check() {
            return Err(e);
        }
        let transmission = match TransmissionType::from_u8(transmission_type) {
            Ok(t) => t,
            Err(e) => return Err(e),
        };
        Ok(CommParams {
            cob_id,
            transmission,
            inhibit_100us,
            event_timer_ms,
            sync_start,
        })
    }
    /// Reads the record at `index` from a dictionary (a device building its engines from its
    /// own configuration). sub01 and sub02 must exist; a missing sub03, sub05 or sub06 is 0.
    pub fn from_od<const N: usize, const B: usize>(
        od: &ObjectDictionary<'_, N, B>,
        index: u16,
    ) -> Result<CommParams, CommError> {
        let get = |sub: u8, required: bool| {
            let addr = Address::new(index, sub);
            match od.get_u32(addr) {
                Ok(v) => Ok(v),
                Err(AbortCode::NoSubIndex | AbortCode::NoObject) if !required => Ok(0),
                Err(code) => Err(CommError::Od { addr, code }),
            }
        };
        let cob = get(SUB_COB_ID, true)?;
        let ty = get(SUB_TRANSMISSION_TYPE, true)?;
        let inhibit = get(SUB_INHIBIT_TIME, false)?;
        let event = get(SUB_EVENT_TIMER, false)?;
        let start = get(SUB_SYNC_START, false)?;
        CommParams::from_od_values(cob, ty as u8, inhibit as u16, event as u16, start as u8)
    }

    /// The entries as `(sub-index, value, size in bytes)` for sub01, 02, 03, 05, 06, in that
    /// order, for the record at `index` (1400h + k - 1 or 1800h + k - 1).
    pub const fn od_values(&self, index: u16) -> [(Address, u32, u8); 5] {
        [
            (Address::new(index, SUB_COB_ID), self.cob_id.to_u32(), 4),
            (
                Address::new(index, SUB_TRANSMISSION_TYPE),
                self.transmission.to_u8() as u32,
                1,
            ),
            (
                Address::new(index, SUB_INHIBIT_TIME),
                self.inhibit_100us as u32,
                2,
            ),
            (
                Address::new(index, SUB_EVENT_TIMER),
                self.event_timer_ms as u32,
                2,
            ),
            (
                Address::new(index, SUB_SYNC_START),
                self.sync_start as u32,
                1,
            ),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cob_id_bits() {
        // TLC5xx 1402h:01 = 8000 04xxh is off, 0000 04xxh is on.
        let off = CobId::from_u32(0x8000_0405);
        assert!(!off.valid && off.rtr_allowed && !off.extended);
        assert_eq!(off.id, 0x405);
        assert_eq!(off.to_u32(), 0x8000_0405);
        let on = CobId::from_u32(0x0000_0405);
        assert!(on.valid);
        let no_rtr_ext = CobId::from_u32(0x6123_4567);
        assert!(!no_rtr_ext.rtr_allowed && no_rtr_ext.extended);
        assert_eq!(no_rtr_ext.id, 0x0123_4567);
        assert_eq!(no_rtr_ext.to_u32(), 0x6123_4567);
        assert_eq!(
            CobId {
                id: 0x800,
                ..CobId::standard(0)
            }
            .check(),
            Err(CommError::IdOutOfRange {
                id: 0x800,
                extended: false
            })
        );
        let f = CobId::standard(0x185).data_frame(&[1, 2]).unwrap();
        assert!(CobId::standard(0x185).matches(&f));
        assert!(!no_rtr_ext.matches(&f));
        let r = CobId::standard(0x185).remote_frame(2).unwrap();
        assert!(r.is_remote() && CobId::standard(0x185).matches(&r));
    }

    #[test]
    fn transmission_types() {
        for v in 0..=255u8 {
            match TransmissionType::from_u8(v) {
                Ok(t) => assert_eq!(t.to_u8(), v),
                Err(e) => {
                    assert!((241..=251).contains(&v));
                    assert_eq!(e, CommError::ReservedType(v));
                }
            }
        }
        assert!(TransmissionType::SyncRtr.is_synchronous());
        assert!(TransmissionType::SyncRtr.is_rtr_only());
        assert!(!TransmissionType::AsyncRtr.is_synchronous());
        assert!(TransmissionType::EventManufacturer.is_event_driven());
    }

    #[test]
    fn od_values_and_units() {
        let node = NodeId::new(5).unwrap();
        let mut c = CommParams::default_tpdo(1, node);
        c.inhibit_100us = 25;
        c.event_timer_ms = 1000;
        assert_eq!(c.inhibit_time(), Duration::from_micros(2500));
        assert_eq!(c.event_timer(), Some(Duration::from_secs(1)));
        let v = c.od_values(0x1800);
        assert_eq!(v[0], (Address::new(0x1800, 1), 0x185, 4));
        assert_eq!(v[1], (Address::new(0x1800, 2), 255, 1));
        assert_eq!(v[2], (Address::new(0x1800, 3), 25, 2));
        assert_eq!(v[3], (Address::new(0x1800, 5), 1000, 2));
        let back = CommParams::from_od_values(v[0].1, v[1].1 as u8, 25, 1000, 0).unwrap();
        assert_eq!(back, c);
        assert_eq!(
            CommParams::from_od_values(0x185, 245, 0, 0, 0),
            Err(CommError::ReservedType(245))
        );
        assert_eq!(CommParams::default_rpdo(2, node).cob_id.id, 0x305);
    }
}
