//! Bad input, everywhere: a table of what a hostile or careless user types into every binary
//! (options, configuration files, client commands), each expecting a refusal that names the
//! option, key or field and what is allowed, a non-zero exit, and never a panic or a hang.
//!
//! Every case runs the real binary as a user would. A case that is accepted, panics, hangs, or
//! refuses without naming what was wrong fails the test with the command and its whole output.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use integration_tests::workspace_bin;

/// A case: the binary (package, name), its arguments, and the texts its refusal must contain.
struct Case {
    package: &'static str,
    bin: &'static str,
    args: Vec<String>,
    expect: Vec<&'static str>,
    /// Run in a network namespace of its own (`unshare -n`): a case that makes the binary
    /// resolve a host name, so that the resolver's query cannot leave this machine.
    offline: bool,
}

fn case(package: &'static str, bin: &'static str, args: &[&str], expect: &[&'static str]) -> Case {
    Case {
        package,
        bin,
        args: args.iter().map(|s| s.to_string()).collect(),
        expect: expect.to_vec(),
        offline: false,
    }
}

/// Nothing a refusal takes longer than this (a case that runs on is a wrong accept or a hang).
const LIMIT: Duration = Duration::from_secs(30);

/// Runs a case; returns (exit code or None when killed, output).
fn run(exe: &Path, args: &[String], dir: &Path, offline: bool) -> (Option<i32>, String) {
    let mut cmd = if offline {
        let mut c = Command::new("unshare");
        c.arg("-n").arg(exe);
        c
    } else {
        Command::new(exe)
    };
    let ended = integration_tests::run_to_end(cmd.args(args).current_dir(dir), LIMIT);
    let code = ended.code();
    (code, ended.stdout + &ended.stderr)
}

/// The example configuration with `from` replaced by `to` (once; `from` must be there).
fn variant(example: &str, from: &str, to: &str) -> String {
    assert!(example.contains(from), "the example has no `{from}`");
    example.replacen(from, to, 1)
}

fn cases(dir: &Path, example: &str) -> Vec<Case> {
    let file = |name: &str, text: String| -> String {
        let p = dir.join(name);
        std::fs::write(&p, text).expect("writing a configuration");
        p.display().to_string()
    };
    let log = file("good.log", "(0.000000) can0 123#00\n".into());
    let good_scenario = "machine = \"embedded\"\nduration_s = 1.0\n".to_string();
    let scenario = file("good-scenario.toml", good_scenario.clone());
    let bus = format!("vbus:bad-input-{}", std::process::id());
    let bus = bus.as_str();
    let mut v = vec![
        // canbus: durations, counts, scales, bus names, frames.
        case(
            "drivers",
            "canbus",
            &["dump", bus, "--timeout", "inf"],
            &["--timeout", "0.001 to 31536000"],
        ),
        case(
            "drivers",
            "canbus",
            &["dump", bus, "--timeout", "NaN"],
            &["--timeout", "0.001 to 31536000"],
        ),
        case(
            "drivers",
            "canbus",
            &["dump", bus, "--timeout", "1e30"],
            &["--timeout", "0.001 to 31536000"],
        ),
        case(
            "drivers",
            "canbus",
            &["dump", bus, "--timeout", "1e-300"],
            &["--timeout", "0.001 to 31536000"],
        ),
        case(
            "drivers",
            "canbus",
            &["dump", bus, "--timeout", "-1"],
            &["-1"],
        ),
        case(
            "drivers",
            "canbus",
            &["dump", bus, "--timeout", "soon"],
            &["--timeout", "soon"],
        ),
        case(
            "drivers",
            "canbus",
            &["dump", bus, "--count", "0"],
            &["--count", "1..="],
        ),
        case(
            "drivers",
            "canbus",
            &["--bitrate", "0", "dump", bus, "--timeout", "0.1"],
            &["bitrate 0", "20000..=1000000"],
        ),
        case(
            "drivers",
            "canbus",
            &["--bitrate", "5000000", "dump", bus, "--timeout", "0.1"],
            &["bitrate 5000000", "20000..=1000000"],
        ),
        case(
            "drivers",
            "canbus",
            &["--bitrate", "fast", "dump", bus],
            &["--bitrate", "fast"],
        ),
        case(
            "drivers",
            "canbus",
            &["dump", "", "--timeout", "0.1"],
            &["name is empty", "vbus:NAME"],
        ),
        case(
            "drivers",
            "canbus",
            &["dump", "vbus:", "--timeout", "0.1"],
            &["name is empty", "vbus:NAME"],
        ),
        case(
            "drivers",
            "canbus",
            &[
                "dump",
                bus,
                "--log",
                "/nonexistent-dir/x.log",
                "--timeout",
                "0.1",
            ],
            &["/nonexistent-dir/x.log"],
        ),
        case(
            "drivers",
            "canbus",
            &[
                "dump",
                bus,
                "--pcap",
                "/nonexistent-dir/x.pcap",
                "--timeout",
                "0.1",
            ],
            &["/nonexistent-dir/x.pcap"],
        ),
        case(
            "drivers",
            "canbus",
            &["send", "", "123#00"],
            &["name is empty"],
        ),
        case(
            "drivers",
            "canbus",
            &["send", bus, "+123#00"],
            &["+123#00", "3 hex digits"],
        ),
        case(
            "drivers",
            "canbus",
            &["send", bus, "800#00"],
            &["800#00", "0x7FF"],
        ),
        case(
            "drivers",
            "canbus",
            &["send", bus, "20000000#00"],
            &["20000000#00", "0x1FFFFFFF"],
        ),
        case(
            "drivers",
            "canbus",
            &["send", bus, "123#001122334455667788"],
            &["at most 8 data bytes"],
        ),
        case(
            "drivers",
            "canbus",
            &["send", bus, "123#0"],
            &["123#0", "pairs of hex digits"],
        ),
        case(
            "drivers",
            "canbus",
            &["send", bus, "123#GG"],
            &["123#GG", "pairs of hex digits"],
        ),
        case(
            "drivers",
            "canbus",
            &["send", bus, "123"],
            &["`123`", "ID#DATA"],
        ),
        case(
            "drivers",
            "canbus",
            &["send", bus, "123#00", "--linger", "99999999"],
            &["--linger", "0..=60000"],
        ),
        case(
            "drivers",
            "canbus",
            &["send", bus, "123#00", "--linger", "inf"],
            &["--linger", "inf"],
        ),
        case(
            "drivers",
            "canbus",
            &["replay", "/nonexistent.log", bus],
            &["/nonexistent.log"],
        ),
        case(
            "drivers",
            "canbus",
            &["replay", &log, bus, "--speed", "0"],
            &["--speed", "0.001 to 1000"],
        ),
        case(
            "drivers",
            "canbus",
            &["replay", &log, bus, "--speed", "inf"],
            &["--speed", "0.001 to 1000"],
        ),
        case(
            "drivers",
            "canbus",
            &["replay", &log, bus, "--speed", "NaN"],
            &["--speed", "0.001 to 1000"],
        ),
        case(
            "drivers",
            "canbus",
            &["replay", &log, bus, "--speed", "1e-300"],
            &["--speed", "0.001 to 1000"],
        ),
        case(
            "drivers",
            "canbus",
            &["replay", &log, bus, "--speed", "1e9"],
            &["--speed", "0.001 to 1000"],
        ),
        // drive-sim: node-IDs, durations, buses, devices and profiles, Modbus addresses.
        case(
            "coordinator",
            "drive-sim",
            &["--device", "tlc5xx", "--bus", bus, "--node", "0"],
            &["--node", "1..=127"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &["--device", "tlc5xx", "--bus", bus, "--node", "128"],
            &["--node", "1..=127"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &[
                "--device", "tlc5xx", "--bus", bus, "--node", "1", "--node", "1",
            ],
            &["--node 1", "twice"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &[
                "--device",
                "tlc5xx",
                "--bus",
                bus,
                "--node",
                "1",
                "--duration",
                "inf",
            ],
            &["--duration inf", "0.001 to 31536000"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &[
                "--device",
                "tlc5xx",
                "--bus",
                bus,
                "--node",
                "1",
                "--duration",
                "NaN",
            ],
            &["--duration NaN", "0.001 to 31536000"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &[
                "--device",
                "tlc5xx",
                "--bus",
                bus,
                "--node",
                "1",
                "--duration",
                "1e30",
            ],
            &["--duration 1e30", "0.001 to 31536000"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &[
                "--device",
                "tlc5xx",
                "--bus",
                bus,
                "--node",
                "1",
                "--duration",
                "1e-300",
            ],
            &["--duration 1e-300", "0.001 to 31536000"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &[
                "--device",
                "tlc5xx",
                "--bus",
                bus,
                "--node",
                "1",
                "--duration=-3",
            ],
            &["--duration -3", "0.001 to 31536000"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &[
                "--device",
                "tlc5xx",
                "--bus",
                bus,
                "--node",
                "1",
                "--status-every",
                "NaN",
            ],
            &["--status-every NaN", "or 0: never"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &[
                "--device",
                "tlc5xx",
                "--bus",
                bus,
                "--node",
                "1",
                "--status-every",
                "0.0001",
            ],
            &["--status-every 0.0001", "0.01 to 86400"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &[
                "--device",
                "tlc5xx",
                "--bus",
                bus,
                "--node",
                "1",
                "--bitrate",
                "0",
            ],
            &["bitrate 0", "20000..=1000000"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &["--device", "tlc5xx", "--bus", "vcan0", "--node", "1"],
            &["--bus vcan0", "vbus:NAME"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &["--device", "tlc5xx", "--bus", "", "--node", "1"],
            &["--bus", "vbus:NAME"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &["--device", "tlc5xx", "--node", "1"],
            &["--bus"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &[
                "--device",
                "tlc5xx",
                "--bus",
                bus,
                "--node",
                "1",
                "--profile",
                "fhpp",
            ],
            &["--profile fhpp", "CiA 402 only"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &[
                "--device",
                "emca",
                "--bus",
                bus,
                "--node",
                "1",
                "--profile",
                "cia402",
            ],
            &["--profile cia402", "FHPP only"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &["--device", "servo9000", "--bus", bus, "--node", "1"],
            &["servo9000", "mtr-dci, emca, tlc5xx, cmmo-st"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &["--device", "cmmo-st", "--modbus", "127.0.0.1"],
            &["--modbus", "127.0.0.1"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &["--device", "cmmo-st", "--modbus", "127.0.0.1:99999"],
            &["--modbus", "127.0.0.1:99999"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &["--config", "/nonexistent.toml"],
            &["/nonexistent.toml"],
        ),
        // drive-sim's TLC5xx switches: whole increments in 32 bits, in order.
        case(
            "coordinator",
            "drive-sim",
            &[
                "--device",
                "tlc5xx",
                "--bus",
                bus,
                "--node",
                "1",
                "--limit-negative",
                "NaN",
            ],
            &[
                "--limit-negative NaN",
                "whole motor increments, -2147483648 to 2147483647",
            ],
        ),
        case(
            "coordinator",
            "drive-sim",
            &[
                "--device",
                "tlc5xx",
                "--bus",
                bus,
                "--node",
                "1",
                "--limit-positive",
                "1e300",
            ],
            &["--limit-positive 1e300", "whole motor increments"],
        ),
        case(
            "coordinator",
            "drive-sim",
            &[
                "--device",
                "tlc5xx",
                "--bus",
                bus,
                "--node",
                "1",
                "--reference",
                "5..-5",
            ],
            &["--reference 5..-5", "FROM must be below TO"],
        ),
        // motion-watch, motion-cmd, motion-top: refused before anything connects.
        case(
            "shm-api",
            "motion-watch",
            &["--rate", "0"],
            &["--rate", "0.01 to 1000000"],
        ),
        case(
            "shm-api",
            "motion-watch",
            &["--rate", "inf"],
            &["--rate", "0.01 to 1000000"],
        ),
        case(
            "shm-api",
            "motion-watch",
            &["--rate", "NaN"],
            &["--rate", "0.01 to 1000000"],
        ),
        case(
            "shm-api",
            "motion-watch",
            &["--rate", "1e30"],
            &["--rate", "0.01 to 1000000"],
        ),
        case(
            "shm-api",
            "motion-watch",
            &["--rate", "1e-300"],
            &["--rate", "0.01 to 1000000"],
        ),
        case(
            "shm-api",
            "motion-watch",
            &["--rate=-1"],
            &["--rate", "0.01 to 1000000"],
        ),
        case(
            "shm-api",
            "motion-watch",
            &["--timeout-ms", "0"],
            &["--timeout-ms", "1..=3600000"],
        ),
        case(
            "shm-api",
            "motion-watch",
            &["--timeout-ms", "99999999999999999999"],
            &["--timeout-ms", "99999999999999999999"],
        ),
        case(
            "shm-api",
            "motion-watch",
            &["--count", "0"],
            &["--count", "1..="],
        ),
        case(
            "shm-api",
            "motion-watch",
            &["--prefix", ""],
            &["--prefix", "1 to 64 letters"],
        ),
        case(
            "shm-api",
            "motion-watch",
            &["--prefix", "a b/../c"],
            &["--prefix", "1 to 64 letters"],
        ),
        case(
            "shm-api",
            "motion-watch",
            &["--rate", "5", "--every-cycle"],
            &["--every-cycle"],
        ),
        case(
            "shm-api",
            "motion-cmd",
            &["--prefix", "", "stop", "--all"],
            &["--prefix", "1 to 64 letters"],
        ),
        case(
            "shm-api",
            "motion-cmd",
            &["--timeout-ms", "0", "stop", "--all"],
            &["--timeout-ms", "1..=3600000"],
        ),
        case("shm-api", "motion-cmd", &["frobnicate"], &["frobnicate"]),
        case(
            "shm-api",
            "motion-cmd",
            &["stop"],
            &["--axis", "--group", "--all"],
        ),
        case(
            "shm-api",
            "motion-cmd",
            &["move", "--axis", "x", "--to", "inf"],
            &["--to", "'inf' is not a number in user units"],
        ),
        case(
            "shm-api",
            "motion-cmd",
            &["move", "--axis", "x", "--to", "NaN"],
            &["--to", "'NaN' is not a number in user units"],
        ),
        case(
            "shm-api",
            "motion-cmd",
            &["move", "--axis", "x", "--to", "1e30"],
            &["--to", "'1e30' is not a number in user units"],
        ),
        case(
            "shm-api",
            "motion-cmd",
            &["move", "--axis", "x", "--to", "0.0000001"],
            &["--to", "at most 6 decimals"],
        ),
        case(
            "shm-api",
            "motion-cmd",
            &["move", "--axis", "x", "--to", "99999999999999999999"],
            &["--to", "not a number in user units"],
        ),
        case(
            "shm-api",
            "motion-cmd",
            &["move", "--group", "g", "--to", "1,,2"],
            &["--to", "'' is not a number"],
        ),
        case(
            "shm-api",
            "motion-cmd",
            &["move", "--axis", "x", "--to", "1", "--percent", "300"],
            &["--percent", "300"],
        ),
        case(
            "shm-api",
            "motion-cmd",
            &["jog", "--axis", "x", "--permille", "40000"],
            &["--permille", "40000"],
        ),
        case(
            "shm-api",
            "motion-cmd",
            &["override", "--all", "--percent", "NaN"],
            &["--percent", "NaN"],
        ),
        case(
            "shm-api",
            "motion-cmd",
            &["set-input", "--bit", "1", "--value", "maybe"],
            &["--value", "maybe", "on/off"],
        ),
        case(
            "shm-api",
            "motion-top",
            &["--prefix", ""],
            &["--prefix", "1 to 64 letters"],
        ),
        // coordinator: run options.
        case(
            "coordinator",
            "coordinator",
            &["run", "--duration", "inf", "--virtual-time"],
            &["--duration", "0.001 to 31536000"],
        ),
        case(
            "coordinator",
            "coordinator",
            &["run", "--duration", "NaN", "--virtual-time"],
            &["--duration", "0.001 to 31536000"],
        ),
        case(
            "coordinator",
            "coordinator",
            &["run", "--duration", "1e30", "--virtual-time"],
            &["--duration", "0.001 to 31536000"],
        ),
        case(
            "coordinator",
            "coordinator",
            &["run", "--duration", "1e-300", "--virtual-time"],
            &["--duration", "0.001 to 31536000"],
        ),
        case(
            "coordinator",
            "coordinator",
            &["run", "--duration=-1", "--virtual-time"],
            &["--duration", "0.001 to 31536000"],
        ),
        case(
            "coordinator",
            "coordinator",
            &["run", "--virtual-time"],
            &["--virtual-time needs --duration"],
        ),
        case(
            "coordinator",
            "coordinator",
            &["run", "--shm-prefix", "", "--duration", "0.1"],
            &["--shm-prefix", "1 to 64 letters"],
        ),
        case(
            "coordinator",
            "coordinator",
            &["run", "--config", "/nonexistent.toml"],
            &["/nonexistent.toml"],
        ),
        case(
            "coordinator",
            "coordinator",
            &["check", "/nonexistent.toml"],
            &["/nonexistent.toml"],
        ),
        // coordinator: scenarios and recordings.
        case(
            "coordinator",
            "coordinator",
            &["scenario", "/nonexistent.toml"],
            &["/nonexistent.toml"],
        ),
        case(
            "coordinator",
            "coordinator",
            &["scenario", &scenario, "--duration", "inf"],
            &["--duration", "0.001 to 31536000"],
        ),
        case(
            "coordinator",
            "coordinator",
            &["scenario", &scenario, "--seed=-1"],
            &["--seed", "0 to 18446744073709551615"],
        ),
        case(
            "coordinator",
            "coordinator",
            &[
                "scenario",
                &file(
                    "s-nan.toml",
                    good_scenario.replace("duration_s = 1.0", "duration_s = nan"),
                ),
            ],
            &["duration_s = NaN", "0.001 to 31536000"],
        ),
        case(
            "coordinator",
            "coordinator",
            &[
                "scenario",
                &file(
                    "s-axis.toml",
                    format!(
                        "{good_scenario}[[fault]]\nat_s = 0.5\nkind = \"drive-reboot\"\naxis = \"q\"\n"
                    ),
                ),
            ],
            &["fault[0].axis = \"q\"", "no such axis"],
        ),
        case(
            "coordinator",
            "coordinator",
            &[
                "scenario",
                &file(
                    "s-kind.toml",
                    format!("{good_scenario}[[fault]]\nat_s = 0.5\nkind = \"meteor\"\n"),
                ),
            ],
            &["unknown variant `meteor`", "frame-loss"],
        ),
        case(
            "coordinator",
            "coordinator",
            &[
                "scenario",
                &file(
                    "s-length.toml",
                    format!("{good_scenario}[random]\nevery_s = 1\nlength_s = [0.5, 0.1]\n"),
                ),
            ],
            &["random.length_s[1] = 0.1", "0.5 to 3600"],
        ),
        case(
            "coordinator",
            "coordinator",
            &["replay", "/nonexistent.rec"],
            &["cannot read /nonexistent.rec"],
        ),
        case(
            "coordinator",
            "coordinator",
            &["replay", &log],
            &["is not a recording"],
        ),
        // timing: sizes, periods, durations, folders.
        case(
            "timing",
            "timing",
            &["cycle", "--period-us", "0"],
            &["--period-us 0", "50 to 100000"],
        ),
        case(
            "timing",
            "timing",
            &["cycle", "--duration", "inf"],
            &["--duration inf", "0.01 to 86400"],
        ),
        case(
            "timing",
            "timing",
            &["cycle", "--priority", "100"],
            &["--priority 100", "1 to 99"],
        ),
        case(
            "timing",
            "timing",
            &["step", "--axes", "0"],
            &["--axes 0", "1 to 128"],
        ),
        case(
            "timing",
            "timing",
            &["step", "--axes", "129"],
            &["--axes 129", "1 to 128"],
        ),
        case(
            "timing",
            "timing",
            &["sim", "--drives", "0"],
            &["--drives 0", "1 to 128"],
        ),
        case(
            "timing",
            "timing",
            &["sim", "--period-us", "1"],
            &["--period-us 1", "250 to 100000"],
        ),
        case(
            "timing",
            "timing",
            &["report", "/nonexistent-dir"],
            &["/nonexistent-dir/summary.json"],
        ),
        case(
            "timing",
            "timing",
            &["step", "--duration", "1e30"],
            &["--duration 1e30", "0.01 to 86400"],
        ),
        case(
            "timing",
            "timing",
            &["publish", "--duration", "NaN"],
            &["--duration NaN", "0.4 to 86400"],
        ),
        case(
            "timing",
            "timing",
            &["publish", "--window-s", "0"],
            &["--window-s 0", "0.05 to 60"],
        ),
        case(
            "timing",
            "timing",
            &["loop", "--duration", "1e-300"],
            &["--duration 1e-300", "0.5 to 86400"],
        ),
        case(
            "timing",
            "timing",
            &["loop", "--cycle-us", "0"],
            &["--cycle-us 0", "250 to 100000"],
        ),
        case(
            "timing",
            "timing",
            &["loop", "--samples", "0"],
            &["--samples 0", "1 to 1000000"],
        ),
        case(
            "timing",
            "timing",
            &["loop", "--drives", "nowhere"],
            &["nowhere", "vbus, in-process, both"],
        ),
        case(
            "timing",
            "timing",
            &["all", "--duration", "0.5"],
            &["--duration 0.5", "0.8 to 86400"],
        ),
        case(
            "timing",
            "timing",
            &["all", "--loop-cycle-us", "1"],
            &["--loop-cycle-us 1", "250 to 100000"],
        ),
        case(
            "timing",
            "timing",
            &["compare", "/nonexistent-a", "/nonexistent-b"],
            &["/nonexistent-a/summary.json"],
        ),
    ];
    // The configuration: each a variant of the example, refused by `check` and by `run`, naming
    // the key.
    let configs: &[(&str, &str, &str, &[&str])] = &[
        (
            "cycle0",
            "cycle_us = 2000",
            "cycle_us = 0",
            &["cycle_us", "250..=100000"],
        ),
        (
            "cycle-float",
            "cycle_us = 2000",
            "cycle_us = 2000.5",
            &["line 6", "2000.5"],
        ),
        (
            "ipu-nan",
            "increments_per_unit = 100.0",
            "increments_per_unit = nan",
            &["axes[3].increments_per_unit", "NaN"],
        ),
        (
            "ipu-inf",
            "increments_per_unit = 100.0",
            "increments_per_unit = inf",
            &["axes[3].increments_per_unit", "inf"],
        ),
        (
            "velocity-negative",
            "velocity = 90.0",
            "velocity = -90.0",
            &["axes[3].limits.velocity", "-90"],
        ),
        (
            "position-nan",
            "position_max = 180.0",
            "position_max = nan",
            &["axes[3].limits.position_max", "NaN"],
        ),
        (
            "duplicate-axis",
            "name = \"gripper\"",
            "name = \"x\"",
            &["axes[3].name", "already used"],
        ),
        (
            "unknown-device",
            "device = \"cmmo-st\"",
            "device = \"cmmo-xx\"",
            &["cmmo-xx", "tlc5xx"],
        ),
        (
            "target-nan",
            "targets = { z = 20.0 }",
            "targets = { z = nan }",
            &["targets.z", "NaN"],
        ),
        (
            "target-outside",
            "targets = { z = 20.0 }",
            "targets = { z = 1e9 }",
            &["targets.z", "outside 0..=120"],
        ),
        (
            "group-unknown-axis",
            "axes = [\"z\"]",
            "axes = [\"w\"]",
            &["groups[1].axes[0]", "\"w\""],
        ),
        (
            "unknown-key",
            "unit = \"deg\"",
            "unit = \"deg\"\ncolour = \"red\"",
            &["colour", "expected one of"],
        ),
        (
            "modbus-no-port",
            "simulated = true",
            "modbus = \"127.0.0.1\"",
            &["axes[3].modbus", "host:port"],
        ),
        (
            "modbus-unresolvable",
            "simulated = true",
            "modbus = \"nohost.invalid:502\"",
            &["modbus", "nohost.invalid:502", "cannot resolve"],
        ),
        (
            "self-step-at-once",
            "step = { condition = \"mc\", next = 12 }",
            "step = { condition = \"immediately\", next = 11 }",
            &["step.next", "the record itself"],
        ),
        (
            "relative-self-step-on-the-fly",
            "step = { condition = \"mc\", next = 12 }",
            "step = { condition = \"time\", min = 0.0, max = 100.0, next = 11 }",
            &["step.next", "crawls"],
        ),
        (
            "virtual-bus-kind",
            "kind = \"simulated\"",
            "kind = \"virtual\"",
            &["virtual", "vbus"],
        ),
    ];
    for (name, from, to, expect) in configs {
        let path = file(&format!("{name}.toml"), variant(example, from, to));
        v.push(Case {
            package: "coordinator",
            bin: "coordinator",
            args: vec!["check".into(), path.clone()],
            expect: expect.to_vec(),
            offline: name.contains("unresolvable"),
        });
        v.push(Case {
            package: "coordinator",
            bin: "coordinator",
            args: vec![
                "run".into(),
                "--config".into(),
                path.clone(),
                "--no-shm".into(),
                "--duration".into(),
                "0.1".into(),
            ],
            expect: expect.to_vec(),
            offline: name.contains("unresolvable"),
        });
    }
    v
}

/// Whether this process may make a network namespace (root, or user namespaces allowed).
fn can_isolate() -> bool {
    Command::new("unshare")
        .args(["-n", "true"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

#[test]
fn every_bad_input_is_refused_clearly_without_a_panic() {
    let dir = std::env::temp_dir().join(format!("bad-input-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a scratch folder");
    let coordinator = workspace_bin("coordinator", "coordinator");
    let example = Command::new(&coordinator)
        .arg("config-example")
        .output()
        .expect("coordinator config-example");
    let example = String::from_utf8(example.stdout).expect("the example is text");
    let cases = cases(&dir, &example);
    assert!(cases.len() >= 80, "{} cases", cases.len());
    let mut failures = Vec::new();
    let mut exes: std::collections::HashMap<&str, PathBuf> = Default::default();
    let isolate = can_isolate();
    let mut skipped = 0;
    for c in &cases {
        if c.offline && !isolate {
            skipped += 1;
            continue;
        }
        let exe = exes
            .entry(c.bin)
            .or_insert_with(|| workspace_bin(c.package, c.bin))
            .clone();
        let (code, out) = run(&exe, &c.args, &dir, c.offline);
        let shown = format!("{} {}", c.bin, c.args.join(" "));
        let mut wrong = Vec::new();
        match code {
            None => wrong.push(format!("still running after {} s", LIMIT.as_secs())),
            Some(0) => wrong.push("accepted (exit 0)".to_string()),
            Some(101) => wrong.push("exit 101 (a panic)".to_string()),
            Some(_) => {}
        }
        if out.contains("panicked") || out.contains("RUST_BACKTRACE") {
            wrong.push("panicked".into());
        }
        for e in &c.expect {
            if !out.contains(e) {
                wrong.push(format!("does not say `{e}`"));
            }
        }
        // Debug text is not for users.
        for debug in ["Some(", "None", "Err(", "Ok(", " { .. }"] {
            if out.contains(debug) {
                wrong.push(format!("shows Rust debug text `{debug}`"));
            }
        }
        if !wrong.is_empty() {
            failures.push(format!("{shown}\n  {}\n  output:\n{out}", wrong.join("; ")));
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        failures.is_empty(),
        "{} of {} bad inputs were not refused clearly:\n\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n")
    );
    if skipped > 0 {
        println!(
            "SKIPPED: {skipped} case(s) that resolve a host name: `unshare -n` cannot make a \
             network namespace here (needs root), and the resolver's query must not leave the \
             machine"
        );
        assert!(
            std::env::var("MOTION_REQUIRE_ALL").as_deref() != Ok("1"),
            "cannot make a network namespace and MOTION_REQUIRE_ALL=1"
        );
    }
    println!("{} bad inputs, each refused clearly", cases.len() - skipped);
}
