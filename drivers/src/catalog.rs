//! The device catalog: every fact about the supported drives (the four of the manuals and a
//! generic CiA 402 drive) that more than one place
//! needs (identity, profiles, PDO1, supervision, record table), in one `const` per device, each
//! fact with the section of the manual digest (`shared/reference/seed-00N-*.md`) it comes from.
//!
//! The coordinator's configuration check, its boot plans and axes, and the simulators' object
//! dictionaries all read these values, so `coordinator check` and `coordinator run` cannot
//! disagree about what a device offers.
//!
//! ```
//! use drivers::catalog::{self, Profile};
//! let emca = catalog::by_id("emca").unwrap();
//! assert_eq!(emca.name, "EMCA");
//! assert!(emca.offers(Profile::Fhpp) && !emca.offers(Profile::Cia402));
//! assert_eq!(emca.records.map(|r| r.last), Some(64));
//! assert_eq!(catalog::TLC5XX.profile(Profile::Cia402).unwrap().device_type, Some(0x0002_0192));
//! ```

use core::ops::RangeInclusive;

/// How the master reaches the device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Link {
    /// CANopen (CiA 301): node-ID, PDOs, SDO.
    Canopen,
    /// Modbus TCP: registers at an IP address.
    ModbusTcp,
}

/// A device profile a drive can be spoken to in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Profile {
    /// Festo Handling and Positioning Profile.
    Fhpp,
    /// CiA 402 drives and motion control.
    Cia402,
}

impl Profile {
    /// The name the configuration uses.
    pub const fn id(self) -> &'static str {
        match self {
            Profile::Fhpp => "fhpp",
            Profile::Cia402 => "cia402",
        }
    }
    /// The name for people.
    pub const fn label(self) -> &'static str {
        match self {
            Profile::Fhpp => "FHPP",
            Profile::Cia402 => "CiA 402",
        }
    }
}

/// One PDO's mapping both ways, entries `index << 16 | sub << 8 | bits` as 1600h/1A00h hold
/// them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct PdoPair {
    /// Master → drive (the RPDO, 160xh).
    pub rpdo: &'static [u32],
    /// Drive → master (the TPDO, 1A0xh).
    pub tpdo: &'static [u32],
}

/// Data bytes of a mapping.
pub const fn mapped_bytes(mapping: &[u32]) -> usize {
    let mut bits = 0;
    let mut i = 0;
    while i < mapping.len() {
        bits += (mapping[i] & 0xFF) as usize;
        i += 1;
    }
    bits / 8
}

impl PdoPair {
    /// Data bytes of the RPDO.
    pub const fn rpdo_bytes(&self) -> usize {
        mapped_bytes(self.rpdo)
    }
    /// Data bytes of the TPDO.
    pub const fn tpdo_bytes(&self) -> usize {
        mapped_bytes(self.tpdo)
    }
}

/// What a device offers in one profile.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ProfileFacts {
    /// The profile.
    pub profile: Profile,
    /// 1000h in this profile; `None` off CANopen.
    pub device_type: Option<u32>,
    /// PDO1 as the coordinator runs it: for a static PDO1 the device's own mapping, otherwise
    /// the mapping the boot writes. `None` off CANopen.
    pub pdo1: Option<PdoPair>,
    /// PDO1 as the device powers up (equal to `pdo1` where it is static).
    pub pdo1_power_up: Option<PdoPair>,
    /// PDO1's mapping cannot be written: the boot only sets the transmission type and reads the
    /// mapping back.
    pub pdo1_static: bool,
    /// The Festo parameter channel (FPC/EFPC) on PDO2, static, where this profile has it.
    pub fpc_pdo2: Option<PdoPair>,
    /// An RPDO2 carrying a move's profile (6081h velocity, 6083h acceleration), static, where
    /// this profile has one: the coordinator sends it with each set-point of a drive that takes
    /// one set-point per move.
    pub profile_rpdo2: Option<&'static [u32]>,
}

