//! `timing publish --duration 2` as a user runs it (the real coordinator, the bare publisher
//! and the measuring client as separate processes), into a folder: `summary.json` has the
//! run's five series, every sample count matches its histogram and timeline files, every ratio
//! is the quotient of the figures in the file, the four goals stand on those ratios, and the
//! notify's cost is recorded. Nothing here asserts a time. Skipped, with a `SKIPPED:` line,
//! where iceoryx2's shared memory is unusable.

mod common;

use std::path::Path;
use std::process::Command;

use serde_json::Value;

#[test]
fn publish_writes_a_consistent_summary() {
    if let Some(why) = common::shm_unusable() {
        eprintln!(
            "SKIPPED: publish_writes_a_consistent_summary: iceoryx2 shared memory is unusable here: {why}"
        );
        return;
    }
    common::build_coordinator();
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("timing-publish");
    let _ = std::fs::remove_dir_all(&dir);
    let out = Command::new(env!("CARGO_BIN_EXE_timing"))
        .args(["publish", "--duration", "2", "--window-s", "0.25", "--out"])
        .arg(&dir)
        .output()
        .expect("timing runs");
    let ctx = format!(
        "--- stdout\n{}\n--- stderr\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "timing publish failed\n{ctx}");
    let text = std::fs::read_to_string(dir.join("summary.json"))
        .unwrap_or_else(|e| panic!("summary.json: {e}\n{ctx}"));
    let s: Value = serde_json::from_str(&text).unwrap();
    assert!(s["command"].as_str().unwrap().starts_with("timing publish"));
    let runs = s["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 1, "{ctx}");
    let run = &runs[0];
    assert_eq!(run["name"], "publish");
    assert_eq!(run["baselines"]["bare iceoryx2 pair"], "ran", "{run}");

    let names = common::series_names(run);
    assert_eq!(
        names,
        [
            "cycle to published",
            "coordinator, busy-poll client",
            "coordinator, event-driven client",
            "bare iceoryx2, busy-poll",
            "bare iceoryx2, event-driven"
        ],
        "{ctx}"
    );
    for x in run["series"].as_array().unwrap() {
        let samples = x["figures"]["samples"].as_u64().unwrap();
        assert!(samples > 0, "every kind had its windows: {x}");
        let (hdr, timeline) = common::samples_in_files(&dir, x["file"].as_str().unwrap());
        assert_eq!((hdr, timeline), (samples, samples), "{x}");
    }

    // Ours over bare, p50 and p99, both client kinds; each the quotient of the file's figures.
    let ratios = run["ratios"].as_array().unwrap();
    assert_eq!(ratios.len(), 4, "{run}");
    for q in ratios {
        let num = q["numerator"]["series"].as_str().unwrap();
        let den = q["denominator"]["series"].as_str().unwrap();
        assert!(
            num.starts_with("coordinator") && den.starts_with("bare"),
            "{q}"
        );
        let f = q["numerator"]["figure"].as_str().unwrap();
        assert_eq!(q["denominator"]["figure"], f);
        let (a, b) = (common::figure(run, num, f), common::figure(run, den, f));
        let v = q["value"].as_f64().expect("a ratio of non-zero figures");
        assert!((v - a as f64 / b as f64).abs() <= 1e-12 * v.abs(), "{q}");
    }
    let goals = run["goals"].as_array().unwrap();
    assert_eq!(goals.len(), 4, "{run}");
    for (g, q) in goals.iter().zip(ratios) {
        assert_eq!(g["limit"].as_f64(), Some(1.3), "{g}");
        assert_eq!(g["measured"], q["value"], "{g} {q}");
        let (m, l) = (g["measured"].as_f64().unwrap(), 1.3);
        assert_eq!(g["met"].as_bool(), Some(m <= l), "{g}");
    }

    // The notify's cost, from the coordinator's own count: one notify per published state.
    let st = &run["settings"];
    assert!(st["notify_calls"].as_u64().unwrap() > 0, "{st}");
    assert_eq!(st["notify_failed"].as_u64(), Some(0), "{st}");
    let (p50, p99, max) = (
        st["notify_p50_us"].as_f64().unwrap(),
        st["notify_p99_us"].as_f64().unwrap(),
        st["notify_max_us"].as_f64().unwrap(),
    );
    assert!(p50 <= p99 && p99 <= max, "{st}");
    assert!(
        run["notes"]
            .as_array()
            .unwrap()
            .iter()
            .any(|n| n.as_str().unwrap().contains("notify")),
        "{run}"
    );
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(table.contains("coordinator, event-driven client"), "{ctx}");
}

#[test]
fn a_bad_duration_is_refused_naming_the_option() {
    let out = Command::new(env!("CARGO_BIN_EXE_timing"))
        .args(["publish", "--duration", "inf"])
        .output()
        .expect("timing runs");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("--duration inf") && err.contains("0.4 to 86400"),
        "{err}"
    );
}
