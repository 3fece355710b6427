#![no_main]
//! The command decoder: arbitrary bytes as the contract's `CommandRequest` (every field, as a
//! client process could fill it), decoded as the coordinator's command thread decodes it and,
//! when it decodes, given to the cycle of the embedded machine (axes online, as after boot).
//! Nothing panics; every request gets a reply.

use std::sync::OnceLock;

use coordinator::config::{Config, EXAMPLE};
use coordinator::runtime::plan::{MachinePlan, plan};
use coordinator::runtime::shm::{StaticInfo, to_command, to_reply};
use coordinator::runtime::stepper::Stepper;
use drivers::time::Instant;
use libfuzzer_sys::fuzz_target;
use shm_api::contract::{CommandRequest, MAX_GROUP_AXES};

fn machine() -> &'static (MachinePlan, StaticInfo) {
    static M: OnceLock<(MachinePlan, StaticInfo)> = OnceLock::new();
    M.get_or_init(|| {
        let p = plan(&Config::parse(EXAMPLE).expect("example parses")).expect("example plans");
        let info = StaticInfo::new(&p, true);
        (p, info)
    })
}

/// Reads little-endian integers off the input, zeros past its end.
struct Bytes<'a>(&'a [u8]);

impl Bytes<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut b = [0u8; N];
        let n = N.min(self.0.len());
        b[..n].copy_from_slice(&self.0[..n]);
        self.0 = &self.0[n..];
        b
    }
    fn u8(&mut self) -> u8 {
        self.take::<1>()[0]
    }
    fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.take())
    }
    fn i64(&mut self) -> i64 {
        i64::from_le_bytes(self.take())
    }
}

fn request(b: &mut Bytes<'_>) -> CommandRequest {
    let mut r = CommandRequest {
        tag: 0,
        kind: b.u16() % 32,
        target: b.u8() % 4,
        percent: b.u8(),
        axis: b.u16() % 8,
        group: b.u16() % 8,
        record: b.u16(),
        sub: b.u8(),
        buffer: b.u8() % 3,
        pnu: b.u16(),
        reserved1: 0,
        value: b.i64(),
        positions: [0; MAX_GROUP_AXES],
    };
    for p in r.positions.iter_mut().take(3) {
        *p = b.i64();
    }
    r
}

fuzz_target!(|data: &[u8]| {
    let (plan, info) = machine();
    let mut stepper = Stepper::new(plan).expect("the example's cycle builds");
    for a in 0..plan.axes.len() {
        stepper.cycle.set_online(a as u16, true, Instant::ZERO);
    }
    let mut b = Bytes(data);
    // A few commands in a row: one may set up the state the next is judged in.
    for tag in 0..8u64 {
        if b.0.is_empty() {
            break;
        }
        let mut r = request(&mut b);
        r.tag = tag;
        match to_command(info, &r) {
            Ok(c) => {
                let reply = to_reply(tag, stepper.cycle.command(&c));
                assert_eq!(reply.tag, tag);
            }
            Err(reply) => assert_eq!(reply.tag, tag),
        }
    }
});
