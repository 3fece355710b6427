#![no_main]
//! The cansend / candump text notation of a frame: parsing never panics, and whatever parses
//! prints back to text that parses to the same frame.

use drivers::can::Frame;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(s) = core::str::from_utf8(data) {
        if let Ok(f) = s.parse::<Frame>() {
            let again: Frame = f.to_string().parse().expect("printed frame parses");
            assert_eq!(again, f);
        }
    }
});
