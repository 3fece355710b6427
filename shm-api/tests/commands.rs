//! Commands and events against the stand-in coordinator in another process.

mod common;

use common::{Standin, field, prefix, serial};
use shm_api::contract::{CommandRequest, event_id, status};
use shm_api::{Client, Latched, Rejected, Target};
use std::collections::HashSet;
use std::time::Duration;

const WAIT: Duration = Duration::from_secs(5);

#[test]
fn a_burst_of_ten_thousand_commands_loses_none() {
    let _g = serial();
    let p = prefix("burst");
    let standin = Standin::spawn(&p, &["--period-us", "1000"]);
    let threads: Vec<_> = (0..4u64)
        .map(|t| {
            let p = p.clone();
            std::thread::spawn(move || {
                let mut c = Client::connect_timeout(&p, WAIT).expect("connect");
                let mut tags = HashSet::new();
                let mut latched = 0;
                for i in 0..2500u64 {
                    let tag = (t + 1) << 32 | i;
                    // Every fifth command is refused (unknown axis): refusals are answers too.
                    let axis = if i % 5 == 0 { 40 } else { (i % 4) as u16 };
                    let req = CommandRequest::jog(axis, (i % 1000) as i16).with_tag(tag);
                    let reply = c.command_reply(&req, WAIT).expect("an answer");
                    assert_eq!(reply.tag, tag);
                    assert!(tags.insert(reply.tag), "tag {tag:#x} answered twice");
                    if reply.status == status::LATCHED {
                        latched += 1;
                    } else {
                        assert_eq!((reply.status, reply.value), (status::UNKNOWN_AXIS, 40));
                    }
                }
                (tags.len(), latched)
            })
        })
        .collect();
    for t in threads {
        let (answered, latched) = t.join().expect("client thread");
        assert_eq!(answered, 2500);
        assert_eq!(latched, 2000);
    }
    let done = standin.stop();
    assert_eq!(field(&done, "commands"), 10_000);
}

#[test]
fn every_request_gets_its_answer_and_refusals_carry_their_numbers() {
    let _g = serial();
    let p = prefix("rejections");
    let standin = Standin::spawn(&p, &["--period-us", "1000", "--axes", "4", "--groups", "2"]);
    let mut c = Client::connect_timeout(&p, WAIT).expect("connect");
    let now = c.next(WAIT).expect("state").cycle;

    let Latched { cycle } = c
        .command(&CommandRequest::enable(Target::All), WAIT)
        .expect("enable all");
    assert!(cycle > now, "latches at a later SYNC: {cycle} after {now}");
    let cases: [(CommandRequest, Rejected); 7] = [
        (
            CommandRequest::enable(Target::Axis(9)),
            Rejected::UnknownAxis(9),
        ),
        (
            CommandRequest::stop(Target::Group(5)),
            Rejected::UnknownGroup(5),
        ),
        (
            CommandRequest::start_chain(1, 70),
            Rejected::UnknownRecord(70),
        ),
        (
            CommandRequest::move_axis(0, 1_000_000, 0),
            Rejected::OutOfRange {
                value: 0,
                min: 1,
                max: 100,
            },
        ),
        (
            CommandRequest::jog(2, 2000),
            Rejected::OutOfRange {
                value: 2000,
                min: -1000,
                max: 1000,
            },
        ),
        (
            CommandRequest::home(Target::Axis(3)),
            Rejected::WrongState("axis not enabled".to_owned()),
        ),
        (CommandRequest::new(99), Rejected::BadRequest),
    ];
    for (req, want) in cases {
        assert_eq!(c.command(&req, WAIT), Err(want.clone()), "{req:?}");
    }
    let msg = Rejected::OutOfRange {
        value: 2000,
        min: -1000,
        max: 1000,
    }
    .to_string();
    assert!(
        msg.contains("2000") && msg.contains("-1000") && msg.contains("1000"),
        "{msg}"
    );
    assert!(Rejected::UnknownAxis(9).to_string().contains('9'));

    // Events: the stand-in signals one every 50 cycles; records arrive in order.
    let a = c.wait_event(WAIT).expect("wait").expect("an event");
    let b = c.wait_event(WAIT).expect("wait").expect("another event");
    assert_eq!(a.id as usize, event_id::STATE_CHANGED);
    assert_eq!(b.seq, a.seq + 1);
    assert_eq!(b.cycle, a.cycle + 50);

    let done = standin.stop();
    assert_eq!(field(&done, "commands"), 8);
    // The coordinator is gone: commands say so instead of hanging.
    let gone = c.command(
        &CommandRequest::stop(Target::All),
        Duration::from_millis(200),
    );
    assert!(
        matches!(gone, Err(Rejected::Disconnected | Rejected::Timeout)),
        "{gone:?}"
    );
}

