//! The CMMO-ST Modbus server as a sans-I/O state machine: fed whole frames, connection events
//! and time; returns response bytes and tells the caller when to close the connection.
//!
//! What it implements (digest 001 §1.2 and §9.1 items 1-6, manual §4.3):
//! - FC 0x03, 0x10, 0x17 on the direction-split register space from address 0: writes latch
//!   the control image (CCON..., + FPCC...), reads return the status image (SCON..., + FPCS...);
//!   the control image cannot be read back. 0x17 writes first, then reads.
//! - FC 0x07: the top fault number (0 = none, numbers above 0xFF read as 0xFF).
//! - FC 0x2B / MEI 0x0E: basic (0x00..0x02) or regular (plus 0x03, 0x04, 0x06) identification,
//!   all objects in one response when they fit.
//! - Exceptions: start address not 0 -> 0x02; quantity not the profile's 4 (or 8), byte count
//!   or PDU length wrong -> 0x03; any other function code or MEI type -> 0x01. As in the
//!   Modbus specification, a quantity no PDU can carry is 0x03 before the address is checked.
//! - The unit id is ignored and echoed; a frame whose protocol id is not 0 is dropped unanswered
//!   (it is not Modbus) and does not feed the node guard.
//! - One client at a time: [`Session::connect`] refuses a second one, and the caller closes it
//!   (the digest's decision: close the second connection).
//! - Node guard: reset by every Modbus frame (and armed by the connection itself, so a client
//!   that connects and says nothing is caught too). On expiry the device raises 47h (Modbus had
//!   master control) or 48h, and the server closes the connection (§4: the device disconnects
//!   "with a timeout set"). The guard keeps running after the peer closes: no more messages
//!   arrive, so it fires just the same (§4.3.4, **(inferred)**: the manual does not
//!   distinguish a closed connection from a silent one).

use super::mbap::{
    self, ExceptionCode, FrameError, IdCategory, MAX_ADU, MAX_PDU, MBAP_LEN, MbapHeader, Request,
};
use super::{Config, ConfigError, ConnectionLost, FhppDevice, Profile};
use crate::time::Instant;

/// Counters of what the server did, for tests and diagnostics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Stats {
    /// Connections accepted.
    pub connections: u32,
    /// Connections refused because one was already open.
    pub refused: u32,
    /// Requests answered normally.
    pub responses: u32,
    /// Requests answered with an exception.
    pub exceptions: u32,
    /// Frames dropped (protocol id not 0).
    pub dropped: u32,
    /// Node-guard expiries.
    pub timeouts: u32,
}

/// The Modbus side of one CMMO-ST: connection state, the latched control image and the node
/// guard. The device is passed in on each call, so it can be shared with whatever else drives
/// it (fault injection, a test).
#[derive(Debug, Clone)]
pub struct Session {
    config: Config,
    connected: bool,
    guard_deadline: Option<Instant>,
    /// The control image as last written (zeros at power-on): the device samples it every
    /// internal cycle, so a read-only request re-presents it.
    output: [u8; 16],
    stats: Stats,
}

impl Session {
    /// A server with no client, control image all zeros. Refuses a node-guard timeout the device
    /// would not have (set it with [`super::node_guard_timeout`]).
    pub fn new(config: Config) -> Result<Session, ConfigError> {
        if let Some(t) = config.timeout {
            let ms = t.as_millis();
            if !(100..=5000).contains(&ms) {
                return Err(ConfigError::TimeoutOutOfRange {
                    ms: u32::try_from(ms).unwrap_or(u32::MAX),
                });
            }
        }
        Ok(Session {
            config,
            connected: false,
            guard_deadline: None,
            output: [0; 16],
            stats: Stats::default(),
        })
    }

    /// The interface parameters.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// Whether a client is connected.
    pub fn is_connected(&self) -> bool {
        self.connected
    }

    /// What the server has done so far.
    pub fn stats(&self) -> Stats {
        self.stats
    }

    /// The control image as last written (8 or 16 bytes per the profile).
    pub fn output_image(&self) -> &[u8] {
        self.output
            .get(..self.config.profile.bytes())
            .unwrap_or(&self.output)
    }

