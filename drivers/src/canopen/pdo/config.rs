//! Configuring a remote node's PDO over SDO, as a plan: the ordered writes, then the read-backs
//! that prove the node took them. Plain data in, plain data out, so any SDO client can run it.
//!
//! The order follows CiA 301 §7.4.8 (and the TLC5xx manual §3.3.4): a PDO's mapping and
//! identifier may change only while it is switched off, and the mapping only while sub00 is 0.
//!
//! 1. COB-ID with bit 31 set (the PDO stops existing; carries the new identifier already);
//! 2. mapping sub00 = 0;
//! 3. mapping sub01..subNN;
//! 4. mapping sub00 = N (the node checks the 64-bit total here);
//! 5. transmission type, inhibit time (TPDO), event timer, SYNC start value (TPDO, only if not
//!    0: DS301 v4.0 nodes have no sub06);
//! 6. the wanted COB-ID (bit 31 clear unless the PDO is meant to stay off).

use crate::canopen::pdo::comm::{
    COB_ID_INVALID, CobId, CommError, SUB_COB_ID, SUB_EVENT_TIMER, SUB_INHIBIT_TIME,
    SUB_SYNC_START, SUB_TRANSMISSION_TYPE, TransmissionType,
};
use crate::canopen::pdo::mapping::{Mapping, MappingError};
use crate::canopen::{Address, FunctionCode, NodeId};

/// The most SDO writes (and read-backs) one PDO needs.
pub const MAX_STEPS: usize = 16;

/// Receive or transmit PDO (as the node sees it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PdoDirection {
    /// The node receives it: 1400h/1600h + k - 1.
    Rpdo,
    /// The node transmits it: 1800h/1A00h + k - 1.
    Tpdo,
}

impl PdoDirection {
    /// The communication parameter index of PDO `k` (1-based).
    pub const fn comm_index(self, k: u16) -> u16 {
        match self {
            PdoDirection::Rpdo => 0x1400 + k - 1,
            PdoDirection::Tpdo => 0x1800 + k - 1,
        }
    }
    /// The mapping parameter index of PDO `k` (1-based).
    pub const fn mapping_index(self, k: u16) -> u16 {
        match self {
            PdoDirection::Rpdo => 0x1600 + k - 1,
            PdoDirection::Tpdo => 0x1A00 + k - 1,
        }
    }
}

/// What is wanted for one PDO of a node, as plain numbers (as a configuration file states them).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PdoSettings<'a> {
    /// RPDO or TPDO.
    pub direction: PdoDirection,
    /// The PDO number k, 1..=512.
    pub number: u16,
    /// The whole COB-ID entry (bits 31/30/29 included); `None` = the predefined connection
    /// set's identifier for k = 1..=4, valid, RTR allowed.
    pub cob_id: Option<u32>,
    /// The mapping entries `index << 16 | sub << 8 | bits`.
    pub mapping: &'a [u32],
    /// sub02.
    pub transmission_type: u8,
    /// sub03, 100 µs (TPDO only; must be 0 for an RPDO).
    pub inhibit_100us: u16,
    /// sub05, ms.
    pub event_timer_ms: u16,
    /// sub06 (TPDO only; must be 0 for an RPDO).
    pub sync_start: u8,
}

/// One SDO transfer of a plan: write `value` (`size` bytes) to `addr`, or expect it on reading.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ConfigStep {
    /// The object.
    pub addr: Address,
    /// The value written, or expected on read-back.
    pub value: u32,
    /// Its size in bytes (1, 2 or 4): the expedited SDO length.
    pub size: u8,
}

/// Why a plan is refused before anything is sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum PlanError {
    /// PDO numbers are 1..=512.
    #[error("PDO number {0} is outside 1..=512")]
    Number(u16),
    /// Only PDOs 1..=4 have a predefined identifier.
    #[error("PDO {0} has no predefined COB-ID; give one")]
    NoDefaultCobId(u16),
    /// The mapping cannot work (too many entries or bits, a zero length).
    #[error(transparent)]
    Mapping(#[from] MappingError),
    /// The communication parameters cannot work (reserved type, identifier range).
    #[error(transparent)]
    Comm(#[from] CommError),
    /// RTR-only types 252/253 do not exist for RPDOs.
    #[error("transmission type {0} is for TPDOs only")]
    RtrTypeForRpdo(u8),
    /// Inhibit time or SYNC start value given for an RPDO, which has neither.
    #[error("RPDOs have no sub-index {sub:02X}h (value {value} given)")]
    RpdoParameter {
        /// The sub-index.
        sub: u8,
        /// The value asked for.
        value: u32,
    },
}

/// A read-back that does not match the plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum VerifyError {
    /// The node holds another value than was written.
    #[error("{addr}: expected {expected:#010x}, read {read:#010x}")]
    Mismatch {
        /// The object.
        addr: Address,
        /// The value the plan wrote.
        expected: u32,
        /// The value read back.
        read: u32,
    },
    /// The address is not one the plan reads back.
    #[error("{0} is not part of this plan")]
    NotInPlan(Address),
}

