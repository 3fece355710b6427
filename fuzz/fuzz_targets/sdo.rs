#![no_main]
//! SDO: the three frame decoders, and a server and a client fed arbitrary frames interleaved
//! with their own traffic and timeouts. No panic; each keeps serving afterwards.

use core::time::Duration;
use drivers::canopen::od::{AccessType, DataType, EntryDef, ObjectDictionary, Value};
use drivers::canopen::sdo::{
    BlockSegment, ClientFrame, DownloadMode, SdoClient, SdoClientConfig, SdoServer, SdoServerConfig,
    ServerFrame,
};
use drivers::canopen::{Address, NodeId};
use drivers::time::Instant;
use libfuzzer_sys::fuzz_target;

static DOMAIN: [u8; 100] = [0x5A; 100];

fuzz_target!(|data: &[u8]| {
    let node = NodeId::new(5).unwrap();
    let mut od: ObjectDictionary<'static, 8, 512> = ObjectDictionary::new();
    let _ = od.insert(EntryDef::new(Address::new(0x2000, 0), "d", DataType::Domain, AccessType::Rw)
        .capacity(200)
        .default_value(Value::Bytes(&DOMAIN)));
    let _ = od.insert(EntryDef::new(Address::new(0x1000, 0), "t", DataType::Unsigned32, AccessType::Ro));
    let mut server: SdoServer<256> = SdoServer::new(node, SdoServerConfig::default());
    let mut client: SdoClient<4, 256> = SdoClient::new(node, SdoClientConfig::default());
    let _ = client.upload(Address::new(0x2000, 0));
    let _ = client.download(Address::new(0x2000, 0), &[1; 50], DownloadMode::Block);
    let mut now = Instant::ZERO;
    for f in drivers_fuzz::frames(data) {
        now += Duration::from_micros(300);
        let _ = ClientFrame::decode(f.data());
        let _ = ServerFrame::decode(f.data());
        let _ = BlockSegment::decode(f.data());
        // Arbitrary frames to both sides, plus their genuine exchange.
        server.handle_frame(&f, now, &mut od);
        client.handle_frame(&f, now);
        while let Some(tx) = client.poll_transmit(now) {
            server.handle_frame(&tx, now, &mut od);
        }
        while let Some(tx) = server.poll_transmit(now) {
            client.handle_frame(&tx, now);
        }
        server.handle_timeout(now);
        client.handle_timeout(now);
        while server.poll_event().is_some() {}
        while client.poll_event().is_some() {}
    }
});
