//! A simulated EtherCAT slave controller (ESC): the memory a master reads and writes through
//! datagrams, with the behaviour of the registers a master uses (digest §2): addressing and
//! working counters, the SII interface, sync managers (mailbox full and empty, process data
//! written), FMMUs for logical addressing, AL control and status, the SM watchdog, and the
//! distributed-clock subset of digest §7.2.
//!
//! The ESC is the EtherCAT side only. The application behind it (the PDI side: the drive's
//! firmware) reads what the master wrote and answers through [`Esc`]'s PDI methods: it takes
//! AL control requests and sets AL status, takes mailbox messages and queues replies, reads the
//! outputs and writes the inputs. Time is fed in; nothing here does I/O.
//!
//! What it leaves out: bit-granular FMMUs (masters map whole bytes), the three-buffer exchange
//! of process data sync managers (one buffer: a frame sees the inputs of the last update), ECAT
//! and PDI interrupts, error counters (always 0), SII writes and the PDI's own EEPROM access,
//! propagation delays (every ESC of a segment sees a frame at the same time, so the DC delays
//! are 0), and DC drift (a written system time is taken exactly).

use super::frame::{Addressing, Command, Datagram, MAX_DATAGRAMS_LEN};
use super::register as reg;
use super::sii::SiiImage;
use crate::time::Instant;

/// Bytes of ESC memory modelled: registers (0000h..0FFFh) and 4 KiB of process RAM.
pub const MEMORY: usize = 0x2000;
/// FMMUs offered.
pub const FMMUS: u8 = 8;
/// Sync managers offered.
pub const SMS: u8 = 8;
/// The longest mailbox message kept for a repeat request.
pub const MAILBOX_MAX: usize = 512;

/// How an ESC is set up (what its hardware and wiring would fix).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EscConfig {
    /// Whether distributed clocks are offered (feature bit 2, 64-bit).
    pub dc: bool,
    /// Whether another ESC follows on port 1 (DL status: port 1 open).
    pub port1_connected: bool,
}

/// A sync manager's set-up, as the master wrote it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SyncManager {
    /// Physical start address.
    pub start: u16,
    /// Length in bytes.
    pub len: u16,
    /// Control byte.
    pub control: u8,
    /// Whether it is enabled.
    pub enabled: bool,
}

impl SyncManager {
    /// Whether it is a mailbox (rather than a buffered process-data sync manager).
    pub fn mailbox(&self) -> bool {
        self.control & reg::SM_MODE_MASK == reg::SM_MODE_MAILBOX
    }
    /// Whether the master writes it (rather than reads it).
    pub fn master_writes(&self) -> bool {
        self.control & reg::SM_DIRECTION_MASK == reg::SM_DIRECTION_WRITE
    }
    /// Its bytes in ESC memory, cut at the memory's end (a master may set any address).
    pub fn area(&self) -> core::ops::Range<usize> {
        let start = usize::from(self.start).min(MEMORY);
        start..(start + usize::from(self.len)).min(MEMORY)
    }
    /// Whether `[start, start + len)` overlaps it.
    fn overlaps(&self, start: usize, len: usize) -> bool {
        let s = usize::from(self.start);
        let e = s + usize::from(self.len);
        self.enabled && self.len > 0 && start < e && s < start + len
    }
    /// Whether an access `[start, start + len)` covers its last byte.
    fn covers_last(&self, start: usize, len: usize) -> bool {
        let last = usize::from(self.start) + usize::from(self.len) - 1;
        start <= last && last < start + len
    }
}

/// A simulated ESC.
#[derive(Clone)]
pub struct Esc {
    mem: [u8; MEMORY],
    sii: SiiImage,
    config: EscConfig,
    /// The AL control value the master wrote, until the application takes it.
    al_request: Option<u16>,
    /// Per sync manager: a mailbox that holds a message (master-written: not yet taken by the
    /// PDI; master-read: not yet read by the master).
    full: [bool; SMS as usize],
    /// Per sync manager: written by the master since the PDI last looked (process data).
    written: [bool; SMS as usize],
    /// The last time a sync manager with the watchdog trigger was written.
    last_trigger: Option<Instant>,
    /// The last message put into the read mailbox, for a repeat request.
    last_out: heapless::Vec<u8, MAILBOX_MAX>,
    /// The repeat-request bit of SM1 as last seen.
    repeat_seen: bool,
    /// The frame's arrival time (the local clock).
    now: Instant,
}

impl core::fmt::Debug for Esc {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Esc")
            .field("station", &self.station_address())
            .field("al_status", &self.al_status())
            .finish_non_exhaustive()
    }
}

