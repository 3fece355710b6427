//! `timing all --duration 2` as a user runs it (cycle, step, sim, publish, loop), into a folder: the folder's `summary.json` has
//! the structure the docs describe, every sample count matches the run and the histogram files,
//! every ratio and goal is the quotient of figures in the same file; `timing report DIR`
//! redraws the plots and the table; `timing compare DIR DIR` reads both.
//!
//! Without cyclictest the run must say `absent` and report ours alone; with
//! `MOTION_REQUIRE_ALL=1` (`.ci/run`, which installs rt-tests) a missing cyclictest fails.
//! Nothing here asserts a time: only structure and arithmetic.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use serde_json::Value;

mod common;

struct Ran {
    dir: PathBuf,
    out: Output,
}

impl Ran {
    /// Everything the run printed, for failure messages.
    fn text(&self) -> String {
        format!(
            "--- stdout\n{}\n--- stderr\n{}",
            String::from_utf8_lossy(&self.out.stdout),
            String::from_utf8_lossy(&self.out.stderr)
        )
    }
}

fn cyclictest_installed() -> bool {
    timing::cyclictest::find().is_some()
}

/// One short `timing all`, shared by the tests of this file.
fn ran() -> &'static Ran {
    static RAN: OnceLock<Ran> = OnceLock::new();
    RAN.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("timing-all");
        let _ = std::fs::remove_dir_all(&dir);
        // `publish` and the loop run start the coordinator's binaries, found beside `timing`.
        common::build_coordinator();
        let out = Command::new(env!("CARGO_BIN_EXE_timing"))
            .args(["all", "--duration", "2", "--axes", "8", "--out"])
            .arg(&dir)
            // The loop's debug drive-sim on a shared host: 10 ms cycles (tests/loop.rs).
            .args(["--loop-cycle-us", "10000"])
            .output()
            .expect("timing runs");
        Ran { dir, out }
    })
}

