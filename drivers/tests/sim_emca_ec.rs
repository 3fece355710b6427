//! The simulated EMCA-EC against a real EtherCAT master, ethercrab 0.7, in one process: the
//! master's frames go straight through the simulated segment (no socket), so what is checked
//! is the subdevice's behaviour as ethercrab's start-up, CoE and cyclic exchange see it
//! (digest `ethercat-digest.md`; ethercrab's own sequence in its `maindevice.rs`,
//! `subdevice/configuration.rs`, `subdevice_group/mod.rs`). Across processes, on a veth pair,
//! is the coordinator's test.

#[path = "common/tshark.rs"]
mod tshark;
use std::future::Future;
use std::pin::pin;
use std::task::{Context, Poll, Waker};
use std::time::Duration;
use tshark::tshark_or_skip;

use drivers::ethercat::esm::{AlState, AlStatusCode};
use drivers::ethercat::segment::{self, Subdevice};
use drivers::sim::emca_ec::EmcaEc;
use drivers::time::monotonic_now;
use ethercrab::error::{CoeAbortCode, Error, MailboxError};
use ethercrab::std::ethercat_now;
use ethercrab::subdevice_group::{Op, PreOp, SubDeviceGroup};
use ethercrab::{
    AlStatusCode as EcAlStatusCode, MainDevice, MainDeviceConfig, PduRx, PduStorage, PduTx,
    SubDeviceState, Timeouts,
};

const MAX_SD: usize = 4;
/// ethercrab's groups in their states (its default lock, no distributed clocks).
type PreOpGroup = SubDeviceGroup<MAX_SD, PDI, ethercrab::DefaultLock, PreOp>;
type OpGroup = SubDeviceGroup<MAX_SD, PDI, ethercrab::DefaultLock, Op>;
const PDI: usize = 256;
const FRAMES: usize = 16;
const DATA: usize = PduStorage::element_size(1100);

/// FHPP control bytes (seed-002 §2): CCON ENABLE | STOP (not stopped) | LOCK, CPOS HALT (not
/// halted), and HOM (start homing) / START.
const CCON: u8 = 0x23;
const CCON_DIRECT: u8 = 0x63;
const CPOS_RUN: u8 = 0x01;
const CPOS_HOME: u8 = 0x05;
const CPOS_START: u8 = 0x03;
/// Status: SCON enabled (ENABLED | OPEN | VLOAD), SPOS ACK and MC.
const SCON_READY: u8 = 0x13;
const SPOS_ACK: u8 = 0x02;
const SPOS_MC: u8 = 0x04;

/// The master and the segment it talks to, pumped by hand.
struct Rig {
    md: &'static MainDevice<'static>,
    tx: PduTx<'static>,
    rx: PduRx<'static>,
    subs: Vec<EmcaEc>,
}

impl Rig {
    fn new(n: u8) -> Rig {
        let storage: &'static PduStorage<FRAMES, DATA> = Box::leak(Box::new(PduStorage::new()));
        let (tx, rx, pdu_loop) = storage.try_split().expect("a fresh storage splits");
        let md = Box::leak(Box::new(MainDevice::new(
            pdu_loop,
            Timeouts::default(),
            // No static drift compensation: 10 000 frames that prove nothing about the drive.
            MainDeviceConfig {
                dc_static_sync_iterations: 0,
                ..MainDeviceConfig::default()
            },
        )));
        let now = monotonic_now();
        let subs = (0..n)
            .map(|i| EmcaEc::with_config(EmcaEc::drive_config(), i + 1 < n, now).unwrap())
            .collect();
        Rig { md, tx, rx, subs }
    }