impl Esc {
    /// An ESC after power-on: Init, registers at their reset values, alias from the SII.
    pub fn new(config: EscConfig, sii: SiiImage) -> Esc {
        let mut esc = Esc {
            mem: [0; MEMORY],
            sii,
            config,
            al_request: None,
            full: [false; SMS as usize],
            written: [false; SMS as usize],
            last_trigger: None,
            last_out: heapless::Vec::new(),
            repeat_seen: false,
            now: Instant::ZERO,
        };
        esc.power_on();
        esc
    }

    /// Resets every register to its power-on value (a drive switched off and on).
    pub fn power_on(&mut self) {
        self.mem = [0; MEMORY];
        // ET1100-like: type 11h, revision 0, build 0; 8 FMMUs, 8 SMs, 8 KiB RAM; ports 0 and 1
        // EBUS, 2 and 3 not implemented.
        self.put8(reg::TYPE, 0x11);
        self.put8(reg::FMMU_COUNT, FMMUS);
        self.put8(reg::SM_COUNT, SMS);
        self.put8(reg::RAM_SIZE, 8);
        self.put8(reg::PORT_DESCRIPTOR, 0x0A);
        let features = if self.config.dc {
            reg::FEATURE_DC | reg::FEATURE_DC64
        } else {
            0
        };
        self.put16(reg::FEATURES, features);
        self.put16(reg::STATION_ALIAS, self.sii.word(4));
        let pdi = self.sii.word(0);
        self.put8(reg::PDI_CONTROL, pdi as u8);
        self.put8(reg::ESC_CONFIG, (pdi >> 8) as u8);
        self.put16(reg::DL_STATUS, self.dl_status());
        self.put16(reg::AL_STATUS, crate::ethercat::esm::AlState::Init as u16);
        // Watchdog: divider 2498 (100 µs), SM watchdog 1000 (100 ms), PDI watchdog 1000.
        self.put16(reg::WATCHDOG_DIVIDER, 2498);
        self.put16(reg::WATCHDOG_PDI, 1000);
        self.put16(reg::WATCHDOG_SM, 1000);
        self.put16(reg::SII_CONTROL, reg::SII_READ_8);
        self.al_request = None;
        self.full = [false; SMS as usize];
        self.written = [false; SMS as usize];
        self.last_trigger = None;
        self.last_out.clear();
        self.repeat_seen = false;
    }

    /// DL status: PDI operational and watchdog fine, port 0 linked and communicating, port 1
    /// the same when another ESC follows, else closed; ports 2 and 3 closed.
    fn dl_status(&self) -> u16 {
        let mut v = 0x0001 | 0x0002 | 0x0010 | 0x0200 | 0x1000 | 0x4000;
        if self.config.port1_connected {
            v |= 0x0020 | 0x0800;
        } else {
            v |= 0x0400;
        }
        v
    }

    // ---- the EtherCAT side ---------------------------------------------------------------

    /// Processes one datagram as the frame passes through, at time `now`.
    pub fn process(&mut self, dg: &mut Datagram<'_>, now: Instant) {
        self.now = now;
        let Some(cmd) = dg.command() else {
            return;
        };
        match cmd.addressing() {
            Addressing::None => {}
            Addressing::Position => {
                let adp = dg.adp();
                dg.set_adp(adp.wrapping_add(1));
                if adp == 0 {
                    self.physical(cmd, dg, true);
                } else if cmd == Command::Armw {
                    self.physical(cmd, dg, false);
                }
            }
            Addressing::Station => {
                let adp = dg.adp();
                let alias_on = self.mem[usize::from(reg::DL_CONTROL) + 3] & 1 != 0;
                let me = adp == self.station_address()
                    || (alias_on && adp != 0 && adp == self.get16(reg::STATION_ALIAS));
                if me {
                    self.physical(cmd, dg, true);
                } else if cmd == Command::Frmw {
                    self.physical(cmd, dg, false);
                }
            }
            Addressing::Broadcast => {
                let adp = dg.adp();
                dg.set_adp(adp.wrapping_add(1));
                self.physical(cmd, dg, true);
            }
            Addressing::Logical => self.logical(cmd, dg),
        }
    }

