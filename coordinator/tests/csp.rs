//! Cyclic synchronous modes end to end in virtual time: generic CiA 402 drives (the project's
//! simulator, inside the coordinator on a simulated bus) commanded by the coordinator's own
//! boot, cycle and axes, a group following a synchronised path with a bounded following error.
//!
//! The bound, from the cycle's data flow: a set-point computed in cycle k goes out after SYNC k,
//! the drive latches it at SYNC k + 1 and its reference reaches it at SYNC k + 2 (it
//! interpolates over one period, 60C2h); the position loop lags the reference by at most v·τ
//! (τ = 2 ms in the simulator); the TPDO after SYNC k + 2 reports it. So the set-point of a
//! cycle is ahead of the position reported in it by at most v·(3 cycles + τ), plus rounding.

use std::time::Duration;

use coordinator::config::Config;
use coordinator::runtime::plan::plan;
use coordinator::runtime::run::{RunOptions, Summary, run};
use coordinator::runtime::script::ScriptOptions;

/// The example machine of four CSP axes at 2 ms, its bus simulated inside the coordinator.
fn example(edit: &[(&str, &str)]) -> String {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/csp-4-axes.toml");
    let mut text = std::fs::read_to_string(path)
        .unwrap()
        .replace("kind = \"vbus\"", "kind = \"simulated\"");
    for (from, to) in edit {
        assert!(text.contains(from), "the example has no {from:?}");
        text = text.replace(from, to);
    }
    text
}

/// Runs `text` in virtual time for `seconds` with the demonstration's chains: a run without
/// faults whose path ran.
fn run_for(text: &str, seconds: u64) -> Summary {
    let s = run_clean(text, seconds);
    assert!(s.records_reached >= 4, "the path ran: {s}");
    s
}

/// Runs `text` in virtual time for `seconds` with the demonstration's chains, without faults.
fn run_clean(text: &str, seconds: u64) -> Summary {
    let cfg = Config::parse(text).unwrap();
    assert!(cfg.check().is_ok(), "{}", cfg.check());
    let opts = RunOptions {
        duration: Some(Duration::from_secs(seconds)),
        virtual_time: true,
        status_every: None,
        script: ScriptOptions {
            demo: true,
            chains: true,
            home: true,
        },
        shm: None,
        capture: None,
        record: None,
    };
    let mut out = Vec::new();
    let s = run(&cfg, &opts, &mut out).unwrap();
    let text = String::from_utf8_lossy(&out);
    assert!(
        s.faults.is_empty() && s.boot_failures.is_empty(),
        "{s}\n{text}"
    );
    s
}

/// The bound of the module's doc, in mm, for `cycle_ms` and the axes' 100 mm/s.
fn bound_mm(cycle_ms: f64) -> f64 {
    let (v_mm_s, tau_ms, rounding_mm) = (100.0, 2.0, 0.003);
    v_mm_s * (3.0 * cycle_ms + tau_ms) / 1000.0 + rounding_mm
}

#[test]
fn four_csp_axes_at_2_ms_follow_a_synchronised_path_within_the_bound() {
    let s = run_for(&example(&[]), 10);
    let bound = bound_mm(2.0);
    for (i, e) in s.following.iter().enumerate() {
        assert!(
            *e > 0.0 && *e <= bound,
            "axis {i}: {e} mm, bound {bound} mm\n{s}"
        );
    }
    // The axis with the longest moves runs at the full 100 mm/s: the lag is most of the bound.
    let worst = s.following.iter().copied().fold(0.0, f64::max);
    assert!(worst > bound * 0.8, "worst {worst} mm, bound {bound} mm");
    // And the coordinator's frames are the same every time (virtual time is deterministic).
    assert_eq!(run_for(&example(&[]), 10).frame_hash, s.frame_hash);
}

#[test]
fn one_csp_axis_at_1_ms_the_most_the_budget_admits() {
    // At 1 ms and 1 Mbit/s one CSP axis fits with its heartbeat, an EMCY and an SDO slot; a
    // second does not (`config::tests` checks the refusal and its numbers).
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/csp-1-axis-1ms.toml");
    let one = std::fs::read_to_string(path)
        .unwrap()
        .replace("kind = \"vbus\"", "kind = \"simulated\"");
    let s = run_for(&one, 6);
    let bound = bound_mm(1.0);
    assert_eq!(s.following.len(), 1);
    assert!(
        s.following[0] > bound * 0.8 && s.following[0] <= bound,
        "{} mm, bound {bound} mm",
        s.following[0]
    );
}

#[test]
fn csv_axes_follow_the_same_path_with_the_position_loop_closed_by_the_coordinator() {
    let s = run_for(&example(&[(r#"mode = "csp""#, r#"mode = "csv""#)]), 10);
    // a1 in CSV, the others in CSP: a1's error stays within the CSP bound too.
    let bound = bound_mm(2.0);
    assert!(
        s.following[0] > 0.0 && s.following[0] <= bound,
        "{} mm\n{s}",
        s.following[0]
    );
    let plan =
        plan(&Config::parse(&example(&[(r#"mode = "csp""#, r#"mode = "csv""#)])).unwrap()).unwrap();
    assert_eq!(plan.axes[0].setup.mode, coordinator::axis::CyclicMode::Csv);
    assert_eq!(plan.axes[1].setup.mode, coordinator::axis::CyclicMode::Csp);
}

#[test]
fn a_cst_axis_pushing_past_its_position_limit_stops_there() {
    // The boot writes the axis's position limits into 607Dh; the drive brakes to a stop at
    // them in CST (the coordinator commands a torque, no position).
    let text = r#"
cycle_us = 2000

[[buses]]
name = "can0"
kind = "simulated"
bitrate = 1000000

[[axes]]
name = "a1"
device = "cia402"
mode = "cst"
bus = "can0"
node = 1
unit = "mm"
increments_per_unit = 1000
limits = { position_min = -100, position_max = 20, velocity = 100, acceleration = 1000 }

[[groups]]
name = "g"
axes = ["a1"]

[[groups.records]]
number = 0
targets = { a1 = 20.0 }
mode = "force"
force = 50
"#;
    let s = run_clean(text, 3);
    // At 100 mm/s the 20 mm are crossed in 0.2 s: without 607Dh the axis would be far past.
    let at = s.axes[0].2;
    assert!((19.9..=20.01).contains(&at), "a1 at {at} mm\n{s}");
}
