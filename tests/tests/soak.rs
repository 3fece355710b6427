//! The soak: `coordinator scenario tests/data/soak-1h.toml` as a user runs it, an hour of
//! machine time at 1 ms with 8 axes and a random fault every second on average. It must end
//! with no invariant violated, no command lost, and the machine back.

use std::path::Path;
use std::process::Command;

#[test]
fn an_hour_of_random_faults_breaks_no_invariant_and_loses_no_command() {
    let coordinator = integration_tests::workspace_bin("coordinator", "coordinator");
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/soak-1h.toml");
    let out = Command::new(coordinator)
        .args(["scenario", "--quiet"])
        .arg(&file)
        .output()
        .unwrap();
    let text = format!(
        "exit {:?}\n--- stdout\n{}--- stderr\n{}",
        out.status.code(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(out.status.code(), Some(0), "{text}");
    assert!(text.contains("invariant violations: 0"), "{text}");
    assert!(text.contains(" 0 lost, 0 answered twice"), "{text}");
    assert!(text.contains("recovered: every axis"), "{text}");
    // At least an hour, and at least a thousand faults of every kind together.
    let faults: u64 = text
        .split("faults injected: ")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no fault count: {text}"));
    assert!(faults >= 1000, "{faults} faults: {text}");
    let cycles: u64 = text
        .split(" s of machine time after start-up (")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no cycle count: {text}"));
    assert!(cycles >= 3_600_000, "{cycles} cycles: {text}");
}
