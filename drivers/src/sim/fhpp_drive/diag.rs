//! The documented faults and warnings of the three FHPP devices, as data: the number each device
//! reports, whether it is a fault or a warning, how it is acknowledged (T9 serious / T10
//! simple), the EMCY code and error-register bit, and the MTR-DCI device-fault bit (PNU 205).
//!
//! Sources: MTR-DCI digest §8.1 Tab. 6/6 and §7.7 Tab. 6/11 (serious/simple per erratum E9);
//! EMCA digest §7 and §2.11; CMMO-ST digest §7. For EMCA/CMMO-ST the class follows the default
//! reaction this simulator picks among the permitted ones (A–D output stage off = serious,
//! E–G on = simple); the manuals' factory reactions are lost in the extracts.

/// A cause the simulator can detect or have injected, independent of the device's numbering.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FaultKind {
    /// START without a valid reference (MTR-DCI 1, EMCA/CMMO-ST 28h).
    NotReferenced,
    /// The fieldbus connection was lost. The CMMO-ST's Modbus node guard expired: 47h (Modbus
    /// held master control; a fault by default) or 48h (it did not; a warning that clears on
    /// reconnection). The EMCA's EtherCAT link (SM watchdog, or Op left): 50h / 51h.
    FieldbusLost {
        /// Whether the fieldbus held master control.
        master_control: bool,
    },
    /// The target lies beyond a software end position (MTR-DCI 2; 29h negative, 2Ah positive).
    TargetOutOfLimit {
        /// Beyond the upper limit.
        positive: bool,
    },
    /// The record is invalid or not executable (MTR-DCI warning 3; 3Fh).
    InvalidRecord,
    /// The record number is out of range (MTR-DCI warning 3; EMCA 2Ch; CMMO-ST 3Fh).
    RecordNumber,
    /// A direct-mode setpoint that cannot run, e.g. 0 % speed (MTR-DCI warning 3; EMCA 21h;
    /// CMMO-ST 4Ch).
    InvalidSetpoint,
    /// Following (drag) error (MTR-DCI 31 / 8600h; 2Fh).
    FollowingError,
    /// Homing failed or was aborted (MTR-DCI 32 / 5441h; 22h).
    HomingError,
    /// The homing method is not one the device runs (MTR-DCI 32; 3Bh).
    HomingMethod,
    /// A speed/force task reached a software end position (EMCA/CMMO-ST 11h positive, 12h
    /// negative); the MTR-DCI just ends the task.
    SoftwareLimit {
        /// The upper limit.
        positive: bool,
    },
    /// Load / DC-link voltage missing (MTR-DCI 70 / 5112h; 1Bh / 3220h).
    LoadVoltage,
    /// Output stage over-temperature (MTR-DCI 101 / 4210h; 15h / 4210h).
    OverTemperature,
    /// I²t (MTR-DCI 100 / 2310h; 0Eh / 2312h).
    I2t,
    /// Panel emergency stop (MTR-DCI 106 / 7122h only).
    MotorStop,
    /// Hardware / EEPROM fault (MTR-DCI 52 / 7600h; EMCA/CMMO-ST general error 0Ah).
    Hardware,
    /// STO requested (EMCA/CMMO-ST 34h).
    Sto,
    /// Two start edges in one input cycle (CMMO-ST 3Ch).
    TwoEdges,
    /// Standstill monitoring (MTR-DCI warning 36; 37h).
    Standstill,
    /// Teach not possible on this target (EMCA/CMMO-ST warning 40h).
    TeachFailed,
    /// CANopen life guarding: no guard poll within the life time. MTR-DCI: fault reaction
    /// 605Eh = 2 (emergency ramp), reported as the CAN-bus fault 51 (device bit 8000h); EMCA:
    /// diagnostic 1Ch. Both send the CiA 301 EMCY 8130h (communication bit).
    LifeGuarding,
}

/// Fault or warning.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Severity {
    /// SCON.FAULT, a fault reaction, an acknowledge needed.
    Fault,
    /// SCON.WARN only; motion goes on.
    Warning,
}

