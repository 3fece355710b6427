//! What an operator reads from `coordinator run`: words, not Rust `Debug` text (`Some(..)`,
//! `None`, `Stats { .. }`, `QuickStopping`); a normal end that reads as normal (the end's own
//! stop of a running chain is not an abort); an operator's stop still said plainly; the
//! real-time set-up said before the first status line.

use std::process::Command;
use std::time::Duration;

use coordinator::command::{Command as Cmd, Target};
use coordinator::config::{Config, EXAMPLE};
use coordinator::event::Event;
use coordinator::fault::FaultReason;
use coordinator::records::{ChainState, ChainStatus};
use coordinator::runtime::plan::{MachinePlan, plan};
use coordinator::runtime::run::{RunOptions, chain_text, describe, describe_in, group_move_text};
use coordinator::runtime::script::{Phase, ScriptOptions};
use coordinator::runtime::services::ServiceEvent;
use coordinator::runtime::virtual_clock::VirtualRun;

fn coordinator() -> Command {
    Command::new(env!("CARGO_BIN_EXE_coordinator"))
}

/// Every way `Debug` text shows through: `Some(`, `None`, braces of a struct, and a CamelCase
/// word (`QuickStopping`, `SwitchOnDisabled`; names like `MTR-DCI`, `TLC5xx` or hex are not).
fn debug_text(text: &str) -> Vec<String> {
    let mut found = Vec::new();
    for line in text.lines() {
        if line.contains("Some(") || line.contains("None") || line.contains('{') {
            found.push(line.to_owned());
            continue;
        }
        let camel = line.split(|c: char| !c.is_ascii_alphanumeric()).any(|w| {
            let b = w.as_bytes();
            b.windows(2)
                .any(|p| p[0].is_ascii_lowercase() && p[1].is_ascii_uppercase())
        });
        if camel {
            found.push(line.to_owned());
        }
    }
    found
}

#[test]
fn the_debug_detector_sees_what_the_output_used_to_show() {
    for old in [
        "  group gantry   chain Idle record - RC1=0 RCC=0 move None override 100 %",
        "  group gantry   chain Moving record 3 RC1=1 RCC=0 move Some(Moving) override 100 %",
        "drive-sim: Stats { connections: 0, refused: 0 }",
        "z | NMT Operational SwitchOnDisabled",
        "cycle 7: services: ChainAborted { cycle: 7, group: 0, record: 3 }",
    ] {
        assert!(!debug_text(old).is_empty(), "not seen: {old}");
    }
    for fine in [
        "drive ready: node 3 (TLC5xx \"z\") on can0 (simulated): device type 00020192h",
        "axis gripper: simulated CMMO-ST on Modbus TCP 127.0.0.1:39561",
        "real-time: memory locked, scheduler SCHED_FIFO 80, cpu any",
        "  frame hash 847126ce62a881d8",
    ] {
        assert!(debug_text(fine).is_empty(), "seen: {fine}");
    }
}

#[test]
fn a_virtual_run_reads_in_words_and_ends_normally() {
    let out = coordinator()
        .args(["run", "--virtual-time", "--duration", "30", "--no-shm"])
        .output()
        .expect("coordinator runs");
    let text = String::from_utf8_lossy(&out.stdout);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{text}\n{err}");
    let debug = debug_text(&text);
    assert!(debug.is_empty(), "Debug text {debug:#?} in:\n{text}\n{err}");
    // The chains run, then the end stops them: said as the end, not as a problem.
    for needle in [
        "in a group move",
        "running its chain:",
        "move running",
        "for the end of the run",
        "summary:",
    ] {
        assert!(
            text.contains(needle),
            "{needle:?} missing in:\n{text}\n{err}"
        );
    }
    assert!(
        !text.to_lowercase().contains("abort"),
        "a normal end reads as normal:\n{text}\n{err}"
    );
    assert!(!text.contains("FAULT"), "{text}\n{err}");
}