/// A device's own table of positioning records.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Records {
    /// The highest record number a START runs in record select (the lowest is 1; record 0 is
    /// homing on every FHPP device).
    pub last: u8,
    /// The record whose row is sub-index 1 of the record PNUs (401...): record n is sub-index
    /// n − first_row + 1.
    pub first_row: u8,
    /// Whether the drive chains records by itself (a next record, step conditions).
    pub chaining: bool,
}

impl Records {
    /// The sub-index of record `n` in the record PNUs, or `None` outside the table.
    pub const fn subindex(&self, n: u8) -> Option<u8> {
        if n < self.first_row || n > self.last {
            None
        } else {
            Some(n - self.first_row + 1)
        }
    }
}

/// The strings of Modbus Read Device Identification (FC 2Bh / MEI 0Eh) the manual gives.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ModbusIdentity {
    /// Object 0x00 VendorName.
    pub vendor_name: &'static str,
    /// Object 0x03 VendorUrl.
    pub vendor_url: &'static str,
    /// Object 0x04 ProductName.
    pub product_name: &'static str,
}

/// One PDO of an EtherCAT device: its mapping object and the entries it maps (fixed).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct EcPdo {
    /// The mapping object (16xxh outputs, 1Axxh inputs).
    pub index: u16,
    /// Its entries, `index << 16 | sub << 8 | bits`.
    pub entries: &'static [u32],
}

impl EcPdo {
    /// The bytes the PDO occupies in its sync manager.
    pub const fn bytes(&self) -> u16 {
        let mut bits = 0u32;
        let mut i = 0;
        while i < self.entries.len() {
            bits += self.entries[i] & 0xFF;
            i += 1;
        }
        bits.div_ceil(8) as u16
    }
}

/// What a device is on EtherCAT (CoE): the identity and layout its ESI file would give, and
/// its synchronisation limits (1C32h). The EMCA manual leaves these to the ESI, which is not
/// in the seeds: where marked ASSUMED, the value is this project's choice, used alike by the
/// simulated subdevice (SII image and object dictionary) and the coordinator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct EthercatFacts {
    /// Product code (SII word 0Ah, 1018h:02).
    pub product_code: u32,
    /// Revision (SII word 0Ch, 1018h:03).
    pub revision: u32,
    /// The name the SII's strings give (the order code).
    pub name: &'static str,
    /// SM0, the write mailbox: start and length.
    pub mailbox_out: (u16, u16),
    /// SM1, the read mailbox: start and length.
    pub mailbox_in: (u16, u16),
    /// SM2 (outputs) start.
    pub outputs_start: u16,
    /// SM3 (inputs) start.
    pub inputs_start: u16,
    /// The RxPDOs (outputs) the device offers, in 1C12h order.
    pub rx_pdos: &'static [EcPdo],
    /// The TxPDOs (inputs), in 1C13h order.
    pub tx_pdos: &'static [EcPdo],
    /// How many of them are assigned at power-on (1C12h:00 and 1C13h:00).
    pub default_assigned: u8,
    /// 1C32h:04, the synchronisation types supported (bit 0 free run, 1 SM, 2 DC SYNC0).
    pub sync_types: u16,
    /// 1C32h:05, the shortest cycle, ns.
    pub min_cycle_ns: u32,
    /// 1C32h:06, the calc-and-copy time, ns.
    pub calc_copy_ns: u32,
    /// Whether it has distributed clocks (seed-002 p.52: yes).
    pub dc: bool,
}

impl EthercatFacts {
    /// The PDOs the coordinator assigns (1C12h, 1C13h): the first of each direction, FHPP's
    /// 8-byte standard data (1600h and 1A00h on the EMCA; seed-002 §5.2).
    pub const fn cyclic_pdos(&self) -> (&'static EcPdo, &'static EcPdo) {
        (&self.rx_pdos[0], &self.tx_pdos[0])
    }
}