/// How a device reports one [`FaultKind`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct DiagInfo {
    /// MTR-DCI fault number (decimal) or EMCA/CMMO-ST diagnostic number.
    pub number: u16,
    /// Fault or warning.
    pub severity: Severity,
    /// Serious: the output stage goes off (T9 to S2); simple: it stays on (T10 to S3).
    pub serious: bool,
    /// The EMCY error code the manual prints, `None` where it prints none (warnings never send
    /// one; see [`super::Emcy`] for what a transport sends instead).
    pub emcy: Option<u16>,
    /// Error register 1001h bit mask (bit 0 "generic" is added when sent).
    pub register: u8,
    /// MTR-DCI device-fault bit (PNU 205 / 2FF1h); 0 elsewhere.
    pub device_bit: u16,
    /// The cause must be gone before an acknowledge is taken (EMCA/CMMO-ST "cause"; PNU 230 =
    /// 1); otherwise acknowledgeable at once (PNU 230 = 2).
    pub needs_cause_gone: bool,
}

const CUR: u8 = 0x02;
const VOLT: u8 = 0x04;
const TEMP: u8 = 0x08;
const COMM: u8 = 0x10;
const PROF: u8 = 0x20;
const MANU: u8 = 0x80;

const fn fault(number: u16, serious: bool, emcy: Option<u16>, register: u8) -> DiagInfo {
    DiagInfo {
        number,
        severity: Severity::Fault,
        serious,
        emcy,
        register,
        device_bit: 0,
        needs_cause_gone: false,
    }
}

const fn warning(number: u16) -> DiagInfo {
    DiagInfo {
        number,
        severity: Severity::Warning,
        serious: false,
        emcy: None,
        register: 0,
        device_bit: 0,
        needs_cause_gone: false,
    }
}

const fn bit(mut d: DiagInfo, device_bit: u16) -> DiagInfo {
    d.device_bit = device_bit;
    d
}

const fn cause(mut d: DiagInfo) -> DiagInfo {
    d.needs_cause_gone = true;
    d
}

