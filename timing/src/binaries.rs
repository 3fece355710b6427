//! The coordinator's binaries (`coordinator`, `drive-sim`) that `timing publish` and `timing
//! loop` start, found beside the `timing` executable, as `cargo build -p coordinator --bins`
//! puts them.

use std::path::{Path, PathBuf};

/// `name` beside `exe` (or one folder up: a test or an example runs from `deps/` or
/// `examples/`), or an error naming the binary and the cargo command that builds it.
pub fn beside(exe: &Path, name: &str) -> Result<PathBuf, String> {
    let dir = exe
        .parent()
        .ok_or_else(|| format!("{}: no folder", exe.display()))?;
    for d in [dir, dir.parent().unwrap_or(dir)] {
        let p = d.join(name);
        if p.is_file() {
            return Ok(p);
        }
    }
    let release = dir.components().any(|c| c.as_os_str() == "release");
    Err(format!(
        "{name} is not next to this program ({} is missing): build it with `cargo build -p coordinator --bins{}`",
        dir.join(name).display(),
        if release { " --release" } else { "" }
    ))
}

/// `name` beside this executable (see [`beside`]).
pub fn sibling(name: &str) -> Result<PathBuf, String> {
    let exe =
        std::env::current_exe().map_err(|e| format!("cannot find this program's path: {e}"))?;
    beside(&exe, name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_binary_is_named_with_its_build_command() {
        let e = beside(Path::new("/nonexistent/release/timing"), "coordinator").unwrap_err();
        assert!(e.contains("/nonexistent/release/coordinator"), "{e}");
        assert!(
            e.contains("cargo build -p coordinator --bins --release"),
            "{e}"
        );
        let e = beside(Path::new("/nonexistent/debug/deps/x"), "drive-sim").unwrap_err();
        assert!(e.contains("drive-sim is not next to this program"), "{e}");
        assert!(e.ends_with("`cargo build -p coordinator --bins`"), "{e}");
    }
}
