//! The EtherCAT state machine (ESM, digest §4): the states, the AL status codes, and the one
//! transition table a subdevice applies when the master writes AL control (ETG.1000.6; EMCA
//! manual p.42–44: every transition is commanded by the master).
//!
//! The table says what a request means: stay, go after the checks of that transition, or refuse
//! with a code. The checks themselves (mailbox set-up, process data sizes, valid outputs) are
//! the subdevice's, since they read its sync managers and dictionary.
//!
//! ```
//! use drivers::ethercat::esm::{AlState, AlStatusCode, Request, request};
//! assert_eq!(request(AlState::Init, 0x02), Request::Go(AlState::PreOp));
//! assert_eq!(request(AlState::Init, 0x08), Request::Refuse(AlStatusCode::INVALID_STATE_CHANGE));
//! assert_eq!(request(AlState::Op, 0x01), Request::Go(AlState::Init));
//! ```

/// An ESM state, as AL control and AL status code it (bits 0–3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[repr(u8)]
pub enum AlState {
    /// Init: no mailbox, no process data.
    Init = 0x01,
    /// Pre-operational: mailbox communication.
    PreOp = 0x02,
    /// Bootstrap: firmware download (not offered by the simulated EMCA).
    Boot = 0x03,
    /// Safe-operational: inputs are updated, outputs are not applied.
    SafeOp = 0x04,
    /// Operational: inputs and outputs.
    Op = 0x08,
}

impl AlState {
    /// The state for a code (bits 0–3), if it is one.
    pub const fn from_code(code: u8) -> Option<AlState> {
        match code & 0x0F {
            0x01 => Some(AlState::Init),
            0x02 => Some(AlState::PreOp),
            0x03 => Some(AlState::Boot),
            0x04 => Some(AlState::SafeOp),
            0x08 => Some(AlState::Op),
            _ => None,
        }
    }

    /// The name ETG.1000 and the manuals use.
    pub const fn name(self) -> &'static str {
        match self {
            AlState::Init => "Init",
            AlState::PreOp => "Pre-Operational",
            AlState::Boot => "Bootstrap",
            AlState::SafeOp => "Safe-Operational",
            AlState::Op => "Operational",
        }
    }

    /// The rank on the way up: Init 0, PreOp 1, SafeOp 2, Op 3 (Boot beside Init).
    const fn rank(self) -> u8 {
        match self {
            AlState::Init | AlState::Boot => 0,
            AlState::PreOp => 1,
            AlState::SafeOp => 2,
            AlState::Op => 3,
        }
    }
}

impl core::fmt::Display for AlState {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.name())
    }
}

/// An AL status code (register 0134h, digest §4.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct AlStatusCode(pub u16);

impl AlStatusCode {
    /// No error.
    pub const NONE: AlStatusCode = AlStatusCode(0x0000);
    /// Invalid requested state change (a state skipped).
    pub const INVALID_STATE_CHANGE: AlStatusCode = AlStatusCode(0x0011);
    /// Unknown requested state.
    pub const UNKNOWN_STATE: AlStatusCode = AlStatusCode(0x0012);
    /// Bootstrap not supported.
    pub const BOOTSTRAP_NOT_SUPPORTED: AlStatusCode = AlStatusCode(0x0013);
    /// Invalid mailbox configuration.
    pub const INVALID_MAILBOX_CONFIG: AlStatusCode = AlStatusCode(0x0016);
    /// Invalid sync manager configuration.
    pub const INVALID_SM_CONFIG: AlStatusCode = AlStatusCode(0x0017);
    /// No valid outputs.
    pub const NO_VALID_OUTPUTS: AlStatusCode = AlStatusCode(0x0019);
    /// Synchronisation error.
    pub const SYNC_ERROR: AlStatusCode = AlStatusCode(0x001A);
    /// Sync manager watchdog.
    pub const SM_WATCHDOG: AlStatusCode = AlStatusCode(0x001B);
    /// Invalid output configuration.
    pub const INVALID_OUTPUT_CONFIG: AlStatusCode = AlStatusCode(0x001D);
    /// Invalid input configuration.
    pub const INVALID_INPUT_CONFIG: AlStatusCode = AlStatusCode(0x001E);
    /// Synchronisation mode not supported.
    pub const SYNC_MODE_NOT_SUPPORTED: AlStatusCode = AlStatusCode(0x0028);
    /// Invalid DC SYNC configuration.
    pub const INVALID_DC_SYNC_CONFIG: AlStatusCode = AlStatusCode(0x0030);
    /// Invalid SYNC0 cycle time.
    pub const INVALID_SYNC0_CYCLE: AlStatusCode = AlStatusCode(0x0036);

