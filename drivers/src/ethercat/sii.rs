//! The SII EEPROM image of a subdevice (digest §3): the fixed words 00h..3Fh (PDI set-up, the
//! CRC at word 7, identity, mailboxes, protocols) and the categories from word 40h (strings,
//! general, FMMU, sync managers, PDOs). A master reads it through registers 0502h..050Fh.
//!
//! ```
//! use drivers::ethercat::sii::{SiiImage, SiiSpec, SmSpec, SmKind};
//! let spec = SiiSpec::example();
//! let img = SiiImage::build(&spec).unwrap();
//! assert_eq!(img.word(0x08), 0x001D); // vendor, low word
//! assert_eq!(img.word(0x1C), 0x0004); // CoE only
//! assert!(img.crc_ok());
//! ```

/// Category: strings.
pub const CAT_STRINGS: u16 = 10;
/// Category: general.
pub const CAT_GENERAL: u16 = 30;
/// Category: FMMU usage.
pub const CAT_FMMU: u16 = 40;
/// Category: sync managers.
pub const CAT_SYNCM: u16 = 41;
/// Category: TxPDOs (inputs).
pub const CAT_TXPDO: u16 = 50;
/// Category: RxPDOs (outputs).
pub const CAT_RXPDO: u16 = 51;
/// Category: distributed clocks.
pub const CAT_DC: u16 = 60;
/// The end marker.
pub const CAT_END: u16 = 0xFFFF;

/// Mailbox protocol bit: CoE (SII word 1Ch).
pub const MAILBOX_COE: u16 = 0x0004;

/// The most bytes an image holds (2 KiB, a 16 Kibit EEPROM).
pub const SII_BYTES: usize = 2048;

/// What a sync manager is for (SYNCM category, type byte).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum SmKind {
    /// Mailbox, master to subdevice (SM0).
    MailboxOut = 1,
    /// Mailbox, subdevice to master (SM1).
    MailboxIn = 2,
    /// Process data outputs (SM2).
    Outputs = 3,
    /// Process data inputs (SM3).
    Inputs = 4,
}

/// One sync manager as the SII describes it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SmSpec {
    /// Physical start address in the ESC.
    pub start: u16,
    /// Length in bytes (for process data, the default assignment's).
    pub len: u16,
    /// Control byte (mode, direction, interrupts, watchdog).
    pub control: u8,
    /// What it is for.
    pub kind: SmKind,
}

/// One PDO entry as the SII lists it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PdoEntrySpec {
    /// Object index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
    /// CiA data type code (0005h UNSIGNED8, 0004h INTEGER32, ...).
    pub data_type: u8,
    /// Length in bits.
    pub bits: u8,
}

/// One PDO as the SII lists it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PdoSpec {
    /// The mapping object (1600h.., 1A00h..).
    pub index: u16,
    /// The sync manager it is assigned to.
    pub sm: u8,
    /// Its entries.
    pub entries: &'static [PdoEntrySpec],
}

/// Everything an image is built from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SiiSpec {
    /// Vendor ID (1018h:01).
    pub vendor: u32,
    /// Product code (1018h:02).
    pub product: u32,
    /// Revision (1018h:03).
    pub revision: u32,
    /// Serial number (1018h:04).
    pub serial: u32,
    /// The device's name (order number), the first string.
    pub name: &'static str,
    /// The sync managers, SM0 first.
    pub sms: &'static [SmSpec],
    /// FMMU usage bytes (1 outputs, 2 inputs, 3 SM status).
    pub fmmus: &'static [u8],
    /// RxPDOs (outputs).
    pub rxpdos: &'static [PdoSpec],
    /// TxPDOs (inputs).
    pub txpdos: &'static [PdoSpec],
    /// CoE details (GENERAL byte 5): bit 0 SDO, 2 PDO assign, 3 PDO config, 5 complete access.
    pub coe_details: u8,
    /// Whether a DC category is written.
    pub dc: bool,
}

impl SiiSpec {
    /// A small spec for examples and tests: a CoE device with two mailboxes, one byte of
    /// process data each way.
    pub const fn example() -> SiiSpec {
        const SMS: [SmSpec; 4] = [
            SmSpec {
                start: 0x1000,
                len: 128,
                control: 0x26,
                kind: SmKind::MailboxOut,
            },
            SmSpec {
                start: 0x1080,
                len: 128,
                control: 0x22,
                kind: SmKind::MailboxIn,
            },
            SmSpec {
                start: 0x1100,
                len: 1,
                control: 0x64,
                kind: SmKind::Outputs,
            },
            SmSpec {
                start: 0x1180,
                len: 1,
                control: 0x20,
                kind: SmKind::Inputs,
            },
        ];
        SiiSpec {
            vendor: 0x1D,
            product: 0x1234,
            revision: 0x0001_0000,
            serial: 0,
            name: "example",
            sms: &SMS,
            fmmus: &[1, 2],
            rxpdos: &[],
            txpdos: &[],
            coe_details: 0x01,
            dc: false,
        }
    }
}