impl FaultKind {
    /// How `variant` reports this cause; `None` where the device has no such message.
    pub const fn info(self, variant: crate::fhpp::Variant) -> Option<DiagInfo> {
        use crate::fhpp::Variant::{CmmoSt, Emca, MtrDci};
        use FaultKind as K;
        let emca = matches!(variant, Emca);
        Some(match (variant, self) {
            // MTR-DCI, Tab. 6/6 + Tab. 6/11; serious/simple per E9.
            (MtrDci, K::NotReferenced) => bit(fault(1, false, Some(0x6310), PROF), 0x0200),
            (MtrDci, K::TargetOutOfLimit { .. }) => {
                bit(fault(2, false, Some(0x6320), PROF), 0x0080)
            }
            (MtrDci, K::InvalidRecord | K::RecordNumber | K::InvalidSetpoint) => {
                bit(warning(3), 0x0100)
            }
            (MtrDci, K::FollowingError) => bit(fault(31, false, Some(0x8600), PROF), 0x0001),
            (MtrDci, K::HomingError | K::HomingMethod) => {
                bit(fault(32, false, Some(0x5441), PROF), 0x0004)
            }
            (MtrDci, K::LoadVoltage) => cause(bit(fault(70, true, Some(0x5112), VOLT), 0x0010)),
            (MtrDci, K::OverTemperature) => {
                cause(bit(fault(101, true, Some(0x4210), TEMP), 0x0008))
            }
            (MtrDci, K::I2t) => cause(bit(fault(100, true, Some(0x2310), CUR), 0x0020)),
            (MtrDci, K::MotorStop) => bit(fault(106, false, Some(0x7122), PROF), 0x0002),
            (MtrDci, K::Hardware) => cause(bit(fault(52, true, Some(0x7600), PROF), 0x0040)),
            (MtrDci, K::Standstill) => bit(warning(36), 0x4000),
            // E9: CAN faults (51) are serious.
            (MtrDci, K::LifeGuarding) => bit(fault(51, true, Some(0x8130), COMM), 0x8000),
            (MtrDci, K::SoftwareLimit { .. } | K::Sto | K::TwoEdges | K::TeachFailed) => {
                return None;
            }
            // EMCA / CMMO-ST.
            (_, K::NotReferenced) => fault(0x28, false, None, PROF),
            // 47h: "F", acknowledgeable at once; 48h: "W/I", clears on reconnection.
            (
                CmmoSt,
                K::FieldbusLost {
                    master_control: true,
                },
            ) => fault(0x47, false, None, 0x10),
            (
                CmmoSt,
                K::FieldbusLost {
                    master_control: false,
                },
            ) => warning(0x48),
            // The EMCA on EtherCAT (seed-002 §7): 50h with master control (EMCY 8100h, a fault
            // whose reaction keeps the output stage on), 51h without (a warning: the fieldbus
            // did not control the drive, so losing it stops nothing).
            (
                Emca,
                K::FieldbusLost {
                    master_control: true,
                },
            ) => fault(0x50, false, Some(0x8100), COMM),
            (
                Emca,
                K::FieldbusLost {
                    master_control: false,
                },
            ) => warning(0x51),
            (_, K::FieldbusLost { .. }) => return None,
            (_, K::TargetOutOfLimit { positive }) => {
                fault(if positive { 0x2A } else { 0x29 }, false, None, PROF)
            }
            (_, K::InvalidRecord) => {
                fault(0x3F, false, if emca { Some(0xFF19) } else { None }, MANU)
            }
            (Emca, K::RecordNumber) => fault(0x2C, false, None, PROF),
            (_, K::RecordNumber) => fault(0x3F, false, None, MANU),
            (Emca, K::InvalidSetpoint) => fault(0x21, false, None, PROF),
            (_, K::InvalidSetpoint) => fault(0x4C, false, None, PROF),
            (_, K::FollowingError) => cause(fault(0x2F, true, None, PROF)),
            (_, K::HomingError) => fault(0x22, false, None, PROF),
            (_, K::HomingMethod) => {
                fault(0x3B, false, if emca { Some(0xFF15) } else { None }, PROF)
            }
            (_, K::SoftwareLimit { positive }) => {
                fault(if positive { 0x11 } else { 0x12 }, false, None, PROF)
            }
            (_, K::LoadVoltage) => cause(fault(
                0x1B,
                true,
                if emca { Some(0x3220) } else { None },
                VOLT,
            )),
            (_, K::OverTemperature) => cause(fault(
                0x15,
                true,
                if emca { Some(0x4210) } else { None },
                TEMP,
            )),
            (_, K::I2t) => cause(fault(
                0x0E,
                true,
                if emca { Some(0x2312) } else { None },
                CUR,
            )),
            (_, K::MotorStop) => return None,
            (_, K::Hardware) => cause(fault(
                0x0A,
                true,
                if emca { Some(0xFF03) } else { None },
                MANU,
            )),
            (_, K::Sto) => cause(fault(
                0x34,
                true,
                if emca { Some(0xFF26) } else { None },
                MANU,
            )),
            (Emca, K::LifeGuarding) => fault(0x1C, true, Some(0x8130), COMM),
            (_, K::LifeGuarding) => return None,
            (CmmoSt, K::TwoEdges) => fault(0x3C, false, None, PROF),
            (_, K::TwoEdges) => return None,
            (_, K::Standstill) => warning(0x37),
            (_, K::TeachFailed) => warning(0x40),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fhpp::Variant;

    #[test]
    fn mtr_dci_numbers_and_emcy_codes_follow_tab_6_11() {
        let f = |k: FaultKind| k.info(Variant::MtrDci).unwrap();
        assert_eq!(
            (
                f(FaultKind::FollowingError).number,
                f(FaultKind::FollowingError).emcy
            ),
            (31, Some(0x8600))
        );
        assert_eq!(f(FaultKind::NotReferenced).emcy, Some(0x6310));
        assert_eq!(f(FaultKind::LoadVoltage).emcy, Some(0x5112));
        assert!(f(FaultKind::LoadVoltage).serious);
        assert!(!f(FaultKind::HomingError).serious);
        assert_eq!(f(FaultKind::InvalidRecord).severity, Severity::Warning);
        assert_eq!(f(FaultKind::Standstill).device_bit, 0x4000);
        assert!(FaultKind::Sto.info(Variant::MtrDci).is_none());
    }

    #[test]
    fn emca_and_cmmo_diagnostic_numbers() {
        for v in [Variant::Emca, Variant::CmmoSt] {
            let f = |k: FaultKind| k.info(v).unwrap();
            assert_eq!(f(FaultKind::NotReferenced).number, 0x28);
            assert_eq!(
                f(FaultKind::TargetOutOfLimit { positive: true }).number,
                0x2A
            );
            assert_eq!(
                f(FaultKind::TargetOutOfLimit { positive: false }).number,
                0x29
            );
            assert_eq!(f(FaultKind::FollowingError).number, 0x2F);
            assert_eq!(f(FaultKind::Standstill).severity, Severity::Warning);
        }
        assert_eq!(
            FaultKind::RecordNumber.info(Variant::Emca).unwrap().number,
            0x2C
        );
        assert_eq!(
            FaultKind::RecordNumber
                .info(Variant::CmmoSt)
                .unwrap()
                .number,
            0x3F
        );
        assert!(FaultKind::TwoEdges.info(Variant::Emca).is_none());
        assert_eq!(
            FaultKind::TwoEdges.info(Variant::CmmoSt).unwrap().number,
            0x3C
        );
    }
}