    /// What the code means (ETG.1000.6 table 11, as ethercrab's `al_status_code.rs` lists it).
    pub const fn description(self) -> &'static str {
        match self.0 {
            0x0000 => "no error",
            0x0001 => "unspecified error",
            0x0002 => "no memory",
            0x0003 => "invalid device setup",
            0x0011 => "invalid requested state change",
            0x0012 => "unknown requested state",
            0x0013 => "bootstrap not supported",
            0x0014 => "no valid firmware",
            0x0015 => "invalid mailbox configuration (bootstrap)",
            0x0016 => "invalid mailbox configuration",
            0x0017 => "invalid sync manager configuration",
            0x0018 => "no valid inputs available",
            0x0019 => "no valid outputs",
            0x001A => "synchronization error",
            0x001B => "sync manager watchdog",
            0x001C => "invalid sync manager types",
            0x001D => "invalid output configuration",
            0x001E => "invalid input configuration",
            0x001F => "invalid watchdog configuration",
            0x0020 => "slave needs cold start",
            0x0021 => "slave needs Init",
            0x0022 => "slave needs Pre-Operational",
            0x0023 => "slave needs Safe-Operational",
            0x0024 => "invalid input mapping",
            0x0025 => "invalid output mapping",
            0x0026 => "inconsistent settings",
            0x0027 => "free-run not supported",
            0x0028 => "synchronization mode not supported",
            0x0029 => "free-run needs three buffer mode",
            0x002A => "background watchdog",
            0x002B => "no valid inputs and outputs",
            0x002C => "fatal sync error",
            0x002D => "no sync error",
            0x0030 => "invalid DC SYNC configuration",
            0x0031 => "invalid DC latch configuration",
            0x0032 => "PLL error",
            0x0033 => "DC sync IO error",
            0x0034 => "DC sync timeout error",
            0x0035 => "DC invalid sync cycle time",
            0x0036 => "DC SYNC0 cycle time",
            0x0037 => "DC SYNC1 cycle time",
            0x0050 => "EEPROM no access",
            0x0051 => "EEPROM error",
            0x0060 => "slave restarted locally",
            _ => "code not listed by ETG.1000",
        }
    }
}

impl core::fmt::Display for AlStatusCode {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "AL status code {:04X}h ({})", self.0, self.description())
    }
}

/// What an AL control request asks of a subdevice in a given state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Request {
    /// Already there: nothing to do.
    Stay,
    /// Go to this state once its checks pass (none for a step down).
    Go(AlState),
    /// Refused: stay, set the error flag and this code.
    Refuse(AlStatusCode),
}

/// The transition table (digest §4.2): what the requested state code (AL control bits 0–3)
/// means in state `from`.
///
/// | from \ to | Init | PreOp | Boot | SafeOp | Op |
/// |---|---|---|---|---|---|
/// | Init | stay | go | 0013h | 0011h | 0011h |
/// | PreOp | go | stay | 0011h | go | 0011h |
/// | Boot | go | 0011h | stay | 0011h | 0011h |
/// | SafeOp | go | go | 0011h | stay | go |
/// | Op | go | go | 0011h | go | stay |
///
/// Any other code: 0012h. Going down is always allowed; going up takes one step at a time.
pub const fn request(from: AlState, code: u8) -> Request {
    let Some(to) = AlState::from_code(code) else {
        return Request::Refuse(AlStatusCode::UNKNOWN_STATE);
    };
    if to as u8 == from as u8 {
        return Request::Stay;
    }
    match (from, to) {
        (AlState::Init, AlState::Boot) => Request::Refuse(AlStatusCode::BOOTSTRAP_NOT_SUPPORTED),
        (_, AlState::Boot) | (AlState::Boot, _) if !matches!(to, AlState::Init) => {
            Request::Refuse(AlStatusCode::INVALID_STATE_CHANGE)
        }
        _ if to.rank() < from.rank() || matches!(to, AlState::Init) => Request::Go(to),
        _ if to.rank() == from.rank() + 1 => Request::Go(to),
        _ => Request::Refuse(AlStatusCode::INVALID_STATE_CHANGE),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use AlState::*;

    #[test]
    fn the_table_matches_the_documented_one() {
        let states = [Init, PreOp, Boot, SafeOp, Op];
        // Rows: from; columns: to, in the order above. G = go, S = stay, else the code.
        const G: u16 = 1;
        const S: u16 = 0;
        let table: [[u16; 5]; 5] = [
            [S, G, 0x13, 0x11, 0x11],
            [G, S, 0x11, G, 0x11],
            [G, 0x11, S, 0x11, 0x11],
            [G, G, 0x11, S, G],
            [G, G, 0x11, G, S],
        ];
        for (i, from) in states.iter().enumerate() {
            for (j, to) in states.iter().enumerate() {
                let want = match table[i][j] {
                    S => Request::Stay,
                    G => Request::Go(*to),
                    c => Request::Refuse(AlStatusCode(c)),
                };
                assert_eq!(request(*from, *to as u8), want, "{from} -> {to}");
            }
        }
        for bad in [0x00, 0x05, 0x06, 0x07, 0x09, 0x0F] {
            assert_eq!(
                request(Op, bad),
                Request::Refuse(AlStatusCode::UNKNOWN_STATE)
            );
        }
    }

    #[test]
    fn codes_read_as_text() {
        assert_eq!(
            AlStatusCode::SM_WATCHDOG.to_string(),
            "AL status code 001Bh (sync manager watchdog)"
        );
    }
}
