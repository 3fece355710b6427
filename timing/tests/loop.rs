//! `timing loop` as a user runs it: the `timing` binary starts `drive-sim` and `coordinator`
//! (built here next to it, as `cargo build -p coordinator --bins` puts them), commands the axis
//! over shared memory and writes its folder. Checked from the folder's `summary.json` alone:
//! both machines ran, every series has the samples sent, every sample's stages are in order
//! and add up to its round trip, the cycles and the goal's verdict are computed from the
//! figures in the file. Nothing here asserts a time.
//!
//! A `timing` whose sibling binaries are missing says which one and the cargo command.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;
use timing::round_trip::{GOAL, SERIES};

fn folder(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn u(v: &Value) -> u64 {
    v.as_u64().unwrap_or_else(|| panic!("not a count: {v}"))
}

#[test]
fn a_short_loop_on_both_machines_writes_a_consistent_folder() {
    common::build_coordinator();
    let dir = folder("timing-loop");
    // 10 ms cycles: the debug drive-sim and coordinator share two CPUs with other work, and a
    // drive is faulted after three cycles without its TPDO.
    let cycle_us = 10_000u64;
    let out = Command::new(env!("CARGO_BIN_EXE_timing"))
        .args([
            "loop",
            "--drives",
            "both",
            "--samples",
            "8",
            "--duration",
            "60",
        ])
        .args(["--cycle-us", &cycle_us.to_string(), "--out"])
        .arg(&dir)
        .output()
        .expect("timing runs");
    let text = format!(
        "--- stdout\n{}\n--- stderr\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "timing loop failed\n{text}");
    let s: Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("summary.json"))
            .unwrap_or_else(|e| panic!("summary.json: {e}\n{text}")),
    )
    .unwrap();
    let runs = s["runs"].as_array().unwrap();
    let names: Vec<&str> = runs.iter().map(|r| r["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["loop-vbus", "loop-in-process"], "{text}");
    for run in runs {
        let name = run["name"].as_str().unwrap();
        let set = &run["settings"];
        assert_eq!(u(&set["cycle_us"]), cycle_us);
        let sent = u(&set["samples_sent"]);
        assert_eq!(sent, 8, "{name}");
        let raw = set["stages_ns"].as_array().unwrap();
        assert_eq!(
            raw.len() as u64,
            sent,
            "{name}: every sample matched the bus\n{text}"
        );
        let series = run["series"].as_array().unwrap();
        let got: Vec<&str> = series.iter().map(|x| x["name"].as_str().unwrap()).collect();
        assert_eq!(got, SERIES, "{name}");
        let fig =
            |n: &str, f: &str| u(&series.iter().find(|x| x["name"] == n).unwrap()["figures"][f]);
        for x in series {
            let n = x["name"].as_str().unwrap();
            assert_eq!(u(&x["figures"]["samples"]), sent, "{name}: {n}");
            assert_eq!(u(&x["planned_samples"]), sent, "{name}: {n}");
            let hdr = dir.join(format!("{}.hdr", x["file"].as_str().unwrap()));
            assert!(hdr.is_file(), "{}", hdr.display());
        }
        // Every stage is a duration (t0 <= t1 <= t2 <= t3 <= t4): unsigned, and the four add up
        // to the round trip, whose extremes are the series' (within the histogram's 0.1 %).
        let sums: Vec<u64> = raw
            .iter()
            .map(|r| {
                let d: Vec<u64> = r.as_array().unwrap().iter().map(u).collect();
                assert_eq!(d.len(), 4, "{r}");
                d.iter().sum()
            })
            .collect();
        let close = |a: u64, b: u64| a.abs_diff(b) <= b / 500 + 1;
        let (lo, hi) = (*sums.iter().min().unwrap(), *sums.iter().max().unwrap());
        assert!(close(fig("round trip", "min"), lo), "{name}: {lo}");
        assert!(close(fig("round trip", "max"), hi), "{name}: {hi}");
        let firsts: Vec<u64> = raw.iter().map(|r| u(&r[0]) + u(&r[1])).collect();
        assert!(close(
            fig("command to latched", "max"),
            *firsts.iter().max().unwrap()
        ));
        // Cycles: the figures over the period.
        let p99 = fig("round trip", "p99");
        let in_cycles = set["in_cycles"]["round trip"]["p99"].as_f64().unwrap();
        assert!((in_cycles - p99 as f64 / (cycle_us * 1000) as f64).abs() < 0.001);
        // The goal's verdict from the figure beside it.
        let goal = &run["goals"][0];
        assert_eq!(goal["text"], GOAL);
        let measured = goal["measured"].as_f64().unwrap();
        let limit = goal["limit"].as_f64().unwrap();
        assert_eq!(measured, fig("command to latched", "p99") as f64 / 1000.0);
        assert_eq!(limit, 2.0 * cycle_us as f64 + 100.0);
        assert_eq!(goal["met"].as_bool().unwrap(), measured <= limit);
    }
    let table = std::fs::read_to_string(dir.join("table.txt")).unwrap();
    assert!(
        table.contains("command to latched") && table.contains("p99.99"),
        "{table}"
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains(&table));
}

#[test]
fn a_missing_coordinator_is_named_with_the_command_that_builds_it() {
    let dir = folder("timing-loop-alone");
    std::fs::create_dir_all(&dir).unwrap();
    let alone = dir.join("timing");
    std::fs::hard_link(env!("CARGO_BIN_EXE_timing"), &alone)
        .or_else(|_| std::fs::copy(env!("CARGO_BIN_EXE_timing"), &alone).map(|_| ()))
        .unwrap();
    let out = Command::new(&alone)
        .args(["loop", "--drives", "in-process", "--samples", "1", "--out"])
        .arg(dir.join("out"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("coordinator is not next to this program")
            && err.contains("cargo build")
            && err.contains("-p coordinator --bins"),
        "{err}"
    );
}
