//! A stand-in coordinator for the shm-api tests and for client development: publishes a
//! synthetic [`MachineState`] every period with the cycle counting up by one, answers commands
//! by simple rules, and publishes an event every few cycles.
//!
//! ```text
//! motion-standin [--prefix P] [--period-us N] [--count N] [--axes N] [--groups N]
//!                [--buffer N] [--max-subscribers N] [--events-every N]
//!                [--stop-on-stdin-eof]
//! ```
//!
//! With `--stop-on-stdin-eof` it ends (cleanly, removing its services) when its standard input
//! closes: a test holds the pipe and drops it to stop the stand-in.
//!
//! SIGINT and SIGTERM stop it cleanly. Prints `ready` once every service is up, `cleaned N` whenever it removed dead nodes, and
//! `done published=N commands=N events=N` when `--count` samples are out (0: run forever).
//!
//! The axes are in mm at 400 increments per mm (`position_inc` is published beside
//! `position`) with positions limited to 0..=400 mm (0..=160 000 increments). Its machine
//! description (`PREFIX/description`) says so: each axis an EMCA on `vbus:standin` (node = its
//! index + 1, without a parameter channel) with one drive record, record 1 to 10 mm at 50
//! mm/s; the groups have no members and no records.
//!
//! Command rules: axis ≥ `--axes` → unknown axis; group ≥ `--groups` → unknown group; record
//! ≥ 64 → unknown record; an axis move outside the position limits → out of range in
//! increments, as the coordinator answers; move percent outside 1..=100, jog outside ±1000 ‰
//! and override above 200 % → out of range; homing axis 3 → wrong state with the admission
//! table's reason (`axis not enabled`); an unknown kind or target → bad request; everything
//! else latches at the next cycle.

use iceoryx2::prelude::SignalHandlingMode;
use shm_api::contract::{
    AxisState, CommandReply, CommandRequest, EventRecord, GroupState, LAYOUT_HASH, LAYOUT_VERSION,
    MAX_AXES, MAX_GROUPS, MachineDescription, MachineState, axis_flags, axis_state, bus_kind,
    command_kind, device, event_id, link, status, target,
};
use shm_api::request::name_bytes;
use shm_api::{
    CommandServer, DescriptionPublisher, EventPublisher, PublisherSettings, ServiceNames,
    StatePublisher, cleanup_dead_nodes_with, create_node_with,
};
use std::io::Write;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

struct Args {
    prefix: String,
    period: Duration,
    count: u64,
    axes: u16,
    groups: u16,
    settings: PublisherSettings,
    events_every: u64,
    stop_on_eof: bool,
}

fn parse() -> Result<Args, String> {
    let mut a = Args {
        prefix: shm_api::DEFAULT_PREFIX.to_owned(),
        period: Duration::from_millis(2),
        count: 0,
        axes: 4,
        groups: 2,
        settings: PublisherSettings::default(),
        events_every: 50,
        stop_on_eof: false,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or_else(|| format!("{flag} needs a value"));
        let num = |v: String| -> Result<u64, String> {
            v.parse()
                .map_err(|_| format!("{flag}: `{v}` is not a number"))
        };
        match flag.as_str() {
            "--prefix" => a.prefix = value()?,
            "--period-us" => a.period = Duration::from_micros(num(value()?)?),
            "--count" => a.count = num(value()?)?,
            "--axes" => a.axes = num(value()?)?.min(MAX_AXES as u64) as u16,
            "--groups" => a.groups = num(value()?)?.min(MAX_GROUPS as u64) as u16,
            "--buffer" => a.settings.state_buffer = num(value()?)? as usize,
            "--max-subscribers" => a.settings.max_subscribers = num(value()?)? as usize,
            "--events-every" => a.events_every = num(value()?)?,
            "--stop-on-stdin-eof" => a.stop_on_eof = true,
            _ => return Err(format!("unknown flag `{flag}`")),
        }
    }
    Ok(a)
}

