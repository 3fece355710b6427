//! The PDO engines, sans-I/O: a [`Tpdo`] decides when its data goes on the bus, an [`Rpdo`]
//! latches received data and says when it applies. Both are fed SYNCs, frames and time.
//!
//! They work on either side of the bus: a device runs a `Tpdo` per transmit PDO and an `Rpdo`
//! per receive PDO; the master runs the mirror image (its `Tpdo`s are the drives' RPDOs).

use crate::can::Frame;
use crate::canopen::pdo::comm::{CommParams, TransmissionType};
use crate::canopen::pdo::mapping::{Mapping, PdoError, PdoValues};
use crate::time::Instant;

/// A transmit PDO.
///
/// The application hands it the current data ([`Tpdo::set_values`] or [`Tpdo::set_data`])
/// whenever it may have changed; the engine compares with what it last sent.
///
/// | type | sent |
/// |---|---|
/// | 0 | at a SYNC, if the data differs from the last frame sent |
/// | n = 1..=240 | at the first SYNC (or the first whose counter equals the SYNC start value), then every n-th |
/// | 252 | on RTR, with the data sampled at the last SYNC |
/// | 253 | on RTR, with the current data |
/// | 254, 255 | when the data changed (or was never sent), no sooner than the inhibit time after the last frame; and when the event timer expires |
///
/// Remote requests are answered only for 252/253 and only when the COB-ID allows RTR. A PDO
/// whose COB-ID is invalid (bit 31) sends nothing. A frame made due by a SYNC or an RTR and not
/// yet taken by [`Tpdo::poll_transmit`] is replaced by the next one (the newest data wins).
#[derive(Debug, Clone)]
pub struct Tpdo {
    comm: CommParams,
    mapping: Mapping,
    current: [u8; 8],
    last_sent: Option<[u8; 8]>,
    sampled: Option<[u8; 8]>,
    queued: Option<[u8; 8]>,
    sync_started: bool,
    sync_count: u8,
    last_tx: Option<Instant>,
    event_deadline: Option<Instant>,
}

impl Tpdo {
    /// A TPDO with its parameters and mapping; its data starts as zeros.
    pub fn new(comm: CommParams, mapping: Mapping) -> Tpdo {
        Tpdo {
            comm,
            mapping,
            current: [0; 8],
            last_sent: None,
            sampled: None,
            queued: None,
            sync_started: false,
            sync_count: 0,
            last_tx: None,
            event_deadline: None,
        }
    }

    /// The communication parameters.
    pub fn comm(&self) -> &CommParams {
        &self.comm
    }
    /// The mapping.
    pub fn mapping(&self) -> &Mapping {
        &self.mapping
    }
    /// Replaces the parameters and mapping (after an SDO reconfiguration) and restarts.
    pub fn reconfigure(&mut self, comm: CommParams, mapping: Mapping) {
        self.comm = comm;
        self.mapping = mapping;
        self.reset();
    }
    /// Forgets what was sent, sampled and counted, as on entering Operational: an event-driven
    /// PDO is sent at the next poll, a cyclic one restarts its SYNC count.
    pub fn reset(&mut self) {
        self.last_sent = None;
        self.sampled = None;
        self.queued = None;
        self.sync_started = false;
        self.sync_count = 0;
        self.last_tx = None;
        self.event_deadline = None;
    }

    /// Sets the current data from packed frame bytes (beyond the mapped length they are zero).
    pub fn set_data(&mut self, data: &[u8]) {
        let n = self.mapping.byte_len().min(data.len());
        self.current = [0; 8];
        self.current[..n].copy_from_slice(&data[..n]);
    }
    /// Sets the current data from one value per mapping entry.
    pub fn set_values(&mut self, values: &[u64]) {
        let mut out = [0u8; 8];
        self.mapping.pack(values, &mut out);
        self.current = out;
    }
    /// The current data.
    pub fn data(&self) -> &[u8] {
        &self.current[..self.mapping.byte_len()]
    }

