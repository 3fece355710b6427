#![no_main]
//! The coordinator's Modbus TCP client: any bytes from the server, split into frames the way
//! the exchange thread splits its stream, decoded against the outstanding request. No panic; a
//! register answer that is accepted has exactly the quantity asked for.

use drivers::modbus::client::{
    Answer, Client, Expected, Request, Response, decode_response, frame_len,
};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&selector, stream)) = data.split_first() else {
        return;
    };
    // The first byte picks the expectation: FC 0x17 or 0x03 of 1..=8 registers, or FC 0x10.
    let quantity = u16::from(selector & 0x07) + 1;
    let answer = match selector >> 6 {
        0 => Answer::Registers {
            function: 0x17,
            quantity,
        },
        1 => Answer::Registers {
            function: 0x03,
            quantity,
        },
        _ => Answer::Written { start: 0, quantity },
    };
    let expected = Expected {
        transaction_id: u16::from(selector >> 3 & 0x07),
        unit_id: 0,
        answer,
    };
    if let Ok(Response::Registers(b)) = decode_response(stream, &expected) {
        assert_eq!(b.len(), 2 * usize::from(quantity));
    }
    let mut client = Client::new(0);
    let mut out = [0u8; 260];
    let mut rest = stream;
    while let Ok(Some(n)) = frame_len(rest) {
        let (frame, tail) = rest.split_at(n);
        if client.pending().is_none()
            && client
                .request(&Request::image_exchange(&[0; 8]), &mut out)
                .is_err()
        {
            return;
        }
        if let Ok(r) = client.handle_response(frame) {
            assert_eq!(r.image().map(|i| i.len()), Some(8));
        }
        rest = tail;
    }
});
