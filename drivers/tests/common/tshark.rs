//! Whether tshark can be run, for the tests that decode captures with it (included with
//! `#[path]` by each such test file).

use std::io::Write as _;
use std::process::Command;

/// True if `tshark` runs. Otherwise fails when `MOTION_REQUIRE_ALL=1` (CI, whose `.ci/run`
/// installs tshark), else says on stderr that `test` is skipped and returns false.
pub fn tshark_or_skip(test: &str) -> bool {
    if Command::new("tshark").arg("-v").output().is_ok() {
        return true;
    }
    assert!(
        std::env::var("MOTION_REQUIRE_ALL").as_deref() != Ok("1"),
        "tshark is not installed and MOTION_REQUIRE_ALL=1"
    );
    let _ = writeln!(
        std::io::stderr(),
        "SKIPPED {test}: tshark is not installed (.ci/run installs it)"
    );
    false
}

/// The `fields` tshark reads from the capture `bytes` (written to a temporary file named after
/// `name` and removed again), a line per packet, fields separated by `;`; `options` come first
/// (how to decode). Fails the test, with tshark's message, when tshark fails.
pub fn fields(name: &str, bytes: &[u8], options: &[&str], fields: &[&str]) -> String {
    let path = std::env::temp_dir().join(format!("{name}_{}.pcap", std::process::id()));
    std::fs::write(&path, bytes).unwrap();
    let mut cmd = Command::new("tshark");
    cmd.args(options)
        .arg("-r")
        .arg(&path)
        .args(["-T", "fields", "-E", "separator=;"]);
    for f in fields {
        cmd.args(["-e", f]);
    }
    let out = cmd.output().unwrap();
    let _ = std::fs::remove_file(&path);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}
