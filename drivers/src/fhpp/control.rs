//! The master's control bytes CCON, CPOS, CDIR and its 8 output bytes (MTR-DCI §5.5.2/§5.5.5,
//! EMCA p.123–133, CMMO-ST §5.3.2/§5.4.1).
//!
//! | byte | record select | direct mode |
//! |---|---|---|
//! | 1 | CCON | CCON |
//! | 2 | CPOS | CPOS |
//! | 3 | record number | CDIR |
//! | 4 | reserved 0 | setpoint value 1 (u8, a percentage) |
//! | 5..8 | reserved 0 | setpoint value 2 (i32: position, force or speed) |

use super::{ByteOrder, ControlMode, Opm, Variant, bit, set};

/// CCON, control byte 1: device control.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Ccon {
    /// B0 ENABLE: 1 = controller enabled, 0 = drive blocked.
    pub enable: bool,
    /// B1 STOP: 1 = operation enabled, 0 = stop (quick-stop/emergency ramp, task cancelled).
    pub stop: bool,
    /// B2 BRAKE: 1 = release the brake while the controller is blocked (EMCA, CMMO-ST);
    /// reserved on the MTR-DCI.
    pub brake: bool,
    /// B3 RESET: a rising edge acknowledges a fault.
    pub reset: bool,
    /// B5 LOCK: 1 = FCT/HMI may only observe and cannot take device control.
    pub lock: bool,
    /// B6/B7 OPM1/OPM2: the operating mode.
    pub opm: Opm,
}

impl Ccon {
    /// Bit number of ENABLE.
    pub const ENABLE: u8 = 0;
    /// Bit number of STOP.
    pub const STOP: u8 = 1;
    /// Bit number of BRAKE.
    pub const BRAKE: u8 = 2;
    /// Bit number of RESET.
    pub const RESET: u8 = 3;
    /// Bit number of LOCK.
    pub const LOCK: u8 = 5;
    /// Bit number of OPM1 (OPM2 is the next bit).
    pub const OPM1: u8 = 6;
    /// Bit number of OPM2.
    pub const OPM2: u8 = 7;
    /// The reserved bit (B4), which must be 0.
    pub const RESERVED_MASK: u8 = 0x10;

    /// Decodes the byte; the reserved bit B4 is dropped (see [`Ccon::RESERVED_MASK`]).
    pub const fn from_byte(b: u8) -> Ccon {
        Ccon {
            enable: bit(b, Self::ENABLE),
            stop: bit(b, Self::STOP),
            brake: bit(b, Self::BRAKE),
            reset: bit(b, Self::RESET),
            lock: bit(b, Self::LOCK),
            opm: Opm::from_bits(b >> Self::OPM1),
        }
    }
    /// Encodes the byte; B4 is 0.
    pub const fn to_byte(self) -> u8 {
        set(self.enable, Self::ENABLE)
            | set(self.stop, Self::STOP)
            | set(self.brake, Self::BRAKE)
            | set(self.reset, Self::RESET)
            | set(self.lock, Self::LOCK)
            | (self.opm.bits() << Self::OPM1)
    }
}

/// CPOS, control byte 2: positioning control.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Cpos {
    /// B0 HALT (the MTR-DCI manual calls it HOLD): **active low**. 1 = no halt; 0 = halt on the
    /// task ramp, the position task stays active (resume with START, delete with CLEAR).
    pub halt: bool,
    /// B1 START: a rising edge takes over the setpoints (record or direct) and starts.
    pub start: bool,
    /// B2 HOM: a rising edge starts homing.
    pub hom: bool,
    /// B3 JOGP: level, jog toward larger actual values.
    pub jogp: bool,
    /// B4 JOGN: level, jog toward smaller actual values.
    pub jogn: bool,
    /// B5 TEACH: a falling edge stores the actual position into the PNU 520 target.
    pub teach: bool,
    /// B6 CLEAR: a rising edge in the halt state deletes the remaining path.
    pub clear: bool,
}