    /// A SYNC was received; `counter` is its counter byte if it carries one.
    pub fn handle_sync(&mut self, counter: Option<u8>, _now: Instant) {
        if !self.comm.cob_id.valid {
            return;
        }
        match self.comm.transmission {
            TransmissionType::SyncAcyclic if self.last_sent != Some(self.current) => {
                self.queued = Some(self.current);
            }
            TransmissionType::SyncCyclic(n) => {
                if !self.sync_started {
                    let start = self.comm.sync_start;
                    if start == 0 || counter.is_none() || counter == Some(start) {
                        self.sync_started = true;
                        self.sync_count = 0;
                        self.queued = Some(self.current);
                    }
                } else {
                    self.sync_count = self.sync_count.saturating_add(1);
                    if self.sync_count >= n {
                        self.sync_count = 0;
                        self.queued = Some(self.current);
                    }
                }
            }
            TransmissionType::SyncRtr => self.sampled = Some(self.current),
            _ => {}
        }
    }

    /// Whether `frame` is on this PDO's identifier while the PDO is valid (a remote request
    /// for it, or another device's frame on the same identifier).
    pub fn accepts(&self, frame: &Frame) -> bool {
        self.comm.cob_id.accepts(frame)
    }

    /// A frame was received; returns whether it was a remote request this PDO answers.
    pub fn handle_frame(&mut self, frame: &Frame, _now: Instant) -> bool {
        let c = &self.comm.cob_id;
        if !c.rtr_allowed || !frame.is_remote() || !self.accepts(frame) {
            return false;
        }
        match self.comm.transmission {
            TransmissionType::SyncRtr => match self.sampled {
                Some(s) => self.queued = Some(s),
                // Nothing sampled yet: no SYNC since the start, nothing valid to send.
                None => return false,
            },
            TransmissionType::AsyncRtr => self.queued = Some(self.current),
            _ => return false,
        }
        true
    }

    fn inhibit_over(&self, now: Instant) -> bool {
        self.last_tx
            .is_none_or(|t| now >= t + self.comm.inhibit_time())
    }

    /// The next frame to send, if one is due at `now`.
    pub fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        if !self.comm.cob_id.valid {
            return None;
        }
        if let Some(d) = self.queued.take() {
            return self.emit(d, now);
        }
        if self.comm.transmission.is_event_driven() {
            let changed = self.last_sent != Some(self.current);
            let timer = self.event_deadline.is_some_and(|d| now >= d);
            if (changed || timer) && self.inhibit_over(now) {
                return self.emit(self.current, now);
            }
        }
        None
    }

    fn emit(&mut self, data: [u8; 8], now: Instant) -> Option<Frame> {
        self.last_sent = Some(data);
        self.last_tx = Some(now);
        self.event_deadline = self.comm.event_timer().map(|p| now + p);
        self.comm
            .cob_id
            .data_frame(&data[..self.mapping.byte_len()])
    }

    /// When [`Tpdo::poll_transmit`] next has something to send without new input: the end of
    /// the inhibit time for changed data, or the event timer. `None` for SYNC and RTR types.
    pub fn poll_timeout(&self) -> Option<Instant> {
        if !self.comm.cob_id.valid || !self.comm.transmission.is_event_driven() {
            return None;
        }
        let mut t = self.event_deadline;
        if self.last_sent != Some(self.current) {
            let ready = self
                .last_tx
                .map_or(Instant::ZERO, |l| l + self.comm.inhibit_time());
            t = Some(t.map_or(ready, |e| e.min(ready)));
        }
        t
    }
}

/// What an [`Rpdo`] reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RpdoEvent {
    /// Data to apply now: at the SYNC after reception for types 0..=240, on reception for 254
    /// and 255.
    Applied(PdoValues),
    /// A frame could not be unpacked (for example shorter than the mapping); the PDO goes on.
    Error(PdoError),
}