/// The SDO writes and read-backs that configure one PDO of one node.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConfigPlan {
    /// The node the SDO transfers go to.
    pub node: NodeId,
    writes: heapless::Vec<ConfigStep, MAX_STEPS>,
    reads: heapless::Vec<ConfigStep, MAX_STEPS>,
}

impl ConfigPlan {
    /// Plans the configuration of `pdo` on `node`; refuses settings that cannot work.
    pub fn new(node: NodeId, pdo: &PdoSettings<'_>) -> Result<ConfigPlan, PlanError> {
        let k = pdo.number;
        if !(1..=512).contains(&k) {
            return Err(PlanError::Number(k));
        }
        let mapping = Mapping::from_raw(pdo.mapping)?;
        let transmission = TransmissionType::from_u8(pdo.transmission_type)?;
        let rpdo = pdo.direction == PdoDirection::Rpdo;
        if rpdo && transmission.is_rtr_only() {
            return Err(PlanError::RtrTypeForRpdo(pdo.transmission_type));
        }
        if rpdo && pdo.inhibit_100us != 0 {
            return Err(PlanError::RpdoParameter {
                sub: SUB_INHIBIT_TIME,
                value: pdo.inhibit_100us as u32,
            });
        }
        if rpdo && pdo.sync_start != 0 {
            return Err(PlanError::RpdoParameter {
                sub: SUB_SYNC_START,
                value: pdo.sync_start as u32,
            });
        }
        let cob = match pdo.cob_id {
            Some(v) => v,
            None => {
                if k > 4 {
                    return Err(PlanError::NoDefaultCobId(k));
                }
                let f = if rpdo {
                    FunctionCode::Rpdo(k as u8)
                } else {
                    FunctionCode::Tpdo(k as u8)
                };
                CobId::standard(f.cob_id(node)).to_u32()
            }
        };
        let parsed = CobId::from_u32(cob);
        parsed.check()?;

        let comm = pdo.direction.comm_index(k);
        let map = pdo.direction.mapping_index(k);
        let mut plan = ConfigPlan {
            node,
            writes: heapless::Vec::new(),
            reads: heapless::Vec::new(),
        };
        let cob_addr = Address::new(comm, SUB_COB_ID);
        plan.write(cob_addr, cob | COB_ID_INVALID, 4);
        plan.write(Address::new(map, 0), 0, 1);
        for (i, e) in mapping.entries().iter().enumerate() {
            plan.write_and_check(Address::new(map, i as u8 + 1), e.to_u32(), 4);
        }
        plan.write_and_check(Address::new(map, 0), mapping.len() as u32, 1);
        plan.write_and_check(
            Address::new(comm, SUB_TRANSMISSION_TYPE),
            transmission.to_u8() as u32,
            1,
        );
        if !rpdo {
            plan.write_and_check(
                Address::new(comm, SUB_INHIBIT_TIME),
                pdo.inhibit_100us as u32,
                2,
            );
        }
        if !rpdo || pdo.event_timer_ms != 0 {
            plan.write_and_check(
                Address::new(comm, SUB_EVENT_TIMER),
                pdo.event_timer_ms as u32,
                2,
            );
        }
        if pdo.sync_start != 0 {
            plan.write_and_check(Address::new(comm, SUB_SYNC_START), pdo.sync_start as u32, 1);
        }
        plan.write_and_check(cob_addr, cob, 4);
        Ok(plan)
    }

    // At most 1 + 1 + 8 + 1 + 4 + 1 = 16 writes, so the pushes below cannot fail.
    fn write(&mut self, addr: Address, value: u32, size: u8) {
        let _ = self.writes.push(ConfigStep { addr, value, size });
    }

    fn write_and_check(&mut self, addr: Address, value: u32, size: u8) {
        self.write(addr, value, size);
        let step = ConfigStep { addr, value, size };
        // A later write to the same address (sub00, COB-ID) replaces the expectation.
        match self.reads.iter_mut().find(|r| r.addr == addr) {
            Some(r) => *r = step,
            None => {
                let _ = self.reads.push(step);
            }
        }
    }

    /// The SDO downloads, in order.
    pub fn writes(&self) -> &[ConfigStep] {
        &self.writes
    }

    /// The SDO uploads to do after the writes, with the values they must return; the last one
    /// is the COB-ID.
    pub fn reads(&self) -> &[ConfigStep] {
        &self.reads
    }

