#![no_main]
//! EDS/DCF import: arbitrary text parses or gives a typed error naming the line; what parses
//! loads into a dictionary or is refused with a typed error.

use drivers::canopen::eds::Eds;
use drivers::canopen::od::ObjectDictionary;
use drivers::canopen::NodeId;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = core::str::from_utf8(data) else { return };
    if let Ok(eds) = Eds::parse(text, NodeId::new(3)) {
        let mut od: ObjectDictionary<'_, 64, 4096> = ObjectDictionary::new();
        let _ = eds.load_into(&mut od);
    }
});