/// The EMCA's FHPP+ output bytes 1..8 (1602h) and 9..16 (1603h): 3101h..3109h, 3110h..3116h
/// (the manual numbers them so: 3109h is followed by 3110h).
const EMCA_FHPP_PLUS_OUT: [&[u32]; 2] = [
    &[
        0x3101_0008,
        0x3102_0008,
        0x3103_0008,
        0x3104_0008,
        0x3105_0008,
        0x3106_0008,
        0x3107_0008,
        0x3108_0008,
    ],
    &[
        0x3109_0008,
        0x3110_0008,
        0x3111_0008,
        0x3112_0008,
        0x3113_0008,
        0x3114_0008,
        0x3115_0008,
        0x3116_0008,
    ],
];
/// Its FHPP+ inputs 1..8 (1A02h) and 9..16 (1A03h).
const EMCA_FHPP_PLUS_IN: [&[u32]; 2] = [
    &[
        0x3201_0008,
        0x3202_0008,
        0x3203_0008,
        0x3204_0008,
        0x3205_0008,
        0x3206_0008,
        0x3207_0008,
        0x3208_0008,
    ],
    &[
        0x3209_0008,
        0x3210_0008,
        0x3211_0008,
        0x3212_0008,
        0x3213_0008,
        0x3214_0008,
        0x3215_0008,
        0x3216_0008,
    ],
];

/// The EMCA-EC on EtherCAT (seed-002 §5.2, digest `ethercat-digest.md` §10): PDO mappings
/// 1600h..1603h / 1A00h..1A03h as the manual prints them (p.54–61), all four assigned at
/// power-on (SM2 = SM3 = 32 bytes); DC supported (p.52). ASSUMED (ESI values, not in the
/// seed): product code 0x0000_0B0C, revision 0x0001_0000, SM0 1000h/128, SM1 1080h/128, SM2
/// 1100h, SM3 1180h, 1C32h:04 = 0007h, 1C32h:05 = 1 ms, 1C32h:06 = 100 µs.
pub const EMCA_ETHERCAT: EthercatFacts = EthercatFacts {
    product_code: 0x0000_0B0C,
    revision: 0x0001_0000,
    name: "EMCA-EC-67-M-1TE-EC",
    mailbox_out: (0x1000, 128),
    mailbox_in: (0x1080, 128),
    outputs_start: 0x1100,
    inputs_start: 0x1180,
    rx_pdos: &[
        EcPdo {
            index: 0x1600,
            entries: FHPP_RPDO1,
        },
        EcPdo {
            index: 0x1601,
            entries: FPC_RPDO2,
        },
        EcPdo {
            index: 0x1602,
            entries: EMCA_FHPP_PLUS_OUT[0],
        },
        EcPdo {
            index: 0x1603,
            entries: EMCA_FHPP_PLUS_OUT[1],
        },
    ],
    tx_pdos: &[
        EcPdo {
            index: 0x1A00,
            entries: FHPP_TPDO1,
        },
        EcPdo {
            index: 0x1A01,
            entries: FPC_TPDO2,
        },
        EcPdo {
            index: 0x1A02,
            entries: EMCA_FHPP_PLUS_IN[0],
        },
        EcPdo {
            index: 0x1A03,
            entries: EMCA_FHPP_PLUS_IN[1],
        },
    ],
    default_assigned: 4,
    sync_types: 0x0007,
    min_cycle_ns: 1_000_000,
    calc_copy_ns: 100_000,
    dc: true,
};

