//! The shipped clients against an in-process fake machine: argument parsing, name resolution,
//! CSV output, exit codes, and motion-top's rendering and keys.

use std::collections::VecDeque;
use std::time::Duration;

use clap::Parser;
use crossterm::event::{KeyCode, KeyEvent, KeyModifiers};
use ratatui::Terminal;
use ratatui::backend::TestBackend;
use ratatui::buffer::Buffer;
use ratatui::style::Color;
use shm_api::cli::cmd::{self, CmdArgs};
use shm_api::cli::top::{App, Link, Selection};
use shm_api::cli::watch::{self, WatchArgs};
use shm_api::cli::{ClientError, Latched, Machine, Rejected, Target, exit, resolve};
use shm_api::contract::{
    AxisState, BusStats, CommandRequest, EventRecord, GroupState, MAX_AXES, MAX_GROUP_AXES,
    MAX_GROUPS, MachineDescription, MachineState, axis_mode, axis_state, buffer_mode, command_kind,
    device, event_id, fault, link,
};

fn name<const N: usize>(s: &str) -> [u8; N] {
    let mut b = [0; N];
    for (d, s) in b.iter_mut().zip(s.bytes()) {
        *d = s;
    }
    b
}

fn axis(n: &str) -> AxisState {
    AxisState {
        position: 0,
        setpoint: 0,
        velocity: 0,
        position_inc: 0,
        setpoint_inc: 0,
        fault_value: 0,
        fault_limit: 0,
        force_permille: 0,
        status_bits: 0,
        flags: 0,
        state: axis_state::READY,
        mode: axis_mode::ON,
        fault: fault::NONE,
        activity: 0,
        fault_code: 0,
        active_record: -1,
        name: name(n),
        unit: name("mm"),
        reserved1: [0; 32],
    }
}

fn group(n: &str, members: &[u8]) -> GroupState {
    let mut axes = [0; MAX_GROUP_AXES];
    for (d, s) in axes.iter_mut().zip(members) {
        *d = *s;
    }
    GroupState {
        active_record: -1,
        record: -1,
        reached: -1,
        override_percent: 100,
        chain_state: 0,
        rc1: 0,
        rcc: 0,
        motion: 0,
        axis_count: members.len() as u8,
        activity: 0,
        reserved0: [0; 2],
        axes,
        name: name(n),
        reserved1: [0; 8],
    }
}

/// Axes x, y, z (y faulted with a following error), group xy of x and y.
fn machine(cycle: u64) -> MachineState {
    let blank = axis("");
    let mut s = MachineState {
        version: 1,
        layout_hash: 0,
        cycle,
        sync_time_ns: cycle * 1_000_000,
        publish_time_ns: 0,
        cycle_ns: 1_000_000,
        axis_count: 3,
        group_count: 1,
        inputs: 0,
        virtual_time: 1,
        reserved0: [0; 3],
        bus: BusStats {
            frames_sent: 10,
            frames_received: 20,
            tx_refused: 0,
            rx_dropped: 0,
            skipped_cycles: 0,
            step_ns: 12_345,
            wake_late_us: 3,
        },
        axes: [blank; MAX_AXES],
        groups: [group("", &[]); MAX_GROUPS],
    };
    s.axes[0] = axis("x");
    s.axes[0].position = 12_500_000 + cycle as i64;
    s.axes[0].setpoint = 12_500_000;
    s.axes[0].velocity = -250_000;
    s.axes[1] = axis("y");
    s.axes[1].state = axis_state::FAULT;
    s.axes[1].fault = fault::FOLLOWING_ERROR;
    s.axes[1].fault_value = 120;
    s.axes[1].fault_limit = 100;
    s.axes[2] = axis("z");
    s.groups[0] = group("xy", &[0, 1]);
    s
}

/// The fake: a queue of states, one canned answer, a queue of events; records the requests.
/// With a description, it has one; with `drive`, every parameter read is answered by an event
/// from it (value or drive error).
struct Fake {
    states: VecDeque<MachineState>,
    current: Option<MachineState>,
    answer: Result<Latched, Rejected>,
    events: VecDeque<EventRecord>,
    sent: Vec<CommandRequest>,
    description: Option<Box<MachineDescription>>,
    drive: Option<FakeDrive>,
}

/// A drive's answer to a read of `pnu`:`sub`: the value, or its error number.
type FakeDrive = fn(u16, u8) -> Result<i64, i64>;

impl Fake {
    fn new(cycles: impl IntoIterator<Item = u64>) -> Self {
        Self {
            states: cycles.into_iter().map(machine).collect(),
            current: None,
            answer: Ok(Latched { cycle: 42 }),
            events: VecDeque::new(),
            sent: Vec::new(),
            description: None,
            drive: None,
        }
    }
}

