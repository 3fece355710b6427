//! The demonstration script of the embedded default machine (or `--demo`), a built-in client:
//! boot, enable, home every axis, then run each group's record chain from its first record,
//! over and over, until an operator's stop ends it for good. Without the demonstration the
//! script does nothing until the end. At the end (duration or a signal) it stops, then
//! disables, whatever ran. It reads the cycle's published status; its commands take the same
//! path into the cycle as every client's ([`crate::runtime::cycle_loop::CycleLoop`] hands them
//! to the cycle's admission and gives the script the replies). It allocates nothing, so it may
//! run on the cycle thread.

use drivers::time::Instant;

use crate::axis::AxisState;
use crate::command::{Command, GroupId, Reply, Target};
use crate::cycle::{AxisMode, Cycle};
use crate::records::ChainState;

/// Where the script is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// No demonstration: the drives are booted and wait for an operator's commands.
    Idle,
    /// The demonstration was ended by an operator's stop (or quick stop): nothing restarts.
    Stopped,
    /// Waiting for the drives to boot.
    Boot,
    /// Enable sent; waiting for operation enabled.
    Enabling,
    /// Homing.
    Homing,
    /// The chains run.
    Running,
    /// Stop sent; waiting for standstill.
    Stopping,
    /// Disable sent; waiting for the power stages to go off.
    Disabling,
    /// Everything is off.
    Done,
}

/// What the script does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ScriptOptions {
    /// Run the demonstration (enable, home, chains); without, the script only shuts down at the
    /// end.
    pub demo: bool,
    /// Run the chains in the demonstration; without, it only enables and homes.
    pub chains: bool,
    /// Home the axes after enabling.
    pub home: bool,
}

/// The script's state.
#[derive(Clone, Debug)]
pub struct Script {
    opts: ScriptOptions,
    phase: Phase,
    since: Instant,
    /// Chain laps completed (all groups' chains finished once).
    pub laps: u64,
    /// Commands the cycle refused (the script logs none: it counts).
    pub refused: u64,
    /// Set when the user or the duration asked for the end.
    shutdown: bool,
    /// Commands given in the last poll, for the command path to take.
    outbox: heapless::Deque<Command, OUTBOX>,
    /// The cycle's count of accepted stops when the script began ([`Cycle::stops`]).
    stops: Option<u32>,
}

/// Commands one poll can give: one per axis (enable, home) and a few more.
const OUTBOX: usize = crate::config::MAX_AXES + 8;

/// How long a phase may wait before the script gives up on it and moves on.
const PHASE_TIMEOUT: core::time::Duration = core::time::Duration::from_secs(30);
/// The stop phases wait at most this long.
const STOP_TIMEOUT: core::time::Duration = core::time::Duration::from_secs(3);

impl Script {
    /// A script at its start.
    pub fn new(opts: ScriptOptions, now: Instant) -> Script {
        Script {
            opts,
            phase: if opts.demo { Phase::Boot } else { Phase::Idle },
            since: now,
            laps: 0,
            refused: 0,
            shutdown: false,
            stops: None,
            outbox: heapless::Deque::new(),
        }
    }

    /// The phase.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// Asks for the orderly end: stop, then disable.
    pub fn shut_down(&mut self) {
        self.shutdown = true;
    }

    fn go(&mut self, p: Phase, now: Instant) {
        self.phase = p;
        self.since = now;
    }

    /// Gives a command: it goes into the cycle after this poll, by the clients' path.
    fn send(&mut self, cmd: Command) {
        if self.outbox.push_back(cmd).is_err() {
            self.refused += 1;
        }
    }

    /// The next command the script gave, for the command path.
    pub fn next_command(&mut self) -> Option<Command> {
        self.outbox.pop_front()
    }

    /// The cycle's reply to one of the script's commands.
    pub fn answered(&mut self, reply: Reply) {
        if let Reply::Rejected(_) = reply {
            self.refused += 1;
        }
    }