/// One kind of drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Device {
    /// The name as its manual writes it.
    pub name: &'static str,
    /// The name in the coordinator's configuration and on `drive-sim --device`.
    pub id: &'static str,
    /// The manufacturer.
    pub vendor: &'static str,
    /// How it is reached.
    pub link: Link,
    /// The profiles offered (modelled by its simulator and driven by the coordinator); the
    /// first is the default.
    pub profiles: &'static [ProfileFacts],
    /// 1018h:01; `None` off CANopen.
    pub vendor_id: Option<u32>,
    /// 1018h:02, where the manual gives one.
    pub product_code: Option<u32>,
    /// Modbus device identification, where the device is on Modbus.
    pub modbus_identity: Option<ModbusIdentity>,
    /// The largest producer heartbeat time 1017h, ms; `None`: no heartbeat producer.
    pub heartbeat_max_ms: Option<u16>,
    /// The largest guard time 100Ch, ms; `None`: no node guarding.
    pub guard_time_max_ms: Option<u16>,
    /// The CAN bitrates it runs at, kbit/s (its EDS's `BaudRate_` keys); empty off CANopen.
    pub can_bitrates_kbit: &'static [u16],
    /// The drive's own record table; `None`: it has none.
    pub records: Option<Records>,
    /// What it is on EtherCAT, where it has an EtherCAT variant.
    pub ethercat: Option<&'static EthercatFacts>,
}

impl Device {
    /// The facts of `profile`, if offered.
    pub const fn profile(&self, profile: Profile) -> Option<&ProfileFacts> {
        let mut i = 0;
        while i < self.profiles.len() {
            if self.profiles[i].profile as u8 == profile as u8 {
                return Some(&self.profiles[i]);
            }
            i += 1;
        }
        None
    }
    /// Whether `profile` is offered.
    pub const fn offers(&self, profile: Profile) -> bool {
        self.profile(profile).is_some()
    }
    /// The default profile (the first offered).
    pub const fn default_profile(&self) -> Profile {
        self.profiles[0].profile
    }
    /// Whether the device produces a heartbeat (1017h).
    pub const fn has_heartbeat(&self) -> bool {
        self.heartbeat_max_ms.is_some()
    }
    /// Whether the device is on CANopen.
    pub const fn is_canopen(&self) -> bool {
        matches!(self.link, Link::Canopen)
    }
}

/// CANopen node-IDs a drive may have (0 is the NMT broadcast): seed-002 §5.1, seed-003 §2.1.
pub const NODE_IDS: RangeInclusive<u8> = 1..=127;

/// 1000h of the Festo drives in FHPP: seed-000 §1.2 and §7.3, seed-002 §5.1 ("Device objects").
pub const FESTO_FHPP_DEVICE_TYPE: u32 = 0x0000_012D;
/// 1000h of a CiA 402 servo drive: seed-003 §1.2 (TLC5xx), seed-000 §10 erratum E1 (MTR-DCI,
/// printed as 0x00420192; 131474 = 0x00020192).
pub const CIA402_DEVICE_TYPE: u32 = 0x0002_0192;
/// Festo's vendor-ID: seed-000 §7.3, seed-002 §5.1.
pub const FESTO_VENDOR_ID: u32 = 0x0000_001D;
/// The TLC5xx's vendor-ID (SIG Positec / Berger Lahr): seed-003 §5.1.
pub const TLC5XX_VENDOR_ID: u32 = 0x0100_002E;