impl Cpos {
    /// Bit number of HALT (HOLD).
    pub const HALT: u8 = 0;
    /// Bit number of START.
    pub const START: u8 = 1;
    /// Bit number of HOM.
    pub const HOM: u8 = 2;
    /// Bit number of JOGP.
    pub const JOGP: u8 = 3;
    /// Bit number of JOGN.
    pub const JOGN: u8 = 4;
    /// Bit number of TEACH.
    pub const TEACH: u8 = 5;
    /// Bit number of CLEAR.
    pub const CLEAR: u8 = 6;
    /// The reserved bit (B7), which must be 0.
    pub const RESERVED_MASK: u8 = 0x80;

    /// HALT = 1 (no halt) and nothing else: the idle pattern of a running machine.
    pub const fn idle() -> Cpos {
        Cpos {
            halt: true,
            start: false,
            hom: false,
            jogp: false,
            jogn: false,
            teach: false,
            clear: false,
        }
    }
    /// Decodes the byte; the reserved bit B7 is dropped.
    pub const fn from_byte(b: u8) -> Cpos {
        Cpos {
            halt: bit(b, Self::HALT),
            start: bit(b, Self::START),
            hom: bit(b, Self::HOM),
            jogp: bit(b, Self::JOGP),
            jogn: bit(b, Self::JOGN),
            teach: bit(b, Self::TEACH),
            clear: bit(b, Self::CLEAR),
        }
    }
    /// Encodes the byte; B7 is 0.
    pub const fn to_byte(self) -> u8 {
        set(self.halt, Self::HALT)
            | set(self.start, Self::START)
            | set(self.hom, Self::HOM)
            | set(self.jogp, Self::JOGP)
            | set(self.jogn, Self::JOGN)
            | set(self.teach, Self::TEACH)
            | set(self.clear, Self::CLEAR)
    }
}

/// CDIR, control byte 3 in direct mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Cdir {
    /// B0 ABS: 0 = setpoint absolute (to the project zero point); 1 = relative. The reference
    /// of a relative setpoint is the last setpoint on the MTR-DCI (digest 000 E13), and chosen
    /// by PNU 524 bit 0 on EMCA/CMMO-ST (default: the actual position). Position mode only.
    pub abs: bool,
    /// B1/B2 COM1/COM2: control mode.
    pub com: ControlMode,
    /// B3 CONT: reserved 0.
    pub cont: bool,
    /// B4 VLIM: reserved 0.
    pub vlim: bool,
    /// B5 XLIM: 1 = stroke monitoring **off** (force and speed modes).
    pub xlim: bool,
    /// B6 FAST: reserved 0.
    pub fast: bool,
    /// B7 FUNC: reserved 0.
    pub func: bool,
}

impl Cdir {
    /// Bit number of ABS.
    pub const ABS: u8 = 0;
    /// Bit number of COM1 (COM2 is the next bit).
    pub const COM1: u8 = 1;
    /// Bit number of COM2.
    pub const COM2: u8 = 2;
    /// Bit number of CONT.
    pub const CONT: u8 = 3;
    /// Bit number of VLIM.
    pub const VLIM: u8 = 4;
    /// Bit number of XLIM.
    pub const XLIM: u8 = 5;
    /// Bit number of FAST.
    pub const FAST: u8 = 6;
    /// Bit number of FUNC.
    pub const FUNC: u8 = 7;

    /// Decodes the byte (every bit has a name, so nothing is dropped).
    pub const fn from_byte(b: u8) -> Cdir {
        Cdir {
            abs: bit(b, Self::ABS),
            com: ControlMode::from_bits(b >> Self::COM1),
            cont: bit(b, Self::CONT),
            vlim: bit(b, Self::VLIM),
            xlim: bit(b, Self::XLIM),
            fast: bit(b, Self::FAST),
            func: bit(b, Self::FUNC),
        }
    }
    /// Encodes the byte.
    pub const fn to_byte(self) -> u8 {
        set(self.abs, Self::ABS)
            | (self.com.bits() << Self::COM1)
            | set(self.cont, Self::CONT)
            | set(self.vlim, Self::VLIM)
            | set(self.xlim, Self::XLIM)
            | set(self.fast, Self::FAST)
            | set(self.func, Self::FUNC)
    }
}

/// Bytes 3..8 of the output image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum OutputPayload {
    /// Record select: byte 3 = record number (0 = homing); bytes 4..8 reserved (0).
    Record {
        /// The record to start.
        record: u8,
    },
    /// Direct mode.
    Direct(DirectSetpoint),
}