    /// Runs a master future to its end, passing every frame it sends through the segment.
    fn run<T>(&mut self, fut: impl Future<Output = T>) -> T {
        let mut fut = pin!(fut);
        let mut cx = Context::from_waker(Waker::noop());
        loop {
            if let Poll::Ready(r) = fut.as_mut().poll(&mut cx) {
                return r;
            }
            let mut sent = false;
            while let Some(frame) = self.tx.next_sendable_frame() {
                let mut bytes = Vec::new();
                frame
                    .send_blocking(|b| {
                        bytes.extend_from_slice(b);
                        Ok(b.len())
                    })
                    .expect("the frame is taken");
                segment::pass(&mut bytes, &mut self.subs, monotonic_now())
                    .expect("the master's frame is EtherCAT datagrams");
                self.rx
                    .receive_frame(&bytes)
                    .expect("ethercrab takes the reply");
                sent = true;
            }
            if !sent {
                let now = monotonic_now();
                for s in self.subs.iter_mut() {
                    s.poll(now);
                }
                std::thread::sleep(Duration::from_micros(50));
            }
        }
    }

    /// Boots the segment to PreOp.
    fn init(&mut self) -> PreOpGroup {
        let md = self.md;
        self.run(md.init_single_group::<MAX_SD, PDI>(ethercat_now))
            .expect("ethercrab boots the segment to PreOp")
    }