impl Machine for Fake {
    fn latest(&mut self) -> Option<&MachineState> {
        if let Some(s) = self.states.drain(..).next_back() {
            self.current = Some(s);
        }
        self.current.as_ref()
    }
    fn next(&mut self, _: Duration) -> Result<&MachineState, ClientError> {
        let s = self.states.pop_front().ok_or(ClientError::Timeout)?;
        Ok(self.current.insert(s))
    }
    fn command(&mut self, req: &CommandRequest, _: Duration) -> Result<Latched, Rejected> {
        self.sent.push(*req);
        if let (Some(drive), Ok(l)) = (self.drive, &self.answer)
            && req.kind == command_kind::READ_PARAMETER
        {
            let (value, error) = match drive(req.pnu, req.sub) {
                Ok(v) => (v, 0),
                Err(n) => (n, 1),
            };
            let mut ev = param_event(l.cycle, req.axis, req.pnu, value, error);
            ev.sub = req.sub;
            self.events.push_back(ev);
        }
        self.answer.clone()
    }
    fn description(&mut self, _: Duration) -> Result<&MachineDescription, ClientError> {
        self.description
            .as_deref()
            .ok_or(ClientError::NoDescription)
    }
    fn wait_event(&mut self, _: Duration) -> Result<Option<EventRecord>, ClientError> {
        Ok(self.events.pop_front())
    }
}

fn run_watch(fake: &mut Fake, args: &[&str]) -> (i32, String, String) {
    let args =
        WatchArgs::try_parse_from(std::iter::once("motion-watch").chain(args.iter().copied()))
            .expect("arguments parse");
    let (mut out, mut err) = (Vec::new(), Vec::new());
    let code = watch::run(fake, &args, &mut out, &mut err);
    (
        code,
        String::from_utf8(out).unwrap(),
        String::from_utf8(err).unwrap(),
    )
}

fn run_cmd(fake: &mut Fake, args: &[&str]) -> (i32, String, String) {
    let args = CmdArgs::try_parse_from(std::iter::once("motion-cmd").chain(args.iter().copied()))
        .expect("arguments parse");
    let (mut out, mut err) = (Vec::new(), Vec::new());
    let code = cmd::run(fake, &args, &mut out, &mut err);
    (
        code,
        String::from_utf8(out).unwrap(),
        String::from_utf8(err).unwrap(),
    )
}

fn request(args: &[&str]) -> Result<CommandRequest, resolve::ResolveError> {
    let args = CmdArgs::try_parse_from(std::iter::once("motion-cmd").chain(args.iter().copied()))
        .expect("arguments parse");
    cmd::build_request(&machine(1), &args.command)
}

#[test]
fn csv_every_cycle_prints_header_then_count_lines() {
    let mut fake = Fake::new(1..=10);
    let (code, out, err) = run_watch(
        &mut fake,
        &["--axes", "x,z", "--every-cycle", "--csv", "--count", "3"],
    );
    assert_eq!(code, exit::OK, "{err}");
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(
        lines,
        [
            "cycle,time_s,x_position,x_setpoint,x_velocity,x_state,z_position,z_setpoint,z_velocity,z_state",
            "1,0.000000000,12.500001,12.500000,-0.250000,ready,0.000000,0.000000,0.000000,ready",
            "2,0.001000000,12.500002,12.500000,-0.250000,ready,0.000000,0.000000,0.000000,ready",
            "3,0.002000000,12.500003,12.500000,-0.250000,ready,0.000000,0.000000,0.000000,ready",
        ]
    );
    assert!(err.is_empty());
}

/// The CSV names the states and counts its time from the first line, whenever the watch
/// starts (a late start reads 0 too, not the coordinator's clock).
#[test]
fn csv_names_states_and_starts_its_time_at_zero() {
    let mut fake = Fake::new(5000..=5002);
    let (code, out, err) = run_watch(
        &mut fake,
        &["--axes", "y", "--every-cycle", "--csv", "--count", "3"],
    );
    assert_eq!(code, exit::OK, "{err}");
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(
        lines[0],
        "cycle,time_s,y_position,y_setpoint,y_velocity,y_state"
    );
    let times: Vec<&str> = lines[1..]
        .iter()
        .map(|l| l.split(',').nth(1).unwrap())
        .collect();
    assert_eq!(times, ["0.000000000", "0.001000000", "0.002000000"]);
    for l in &lines[1..] {
        assert!(l.ends_with(",FAULT"), "the state by name: {l}");
    }
}

#[test]
fn every_cycle_reports_skipped_cycles() {
    let mut fake = Fake::new([1, 2, 5]);
    let (code, out, err) = run_watch(&mut fake, &["--every-cycle", "--csv", "--count", "3"]);
    assert_eq!(code, exit::OK);
    assert_eq!(out.lines().count(), 4);
    assert!(err.contains("skipped 2 cycles after cycle 2"), "{err}");
}

#[test]
fn watch_fails_when_the_states_stop() {
    let mut fake = Fake::new([1, 2]);
    let (code, out, err) = run_watch(&mut fake, &["--every-cycle", "--count", "5"]);
    assert_eq!(code, exit::ERROR);
    assert_eq!(out.lines().count(), 2);
    assert!(err.contains("no new state"), "{err}");
}

