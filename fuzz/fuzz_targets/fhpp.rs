#![no_main]
//! FHPP and CiA 402 decoders, and a simulated FHPP drive of each variant fed arbitrary control
//! images and parameter requests: no panic, and every image it returns decodes.

use core::time::Duration;
use drivers::cia402::controlword::Controlword;
use drivers::cia402::state::State;
use drivers::cia402::statusword::Statusword;
use drivers::fhpp::control::OutputImage;
use drivers::fhpp::fpc::{Channel, Codec};
use drivers::fhpp::status::InputImage;
use drivers::fhpp::{ByteOrder, Variant};
use drivers::sim::fhpp_drive::{DriveConfig, FhppDrive};
use drivers::time::Instant;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    for order in [ByteOrder::Little, ByteOrder::Big] {
        let _ = OutputImage::from_bytes(data, order);
        for v in [Variant::MtrDci, Variant::Emca, Variant::CmmoSt] {
            let _ = InputImage::from_bytes(data, v, order);
        }
        for ch in [Channel::Classic, Channel::Enhanced] {
            let c = Codec::new(ch, order);
            let _ = c.decode_request(data);
            let _ = c.decode_response(data);
        }
    }
    if let Some(cw) = Controlword::decode(data) {
        let _ = cw.command();
    }
    if let Some(sw) = Statusword::decode(data) {
        let _ = State::from_statusword(sw);
    }
    let Some((&sel, rest)) = data.split_first() else { return };
    let variant = [Variant::MtrDci, Variant::Emca, Variant::CmmoSt][sel as usize % 3];
    let Ok(mut drive) = FhppDrive::new(DriveConfig::new(variant)) else { return };
    let mut now = Instant::ZERO;
    for chunk in rest.chunks(9) {
        now += Duration::from_millis(chunk[0] as u64 % 20);
        let mut img = [0u8; 8];
        img[..chunk.len() - 1].copy_from_slice(&chunk[1..]);
        let out = if chunk[0] & 0x80 != 0 { drive.parameter(&img, now) } else { drive.exchange(&img, now) };
        let _ = out;
        let order = DriveConfig::new(variant).byte_order;
        InputImage::from_bytes(&drive.input(), variant, order).expect("the drive's own image decodes");
    }
});
