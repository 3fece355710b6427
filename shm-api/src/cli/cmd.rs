//! `motion-cmd`: every command of the contract from the shell, names resolved from the state,
//! and what an axis or a group holds (`records`, `params`) from the coordinator's machine
//! description. Exits [`exit::OK`] when the command latched (or the listing was printed),
//! [`exit::REJECTED`] when it was rejected (or the drive refused a parameter task),
//! [`exit::ERROR`] on errors.

use std::io::Write;
use std::time::{Duration, Instant};

use clap::{Args, Parser, Subcommand};

use super::describe;
use super::resolve::{
    ResolveError, axes, axis_index, group_index, group_members, groups, parse_micro,
    parse_micro_list,
};
use super::{Latched, Machine, Rejected, Target, exit, format, name_str};
use crate::contract::{
    AxisState, CommandRequest, EventRecord, MachineDescription, MachineState, event_id,
};

/// Arguments of `motion-cmd`.
#[derive(Debug, Clone, Parser)]
#[command(
    name = "motion-cmd",
    about = "Sends one command to the motion coordinator"
)]
pub struct CmdArgs {
    /// The coordinator's service prefix.
    #[arg(long, global = true, default_value = crate::DEFAULT_PREFIX, value_parser = crate::names::check_prefix)]
    pub prefix: String,
    /// How long to wait for the state, the reply and a parameter's value, ms (1 to 3600000).
    #[arg(long, global = true, default_value_t = 2000, value_parser = clap::value_parser!(u64).range(1..=3_600_000))]
    pub timeout_ms: u64,
    /// The command.
    #[command(subcommand)]
    pub command: Command,
    /// Show a progress line while `params` reads (the binary sets it when standard error is a
    /// terminal).
    #[arg(skip)]
    pub progress: bool,
}

/// What `records` lists: an axis's drive records or a group's record table.
#[derive(Debug, Clone, Args)]
#[group(required = true, multiple = false)]
pub struct RecordsTarget {
    /// The axis whose drive records to list.
    #[arg(long)]
    pub axis: Option<String>,
    /// The group whose record table to list, with the step conditions.
    #[arg(long)]
    pub group: Option<String>,
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
        /// Signed ‰ of the velocity limit (-1000 to 1000).
        #[arg(long, allow_negative_numbers = true)]
        permille: i16,
    },
    /// Move an axis or a group to positions in user units.
    Move {
        /// What moves.
        #[command(flatten)]
        target: MoveTarget,
        /// Target(s) in user units, comma-separated for a group ("100,50").
        #[arg(long, allow_hyphen_values = true, value_parser = positions)]
        to: String,
        /// Share of the limits, % (1 to 100).
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
        /// Override, % (0 to 200).
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
    /// List an axis's drive records, or a group's record table with its step conditions (from
    /// the coordinator's machine description, in the axes' units).
    Records(RecordsTarget),
    /// List the parameters (PNUs) of an axis's drive and, where the axis has the parameter
    /// channel, read each simple value.
    Params {
        /// The axis.
        #[arg(long)]
        axis: String,
        /// Only this parameter: every sub-index of it is read (arrays and texts too).
        #[arg(long)]
        pnu: Option<u16>,
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

/// `--to`: decimals in user units, checked before anything connects (the axis's scale, known
/// once connected, then converts them exactly).
fn positions(text: &str) -> Result<String, String> {
    super::resolve::parse_micro_list(text)
        .map(|_| text.to_owned())
        .map_err(|e| e.to_string())
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
                    option: "--axis",
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
        Command::Records(_) => return Err(ResolveError::NoRequest("records")),
        Command::Params { .. } => return Err(ResolveError::NoRequest("params")),
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

/// Waits for the answer to the parameter task `req` and prints it; with the axis's `device`
/// (from the description) the value reads as its type and the refusal in words.
#[allow(clippy::too_many_arguments)]
fn wait_parameter(
    m: &mut impl Machine,
    req: &CommandRequest,
    latched: Latched,
    axis_name: &str,
    device: Option<u8>,
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
                        "rejected: the drive refused parameter {}:{} of axis {axis_name}: {}",
                        req.pnu,
                        req.sub,
                        describe::drive_error_text(device, req.pnu, req.sub, ev.value)
                    );
                    return exit::REJECTED;
                }
                let def = device.and_then(describe::fhpp_variant).and_then(|v| {
                    drivers::fhpp::pnu::Table::of(v)
                        .lookup(drivers::fhpp::fpc::Param::new(req.pnu, req.sub))
                        .ok()
                });
                match def {
                    Some(d) => {
                        let (name, unit) = describe::name_and_unit(d.name);
                        let _ = writeln!(
                            out,
                            "axis {axis_name} parameter {}:{} = {}{} ({name})",
                            req.pnu,
                            req.sub,
                            describe::decode(d, ev.value),
                            if unit.is_empty() {
                                String::new()
                            } else {
                                format!(" {unit}")
                            }
                        );
                    }
                    None => {
                        let _ = writeln!(
                            out,
                            "axis {axis_name} parameter {}:{} = {}",
                            req.pnu, req.sub, ev.value
                        );
                    }
                }
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
    match &args.command {
        Command::Records(t) => return records(m, t, timeout, out, err),
        Command::Params { axis, pnu } => {
            return params(m, axis, *pnu, timeout, args.progress, out, err);
        }
        _ => {}
    }
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
                    // The drive's table reads the answer, where the coordinator describes it.
                    let device = m.description(timeout).ok().and_then(|d| {
                        describe::described_axes(d)
                            .get(usize::from(req.axis))
                            .map(|a| a.device)
                    });
                    wait_parameter(m, &req, latched, name, device, timeout, out, err)
                }
                _ => exit::OK,
            }
        }
        Err(e @ (Rejected::Timeout | Rejected::Disconnected)) => {
            let _ = writeln!(err, "error: {e}");
            exit::ERROR
        }
        Err(e) => {
            let _ = writeln!(
                out,
                "rejected: {}",
                refusal_text(&state, &args.command, &req, &e)
            );
            exit::REJECTED
        }
    }
}

