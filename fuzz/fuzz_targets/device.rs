#![no_main]
//! A whole CiA 301 device and master fed arbitrary frames: NMT, SDO, PDO, SYNC, guarding all
//! at once. No panic, and the device still answers an SDO read of 1000h afterwards.

use core::time::Duration;
use drivers::canopen::device::{insert_communication_objects, CommProfile, Device, NoHooks, PdoDefault};
use drivers::canopen::endpoint::Endpoint;
use drivers::canopen::master::Master;
use drivers::canopen::od::{AccessType, DataType, EntryDef, ObjectDictionary};
use drivers::canopen::{Address, NodeId};
use drivers::can::Frame;
use drivers::time::Instant;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let node = NodeId::new(1).unwrap();
    let mut od: ObjectDictionary<'static, 96, 2048> = ObjectDictionary::new();
    let profile = CommProfile {
        rpdo: [
            PdoDefault { valid: true, transmission: 0, event_ms: 0, mapping: &[0x6040_0010, 0x607A_0020], fixed: false },
            PdoDefault::ABSENT, PdoDefault::ABSENT, PdoDefault::ABSENT,
        ],
        tpdo: [
            PdoDefault { valid: true, transmission: 1, event_ms: 0, mapping: &[0x6041_0010], fixed: false },
            PdoDefault { valid: true, transmission: 255, event_ms: 10, mapping: &[0x6041_0010], fixed: false },
            PdoDefault::ABSENT, PdoDefault::ABSENT,
        ],
        ..CommProfile::basic(0x20192)
    };
    insert_communication_objects(&mut od, node, &profile).unwrap();
    od.insert(EntryDef::new(Address::new(0x6040, 0), "cw", DataType::Unsigned16, AccessType::Rww).mappable()).unwrap();
    od.insert(EntryDef::new(Address::new(0x6041, 0), "sw", DataType::Unsigned16, AccessType::Rwr).mappable()).unwrap();
    od.insert(EntryDef::new(Address::new(0x607A, 0), "tp", DataType::Integer32, AccessType::Rww).mappable()).unwrap();
    let mut dev: Device<'static, 96, 2048, 256, NoHooks> = Device::new(node, od, profile.boot_up, NoHooks);
    let mut master: Master<2, 2, 64> = Master::default();
    let _ = master.add_node(node, drivers::canopen::master::Supervision::Guarding { guard_ms: 5, factor: 2 }, Instant::ZERO);
    dev.power_on(Instant::ZERO);
    let mut now = Instant::ZERO;
    for f in drivers_fuzz::frames(data) {
        now += Duration::from_micros(250);
        dev.handle_frame(&f, now);
        master.handle_frame(&f, now);
        dev.handle_timeout(now);
        master.handle_timeout(now);
        while let Some(tx) = dev.poll_transmit(now) {
            master.handle_frame(&tx, now);
        }
        while let Some(tx) = master.poll_transmit(now) {
            dev.handle_frame(&tx, now);
        }
        while dev.poll_event().is_some() {}
        while master.poll_event().is_some() {}
    }
    // Unless the fuzzer stopped it, the device still answers.
    let state = dev.state();
    now += Duration::from_secs(1);
    dev.handle_timeout(now);
    while dev.poll_transmit(now).is_some() {}
    dev.handle_frame(&Frame::new_std(0x601, &[0x40, 0, 0x10, 0, 0, 0, 0, 0]).unwrap(), now);
    if state != drivers::canopen::nmt::NmtState::Stopped && state != drivers::canopen::nmt::NmtState::Initialising {
        let reply = core::iter::from_fn(|| dev.poll_transmit(now)).find(|f| f.cob_id() == Some(0x581));
        assert!(reply.is_some(), "device stopped answering SDO in state {state:?}");
    }
});