#[test]
fn a_command_dropped_unanswered_is_refused_as_overloaded() {
    // The server (this thread) takes the request and drops it; the client's wait (another
    // thread) ends with the automatic answer instead of a timeout.
    let p = prefix("dropped");
    let node = shm_api::create_node().expect("node");
    let names = shm_api::ServiceNames::new(&p);
    let settings = shm_api::PublisherSettings::default();
    let mut server = shm_api::CommandServer::create(&node, &names, &settings).expect("server");
    let _events = shm_api::EventPublisher::create(&node, &names, &settings).expect("events");
    let _state = shm_api::StatePublisher::create(&node, &names, &settings).expect("state");
    let client = {
        let p = p.clone();
        std::thread::spawn(move || {
            let mut c = Client::connect(&p).expect("client");
            c.command(&CommandRequest::hold(Target::Group(0)).with_tag(77), WAIT)
        })
    };
    let deadline = std::time::Instant::now() + WAIT;
    let pending = loop {
        if let Some(p) = server.receive() {
            break p;
        }
        assert!(std::time::Instant::now() < deadline, "no request");
        std::thread::sleep(Duration::from_millis(1));
    };
    assert_eq!(pending.request().tag, 77);
    assert_eq!(
        pending.request().kind,
        shm_api::contract::command_kind::HOLD
    );
    drop(pending);
    assert_eq!(client.join().expect("client"), Err(Rejected::Overloaded));
}

/// `motion-cmd` as a process against the stand-in: a position refused in increments reads in
/// millimetres, the admission table's reason in words with its axis, a buffered move latches.
#[test]
fn motion_cmd_says_refusals_in_the_units_typed() {
    let _g = serial();
    let p = prefix("cmd-units");
    let standin = Standin::spawn(&p, &["--period-us", "1000", "--axes", "4", "--groups", "2"]);
    let run = |args: &[&str]| {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_motion-cmd"))
            .args(["--prefix", &p])
            .args(args)
            .output()
            .expect("motion-cmd runs");
        (
            o.status.code(),
            String::from_utf8_lossy(&o.stdout).into_owned(),
        )
    };
    let rejected = Some(shm_api::cli::exit::REJECTED);
    assert_eq!(
        run(&["move", "--axis", "X0", "--to", "1000"]),
        (
            rejected,
            "rejected: axis X0: 1000 mm outside 0..=400 mm\n".to_owned()
        )
    );
    assert_eq!(
        run(&["home", "--axis", "X3"]),
        (rejected, "rejected: axis X3: axis not enabled\n".to_owned())
    );
    assert_eq!(
        run(&["override", "--axis", "X1", "--percent", "250"]),
        (
            rejected,
            "rejected: axis X1: override 250 % outside 0..=200 %\n".to_owned()
        )
    );
    let (code, out) = run(&["move", "--axis", "X0", "--to", "12.5", "--buffered"]);
    assert_eq!(code, Some(shm_api::cli::exit::OK), "{out}");
    assert!(out.starts_with("latched in cycle "), "{out}");
    standin.stop();
}