/// The direct-mode setpoints, bytes 3..8.
///
/// | COM | `value1` (byte 4) | `value2` (bytes 5..8) |
/// |---|---|---|
/// | position | speed, % of PNU 502 (MTR-DCI) / PNU 540 | target position \[inc / SINC\] |
/// | force | MTR-DCI: not used (speed limit is PNU 554); EMCA/CMMO-ST: speed limit % of PNU 540 | force: % of rated current (MTR-DCI) / ‰ of PNU 555 (EMCA, CMMO-ST) |
/// | speed | acceleration, % of PNU 560 | target speed \[SINC/s\], signed |
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct DirectSetpoint {
    /// CDIR, byte 3.
    pub cdir: Cdir,
    /// Setpoint value 1, byte 4 (a percentage; see [`super::units::percent_of`]).
    pub value1: u8,
    /// Setpoint value 2, bytes 5..8.
    pub value2: i32,
}

impl DirectSetpoint {
    /// A positioning task: `target` absolute (or relative if `relative`) at `speed_percent`.
    pub const fn position(target: i32, speed_percent: u8, relative: bool) -> DirectSetpoint {
        DirectSetpoint {
            cdir: Cdir {
                abs: relative,
                com: ControlMode::Position,
                cont: false,
                vlim: false,
                xlim: false,
                fast: false,
                func: false,
            },
            value1: speed_percent,
            value2: target,
        }
    }
    /// A force task: `force` (units per variant, see the type's table), speed limit
    /// `speed_percent`, stroke monitoring off if `stroke_monitoring_off`.
    pub const fn force(
        force: i32,
        speed_percent: u8,
        stroke_monitoring_off: bool,
    ) -> DirectSetpoint {
        DirectSetpoint {
            cdir: Cdir {
                abs: false,
                com: ControlMode::Force,
                cont: false,
                vlim: false,
                xlim: stroke_monitoring_off,
                fast: false,
                func: false,
            },
            value1: speed_percent,
            value2: force,
        }
    }
    /// A speed task: `speed` \[SINC/s\] (signed) with ramp `ramp_percent` of PNU 560.
    pub const fn speed(
        speed: i32,
        ramp_percent: u8,
        stroke_monitoring_off: bool,
    ) -> DirectSetpoint {
        DirectSetpoint {
            cdir: Cdir {
                abs: false,
                com: ControlMode::Speed,
                cont: false,
                vlim: false,
                xlim: stroke_monitoring_off,
                fast: false,
                func: false,
            },
            value1: ramp_percent,
            value2: speed,
        }
    }
}

/// Why an output or input image could not be decoded or does not fit the device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ImageError {
    /// The image is not 8 bytes long.
    #[error("FHPP image must be 8 bytes, got {len}")]
    Length {
        /// The length received.
        len: usize,
    },
    /// CCON.OPM / SCON.OPM holds a reserved mode (2 or 3), so bytes 3..8 have no meaning.
    #[error("FHPP operating mode {opm} is reserved")]
    ReservedOpm {
        /// The OPM bits (OPM2, OPM1) as a number.
        opm: u8,
    },
    /// The record number is above the device's last record.
    #[error("record {record} out of range 0..={max}")]
    RecordOutOfRange {
        /// The record number in byte 3.
        record: u8,
        /// The device's last record.
        max: u8,
    },
    /// The direct-mode control mode is reserved or the device lacks it.
    #[error("control mode {com} not supported by this device")]
    UnsupportedMode {
        /// The COM bits (COM2, COM1) as a number.
        com: u8,
    },
}

/// The master's 8 output bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct OutputImage {
    /// Byte 1.
    pub ccon: Ccon,
    /// Byte 2.
    pub cpos: Cpos,
    /// Bytes 3..8; their meaning follows `ccon.opm` (record select or direct).
    pub payload: OutputPayload,
}

impl OutputImage {
    /// A record-select image: CCON.OPM is set to record select.
    pub const fn record(mut ccon: Ccon, cpos: Cpos, record: u8) -> OutputImage {
        ccon.opm = Opm::RecordSelect;
        OutputImage {
            ccon,
            cpos,
            payload: OutputPayload::Record { record },
        }
    }
    /// A direct-mode image: CCON.OPM is set to direct.
    pub const fn direct(mut ccon: Ccon, cpos: Cpos, setpoint: DirectSetpoint) -> OutputImage {
        ccon.opm = Opm::Direct;
        OutputImage {
            ccon,
            cpos,
            payload: OutputPayload::Direct(setpoint),
        }
    }