fn summary(r: &Ran) -> Value {
    let text = std::fs::read_to_string(r.dir.join("summary.json"))
        .unwrap_or_else(|e| panic!("summary.json: {e}\n{}", r.text()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("summary.json: {e}\n{}", r.text()))
}

const FIGURES: [&str; 8] = [
    "min", "p50", "p90", "p99", "p99_9", "p99_99", "max", "samples",
];

#[test]
fn all_writes_a_consistent_summary() {
    // `timing all` runs `publish`, which needs iceoryx2's shared memory.
    if let Some(why) = common::shm_unusable() {
        eprintln!(
            "SKIPPED: all_writes_a_consistent_summary: iceoryx2 shared memory is unusable here: {why}"
        );
        return;
    }
    let r = ran();
    assert!(r.out.status.success(), "timing all failed\n{}", r.text());
    let s = summary(r);
    let ctx = r.text();
    assert_eq!(s["format"], 1, "{ctx}");
    assert!(s["command"].as_str().unwrap().starts_with("timing all"));
    for key in ["cpu", "kernel", "kernel_version", "preemption"] {
        assert!(
            s["machine"][key].as_str().is_some_and(|v| !v.is_empty()),
            "machine.{key}"
        );
    }
    for key in ["load_before", "load_after"] {
        assert_eq!(
            s["machine"][key].as_array().map(Vec::len),
            Some(3),
            "machine.{key}"
        );
    }
    // The test builds timing with debug assertions on (scripts/pgo-build's is "release,
    // trained on typical runs (scripts/pgo-build)").
    assert_eq!(s["machine"]["build"], "debug", "machine.build");
    assert!(
        String::from_utf8_lossy(&r.out.stdout).contains("; build: debug"),
        "the table names the build\n{ctx}"
    );
    assert!(s["load"].is_null());
    let runs = s["runs"].as_array().unwrap();
    let names: Vec<&str> = runs.iter().map(|r| r["name"].as_str().unwrap()).collect();
    assert_eq!(
        names,
        [
            "cycle",
            "step",
            "sim",
            "publish",
            "loop-vbus",
            "loop-in-process"
        ],
        "{ctx}"
    );

    for run in runs {
        let name = run["name"].as_str().unwrap();
        let series = run["series"].as_array().unwrap();
        assert!(!series.is_empty(), "{name}");
        for x in series {
            let f = &x["figures"];
            let v: Vec<u64> = FIGURES.iter().map(|k| f[k].as_u64().unwrap()).collect();
            // min <= p50 <= ... <= max.
            assert!(v[..7].windows(2).all(|w| w[0] <= w[1]), "{name}: {f}");
            let samples = v[7];
            assert!(samples > 0, "{name}: {x}");
            // publish's samples are what arrived in its windows: it plans none.
            if name != "publish" {
                assert_eq!(Some(samples), x["planned_samples"].as_u64(), "{name}: {x}");
            }
            let (hdr, timeline) = common::samples_in_files(&r.dir, x["file"].as_str().unwrap());
            assert_eq!((hdr, timeline), (samples, samples), "{name}: {x}");
        }
        // Every ratio is the quotient of two figures of this file.
        for q in run["ratios"].as_array().unwrap() {
            let a = common::figure(
                run,
                q["numerator"]["series"].as_str().unwrap(),
                q["numerator"]["figure"].as_str().unwrap(),
            );
            let b = common::figure(
                run,
                q["denominator"]["series"].as_str().unwrap(),
                q["denominator"]["figure"].as_str().unwrap(),
            );
            let v = q["value"].as_f64().expect("a ratio of non-zero figures");
            assert!((v - a as f64 / b as f64).abs() <= 1e-12 * v.abs(), "{q}");
        }
        for g in run["goals"].as_array().unwrap() {
            let (m, l) = (
                g["measured"].as_f64().unwrap(),
                g["limit"].as_f64().unwrap(),
            );
            assert_eq!(g["met"].as_bool(), Some(m <= l), "{g}");
        }
    }

    // The cycle run: its windows and the baseline.
    let cycle = &runs[0];
    let st = &cycle["settings"];
    let loops = st["loops_per_window"].as_u64().unwrap();
    assert_eq!(
        common::figure(cycle, "ours", "samples"),
        st["windows_ours"].as_u64().unwrap() * loops
    );
    let granted = &cycle["realtime"];
    assert_eq!(granted["priority_requested"], 80);
    assert_eq!(granted["timer_slack_ns"], 1, "{granted}");
    if granted["priority"].is_null() {
        // Refused: the reader is told why, and how to grant it.
        assert!(
            cycle["notes"]
                .as_array()
                .unwrap()
                .iter()
                .any(|n| n.as_str().unwrap().contains("SCHED_FIFO")),
            "{cycle}"
        );
    }
    let state = cycle["baselines"]["cyclictest"].as_str().unwrap();
    if cyclictest_installed() {
        assert_eq!(state, "ran", "{ctx}");
        assert_eq!(
            common::figure(cycle, "cyclictest", "samples"),
            st["windows_cyclictest"].as_u64().unwrap() * loops
        );
        let p99 = cycle["ratios"]
            .as_array()
            .unwrap()
            .iter()
            .find(|q| q["numerator"]["figure"] == "p99")
            .expect("the p99 ratio");
        assert_eq!(p99["numerator"]["series"], "ours");
        assert_eq!(p99["denominator"]["series"], "cyclictest");
        assert_eq!(cycle["goals"].as_array().unwrap().len(), 1);
        let table = String::from_utf8_lossy(&r.out.stdout);
        assert!(table.contains("ours / cyclictest"), "{ctx}");
    } else {
        integration_tests::skip_or_fail(
            "the cyclictest comparison",
            "cyclictest (rt-tests) is not installed; checked the absent path",
        );
        assert_eq!(state, "absent", "{ctx}");
        assert_eq!(cycle["series"].as_array().unwrap().len(), 1);
        assert!(cycle["ratios"].as_array().unwrap().is_empty());
        assert!(
            String::from_utf8_lossy(&r.out.stderr).contains("cyclictest is not installed")
                || String::from_utf8_lossy(&r.out.stdout).contains("cyclictest is not installed"),
            "{ctx}"
        );
    }

    // The step run: every cold series has its memory floor beside it, the ratio of the two,
    // and the count of lines the floor read.
    let step = &runs[1];
    let step_series = common::series_names(step);
    let cold: Vec<&str> = step_series
        .iter()
        .copied()
        .filter(|n| n.ends_with(", cold"))
        .collect();
    assert!(!cold.is_empty(), "{step_series:?}");
    for c in cold {
        let floor = format!("{c}, memory floor");
        assert!(
            step_series.contains(&floor.as_str()),
            "{floor} in {step_series:?}"
        );
        let pair =
            step["ratios"].as_array().unwrap().iter().any(|q| {
                q["numerator"]["series"] == c && q["denominator"]["series"] == floor.as_str()
            });
        assert!(pair, "no ratio {c} / {floor}: {}", step["ratios"]);
        let machine = c.trim_end_matches(", cold");
        let lines = &step["settings"][format!("hot_lines ({machine})")];
        assert!(lines.as_u64().is_some_and(|n| n > 0), "{machine}: {lines}");
    }

    // The sim run: its figures add up, and every drive sent its TPDO on every SYNC.
    let sim = &runs[2];
    let results = sim["settings"]["results"].as_array().unwrap();
    assert_eq!(results.len(), 1, "{sim}");
    let m = &results[0];
    let num = |k: &str| {
        m[k].as_f64()
            .unwrap_or_else(|| panic!("sim: no {k} in {m}"))
    };
    assert_eq!(m["drives"], 8, "{m}");
    assert_eq!(m["period_us"], 1000, "{m}");
    assert_eq!(m["can_drives"], 8, "{m}");
    let series = m["series"].as_str().unwrap();
    assert_eq!(
        common::figure(sim, series, "samples"),
        m["cycles"].as_u64().unwrap()
    );
    // Drive-seconds per wall second from the file's own figures.
    let dsps = num("drive_seconds_per_wall_second");
    let expect = num("drives") * num("machine_s") / num("wall_s");
    assert!(dsps > 0.0 && (dsps - expect).abs() <= 1e-9 * dsps, "{m}");
    // The machine time is the cycles times the period.
    let machine = num("cycles") * num("period_us") / 1e6;
    assert!((num("machine_s") - machine).abs() < 1e-6, "{m}");
    // One TPDO frame per drive per SYNC, within a count per drive (the last cycle's frames
    // may fall either side of the end).
    let syncs = num("drive_syncs");
    let tpdo = num("tpdo_frames");
    assert!(syncs >= num("cycles") * 8.0 - 8.0, "{m}");
    assert!((tpdo - syncs).abs() <= num("can_drives"), "{m}");
    assert!(
        (num("tpdos_per_drive_per_cycle") - tpdo / syncs).abs() < 1e-12,
        "{m}"
    );
    assert_eq!(m["tpdo_senders"], 8, "{m}");
    for k in [
        "tpdos_per_drive_per_cycle_min",
        "tpdos_per_drive_per_cycle_max",
    ] {
        assert!((num(k) - 1.0).abs() * num("cycles") <= 1.0, "{k}: {m}");
    }
    // SYNC, RPDO and TPDO at least, per drive (one bus each at 1 ms).
    assert!(num("frames_per_cycle") >= 3.0 * 8.0 - 1.0, "{m}");
    let goal = &sim["goals"].as_array().unwrap()[0];
    assert!(
        (goal["measured"].as_f64().unwrap() - 1e6 / dsps).abs() < 1e-6,
        "{goal}"
    );

    // The table went to the terminal and into the folder, with every column.
    let table = std::fs::read_to_string(r.dir.join("table.txt")).unwrap();
    for head in [
        "samples", "min", "p50", "p90", "p99", "p99.9", "p99.99", "max",
    ] {
        assert!(table.contains(head), "{table}");
    }
    assert!(
        String::from_utf8_lossy(&r.out.stdout).contains(&table),
        "{ctx}"
    );
    for run in names {
        for kind in ["histogram", "percentiles", "over-time"] {
            let png = std::fs::read(r.dir.join(format!("{run}-{kind}.png"))).unwrap();
            assert!(png.starts_with(b"\x89PNG"), "{run}-{kind}.png");
        }
    }
}

#[test]
fn report_redraws_the_folder_and_compare_reads_two() {
    // `timing all` runs `publish`, which needs iceoryx2's shared memory.
    if let Some(why) = common::shm_unusable() {
        eprintln!(
            "SKIPPED: report_redraws_the_folder_and_compare_reads_two: iceoryx2 shared memory is unusable here: {why}"
        );
        return;
    }
    let r = ran();
    assert!(r.out.status.success(), "timing all failed\n{}", r.text());
    // A copy, so that the other test reads the original.
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("timing-report");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    for e in std::fs::read_dir(&r.dir).unwrap() {
        let p = e.unwrap().path();
        let keep = p.extension().is_none_or(|x| x != "png") && !p.ends_with("table.txt");
        if keep {
            std::fs::copy(&p, dir.join(p.file_name().unwrap())).unwrap();
        }
    }
    let out = Command::new(env!("CARGO_BIN_EXE_timing"))
        .arg("report")
        .arg(&dir)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for run in ["cycle", "step", "sim", "publish"] {
        for kind in ["histogram", "percentiles", "over-time"] {
            let png = std::fs::read(dir.join(format!("{run}-{kind}.png")))
                .unwrap_or_else(|e| panic!("{run}-{kind}.png: {e}\n{text}"));
            assert!(png.starts_with(b"\x89PNG"));
        }
    }
    // The same figures as the run printed: the table is drawn from the same file.
    let original = std::fs::read_to_string(r.dir.join("table.txt")).unwrap();
    let redrawn = std::fs::read_to_string(dir.join("table.txt")).unwrap();
    assert_eq!(original, redrawn);

    let out = Command::new(env!("CARGO_BIN_EXE_timing"))
        .arg("compare")
        .arg(&r.dir)
        .arg(&dir)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    assert!(
        text.contains("1.00x") && !text.contains("only in"),
        "{text}"
    );

    // A folder without a summary is an error in words, not a panic.
    let out = Command::new(env!("CARGO_BIN_EXE_timing"))
        .args(["report", "/nonexistent/timing"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.starts_with("error: /nonexistent/timing/summary.json:"),
        "{err}"
    );
}
