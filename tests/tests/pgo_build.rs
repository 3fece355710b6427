//! `scripts/pgo-build`, the optional build trained on typical runs: what it says about this
//! machine (`--check`) and how it refuses a wrong option. The build itself (two release builds
//! and the training runs, minutes) is not run here; docs/performance.md has its figures.
//!
//! The script needs llvm-profdata of rustc's own LLVM (`rustup component add llvm-tools`):
//! where it is missing the test checks the refusal instead and says SKIPPED; with
//! `MOTION_REQUIRE_ALL=1` (`.ci/run`, which installs the component) a missing one fails.

use std::path::PathBuf;
use std::process::{Command, Output};

use integration_tests::skip_or_fail;

fn script() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scripts/pgo-build")
}

fn run(args: &[&str]) -> Output {
    Command::new("bash")
        .arg(script())
        .args(args)
        .output()
        .expect("bash runs scripts/pgo-build")
}

fn text(o: &Output) -> String {
    format!(
        "exit {:?}\nstdout:\n{}\nstderr:\n{}",
        o.status.code(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// rustc's own llvm-profdata, where the script looks for it.
fn profdata() -> PathBuf {
    let out = |args: &[&str]| {
        let o = Command::new("rustc")
            .args(args)
            .output()
            .expect("rustc runs");
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    let host = out(&["-vV"])
        .lines()
        .find_map(|l| l.strip_prefix("host: ").map(str::to_owned))
        .expect("rustc -vV names the host");
    PathBuf::from(out(&["--print", "sysroot"]).trim())
        .join("lib/rustlib")
        .join(host)
        .join("bin/llvm-profdata")
}

#[test]
fn the_check_names_the_tool_it_found_or_how_to_install_it() {
    let o = run(&["--check"]);
    let t = text(&o);
    if profdata().exists() {
        assert_eq!(o.status.code(), Some(0), "{t}");
        let out = String::from_utf8_lossy(&o.stdout);
        assert!(out.contains("can build here"), "{t}");
        assert!(
            out.contains(&profdata().display().to_string()),
            "the check names the llvm-profdata it found\n{t}"
        );
    } else {
        skip_or_fail(
            "the found path of scripts/pgo-build --check",
            "llvm-profdata (rustup component llvm-tools) is not installed; checked the refusal",
        );
        assert_eq!(o.status.code(), Some(1), "{t}");
        assert!(
            String::from_utf8_lossy(&o.stderr).contains("rustup component add llvm-tools"),
            "the refusal says how to install the tool\n{t}"
        );
    }
}

#[test]
fn an_unknown_option_is_refused_naming_it_and_what_is_allowed() {
    if !profdata().exists() {
        // The tool is looked for first; its refusal is the other test's.
        skip_or_fail(
            "an_unknown_option_is_refused_naming_it_and_what_is_allowed",
            "llvm-profdata (rustup component llvm-tools) is not installed",
        );
        return;
    }
    let o = run(&["--fast"]);
    let t = text(&o);
    assert_eq!(o.status.code(), Some(2), "{t}");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("'--fast'"), "{t}");
    assert!(err.contains("--check"), "{t}");
}