/// The machine's description, or the error said on `err` (then `None`).
fn description<'m>(
    m: &'m mut impl Machine,
    timeout: Duration,
    err: &mut impl Write,
) -> Option<&'m MachineDescription> {
    match m.description(timeout) {
        Ok(d) => Some(d),
        Err(e) => {
            let _ = writeln!(err, "error: {e}");
            None
        }
    }
}

/// `motion-cmd records --axis NAME | --group NAME`.
fn records(
    m: &mut impl Machine,
    target: &RecordsTarget,
    timeout: Duration,
    out: &mut impl Write,
    err: &mut impl Write,
) -> i32 {
    let Some(d) = description(m, timeout, err) else {
        return exit::ERROR;
    };
    let lines = match (&target.axis, &target.group) {
        (Some(a), _) => describe::find_axis(d, a).map(|(_, a)| describe::axis_records(d, a)),
        (None, Some(g)) => describe::find_group(d, g).map(|g| describe::group_records(d, g)),
        // clap requires one of the two.
        (None, None) => Ok(Vec::new()),
    };
    match lines {
        Ok(lines) => {
            for l in lines {
                let _ = writeln!(out, "{l}");
            }
            exit::OK
        }
        Err(e) => {
            let _ = writeln!(err, "error: {e}");
            exit::ERROR
        }
    }
}

/// Why a parameter could not be read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ReadFailure {
    /// The drive refused it: its error number.
    Drive(i64),
    /// No answer in time.
    NoAnswer,
    /// The coordinator refused the request.
    Refused(Rejected),
    /// The connection failed (no reply, the coordinator went away).
    Lost(String),
}

/// Reads parameter `pnu`:`sub` of `axis` through READ_PARAMETER and waits for its answer: the
/// drive's 32 bits, as the event carries them. A busy channel (one task at a time, and a closing
/// exchange between two) is asked again until `timeout`.
pub fn read_parameter(
    m: &mut impl Machine,
    axis: u16,
    pnu: u16,
    sub: u8,
    timeout: Duration,
) -> Result<i64, ReadFailure> {
    let req = CommandRequest::read_parameter(axis, pnu, sub);
    let deadline = Instant::now() + timeout;
    let latched = loop {
        match m.command(&req, timeout) {
            Ok(l) => break l,
            Err(Rejected::Busy) if Instant::now() < deadline => {
                std::thread::sleep(Duration::from_millis(1));
            }
            Err(e @ (Rejected::Timeout | Rejected::Disconnected)) => {
                return Err(ReadFailure::Lost(e.to_string()));
            }
            Err(e) => return Err(ReadFailure::Refused(e)),
        }
    };
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(ReadFailure::NoAnswer);
        }
        match m.wait_event(left) {
            Ok(Some(ev)) if is_answer(&ev, &req, latched) => {
                return if ev.error != 0 {
                    Err(ReadFailure::Drive(ev.value))
                } else {
                    Ok(ev.value)
                };
            }
            Ok(_) => {}
            Err(e) => return Err(ReadFailure::Lost(e.to_string())),
        }
    }
}