/// FHPP control bytes on RPDO1: CCON, CPOS, CDIR/record, value 1, value 2 (seed-000 §7.4,
/// whose fifth entry the digest infers; seed-002 §5.1 names 3004h DEM_VAL2 int32).
pub const FHPP_RPDO1: &[u32] = &[
    0x3000_0008,
    0x3001_0008,
    0x3002_0008,
    0x3003_0008,
    0x3004_0020,
];
/// FHPP status bytes on TPDO1: SCON, SPOS, SDIR/record, RSB/value 1, value 2 (seed-000 §7.4,
/// seed-002 §5.1).
pub const FHPP_TPDO1: &[u32] = &[
    0x3020_0008,
    0x3021_0008,
    0x3022_0008,
    0x3023_0008,
    0x3024_0020,
];
/// The FPC/EFPC request on RPDO2: byte 1, sub-index, PKE/PNU, PWE (seed-000 §7.4, seed-002
/// §5.1).
pub const FPC_RPDO2: &[u32] = &[0x3010_0008, 0x3011_0008, 0x3012_0010, 0x3013_0020];
/// The FPC/EFPC response on TPDO2 (seed-000 §7.4, seed-002 §5.1).
pub const FPC_TPDO2: &[u32] = &[0x3030_0008, 0x3031_0008, 0x3032_0010, 0x3033_0020];
/// The MTR-DCI's static CiA 402 RPDO1: controlword, record number 2032h:01, modes of operation,
/// target position (seed-000 §7.4).
pub const MTR_DCI_402_RPDO1: &[u32] = &[0x6040_0010, 0x2032_0108, 0x6060_0008, 0x607A_0020];
/// MTR-DCI CiA 402 RPDO2 (static, §7.4): 6081h profile velocity, 6083h profile acceleration,
/// taken over at the next set-point edge when 2032h = 0 ("direct set").
pub const MTR_DCI_402_RPDO2: &[u32] = &[0x6081_0020, 0x6083_0020];
/// Its TPDO1: statusword, record number, modes display, position actual value (seed-000 §7.4).
pub const MTR_DCI_402_TPDO1: &[u32] = &[0x6041_0010, 0x2032_0108, 0x6061_0008, 0x6064_0020];
/// The TLC5xx's RPDO1 as the coordinator maps it (7 bytes; PDO1 is dynamic, at most 64 bits,
/// seed-003 §2.4): controlword, target position 607Ah, modes of operation 6060h.
pub const TLC_RPDO1: &[u32] = &[0x6040_0010, 0x607A_0020, 0x6060_0008];
/// Its TPDO1: statusword, position actual value 6064h, modes display 6061h.
pub const TLC_TPDO1: &[u32] = &[0x6041_0010, 0x6064_0020, 0x6061_0008];
/// The TLC5xx's power-up PDO1: controlword / statusword only (seed-003 §2.4).
pub const TLC_PDO1_POWER_UP: PdoPair = PdoPair {
    rpdo: &[0x6040_0010],
    tpdo: &[0x6041_0010],
};

const FHPP_PDO1: PdoPair = PdoPair {
    rpdo: FHPP_RPDO1,
    tpdo: FHPP_TPDO1,
};
const FPC_PDO2: PdoPair = PdoPair {
    rpdo: FPC_RPDO2,
    tpdo: FPC_TPDO2,
};
const MTR_DCI_402_PDO1: PdoPair = PdoPair {
    rpdo: MTR_DCI_402_RPDO1,
    tpdo: MTR_DCI_402_TPDO1,
};

/// FHPP over CANopen on a Festo drive: static PDO1 (seed-000 §7.4 "static, cannot be changed";
/// the EMCA digest §5.1 gives the same fixed layout and no remapping), the parameter channel on
/// PDO2.
const FESTO_FHPP: ProfileFacts = ProfileFacts {
    profile: Profile::Fhpp,
    device_type: Some(FESTO_FHPP_DEVICE_TYPE),
    pdo1: Some(FHPP_PDO1),
    pdo1_power_up: Some(FHPP_PDO1),
    pdo1_static: true,
    fpc_pdo2: Some(FPC_PDO2),
    profile_rpdo2: None,
};