#[test]
fn watch_at_a_rate_prints_user_units_and_faults() {
    let mut fake = Fake::new(1..=4);
    let (code, out, _) = run_watch(
        &mut fake,
        &["--rate", "1000", "--count", "2", "--axes", "x,y"],
    );
    assert_eq!(code, exit::OK);
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines.len(), 2);
    assert!(
        lines[0].starts_with("cycle 1  x ready/on pos 12.500 mm set 12.500 vel -0.250 mm/s"),
        "{}",
        lines[0]
    );
    assert!(lines[0].contains("y FAULT/on"), "{}", lines[0]);
    assert!(
        lines[0].contains("fault: following error 120 inc (limit 100)"),
        "{}",
        lines[0]
    );
    // The second line shows the newest state, the older ones drained.
    assert!(lines[1].starts_with("cycle 4 "), "{}", lines[1]);
}

#[test]
fn watch_refuses_unknown_axes_bad_rates_and_no_state() {
    let (code, _, err) = run_watch(&mut Fake::new([1]), &["--axes", "x,w"]);
    assert_eq!(code, exit::ERROR);
    assert!(
        err.contains("--axes w: no such axis; the axes are x, y, z"),
        "{err}"
    );
    // A rate out of range is refused as it is parsed, before anything connects.
    let err = WatchArgs::try_parse_from(["motion-watch", "--rate", "0"])
        .expect_err("a rate of 0 is refused")
        .to_string();
    assert!(
        err.contains("--rate") && err.contains("0.01 to 1000000"),
        "{err}"
    );
    let (code, _, _) = run_watch(&mut Fake::new([]), &[]);
    assert_eq!(code, exit::ERROR);
    assert!(WatchArgs::try_parse_from(["motion-watch", "--rate", "5", "--every-cycle"]).is_err());
}

#[test]
fn names_resolve_by_name_then_index() {
    let s = machine(1);
    assert_eq!(resolve::axis_index(&s, "z"), Ok(2));
    assert_eq!(resolve::axis_index(&s, "1"), Ok(1));
    assert!(
        resolve::axis_index(&s, "3").is_err(),
        "index past axis_count"
    );
    assert_eq!(resolve::group_index(&s, "xy"), Ok(0));
    assert!(resolve::group_index(&s, "yz").is_err());
    assert_eq!(resolve::axis_list(&s, &[]), Ok(vec![0, 1, 2]));
    // A garbage count from the other process is clamped, never indexed past the array.
    let mut g = machine(1);
    g.axis_count = u16::MAX;
    g.group_count = u16::MAX;
    g.groups[0].axis_count = u8::MAX;
    assert_eq!(resolve::axes(&g).len(), MAX_AXES);
    assert_eq!(resolve::groups(&g).len(), MAX_GROUPS);
    assert_eq!(resolve::group_members(&g.groups[0]).len(), MAX_GROUP_AXES);
}

#[test]
fn every_command_builds_its_request() {
    type C = CommandRequest;
    let ok = |a: &[&str]| request(a).expect("resolves");
    assert_eq!(ok(&["enable", "--axis", "y"]), C::enable(Target::Axis(1)));
    assert_eq!(
        ok(&["disable", "--group", "xy"]),
        C::disable(Target::Group(0))
    );
    assert_eq!(ok(&["acknowledge", "--all"]), C::acknowledge(Target::All));
    assert_eq!(ok(&["home", "--axis", "x"]), C::home(Target::Axis(0)));
    assert_eq!(ok(&["hold", "--all"]), C::hold(Target::All));
    assert_eq!(
        ok(&["resume", "--group", "xy"]),
        C::resume(Target::Group(0))
    );
    assert_eq!(ok(&["stop", "--axis", "z"]), C::stop(Target::Axis(2)));
    assert_eq!(ok(&["quick-stop", "--all"]), C::quick_stop(Target::All));
    assert_eq!(
        ok(&["jog", "--axis", "x", "--permille", "-300"]),
        C::jog(0, -300)
    );
    assert_eq!(
        ok(&["move", "--axis", "x", "--to", "12.5", "--percent", "50"]),
        C::move_axis(0, 12_500_000, 50)
    );
    assert_eq!(
        ok(&["move", "--axis", "x", "--to", "-3"]),
        C::move_axis(0, -3_000_000, 100)
    );
    assert_eq!(
        ok(&[
            "move",
            "--group",
            "xy",
            "--to",
            "100,-50.25",
            "--percent",
            "50"
        ]),
        C::move_group(0, &[100_000_000, -50_250_000], 50)
    );
    assert_eq!(
        ok(&["start-chain", "--group", "xy", "--record", "10"]),
        C::start_chain(0, 10)
    );
    assert_eq!(
        ok(&["override", "--group", "xy", "--percent", "80"]),
        C::set_override(0, 80)
    );
    assert_eq!(
        ok(&["override", "--axis", "z", "--percent", "120"]),
        C::set_override_of(Target::Axis(2), 120)
    );
    assert_eq!(
        ok(&["override", "--all", "--percent", "0"]),
        C::set_override_of(Target::All, 0)
    );
    assert_eq!(
        ok(&["move", "--axis", "x", "--to", "5", "--buffered"]),
        C::move_axis(0, 5_000_000, 100).with_buffer(buffer_mode::BUFFERED)
    );
    assert_eq!(
        ok(&["move", "--group", "xy", "--to", "1,2", "--buffered"]),
        C::move_group(0, &[1_000_000, 2_000_000], 100).with_buffer(buffer_mode::BUFFERED)
    );
    assert_eq!(
        ok(&["move", "--axis", "x", "--to", "5"]).buffer,
        buffer_mode::ABORTING
    );
    assert_eq!(
        ok(&["read-param", "--axis", "x", "--pnu", "502"]),
        C::read_parameter(0, 502, 0)
    );
    assert_eq!(
        ok(&[
            "write-param",
            "--axis",
            "y",
            "--pnu",
            "502",
            "--sub",
            "2",
            "--value",
            "-7"
        ]),
        C::write_parameter(1, 502, 2, -7)
    );
    assert_eq!(
        ok(&["set-input", "--bit", "3", "--value", "1"]),
        C::set_input(3, true)
    );
    assert_eq!(
        ok(&["set-input", "--bit", "0", "--value", "off"]),
        C::set_input(0, false)
    );
    assert_eq!(ok(&["enable", "--axis", "2"]), C::enable(Target::Axis(2)));
}