    /// The 8 bytes; multi-byte values in `order`. The OPM bits written are those of the payload
    /// (record select or direct), whatever `ccon.opm` holds, so the image is self-consistent.
    // Inlined where it is called, as `InputImage::from_bytes`.
    #[inline]
    pub fn to_bytes(&self, order: ByteOrder) -> [u8; 8] {
        let mut ccon = self.ccon;
        let mut out = [0u8; 8];
        match self.payload {
            OutputPayload::Record { record } => {
                ccon.opm = Opm::RecordSelect;
                out[2] = record;
            }
            OutputPayload::Direct(d) => {
                ccon.opm = Opm::Direct;
                out[2] = d.cdir.to_byte();
                out[3] = d.value1;
                out[4..8].copy_from_slice(&order.u32_bytes(d.value2 as u32));
            }
        }
        out[0] = ccon.to_byte();
        out[1] = self.cpos.to_byte();
        out
    }

    /// Decodes 8 bytes; the payload follows CCON.OPM. Reserved bytes of record select are
    /// ignored.
    pub fn from_bytes(bytes: &[u8], order: ByteOrder) -> Result<OutputImage, ImageError> {
        let b: &[u8; 8] = bytes
            .try_into()
            .map_err(|_| ImageError::Length { len: bytes.len() })?;
        let ccon = Ccon::from_byte(b[0]);
        let cpos = Cpos::from_byte(b[1]);
        let payload = match ccon.opm {
            Opm::RecordSelect => OutputPayload::Record { record: b[2] },
            Opm::Direct => OutputPayload::Direct(DirectSetpoint {
                cdir: Cdir::from_byte(b[2]),
                value1: b[3],
                value2: order.u32_from([b[4], b[5], b[6], b[7]]) as i32,
            }),
            opm => return Err(ImageError::ReservedOpm { opm: opm.bits() }),
        };
        Ok(OutputImage {
            ccon,
            cpos,
            payload,
        })
    }