/// Why an image could not be built.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SiiError {
    /// The image would not fit [`SII_BYTES`].
    #[error("the SII image does not fit {SII_BYTES} bytes")]
    TooLarge,
    /// The spec has no mailbox sync managers (SM0 out, SM1 in).
    #[error("the SII spec needs SM0 (mailbox out) and SM1 (mailbox in)")]
    NoMailbox,
}

/// A built SII image: little-endian words, read by word address.
#[derive(Debug, Clone)]
pub struct SiiImage {
    bytes: heapless::Vec<u8, SII_BYTES>,
}

impl SiiImage {
    /// Builds the image of a spec.
    pub fn build(spec: &SiiSpec) -> Result<SiiImage, SiiError> {
        let (mbx_out, mbx_in) = match spec.sms {
            [a, b, ..] if a.kind == SmKind::MailboxOut && b.kind == SmKind::MailboxIn => (a, b),
            _ => return Err(SiiError::NoMailbox),
        };
        let mut w = Writer::default();
        // Words 0..7: PDI control (0005h: SPI, no device emulation), PDI config, SYNC pulse
        // length, extended PDI config, alias 0, reserved; word 7 is the CRC, set below.
        for word in [
            0x0005, 0x0000, 0x0000, 0x0000, 0x0000, 0x0000, 0x0000, 0x0000,
        ] {
            w.u16(word)?;
        }
        for v in [spec.vendor, spec.product, spec.revision, spec.serial] {
            w.u32(v)?;
        }
        // Words 10h..13h: execution delay, port delays, reserved.
        w.zeros(8)?;
        // Bootstrap mailboxes (14h..17h): the standard ones (no bootstrap state).
        for word in [mbx_out.start, mbx_out.len, mbx_in.start, mbx_in.len] {
            w.u16(word)?;
        }
        // Standard mailboxes (18h..1Bh), protocols (1Ch).
        for word in [mbx_out.start, mbx_out.len, mbx_in.start, mbx_in.len] {
            w.u16(word)?;
        }
        w.u16(MAILBOX_COE)?;
        // 1Dh..3Dh reserved; 3Eh size (KiBit - 1: 16 Kibit), 3Fh version 1.
        w.zeros((0x3E - 0x1D) * 2)?;
        w.u16((SII_BYTES * 8 / 1024 - 1) as u16)?;
        w.u16(1)?;

        // Strings: 1 = the name.
        let name = spec.name.as_bytes();
        let mut strings = heapless::Vec::<u8, 256>::new();
        let _ = strings.push(1);
        let _ = strings.push(name.len().min(255) as u8);
        let _ = strings.extend_from_slice(&name[..name.len().min(250)]);
        w.category(CAT_STRINGS, &strings)?;

        // General (32 bytes): group, image, order, name string indices (name = 1); CoE details;
        // FoE, EoE, SoE, DS402, sysman 0; flags (bit 0 SafeOp enabled); EBus current 0;
        // physical ports (two EBUS ports: 0x0011... as `0x11`); the rest 0.
        let mut general = [0u8; 32];
        general[2] = 1;
        general[3] = 1;
        general[5] = spec.coe_details;
        general[11] = 0x01;
        general[14] = 0x11;
        w.category(CAT_GENERAL, &general)?;

        let mut fmmu = heapless::Vec::<u8, 16>::new();
        let _ = fmmu.extend_from_slice(&spec.fmmus[..spec.fmmus.len().min(16)]);
        if fmmu.len() % 2 == 1 {
            let _ = fmmu.push(0xFF);
        }
        w.category(CAT_FMMU, &fmmu)?;

        let mut syncm = heapless::Vec::<u8, 64>::new();
        for sm in spec.sms.iter().take(8) {
            let _ = syncm.extend_from_slice(&sm.start.to_le_bytes());
            let _ = syncm.extend_from_slice(&sm.len.to_le_bytes());
            let _ = syncm.extend_from_slice(&[sm.control, 0, 0x01, sm.kind as u8]);
        }
        w.category(CAT_SYNCM, &syncm)?;

        for (cat, pdos) in [(CAT_TXPDO, spec.txpdos), (CAT_RXPDO, spec.rxpdos)] {
            for pdo in pdos {
                let mut b = heapless::Vec::<u8, 512>::new();
                let _ = b.extend_from_slice(&pdo.index.to_le_bytes());
                let _ = b.extend_from_slice(&[pdo.entries.len() as u8, pdo.sm, 0, 0, 0, 0]);
                for e in pdo.entries {
                    let _ = b.extend_from_slice(&e.index.to_le_bytes());
                    let _ = b.extend_from_slice(&[e.sub, 0, e.data_type, e.bits, 0, 0]);
                }
                w.category(cat, &b)?;
            }
        }
        if spec.dc {
            // One DC operation mode, "SYNC0": cycle time 0 (from the master), activation 0300h.
            let mut dc = [0u8; 24];
            dc[16..18].copy_from_slice(&0x0300u16.to_le_bytes());
            w.category(CAT_DC, &dc)?;
        }
        w.u16(CAT_END)?;
        w.u16(0)?;

        let crc = crc8(&w.bytes[..14]);
        w.bytes[14] = crc;
        w.bytes[15] = 0;
        Ok(SiiImage { bytes: w.bytes })
    }

