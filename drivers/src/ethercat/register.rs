//! The ESC registers a master uses (digest §2, checked there against ethercrab's `register.rs`
//! and SOEM's `ECT_REG_*`), and the bit layouts of those whose bits matter here. One list for
//! the simulated ESC, the master side and the tests.

/// ESC type (read only).
pub const TYPE: u16 = 0x0000;
/// ESC revision.
pub const REVISION: u16 = 0x0001;
/// ESC build (u16).
pub const BUILD: u16 = 0x0002;
/// FMMUs supported (u8).
pub const FMMU_COUNT: u16 = 0x0004;
/// Sync managers supported (u8).
pub const SM_COUNT: u16 = 0x0005;
/// Process RAM size in KiB (u8).
pub const RAM_SIZE: u16 = 0x0006;
/// Port descriptor: 2 bits per port (00 none, 01 not configured, 10 EBUS, 11 MII).
pub const PORT_DESCRIPTOR: u16 = 0x0007;
/// ESC features (u16): bit 2 distributed clocks, bit 3 64-bit DC.
pub const FEATURES: u16 = 0x0008;
/// Configured station address (u16, written by the master).
pub const STATION_ADDRESS: u16 = 0x0010;
/// Configured station alias (u16, loaded from SII word 4).
pub const STATION_ALIAS: u16 = 0x0012;
/// DL control (u32): forwarding, loop control, alias enable (bit 24).
pub const DL_CONTROL: u16 = 0x0100;
/// DL status (u16): PDI operational, links and loops per port.
pub const DL_STATUS: u16 = 0x0110;
/// AL control (u16): requested state, error acknowledge.
pub const AL_CONTROL: u16 = 0x0120;
/// AL status (u16): the state, the error flag (bit 4).
pub const AL_STATUS: u16 = 0x0130;
/// AL status code (u16): why the last transition failed (digest §4.3).
pub const AL_STATUS_CODE: u16 = 0x0134;
/// PDI control (u8): the PDI type, from SII word 0.
pub const PDI_CONTROL: u16 = 0x0140;
/// ESC configuration (u8), from SII word 0's high byte.
pub const ESC_CONFIG: u16 = 0x0141;
/// ECAT event mask (u16).
pub const EVENT_MASK: u16 = 0x0200;
/// ECAT event request (u16).
pub const EVENT_REQUEST: u16 = 0x0210;
/// First error counter (RX errors, 0300h..0313h).
pub const ERROR_COUNTERS: u16 = 0x0300;
/// Watchdog divider (u16, in 40 ns units).
pub const WATCHDOG_DIVIDER: u16 = 0x0400;
/// PDI watchdog (u16).
pub const WATCHDOG_PDI: u16 = 0x0410;
/// Sync manager watchdog time (u16, in divider units).
pub const WATCHDOG_SM: u16 = 0x0420;
/// Sync manager watchdog status (u16: bit 0 = 1 while not expired).
pub const WATCHDOG_SM_STATUS: u16 = 0x0440;
/// SII EEPROM owner (u8: bit 0 PDI).
pub const SII_CONFIG: u16 = 0x0500;
/// SII control and status (u16).
pub const SII_CONTROL: u16 = 0x0502;
/// SII word address (u32).
pub const SII_ADDRESS: u16 = 0x0504;
/// SII data (4 or 8 bytes read; 2 written).
pub const SII_DATA: u16 = 0x0508;
/// FMMU 0; FMMU n at `FMMU0 + 16 n`.
pub const FMMU0: u16 = 0x0600;
/// Bytes per FMMU.
pub const FMMU_LEN: u16 = 16;
/// Sync manager 0; SM n at `SM0 + 8 n`.
pub const SM0: u16 = 0x0800;
/// Bytes per sync manager.
pub const SM_LEN: u16 = 8;
/// DC receive time port 0 (u32); a write latches the receive times.
pub const DC_RECEIVE_TIME_PORT0: u16 = 0x0900;
/// DC system time (u64): local time plus offset.
pub const DC_SYSTEM_TIME: u16 = 0x0910;
/// DC receive time at the processing unit (u64), latched with port 0's.
pub const DC_RECEIVE_TIME_PU: u16 = 0x0918;
/// DC system time offset (u64).
pub const DC_SYSTEM_TIME_OFFSET: u16 = 0x0920;
/// DC system time delay (u32).
pub const DC_SYSTEM_TIME_DELAY: u16 = 0x0928;
/// DC system time difference (u32: bit 31 sign, 0..30 magnitude).
pub const DC_SYSTEM_TIME_DIFFERENCE: u16 = 0x092C;
/// DC speed counter start (u16).
pub const DC_SPEED_COUNTER_START: u16 = 0x0930;
/// DC time filter depth (u16).
pub const DC_FILTER_DEPTH: u16 = 0x0934;
/// DC cyclic unit control (u8).
pub const DC_CYCLIC_UNIT_CONTROL: u16 = 0x0980;
/// DC activation (u8): bit 0 cyclic unit, bit 1 SYNC0, bit 2 SYNC1.
pub const DC_ACTIVATION: u16 = 0x0981;
/// DC start time of cyclic operation (u64, system time).
pub const DC_START_TIME: u16 = 0x0990;
/// DC SYNC0 cycle time (u32, ns).
pub const DC_SYNC0_CYCLE: u16 = 0x09A0;
/// DC SYNC1 cycle time (u32, ns).
pub const DC_SYNC1_CYCLE: u16 = 0x09A4;
/// The first byte of process memory (mailboxes and process data).
pub const PROCESS_RAM: u16 = 0x1000;

