//! `motion-cmd`: every command of the contract from the shell, names resolved from the state.
//! Exits [`exit::OK`] when the command latched, [`exit::REJECTED`] when it was rejected (or
//! the drive refused a parameter task), [`exit::ERROR`] on errors.

use std::io::Write;
use std::time::{Duration, Instant};

use clap::{Args, Parser, Subcommand};

use super::resolve::{
    ResolveError, axis_index, group_index, group_members, groups, parse_micro, parse_micro_list,
};
use super::{Latched, Machine, Rejected, Target, exit, name_str};
use crate::contract::{CommandRequest, EventRecord, MachineState, event_id};

/// Arguments of `motion-cmd`.
#[derive(Debug, Clone, Parser)]
#[command(
    name = "motion-cmd",
    about = "Sends one command to the motion coordinator"
)]
pub struct CmdArgs {
    /// The coordinator's service prefix.
    #[arg(long, global = true, default_value = crate::DEFAULT_PREFIX)]
    pub prefix: String,
    /// How long to wait for the state, the reply and a parameter's value, ms.
    #[arg(long, global = true, default_value_t = 2000)]
    pub timeout_ms: u64,
    /// The command.
    #[command(subcommand)]
    pub command: Command,
}

/// Which axes a command addresses, by name (or index).
#[derive(Debug, Clone, Args)]
#[group(required = true, multiple = false)]
pub struct TargetArgs {
    /// One axis.
    #[arg(long)]
    pub axis: Option<String>,
    /// Every axis of a group.
    #[arg(long)]
    pub group: Option<String>,
    /// Every axis.
    #[arg(long)]
    pub all: bool,
}

/// The axis or the group a move addresses.
#[derive(Debug, Clone, Args)]
#[group(required = true, multiple = false)]
pub struct MoveTarget {
    /// Move one axis.
    #[arg(long)]
    pub axis: Option<String>,
    /// Move a group (one position per member, in group order).
    #[arg(long)]
    pub group: Option<String>,
}

/// The commands.
#[derive(Debug, Clone, Subcommand)]
pub enum Command {
    /// Enable the power stage.
    Enable(TargetArgs),
    /// Disable the power stage.
    Disable(TargetArgs),
    /// Acknowledge faults.
    Acknowledge(TargetArgs),
    /// Home.
    Home(TargetArgs),
    /// Hold (decelerate on the path; resumable).
    Hold(TargetArgs),
    /// Resume after a hold.
    Resume(TargetArgs),
    /// Stop (end the move or chain).
    Stop(TargetArgs),
    /// Quick stop.
    QuickStop(TargetArgs),
    /// Jog an axis at ‰ of its velocity limit (0 stops).
    Jog {
        /// The axis.
        #[arg(long)]
        axis: String,
        /// Signed ‰ of the velocity limit.
        #[arg(long, allow_negative_numbers = true)]
        permille: i16,
    },
    /// Move an axis or a group to positions in user units.
    Move {
        /// What moves.
        #[command(flatten)]
        target: MoveTarget,
        /// Target(s) in user units, comma-separated for a group ("100,50").
        #[arg(long, allow_hyphen_values = true)]
        to: String,
        /// Share of the limits, %.
        #[arg(long, default_value_t = 100)]
        percent: u8,
        /// If a move runs already, start this one when it has arrived (PLCopen Buffered);
        /// without, the running move ramps down and this one starts from there (Aborting).
        #[arg(long)]
        buffered: bool,
    },
    /// Start a group's record chain.
    StartChain {
        /// The group.
        #[arg(long)]
        group: String,
        /// The first record.
        #[arg(long)]
        record: u16,
    },
    /// Set the feed override of an axis's own moves and jogs, of a group's moves (and its
    /// members'), or of all.
    Override {
        /// What it applies to.
        #[command(flatten)]
        target: TargetArgs,
        /// Override, % (0..=200).
        #[arg(long)]
        percent: u16,
    },
    /// Read a drive parameter and print its value.
    ReadParam {
        /// The axis.
        #[arg(long)]
        axis: String,
        /// Parameter number.
        #[arg(long)]
        pnu: u16,
        /// Sub-index.
        #[arg(long, default_value_t = 0)]
        sub: u8,
    },
    /// Write a drive parameter.
    WriteParam {
        /// The axis.
        #[arg(long)]
        axis: String,
        /// Parameter number.
        #[arg(long)]
        pnu: u16,
        /// Sub-index.
        #[arg(long, default_value_t = 0)]
        sub: u8,
        /// The value.
        #[arg(long, allow_negative_numbers = true)]
        value: i64,
    },
    /// Set a bit of the machine's input word.
    SetInput {
        /// The bit.
        #[arg(long)]
        bit: u16,
        /// 1/0 (or true/false, on/off).
        #[arg(long, value_parser = parse_level, action = clap::ArgAction::Set)]
        value: bool,
    },
}

fn parse_level(s: &str) -> Result<bool, String> {
    match s {
        "1" | "true" | "on" | "high" => Ok(true),
        "0" | "false" | "off" | "low" => Ok(false),
        _ => Err(format!("'{s}' is not 1/0, true/false or on/off")),
    }
}

fn target(state: &MachineState, t: &TargetArgs) -> Result<Target, ResolveError> {
    Ok(match (&t.axis, &t.group) {
        (Some(a), _) => Target::Axis(axis_index(state, a)?),
        (None, Some(g)) => Target::Group(group_index(state, g)?),
        (None, None) => Target::All,
    })
}