    /// Checks one read-back value.
    pub fn verify(&self, addr: Address, value: u32) -> Result<(), VerifyError> {
        let r = self
            .reads
            .iter()
            .find(|r| r.addr == addr)
            .ok_or(VerifyError::NotInPlan(addr))?;
        if r.value == value {
            Ok(())
        } else {
            Err(VerifyError::Mismatch {
                addr,
                expected: r.value,
                read: value,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node5() -> NodeId {
        NodeId::new(5).unwrap()
    }

    fn rpdo2() -> PdoSettings<'static> {
        PdoSettings {
            direction: PdoDirection::Rpdo,
            number: 2,
            cob_id: None,
            mapping: &[0x6040_0010, 0x607A_0020],
            transmission_type: 0,
            inhibit_100us: 0,
            event_timer_ms: 0,
            sync_start: 0,
        }
    }

    fn step(index: u16, sub: u8, value: u32, size: u8) -> ConfigStep {
        ConfigStep {
            addr: Address::new(index, sub),
            value,
            size,
        }
    }

    #[test]
    fn tlc_rpdo2_sequence() {
        let p = ConfigPlan::new(node5(), &rpdo2()).unwrap();
        assert_eq!(
            p.writes(),
            &[
                step(0x1401, 1, 0x8000_0305, 4),
                step(0x1601, 0, 0, 1),
                step(0x1601, 1, 0x6040_0010, 4),
                step(0x1601, 2, 0x607A_0020, 4),
                step(0x1601, 0, 2, 1),
                step(0x1401, 2, 0, 1),
                step(0x1401, 1, 0x0000_0305, 4),
            ]
        );
        assert_eq!(
            p.reads(),
            &[
                step(0x1601, 1, 0x6040_0010, 4),
                step(0x1601, 2, 0x607A_0020, 4),
                step(0x1601, 0, 2, 1),
                step(0x1401, 2, 0, 1),
                step(0x1401, 1, 0x0000_0305, 4),
            ]
        );
        assert_eq!(p.verify(Address::new(0x1601, 0), 2), Ok(()));
        assert_eq!(
            p.verify(Address::new(0x1401, 1), 0x8000_0305),
            Err(VerifyError::Mismatch {
                addr: Address::new(0x1401, 1),
                expected: 0x305,
                read: 0x8000_0305
            })
        );
        assert_eq!(
            p.verify(Address::new(0x1401, 3), 0),
            Err(VerifyError::NotInPlan(Address::new(0x1401, 3)))
        );
    }

    #[test]
    fn tpdo_with_timers_and_explicit_cob_id() {
        let p = ConfigPlan::new(
            node5(),
            &PdoSettings {
                direction: PdoDirection::Tpdo,
                number: 5,
                cob_id: Some(0x4000_0290),
                mapping: &[0x6041_0010, 0x6064_0020],
                transmission_type: 255,
                inhibit_100us: 50,
                event_timer_ms: 100,
                sync_start: 0,
            },
        )
        .unwrap();
        let w = p.writes();
        assert_eq!(w.first(), Some(&step(0x1804, 1, 0xC000_0290, 4)));
        assert!(w.contains(&step(0x1804, 3, 50, 2)));
        assert!(w.contains(&step(0x1804, 5, 100, 2)));
        assert!(!w.iter().any(|s| s.addr.sub == 6));
        assert_eq!(w.last(), Some(&step(0x1804, 1, 0x4000_0290, 4)));
        assert_eq!(p.reads().last(), w.last());
        // The mapping goes to 1A04h.
        assert!(w.contains(&step(0x1A04, 2, 0x6064_0020, 4)));
    }

    #[test]
    fn largest_plan_fits() {
        let map = [0x2000_0108u32; 8];
        let p = ConfigPlan::new(
            node5(),
            &PdoSettings {
                direction: PdoDirection::Tpdo,
                number: 1,
                cob_id: None,
                mapping: &map,
                transmission_type: 1,
                inhibit_100us: 1,
                event_timer_ms: 1,
                sync_start: 2,
            },
        )
        .unwrap();
        assert_eq!(p.writes().len(), MAX_STEPS);
        assert_eq!(p.reads().len(), 14);
    }

    #[test]
    fn refuses_what_cannot_work() {
        let plan = |f: &dyn Fn(&mut PdoSettings<'static>)| {
            let mut s = rpdo2();
            f(&mut s);
            ConfigPlan::new(node5(), &s)
        };
        assert_eq!(
            plan(&|s| s.mapping = &[0x6040_0010, 0x607A_0020, 0x60FF_0020]),
            Err(PlanError::Mapping(MappingError::TooManyBits { bits: 80 }))
        );
        assert_eq!(
            plan(&|s| s.transmission_type = 241),
            Err(PlanError::Comm(CommError::ReservedType(241)))
        );
        assert_eq!(
            plan(&|s| s.transmission_type = 252),
            Err(PlanError::RtrTypeForRpdo(252))
        );
        assert_eq!(plan(&|s| s.number = 0), Err(PlanError::Number(0)));
        assert_eq!(plan(&|s| s.number = 5), Err(PlanError::NoDefaultCobId(5)));
        assert_eq!(
            plan(&|s| s.cob_id = Some(0x800)),
            Err(PlanError::Comm(CommError::IdOutOfRange {
                id: 0x800,
                extended: false
            }))
        );
        assert_eq!(
            plan(&|s| s.inhibit_100us = 3),
            Err(PlanError::RpdoParameter { sub: 3, value: 3 })
        );
    }
}
