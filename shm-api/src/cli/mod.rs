//! Code shared by the clients that ship (`motion-watch`, `motion-cmd`, `motion-top`): name
//! resolution against the names in [`MachineState`], formatting in user units, CSV, and each
//! client's argument parsing and main loop. The clients talk to the coordinator only through
//! the small [`Machine`] trait, so that they are tested against an in-process fake and the
//! library's `Client` plugs in by implementing it.

pub mod cmd;
pub mod describe;
pub mod format;
pub mod resolve;
pub mod top;
pub mod watch;

use core::time::Duration;

use crate::contract::{CommandRequest, EventRecord, MachineDescription, MachineState};

pub use crate::client::{ClientError, Latched, Rejected};
pub use crate::request::{Target, name_str};

/// What the clients need of a connection to the coordinator (the library's `Client` implements
/// it by forwarding to its methods of the same names).
pub trait Machine {
    /// The newest state received so far, if any.
    fn latest(&mut self) -> Option<&MachineState>;
    /// The next new state, waiting up to `timeout`.
    fn next(&mut self, timeout: Duration) -> Result<&MachineState, ClientError>;
    /// Sends a command and waits up to `timeout` for its reply.
    fn command(&mut self, req: &CommandRequest, timeout: Duration) -> Result<Latched, Rejected>;
    /// The next event record, waiting up to `timeout` (`Ok(None)`: none came).
    fn wait_event(&mut self, timeout: Duration) -> Result<Option<EventRecord>, ClientError>;
    /// Whether the coordinator still publishes the state (a fake that cannot tell says yes).
    fn coordinator_present(&self) -> bool {
        true
    }
    /// The machine's description, waiting up to `timeout` for it (a fake without one has
    /// none).
    fn description(&mut self, _timeout: Duration) -> Result<&MachineDescription, ClientError> {
        Err(ClientError::NoDescription)
    }
}

/// Connects to the coordinator publishing under `prefix`; fails at once when there is none.
pub fn connect(prefix: &str) -> Result<impl Machine + use<>, ClientError> {
    crate::client::Client::connect(prefix)
}

impl Machine for crate::client::Client {
    fn latest(&mut self) -> Option<&MachineState> {
        crate::client::Client::latest(self)
    }
    fn next(&mut self, timeout: Duration) -> Result<&MachineState, ClientError> {
        crate::client::Client::next(self, timeout)
    }
    fn command(&mut self, req: &CommandRequest, timeout: Duration) -> Result<Latched, Rejected> {
        crate::client::Client::command(self, req, timeout)
    }
    fn wait_event(&mut self, timeout: Duration) -> Result<Option<EventRecord>, ClientError> {
        crate::client::Client::wait_event(self, timeout)
    }
    fn coordinator_present(&self) -> bool {
        crate::client::Client::coordinator_present(self)
    }
    fn description(&mut self, timeout: Duration) -> Result<&MachineDescription, ClientError> {
        crate::client::Client::description(self, timeout)
    }
}

/// Process exit codes of the clients.
pub mod exit {
    /// Done; the command latched.
    pub const OK: i32 = 0;
    /// An error: no coordinator, bad arguments, unknown names, no answer.
    pub const ERROR: i32 = 1;
    /// The coordinator (or the drive) rejected the command.
    pub const REJECTED: i32 = 2;
}

/// Parses `args` with clap; on `--help`/`--version` prints and exits 0, on a usage error prints
/// and exits [`exit::ERROR`] (clap's own code would be 2, which means "rejected" here).
pub fn parse_or_exit<P: clap::Parser>(args: impl IntoIterator<Item = std::ffi::OsString>) -> P {
    match P::try_parse_from(args) {
        Ok(p) => p,
        Err(e) => {
            let code = if e.use_stderr() {
                exit::ERROR
            } else {
                exit::OK
            };
            let _ = e.print();
            std::process::exit(code);
        }
    }
}