/// The request for `command`, names resolved against `state`.
pub fn build_request(
    state: &MachineState,
    command: &Command,
) -> Result<CommandRequest, ResolveError> {
    type C = CommandRequest;
    Ok(match command {
        Command::Enable(t) => C::enable(target(state, t)?),
        Command::Disable(t) => C::disable(target(state, t)?),
        Command::Acknowledge(t) => C::acknowledge(target(state, t)?),
        Command::Home(t) => C::home(target(state, t)?),
        Command::Hold(t) => C::hold(target(state, t)?),
        Command::Resume(t) => C::resume(target(state, t)?),
        Command::Stop(t) => C::stop(target(state, t)?),
        Command::QuickStop(t) => C::quick_stop(target(state, t)?),
        Command::Jog { axis, permille } => C::jog(axis_index(state, axis)?, *permille),
        Command::Move {
            target,
            to,
            percent,
            buffered,
        } => match (&target.axis, &target.group) {
            (Some(a), _) => C::move_axis(axis_index(state, a)?, parse_micro(to)?, *percent)
                .with_buffer(buffer(*buffered)),
            (None, Some(g)) => {
                let gi = group_index(state, g)?;
                let positions = parse_micro_list(to)?;
                let members = groups(state)
                    .get(usize::from(gi))
                    .map_or(0, |g| group_members(g).len());
                if positions.len() != members {
                    return Err(ResolveError::PositionCount {
                        group: g.clone(),
                        axes: members,
                        given: positions.len(),
                    });
                }
                C::move_group(gi, &positions, *percent).with_buffer(buffer(*buffered))
            }
            // clap requires one of the two.
            (None, None) => {
                return Err(ResolveError::UnknownAxis {
                    name: String::new(),
                    known: String::new(),
                });
            }
        },
        Command::StartChain { group, record } => {
            C::start_chain(group_index(state, group)?, *record)
        }
        Command::Override { target: t, percent } => C::set_override_of(target(state, t)?, *percent),
        Command::ReadParam { axis, pnu, sub } => {
            C::read_parameter(axis_index(state, axis)?, *pnu, *sub)
        }
        Command::WriteParam {
            axis,
            pnu,
            sub,
            value,
        } => C::write_parameter(axis_index(state, axis)?, *pnu, *sub, *value),
        Command::SetInput { bit, value } => C::set_input(*bit, *value),
    })
}

/// Whether `ev` ends the parameter task `req` latched in `latched`. Older records (the event
/// log keeps a history for late joiners) are skipped by their cycle.
pub fn is_answer(ev: &EventRecord, req: &CommandRequest, latched: Latched) -> bool {
    ev.id == event_id::PARAMETER as u16
        && ev.axis == req.axis
        && ev.code == req.pnu
        && ev.sub == req.sub
        && ev.cycle >= latched.cycle
}

fn wait_parameter(
    m: &mut impl Machine,
    req: &CommandRequest,
    latched: Latched,
    axis_name: &str,
    timeout: Duration,
    out: &mut impl Write,
    err: &mut impl Write,
) -> i32 {
    let deadline = Instant::now() + timeout;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            let _ = writeln!(
                err,
                "error: no answer to parameter {}:{} of axis {axis_name} within {} ms",
                req.pnu,
                req.sub,
                timeout.as_millis()
            );
            return exit::ERROR;
        }
        match m.wait_event(left) {
            Ok(Some(ev)) if is_answer(&ev, req, latched) => {
                if ev.error != 0 {
                    let _ = writeln!(
                        out,
                        "rejected: the drive refused parameter {}:{} of axis {axis_name}: error {}",
                        req.pnu, req.sub, ev.value
                    );
                    return exit::REJECTED;
                }
                let _ = writeln!(
                    out,
                    "axis {axis_name} parameter {}:{} = {}",
                    req.pnu, req.sub, ev.value
                );
                return exit::OK;
            }
            Ok(_) => {}
            Err(e) => {
                let _ = writeln!(err, "error: waiting for the parameter: {e}");
                return exit::ERROR;
            }
        }
    }
}

/// Runs `motion-cmd` on a connected machine; returns the exit code.
pub fn run(
    m: &mut impl Machine,
    args: &CmdArgs,
    out: &mut impl Write,
    err: &mut impl Write,
) -> i32 {
    let timeout = Duration::from_millis(args.timeout_ms);
    let state = match m.latest() {
        Some(s) => *s,
        None => match m.next(timeout) {
            Ok(s) => *s,
            Err(e) => {
                let _ = writeln!(err, "error: {e}");
                return exit::ERROR;
            }
        },
    };
    let req = match build_request(&state, &args.command) {
        Ok(r) => r,
        Err(e) => {
            let _ = writeln!(err, "error: {e}");
            return exit::ERROR;
        }
    };
    match m.command(&req, timeout) {
        Ok(latched) => {
            let _ = writeln!(out, "latched in cycle {}", latched.cycle);
            match &args.command {
                Command::ReadParam { .. } | Command::WriteParam { .. } => {
                    let name = state
                        .axes
                        .get(usize::from(req.axis))
                        .map_or("?", |a| name_str(&a.name));
                    wait_parameter(m, &req, latched, name, timeout, out, err)
                }
                _ => exit::OK,
            }
        }
        Err(e @ (Rejected::Timeout | Rejected::Disconnected)) => {
            let _ = writeln!(err, "error: {e}");
            exit::ERROR
        }
        Err(e) => {
            let _ = writeln!(out, "rejected: {e}");
            exit::REJECTED
        }
    }
}

/// The request's buffer mode for `--buffered`.
fn buffer(buffered: bool) -> u8 {
    if buffered {
        crate::contract::buffer_mode::BUFFERED
    } else {
        crate::contract::buffer_mode::ABORTING
    }
}