#[test]
fn a_real_time_run_says_its_set_up_before_its_first_status_line() {
    let out = coordinator()
        .args(["run", "--duration", "2", "--no-shm"])
        .output()
        .expect("coordinator runs");
    let text = String::from_utf8_lossy(&out.stdout);
    let err = String::from_utf8_lossy(&out.stderr);
    // 0, or 2 when a loaded host starved the simulated drives into a fault: the lines are
    // what this test is about.
    assert!(
        matches!(out.status.code(), Some(0 | 2)),
        "{:?}\n{text}\n{err}",
        out.status
    );
    let lines: Vec<&str> = text.lines().collect();
    let at = |p: &dyn Fn(&str) -> bool| lines.iter().position(|l| p(l));
    let machine = at(&|l| l.starts_with("machine: ") && l.ends_with("real time"));
    let rt = at(&|l| l.starts_with("real-time: "));
    let first_status = at(&|l| l.starts_with("t="));
    let first_drive = at(&|l| l.starts_with("drive ready: "));
    let summary = at(&|l| l.starts_with("summary: "));
    let (Some(machine), Some(rt), Some(first_status), Some(summary)) =
        (machine, rt, first_status, summary)
    else {
        panic!("a line is missing:\n{text}\n{err}");
    };
    assert!(machine < rt, "the machine first:\n{text}\n{err}");
    assert!(
        rt < first_status,
        "the set-up before the status:\n{text}\n{err}"
    );
    assert!(
        first_drive.is_none_or(|d| rt < d),
        "the set-up before the drives' reports:\n{text}\n{err}"
    );
    // Its warnings (where real-time scheduling or memory locking is refused) follow it.
    for (i, l) in lines.iter().enumerate() {
        if l.starts_with("warning: ") {
            assert!(i < first_status, "warnings at the start:\n{text}\n{err}");
        }
    }
    assert!(summary > first_status, "{text}\n{err}");
    let debug = debug_text(&text);
    assert!(debug.is_empty(), "Debug text {debug:#?} in:\n{text}\n{err}");
}

fn example() -> MachinePlan {
    plan(&Config::parse(EXAMPLE).expect("example parses")).expect("example plans")
}

#[test]
fn an_operators_stop_of_a_running_chain_is_said_plainly() {
    let plan = example();
    let opts = RunOptions {
        duration: None,
        virtual_time: true,
        status_every: Some(Duration::from_millis(500)),
        script: ScriptOptions {
            demo: true,
            chains: true,
            home: true,
        },
        shm: None,
        capture: None,
        record: None,
    };
    let mut run = VirtualRun::new(&plan, &opts).expect("machine builds");
    let mut out = Vec::new();
    // Until the chains run, and a little longer: the first records are under way.
    while run.lp.script.phase() != Phase::Running {
        run.step(&mut out);
        assert!(
            run.elapsed() < Duration::from_secs(60),
            "no chains after 60 s:\n{}",
            String::from_utf8_lossy(&out)
        );
    }
    for _ in 0..200 {
        run.step(&mut out);
    }
    let reply = run.stepper.cycle.command(&Cmd::Stop(Target::All));
    assert!(
        matches!(reply, coordinator::command::Reply::Latched { .. }),
        "{reply:?}"
    );
    for _ in 0..500 {
        run.step(&mut out);
    }
    let text = String::from_utf8_lossy(&out);
    assert!(
        text.contains("chain aborted at record"),
        "an operator's stop is an abort:\n{text}"
    );
    assert!(!text.contains("for the end of the run"), "{text}");
    let debug = debug_text(&text);
    assert!(debug.is_empty(), "Debug text {debug:#?} in:\n{text}");
}

#[test]
fn events_faults_and_states_have_words() {
    let e = Event::ChainAborted {
        cycle: 7,
        group: 0,
        record: 3,
    };
    assert_eq!(e.to_string(), "cycle 7: group 0 chain aborted at record 3");
    assert_eq!(e.cycle(), 7);
    let s = ServiceEvent::Cycle(e).to_string();
    assert!(debug_text(&s).is_empty(), "{s}");
    let late = Event::Parameter {
        cycle: 1,
        axis: 2,
        pnu: 1001,
        sub: 0,
        result: Err(u16::MAX),
    };
    assert!(late.to_string().ends_with("no reply"), "{late}");

    let fe = FaultReason::FollowingError {
        error: 2500,
        limit: 1000,
    };
    assert_eq!(describe(fe), "following error 2500 inc > 1000 inc");
    assert_eq!(
        describe_in(fe, "mm", coordinator::units::Scale::integer(1000)),
        "following error 2.500 mm > limit 1.000 mm (2500 inc > 1000 inc)"
    );
    assert_eq!(FaultReason::LateTpdo(3).to_string(), "no TPDO for 3 cycles");

    let chain = ChainStatus {
        active: Some(3),
        record: Some(3),
        state: ChainState::Waiting,
        ..ChainStatus::default()
    };
    assert_eq!(
        chain_text(&chain),
        "record 3 waiting for its step condition"
    );
    let aborted = ChainStatus {
        active: None,
        state: ChainState::Aborted,
        ..chain
    };
    assert_eq!(chain_text(&aborted), "chain stopped at record 3");
    assert_eq!(group_move_text(None), "no move");
}