    /// A register or memory access at ADO. `addressed` is false for the "multiple write" half
    /// of ARMW/FRMW (this ESC writes rather than reads).
    fn physical(&mut self, cmd: Command, dg: &mut Datagram<'_>, addressed: bool) {
        let start = usize::from(dg.ado());
        let len = dg.data().len();
        if start + len > MEMORY {
            return;
        }
        let (read, write) = match (cmd, addressed) {
            (Command::Armw | Command::Frmw, true) => (true, false),
            (Command::Armw | Command::Frmw, false) => (false, true),
            _ => (cmd.reads(), cmd.writes()),
        };
        if !self.sm_allows(start, len, read, write) {
            return;
        }
        let mut wkc = 0;
        if read {
            self.refresh(start, len);
            let src = &self.mem[start..start + len];
            let data = dg.data_mut();
            if cmd == Command::Brd || cmd == Command::Brw {
                data.iter_mut().zip(src).for_each(|(d, s)| *d |= s);
            } else if !write {
                data.copy_from_slice(src);
            }
            wkc += 1;
        }
        if write {
            if read && cmd != Command::Brw {
                // Read-write: the old contents go back, the new ones stay.
                let mut incoming = [0u8; MAX_DATAGRAMS_LEN];
                let incoming = &mut incoming[..len];
                incoming.copy_from_slice(dg.data());
                dg.data_mut().copy_from_slice(&self.mem[start..start + len]);
                self.write(start, incoming);
            } else {
                self.write(start, dg.data());
            }
            wkc += if read { 2 } else { 1 };
        }
        if read {
            self.after_read(start, len);
        }
        dg.add_wkc(wkc);
    }

    /// LRD/LWR/LRW through the FMMUs: +1 if a read FMMU matched, +2 if a write FMMU did.
    fn logical(&mut self, cmd: Command, dg: &mut Datagram<'_>) {
        let address = dg.address();
        let len = dg.data().len() as u32;
        let (mut read_hit, mut write_hit) = (false, false);
        for n in 0..FMMUS {
            let f = usize::from(reg::fmmu(n));
            if self.mem[f + 12] & 1 == 0 {
                continue;
            }
            let log_start = u32::from_le_bytes([
                self.mem[f],
                self.mem[f + 1],
                self.mem[f + 2],
                self.mem[f + 3],
            ]);
            let log_len = u32::from(u16::from_le_bytes([self.mem[f + 4], self.mem[f + 5]]));
            let phys = u16::from_le_bytes([self.mem[f + 8], self.mem[f + 9]]);
            let kind = self.mem[f + 11];
            let lo = log_start.max(address);
            let hi = log_start
                .saturating_add(log_len)
                .min(address.saturating_add(len));
            if lo >= hi {
                continue;
            }
            let n_bytes = (hi - lo) as usize;
            let phys_at = usize::from(phys) + (lo - log_start) as usize;
            let dg_at = (lo - address) as usize;
            if phys_at + n_bytes > MEMORY {
                continue;
            }
            if kind & 0x01 != 0 && cmd.reads() && self.sm_allows(phys_at, n_bytes, true, false) {
                self.refresh(phys_at, n_bytes);
                dg.data_mut()[dg_at..dg_at + n_bytes]
                    .copy_from_slice(&self.mem[phys_at..phys_at + n_bytes]);
                self.after_read(phys_at, n_bytes);
                read_hit = true;
            }
            if kind & 0x02 != 0 && cmd.writes() && self.sm_allows(phys_at, n_bytes, false, true) {
                self.write(phys_at, &dg.data()[dg_at..dg_at + n_bytes]);
                write_hit = true;
            }
        }
        dg.add_wkc(u16::from(read_hit) + 2 * u16::from(write_hit));
    }

    /// Whether the sync managers let this access through: a master-written mailbox refuses a
    /// write while it is full, a master-read mailbox refuses a read while it is empty.
    fn sm_allows(&self, start: usize, len: usize, read: bool, write: bool) -> bool {
        (0..SMS).all(|n| {
            let sm = self.sync_manager(n);
            if !sm.overlaps(start, len) || !sm.mailbox() {
                return true;
            }
            let full = self.full[usize::from(n)];
            if sm.master_writes() {
                !write || !full
            } else {
                !read || full
            }
        })
    }

    /// Brings computed registers up to date before the master reads them.
    fn refresh(&mut self, start: usize, len: usize) {
        let touches = |r: u16, n: usize| start < usize::from(r) + n && usize::from(r) < start + len;
        if touches(reg::DC_SYSTEM_TIME, 8) {
            let t = self.system_time();
            self.put64(reg::DC_SYSTEM_TIME, t);
        }
        if touches(reg::WATCHDOG_SM_STATUS, 2) {
            let ok = !self.watchdog_expired();
            self.put16(reg::WATCHDOG_SM_STATUS, u16::from(ok));
        }
        for n in 0..SMS {
            let status = usize::from(reg::sm(n)) + 5;
            if start <= status && status < start + len {
                let mut s = self.mem[status] & !reg::SM_STATUS_FULL;
                if self.full[usize::from(n)] {
                    s |= reg::SM_STATUS_FULL;
                }
                self.mem[status] = s;
            }
        }
    }