/// A receive PDO: up to `Q` events wait for [`Rpdo::poll_event`].
///
/// Types 0..=240 apply at the SYNC after reception, 254 and 255 at once. 252 and 253 do not
/// exist for RPDOs (the configuration plan refuses them); here they count as synchronous.
///
/// For synchronous types the newest frame received before a SYNC is the one applied at it
/// (an older one is overwritten, as on a device). If the event queue is full the oldest event is
/// dropped and counted in [`Rpdo::overruns`].
#[derive(Debug, Clone)]
pub struct Rpdo<const Q: usize = 4> {
    comm: CommParams,
    mapping: Mapping,
    latched: Option<PdoValues>,
    events: heapless::Deque<RpdoEvent, Q>,
    overruns: u32,
}

impl<const Q: usize> Rpdo<Q> {
    /// An RPDO with its parameters and mapping.
    pub fn new(comm: CommParams, mapping: Mapping) -> Self {
        Rpdo {
            comm,
            mapping,
            latched: None,
            events: heapless::Deque::new(),
            overruns: 0,
        }
    }
    /// The communication parameters.
    pub fn comm(&self) -> &CommParams {
        &self.comm
    }
    /// The mapping (to store applied values: [`Mapping::store_into_od`]).
    pub fn mapping(&self) -> &Mapping {
        &self.mapping
    }
    /// Replaces the parameters and mapping and drops latched data and events.
    pub fn reconfigure(&mut self, comm: CommParams, mapping: Mapping) {
        self.comm = comm;
        self.mapping = mapping;
        self.latched = None;
        self.events.clear();
    }
    /// Events dropped because the queue was full.
    pub fn overruns(&self) -> u32 {
        self.overruns
    }

    fn push(&mut self, e: RpdoEvent) {
        if self.events.is_full() {
            self.events.pop_front();
            self.overruns = self.overruns.saturating_add(1);
        }
        // Room was made above; a zero-capacity queue just drops.
        let _ = self.events.push_back(e);
    }

    /// Whether `frame` is on this PDO's identifier while the PDO is valid.
    pub fn accepts(&self, frame: &Frame) -> bool {
        self.comm.cob_id.accepts(frame)
    }

    /// A frame was received; returns whether it is this PDO's.
    pub fn handle_frame(&mut self, frame: &Frame, _now: Instant) -> bool {
        if frame.is_remote() || !self.accepts(frame) {
            return false;
        }
        match self.mapping.unpack_values(frame.data()) {
            Err(e) => self.push(RpdoEvent::Error(e)),
            Ok(v) if self.comm.transmission.is_event_driven() => self.push(RpdoEvent::Applied(v)),
            Ok(v) => self.latched = Some(v),
        }
        true
    }