/// Festo MTR-DCI-...-CO (seed-000).
pub const MTR_DCI: Device = Device {
    name: "MTR-DCI",
    id: "mtr-dci",
    vendor: "Festo",
    link: Link::Canopen,
    // FHPP or CiA 402, chosen by the CAN profile setting (§1.2). In CiA 402, PDO2 carries
    // profile velocity/acceleration and TPDO2 is not supported: no FPC (§7.4).
    profiles: &[
        FESTO_FHPP,
        ProfileFacts {
            profile: Profile::Cia402,
            device_type: Some(CIA402_DEVICE_TYPE),
            pdo1: Some(MTR_DCI_402_PDO1),
            pdo1_power_up: Some(MTR_DCI_402_PDO1),
            pdo1_static: true,
            fpc_pdo2: None,
            profile_rpdo2: Some(MTR_DCI_402_RPDO2),
        },
    ],
    vendor_id: Some(FESTO_VENDOR_ID),
    // 1018h:02 "not given" (§7.3).
    product_code: None,
    modbus_identity: None,
    // No 1017h in the object list: node guarding only (§7.3); 100Ch is 0..32767 ms (§7.3).
    heartbeat_max_ms: None,
    guard_time_max_ms: Some(32767),
    // §5.4.1: 1000, 800, 500, 250, 125, 100, 50, 20 kbit/s (100 has no CiA 306 key).
    can_bitrates_kbit: &[20, 50, 125, 250, 500, 800, 1000],
    // Records 1..31, record 0 = homing at sub-index 1; no chaining (§4.1, §4.3).
    records: Some(Records {
        last: 31,
        first_row: 0,
        chaining: false,
    }),
    ethercat: None,
};

/// Festo EMCA-...-CO (seed-002).
pub const EMCA: Device = Device {
    name: "EMCA",
    id: "emca",
    vendor: "Festo",
    link: Link::Canopen,
    // FHPP only: its CiA 402 profile has a manual of its own that the digest does not cover
    // (§5.6), and neither the simulator nor the coordinator's axis model it.
    profiles: &[FESTO_FHPP],
    vendor_id: Some(FESTO_VENDOR_ID),
    product_code: None,
    modbus_identity: None,
    // "Heartbeat is not mentioned"; 100Ch is u16 ms (§5.1 "Node guarding").
    heartbeat_max_ms: None,
    guard_time_max_ms: Some(u16::MAX),
    // The manual sets the bit rate through FCT without listing the rates (seed-002 p.16):
    // the CiA set is assumed.
    can_bitrates_kbit: &[10, 20, 50, 125, 250, 500, 800, 1000],
    // 64 records, sub-index 1..64 = record number, with chaining (§3.1, §3.2).
    records: Some(Records {
        last: 64,
        first_row: 1,
        chaining: true,
    }),
    ethercat: Some(&EMCA_ETHERCAT),
};

/// Festo CMMO-ST-C5-1-LKP on Modbus TCP (seed-001).
pub const CMMO_ST: Device = Device {
    name: "CMMO-ST",
    id: "cmmo-st",
    vendor: "Festo",
    link: Link::ModbusTcp,
    // FHPP only (§1.1); the coordinator exchanges the 8-byte "FHPP standard" image, 4
    // registers (§1.2). Its 16-byte "+ FPC" variant is not a PDO, so no `fpc_pdo2`.
    profiles: &[ProfileFacts {
        profile: Profile::Fhpp,
        device_type: None,
        pdo1: None,
        pdo1_power_up: None,
        pdo1_static: false,
        fpc_pdo2: None,
        profile_rpdo2: None,
    }],
    vendor_id: None,
    product_code: None,
    // Read Device Identification: PNUs 122, 123, 120 (§1.2).
    modbus_identity: Some(ModbusIdentity {
        vendor_name: "Festo AG & Co. KG",
        vendor_url: "http://www.festo.com",
        product_name: "CMMO-ST-C5-1-LKP",
    }),
    // Supervised by its Modbus connection timeout instead (§1.2).
    heartbeat_max_ms: None,
    guard_time_max_ms: None,
    can_bitrates_kbit: &[],
    // 64 records 1..64 at sub-index = record number, with chaining (§4.1, §4.2).
    records: Some(Records {
        last: 64,
        first_row: 1,
        chaining: true,
    }),
    ethercat: None,
};