    /// PreOp to Op: PDO configuration over CoE, SafeOp, then Op once outputs flowed.
    fn bring_to_op(&mut self, group: PreOpGroup) -> OpGroup {
        let md = self.md;
        let group = self.run(group.into_safe_op(md)).expect("SafeOp");
        // SafeOp -> Op needs valid outputs (0019h otherwise): exchange process data in SafeOp
        // first, then request Op and keep it flowing. ethercrab's `into_op` does neither.
        for _ in 0..3 {
            self.run(group.tx_rx(md)).expect("cycle in SafeOp");
        }
        let group = self.run(group.request_into_op(md)).expect("Op requested");
        for _ in 0..200 {
            let r = self.run(group.tx_rx(md)).expect("cycle");
            if r.all_op() {
                return group;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        panic!("the segment did not reach Op: {:?}", self.states());
    }

    /// `n` subdevices booted to Op and their drives enabled over the process data.
    fn enabled(n: u8) -> (Rig, OpGroup) {
        let mut rig = Rig::new(n);
        let group = rig.init();
        let group = rig.bring_to_op(group);
        rig.until(
            &group,
            [CCON, CPOS_RUN, 0, 0, 0, 0, 0, 0],
            "enabled",
            100,
            |s| s[0] == SCON_READY,
        );
        (rig, group)
    }

    fn states(&self) -> Vec<(AlState, Option<AlStatusCode>)> {
        self.subs.iter().map(|s| (s.state(), s.error())).collect()
    }

    /// One cycle with `outputs` (8 FHPP bytes) for every subdevice; returns the WKC and each
    /// subdevice's 8 status bytes.
    fn cycle(&mut self, group: &OpGroup, outputs: [u8; 8]) -> (u16, Vec<[u8; 8]>) {
        let md = self.md;
        for sd in group.iter(md) {
            let mut o = sd.outputs_raw_mut();
            o[..8].copy_from_slice(&outputs);
        }
        let r = self.run(group.tx_rx(md)).expect("cycle");
        let inputs = group
            .iter(md)
            .map(|sd| {
                let i = sd.inputs_raw();
                let mut b = [0u8; 8];
                b.copy_from_slice(&i[..8]);
                b
            })
            .collect();
        std::thread::sleep(Duration::from_millis(1));
        (r.working_counter, inputs)
    }

    /// Cycles until every subdevice's status satisfies `done`; panics after `limit` cycles.
    fn until(
        &mut self,
        group: &OpGroup,
        outputs: [u8; 8],
        what: &str,
        limit: usize,
        done: impl Fn(&[u8; 8]) -> bool,
    ) -> Vec<[u8; 8]> {
        for _ in 0..limit {
            let (_, s) = self.cycle(group, outputs);
            if s.iter().all(&done) {
                return s;
            }
        }
        let (_, s) = self.cycle(group, outputs);
        panic!("{what}: not reached in {limit} cycles; status bytes {s:02X?}");
    }
}

#[test]
fn ethercrab_boots_three_emcas_reads_their_identity_and_objects_and_reaches_op() {
    let mut rig = Rig::new(3);
    let group = rig.init();
    let md = rig.md;
    assert_eq!(group.len(), 3);
    for (i, sd) in group.iter(md).enumerate() {
        assert_eq!(sd.configured_address(), 0x1000 + i as u16);
        let id = sd.identity();
        assert_eq!(id.vendor_id, drivers::catalog::FESTO_VENDOR_ID);
        assert_eq!(id.product_id, drivers::catalog::EMCA_ETHERCAT.product_code);
        assert_eq!(id.revision, drivers::catalog::EMCA_ETHERCAT.revision);
        assert_eq!(sd.name(), drivers::catalog::EMCA_ETHERCAT.name);
    }
    assert!(rig.states().iter().all(|s| *s == (AlState::PreOp, None)));

    // CoE in PreOp: device type, the minimum cycle, the name as a string, a parameter (PNU
    // 100, firmware version), a read-only object refused with its abort code.
    let sd = group.subdevice(md, 1).unwrap();
    let device_type: u32 = rig.run(sd.sdo_read(0x1000, 0)).unwrap();
    assert_eq!(device_type, 0x0000_012D);
    let min_cycle: u32 = rig.run(sd.sdo_read(0x1C32, 5)).unwrap();
    assert_eq!(min_cycle, drivers::catalog::EMCA_ETHERCAT.min_cycle_ns);
    // A normal (not expedited) upload: 19 bytes in one mailbox.
    let name: [u8; 19] = rig.run(sd.sdo_read(0x1008, 0)).unwrap();
    assert_eq!(&name, drivers::catalog::EMCA_ETHERCAT.name.as_bytes());
    rig.run(sd.sdo_write(0x1C32, 1, 1u16))
        .expect("SM-synchronous is offered");
    let mode: u16 = rig.run(sd.sdo_read(0x1C32, 1)).unwrap();
    assert_eq!(mode, 1);
    match rig.run(sd.sdo_write(0x1C32, 2, 500_000u32)) {
        Err(Error::Mailbox(MailboxError::Aborted { code, .. })) => {
            assert_eq!(code, CoeAbortCode::ReadOnlyWrite)
        }
        other => panic!("a write of 1C32h:02 must abort as read only: {other:?}"),
    }

    let group = rig.bring_to_op(group);
    assert!(rig.states().iter().all(|s| *s == (AlState::Op, None)));
    // One LRW: each EMCA reads (+1) and writes (+2) through its FMMUs.
    let (wkc, status) = rig.cycle(&group, [0; 8]);
    assert_eq!(wkc, 9);
    // Power-up image: SCON VLOAD, SPOS HALT (seed-002 §2.4).
    assert!(
        status.iter().all(|s| s[..2] == [0x10, 0x04]),
        "{status:02X?}"
    );
    for sd in group.iter(md) {
        assert_eq!(sd.inputs_raw().len(), 32);
        assert_eq!(sd.outputs_raw().len(), 32);
    }
}

#[test]
fn three_emcas_enable_home_and_move_together_and_a_dropped_one_takes_the_rest_off_the_line() {
    let (mut rig, group) = Rig::enabled(3);
    rig.until(
        &group,
        [CCON, CPOS_HOME, 0, 0, 0, 0, 0, 0],
        "homing ACK",
        100,
        |s| s[1] & SPOS_ACK != 0,
    );
    rig.until(
        &group,
        [CCON, CPOS_RUN, 0, 0, 0, 0, 0, 0],
        "homed",
        5_000,
        |s| s[1] & SPOS_MC != 0 && s[1] & 0x80 != 0,
    );
    // A direct move of all three to 15000 increments at 50 % speed, in one frame.
    let target = 15_000i32.to_le_bytes();
    let direct = |cpos| {
        [
            CCON_DIRECT,
            cpos,
            0,
            50,
            target[0],
            target[1],
            target[2],
            target[3],
        ]
    };
    rig.until(&group, direct(CPOS_START), "start ACK", 100, |s| {
        s[1] & SPOS_ACK != 0
    });
    let pos = |s: &[u8; 8]| i32::from_le_bytes([s[4], s[5], s[6], s[7]]);
    let done = rig.until(&group, direct(CPOS_RUN), "at the target", 5_000, |s| {
        s[1] & SPOS_MC != 0 && (pos(s) - 15_000).abs() <= 100
    });
    assert_eq!(done.len(), 3);

    // The second subdevice loses power: the first sees no link on its port 1 and sends the
    // frame back, so the LRW counts one subdevice.
    rig.subs[1].power_off();
    let (wkc, _) = rig.cycle(&group, direct(CPOS_RUN));
    assert_eq!(wkc, 3);
    let md = rig.md;
    let r = rig.run(group.tx_rx(md)).unwrap();
    assert_eq!(
        &r.subdevice_states[..],
        &[
            SubDeviceState::Op,
            SubDeviceState::None,
            SubDeviceState::None
        ]
    );
    // Back on: a fresh drive in Init; the two behind it are reachable again, still in Op.
    rig.subs[1].power_on(monotonic_now()).unwrap();
    let (wkc, _) = rig.cycle(&group, direct(CPOS_RUN));
    assert_eq!(
        wkc, 6,
        "the restarted one has no FMMUs yet, so it adds nothing"
    );
    assert_eq!(rig.subs[1].state(), AlState::Init);
    assert_eq!(rig.subs[2].state(), AlState::Op);
}

#[test]
fn outputs_that_stop_trip_the_sm_watchdog_and_the_drive_faults_with_50h() {
    let (mut rig, group) = Rig::enabled(1);
    // No frame for 150 ms (the SM watchdog is 100 ms): the drive's clock runs on.
    let until = monotonic_now() + Duration::from_millis(150);
    while monotonic_now() < until {
        rig.subs[0].poll(monotonic_now());
        std::thread::sleep(Duration::from_millis(1));
    }
    assert_eq!(
        rig.states(),
        vec![(AlState::SafeOp, Some(AlStatusCode::SM_WATCHDOG))]
    );
    let md = rig.md;
    let sd = group.subdevice(md, 0).unwrap();
    // ethercrab reports the error flag as an error carrying AL status code 001Bh.
    match rig.run(sd.status()) {
        Err(Error::SubDevice(code)) => assert_eq!(code, EcAlStatusCode::SyncManagerWatchdog),
        other => panic!("ethercrab must see the watchdog's AL status code: {other:?}"),
    }
    // The drive reacted: fault 50h (EtherCAT connection lost with master control).
    assert_eq!(rig.subs[0].drive().fault_number(), Some(0x50));
    // SCON.FAULT in the inputs, which SafeOp still updates.
    let (_, s) = rig.cycle(&group, [CCON, CPOS_RUN, 0, 0, 0, 0, 0, 0]);
    assert_ne!(s[0][0] & 0x08, 0, "{:02X?}", s[0]);
    // Up again only after the acknowledge (SafeOp | 10h), then Op with outputs flowing.
    let _: u16 = rig.run(sd.register_write(0x0120u16, 0x0008u16)).unwrap();
    rig.cycle(&group, [CCON, CPOS_RUN, 0, 0, 0, 0, 0, 0]);
    assert_eq!(
        rig.subs[0].state(),
        AlState::SafeOp,
        "no acknowledge, no Op"
    );
    let _: u16 = rig.run(sd.register_write(0x0120u16, 0x0014u16)).unwrap();
    assert_eq!(rig.states(), vec![(AlState::SafeOp, None)]);
    let _: u16 = rig.run(sd.register_write(0x0120u16, 0x0008u16)).unwrap();
    rig.cycle(&group, [CCON, CPOS_RUN, 0, 0, 0, 0, 0, 0]);
    assert_eq!(rig.states(), vec![(AlState::Op, None)]);
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]
    /// Whatever datagrams a master sends (any command, address, length, data, including SM and
    /// FMMU set-ups pointing anywhere and AL control values of every kind), the segment answers
    /// without panicking and the reply keeps the frame's length.
    #[test]
    fn any_datagrams_are_answered_without_a_panic(
        frames in proptest::collection::vec(
            proptest::collection::vec(
                (0u8..16, proptest::prelude::any::<u32>(), proptest::collection::vec(proptest::prelude::any::<u8>(), 0..48)),
                1..6,
            ),
            1..40,
        )
    ) {
        use drivers::ethercat::frame::{Command, FrameBuilder};
        let now = drivers::time::Instant::ZERO;
        let mut subs: Vec<EmcaEc> = (0..2).map(|i| EmcaEc::with_config(
            EmcaEc::drive_config(), i == 0, now).unwrap()).collect();
        for (k, datagrams) in frames.iter().enumerate() {
            let mut buf = [0u8; 1514];
            let mut b = FrameBuilder::new(&mut buf, [0x10; 6]).unwrap();
            for (cmd, address, data) in datagrams {
                // Mostly registers and process RAM (ADO below 2000h), some anywhere.
                let address = if address % 4 == 0 { *address } else { address & 0x1FFF_FFFF };
                let cmd = Command::from_code(*cmd).unwrap_or(Command::Nop);
                b.push(cmd, 0, address, data).unwrap();
            }
            let n = b.finish();
            let at = drivers::time::Instant::from_micros(100 * k as u64);
            proptest::prop_assert!(segment::pass(&mut buf[..n], &mut subs, at).is_ok());
        }
    }
}

/// A capture of what a master sends and what the segment answers, decoded by tshark as
/// EtherCAT: commands, addresses and working counters as they were on the wire.
#[test]
fn tshark_decodes_a_capture_of_the_segment_as_ethercat() {
    use drivers::ethercat::frame::{Command, FrameBuilder};
    use drivers::ethercat::pcap::EcPcapWriter;
    if !tshark_or_skip("tshark_decodes_a_capture_of_the_segment_as_ethercat") {
        return;
    }
    let now = drivers::time::Instant::ZERO;
    let mut subs: Vec<EmcaEc> = (0..2)
        .map(|i| EmcaEc::with_config(EmcaEc::drive_config(), i == 0, now).unwrap())
        .collect();
    let mut w = EcPcapWriter::new(Vec::new()).unwrap();
    // A BRD of the ESC type (both count), then an APWR of station address 1000h to position 0.
    let frames: [(Command, u32, &[u8]); 2] = [
        (Command::Brd, 0x0000_0000, &[0, 0]),
        (Command::Apwr, 0x0010_0000, &[0x00, 0x10]),
    ];
    for (k, (cmd, address, data)) in frames.iter().enumerate() {
        let mut buf = [0u8; 128];
        let mut b = FrameBuilder::new(&mut buf, [0x10; 6]).unwrap();
        b.push(*cmd, k as u8, *address, data).unwrap();
        let n = b.finish();
        let t = drivers::time::Instant::from_micros(1_000 * (2 * k as u64 + 1));
        w.write(t, &buf[..n]).unwrap();
        segment::pass(&mut buf[..n], &mut subs, t).unwrap();
        w.write(t, &buf[..n]).unwrap();
    }
    let text = tshark::fields(
        "sim_emca_ec",
        &w.into_inner(),
        &[],
        &["ecat.cmd", "ecat.idx", "ecat.cnt", "eth.src"],
    );
    let lines: Vec<Vec<&str>> = text.lines().map(|l| l.split(';').collect()).collect();
    assert_eq!(lines.len(), 4, "{text}");
    // Requests with working counter 0 from the master; replies counted and marked.
    assert_eq!(lines[0][..3], ["0x07", "0x00", "0"], "{text}");
    assert_eq!(lines[1][..3], ["0x07", "0x00", "2"], "{text}");
    assert_eq!(lines[2][..3], ["0x02", "0x01", "0"], "{text}");
    assert_eq!(lines[3][..3], ["0x02", "0x01", "1"], "{text}");
    assert_eq!(lines[0][3], "10:10:10:10:10:10");
    assert_eq!(lines[1][3], "12:10:10:10:10:10");
}