    /// A SYNC was received: latched data applies now.
    pub fn handle_sync(&mut self, _now: Instant) {
        if let Some(v) = self.latched.take() {
            self.push(RpdoEvent::Applied(v));
        }
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<RpdoEvent> {
        self.events.pop_front()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canopen::pdo::comm::CobId;

    fn cw_target() -> Mapping {
        Mapping::from_raw(&[0x6040_0010, 0x607A_0020]).unwrap()
    }

    fn tpdo(t: TransmissionType) -> Tpdo {
        Tpdo::new(CommParams::new(CobId::standard(0x285), t), cw_target())
    }

    fn ms(n: u64) -> Instant {
        Instant::from_millis(n)
    }

    /// Frames sent at each of `n` SYNCs (1 = sent).
    fn sync_pattern(p: &mut Tpdo, counters: &[Option<u8>]) -> Vec<u8> {
        counters
            .iter()
            .enumerate()
            .map(|(i, c)| {
                p.handle_sync(*c, ms(i as u64));
                p.poll_transmit(ms(i as u64)).is_some() as u8
            })
            .collect()
    }

    #[test]
    fn cyclic_sends_every_nth_sync_from_the_first() {
        let mut p = tpdo(TransmissionType::SyncCyclic(3));
        assert_eq!(sync_pattern(&mut p, &[None; 7]), [1, 0, 0, 1, 0, 0, 1]);
        let mut p = tpdo(TransmissionType::SyncCyclic(1));
        assert_eq!(sync_pattern(&mut p, &[None; 3]), [1, 1, 1]);
        // Nothing between SYNCs.
        assert_eq!(p.poll_transmit(ms(100)), None);
        assert_eq!(p.poll_timeout(), None);
    }

    proptest::proptest! {
        /// Type n sends at SYNCs 0, n, 2n, ... counting from the first, and nowhere else.
        #[test]
        fn cyclic_pattern(n in 1u8..=240, syncs in 1usize..600) {
            let mut p = tpdo(TransmissionType::SyncCyclic(n));
            let sent = sync_pattern(&mut p, &vec![None; syncs]);
            for (i, s) in sent.iter().enumerate() {
                proptest::prop_assert_eq!(*s == 1, i % n as usize == 0, "SYNC {}", i);
            }
        }
    }

    #[test]
    fn cyclic_honours_the_sync_start_value() {
        let mut p = tpdo(TransmissionType::SyncCyclic(2));
        p.comm.sync_start = 3;
        let counters: Vec<Option<u8>> = (1..=8).map(Some).collect();
        assert_eq!(sync_pattern(&mut p, &counters), [0, 0, 1, 0, 1, 0, 1, 0]);
    }

    #[test]
    fn acyclic_sends_at_the_sync_after_a_change() {
        let mut p = tpdo(TransmissionType::SyncAcyclic);
        p.set_values(&[0x0006, 100]);
        // A change alone sends nothing until SYNC.
        assert_eq!(p.poll_transmit(ms(0)), None);
        assert_eq!(sync_pattern(&mut p, &[None; 3]), [1, 0, 0]);
        p.set_values(&[0x0007, 100]);
        p.handle_sync(None, ms(10));
        let f = p.poll_transmit(ms(10)).unwrap();
        assert_eq!(f.cob_id(), Some(0x285));
        assert_eq!(f.data(), &[0x07, 0x00, 100, 0, 0, 0]);
    }

    #[test]
    fn rtr_types() {
        let rtr = CobId::standard(0x285).remote_frame(6).unwrap();
        // 252: the data sampled at SYNC, not the newer current data.
        let mut p = tpdo(TransmissionType::SyncRtr);
        assert!(!p.handle_frame(&rtr, ms(0)));
        p.set_values(&[1, 1]);
        p.handle_sync(None, ms(1));
        assert_eq!(p.poll_transmit(ms(1)), None);
        p.set_values(&[2, 2]);
        assert!(p.handle_frame(&rtr, ms(2)));
        assert_eq!(p.poll_transmit(ms(2)).unwrap().data(), &[1, 0, 1, 0, 0, 0]);
        // 253: the data of the moment.
        let mut p = tpdo(TransmissionType::AsyncRtr);
        p.set_values(&[3, 0]);
        assert!(p.handle_frame(&rtr, ms(0)));
        assert_eq!(p.poll_transmit(ms(0)).unwrap().data(), &[3, 0, 0, 0, 0, 0]);
        // RTR not allowed (bit 30), or another PDO's identifier: ignored.
        let mut p = Tpdo::new(
            CommParams::new(CobId::from_u32(0x4000_0285), TransmissionType::AsyncRtr),
            cw_target(),
        );
        assert!(!p.handle_frame(&rtr, ms(0)));
        let other = CobId::standard(0x286).remote_frame(6).unwrap();
        assert!(!tpdo(TransmissionType::AsyncRtr).handle_frame(&other, ms(0)));
        // Event-driven PDOs do not answer RTR.
        assert!(!tpdo(TransmissionType::EventProfile).handle_frame(&rtr, ms(0)));
    }

    #[test]
    fn event_driven_respects_inhibit_time() {
        let mut p = tpdo(TransmissionType::EventProfile);
        p.comm.inhibit_100us = 100; // 10 ms
        // Never sent: due at once.
        assert_eq!(p.poll_timeout(), Some(Instant::ZERO));
        assert!(p.poll_transmit(ms(0)).is_some());
        assert_eq!(p.poll_transmit(ms(1)), None);
        assert_eq!(p.poll_timeout(), None);
        p.set_values(&[1, 0]);
        p.set_values(&[2, 0]);
        assert_eq!(p.poll_timeout(), Some(ms(10)));
        assert_eq!(p.poll_transmit(ms(9)), None);
        // The newest data goes out when the inhibit time ends.
        assert_eq!(p.poll_transmit(ms(10)).unwrap().data()[0], 2);
        // A change back to what was sent is no change.
        p.set_values(&[2, 0]);
        assert_eq!(p.poll_transmit(ms(30)), None);
    }

    #[test]
    fn event_timer_resends_unchanged_data() {
        let mut p = tpdo(TransmissionType::EventManufacturer);
        p.comm.event_timer_ms = 100;
        assert!(p.poll_transmit(ms(0)).is_some());
        assert_eq!(p.poll_timeout(), Some(ms(100)));
        assert_eq!(p.poll_transmit(ms(99)), None);
        assert!(p.poll_transmit(ms(100)).is_some());
        // A change restarts the timer.
        p.set_values(&[5, 5]);
        assert!(p.poll_transmit(ms(150)).is_some());
        assert_eq!(p.poll_timeout(), Some(ms(250)));
        assert_eq!(p.poll_transmit(ms(200)), None);
    }

    #[test]
    fn invalid_pdo_is_silent() {
        let mut p = Tpdo::new(
            CommParams::new(
                CobId::standard(0x285).invalid(),
                TransmissionType::SyncCyclic(1),
            ),
            cw_target(),
        );
        assert_eq!(sync_pattern(&mut p, &[None; 3]), [0, 0, 0]);
        p.reconfigure(
            CommParams::new(CobId::standard(0x285), TransmissionType::SyncCyclic(1)),
            cw_target(),
        );
        assert_eq!(sync_pattern(&mut p, &[None; 2]), [1, 1]);
    }

    fn rx_frame(cw: u16, target: i32) -> Frame {
        let mut d = [0u8; 6];
        d[..2].copy_from_slice(&cw.to_le_bytes());
        d[2..].copy_from_slice(&target.to_le_bytes());
        Frame::new_std(0x305, &d).unwrap()
    }

    #[test]
    fn sync_rpdo_applies_the_newest_frame_at_sync() {
        let mut r: Rpdo = Rpdo::new(
            CommParams::new(CobId::standard(0x305), TransmissionType::SyncAcyclic),
            cw_target(),
        );
        assert!(r.handle_frame(&rx_frame(0x0F, 10), ms(0)));
        assert!(r.handle_frame(&rx_frame(0x1F, 20), ms(1)));
        assert_eq!(r.poll_event(), None);
        r.handle_sync(ms(2));
        match r.poll_event() {
            Some(RpdoEvent::Applied(v)) => assert_eq!(v.as_slice(), &[0x1F, 20]),
            e => panic!("{e:?}"),
        }
        // Nothing new: nothing applied at the next SYNC.
        r.handle_sync(ms(3));
        assert_eq!(r.poll_event(), None);
        assert!(!r.handle_frame(&Frame::new_std(0x306, &[0; 6]).unwrap(), ms(4)));
    }

    #[test]
    fn event_rpdo_applies_at_once_and_reports_short_frames() {
        let mut r: Rpdo<2> = Rpdo::new(
            CommParams::new(CobId::standard(0x305), TransmissionType::EventProfile),
            cw_target(),
        );
        r.handle_frame(&rx_frame(0x0F, -1), ms(0));
        match r.poll_event() {
            Some(RpdoEvent::Applied(v)) => {
                assert_eq!(crate::canopen::pdo::sign_extend(v.values[1], 32), -1)
            }
            e => panic!("{e:?}"),
        }
        r.handle_frame(&Frame::new_std(0x305, &[1, 2, 3]).unwrap(), ms(1));
        assert_eq!(
            r.poll_event(),
            Some(RpdoEvent::Error(PdoError::TooShort {
                expected_bits: 48,
                got_bytes: 3
            }))
        );
        // The PDO goes on after the error; a full queue drops the oldest and counts it.
        for i in 0..3 {
            r.handle_frame(&rx_frame(i, 0), ms(2));
        }
        assert_eq!(r.overruns(), 1);
        match r.poll_event() {
            Some(RpdoEvent::Applied(v)) => assert_eq!(v.values[0], 1),
            e => panic!("{e:?}"),
        }
    }
}