/// Twin Line TLC5xx on CANopen (seed-003).
pub const TLC5XX: Device = Device {
    name: "TLC5xx",
    id: "tlc5xx",
    // The manual is SIG Positec's (Berger Lahr), now Schneider Electric (seed-003 header).
    vendor: "Schneider",
    link: Link::Canopen,
    // DSP402 only (§1.2); PDO1..3 dynamic, PDO4 static (§2.4).
    profiles: &[ProfileFacts {
        profile: Profile::Cia402,
        device_type: Some(CIA402_DEVICE_TYPE),
        pdo1: Some(PdoPair {
            rpdo: TLC_RPDO1,
            tpdo: TLC_TPDO1,
        }),
        pdo1_power_up: Some(TLC_PDO1_POWER_UP),
        pdo1_static: false,
        fpc_pdo2: None,
        profile_rpdo2: None,
    }],
    vendor_id: Some(TLC5XX_VENDOR_ID),
    // 1018h:02 default 0 (§5.1).
    product_code: Some(0),
    modbus_identity: None,
    // 1017h and 100Ch are U16 ms, heartbeat or guarding, not both (§2.7, §5.1).
    heartbeat_max_ms: Some(u16::MAX),
    guard_time_max_ms: Some(u16::MAX),
    // "the CiA set 10-1000 kbit/s" (seed-003 §4.2.1, an assumption of the digest).
    can_bitrates_kbit: &[10, 20, 50, 125, 250, 500, 800, 1000],
    // Record processing is "only for TLC4xx" (§4.2): the TLC5xx has no record table.
    records: None,
    ethercat: None,
};

/// The generic CiA 402 drive's RPDO1 for cyclic synchronous (and profile) position, as the
/// coordinator maps it: controlword, target position 607Ah, modes of operation 6060h (7 bytes:
/// the mode travels in the PDO, so homing and a mode change need no SDO mid-run; SYNC plus
/// three such axes fit 1 ms at 1 Mbit/s, `plcopen-and-cia402-csp.md` §9).
pub const CIA402_CSP_RPDO1: &[u32] = &[0x6040_0010, 0x607A_0020, 0x6060_0008];
/// Its TPDO1 in every mode: statusword, position actual value 6064h, modes display 6061h.
pub const CIA402_TPDO1: &[u32] = &[0x6041_0010, 0x6064_0020, 0x6061_0008];
/// Its RPDO1 for cyclic synchronous velocity: 60FFh target velocity in place of 607Ah.
pub const CIA402_CSV_RPDO1: &[u32] = &[0x6040_0010, 0x60FF_0020, 0x6060_0008];
/// Its RPDO1 for cyclic synchronous torque: 6071h target torque (16 bits), 5 bytes.
pub const CIA402_CST_RPDO1: &[u32] = &[0x6040_0010, 0x6071_0010, 0x6060_0008];
/// The generic drive's power-up PDO1 (the CiA 402-3 defaults: controlword / statusword).
pub const CIA402_PDO1_POWER_UP: PdoPair = PdoPair {
    rpdo: &[0x6040_0010],
    tpdo: &[0x6041_0010],
};
/// Its vendor-ID as this project's simulator reports it, and in the built-in EDS: 0, no
/// vendor's (a real drive's comes from its EDS).
pub const CIA402_SIM_VENDOR_ID: u32 = 0;
/// Its product code as the simulator reports it (1018h:02).
pub const CIA402_SIM_PRODUCT_CODE: u32 = 0x0000_0402;

