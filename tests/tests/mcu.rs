//! The core on a microcontroller: the `mcu/` RTIC application, built for `thumbv7m-none-eabi`
//! and run on QEMU's `mps2-an385` (Cortex-M3), computes the same cycles as the host, bit for
//! bit. Both run the `mcu-scenario` crate (the machine, the script, the drives' side, the
//! hash); this test compares every cycle's hash and frames and reports the first that differs.
//!
//! Skips with a notice where `qemu-system-arm` or the `thumbv7m-none-eabi` target is missing,
//! unless `MOTION_REQUIRE_ALL=1` (CI: `.ci/run` installs both). Timing is never asserted.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

/// QEMU's run of the whole scenario takes about a second; this bounds a hung run.
const QEMU_TIMEOUT: Duration = Duration::from_secs(300);

fn skip_or_fail(why: &str) {
    integration_tests::skip_or_fail(
        "the_microcontroller_computes_the_same_cycles_as_the_host",
        &format!("{why} (.ci/run installs it)"),
    );
}

fn workspace() -> PathBuf {
    integration_tests::repo_root()
}

/// Whether rustc has the standard library for `thumbv7m-none-eabi`.
fn have_target() -> bool {
    let Ok(out) = Command::new("rustc")
        .args(["--print", "target-libdir", "--target", "thumbv7m-none-eabi"])
        .output()
    else {
        return false;
    };
    let dir = String::from_utf8_lossy(&out.stdout).trim().to_string();
    out.status.success()
        && std::fs::read_dir(&dir).is_ok_and(|mut d| {
            d.any(|e| e.is_ok_and(|e| e.file_name().to_string_lossy().starts_with("libcore-")))
        })
}

/// One cycle's line: its number, its hash, its frames as printed.
#[derive(PartialEq, Eq)]
struct Line {
    cycle: u64,
    hash: u64,
    frames: String,
}

impl std::fmt::Display for Line {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "C {} {:016x} {}", self.cycle, self.hash, self.frames)
    }
}

/// The `C` lines of the application's output, or the line that could not be read.
fn parse(output: &str) -> Result<Vec<Line>, String> {
    let mut lines = Vec::new();
    for l in output.lines().filter(|l| l.starts_with("C ")) {
        let mut parts = l.splitn(4, ' ').skip(1);
        let cycle = parts.next().and_then(|c| c.parse().ok());
        let hash = parts.next().and_then(|h| u64::from_str_radix(h, 16).ok());
        let (Some(cycle), Some(hash)) = (cycle, hash) else {
            return Err(format!("unreadable line: {l}"));
        };
        let frames = parts.next().unwrap_or("").to_string();
        lines.push(Line {
            cycle,
            hash,
            frames,
        });
    }
    Ok(lines)
}

/// The host's run of the same scenario, printed the same way.
fn host() -> (Vec<Line>, &'static str) {
    let table = mcu_scenario::controller::record_table();
    let mut lines = Vec::new();
    let phase = mcu_scenario::run(&table, &mut |cycle, hash, frames| {
        let frames = frames
            .iter()
            .map(|f| f.frame.to_string())
            .collect::<Vec<_>>()
            .join(" ");
        lines.push(Line {
            cycle,
            hash,
            frames,
        });
    });
    let end = match phase {
        mcu_scenario::controller::Phase::Done => "reached",
        mcu_scenario::controller::Phase::Failed(f) => f.text(),
        p => p.name(),
    };
    (lines, end)
}

/// Builds the application; its path.
fn build() -> PathBuf {
    // Its own target folder: the outer `cargo test` holds the workspace target's lock.
    let target = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .parent()
        .expect("the tmp folder is in the target folder")
        .join("mcu");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .args(["build", "--release", "--locked"])
        .current_dir(workspace().join("mcu"))
        .env("CARGO_TARGET_DIR", &target)
        .output()
        .expect("cargo starts");
    assert!(
        out.status.success(),
        "building mcu/ failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    target.join("thumbv7m-none-eabi/release/mcu")
}

/// Runs the application on QEMU as mcu/.cargo/config.toml's runner does; its standard output.
fn run(elf: &Path) -> String {
    let ended = integration_tests::run_to_end(
        Command::new("qemu-system-arm")
            .args([
                "-cpu",
                "cortex-m3",
                "-machine",
                "mps2-an385",
                "-nographic",
                "-icount",
                "shift=0,sleep=off",
                "-semihosting-config",
                "enable=on,target=native",
                "-kernel",
            ])
            .arg(elf),
        QEMU_TIMEOUT,
    );
    let (out, err) = (ended.stdout, ended.stderr);
    match ended.status {
        Some(s) if s.success() => out,
        Some(s) => panic!("QEMU exited with {s}:\n{out}{err}"),
        None => panic!("QEMU did not end within {QEMU_TIMEOUT:?}:\n{out}{err}"),
    }
}

#[test]
fn the_microcontroller_computes_the_same_cycles_as_the_host() {
    if Command::new("qemu-system-arm")
        .arg("--version")
        .output()
        .is_err()
    {
        skip_or_fail("qemu-system-arm is not installed");
        return;
    }
    if !have_target() {
        skip_or_fail("the thumbv7m-none-eabi target is not installed");
        return;
    }
    let elf = build();
    let output = run(&elf);
    // The whole output on failure: the lines before a difference say how it came about.
    let keep = Path::new(env!("CARGO_TARGET_TMPDIR")).join("mcu-qemu.txt");
    let _ = std::fs::write(&keep, &output);
    let mcu = parse(&output).unwrap_or_else(|e| panic!("{e}\n(output in {})", keep.display()));
    let (host, host_end) = host();
    assert_eq!(host_end, "reached", "the host's run did not reach the end");
    let done = output
        .lines()
        .find(|l| l.starts_with("DONE "))
        .unwrap_or("no DONE line");
    assert_eq!(
        done,
        "DONE reached",
        "the application did not reach the end (output in {})",
        keep.display()
    );
    for (i, (m, h)) in mcu.iter().zip(&host).enumerate() {
        assert!(
            m == h,
            "cycle {i} differs (output in {}):\n  mcu:  {m}\n  host: {h}",
            keep.display()
        );
    }
    assert_eq!(
        mcu.len(),
        host.len(),
        "the application ran {} cycles, the host {} (output in {})",
        mcu.len(),
        host.len(),
        keep.display()
    );
    // The figures, for docs/performance.md; nothing is asserted about them.
    for l in output.lines().filter(|l| l.starts_with("M ")) {
        let _ = writeln!(std::io::stderr(), "{l}");
    }
}