#[test]
fn bad_command_lines_are_refused() {
    let parse = |a: &[&str]| {
        CmdArgs::try_parse_from(std::iter::once("motion-cmd").chain(a.iter().copied()))
    };
    assert!(parse(&["enable"]).is_err(), "a target is required");
    assert!(
        parse(&["enable", "--axis", "x", "--all"]).is_err(),
        "only one target"
    );
    assert!(parse(&["move", "--axis", "x", "--group", "xy", "--to", "1"]).is_err());
    assert!(parse(&["set-input", "--bit", "0", "--value", "2"]).is_err());
    assert!(parse(&["jog", "--axis", "x", "--permille", "40000"]).is_err());
    assert!(matches!(
        request(&["move", "--group", "xy", "--to", "1,2,3"]),
        Err(resolve::ResolveError::PositionCount {
            axes: 2,
            given: 3,
            ..
        })
    ));
    // A position that is not a decimal in user units is refused as it is parsed.
    let err = parse(&["move", "--axis", "x", "--to", "1.2345678"])
        .expect_err("7 decimals are refused")
        .to_string();
    assert!(
        err.contains("--to") && err.contains("at most 6 decimals"),
        "{err}"
    );
    assert!(request(&["start-chain", "--group", "ab", "--record", "1"]).is_err());
}

#[test]
fn cmd_exit_codes() {
    let mut fake = Fake::new([7]);
    let (code, out, _) = run_cmd(&mut fake, &["enable", "--all"]);
    assert_eq!((code, out.as_str()), (exit::OK, "latched in cycle 42\n"));
    assert_eq!(fake.sent, [CommandRequest::enable(Target::All)]);

    let mut fake = Fake::new([7]);
    fake.answer = Err(Rejected::WrongState("axis y is faulted".into()));
    let (code, out, _) = run_cmd(&mut fake, &["home", "--axis", "y"]);
    assert_eq!(code, exit::REJECTED);
    assert!(
        out.starts_with("rejected: ") && out.contains("axis y is faulted"),
        "{out}"
    );

    let mut fake = Fake::new([7]);
    fake.answer = Err(Rejected::Timeout);
    assert_eq!(run_cmd(&mut fake, &["stop", "--all"]).0, exit::ERROR);

    // An unknown name is an error; nothing is sent.
    let mut fake = Fake::new([7]);
    let (code, _, err) = run_cmd(&mut fake, &["enable", "--axis", "w"]);
    assert_eq!(code, exit::ERROR);
    assert!(
        err.contains("--axis w: no such axis; the axes are x, y, z"),
        "{err}"
    );
    assert!(fake.sent.is_empty());

    // No state: no coordinator publishing.
    assert_eq!(
        run_cmd(&mut Fake::new([]), &["enable", "--all"]).0,
        exit::ERROR
    );
}

/// What motion-cmd prints for a refusal `answer` of the command `args`, on a machine whose x
/// has 400 increments per mm and y 100 (published as position and position_inc).
fn refusal(answer: Rejected, args: &[&str]) -> String {
    let mut fake = Fake::new([7]);
    let s = &mut fake.states[0];
    s.axes[0].position = 10_000_000;
    s.axes[0].position_inc = 4000;
    s.axes[1].position = 10_000_000;
    s.axes[1].position_inc = 1000;
    fake.answer = Err(answer);
    let (code, out, err) = run_cmd(&mut fake, args);
    assert_eq!(code, exit::REJECTED, "{out}{err}");
    out.strip_prefix("rejected: ")
        .and_then(|o| o.strip_suffix('\n'))
        .unwrap_or_else(|| panic!("one refusal line: {out:?}"))
        .to_owned()
}