    /// A read that covered the last byte of a master-read mailbox empties it.
    fn after_read(&mut self, start: usize, len: usize) {
        for n in 0..SMS {
            let sm = self.sync_manager(n);
            if sm.overlaps(start, len)
                && sm.mailbox()
                && !sm.master_writes()
                && sm.covers_last(start, len)
            {
                self.full[usize::from(n)] = false;
            }
        }
    }

    /// Stores what the master wrote, byte by byte as the register map allows, then runs the
    /// side effects of the registers written.
    fn write(&mut self, start: usize, data: &[u8]) {
        let len = data.len();
        let touches = |r: u16, n: usize| start < usize::from(r) + n && usize::from(r) < start + len;
        // The set-ups before the write, only when it reaches the SM registers (a process-data
        // write, every cycle, does not).
        let old_sm: Option<[SyncManager; SMS as usize]> = touches(reg::SM0, usize::from(SMS) * 8)
            .then(|| core::array::from_fn(|n| self.sync_manager(n as u8)));
        for (i, &b) in data.iter().enumerate() {
            let a = start + i;
            if writable(a) {
                self.mem[a] = b;
            }
        }
        if touches(reg::AL_CONTROL, 2) {
            self.al_request = Some(self.get16(reg::AL_CONTROL));
        }
        if touches(reg::SII_CONTROL, 2) {
            self.sii_command();
        }
        if touches(reg::DC_RECEIVE_TIME_PORT0, 4) {
            let t = self.now.as_nanos();
            for p in 0..4u16 {
                self.put32(reg::DC_RECEIVE_TIME_PORT0 + 4 * p, t as u32);
            }
            self.put64(reg::DC_RECEIVE_TIME_PU, t);
        }
        if touches(reg::DC_SYSTEM_TIME, 8) {
            // A system time written by ARMW/FRMW from the reference: lock to it at once.
            let mut b = [0u8; 8];
            for (i, x) in b.iter_mut().enumerate() {
                let a = usize::from(reg::DC_SYSTEM_TIME) + i;
                *x = if (start..start + len).contains(&a) {
                    data[a - start]
                } else {
                    self.mem[a]
                };
            }
            let written = u64::from_le_bytes(b);
            let offset = written.wrapping_sub(self.now.as_nanos());
            self.put64(reg::DC_SYSTEM_TIME_OFFSET, offset);
        }
        if touches(reg::ERROR_COUNTERS, 0x14) {
            self.mem[usize::from(reg::ERROR_COUNTERS)..usize::from(reg::ERROR_COUNTERS) + 0x14]
                .fill(0);
        }
        for n in 0..SMS {
            let i = usize::from(n);
            let sm = self.sync_manager(n);
            if old_sm.is_some_and(|old| old[i] != sm) {
                // A sync manager set up anew starts empty.
                self.full[i] = false;
                self.written[i] = false;
                if n == 1 {
                    self.repeat_seen = self.mem[usize::from(reg::sm(1)) + 6] & reg::SM_REPEAT != 0;
                }
            }
            if !sm.overlaps(start, len) || !sm.master_writes() || !sm.covers_last(start, len) {
                continue;
            }
            if sm.mailbox() {
                self.full[i] = true;
            } else {
                self.written[i] = true;
            }
            if sm.control & reg::SM_WATCHDOG != 0 {
                self.last_trigger = Some(self.now);
            }
        }
        // Repeat request on the read mailbox: put the last message back.
        let activate = self.mem[usize::from(reg::sm(1)) + 6];
        let repeat = activate & reg::SM_REPEAT != 0;
        if repeat != self.repeat_seen {
            self.repeat_seen = repeat;
            let sm = self.sync_manager(1);
            if sm.mailbox() && !self.last_out.is_empty() {
                let area = sm.area();
                let n = self.last_out.len().min(area.len());
                let (mem, last) = (&mut self.mem, &self.last_out);
                mem[area.start..area.start + n].copy_from_slice(&last[..n]);
                self.full[1] = true;
            }
            let pdi = usize::from(reg::sm(1)) + 7;
            self.mem[pdi] =
                (self.mem[pdi] & !reg::SM_REPEAT_ACK) | if repeat { reg::SM_REPEAT_ACK } else { 0 };
        }
    }

    /// Runs an SII command written to 0502h at once (never busy).
    fn sii_command(&mut self) {
        let control = self.get16(reg::SII_CONTROL);
        let cmd = control & reg::SII_CMD_MASK;
        let mut status = reg::SII_READ_8;
        if cmd == reg::SII_CMD_READ {
            let address = self.get32(reg::SII_ADDRESS);
            for w in 0..4u32 {
                let word = self.sii.word(address.wrapping_add(w));
                self.put16(reg::SII_DATA + 2 * w as u16, word);
            }
        } else if cmd == reg::SII_CMD_WRITE {
            // The image is read only: the write is not acknowledged.
            status |= reg::SII_NACK;
        }
        self.put16(reg::SII_CONTROL, status);
    }