/// `motion-cmd params --axis NAME [--pnu N]`.
fn params(
    m: &mut impl Machine,
    axis: &str,
    pnu: Option<u16>,
    timeout: Duration,
    progress: bool,
    out: &mut impl Write,
    err: &mut impl Write,
) -> i32 {
    let Some(d) = description(m, timeout, err) else {
        return exit::ERROR;
    };
    let (index, a) = match describe::find_axis(d, axis) {
        Ok((i, a)) => (i, *a),
        Err(e) => {
            let _ = writeln!(err, "error: {e}");
            return exit::ERROR;
        }
    };
    let heading = describe::axis_heading(d, &a);
    let name = name_str(&a.name).to_owned();
    let device = describe::device_name(a.device);
    let Some(variant) = describe::fhpp_variant(a.device) else {
        let _ = writeln!(out, "{heading}");
        let _ = writeln!(
            out,
            "the {device} is a CiA 402 drive: it has no FHPP parameters (PNUs) to list"
        );
        return exit::OK;
    };
    let entries = match pnu {
        Some(p) => {
            let e = describe::entries_of(variant, p);
            if e.is_empty() {
                let _ = writeln!(err, "error: --pnu {p}: the {device} has no parameter {p}");
                return exit::ERROR;
            }
            e
        }
        None => describe::parameter_entries(variant),
    };
    let _ = writeln!(out, "{heading}");
    if a.fpc == 0 {
        let why = if a.link == crate::contract::link::MODBUS {
            "its 8-byte Modbus profile carries none".to_owned()
        } else if a.link == crate::contract::link::ETHERCAT {
            "the coordinator maps FHPP's 8-byte standard data on EtherCAT, without the FPC"
                .to_owned()
        } else if a.profile != crate::contract::profile::FHPP {
            "the parameter channel is FHPP's, and this axis runs CiA 402".to_owned()
        } else {
            "`fpc = true` on the axis in the configuration maps it on PDO2".to_owned()
        };
        let _ = writeln!(
            out,
            "no parameter channel on axis {name} ({why}): values cannot be read; the \
             {device}'s {} parameters:",
            entries.len()
        );
        let mut cols = describe::parameter_columns(false);
        for e in &entries {
            cols.push(describe::parameter_row(e));
        }
        for l in cols.lines() {
            let _ = writeln!(out, "{l}");
        }
        return exit::OK;
    }
    // What to read: without --pnu each simple value, with it every readable sub-index.
    let readable = |e: &drivers::fhpp::pnu::ParamDef| match pnu {
        Some(_) => e.access != drivers::fhpp::pnu::Access::Wo,
        None => describe::is_simple(e),
    };
    let reads: Vec<(usize, u8)> = entries
        .iter()
        .enumerate()
        .filter(|(_, e)| readable(e))
        .flat_map(|(i, e)| {
            let last = if pnu.is_some() {
                e.last_sub
            } else {
                e.first_sub
            };
            (e.first_sub..=last).map(move |s| (i, s))
        })
        .collect();
    let mut values: Vec<Vec<(u8, Result<i64, ReadFailure>)>> = vec![Vec::new(); entries.len()];
    for (k, &(i, sub)) in reads.iter().enumerate() {
        let e = entries[i];
        if progress {
            let _ = write!(
                err,
                "\r\x1b[Kreading {}/{}: PNU {}:{sub} {}",
                k + 1,
                reads.len(),
                e.pnu,
                describe::name_and_unit(e.name).0
            );
            let _ = err.flush();
        }
        let r = read_parameter(m, index, e.pnu, sub, timeout);
        match r {
            Err(ReadFailure::Refused(why)) => {
                if progress {
                    let _ = write!(err, "\r\x1b[K");
                }
                let text = match why {
                    Rejected::WrongState(reason) => format!("axis {name}: {reason}"),
                    other => other.to_string(),
                };
                let _ = writeln!(out, "rejected: {text}");
                return exit::REJECTED;
            }
            Err(ReadFailure::Lost(e)) => {
                if progress {
                    let _ = write!(err, "\r\x1b[K");
                }
                let _ = writeln!(err, "error: reading the parameters: {e}");
                return exit::ERROR;
            }
            r => values[i].push((sub, r)),
        }
    }
    if progress {
        let _ = write!(err, "\r\x1b[K");
        let _ = err.flush();
    }
    let _ = writeln!(
        out,
        "{} parameter{} of the {device}, {} value{} read over the parameter channel:",
        entries.len(),
        if entries.len() == 1 { "" } else { "s" },
        reads.len(),
        if reads.len() == 1 { "" } else { "s" }
    );
    let mut cols = describe::parameter_columns(true);
    for (e, vals) in entries.iter().zip(&values) {
        let cell = |r: &Result<i64, ReadFailure>| match r {
            Ok(v) => describe::decode(e, *v).to_string(),
            Err(ReadFailure::Drive(n)) => format!(
                "refused by the drive, {}",
                describe::drive_error_text(Some(a.device), e.pnu, e.first_sub, *n)
            ),
            Err(_) => "no answer".to_owned(),
        };
        let mut row = describe::parameter_row(e);
        if vals.is_empty() {
            row.push(describe::unread_text(e, &name));
            cols.push(row);
        } else if e.dtype == drivers::fhpp::pnu::DataType::Char {
            // A text, one character per sub-index.
            let chars: Result<Vec<i64>, &ReadFailure> =
                vals.iter().map(|(_, r)| r.as_ref().map(|v| *v)).collect();
            row.push(match chars {
                Ok(c) => format!("\"{}\"", describe::chars_text(&c)),
                Err(f) => cell(&Err(f.clone())),
            });
            cols.push(row);
        } else if vals.len() == 1 {
            row.push(cell(&vals[0].1));
            cols.push(row);
        } else {
            for (sub, r) in vals {
                let mut row = describe::parameter_row(e);
                row[1] = sub.to_string();
                row.push(cell(r));
                cols.push(row);
            }
        }
    }
    for l in cols.lines() {
        let _ = writeln!(out, "{l}");
    }
    exit::OK
}

