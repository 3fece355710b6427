#![no_main]
//! The machine configuration: arbitrary text parses or is refused with an error naming the line;
//! what parses is checked (every refusal names its key) and, when accepted, planned. Nothing
//! panics. (`Config::check` does no I/O: host names are resolved only by `coordinator check`.)

use coordinator::config::Config;
use coordinator::runtime::plan::plan;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = core::str::from_utf8(data) else { return };
    let Ok(config) = Config::parse(text) else { return };
    let report = config.check();
    for e in &report.errors {
        assert!(!e.key.is_empty(), "a refusal without its key: {e}");
    }
    let accepted = report.is_ok();
    let _ = report.to_string();
    if accepted {
        plan(&config).expect("an accepted configuration plans");
    }
});
