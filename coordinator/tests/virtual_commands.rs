//! Virtual time answers client commands: the same cycle iteration as real time, with the
//! shm-api command server served between cycles. A client in another thread commands the
//! machine while the test steps it; every answer names the cycle that latches it, and a bad
//! command is refused with its reason.

use std::sync::mpsc;
use std::time::Duration;

use coordinator::config::{Config, EXAMPLE};
use coordinator::runtime::plan::plan;
use coordinator::runtime::run::RunOptions;
use coordinator::runtime::script::ScriptOptions;
use coordinator::runtime::virtual_clock::VirtualRun;
use shm_api::client::{Client, Rejected};
use shm_api::contract::CommandRequest;
use shm_api::request::Target;

#[test]
fn a_virtual_time_run_answers_client_commands() {
    let prefix = format!("t-virtual-commands-{}", std::process::id());
    let plan = plan(&Config::parse(EXAMPLE).unwrap()).unwrap();
    let opts = RunOptions {
        duration: None,
        virtual_time: true,
        status_every: None,
        // The script stays out of the way: it only boots (no enable, no homing).
        script: ScriptOptions {
            demo: true,
            chains: false,
            home: false,
        },
        shm: Some(prefix.clone()),
        capture: None,
        record: None,
    };
    let mut run = VirtualRun::new(&plan, &opts).unwrap();
    let mut out = Vec::new();
    while !run.booted() {
        run.step(&mut out);
        assert!(run.elapsed() < Duration::from_secs(30));
    }
    let (tx, rx) = mpsc::channel();
    let client = std::thread::spawn(move || {
        let mut c = Client::connect_timeout(&prefix, Duration::from_secs(10)).expect("connects");
        let ok = c.command(
            &CommandRequest::enable(Target::All),
            Duration::from_secs(10),
        );
        let bad = c.command(
            &CommandRequest::enable(Target::Axis(99)),
            Duration::from_secs(10),
        );
        tx.send((ok, bad)).unwrap();
    });
    // Step the machine while the client waits for its answers (bounded).
    let (ok, bad) = loop {
        run.step(&mut out);
        if let Ok(r) = rx.try_recv() {
            break r;
        }
        assert!(
            run.elapsed() < Duration::from_secs(600),
            "no answer: {}",
            String::from_utf8_lossy(&out)
        );
        std::thread::sleep(Duration::from_micros(200));
    };
    client.join().unwrap();
    let latched = ok.expect("enable is latched");
    assert!(
        latched.cycle > 0 && latched.cycle <= run.cycles() + 1,
        "{latched:?}"
    );
    assert_eq!(bad, Err(Rejected::UnknownAxis(99)));
    // The enable took effect in the machine.
    for _ in 0..500 {
        run.step(&mut out);
    }
    for a in 0..plan.axes.len() as u16 {
        assert!(
            run.stepper.cycle.axis_status(a).unwrap().enabled,
            "axis {a}"
        );
    }
}
