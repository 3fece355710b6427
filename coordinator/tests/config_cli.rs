//! `coordinator config-example` and `coordinator check FILE`, run as the built binary.

use std::path::PathBuf;
use std::process::{Command, Output};

fn coordinator(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_coordinator"))
        .args(args)
        .output()
        .expect("the coordinator binary runs")
}

/// Writes `text` to a file unique to this test and returns its path.
fn file(name: &str, text: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("coordinator-config-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

fn example() -> String {
    let out = coordinator(&["config-example"]);
    assert!(out.status.success());
    String::from_utf8(out.stdout).unwrap()
}

fn check(name: &str, text: &str) -> (bool, String) {
    let path = file(name, text);
    let out = coordinator(&["check", path.to_str().unwrap()]);
    // The file, and the folder once the last test's file is gone.
    let _ = std::fs::remove_file(&path);
    if let Some(dir) = path.parent() {
        let _ = std::fs::remove_dir(dir);
    }
    let mut s = String::from_utf8(out.stdout).unwrap();
    s.push_str(&String::from_utf8(out.stderr).unwrap());
    (out.status.success(), s)
}

#[test]
fn the_example_round_trips_through_check() {
    let text = example();
    assert!(text.contains("device = \"cmmo-st\""));
    assert!(text.lines().filter(|l| l.starts_with('#')).count() > 5);
    let (ok, out) = check("example.toml", &text);
    assert!(ok, "{out}");
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(
        lines[0],
        "bus can0: 11 frames, 1165 us per 2000 us cycle = 58.3 % \
         (mean 49.2 %, 1000 kbit/s, room for 6 more 8-byte frames)"
    );
    assert!(lines.contains(&"  RPDO                  2 frames    260 bits"));
    // The EMCA on its own bus, with its parameter channel: PDO1 and PDO2 each way.
    assert!(lines.contains(
        &"bus can1: 10 frames, 1120 us per 2000 us cycle = 56.0 % \
          (mean 50.2 %, 1000 kbit/s, room for 6 more 8-byte frames)"
    ));
    assert!(lines.contains(&"  RPDO                  2 frames    270 bits"));
    assert_eq!(lines.last(), Some(&"OK"));
}

#[test]
fn bad_settings_are_all_refused_with_their_keys() {
    let text = example()
        .replacen("node = 2", "node = 0", 1)
        .replacen("axes = [\"x\", \"y\"]", "axes = [\"x\", \"y\", \"v\"]", 1)
        .replacen(
            "increments_per_unit = 3200.0",
            "increments_per_unit = 0.0",
            1,
        )
        .replacen("simulated = true", "simulated = true\nbus = \"can0\"", 1)
        .replacen("axis = \"gripper\"", "axis = \"hand\"", 1);
    let (ok, out) = check("bad.toml", &text);
    assert!(!ok);
    for expected in [
        "error: axes[1].node: 0 is not a CANopen node-ID (1..=127)",
        "error: groups[0].axes[2]: no axis named \"v\"",
        "error: axes[2].increments_per_unit: 0 must be a positive number",
        "error: axes[3].bus: a cmmo-st axis is on Modbus TCP, not on a CAN bus",
        "error: records[2].axis: no axis named \"hand\"",
        "refused: 5 error(s)",
    ] {
        assert!(out.lines().any(|l| l == expected), "{expected:?} in\n{out}");
    }
    assert!(!out.lines().any(|l| l == "OK"));
}

#[test]
fn a_cycle_that_cannot_fit_is_refused_with_the_numbers() {
    let text = example().replacen("cycle_us = 2000", "cycle_us = 1000", 1);
    let (ok, out) = check("short.toml", &text);
    assert!(!ok);
    assert!(
        out.contains(
            "error: buses[0]: bus can0: 11 frames, 1165 us per 1000 us cycle = 116.5 %, \
             does not fit the cycle"
        ),
        "{out}"
    );
    // The budget lines are still printed, so the user sees where the time goes.
    assert!(out.starts_with("bus can0: 11 frames"), "{out}");
}

#[test]
fn a_load_over_the_limit_is_refused() {
    let text = example().replacen("load_limit_percent = 80", "load_limit_percent = 50", 1);
    let (ok, out) = check("limit.toml", &text);
    assert!(!ok);
    assert!(out.contains("= 58.3 %, over the 50.0 % limit"), "{out}");
}

#[test]
fn a_typo_in_a_key_is_refused() {
    let text = example().replacen("sync_counter", "sync_countr", 1);
    let (ok, out) = check("typo.toml", &text);
    assert!(!ok);
    assert!(
        out.contains("line 17: unknown field `sync_countr`"),
        "{out}"
    );
}

#[test]
fn a_missing_file_is_an_error() {
    let out = coordinator(&["check", "/nonexistent/coordinator.toml"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/coordinator.toml"));
}