/// Any CiA 402 drive, described by its EDS (`plcopen-and-cia402-csp.md` §10). The facts here
/// are the profile's defaults and those of this project's simulator of it; a configured EDS
/// overrides the identity, the modes and what can be mapped.
pub const CIA402_GENERIC: Device = Device {
    name: "CiA 402 drive",
    id: "cia402",
    vendor: "any",
    link: Link::Canopen,
    profiles: &[ProfileFacts {
        profile: Profile::Cia402,
        device_type: Some(CIA402_DEVICE_TYPE),
        pdo1: Some(PdoPair {
            rpdo: CIA402_CSP_RPDO1,
            tpdo: CIA402_TPDO1,
        }),
        pdo1_power_up: Some(CIA402_PDO1_POWER_UP),
        pdo1_static: false,
        fpc_pdo2: None,
        profile_rpdo2: None,
    }],
    vendor_id: Some(CIA402_SIM_VENDOR_ID),
    product_code: Some(CIA402_SIM_PRODUCT_CODE),
    modbus_identity: None,
    // 1017h and 100Ch are U16 ms in CiA 301.
    heartbeat_max_ms: Some(u16::MAX),
    guard_time_max_ms: Some(u16::MAX),
    can_bitrates_kbit: &[10, 20, 50, 125, 250, 500, 800, 1000],
    records: None,
    ethercat: None,
};

/// Every device kind, in the order the documentation lists them.
pub const DEVICES: [&Device; 5] = [&MTR_DCI, &EMCA, &CMMO_ST, &TLC5XX, &CIA402_GENERIC];

/// The device with configuration name `id`.
pub fn by_id(id: &str) -> Option<&'static Device> {
    DEVICES.iter().copied().find(|d| d.id == id)
}

/// The devices and profiles that report this identity (1000h, 1018h:01).
pub fn identify(
    device_type: u32,
    vendor_id: u32,
) -> impl Iterator<Item = (&'static Device, &'static ProfileFacts)> {
    DEVICES.iter().copied().flat_map(move |d| {
        d.profiles.iter().filter_map(move |p| {
            (d.vendor_id == Some(vendor_id) && p.device_type == Some(device_type)).then_some((d, p))
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pdo1_is_symmetric_and_fits_a_frame() {
        for d in DEVICES {
            for p in d.profiles {
                assert_eq!(p.pdo1.is_some(), d.is_canopen(), "{}", d.name);
                assert_eq!(p.device_type.is_some(), d.is_canopen(), "{}", d.name);
                for pair in [p.pdo1, p.pdo1_power_up, p.fpc_pdo2].into_iter().flatten() {
                    // The budget counts one length for both directions.
                    assert_eq!(pair.rpdo_bytes(), pair.tpdo_bytes(), "{}", d.name);
                    assert!(pair.rpdo_bytes() <= 8 && pair.rpdo.len() <= 8, "{}", d.name);
                }
                if p.pdo1_static {
                    assert_eq!(p.pdo1, p.pdo1_power_up, "{}", d.name);
                }
            }
        }
    }

    #[test]
    fn names_and_identities_are_unique() {
        for (i, a) in DEVICES.iter().enumerate() {
            assert_eq!(by_id(a.id).map(|d| d.name), Some(a.name));
            for b in &DEVICES[i + 1..] {
                assert_ne!(a.id, b.id);
            }
        }
        let festo_fhpp: heapless::Vec<&str, 4> = identify(FESTO_FHPP_DEVICE_TYPE, FESTO_VENDOR_ID)
            .map(|(d, _)| d.name)
            .collect();
        assert_eq!(festo_fhpp, ["MTR-DCI", "EMCA"]);
        let tlc = identify(CIA402_DEVICE_TYPE, TLC5XX_VENDOR_ID).next();
        assert_eq!(
            tlc.map(|(d, p)| (d.name, p.profile)),
            Some(("TLC5xx", Profile::Cia402))
        );
    }

    #[test]
    fn record_rows() {
        let mtr = MTR_DCI.records.unwrap();
        assert_eq!(
            (mtr.subindex(0), mtr.subindex(31), mtr.subindex(32)),
            (Some(1), Some(32), None)
        );
        let emca = EMCA.records.unwrap();
        assert_eq!(
            (emca.subindex(0), emca.subindex(1), emca.subindex(64)),
            (None, Some(1), Some(64))
        );
        assert_eq!(emca.subindex(65), None);
    }
}