    /// The word at a word address; past the image, an erased EEPROM's FFFFh.
    pub fn word(&self, address: u32) -> u16 {
        let at = address as usize * 2;
        match self.bytes.get(at..at + 2) {
            Some(b) => u16::from_le_bytes([b[0], b[1]]),
            None => 0xFFFF,
        }
    }

    /// Whether the CRC at word 7 matches words 0..6.
    pub fn crc_ok(&self) -> bool {
        self.bytes[14] == crc8(&self.bytes[..14])
    }

    /// The image's bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes
    }
}

/// Appends little-endian words and categories.
#[derive(Default)]
struct Writer {
    bytes: heapless::Vec<u8, SII_BYTES>,
}

impl Writer {
    fn u16(&mut self, v: u16) -> Result<(), SiiError> {
        self.bytes
            .extend_from_slice(&v.to_le_bytes())
            .map_err(|_| SiiError::TooLarge)
    }
    fn u32(&mut self, v: u32) -> Result<(), SiiError> {
        self.bytes
            .extend_from_slice(&v.to_le_bytes())
            .map_err(|_| SiiError::TooLarge)
    }
    fn zeros(&mut self, n: usize) -> Result<(), SiiError> {
        (0..n).try_for_each(|_| self.bytes.push(0).map_err(|_| SiiError::TooLarge))
    }
    /// A category: type, size in words, the data padded to whole words.
    fn category(&mut self, kind: u16, data: &[u8]) -> Result<(), SiiError> {
        let words = data.len().div_ceil(2);
        self.u16(kind)?;
        self.u16(words as u16)?;
        self.bytes
            .extend_from_slice(data)
            .map_err(|_| SiiError::TooLarge)?;
        if data.len() % 2 == 1 {
            self.bytes.push(0).map_err(|_| SiiError::TooLarge)?;
        }
        Ok(())
    }
}

/// The SII checksum: CRC-8, polynomial 07h, initial FFh, no reflection, no final XOR.
pub fn crc8(bytes: &[u8]) -> u8 {
    let mut crc = 0xFFu8;
    for &b in bytes {
        crc ^= b;
        for _ in 0..8 {
            crc = if crc & 0x80 != 0 {
                (crc << 1) ^ 0x07
            } else {
                crc << 1
            };
        }
    }
    crc
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Walks the categories from word 40h: (type, word address of the data, size in words).
    fn categories(img: &SiiImage) -> heapless::Vec<(u16, u32, u16), 32> {
        let mut out = heapless::Vec::new();
        let mut at = 0x40;
        loop {
            let kind = img.word(at);
            if kind == CAT_END {
                return out;
            }
            let size = img.word(at + 1);
            out.push((kind, at + 2, size)).unwrap();
            at += 2 + u32::from(size);
        }
    }

    #[test]
    fn the_image_has_identity_mailboxes_and_categories_where_masters_look() {
        let spec = SiiSpec::example();
        let img = SiiImage::build(&spec).unwrap();
        assert!(img.crc_ok());
        assert_eq!(img.word(0x0A), 0x1234);
        assert_eq!(img.word(0x0C), 0x0000);
        assert_eq!(img.word(0x0D), 0x0001);
        assert_eq!(
            [
                img.word(0x18),
                img.word(0x19),
                img.word(0x1A),
                img.word(0x1B)
            ],
            [0x1000, 128, 0x1080, 128]
        );
        let cats = categories(&img);
        let kinds: heapless::Vec<u16, 32> = cats.iter().map(|c| c.0).collect();
        assert_eq!(&kinds[..], &[CAT_STRINGS, CAT_GENERAL, CAT_FMMU, CAT_SYNCM]);
        let (_, syncm, size) = cats[3];
        assert_eq!(size, 16); // four sync managers of 8 bytes
        // Four words per sync manager: SM2's start, and its type in the high byte of word 3.
        assert_eq!(img.word(syncm + 8), 0x1100);
        assert_eq!(img.word(syncm + 11) >> 8, SmKind::Outputs as u16);
        // Past the image: erased.
        assert_eq!(img.word(5000), 0xFFFF);
    }

    #[test]
    fn the_crc_is_the_one_etg_specifies() {
        // CRC-8 with polynomial 07h and initial value FFh, unreflected (ethercrab's
        // `ECAT_CRC_ALGORITHM`): FBh over "123456789" (with initial value 0 it would be F4h,
        // CRC-8/SMBUS's check value).
        assert_eq!(crc8(b"123456789"), 0xFB);
    }
}