/// What `command` addressed, in words: `axis x`, `group gantry`, `every axis`.
fn target_text(state: &MachineState, req: &CommandRequest) -> String {
    match req.target() {
        Some(Target::Axis(a)) => format!("axis {}", axis_name(state, a)),
        Some(Target::Group(g)) => format!(
            "group {}",
            groups(state)
                .get(usize::from(g))
                .map_or("?", |g| name_str(&g.name))
        ),
        Some(Target::All) | None => "every axis".into(),
    }
}

fn axis_name(state: &MachineState, axis: u16) -> &str {
    axes(state)
        .get(usize::from(axis))
        .map_or("?", |a| name_str(&a.name))
}

/// A refusal in words and in the units the user typed: positions in the axis's unit (the
/// coordinator answers them in increments), jog in ‰, override and shares in %; the admission
/// table's reason with the target it concerns.
pub fn refusal_text(
    state: &MachineState,
    command: &Command,
    req: &CommandRequest,
    why: &Rejected,
) -> String {
    match why {
        Rejected::OutOfRange { value, min, max } => {
            out_of_range_text(state, command, req, *value, *min, *max)
        }
        Rejected::WrongState(reason) => format!("{}: {reason}", target_text(state, req)),
        Rejected::Faulted => format!(
            "{}: a fault must be acknowledged first (motion-cmd acknowledge)",
            target_text(state, req)
        ),
        other => other.to_string(),
    }
}

