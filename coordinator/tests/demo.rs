//! The virtual-bus demo behind `coordinator run`, in virtual time.

use std::time::Duration;

use coordinator::demo::{DemoConfig, run};

fn cfg(nodes: u8) -> DemoConfig {
    DemoConfig {
        nodes,
        duration: Duration::from_millis(400),
        virtual_time: true,
        status_every: None,
        ..DemoConfig::default()
    }
}

#[test]
fn boots_configures_and_drives_every_node() {
    let mut out = Vec::new();
    let s = run(&cfg(4), &mut out).expect("demo runs");
    let text = String::from_utf8(out).unwrap();
    assert!(text.contains("boot-up: 4 nodes pre-operational"), "{text}");
    assert_eq!(text.matches("read back OK").count(), 4, "{text}");
    // 400 ms at a 2 ms cycle: 200 SYNCs (plus the one at the end instant).
    assert!((200..=201).contains(&s.cycles), "{s:?}");
    // Every node answers every SYNC after the first with a TPDO2, and all decode.
    assert!(s.tpdos_received >= 4 * (s.cycles - 1), "{s:?}");
    assert_eq!(s.bad_tpdos, 0);
    assert_eq!(s.supervision_events, 0, "{text}");
    // The drives follow: within one cycle's travel (400 increments) of the target.
    assert!(s.final_max_error <= 400, "{s:?}");
    // SYNC (55 bits) + 4 x (RPDO2 + TPDO2, 6 bytes: 115 bits each) every 2000 us at 1 Mbit/s:
    // 975 us of 2000, plus a few heartbeats.
    assert!(
        s.bus_load_percent > 48.0 && s.bus_load_percent < 52.0,
        "{s:?}"
    );
}

#[test]
fn runs_are_deterministic_in_virtual_time() {
    let a = run(&cfg(3), &mut Vec::new()).unwrap();
    let b = run(&cfg(3), &mut Vec::new()).unwrap();
    assert_eq!(
        (a.cycles, a.frames, a.tpdos_received, a.final_max_error),
        (b.cycles, b.frames, b.tpdos_received, b.final_max_error)
    );
    assert_eq!(a.bus_time, b.bus_time);
}

#[test]
fn a_cycle_too_short_for_the_traffic_shows_as_full_load() {
    // 8 nodes at 1 ms cannot fit: the bus saturates (the coordinator's budget check will refuse
    // such a configuration before it runs; the demo shows what happens without one).
    let s = run(
        &DemoConfig {
            nodes: 8,
            cycle: Duration::from_millis(1),
            ..cfg(8)
        },
        &mut Vec::new(),
    )
    .unwrap();
    assert!(s.bus_load_percent > 95.0, "{s:?}");
}