#[test]
fn refusals_are_in_the_units_typed() {
    let range = |value, min, max| Rejected::OutOfRange { value, min, max };
    // The coordinator answers positions in increments: 1000 mm are 400 000 increments on x.
    assert_eq!(
        refusal(
            range(400_000, 0, 160_000),
            &["move", "--axis", "x", "--to", "1000"]
        ),
        "axis x: 1000 mm outside 0..=400 mm"
    );
    assert_eq!(
        refusal(
            range(-40, 0, 160_000),
            &["move", "--axis", "x", "--to", "-0.1"]
        ),
        "axis x: -0.1 mm outside 0..=400 mm"
    );
    // In a group move, the member whose position was refused (y: 100 increments per mm).
    assert_eq!(
        refusal(
            range(70_000, 0, 50_000),
            &["move", "--group", "xy", "--to", "50,700"]
        ),
        "axis y: 700 mm outside 0..=500 mm"
    );
    assert_eq!(
        refusal(
            range(0, 1, 100),
            &["move", "--axis", "x", "--to", "1", "--percent", "0"]
        ),
        "--percent 0 % outside 1..=100 %"
    );
    assert_eq!(
        refusal(
            range(2000, -1000, 1000),
            &["jog", "--axis", "x", "--permille", "2000"]
        ),
        "axis x: jog 2000 ‰ outside -1000..=1000 ‰"
    );
    assert_eq!(
        refusal(
            range(250, 0, 200),
            &["override", "--group", "xy", "--percent", "250"]
        ),
        "group xy: override 250 % outside 0..=200 %"
    );
    assert_eq!(
        refusal(
            range(40, 0, 31),
            &["set-input", "--bit", "40", "--value", "1"]
        ),
        "input bit 40 outside 0..=31"
    );
}

#[test]
fn refusals_name_their_target_and_the_tables_reason() {
    assert_eq!(
        refusal(
            Rejected::WrongState("axis not enabled".into()),
            &["home", "--axis", "z"]
        ),
        "axis z: axis not enabled"
    );
    assert_eq!(
        refusal(
            Rejected::WrongState("the group is held: resume or stop it".into()),
            &["move", "--group", "xy", "--to", "1,2"]
        ),
        "group xy: the group is held: resume or stop it"
    );
    assert_eq!(
        refusal(Rejected::Faulted, &["enable", "--all"]),
        "every axis: a fault must be acknowledged first (motion-cmd acknowledge)"
    );
    let plan = refusal(Rejected::Plan, &["move", "--axis", "x", "--to", "1"]);
    assert_eq!(plan, Rejected::Plan.to_string());
    assert!(!plan.contains('{') && !plan.contains("Some("), "{plan}");
}

#[test]
fn connect_fails_at_once_without_a_coordinator() {
    let prefix = format!("clients-test-{}", std::process::id());
    match shm_api::cli::connect(&prefix) {
        Err(ClientError::NoCoordinator(p)) => assert_eq!(p, prefix),
        Err(e) => panic!("wrong error {e}"),
        Ok(_) => panic!("connected to nothing"),
    }
}

fn param_event(cycle: u64, axis: u16, pnu: u16, value: i64, error: u8) -> EventRecord {
    EventRecord {
        seq: cycle,
        cycle,
        value,
        id: event_id::PARAMETER as u16,
        axis,
        group: 0xFFFF,
        record: 0xFFFF,
        state: 0,
        error,
        sub: 0,
        reserved0: 0,
        code: pnu,
        reserved1: 0,
    }
}

#[test]
fn read_param_waits_for_its_own_answer() {
    let mut fake = Fake::new([7]);
    fake.events.extend([
        param_event(10, 0, 502, 111, 0), // an older task's answer, from the log's history
        param_event(43, 1, 502, 222, 0), // another axis
        param_event(43, 0, 503, 333, 0), // another parameter
        param_event(44, 0, 502, 1234, 0),
    ]);
    let (code, out, err) = run_cmd(&mut fake, &["read-param", "--axis", "x", "--pnu", "502"]);
    assert_eq!(code, exit::OK, "{err}");
    assert_eq!(out, "latched in cycle 42\naxis x parameter 502:0 = 1234\n");

    let mut fake = Fake::new([7]);
    fake.events.push_back(param_event(45, 1, 502, 17, 1));
    let (code, out, _) = run_cmd(
        &mut fake,
        &["write-param", "--axis", "y", "--pnu", "502", "--value", "5"],
    );
    assert_eq!(code, exit::REJECTED);
    assert_eq!(
        out,
        "latched in cycle 42\nrejected: the drive refused parameter 502:0 of axis y: error 17\n"
    );

    let mut fake = Fake::new([7]);
    let (code, _, err) = run_cmd(
        &mut fake,
        &[
            "--timeout-ms",
            "20",
            "read-param",
            "--axis",
            "x",
            "--pnu",
            "502",
        ],
    );
    assert_eq!(code, exit::ERROR);
    assert!(err.contains("no answer"), "{err}");
}