    /// A client opens a connection. Returns `false` when one is already open: the caller closes
    /// the new connection unanswered.
    pub fn connect<D: FhppDevice + ?Sized>(&mut self, device: &mut D, now: Instant) -> bool {
        if self.connected {
            self.stats.refused += 1;
            return false;
        }
        self.connected = true;
        self.stats.connections += 1;
        self.reset_guard(now);
        device.connection_established(now);
        true
    }

    /// The peer closed the connection (or it broke). The node guard keeps running.
    pub fn disconnect(&mut self) {
        self.connected = false;
    }

    /// When [`handle_timeout`](Self::handle_timeout) must run next: the node-guard deadline.
    pub fn poll_timeout(&self) -> Option<Instant> {
        self.guard_deadline
    }

    /// Runs the node guard. Returns the diagnostic raised if it expired; the connection (if
    /// any) is then closed, and the caller must close its socket.
    pub fn handle_timeout<D: FhppDevice + ?Sized>(
        &mut self,
        device: &mut D,
        now: Instant,
    ) -> Option<ConnectionLost> {
        let deadline = self.guard_deadline?;
        if now < deadline {
            return None;
        }
        self.guard_deadline = None;
        self.connected = false;
        self.stats.timeouts += 1;
        device.step_to(now);
        let lost = if device.master_control() {
            ConnectionLost::WithMasterControl
        } else {
            ConnectionLost::WithoutMasterControl
        };
        device.connection_lost(lost, now);
        Some(lost)
    }

    /// Handles one whole ADU (header + PDU, as [`mbap::Deframer`] yields it) and writes the
    /// response ADU to `out`. `Ok(None)`: nothing to send (frame dropped). `Err`: the frame is
    /// malformed beyond an exception; close the connection.
    pub fn handle_frame<D: FhppDevice + ?Sized>(
        &mut self,
        adu: &[u8],
        device: &mut D,
        now: Instant,
        out: &mut [u8; MAX_ADU],
    ) -> Result<Option<usize>, FrameError> {
        let header = MbapHeader::from_bytes(adu)?;
        let pdu_len = header.pdu_len()?;
        let pdu = adu
            .get(MBAP_LEN..MBAP_LEN + pdu_len)
            .ok_or(FrameError::Truncated { len: adu.len() })?;
        if header.protocol_id != 0 {
            self.stats.dropped += 1;
            return Ok(None);
        }
        self.reset_guard(now);
        device.step_to(now);
        let mut resp = PduWriter::new();
        match self.execute(pdu, device, now, &mut resp) {
            Ok(()) => self.stats.responses += 1,
            Err(code) => {
                self.stats.exceptions += 1;
                let function = pdu.first().copied().unwrap_or(0);
                resp = PduWriter::new();
                resp.put(&mbap::Exception { function, code }.to_bytes());
            }
        }
        Ok(Some(mbap::encode_response(&header, resp.bytes(), out)))
    }

    fn reset_guard(&mut self, now: Instant) {
        self.guard_deadline = self.config.timeout.map(|t| now + t);
    }

    fn check_registers(&self, start: u16, quantity: u16) -> Result<(), ExceptionCode> {
        if start != 0 {
            Err(ExceptionCode::IllegalDataAddress)
        } else if quantity != self.config.profile.registers() {
            Err(ExceptionCode::IllegalDataValue)
        } else {
            Ok(())
        }
    }