    // ---- the PDI side (the application behind the ESC) ------------------------------------

    /// The AL control value the master wrote since the last call, if it wrote one.
    pub fn take_al_control(&mut self) -> Option<u16> {
        self.al_request.take()
    }

    /// Sets AL status (state, error flag) and the AL status code.
    pub fn set_al_status(&mut self, state: super::esm::AlState, error: bool, code: u16) {
        let v = state as u16 | if error { reg::AL_ERROR } else { 0 };
        self.put16(reg::AL_STATUS, v);
        self.put16(reg::AL_STATUS_CODE, code);
    }

    /// AL status as the master reads it.
    pub fn al_status(&self) -> u16 {
        self.get16(reg::AL_STATUS)
    }

    /// The configured station address.
    pub fn station_address(&self) -> u16 {
        self.get16(reg::STATION_ADDRESS)
    }

    /// Sync manager `n` as the master set it up.
    pub fn sync_manager(&self, n: u8) -> SyncManager {
        let at = reg::sm(n);
        SyncManager {
            start: self.get16(at),
            len: self.get16(at + 2),
            control: self.mem[usize::from(at) + 4],
            enabled: self.mem[usize::from(at) + 6] & reg::SM_ENABLE != 0,
        }
    }

    /// The message the master put into the write mailbox (SM0), if there is one not yet taken.
    pub fn mailbox_in(&self) -> Option<&[u8]> {
        let sm = self.sync_manager(0);
        (sm.enabled && sm.mailbox() && self.full[0]).then(|| &self.mem[sm.area()])
    }

    /// Frees the write mailbox once its message is taken.
    pub fn mailbox_in_done(&mut self) {
        self.full[0] = false;
    }

    /// Puts a message into the read mailbox (SM1) if it is empty; false if it is still full
    /// (or not set up), so the caller keeps the message for later.
    pub fn mailbox_out(&mut self, message: &[u8]) -> bool {
        let sm = self.sync_manager(1);
        let area = sm.area();
        if !sm.enabled || !sm.mailbox() || self.full[1] || message.len() > area.len() {
            return false;
        }
        let (head, tail) = self.mem[area].split_at_mut(message.len());
        head.copy_from_slice(message);
        tail.fill(0);
        self.last_out.clear();
        let _ = self
            .last_out
            .extend_from_slice(&message[..message.len().min(MAILBOX_MAX)]);
        self.full[1] = true;
        true
    }

    /// Whether the read mailbox still holds a message the master has not read.
    pub fn mailbox_out_full(&self) -> bool {
        self.full[1]
    }

    /// The bytes of sync manager `n`'s area (the outputs, for SM2).
    pub fn sm_area(&self, n: u8) -> &[u8] {
        &self.mem[self.sync_manager(n).area()]
    }

    /// Writes the inputs into sync manager `n`'s area (SM3), as many bytes as it has.
    pub fn set_sm_area(&mut self, n: u8, bytes: &[u8]) {
        let area = self.sync_manager(n).area();
        let len = area.len().min(bytes.len());
        self.mem[area.start..area.start + len].copy_from_slice(&bytes[..len]);
    }

    /// Whether the master wrote process-data sync manager `n` (covering its last byte) since
    /// the last call.
    pub fn take_written(&mut self, n: u8) -> bool {
        core::mem::take(&mut self.written[usize::from(n)])
    }

    /// The SM watchdog time, or `None` when it is off (0420h or 0400h zero).
    pub fn watchdog_time(&self) -> Option<core::time::Duration> {
        let ticks = u64::from(self.get16(reg::WATCHDOG_SM))
            * (u64::from(self.get16(reg::WATCHDOG_DIVIDER)) + 2);
        (ticks > 0 && self.get16(reg::WATCHDOG_SM) > 0)
            .then(|| core::time::Duration::from_nanos(ticks * 40))
    }

    /// Whether the SM watchdog has run out: a triggering sync manager was written once and
    /// not again within the watchdog time.
    pub fn watchdog_expired(&self) -> bool {
        self.watchdog_expired_at(self.now)
    }

    /// [`Esc::watchdog_expired`] at a given time.
    pub fn watchdog_expired_at(&self, now: Instant) -> bool {
        match (self.watchdog_time(), self.last_trigger) {
            (Some(t), Some(last)) => now.saturating_duration_since(last) > t,
            _ => false,
        }
    }