fn draw(app: &App, state: Option<&MachineState>) -> ratatui::buffer::Buffer {
    let mut t = Terminal::new(TestBackend::new(140, 20)).unwrap();
    t.draw(|f| app.render(f, state, Link::Live)).unwrap();
    t.backend().buffer().clone()
}

fn row_of(buf: &ratatui::buffer::Buffer, text: &str) -> Option<u16> {
    (0..buf.area.height).find(|&y| {
        let line: String = (0..buf.area.width).map(|x| buf[(x, y)].symbol()).collect();
        line.contains(text)
    })
}

#[test]
fn top_renders_axes_groups_and_red_faults() {
    let app = App::new("motion");
    let s = machine(5);
    let buf = draw(&app, Some(&s));
    assert!(row_of(&buf, "cycle 5").is_some());
    let x = row_of(&buf, "12.500").expect("axis x row");
    let y = row_of(&buf, "following error 120 inc").expect("axis y row with its fault");
    assert!(row_of(&buf, "x,y").is_some(), "group xy with its members");
    // Column 2 is inside the table border, on the name cell.
    assert_eq!(buf[(2, y)].fg, Color::Red);
    assert_ne!(buf[(2, x)].fg, Color::Red);
}

#[test]
fn top_without_coordinator_says_so() {
    let buf = draw(&App::new("cell7"), None);
    assert!(row_of(&buf, "no coordinator with prefix 'cell7'").is_some());
}

fn key(c: KeyCode) -> KeyEvent {
    KeyEvent::new(c, KeyModifiers::NONE)
}

#[test]
fn top_keys_produce_commands_for_the_selection() {
    let s = machine(1);
    let mut app = App::new("motion");
    assert_eq!(
        app.handle_key(key(KeyCode::Char('h')), Some(&s)),
        Some(CommandRequest::hold(Target::All))
    );
    assert_eq!(app.handle_key(key(KeyCode::Down), Some(&s)), None);
    assert_eq!(app.selection, Selection::Axis(0));
    assert_eq!(
        app.handle_key(key(KeyCode::Char('r')), Some(&s)),
        Some(CommandRequest::resume(Target::Axis(0)))
    );
    for _ in 0..3 {
        app.handle_key(key(KeyCode::Down), Some(&s));
    }
    assert_eq!(app.selection, Selection::Group(0));
    app.handle_key(key(KeyCode::Down), Some(&s));
    assert_eq!(app.selection, Selection::Group(0), "stays on the last row");
    assert_eq!(
        app.handle_key(key(KeyCode::Char('s')), Some(&s)),
        Some(CommandRequest::stop(Target::Group(0)))
    );
    app.handle_key(key(KeyCode::Up), Some(&s));
    assert_eq!(app.selection, Selection::Axis(2));
    assert_eq!(
        app.handle_key(key(KeyCode::Char('a')), Some(&s)),
        Some(CommandRequest::acknowledge(Target::Axis(2)))
    );
    app.handle_key(key(KeyCode::Esc), Some(&s));
    assert_eq!(app.selection, Selection::All);
    // Without a state there is nothing to command.
    assert_eq!(app.handle_key(key(KeyCode::Char('h')), None), None);
    assert_eq!(app.message, "not connected");
    assert!(!app.quit);
    app.handle_key(key(KeyCode::Char('q')), None);
    assert!(app.quit);
}

#[test]
fn top_shows_answers() {
    let mut app = App::new("motion");
    app.set_answer(&Ok(Latched { cycle: 9 }));
    assert_eq!(app.message, "latched in cycle 9");
    app.set_answer(&Err(Rejected::Busy));
    assert!(app.message.starts_with("rejected: "));
    let buf = draw(&app, Some(&machine(1)));
    assert!(row_of(&buf, "rejected: ").is_some());
}

fn draw_at(width: u16, app: &App, state: Option<&MachineState>, link: Link) -> Buffer {
    let mut t = Terminal::new(TestBackend::new(width, 20)).unwrap();
    t.draw(|f| app.render(f, state, link)).unwrap();
    t.backend().buffer().clone()
}

fn line_at(buf: &Buffer, y: u16) -> String {
    (0..buf.area.width).map(|x| buf[(x, y)].symbol()).collect()
}

#[test]
fn top_marks_a_stale_state() {
    let buf = draw_at(160, &App::new("motion"), Some(&machine(3)), Link::Stale(5));
    let y = row_of(&buf, "STALE: no new state for 5 s").expect("stale marker");
    assert_eq!(buf[(0, y)].fg, Color::Yellow);
}

