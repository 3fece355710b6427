#![no_main]
//! The CMMO-ST's Modbus TCP side: a byte stream of any content through the deframer and the
//! session, with the simulated drive behind it. No panic; every answer is a well-formed ADU.

use core::time::Duration;
use drivers::sim::cmmo_st::mbap::{Deframer, MAX_ADU, MbapHeader};
use drivers::sim::cmmo_st::{Config, Session, drive};
use drivers::time::Instant;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(mut dev) = drive::new_drive() else { return };
    let Ok(mut session) = Session::new(Config::default()) else { return };
    let mut now = Instant::ZERO;
    session.connect(&mut dev, now);
    let mut deframer = Deframer::new();
    let mut adu = [0u8; MAX_ADU];
    let mut out = [0u8; MAX_ADU];
    for chunk in data.chunks(7) {
        now += Duration::from_millis(1);
        let mut rest = chunk;
        while !rest.is_empty() {
            let n = deframer.push(rest);
            rest = &rest[n..];
            loop {
                match deframer.next_frame(&mut adu) {
                    Ok(Some(len)) => {
                        if let Ok(Some(n)) = session.handle_frame(&adu[..len], &mut dev, now, &mut out) {
                            let h = MbapHeader::from_bytes(&out[..n]).expect("own header decodes");
                            assert_eq!(h.pdu_len().expect("own length is sane") + 7, n);
                        }
                    }
                    Ok(None) => break,
                    Err(_) => {
                        deframer.clear();
                        break;
                    }
                }
            }
            if n == 0 {
                deframer.clear();
            }
        }
    }
});
