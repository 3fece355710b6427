//! What the tests that start `timing publish` need: the coordinator binary beside `timing`, and
//! whether iceoryx2's shared memory works here at all.

use std::path::{Path, PathBuf};

use serde_json::Value;

/// Builds the coordinator's binaries (coordinator, drive-sim) into the target folder `timing` runs from (`timing publish`
/// looks for it there), with the test's profile; a no-op when it is fresh.
#[allow(dead_code)] // not every test binary that includes this module uses each helper
pub fn build_coordinator() -> PathBuf {
    let timing = PathBuf::from(env!("CARGO_BIN_EXE_timing"));
    let dir = timing.parent().expect("target/<profile>").to_path_buf();
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut cmd = std::process::Command::new(cargo);
    cmd.args(["build", "-q", "-p", "coordinator", "--bins"]);
    if dir.file_name().is_some_and(|d| d == "release") {
        cmd.arg("--release");
    }
    let ok = cmd.status().expect("cargo runs");
    assert!(ok.success(), "building the coordinator binary");
    dir.join("coordinator")
}

/// Why iceoryx2's shared memory cannot be used here (no /dev/shm, no permission), if it
/// cannot: a service is created and dropped under a unique name.
#[allow(dead_code)] // as above
pub fn shm_unusable() -> Option<String> {
    let node = match shm_api::create_node() {
        Ok(n) => n,
        Err(e) => return Some(e.to_string()),
    };
    // Unique per call: the tests of one binary probe at the same time.
    static N: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    let n = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let name = format!("timing-test-probe-{}-{n}", std::process::id());
    let name: iceoryx2::prelude::ServiceName = match name.as_str().try_into() {
        Ok(n) => n,
        Err(e) => return Some(shm_api::words(e)),
    };
    let service = node
        .service_builder(&name)
        .publish_subscribe::<u64>()
        .create();
    match service {
        Ok(s) => match s.publisher_builder().create() {
            Ok(_) => None,
            Err(e) => Some(shm_api::words(e)),
        },
        Err(e) => Some(shm_api::words(e)),
    }
}

/// A figure of a series in a run of `summary.json`.
#[allow(dead_code)] // not every test binary that includes this module reads figures
pub fn figure(run: &Value, series: &str, f: &str) -> u64 {
    run["series"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["name"] == series)
        .unwrap_or_else(|| panic!("no series {series}"))["figures"][f]
        .as_u64()
        .unwrap()
}

/// The names of a run's series in `summary.json`, in order.
#[allow(dead_code)] // as above
pub fn series_names(run: &Value) -> Vec<&str> {
    run["series"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x["name"].as_str().unwrap())
        .collect()
}

/// Samples in a series' `.hdr` file and in its timeline.
#[allow(dead_code)] // as above
pub fn samples_in_files(dir: &Path, file: &str) -> (u64, u64) {
    let bytes = std::fs::read(dir.join(format!("{file}.hdr"))).unwrap();
    let h: hdrhistogram::Histogram<u64> = hdrhistogram::serialization::Deserializer::new()
        .deserialize(&mut bytes.as_slice())
        .unwrap();
    let csv = std::fs::read_to_string(dir.join(format!("{file}.timeline.csv"))).unwrap();
    let timeline: u64 = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(1).unwrap().parse::<u64>().unwrap())
        .sum();
    (h.len(), timeline)
}