fn answer(req: &CommandRequest, args: &Args, cycle: u64) -> CommandReply {
    let tag = req.tag;
    let known_target = match req.target {
        target::AXIS => req.axis < args.axes,
        target::GROUP => req.group < args.groups,
        target::ALL => true,
        _ => return CommandReply::rejected(tag, status::BAD_REQUEST, i64::from(req.target)),
    };
    if !known_target {
        return if req.target == target::AXIS {
            CommandReply::rejected(tag, status::UNKNOWN_AXIS, i64::from(req.axis))
        } else {
            CommandReply::rejected(tag, status::UNKNOWN_GROUP, i64::from(req.group))
        };
    }
    match req.kind {
        command_kind::MOVE_AXIS if !(0..=POSITION_MAX_INC).contains(&to_inc(req.positions[0])) => {
            return CommandReply::out_of_range(tag, to_inc(req.positions[0]), 0, POSITION_MAX_INC);
        }
        command_kind::SET_OVERRIDE if req.value > 200 => {
            return CommandReply::out_of_range(tag, req.value, 0, 200);
        }
        command_kind::MOVE_AXIS | command_kind::MOVE_GROUP if !(1..=100).contains(&req.percent) => {
            return CommandReply::out_of_range(tag, i64::from(req.percent), 1, 100);
        }
        command_kind::JOG if !(-1000..=1000).contains(&req.value) => {
            return CommandReply::out_of_range(tag, req.value, -1000, 1000);
        }
        command_kind::START_CHAIN if req.record >= 64 => {
            return CommandReply::rejected(tag, status::UNKNOWN_RECORD, i64::from(req.record));
        }
        command_kind::HOME if req.target == target::AXIS && req.axis == 3 => {
            return CommandReply::wrong_state(tag, "axis not enabled");
        }
        command_kind::ENABLE..=command_kind::SET_INPUT => {}
        _ => return CommandReply::rejected(tag, status::BAD_REQUEST, i64::from(req.kind)),
    }
    CommandReply::latched(tag, cycle + 1)
}

/// µunits per increment: 400 increments per mm.
const MICRO_PER_INC: i64 = 2500;
/// The highest position, increments (400 mm).
const POSITION_MAX_INC: i64 = 160_000;

/// µunits → increments, rounded to nearest.
fn to_inc(micro: i64) -> i64 {
    (micro + micro.signum() * MICRO_PER_INC / 2) / MICRO_PER_INC
}

fn template(args: &Args) -> Box<MachineState> {
    let axis = AxisState {
        position: 0,
        setpoint: 0,
        velocity: 0,
        position_inc: 0,
        setpoint_inc: 0,
        fault_value: 0,
        fault_limit: 0,
        force_permille: 0,
        status_bits: 0,
        flags: axis_flags::ONLINE | axis_flags::ENABLED,
        state: axis_state::READY,
        mode: 1,
        fault: 0,
        activity: 0,
        fault_code: 0,
        active_record: -1,
        name: [0; 16],
        unit: name_bytes("mm"),
        reserved1: [0; 32],
    };
    let group = GroupState {
        active_record: -1,
        record: -1,
        reached: -1,
        override_percent: 100,
        chain_state: 0,
        rc1: 0,
        rcc: 0,
        motion: 0,
        axis_count: 0,
        activity: 0,
        reserved0: [0; 2],
        axes: [0; 8],
        name: [0; 16],
        reserved1: [0; 8],
    };
    let mut s = Box::new(MachineState {
        version: 0,
        layout_hash: 0,
        cycle: 0,
        sync_time_ns: 0,
        publish_time_ns: 0,
        cycle_ns: args.period.as_nanos() as u32,
        axis_count: args.axes,
        group_count: args.groups,
        inputs: 0,
        virtual_time: 0,
        reserved0: [0; 3],
        bus: shm_api::contract::BusStats {
            frames_sent: 0,
            frames_received: 0,
            tx_refused: 0,
            rx_dropped: 0,
            skipped_cycles: 0,
            step_ns: 0,
            wake_late_us: 0,
        },
        axes: [axis; MAX_AXES],
        groups: [group; MAX_GROUPS],
    });
    for (i, a) in s.axes.iter_mut().enumerate().take(usize::from(args.axes)) {
        a.name = name_bytes(&format!("X{i}"));
    }
    for (i, g) in s
        .groups
        .iter_mut()
        .enumerate()
        .take(usize::from(args.groups))
    {
        g.name = name_bytes(&format!("G{i}"));
    }
    s
}

/// The stand-in's machine description (see the module docs).
fn description(args: &Args) -> Box<MachineDescription> {
    // SAFETY: `MachineDescription` is integers and arrays of integers only, so all-zero bytes
    // are a valid value; zeroed on the heap, the 1.3 MB value never lies on the stack.
    let mut d = unsafe { Box::<MachineDescription>::new_zeroed().assume_init() };
    d.version = LAYOUT_VERSION;
    d.layout_hash = LAYOUT_HASH;
    d.cycle_ns = args.period.as_nanos() as u32;
    d.axis_count = args.axes;
    d.group_count = args.groups;
    d.bus_count = 1;
    d.buses[0].name = name_bytes("standin");
    d.buses[0].bitrate = 1_000_000;
    d.buses[0].kind = bus_kind::VBUS;
    for (i, a) in d.axes.iter_mut().enumerate().take(usize::from(args.axes)) {
        a.name = name_bytes(&format!("X{i}"));
        a.unit = name_bytes("mm");
        a.device = device::EMCA;
        a.link = link::CAN;
        a.node = (i % 127) as u8 + 1;
        a.position_max = POSITION_MAX_INC * MICRO_PER_INC;
        a.velocity = 100_000_000;
        a.acceleration = 1_000_000_000;
        a.following_error = 10_000_000;
        (a.increments_per_unit_num, a.increments_per_unit_den) =
            (1_000_000 / MICRO_PER_INC as u64, 1);
        a.record_count = 1;
        a.records[0].number = 1;
        a.records[0].position = 10_000_000;
        a.records[0].velocity = 50_000_000;
        a.records[0].acceleration = 1_000_000_000;
    }
    for (i, g) in d
        .groups
        .iter_mut()
        .enumerate()
        .take(usize::from(args.groups))
    {
        g.name = name_bytes(&format!("G{i}"));
    }
    d
}