/// Feature bit: distributed clocks supported.
pub const FEATURE_DC: u16 = 1 << 2;
/// Feature bit: 64-bit DC.
pub const FEATURE_DC64: u16 = 1 << 3;

/// SII control: 8-byte reads supported (status bit 6).
pub const SII_READ_8: u16 = 1 << 6;
/// SII control: read command.
pub const SII_CMD_READ: u16 = 1 << 8;
/// SII control: write command.
pub const SII_CMD_WRITE: u16 = 1 << 9;
/// SII control: reload command.
pub const SII_CMD_RELOAD: u16 = 1 << 10;
/// SII control: the command bits.
pub const SII_CMD_MASK: u16 = 0x0700;
/// SII status: checksum error, device information error, NACK, write error.
pub const SII_ERROR_MASK: u16 = 0x7800;
/// SII status: acknowledge missing (the word address is past the EEPROM).
pub const SII_NACK: u16 = 1 << 13;
/// SII status: busy.
pub const SII_BUSY: u16 = 1 << 15;

/// AL control/status: the error acknowledge (control) or error flag (status) bit.
pub const AL_ERROR: u16 = 0x10;
/// AL control/status: the state bits.
pub const AL_STATE_MASK: u16 = 0x0F;

/// Sync manager control byte: mode bits (00 buffered, 10 mailbox).
pub const SM_MODE_MASK: u8 = 0x03;
/// Sync manager mode: mailbox.
pub const SM_MODE_MAILBOX: u8 = 0x02;
/// Sync manager control byte: direction bits (00 the master reads, 01 the master writes).
pub const SM_DIRECTION_MASK: u8 = 0x0C;
/// Sync manager direction: the master writes.
pub const SM_DIRECTION_WRITE: u8 = 0x04;
/// Sync manager control byte: watchdog trigger.
pub const SM_WATCHDOG: u8 = 0x40;
/// Sync manager status byte: mailbox full.
pub const SM_STATUS_FULL: u8 = 0x08;
/// Sync manager activate byte: enable.
pub const SM_ENABLE: u8 = 0x01;
/// Sync manager activate byte: repeat request (mailbox).
pub const SM_REPEAT: u8 = 0x02;
/// Sync manager PDI control byte: repeat acknowledge.
pub const SM_REPEAT_ACK: u8 = 0x02;

/// The register of sync manager `n`.
pub const fn sm(n: u8) -> u16 {
    SM0 + SM_LEN * n as u16
}

/// The register of FMMU `n`.
pub const fn fmmu(n: u8) -> u16 {
    FMMU0 + FMMU_LEN * n as u16
}