/// At 80 columns the first line says whether the coordinator is stale or gone, readable in
/// full; a live one shows no such word.
#[test]
fn top_says_stale_and_gone_at_80_columns() {
    let mut app = App::new("motion");
    app.message = "connected to 'motion'".into();
    let s = machine(3);
    let live = line_at(&draw_at(80, &app, Some(&s), Link::Live), 0);
    assert!(live.starts_with("motion  cycle 3"), "{live}");
    assert!(!live.contains("STALE") && !live.contains("GONE"), "{live}");

    let buf = draw_at(80, &app, Some(&s), Link::Stale(7));
    let first = line_at(&buf, 0);
    assert!(first.starts_with("STALE: no new state for 7 s"), "{first}");
    assert_eq!(buf[(0, 0)].fg, Color::Yellow);

    let buf = draw_at(80, &app, Some(&s), Link::Gone);
    let first = line_at(&buf, 0);
    assert!(
        first.starts_with("GONE: coordinator stopped, last state shown"),
        "{first}"
    );
    assert!(first.contains("cycle 3"), "the last cycle shown: {first}");
    assert_eq!(buf[(0, 0)].fg, Color::Red);
}

/// At 80 columns the axes table keeps each axis's position with its unit and its fault in
/// full (setpoint and velocity give way).
#[test]
fn top_axes_fit_80_columns_with_the_fault_readable() {
    let buf = draw_at(80, &App::new("motion"), Some(&machine(5)), Link::Live);
    let y = row_of(&buf, "following error 120 inc").expect("axis y's fault in full");
    assert_eq!(buf[(2, y)].fg, Color::Red);
    assert!(
        row_of(&buf, "12.500 mm").is_some(),
        "x's position with its unit"
    );
}

#[test]
fn top_link_is_gone_before_stale_before_live() {
    use shm_api::cli::top::STALE_AFTER;
    let quiet = STALE_AFTER * 3;
    assert_eq!(Link::of(true, true, Duration::ZERO), Link::Gone);
    assert_eq!(Link::of(false, true, quiet), Link::Stale(quiet.as_secs()));
    assert_eq!(Link::of(false, true, Duration::ZERO), Link::Live);
    // Nothing seen yet: the no-coordinator line says it, not "stale".
    assert_eq!(Link::of(false, false, quiet), Link::Live);
}

/// The step time is in µs with one decimal (12 345 ns is 12.3 µs, not 0.012).
#[test]
fn top_shows_the_step_time_in_microseconds() {
    let buf = draw_at(80, &App::new("motion"), Some(&machine(3)), Link::Live);
    let first = line_at(&buf, 0);
    assert!(first.contains("step 12.3 µs"), "{first}");
    assert!(row_of(&buf, "0.012").is_none());
    // The bus counters have their own line.
    assert!(
        line_at(&buf, 1).starts_with("tx 10 rx 20 refused 0"),
        "{}",
        line_at(&buf, 1)
    );
}

