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