    /// Checks the image against what `variant` can execute: the record number range and the
    /// direct control mode. (A simulator turns an error into the device's own reaction, e.g.
    /// warning 3 "illegal record" on the MTR-DCI.)
    pub fn check(&self, variant: Variant) -> Result<(), ImageError> {
        match self.payload {
            OutputPayload::Record { record } if record > variant.max_record() => {
                Err(ImageError::RecordOutOfRange {
                    record,
                    max: variant.max_record(),
                })
            }
            OutputPayload::Direct(d) if !variant.supports(d.cdir.com) => {
                Err(ImageError::UnsupportedMode {
                    com: d.cdir.com.bits(),
                })
            }
            _ => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_ccon_cpos_cdir_byte_round_trips_except_reserved_bits() {
        for b in 0..=255u8 {
            assert_eq!(Ccon::from_byte(b).to_byte(), b & !Ccon::RESERVED_MASK);
            assert_eq!(Cpos::from_byte(b).to_byte(), b & !Cpos::RESERVED_MASK);
            assert_eq!(Cdir::from_byte(b).to_byte(), b);
        }
    }

    #[test]
    fn bit_names_sit_where_the_manuals_put_them() {
        // MTR-DCI Tab. 5/11: CCON 0x03 = ENABLE + STOP; CPOS 0x05 = HOLD + HOM.
        let c = Ccon::from_byte(0x03);
        assert!(c.enable && c.stop && !c.reset && !c.lock && c.opm == Opm::RecordSelect);
        let p = Cpos::from_byte(0x05);
        assert!(p.halt && p.hom && !p.start);
        // Direct mode => B6 = 1 (0x40); CMMO-ST with LOCK: 0x63.
        let c = Ccon::from_byte(0x63);
        assert!(c.lock && c.opm == Opm::Direct);
        // Force => CDIR 0x02; +0x20 = stroke monitoring off (Tab. 5/14).
        let d = Cdir::from_byte(0x22);
        assert_eq!(d.com, ControlMode::Force);
        assert!(d.xlim && !d.abs);
        assert_eq!(Cdir::from_byte(0x04).com, ControlMode::Speed);
        assert!(Cpos::from_byte(0x40).clear);
        assert!(Cpos::from_byte(0x20).teach);
        assert!(Cpos::from_byte(0x10).jogn);
        assert!(Cpos::from_byte(0x08).jogp);
        assert!(Ccon::from_byte(0x08).reset);
        assert!(Ccon::from_byte(0x04).brake);
    }

    #[test]
    fn record_select_image_matches_the_cmmo_modbus_example() {
        // CMMO-ST §1.2 example: record mode, enable with LOCK: 23 01 00 00 00 00 00 00.
        let img = OutputImage::record(Ccon::from_byte(0x23), Cpos::idle(), 0);
        assert_eq!(img.to_bytes(ByteOrder::Big), [0x23, 0x01, 0, 0, 0, 0, 0, 0]);
        assert_eq!(
            OutputImage::from_bytes(&img.to_bytes(ByteOrder::Big), ByteOrder::Big),
            Ok(img)
        );
    }

    #[test]
    fn direct_position_image_in_both_byte_orders() {
        // MTR-DCI Tab. 5/13: CCON 0x43, CPOS 0x03 (START + HOLD), target 0x0001_2345 inc at 50 %.
        let img = OutputImage::direct(
            Ccon::from_byte(0x03),
            Cpos::from_byte(0x03),
            DirectSetpoint::position(0x0001_2345, 50, false),
        );
        assert_eq!(
            img.to_bytes(ByteOrder::Little),
            [0x43, 0x03, 0x00, 50, 0x45, 0x23, 0x01, 0x00]
        );
        assert_eq!(
            img.to_bytes(ByteOrder::Big),
            [0x43, 0x03, 0x00, 50, 0x00, 0x01, 0x23, 0x45]
        );
        for order in [ByteOrder::Little, ByteOrder::Big] {
            assert_eq!(
                OutputImage::from_bytes(&img.to_bytes(order), order),
                Ok(img)
            );
        }
        // Negative targets survive (two's complement).
        let neg = OutputImage::direct(
            Ccon::default(),
            Cpos::idle(),
            DirectSetpoint::position(-1000, 10, true),
        );
        let b = neg.to_bytes(ByteOrder::Little);
        assert_eq!(&b[4..], &(-1000i32).to_le_bytes());
        assert_eq!(b[2], 0x01);
        assert_eq!(OutputImage::from_bytes(&b, ByteOrder::Little), Ok(neg));
    }

    #[test]
    fn force_prepare_pattern_from_tab_5_14() {
        let img = OutputImage::direct(
            Ccon::from_byte(0x03),
            Cpos::idle(),
            DirectSetpoint::force(80, 0, true),
        );
        let b = img.to_bytes(ByteOrder::Little);
        assert_eq!(&b[..3], &[0x43, 0x01, 0x22]);
    }

    #[test]
    fn decode_rejects_bad_length_and_reserved_opm() {
        assert_eq!(
            OutputImage::from_bytes(&[0; 7], ByteOrder::Little),
            Err(ImageError::Length { len: 7 })
        );
        assert_eq!(
            OutputImage::from_bytes(&[0x83, 0, 0, 0, 0, 0, 0, 0], ByteOrder::Little),
            Err(ImageError::ReservedOpm { opm: 2 })
        );
    }

    #[test]
    fn check_applies_the_device_differences() {
        let rec = |r| OutputImage::record(Ccon::default(), Cpos::idle(), r);
        assert_eq!(rec(31).check(Variant::MtrDci), Ok(()));
        assert_eq!(
            rec(32).check(Variant::MtrDci),
            Err(ImageError::RecordOutOfRange {
                record: 32,
                max: 31
            })
        );
        assert_eq!(rec(64).check(Variant::Emca), Ok(()));
        assert!(rec(65).check(Variant::CmmoSt).is_err());
        let speed = OutputImage::direct(
            Ccon::default(),
            Cpos::idle(),
            DirectSetpoint::speed(1000, 50, false),
        );
        assert_eq!(
            speed.check(Variant::MtrDci),
            Err(ImageError::UnsupportedMode { com: 2 })
        );
        assert_eq!(speed.check(Variant::CmmoSt), Ok(()));
    }
}