    /// Called once per cycle before the step; `all_booted` once the boot is over.
    pub fn poll<const A: usize, const G: usize>(
        &mut self,
        c: &Cycle<'_, A, G>,
        all_booted: bool,
        now: Instant,
    ) {
        let waited = now.saturating_duration_since(self.since);
        let axes = c.axis_count() as u16;
        fn online<'c, const A: usize, const G: usize>(
            c: &'c Cycle<'_, A, G>,
        ) -> impl Iterator<Item = crate::cycle::AxisStatus> + 'c {
            (0..c.axis_count() as u16)
                .filter_map(|a| c.axis_status(a))
                .filter(|s| s.online && s.fault == crate::fault::FaultReason::None)
        }
        if self.shutdown && !matches!(self.phase, Phase::Stopping | Phase::Disabling | Phase::Done)
        {
            self.send(Command::Stop(Target::All));
            self.go(Phase::Stopping, now);
            return;
        }
        // An operator's stop ends the demonstration for good: a stop is sticky.
        let stops = c.stops();
        if *self.stops.get_or_insert(stops) != stops
            && matches!(
                self.phase,
                Phase::Boot | Phase::Enabling | Phase::Homing | Phase::Running
            )
        {
            self.go(Phase::Stopped, now);
            return;
        }
        match self.phase {
            Phase::Idle | Phase::Stopped => {}
            Phase::Boot => {
                if all_booted {
                    // Axis by axis: a drive that failed to boot must not keep the others off.
                    for a in 0..axes {
                        if c.axis_status(a)
                            .is_some_and(|s| s.online && s.fault == crate::fault::FaultReason::None)
                        {
                            self.send(Command::Enable(Target::Axis(a)));
                        }
                    }
                    self.go(Phase::Enabling, now);
                }
            }
            Phase::Enabling => {
                let ready = online(c).all(|s| s.feedback.state == AxisState::Ready);
                if ready || waited > PHASE_TIMEOUT {
                    if self.opts.home {
                        for a in 0..axes {
                            if c.axis_status(a).is_some_and(|s| s.mode == AxisMode::On) {
                                self.send(Command::Home(Target::Axis(a)));
                            }
                        }
                        self.go(Phase::Homing, now);
                    } else {
                        self.go(Phase::Running, now);
                    }
                }
            }
            Phase::Homing => {
                let done = online(c).all(|s| s.mode != AxisMode::Homing);
                if done || waited > PHASE_TIMEOUT {
                    self.go(Phase::Running, now);
                    self.start_chains(c);
                }
            }
            Phase::Running => {
                if !self.opts.chains {
                    return;
                }
                let groups = c.group_count() as GroupId;
                let idle = (0..groups).filter_map(|g| c.group_status(g)).all(|g| {
                    g.motion.is_none()
                        && !matches!(
                            g.chain.state,
                            ChainState::Delay | ChainState::Moving | ChainState::Waiting
                        )
                });
                if idle && waited.as_millis() > 100 {
                    self.laps += 1;
                    self.since = now;
                    self.start_chains(c);
                }
            }
            Phase::Stopping => {
                let still = online(c).all(|s| !s.moving);
                if still || waited > STOP_TIMEOUT {
                    self.send(Command::Disable(Target::All));
                    self.go(Phase::Disabling, now);
                }
            }
            Phase::Disabling => {
                let off = (0..axes)
                    .filter_map(|a| c.axis_status(a))
                    .filter(|s| s.online)
                    .all(|s| {
                        matches!(
                            s.feedback.state,
                            AxisState::Disabled | AxisState::Offline | AxisState::Fault
                        )
                    });
                if off || waited > STOP_TIMEOUT {
                    self.go(Phase::Done, now);
                }
            }
            Phase::Done => {}
        }
    }

    fn start_chains<const A: usize, const G: usize>(&mut self, c: &Cycle<'_, A, G>) {
        if !self.opts.chains {
            return;
        }
        for g in 0..c.group_count() as GroupId {
            if let Some(first) = c.first_record(g) {
                self.send(Command::StartChain {
                    group: g,
                    record: first,
                });
            }
        }
    }
}