    /// Restarts the watchdog (on entering Op, the first outputs count from now).
    pub fn clear_watchdog(&mut self) {
        self.last_trigger = None;
    }

    /// The DC system time at the last frame: local time plus the offset (0920h).
    pub fn system_time(&self) -> u64 {
        self.system_time_at(self.now)
    }

    /// The DC system time at `now`.
    pub fn system_time_at(&self, now: Instant) -> u64 {
        now.as_nanos()
            .wrapping_add(self.get64(reg::DC_SYSTEM_TIME_OFFSET))
    }

    /// SYNC0 as the master activated it: (start time, cycle in ns), in system time.
    pub fn sync0(&self) -> Option<(u64, u32)> {
        let act = self.mem[usize::from(reg::DC_ACTIVATION)];
        let cycle = self.get32(reg::DC_SYNC0_CYCLE);
        (self.config.dc && act & 0x03 == 0x03 && cycle > 0)
            .then(|| (self.get64(reg::DC_START_TIME), cycle))
    }

    /// The raw memory (registers and process RAM), for tests and diagnostics.
    pub fn memory(&self) -> &[u8] {
        &self.mem
    }

    // ---- little-endian accessors ---------------------------------------------------------

    fn put8(&mut self, at: u16, v: u8) {
        self.mem[usize::from(at)] = v;
    }
    fn put16(&mut self, at: u16, v: u16) {
        let a = usize::from(at);
        self.mem[a..a + 2].copy_from_slice(&v.to_le_bytes());
    }
    fn put32(&mut self, at: u16, v: u32) {
        let a = usize::from(at);
        self.mem[a..a + 4].copy_from_slice(&v.to_le_bytes());
    }
    fn put64(&mut self, at: u16, v: u64) {
        let a = usize::from(at);
        self.mem[a..a + 8].copy_from_slice(&v.to_le_bytes());
    }
    /// A little-endian u16 register.
    pub fn get16(&self, at: u16) -> u16 {
        let a = usize::from(at);
        u16::from_le_bytes([self.mem[a], self.mem[a + 1]])
    }
    /// A little-endian u32 register.
    pub fn get32(&self, at: u16) -> u32 {
        let a = usize::from(at);
        u32::from_le_bytes([
            self.mem[a],
            self.mem[a + 1],
            self.mem[a + 2],
            self.mem[a + 3],
        ])
    }
    /// A little-endian u64 register.
    pub fn get64(&self, at: u16) -> u64 {
        let a = usize::from(at);
        let mut b = [0u8; 8];
        b.copy_from_slice(&self.mem[a..a + 8]);
        u64::from_le_bytes(b)
    }
}