fn run(args: &Args) -> Result<(), String> {
    let names = ServiceNames::new(&args.prefix);
    // SIGINT/SIGTERM end the run cleanly (the services are removed).
    let node = create_node_with(SignalHandlingMode::HandleTerminationRequests)
        .map_err(|e| e.to_string())?;
    cleanup_dead_nodes_with(&node);
    let mut server =
        CommandServer::create(&node, &names, &args.settings).map_err(|e| e.to_string())?;
    let mut events =
        EventPublisher::create(&node, &names, &args.settings).map_err(|e| e.to_string())?;
    let mut described =
        DescriptionPublisher::create(&node, &names, &args.settings).map_err(|e| e.to_string())?;
    described
        .publish(&description(args))
        .map_err(|e| e.to_string())?;
    // The state publisher last: a client that sees it finds every other service.
    let mut state =
        StatePublisher::create(&node, &names, &args.settings).map_err(|e| e.to_string())?;
    let out = std::io::stdout();
    let say = |line: &str| {
        let mut o = out.lock();
        let _ = writeln!(o, "{line}");
        let _ = o.flush();
    };
    let stop = Arc::new(AtomicBool::new(false));
    if args.stop_on_eof {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            let _ = std::io::copy(&mut std::io::stdin(), &mut std::io::sink());
            stop.store(true, Ordering::Relaxed);
        });
    }
    say("ready");

    let tpl = template(args);
    let epoch = Instant::now();
    let mut deadline = epoch;
    let (mut cycle, mut commands, mut seq) = (0u64, 0u64, 0u64);
    loop {
        // Serve commands until the cycle's deadline.
        loop {
            // A client that subscribed since gets the description.
            let _ = described.update_connections();
            while let Some(cmd) = server.receive() {
                let reply = answer(cmd.request(), args, cycle);
                cmd.reply(&reply).map_err(|e| e.to_string())?;
                commands += 1;
            }
            let now = Instant::now();
            if now >= deadline {
                break;
            }
            if node
                .wait((deadline - now).min(Duration::from_micros(50)))
                .is_err()
            {
                stop.store(true, Ordering::Relaxed);
                break;
            }
        }
        let mut s = state.loan().map_err(|e| e.to_string())?;
        let (version, hash) = (s.version, s.layout_hash);
        *s = *tpl;
        s.version = version;
        s.layout_hash = hash;
        s.cycle = cycle;
        s.sync_time_ns = (deadline - epoch).as_nanos() as u64;
        s.publish_time_ns = epoch.elapsed().as_nanos() as u64;
        for (i, a) in s.axes.iter_mut().enumerate().take(usize::from(args.axes)) {
            a.position = (cycle as i64) * 1000 + i as i64;
            a.setpoint = a.position;
            a.position_inc = to_inc(a.position);
            a.setpoint_inc = a.position_inc;
        }
        s.send().map_err(|e| e.to_string())?;
        if args.events_every > 0 && cycle % args.events_every == 0 {
            events
                .publish(event(seq, cycle, event_id::STATE_CHANGED))
                .map_err(|e| e.to_string())?;
            seq += 1;
        }
        cycle += 1;
        if cycle % 50 == 0 {
            let n = cleanup_dead_nodes_with(&node);
            if n > 0 {
                say(&format!("cleaned {n}"));
            }
        }
        if (args.count > 0 && cycle >= args.count) || stop.load(Ordering::Relaxed) {
            break;
        }
        deadline += args.period;
    }
    events
        .publish(event(seq, cycle, event_id::SHUTDOWN))
        .map_err(|e| e.to_string())?;
    say(&format!(
        "done published={cycle} commands={commands} events={}",
        seq + 1
    ));
    Ok(())
}

fn event(seq: u64, cycle: u64, id: usize) -> EventRecord {
    EventRecord {
        seq,
        cycle,
        value: 0,
        id: id as u16,
        axis: 0xFFFF,
        group: 0xFFFF,
        record: 0xFFFF,
        state: 0,
        error: 0,
        sub: 0,
        reserved0: 0,
        code: 0,
        reserved1: 0,
    }
}

fn main() -> std::process::ExitCode {
    let args = match parse() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("motion-standin: {e}");
            return std::process::ExitCode::from(2);
        }
    };
    match run(&args) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("motion-standin: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