fn out_of_range_text(
    state: &MachineState,
    command: &Command,
    req: &CommandRequest,
    value: i64,
    min: i64,
    max: i64,
) -> String {
    let range = |unit: &str| format!("{value} {unit} outside {min}..={max} {unit}");
    match command {
        Command::Move { .. } if !(1..=100).contains(&req.percent) => {
            format!("--percent {}", range("%"))
        }
        Command::Move { target, .. } => {
            let members: Vec<(usize, u16)> = if target.axis.is_some() {
                vec![(0, req.axis)]
            } else {
                groups(state)
                    .get(usize::from(req.group))
                    .map(|g| {
                        group_members(g)
                            .iter()
                            .enumerate()
                            .map(|(k, &m)| (k, u16::from(m)))
                            .collect()
                    })
                    .unwrap_or_default()
            };
            position_text(state, req, &members, value, min, max).unwrap_or_else(|| {
                format!("a position outside {min}..={max} increments ({value} increments)")
            })
        }
        Command::Jog { axis, .. } => format!("axis {axis}: jog {}", range("‰")),
        Command::Override { .. } => {
            format!("{}: override {}", target_text(state, req), range("%"))
        }
        Command::SetInput { .. } => format!("input bit {value} outside {min}..={max}"),
        _ => format!("{value} outside {min}..={max}"),
    }
}

/// µunits per increment of an axis as a fraction: from what the user typed and what the
/// coordinator made of it (`typed` µunits are `value` increments), else from the axis's
/// published position (`position` µunits are `position_inc` increments).
fn scale(typed: i64, value: i64, axis: Option<&AxisState>) -> Option<(i128, i128)> {
    if typed != 0 && value != 0 {
        return Some((i128::from(typed), i128::from(value)));
    }
    axis.filter(|a| a.position_inc != 0 && a.position != 0)
        .map(|a| (i128::from(a.position), i128::from(a.position_inc)))
}

/// Increments to µunits at `scale`, rounded to the axis's resolution (the largest power of ten
/// of µunits not above one increment), so that a limit reads `400`, not `399.999998`.
fn inc_to_micro(inc: i64, (num, den): (i128, i128)) -> i64 {
    let exact = i128::from(inc) * num;
    let half = den.abs() / 2;
    let v = if (exact < 0) == (den < 0) {
        (exact.abs() + half) / den.abs()
    } else {
        -((exact.abs() + half) / den.abs())
    };
    let per_inc = (num.abs() / den.abs().max(1)).max(1);
    let mut step = 1_i128;
    while step * 10 <= per_inc && step < i128::from(crate::contract::MICRO) {
        step *= 10;
    }
    let rounded = if v < 0 {
        -((-v + step / 2) / step * step)
    } else {
        (v + step / 2) / step * step
    };
    i64::try_from(rounded).unwrap_or(if rounded < 0 { i64::MIN } else { i64::MAX })
}

/// `axis x: 1000 mm outside 0..=400 mm` for the member (`(position index, axis)`) whose
/// position the coordinator refused; `None` when it cannot be told or converted.
fn position_text(
    state: &MachineState,
    req: &CommandRequest,
    members: &[(usize, u16)],
    value: i64,
    min: i64,
    max: i64,
) -> Option<String> {
    let all = axes(state);
    let typed_of = |k: usize| req.positions.get(k).copied().unwrap_or(0);
    // An axis move names its axis; in a group, the member whose typed position comes out as
    // the refused increments at its published scale (the coordinator refuses the first one).
    let (k, axis) = if members.len() == 1 {
        members[0]
    } else {
        *members.iter().find(|&&(k, m)| {
            all.get(usize::from(m))
                .and_then(|a| scale(0, 0, Some(a)))
                .is_some_and(|(num, den)| {
                    let est = i128::from(typed_of(k)) * den / num;
                    let tolerance = (i128::from(value).abs() / 1000).max(2);
                    (est - i128::from(value)).abs() <= tolerance
                })
        })?
    };
    let a = all.get(usize::from(axis));
    let typed = typed_of(k);
    let sc = scale(typed, value, a)?;
    let unit = a.map_or("", |a| name_str(&a.unit));
    let (lo, hi) = (inc_to_micro(min, sc), inc_to_micro(max, sc));
    let (lo, hi) = if lo <= hi { (lo, hi) } else { (hi, lo) };
    Some(format!(
        "axis {}: {} {unit} outside {}..={} {unit}",
        axis_name(state, axis),
        format::user(typed),
        format::user(lo),
        format::user(hi)
    ))
}

/// The request's buffer mode for `--buffered`.
fn buffer(buffered: bool) -> u8 {
    if buffered {
        crate::contract::buffer_mode::BUFFERED
    } else {
        crate::contract::buffer_mode::ABORTING
    }
}