/// Whether the master may write the byte at `a` (the rest are the ESC's or the PDI's).
fn writable(a: usize) -> bool {
    let a = a as u16;
    match a {
        0x0000..=0x000F => false,
        0x0110..=0x0111 => false,
        0x0130..=0x0135 => false,
        0x0140..=0x0141 => false,
        0x0210..=0x0213 => false,
        0x0440..=0x0441 => false,
        0x0800..=0x087F => a % 8 != 5 && a % 8 != 7,
        0x0900..=0x090F => false,
        0x0910..=0x0917 => false,
        0x0918..=0x091F => false,
        0x092C..=0x092F => false,
        _ => true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ethercat::frame::{Frame, FrameBuilder};
    use crate::ethercat::sii::SiiSpec;

    fn esc() -> Esc {
        Esc::new(
            EscConfig {
                dc: true,
                port1_connected: false,
            },
            SiiImage::build(&SiiSpec::example()).unwrap(),
        )
    }

    /// Sends one datagram through `esc`; returns its data and working counter.
    fn one(
        esc: &mut Esc,
        cmd: Command,
        address: u32,
        data: &[u8],
    ) -> (heapless::Vec<u8, 256>, u16) {
        let mut buf = [0u8; 512];
        let mut b = FrameBuilder::new(&mut buf, [0x10; 6]).unwrap();
        b.push(cmd, 0, address, data).unwrap();
        let n = b.finish();
        let mut f = Frame::parse(&mut buf[..n]).unwrap();
        let mut d = f.datagram(0);
        esc.process(&mut d, Instant::from_millis(1));
        let mut out = heapless::Vec::new();
        out.extend_from_slice(d.data()).unwrap();
        (out, d.wkc())
    }

    fn fpwr(esc: &mut Esc, ado: u16, data: &[u8]) -> u16 {
        let adp = esc.station_address();
        one(
            esc,
            Command::Fpwr,
            u32::from(ado) << 16 | u32::from(adp),
            data,
        )
        .1
    }

    fn fprd(esc: &mut Esc, ado: u16, len: usize) -> (heapless::Vec<u8, 256>, u16) {
        let adp = esc.station_address();
        one(
            esc,
            Command::Fprd,
            u32::from(ado) << 16 | u32::from(adp),
            &[0; 256][..len],
        )
    }

    #[test]
    fn position_then_station_addressing_and_broadcast_counting() {
        let mut e = esc();
        // APWR at position 0 sets the station address; position 1 is someone else.
        assert_eq!(one(&mut e, Command::Apwr, 0x0010_0000, &[0x00, 0x10]).1, 1);
        assert_eq!(one(&mut e, Command::Apwr, 0x0010_FFFF, &[0x99, 0x99]).1, 0);
        assert_eq!(e.station_address(), 0x1000);
        let (d, wkc) = fprd(&mut e, reg::TYPE, 1);
        assert_eq!((d[0], wkc), (0x11, 1));
        // Another station's FPRD is not answered.
        assert_eq!(one(&mut e, Command::Fprd, 0x0000_1001, &[0]).1, 0);
        // BRD ORs and counts; BWR counts.
        assert_eq!(
            one(&mut e, Command::Brd, 0x0130_0000, &[0, 0]),
            (heapless::Vec::from_slice(&[1, 0]).unwrap(), 1)
        );
        assert_eq!(one(&mut e, Command::Bwr, 0x0120_0000, &[0x11, 0]).1, 1);
        assert_eq!(e.take_al_control(), Some(0x11));
        // Read-only registers keep their value.
        fpwr(&mut e, reg::AL_STATUS, &[8, 0]);
        assert_eq!(e.al_status(), 1);
        // FPRW returns the old value and stores the new (+3).
        let adp = u32::from(e.station_address());
        let (old, wkc) = one(
            &mut e,
            Command::Fprw,
            u32::from(reg::EVENT_MASK) << 16 | adp,
            &[4, 0],
        );
        assert_eq!((&old[..], wkc), (&[0u8, 0][..], 3));
        assert_eq!(e.get16(reg::EVENT_MASK), 4);
    }

    #[test]
    fn the_sii_is_read_through_0502h_eight_bytes_at_a_time() {
        let mut e = esc();
        one(&mut e, Command::Apwr, 0x0010_0000, &[0x00, 0x10]);
        let (ctl, _) = fprd(&mut e, reg::SII_CONTROL, 2);
        assert_eq!(
            u16::from_le_bytes([ctl[0], ctl[1]]) & reg::SII_READ_8,
            reg::SII_READ_8
        );
        // ethercrab's request: command 0100h, word address 0008h, two zero bytes.
        fpwr(
            &mut e,
            reg::SII_CONTROL,
            &[0x00, 0x01, 0x08, 0x00, 0x00, 0x00],
        );
        let (ctl, _) = fprd(&mut e, reg::SII_CONTROL, 2);
        let ctl = u16::from_le_bytes([ctl[0], ctl[1]]);
        assert_eq!(
            ctl & (reg::SII_BUSY | reg::SII_CMD_MASK | reg::SII_ERROR_MASK),
            0
        );
        let (data, _) = fprd(&mut e, reg::SII_DATA, 8);
        assert_eq!(&data[..], &[0x1D, 0, 0, 0, 0x34, 0x12, 0, 0]);
    }

    fn mailboxes(e: &mut Esc) {
        one(e, Command::Apwr, 0x0010_0000, &[0x00, 0x10]);
        fpwr(e, reg::sm(0), &[0x00, 0x10, 128, 0, 0x26, 0, 1, 0]);
        fpwr(e, reg::sm(1), &[0x80, 0x10, 128, 0, 0x22, 0, 1, 0]);
    }

    #[test]
    fn mailbox_full_on_the_last_byte_and_refused_while_full() {
        let mut e = esc();
        mailboxes(&mut e);
        // A write that stops short of the last byte does not fill SM0.
        assert_eq!(fpwr(&mut e, 0x1000, &[1; 64]), 1);
        assert!(e.mailbox_in().is_none());
        assert_eq!(fpwr(&mut e, 0x1000, &[2; 128]), 1);
        assert_eq!(e.mailbox_in().map(|m| m[0]), Some(2));
        let (st, _) = fprd(&mut e, reg::sm(0) + 5, 1);
        assert_eq!(st[0] & reg::SM_STATUS_FULL, reg::SM_STATUS_FULL);
        // Full: a second message is refused (no working counter, nothing written).
        assert_eq!(fpwr(&mut e, 0x1000, &[3; 128]), 0);
        assert_eq!(e.mailbox_in().map(|m| m[0]), Some(2));
        e.mailbox_in_done();
        assert_eq!(fpwr(&mut e, 0x1000, &[3; 128]), 1);
        // SM1: empty refuses a read; a message fills it; reading its last byte empties it.
        assert_eq!(fprd(&mut e, 0x1080, 128).1, 0);
        assert!(e.mailbox_out(&[7, 7, 7]));
        assert!(!e.mailbox_out(&[8]), "still full");
        let (m, wkc) = fprd(&mut e, 0x1080, 128);
        assert_eq!((&m[..3], wkc), (&[7u8, 7, 7][..], 1));
        assert!(!e.mailbox_out_full());
        // Repeat request: toggling SM1's repeat bit puts the last message back.
        fpwr(&mut e, reg::sm(1) + 6, &[0x03]);
        assert!(e.mailbox_out_full());
        let (pdi, _) = fprd(&mut e, reg::sm(1) + 7, 1);
        assert_eq!(pdi[0] & reg::SM_REPEAT_ACK, reg::SM_REPEAT_ACK);
    }

    #[test]
    fn lrw_through_two_fmmus_counts_three_and_moves_both_ways() {
        let mut e = esc();
        mailboxes(&mut e);
        fpwr(&mut e, reg::sm(2), &[0x00, 0x11, 2, 0, 0x64, 0, 1, 0]);
        fpwr(&mut e, reg::sm(3), &[0x80, 0x11, 2, 0, 0x20, 0, 1, 0]);
        // ethercrab's layout: inputs at logical 0, outputs after them.
        let fmmu = |log: u32, phys: u16, kind: u8| {
            let mut f = [0u8; 16];
            f[..4].copy_from_slice(&log.to_le_bytes());
            f[4..6].copy_from_slice(&2u16.to_le_bytes());
            f[7] = 7;
            f[8..10].copy_from_slice(&phys.to_le_bytes());
            f[11] = kind;
            f[12] = 1;
            f
        };
        fpwr(&mut e, reg::fmmu(0), &fmmu(2, 0x1100, 2));
        fpwr(&mut e, reg::fmmu(1), &fmmu(0, 0x1180, 1));
        e.set_sm_area(3, &[0xAA, 0xBB]);
        let (d, wkc) = one(&mut e, Command::Lrw, 0, &[0, 0, 5, 6]);
        assert_eq!((&d[..], wkc), (&[0xAAu8, 0xBB, 5, 6][..], 3));
        assert_eq!(e.sm_area(2), &[5, 6]);
        assert!(e.take_written(2));
        assert!(!e.take_written(2));
        // A logical address nobody maps: no count.
        assert_eq!(one(&mut e, Command::Lrw, 0x100, &[0; 4]).1, 0);
    }

    #[test]
    fn the_sm_watchdog_runs_out_after_its_time_without_outputs() {
        let mut e = esc();
        mailboxes(&mut e);
        fpwr(&mut e, reg::sm(2), &[0x00, 0x11, 2, 0, 0x64, 0, 1, 0]);
        assert_eq!(
            e.watchdog_time(),
            Some(core::time::Duration::from_millis(100))
        );
        assert!(
            !e.watchdog_expired_at(Instant::from_millis(500)),
            "never triggered"
        );
        fpwr(&mut e, 0x1100, &[1, 2]); // at 1 ms
        assert!(!e.watchdog_expired_at(Instant::from_millis(100)));
        assert!(e.watchdog_expired_at(Instant::from_millis(102)));
    }

    #[test]
    fn dc_latch_offset_and_system_time() {
        let mut e = esc();
        one(
            &mut e,
            Command::Bwr,
            u32::from(reg::DC_RECEIVE_TIME_PORT0) << 16,
            &[0; 4],
        );
        assert_eq!(e.get64(reg::DC_RECEIVE_TIME_PU), 1_000_000);
        one(&mut e, Command::Apwr, 0x0010_0000, &[0x00, 0x10]);
        fpwr(&mut e, reg::DC_SYSTEM_TIME_OFFSET, &5_000u64.to_le_bytes());
        let (t, _) = fprd(&mut e, reg::DC_SYSTEM_TIME, 8);
        assert_eq!(u64::from_le_bytes(t[..8].try_into().unwrap()), 1_005_000);
        // SYNC0 as ethercrab programs it.
        fpwr(&mut e, reg::DC_START_TIME, &2_000_000u64.to_le_bytes());
        fpwr(&mut e, reg::DC_SYNC0_CYCLE, &1_000_000u64.to_le_bytes());
        assert_eq!(e.sync0(), None);
        fpwr(&mut e, reg::DC_ACTIVATION, &[0x03]);
        assert_eq!(e.sync0(), Some((2_000_000, 1_000_000)));
    }
}