/// The binaries as processes: exit codes without a coordinator and on usage errors (clap's
/// own code 2 would read as "rejected").
#[test]
fn binaries_exit_1_without_coordinator_and_on_usage_errors() {
    use std::process::Command;
    let prefix = format!("clients-bin-{}", std::process::id());
    let run = |bin: &str, args: &[&str]| {
        let o = Command::new(bin).args(args).output().expect("binary runs");
        (
            o.status.code(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    let cmd = env!("CARGO_BIN_EXE_motion-cmd");
    let watch = env!("CARGO_BIN_EXE_motion-watch");
    let (code, err) = run(cmd, &["--prefix", &prefix, "enable", "--all"]);
    assert_eq!(code, Some(exit::ERROR));
    assert!(err.contains(&prefix), "{err}");
    let (code, _) = run(watch, &["--prefix", &prefix, "--count", "1"]);
    assert_eq!(code, Some(exit::ERROR));
    assert_eq!(run(cmd, &["enable"]).0, Some(exit::ERROR));
    assert_eq!(run(cmd, &["frobnicate"]).0, Some(exit::ERROR));
    assert_eq!(run(watch, &["--rate", "x"]).0, Some(exit::ERROR));
    assert_eq!(run(cmd, &["--help"]).0, Some(exit::OK));
    let top = env!("CARGO_BIN_EXE_motion-top");
    assert_eq!(run(top, &["--bogus"]).0, Some(exit::ERROR));
}

/// The fake machine's description: x an EMCA with the parameter channel, y an MTR-DCI without,
/// z a TLC5xx (all on vbus:can0), group xy without records.
fn description() -> Box<MachineDescription> {
    // SAFETY: the description is integers only; all-zero bytes are a valid value.
    let mut d = unsafe { Box::<MachineDescription>::new_zeroed().assume_init() };
    (d.axis_count, d.group_count, d.bus_count) = (3, 1, 1);
    d.buses[0].name = name("can0");
    d.buses[0].kind = shm_api::contract::bus_kind::VBUS;
    for (i, (n, dev, fpc)) in [
        ("x", device::EMCA, 1),
        ("y", device::MTR_DCI, 0),
        ("z", device::TLC5XX, 0),
    ]
    .into_iter()
    .enumerate()
    {
        let a = &mut d.axes[i];
        (a.name, a.unit) = (name(n), name("mm"));
        (a.device, a.fpc, a.link, a.node) = (dev, fpc, link::CAN, i as u8 + 1);
        if dev == device::TLC5XX {
            a.profile = shm_api::contract::profile::CIA402;
        }
    }
    d.groups[0].name = name("xy");
    (d.groups[0].axis_count, d.groups[0].axes[1]) = (2, 1);
    d
}

/// The fake drive behind x's parameter channel: 1011 (homing method, i8) is -35 in 32 bits,
/// 1001:1 and :2 the encoder's 4096 increments per revolution; 1041 refuses with EFPC 0x11.
fn fake_drive(pnu: u16, sub: u8) -> Result<i64, i64> {
    match (pnu, sub) {
        (1011, _) => Ok(0xFFFF_FFDD),
        (1001, 1) => Ok(4096),
        (1041, _) => Err(0x11),
        (p, s) => Ok(i64::from(p) * 10 + i64::from(s)),
    }
}

#[test]
fn records_and_params_read_the_description() {
    let mut fake = Fake::new([7]);
    // No description: said plainly, nothing sent.
    let (code, _, err) = run_cmd(&mut fake, &["records", "--axis", "x"]);
    assert_eq!(code, exit::ERROR);
    assert!(err.contains("published no machine description"), "{err}");

    fake.description = Some(description());
    let (code, out, _) = run_cmd(&mut fake, &["records", "--group", "xy"]);
    assert_eq!(code, exit::OK);
    assert!(
        out.starts_with("group xy: axes x, y, trapezoid profile, 0 records\n"),
        "{out}"
    );
    let (code, _, err) = run_cmd(&mut fake, &["records", "--axis", "w"]);
    assert_eq!(code, exit::ERROR);
    assert_eq!(err, "error: --axis w: no such axis; the axes are x, y, z\n");
    let (code, _, err) = run_cmd(&mut fake, &["params", "--axis", "x", "--pnu", "9999"]);
    assert_eq!(code, exit::ERROR);
    assert_eq!(
        err,
        "error: --pnu 9999: the Festo EMCA has no parameter 9999\n"
    );
    assert!(fake.sent.is_empty());

    // One parameter with two sub-indices, each read; the value as its type.
    fake.drive = Some(fake_drive);
    let (code, out, err) = run_cmd(&mut fake, &["params", "--axis", "x", "--pnu", "1001"]);
    assert_eq!(code, exit::OK, "{err}");
    assert_eq!(
        out.lines().collect::<Vec<_>>(),
        [
            "axis x: Festo EMCA, FHPP, node 1 on vbus:can0, parameter channel",
            "2 parameters of the Festo EMCA, 2 values read over the parameter channel:",
            " PNU  sub  name                type  unit               value",
            "1001  1    Encoder resolution  u32   increments         4096",
            "1001  2    Encoder resolution  u32   motor revolutions  10012",
        ]
    );
    assert_eq!(fake.sent.len(), 2);
    assert!(
        fake.sent
            .iter()
            .all(|r| r.kind == command_kind::READ_PARAMETER && r.axis == 0)
    );

    // The whole table: every simple value read, arrays and texts pointed to --pnu, a refusal
    // in words.
    fake.sent.clear();
    let (code, out, err) = run_cmd(&mut fake, &["params", "--axis", "x"]);
    assert_eq!(code, exit::OK, "{err}");
    let line = |start: &str| {
        out.lines()
            .find(|l| l.starts_with(start))
            .unwrap_or_else(|| panic!("{start:?} in\n{out}"))
            .split_whitespace()
            .collect::<Vec<_>>()
            .join(" ")
    };
    assert_eq!(line("1011"), "1011 1 Homing method i8 -35");
    assert!(
        line(" 401").ends_with("(64 values: --axis x --pnu 401)"),
        "{out}"
    );
    assert!(
        line("1041").contains("refused by the drive, error 17: not possible in the drive's state"),
        "{out}"
    );
    let simple = fake.sent.len();
    assert!(simple > 50, "{simple} reads");
    assert!(out.contains(&format!("{simple} values read over the parameter channel")));

    // No parameter channel: said, and the table still listed; nothing read.
    fake.sent.clear();
    let (code, out, _) = run_cmd(&mut fake, &["params", "--axis", "y"]);
    assert_eq!(code, exit::OK);
    assert!(
        out.contains("no parameter channel on axis y (`fpc = true`"),
        "{out}"
    );
    assert!(out.contains("Manufacturer hardware version"), "{out}");
    assert!(fake.sent.is_empty());
    // A CiA 402 drive has no PNUs.
    let (code, out, _) = run_cmd(&mut fake, &["params", "--axis", "z"]);
    assert_eq!(code, exit::OK);
    assert!(out.contains("it has no FHPP parameters"), "{out}");

    // read-param with the description: the value as its type, with the parameter's name.
    let (code, out, _) = run_cmd(
        &mut fake,
        &["read-param", "--axis", "x", "--pnu", "1011", "--sub", "1"],
    );
    assert_eq!(code, exit::OK);
    assert_eq!(
        out,
        "latched in cycle 42\naxis x parameter 1011:1 = -35 (Homing method)\n"
    );
}