    fn execute<D: FhppDevice + ?Sized>(
        &mut self,
        pdu: &[u8],
        device: &mut D,
        now: Instant,
        resp: &mut PduWriter,
    ) -> Result<(), ExceptionCode> {
        let request = mbap::decode_request(pdu).map_err(|e| e.code)?;
        match request {
            Request::ReadHoldingRegisters { start, quantity } => {
                self.check_registers(start, quantity)?;
                let input = self.exchange(device, now);
                resp.put(&[mbap::FC_READ_HOLDING_REGISTERS]);
                self.put_image(resp, &input);
            }
            Request::WriteMultipleRegisters {
                start,
                quantity,
                values,
            } => {
                self.check_registers(start, quantity)?;
                self.latch(values);
                self.exchange(device, now);
                resp.put(&[mbap::FC_WRITE_MULTIPLE_REGISTERS]);
                resp.put(&start.to_be_bytes());
                resp.put(&quantity.to_be_bytes());
            }
            Request::ReadWriteMultipleRegisters {
                read_start,
                read_quantity,
                write_start,
                write_quantity,
                values,
            } => {
                self.check_registers(write_start, write_quantity)?;
                self.check_registers(read_start, read_quantity)?;
                self.latch(values);
                let input = self.exchange(device, now);
                resp.put(&[mbap::FC_READ_WRITE_MULTIPLE_REGISTERS]);
                self.put_image(resp, &input);
            }
            Request::ReadExceptionStatus => {
                let fault = u8::try_from(device.fault_number()).unwrap_or(0xFF);
                resp.put(&[mbap::FC_READ_EXCEPTION_STATUS, fault]);
            }
            Request::ReadDeviceIdentification {
                category,
                object_id,
            } => identification(device, category, object_id, resp),
        }
        Ok(())
    }

    fn latch(&mut self, values: &[u8]) {
        let n = self.config.profile.bytes().min(values.len());
        if let (Some(dst), Some(src)) = (self.output.get_mut(..n), values.get(..n)) {
            dst.copy_from_slice(src);
        }
    }

    /// Presents the latched control image to the device and returns the status image.
    fn exchange<D: FhppDevice + ?Sized>(&mut self, device: &mut D, now: Instant) -> [u8; 16] {
        let [
            c0,
            c1,
            c2,
            c3,
            c4,
            c5,
            c6,
            c7,
            p0,
            p1,
            p2,
            p3,
            p4,
            p5,
            p6,
            p7,
        ] = self.output;
        let fhpp = device.exchange(&[c0, c1, c2, c3, c4, c5, c6, c7], now);
        let fpc = match self.config.profile {
            Profile::Fhpp => [0; 8],
            Profile::FhppFpc => device.parameter(&[p0, p1, p2, p3, p4, p5, p6, p7], now),
        };
        let mut input = [0; 16];
        input[..8].copy_from_slice(&fhpp);
        input[8..].copy_from_slice(&fpc);
        input
    }

    fn put_image(&self, resp: &mut PduWriter, input: &[u8; 16]) {
        let n = self.config.profile.bytes();
        // n is 8 or 16, so the byte count fits.
        resp.put(&[n as u8]);
        resp.put(input.get(..n).unwrap_or(input));
    }
}

/// Object ids of each category in the order they are sent (Tab. 4.4).
fn objects(category: IdCategory) -> &'static [u8] {
    match category {
        IdCategory::Basic => &[0x00, 0x01, 0x02],
        IdCategory::Regular => &[0x00, 0x01, 0x02, 0x03, 0x04, 0x06],
    }
}

/// Builds the Read Device Identification response. The CMMO-ST sends all objects in one
/// response; should configured strings not fit one PDU, the standard "more follows" mechanism
/// continues at the object that did not fit. An object id outside the category restarts at
/// 0x00, as the Modbus specification says.
fn identification<D: FhppDevice + ?Sized>(
    device: &D,
    category: IdCategory,
    object_id: u8,
    resp: &mut PduWriter,
) {
    // Largest object payload that fits one PDU with the 7-byte response head and its own
    // 2-byte id/length.
    const MAX_OBJECT: usize = MAX_PDU - 7 - 2;
    let id = device.identification();
    let list = objects(category);
    let first = list.iter().position(|&o| o == object_id).unwrap_or(0);
    let mut body = PduWriter::new();
    let mut count = 0u8;
    let mut next = None;
    for &object in list.iter().skip(first) {
        let text = id.object(object).unwrap_or("").as_bytes();
        let text = text.get(..MAX_OBJECT).unwrap_or(text);
        if body.len() + 2 + text.len() > MAX_PDU - 7 {
            next = Some(object);
            break;
        }
        // text.len() <= MAX_OBJECT < 256.
        body.put(&[object, text.len() as u8]);
        body.put(text);
        count += 1;
    }
    resp.put(&[
        mbap::FC_ENCAPSULATED_INTERFACE,
        mbap::MEI_READ_DEVICE_IDENTIFICATION,
        category.code(),
        // Conformity level as Tab. 4.3 lists it: 0x01 basic, 0x02 regular (inferred: echoes
        // the category asked for).
        category.code(),
        if next.is_some() { 0xFF } else { 0x00 },
        next.unwrap_or(0x00),
        count,
    ]);
    resp.put(body.bytes());
}

