//! Real time: six CANopen drives booted together come online without a supervision fault. Their
//! NMT starts leave the services' frame queue two per cycle, so an axis brought online when its
//! report arrived (before its NMT start was on the bus) missed 3 TPDOs and faulted.

use std::time::Duration;

use coordinator::axis::AxisState;
use coordinator::config::Config;
use coordinator::runtime::run::{RunOptions, run};
use coordinator::runtime::script::ScriptOptions;

/// Six TLC5xx on one virtual bus at 4 ms (well within the bus budget).
fn six_tlc5xx() -> String {
    let mut s =
        String::from("cycle_us = 4000\n\n[[buses]]\nname = \"can0\"\nkind = \"simulated\"\n");
    for n in 1..=6 {
        s.push_str(&format!(
            "\n[[axes]]\nname = \"a{n}\"\ndevice = \"tlc5xx\"\nbus = \"can0\"\nnode = {n}\n\
             increments_per_unit = 1000.0\n\
             limits = {{ position_min = 0.0, position_max = 100.0, velocity = 40.0, acceleration = 200.0 }}\n"
        ));
    }
    s
}

#[test]
fn six_drives_booted_together_come_online_without_a_fault() {
    let cfg = Config::parse(&six_tlc5xx()).expect("parses");
    let opts = RunOptions {
        // The boot takes about 0.6 s; the faults came 2 cycles after it.
        duration: Some(Duration::from_secs(3)),
        virtual_time: false,
        status_every: None,
        script: ScriptOptions {
            demo: true,
            chains: false,
            home: false,
        },
        shm: None,
        capture: None,
        record: None,
    };
    let mut out = Vec::new();
    let summary = run(&cfg, &opts, &mut out).expect("runs");
    let text = String::from_utf8_lossy(&out);
    assert!(summary.boot_failures.is_empty(), "{text}");
    assert_eq!(summary.faults, vec![], "{text}");
    // Booted and online: the script's shutdown left them disabled (an axis never online stays
    // offline).
    assert_eq!(summary.axes.len(), 6, "{text}");
    for (name, _, _, state) in &summary.axes {
        assert_eq!(*state, AxisState::Disabled, "axis {name}\n{text}");
    }
}