/// A response PDU being built; writes past [`MAX_PDU`] are cut off instead of panicking.
struct PduWriter {
    buf: [u8; MAX_PDU],
    len: usize,
}

impl PduWriter {
    fn new() -> Self {
        PduWriter {
            buf: [0; MAX_PDU],
            len: 0,
        }
    }
    fn put(&mut self, bytes: &[u8]) {
        let n = bytes.len().min(MAX_PDU - self.len);
        if let (Some(dst), Some(src)) = (self.buf.get_mut(self.len..self.len + n), bytes.get(..n)) {
            dst.copy_from_slice(src);
            self.len += n;
        }
    }
    fn len(&self) -> usize {
        self.len
    }
    fn bytes(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&self.buf)
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Identification, node_guard_timeout};
    use super::*;
    use core::time::Duration;

    /// Test double, not the simulator: power-on status bytes, the record number echoed, a fixed
    /// position, FPC echoed, and a log of what the server told it.
    struct Double {
        last_output: [u8; 8],
        steps: u32,
        fault: u16,
        control: bool,
        lost: Option<ConnectionLost>,
        established: u32,
        name: &'static str,
    }

    impl Double {
        fn new() -> Self {
            Double {
                last_output: [0; 8],
                steps: 0,
                fault: 0,
                control: true,
                lost: None,
                established: 0,
                name: "",
            }
        }
    }

    impl FhppDevice for Double {
        fn exchange(&mut self, output: &[u8; 8], _now: Instant) -> [u8; 8] {
            self.last_output = *output;
            [0x10, 0x04, output[2], 0x00, 0x00, 0x01, 0x23, 0x45]
        }
        fn parameter(&mut self, request: &[u8; 8], _now: Instant) -> [u8; 8] {
            let mut r = *request;
            r[0] |= 0x80;
            r
        }
        fn step_to(&mut self, _now: Instant) {
            self.steps += 1;
        }
        fn fault_number(&self) -> u16 {
            self.fault
        }
        fn identification(&self) -> Identification<'_> {
            Identification {
                user_application_name: self.name,
                ..Identification::default()
            }
        }
        fn master_control(&self) -> bool {
            self.control
        }
        fn connection_lost(&mut self, lost: ConnectionLost, _now: Instant) {
            self.lost = Some(lost);
        }
        fn connection_established(&mut self, _now: Instant) {
            self.established += 1;
        }
    }

    fn run(s: &mut Session, d: &mut Double, adu: &[u8]) -> Vec<u8> {
        let mut out = [0; MAX_ADU];
        let n = s
            .handle_frame(adu, d, Instant::ZERO, &mut out)
            .unwrap()
            .unwrap();
        out[..n].to_vec()
    }

    fn ms(v: u64) -> Instant {
        Instant::from_millis(v)
    }

    #[test]
    fn read_write_exchanges_and_returns_the_status_image() {
        let mut s = Session::new(Config::default()).unwrap();
        let mut d = Double::new();
        let req = [
            0, 1, 0, 0, 0, 0x13, 0, 0x17, 0, 0, 0, 4, 0, 0, 0, 4, 8, 0x23, 0x01, 5, 0, 0, 0, 0, 0,
        ];
        let resp = run(&mut s, &mut d, &req);
        assert_eq!(
            resp,
            [
                0, 1, 0, 0, 0, 0x0B, 0, 0x17, 8, 0x10, 0x04, 5, 0, 0, 0x01, 0x23, 0x45
            ]
        );
        assert_eq!(d.last_output, [0x23, 0x01, 5, 0, 0, 0, 0, 0]);
        assert_eq!(s.output_image(), &[0x23, 0x01, 5, 0, 0, 0, 0, 0]);
        assert!(d.steps >= 1, "the device is stepped to the request time");
    }

    #[test]
    fn read_only_re_presents_the_latched_control_image() {
        let mut s = Session::new(Config::default()).unwrap();
        let mut d = Double::new();
        run(
            &mut s,
            &mut d,
            &[
                0, 1, 0, 0, 0, 0x0F, 0, 0x10, 0, 0, 0, 4, 8, 0x03, 0, 9, 0, 0, 0, 0, 0,
            ],
        );
        d.last_output = [0; 8];
        let resp = run(&mut s, &mut d, &[0, 2, 0, 0, 0, 6, 0, 0x03, 0, 0, 0, 4]);
        assert_eq!(resp[9..12], [0x10, 0x04, 9]);
        assert_eq!(d.last_output, [0x03, 0, 9, 0, 0, 0, 0, 0]);
    }

    #[test]
    fn fpc_profile_carries_16_bytes_and_refuses_4_registers() {
        let cfg = Config {
            profile: Profile::FhppFpc,
            ..Config::default()
        };
        let mut s = Session::new(cfg).unwrap();
        let mut d = Double::new();
        let mut req = vec![0, 1, 0, 0, 0, 0x1B, 0, 0x17, 0, 0, 0, 8, 0, 0, 0, 8, 16];
        req.extend_from_slice(&[0x03, 0, 7, 0, 0, 0, 0, 0, 0x11, 0, 0x22, 0, 0, 0, 0, 0]);
        let resp = run(&mut s, &mut d, &req);
        assert_eq!(&resp[..9], &[0, 1, 0, 0, 0, 0x13, 0, 0x17, 16]);
        assert_eq!(&resp[17..], &[0x91, 0, 0x22, 0, 0, 0, 0, 0]);
        let resp = run(&mut s, &mut d, &[0, 2, 0, 0, 0, 6, 0, 0x03, 0, 0, 0, 4]);
        assert_eq!(&resp[7..], &[0x83, 0x03]);
    }

    #[test]
    fn exceptions_for_address_quantity_and_function() {
        let mut s = Session::new(Config::default()).unwrap();
        let mut d = Double::new();
        // Start 1.
        let r = run(&mut s, &mut d, &[0, 1, 0, 0, 0, 6, 0, 0x03, 0, 1, 0, 4]);
        assert_eq!(&r[7..], &[0x83, 0x02]);
        // Quantity 5.
        let r = run(&mut s, &mut d, &[0, 1, 0, 0, 0, 6, 0, 0x03, 0, 0, 0, 5]);
        assert_eq!(&r[7..], &[0x83, 0x03]);
        // FC 0x06 write single register is not implemented.
        let r = run(&mut s, &mut d, &[0, 1, 0, 0, 0, 6, 0, 0x06, 0, 0, 0, 1]);
        assert_eq!(&r[7..], &[0x86, 0x01]);
        // 0x17 with write start 2.
        let mut req = vec![0, 1, 0, 0, 0, 0x13, 0, 0x17, 0, 0, 0, 4, 0, 2, 0, 4, 8];
        req.extend_from_slice(&[0; 8]);
        let r = run(&mut s, &mut d, &req);
        assert_eq!(&r[4..], &[0, 3, 0, 0x97, 0x02]);
        // A refused write latches nothing.
        assert_eq!(s.output_image(), &[0; 8]);
        assert_eq!(s.stats().exceptions, 4);
    }

    #[test]
    fn exception_status_is_the_fault_number_saturated() {
        let mut s = Session::new(Config::default()).unwrap();
        let mut d = Double::new();
        assert_eq!(
            run(&mut s, &mut d, &[0, 1, 0, 0, 0, 2, 0, 0x07])[7..],
            [0x07, 0x00]
        );
        d.fault = 0x2F;
        assert_eq!(
            run(&mut s, &mut d, &[0, 1, 0, 0, 0, 2, 0, 0x07])[7..],
            [0x07, 0x2F]
        );
        d.fault = 0x1234;
        assert_eq!(
            run(&mut s, &mut d, &[0, 1, 0, 0, 0, 2, 0, 0x07])[7..],
            [0x07, 0xFF]
        );
    }

    #[test]
    fn identification_basic_regular_and_restart() {
        let mut s = Session::new(Config::default()).unwrap();
        let mut d = Double::new();
        d.name = "P1";
        let r = run(
            &mut s,
            &mut d,
            &[0, 1, 0, 0, 0, 5, 0, 0x2B, 0x0E, 0x01, 0x00],
        );
        let mut want = vec![0x2B, 0x0E, 0x01, 0x01, 0x00, 0x00, 3];
        for (id, text) in [
            (0u8, "Festo AG & Co. KG"),
            (1, "CMMO-ST-C5-1-LKP"),
            (2, "1.4.0.0"),
        ] {
            want.push(id);
            want.push(text.len() as u8);
            want.extend_from_slice(text.as_bytes());
        }
        assert_eq!(&r[7..], &want[..]);
        assert_eq!(
            u16::from_be_bytes([r[4], r[5]]) as usize,
            want.len() + 1,
            "MBAP length"
        );
        let r = run(
            &mut s,
            &mut d,
            &[0, 1, 0, 0, 0, 5, 0, 0x2B, 0x0E, 0x02, 0x04],
        );
        // Starts at 0x04: ProductName, then UserApplicationName.
        assert_eq!(&r[7..14], &[0x2B, 0x0E, 0x02, 0x02, 0x00, 0x00, 2]);
        assert_eq!(r[14], 0x04);
        assert_eq!(&r[r.len() - 4..], &[0x06, 2, b'P', b'1']);
        // Object 0x05 does not exist: restart at 0x00, six objects.
        let r = run(
            &mut s,
            &mut d,
            &[0, 1, 0, 0, 0, 5, 0, 0x2B, 0x0E, 0x02, 0x05],
        );
        assert_eq!(r[13], 6);
        assert_eq!(r[14], 0x00);
    }

    #[test]
    fn foreign_protocol_id_is_dropped() {
        let mut s = Session::new(Config::default()).unwrap();
        let mut d = Double::new();
        let mut out = [0; MAX_ADU];
        let r = s.handle_frame(&[0, 1, 0, 1, 0, 2, 0, 0x07], &mut d, ms(0), &mut out);
        assert_eq!(r, Ok(None));
        assert_eq!(s.stats().dropped, 1);
    }

    #[test]
    fn one_client_at_a_time() {
        let mut s = Session::new(Config::default()).unwrap();
        let mut d = Double::new();
        assert!(s.connect(&mut d, ms(0)));
        assert!(!s.connect(&mut d, ms(1)));
        s.disconnect();
        assert!(s.connect(&mut d, ms(2)));
        assert_eq!(d.established, 2);
        assert_eq!(s.stats().refused, 1);
    }

    #[test]
    fn node_guard_is_reset_by_each_frame_and_raises_47h_or_48h() {
        let cfg = Config {
            timeout: node_guard_timeout(50).unwrap(),
            ..Config::default()
        };
        let mut s = Session::new(cfg).unwrap();
        let mut d = Double::new();
        assert!(s.connect(&mut d, ms(0)));
        assert_eq!(s.poll_timeout(), Some(ms(100)), "50 ms is raised to 100 ms");
        let mut out = [0; MAX_ADU];
        s.handle_frame(&[0, 1, 0, 0, 0, 2, 0, 0x07], &mut d, ms(90), &mut out)
            .unwrap();
        assert_eq!(s.poll_timeout(), Some(ms(190)));
        assert_eq!(s.handle_timeout(&mut d, ms(189)), None);
        assert!(s.is_connected());
        assert_eq!(
            s.handle_timeout(&mut d, ms(190)),
            Some(ConnectionLost::WithMasterControl)
        );
        assert!(!s.is_connected());
        assert_eq!(d.lost, Some(ConnectionLost::WithMasterControl));
        assert_eq!(s.poll_timeout(), None, "fires once");

        d.control = false;
        assert!(s.connect(&mut d, ms(300)));
        s.disconnect();
        // The peer closed; nothing arrives any more, so the guard still fires.
        assert_eq!(
            s.handle_timeout(&mut d, ms(400)),
            Some(ConnectionLost::WithoutMasterControl)
        );
        assert_eq!(ConnectionLost::WithoutMasterControl.number(), 0x48);
    }

    #[test]
    fn timeout_off_never_fires() {
        let mut s = Session::new(Config::default()).unwrap();
        let mut d = Double::new();
        s.connect(&mut d, ms(0));
        assert_eq!(s.poll_timeout(), None);
        assert_eq!(s.handle_timeout(&mut d, ms(1_000_000)), None);
    }

    #[test]
    fn config_refuses_a_timeout_the_device_cannot_have() {
        let cfg = Config {
            timeout: Some(Duration::from_millis(6000)),
            ..Config::default()
        };
        assert_eq!(
            Session::new(cfg).err(),
            Some(ConfigError::TimeoutOutOfRange { ms: 6000 })
        );
    }

    proptest::proptest! {
        /// Any byte stream, cut anywhere, through the deframer and the session: no panic, and
        /// every answer echoes its request's transaction id and is a well-formed ADU.
        #[test]
        fn any_bytes_never_panic_and_answers_are_well_formed(
            bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..600),
            cut in 0usize..600,
            fpc in proptest::bool::ANY,
        ) {
            let profile = if fpc { Profile::FhppFpc } else { Profile::Fhpp };
            let mut s = Session::new(Config { profile, ..Config::default() }).unwrap();
            let mut d = Double::new();
            let mut deframer = mbap::Deframer::new();
            let mut adu = [0; MAX_ADU];
            let mut out = [0; MAX_ADU];
            let cut = cut.min(bytes.len());
            'stream: for part in [&bytes[..cut], &bytes[cut..]] {
                let mut rest = part;
                while !rest.is_empty() {
                    let n = deframer.push(rest);
                    rest = &rest[n..];
                    loop {
                        match deframer.next_frame(&mut adu) {
                            Ok(Some(len)) => {
                                if let Some(m) = s.handle_frame(&adu[..len], &mut d, ms(0), &mut out).unwrap() {
                                    proptest::prop_assert_eq!(&out[..2], &adu[..2]);
                                    let h = MbapHeader::from_bytes(&out[..m]).unwrap();
                                    proptest::prop_assert_eq!(usize::from(h.length) + 6, m);
                                }
                            }
                            Ok(None) => break,
                            Err(_) => break 'stream,
                        }
                    }
                }
            }
        }
    }

    proptest::proptest! {
        /// Well-framed requests with random function codes and bodies: every one is answered,
        /// either normally (same function code) or with that function code's exception.
        #[test]
        fn framed_requests_are_always_answered(
            tid in proptest::num::u16::ANY,
            fc in proptest::sample::select(vec![0x01u8, 0x03, 0x07, 0x10, 0x17, 0x2B, 0x80, 0xFF]),
            body in proptest::collection::vec(proptest::num::u8::ANY, 0..40),
        ) {
            let mut s = Session::new(Config::default()).unwrap();
            let mut d = Double::new();
            let mut adu = vec![(tid >> 8) as u8, tid as u8, 0, 0, 0, (body.len() + 2) as u8, 0, fc];
            adu.extend_from_slice(&body);
            let mut out = [0; MAX_ADU];
            let m = s.handle_frame(&adu, &mut d, ms(0), &mut out).unwrap().unwrap();
            proptest::prop_assert_eq!(&out[..2], &tid.to_be_bytes());
            proptest::prop_assert!(out[7] == fc || (out[7] == fc | 0x80 && m == 9));
            proptest::prop_assert_eq!(s.stats().responses + s.stats().exceptions, 1);
        }
    }

    #[test]
    fn malformed_header_is_an_error_not_a_panic() {
        let mut s = Session::new(Config::default()).unwrap();
        let mut d = Double::new();
        let mut out = [0; MAX_ADU];
        assert!(
            s.handle_frame(&[0, 1, 0, 0, 0, 9, 0, 0x07], &mut d, ms(0), &mut out)
                .is_err()
        );
        assert!(s.handle_frame(&[0, 1], &mut d, ms(0), &mut out).is_err());
    }
}
