//! The mailbox and CANopen over EtherCAT (digest §5): the 6-byte mailbox header, the CoE
//! header, and a subdevice's SDO server (expedited, normal and segmented, both ways; aborts
//! with CiA 301 codes) and emergencies, over any [`ObjectAccess`] dictionary.
//!
//! Messages are whole mailbox contents (header first); replies are written into a buffer no
//! longer than the read mailbox (sync manager 1).
//!
//! ```
//! use drivers::canopen::Address;
//! use drivers::canopen::od::{AccessType, DataType, EntryDef, ObjectDictionary, Value};
//! use drivers::ethercat::coe::{CoeServer, sdo_upload_request};
//! let mut od: ObjectDictionary<'_, 4, 64> = ObjectDictionary::new();
//! od.insert(EntryDef::new(Address::new(0x1000, 0), "device type", DataType::Unsigned32,
//!     AccessType::Const).default_value(Value::Unsigned(0x0002_012D))).unwrap();
//! let mut req = [0u8; 128];
//! let n = sdo_upload_request(&mut req, 1, Address::new(0x1000, 0));
//! let mut server = CoeServer::new();
//! let mut reply = [0u8; 128];
//! let len = server.handle(&req[..n], &mut od, &mut reply).unwrap();
//! assert_eq!(len, 16); // 6 + 2 + 8: an expedited upload response
//! assert_eq!(reply[8], 0x43); // 4 bytes
//! assert_eq!(&reply[12..16], &0x0002_012Du32.to_le_bytes());
//! ```

use crate::canopen::od::ObjectAccess;
use crate::canopen::{AbortCode, Address};

/// The mailbox header's length.
pub const MAILBOX_HEADER_LEN: usize = 6;
/// The CoE header's length.
pub const COE_HEADER_LEN: usize = 2;
/// An SDO's fixed part: command, index, sub-index, 4 data bytes.
pub const SDO_LEN: usize = 8;
/// The largest object a segmented transfer carries here.
pub const OBJECT_MAX: usize = 512;

/// Mailbox type: error reply.
pub const TYPE_ERROR: u8 = 0;
/// Mailbox type: CoE.
pub const TYPE_COE: u8 = 3;

/// CoE service: emergency.
pub const SERVICE_EMERGENCY: u8 = 1;
/// CoE service: SDO request.
pub const SERVICE_SDO_REQUEST: u8 = 2;
/// CoE service: SDO response.
pub const SERVICE_SDO_RESPONSE: u8 = 3;
/// CoE service: SDO information.
pub const SERVICE_SDO_INFO: u8 = 8;

/// Mailbox error: the protocol (type) is not supported.
pub const MBX_ERR_UNSUPPORTED_PROTOCOL: u16 = 0x0002;
/// Mailbox error: the service is not supported.
pub const MBX_ERR_SERVICE_NOT_SUPPORTED: u16 = 0x0004;
/// Mailbox error: the header is invalid.
pub const MBX_ERR_INVALID_HEADER: u16 = 0x0005;
/// Mailbox error: the message is too short.
pub const MBX_ERR_TOO_SHORT: u16 = 0x0006;

/// A mailbox header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MailboxHeader {
    /// Bytes after the header.
    pub length: u16,
    /// Station address (0 from the master).
    pub address: u16,
    /// Channel (bits 0–5) and priority (6–7).
    pub channel: u8,
    /// Type (bits 0–3).
    pub kind: u8,
    /// Counter 1..7 (0: not counted).
    pub counter: u8,
}

impl MailboxHeader {
    /// Reads a header; `None` if the message is shorter than one.
    pub fn parse(b: &[u8]) -> Option<MailboxHeader> {
        let h = b.get(..MAILBOX_HEADER_LEN)?;
        Some(MailboxHeader {
            length: u16::from_le_bytes([h[0], h[1]]),
            address: u16::from_le_bytes([h[2], h[3]]),
            channel: h[4],
            kind: h[5] & 0x0F,
            counter: (h[5] >> 4) & 0x07,
        })
    }

    /// Writes the header into the first 6 bytes.
    pub fn write(&self, b: &mut [u8]) {
        b[0..2].copy_from_slice(&self.length.to_le_bytes());
        b[2..4].copy_from_slice(&self.address.to_le_bytes());
        b[4] = self.channel;
        b[5] = (self.kind & 0x0F) | ((self.counter & 0x07) << 4);
    }
}

/// A segmented transfer in progress.
#[derive(Debug, Clone)]
enum Transfer {
    Idle,
    /// Upload: the whole value, how much is sent, the toggle the next segment request carries.
    Upload {
        addr: Address,
        data: heapless::Vec<u8, OBJECT_MAX>,
        sent: usize,
        toggle: bool,
    },
    /// Download: the announced size, what came so far, the next toggle.
    Download {
        addr: Address,
        size: usize,
        data: heapless::Vec<u8, OBJECT_MAX>,
        toggle: bool,
    },
}

/// A subdevice's CoE mailbox server: SDO transfers and emergencies.
#[derive(Debug, Clone)]
pub struct CoeServer {
    /// The counter of the last message sent (1..7).
    counter: u8,
    /// The last request taken and the reply it got: the same request again (same counter,
    /// same bytes) is a retry and gets the same reply without being executed twice.
    last_request: heapless::Vec<u8, 128>,
    last_reply: heapless::Vec<u8, 128>,
    transfer: Transfer,
}

impl Default for CoeServer {
    fn default() -> Self {
        Self::new()
    }
}

impl CoeServer {
    /// A server with no transfer in progress.
    pub const fn new() -> CoeServer {
        CoeServer {
            counter: 0,
            last_request: heapless::Vec::new(),
            last_reply: heapless::Vec::new(),
            transfer: Transfer::Idle,
        }
    }

    /// Forgets any transfer and the counters (a state change to Init).
    pub fn reset(&mut self) {
        *self = CoeServer::new();
    }

    /// The next counter 1..7.
    fn next_counter(&mut self) -> u8 {
        self.counter = if self.counter >= 7 {
            1
        } else {
            self.counter + 1
        };
        self.counter
    }

    /// Handles a message from the write mailbox; writes the reply (if any) into `reply`, which
    /// is as long as the read mailbox (at least 16 bytes, else nothing is answered), and
    /// returns the reply's length.
    pub fn handle(
        &mut self,
        message: &[u8],
        od: &mut impl ObjectAccess,
        reply: &mut [u8],
    ) -> Option<usize> {
        if reply.len() < MAILBOX_HEADER_LEN + COE_HEADER_LEN + SDO_LEN {
            // No room for any answer: a read mailbox shorter than 16 bytes.
            return None;
        }
        let used = MailboxHeader::parse(message)
            .map_or(message.len(), |h| {
                MAILBOX_HEADER_LEN + usize::from(h.length)
            })
            .min(message.len());
        let message = &message[..used];
        let counted = message.len() > 5 && message[5] & 0x70 != 0;
        if counted && !self.last_request.is_empty() && self.last_request.as_slice() == message {
            // A retry of the last request: answer it again, do not execute it twice.
            let n = self.last_reply.len().min(reply.len());
            reply[..n].copy_from_slice(&self.last_reply[..n]);
            return Some(n);
        }
        let n = self.execute(message, od, reply)?;
        self.last_request.clear();
        self.last_reply.clear();
        if message.len() <= 128 && n <= 128 {
            let _ = self.last_request.extend_from_slice(message);
            let _ = self.last_reply.extend_from_slice(&reply[..n]);
        }
        Some(n)
    }

    fn execute(
        &mut self,
        message: &[u8],
        od: &mut impl ObjectAccess,
        reply: &mut [u8],
    ) -> Option<usize> {
        let Some(h) = MailboxHeader::parse(message) else {
            return Some(self.mailbox_error(MBX_ERR_TOO_SHORT, reply));
        };
        let end = MAILBOX_HEADER_LEN + usize::from(h.length);
        let Some(body) = message.get(MAILBOX_HEADER_LEN..end) else {
            return Some(self.mailbox_error(MBX_ERR_INVALID_HEADER, reply));
        };
        if h.kind != TYPE_COE {
            return Some(self.mailbox_error(MBX_ERR_UNSUPPORTED_PROTOCOL, reply));
        }
        if body.len() < COE_HEADER_LEN {
            return Some(self.mailbox_error(MBX_ERR_TOO_SHORT, reply));
        }
        let service = body[1] >> 4;
        if service != SERVICE_SDO_REQUEST {
            return Some(self.mailbox_error(MBX_ERR_SERVICE_NOT_SUPPORTED, reply));
        }
        let sdo = &body[COE_HEADER_LEN..];
        if sdo.is_empty() {
            return Some(self.mailbox_error(MBX_ERR_TOO_SHORT, reply));
        }
        let room = reply.len();
        let out = &mut reply[MAILBOX_HEADER_LEN + COE_HEADER_LEN..];
        let n = self.sdo(sdo, od, out, room);
        Some(self.finish(reply, TYPE_COE, SERVICE_SDO_RESPONSE, n))
    }

    /// Writes the mailbox and CoE headers in front of `n` bytes of SDO; returns the length.
    fn finish(&mut self, reply: &mut [u8], kind: u8, service: u8, n: usize) -> usize {
        let counter = self.next_counter();
        MailboxHeader {
            length: (COE_HEADER_LEN + n) as u16,
            address: 0,
            channel: 0,
            kind,
            counter,
        }
        .write(reply);
        reply[6..8].copy_from_slice(&(u16::from(service) << 12).to_le_bytes());
        MAILBOX_HEADER_LEN + COE_HEADER_LEN + n
    }

    /// A mailbox error reply (type 0): command 0001h and the detail.
    fn mailbox_error(&mut self, detail: u16, reply: &mut [u8]) -> usize {
        let counter = self.next_counter();
        MailboxHeader {
            length: 4,
            address: 0,
            channel: 0,
            kind: TYPE_ERROR,
            counter,
        }
        .write(reply);
        reply[6..8].copy_from_slice(&1u16.to_le_bytes());
        reply[8..10].copy_from_slice(&detail.to_le_bytes());
        MAILBOX_HEADER_LEN + 4
    }

    /// An emergency message (CoE service 1): error code, error register, 5 manufacturer bytes.
    pub fn emergency(&mut self, code: u16, register: u8, data: [u8; 5], out: &mut [u8]) -> usize {
        let body = &mut out[MAILBOX_HEADER_LEN + COE_HEADER_LEN..];
        body[0..2].copy_from_slice(&code.to_le_bytes());
        body[2] = register;
        body[3..8].copy_from_slice(&data);
        self.finish(out, TYPE_COE, SERVICE_EMERGENCY, 8)
    }

    /// One SDO request; writes the response (or an abort) into `out`, returns its length.
    fn sdo(
        &mut self,
        sdo: &[u8],
        od: &mut impl ObjectAccess,
        out: &mut [u8],
        room: usize,
    ) -> usize {
        let cmd = sdo[0];
        let ccs = cmd >> 5;
        let addr_of = |s: &[u8]| -> Option<Address> {
            (s.len() >= 4).then(|| Address::new(u16::from_le_bytes([s[1], s[2]]), s[3]))
        };
        match ccs {
            // Upload (initiate).
            2 => {
                let Some(addr) = addr_of(sdo) else {
                    return abort(out, Address::new(0, 0), AbortCode::InvalidCommand);
                };
                self.transfer = Transfer::Idle;
                if cmd & 0x10 != 0 {
                    return abort(out, addr, AbortCode::Other(0x0601_0004));
                }
                self.upload(addr, od, out, room)
            }
            // Upload segment.
            3 => self.upload_segment(cmd, out, room),
            // Download (initiate).
            1 => {
                let Some(addr) = addr_of(sdo) else {
                    return abort(out, Address::new(0, 0), AbortCode::InvalidCommand);
                };
                self.transfer = Transfer::Idle;
                if cmd & 0x10 != 0 {
                    return abort(out, addr, AbortCode::Other(0x0601_0004));
                }
                self.download(cmd, addr, sdo, od, out)
            }
            // Download segment.
            0 => self.download_segment(cmd, sdo, od, out),
            // Abort from the master: forget the transfer, no reply.
            4 => {
                self.transfer = Transfer::Idle;
                0
            }
            _ => abort(out, Address::new(0, 0), AbortCode::InvalidCommand),
        }
    }

    fn upload(
        &mut self,
        addr: Address,
        od: &mut impl ObjectAccess,
        out: &mut [u8],
        room: usize,
    ) -> usize {
        let size = match od.size(addr) {
            Ok(s) => s,
            Err(code) => return abort(out, addr, code),
        };
        if size > OBJECT_MAX {
            return abort(out, addr, AbortCode::Other(0x0601_0005));
        }
        let mut value = [0u8; OBJECT_MAX];
        let n = match od.read(addr, 0, &mut value[..size]) {
            Ok(n) => n,
            Err(code) => return abort(out, addr, code),
        };
        let value = &value[..n];
        put_addr(out, addr);
        if (1..=4).contains(&n) {
            out[0] = 0x43 | (((4 - n) as u8) << 2);
            out[4..8].fill(0);
            out[4..4 + n].copy_from_slice(value);
            return SDO_LEN;
        }
        // Normal upload: size, then as much as the mailbox holds; segments for the rest.
        out[0] = 0x41;
        out[4..8].copy_from_slice(&(n as u32).to_le_bytes());
        let cap = room - MAILBOX_HEADER_LEN - COE_HEADER_LEN - SDO_LEN;
        let first = n.min(cap);
        out[SDO_LEN..SDO_LEN + first].copy_from_slice(&value[..first]);
        if first < n {
            let mut data = heapless::Vec::new();
            let _ = data.extend_from_slice(value);
            self.transfer = Transfer::Upload {
                addr,
                data,
                sent: first,
                toggle: false,
            };
        }
        SDO_LEN + first
    }

    fn upload_segment(&mut self, cmd: u8, out: &mut [u8], room: usize) -> usize {
        let toggle = cmd & 0x10 != 0;
        let Transfer::Upload {
            addr,
            data,
            sent,
            toggle: expected,
        } = &mut self.transfer
        else {
            return abort(out, Address::new(0, 0), AbortCode::InvalidCommand);
        };
        let addr = *addr;
        if toggle != *expected {
            self.transfer = Transfer::Idle;
            return abort(out, addr, AbortCode::ToggleBit);
        }
        // Segment data: what the mailbox holds after the command byte, at least 7 bytes.
        let cap = room - MAILBOX_HEADER_LEN - COE_HEADER_LEN - 1;
        let rest = &data[*sent..];
        let n = rest.len().min(cap);
        let last = n == rest.len();
        let unused = if n < 7 { (7 - n) as u8 } else { 0 };
        out[0] = (u8::from(toggle) << 4) | (unused << 1) | u8::from(last);
        out[1..1 + n].copy_from_slice(&rest[..n]);
        let len = 1 + n.max(7);
        out[1 + n..len].fill(0);
        *sent += n;
        *expected = !toggle;
        if last {
            self.transfer = Transfer::Idle;
        }
        len
    }

    fn download(
        &mut self,
        cmd: u8,
        addr: Address,
        sdo: &[u8],
        od: &mut impl ObjectAccess,
        out: &mut [u8],
    ) -> usize {
        let expedited = cmd & 0x02 != 0;
        let sized = cmd & 0x01 != 0;
        if expedited {
            let n = if sized {
                4 - usize::from((cmd >> 2) & 0x03)
            } else {
                4
            };
            let Some(data) = sdo.get(4..4 + n) else {
                return abort(out, addr, AbortCode::InvalidCommand);
            };
            return match od.write(addr, data) {
                Ok(()) => download_ok(out, addr),
                Err(code) => abort(out, addr, code),
            };
        }
        let Some(size) = sdo
            .get(4..8)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
        else {
            return abort(out, addr, AbortCode::InvalidCommand);
        };
        if size > OBJECT_MAX {
            return abort(out, addr, AbortCode::OutOfMemory);
        }
        let here = &sdo[SDO_LEN.min(sdo.len())..];
        let here = &here[..here.len().min(size)];
        if here.len() == size {
            return match od.write(addr, here) {
                Ok(()) => download_ok(out, addr),
                Err(code) => abort(out, addr, code),
            };
        }
        let mut data = heapless::Vec::new();
        let _ = data.extend_from_slice(here);
        self.transfer = Transfer::Download {
            addr,
            size,
            data,
            toggle: false,
        };
        download_ok(out, addr)
    }

    fn download_segment(
        &mut self,
        cmd: u8,
        sdo: &[u8],
        od: &mut impl ObjectAccess,
        out: &mut [u8],
    ) -> usize {
        let toggle = cmd & 0x10 != 0;
        let last = cmd & 0x01 != 0;
        let Transfer::Download {
            addr,
            size,
            data,
            toggle: expected,
        } = &mut self.transfer
        else {
            return abort(out, Address::new(0, 0), AbortCode::InvalidCommand);
        };
        let addr = *addr;
        if toggle != *expected {
            self.transfer = Transfer::Idle;
            return abort(out, addr, AbortCode::ToggleBit);
        }
        let unused = usize::from((cmd >> 1) & 0x07);
        let payload = &sdo[1..];
        let n = if payload.len() <= 7 {
            payload.len().saturating_sub(unused)
        } else {
            payload.len()
        };
        let n = n.min(*size - data.len());
        if data.extend_from_slice(&payload[..n]).is_err() {
            self.transfer = Transfer::Idle;
            return abort(out, addr, AbortCode::OutOfMemory);
        }
        *expected = !toggle;
        out[0] = 0x20 | (u8::from(toggle) << 4);
        out[1..8].fill(0);
        if last {
            let result = if data.len() == *size {
                od.write(addr, data)
            } else {
                Err(AbortCode::TooShort)
            };
            self.transfer = Transfer::Idle;
            if let Err(code) = result {
                return abort(out, addr, code);
            }
        }
        SDO_LEN
    }
}

fn put_addr(out: &mut [u8], addr: Address) {
    out[1..3].copy_from_slice(&addr.index.to_le_bytes());
    out[3] = addr.sub;
}

fn download_ok(out: &mut [u8], addr: Address) -> usize {
    out[0] = 0x60;
    put_addr(out, addr);
    out[4..8].fill(0);
    SDO_LEN
}

/// An abort transfer: 80h, the address, the code.
fn abort(out: &mut [u8], addr: Address, code: AbortCode) -> usize {
    out[0] = 0x80;
    put_addr(out, addr);
    out[4..8].copy_from_slice(&code.code().to_le_bytes());
    SDO_LEN
}

/// The error code of the emergency in a mailbox read from a subdevice's input mailbox (SM1),
/// or `None` when the mailbox holds something else (the master side of [`CoeServer::emergency`]).
///
/// ```
/// use drivers::ethercat::coe::{CoeServer, parse_emergency};
/// let mut s = CoeServer::new();
/// let mut mbx = [0u8; 128];
/// let n = s.emergency(0x8100, 0x11, [0; 5], &mut mbx);
/// assert!(n > 0);
/// assert_eq!(parse_emergency(&mbx), Some(0x8100));
/// assert_eq!(parse_emergency(&[0; 16]), None);
/// ```
pub fn parse_emergency(mailbox: &[u8]) -> Option<u16> {
    let h = MailboxHeader::parse(mailbox)?;
    let coe = mailbox.get(MAILBOX_HEADER_LEN..MAILBOX_HEADER_LEN + COE_HEADER_LEN + 2)?;
    if h.kind != TYPE_COE || coe[1] >> 4 != SERVICE_EMERGENCY {
        return None;
    }
    Some(u16::from_le_bytes([coe[2], coe[3]]))
}

/// Writes an SDO upload request (a master's), for tests and examples; returns its length.
pub fn sdo_upload_request(out: &mut [u8], counter: u8, addr: Address) -> usize {
    MailboxHeader {
        length: (COE_HEADER_LEN + SDO_LEN) as u16,
        address: 0,
        channel: 0,
        kind: TYPE_COE,
        counter,
    }
    .write(out);
    out[6..8].copy_from_slice(&(u16::from(SERVICE_SDO_REQUEST) << 12).to_le_bytes());
    out[8] = 0x40;
    put_addr(&mut out[8..], addr);
    out[12..16].fill(0);
    MAILBOX_HEADER_LEN + COE_HEADER_LEN + SDO_LEN
}

/// Writes an SDO download request (expedited up to 4 bytes, normal beyond), for tests and
/// examples; returns its length.
pub fn sdo_download_request(out: &mut [u8], counter: u8, addr: Address, data: &[u8]) -> usize {
    let sdo_len = if data.len() <= 4 {
        SDO_LEN
    } else {
        SDO_LEN + data.len()
    };
    MailboxHeader {
        length: (COE_HEADER_LEN + sdo_len) as u16,
        address: 0,
        channel: 0,
        kind: TYPE_COE,
        counter,
    }
    .write(out);
    out[6..8].copy_from_slice(&(u16::from(SERVICE_SDO_REQUEST) << 12).to_le_bytes());
    let s = &mut out[8..];
    put_addr(s, addr);
    if data.len() <= 4 {
        s[0] = 0x23 | (((4 - data.len()) as u8) << 2);
        s[4..8].fill(0);
        s[4..4 + data.len()].copy_from_slice(data);
    } else {
        s[0] = 0x21;
        s[4..8].copy_from_slice(&(data.len() as u32).to_le_bytes());
        s[8..8 + data.len()].copy_from_slice(data);
    }
    MAILBOX_HEADER_LEN + COE_HEADER_LEN + sdo_len
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canopen::od::{AccessType, DataType, EntryDef, ObjectDictionary, Value};

    const NAME: Address = Address::new(0x1008, 0);
    const TYPE: Address = Address::new(0x1000, 0);
    const RW: Address = Address::new(0x2001, 0);
    const TEXT: Address = Address::new(0x2002, 0);

    fn od() -> ObjectDictionary<'static, 8, 1024> {
        let mut od = ObjectDictionary::new();
        od.insert(
            EntryDef::new(TYPE, "device type", DataType::Unsigned32, AccessType::Const)
                .default_value(Value::Unsigned(0x0002_012D)),
        )
        .unwrap();
        od.insert(
            EntryDef::new(NAME, "name", DataType::VisibleString, AccessType::Const)
                .capacity(300)
                .default_value(Value::Bytes(&[b'x'; 300])),
        )
        .unwrap();
        od.insert(EntryDef::new(
            RW,
            "rw",
            DataType::Unsigned16,
            AccessType::Rw,
        ))
        .unwrap();
        od.insert(EntryDef::new(TEXT, "text", DataType::OctetString, AccessType::Rw).capacity(200))
            .unwrap();
        od
    }

    /// The SDO bytes of a reply (after the mailbox and CoE headers).
    fn sdo(reply: &[u8]) -> &[u8] {
        &reply[8..]
    }

    fn request(cmd: u8, addr: Address, rest: &[u8], counter: u8) -> heapless::Vec<u8, 256> {
        let mut v = heapless::Vec::new();
        let len = (2 + 4 + rest.len()) as u16;
        v.extend_from_slice(&len.to_le_bytes()).unwrap();
        v.extend_from_slice(&[0, 0, 0, TYPE_COE | (counter << 4)])
            .unwrap();
        v.extend_from_slice(&0x2000u16.to_le_bytes()).unwrap();
        v.push(cmd).unwrap();
        v.extend_from_slice(&addr.index.to_le_bytes()).unwrap();
        v.push(addr.sub).unwrap();
        v.extend_from_slice(rest).unwrap();
        v
    }

    #[test]
    fn expedited_download_then_upload_round_trips_and_errors_abort() {
        let mut od = od();
        let mut s = CoeServer::new();
        let mut reply = [0u8; 128];
        let mut req = [0u8; 128];
        let n = sdo_download_request(&mut req, 1, RW, &[0x34, 0x12]);
        s.handle(&req[..n], &mut od, &mut reply).unwrap();
        assert_eq!(sdo(&reply)[0], 0x60);
        let n = sdo_upload_request(&mut req, 2, RW);
        s.handle(&req[..n], &mut od, &mut reply).unwrap();
        assert_eq!(&sdo(&reply)[..6], &[0x4B, 0x01, 0x20, 0x00, 0x34, 0x12]);
        // A constant refuses a write: abort 0601 0002h.
        let n = sdo_download_request(&mut req, 3, TYPE, &[0, 0, 0, 0]);
        s.handle(&req[..n], &mut od, &mut reply).unwrap();
        assert_eq!(sdo(&reply)[0], 0x80);
        assert_eq!(&sdo(&reply)[4..8], &0x0601_0002u32.to_le_bytes());
        // A missing object: 0602 0000h.
        let n = sdo_upload_request(&mut req, 4, Address::new(0x5000, 0));
        s.handle(&req[..n], &mut od, &mut reply).unwrap();
        assert_eq!(&sdo(&reply)[4..8], &0x0602_0000u32.to_le_bytes());
    }

    #[test]
    fn a_retried_request_is_answered_again_without_running_twice() {
        let mut od = od();
        let mut s = CoeServer::new();
        let mut reply = [0u8; 128];
        let mut again = [0u8; 128];
        let mut req = [0u8; 128];
        // A write of 1, then the same message again after the value changed behind it: the
        // retry must not write 1 a second time.
        let n = sdo_download_request(&mut req, 5, RW, &[1, 0]);
        let a = s.handle(&req[..n], &mut od, &mut reply).unwrap();
        od.set_u16(RW, 9).unwrap();
        let b = s.handle(&req[..n], &mut od, &mut again).unwrap();
        assert_eq!(&reply[..a], &again[..b]);
        assert_eq!(od.get_u16(RW), Ok(9));
        // The same counter with other bytes is a new request (a master that started over).
        let n = sdo_download_request(&mut req, 5, RW, &[2, 0]);
        s.handle(&req[..n], &mut od, &mut reply).unwrap();
        assert_eq!(od.get_u16(RW), Ok(2));
        // The server's own counter runs 1..7 and wraps.
        let mut counters = heapless::Vec::<u8, 16>::new();
        for c in 0..9u8 {
            let n = sdo_upload_request(&mut req, c % 7 + 1, TYPE);
            s.handle(&req[..n], &mut od, &mut reply).unwrap();
            counters.push(reply[5] >> 4).unwrap();
        }
        assert_eq!(&counters[..], &[3, 4, 5, 6, 7, 1, 2, 3, 4]);
    }

    #[test]
    fn a_long_value_uploads_in_segments_with_toggles() {
        let mut od = od();
        let mut s = CoeServer::new();
        let mut reply = [0u8; 128];
        let mut req = [0u8; 128];
        let n = sdo_upload_request(&mut req, 1, NAME);
        s.handle(&req[..n], &mut od, &mut reply).unwrap();
        assert_eq!(sdo(&reply)[0], 0x41);
        assert_eq!(&sdo(&reply)[4..8], &300u32.to_le_bytes());
        let first = usize::from(u16::from_le_bytes([reply[0], reply[1]])) - 2 - 8;
        assert_eq!(first, 128 - 16);
        let mut got = first;
        let mut toggle = false;
        let mut counter = 2;
        loop {
            let r = request(
                0x60 | (u8::from(toggle) << 4),
                Address::new(0, 0),
                &[0; 4],
                counter,
            );
            counter = counter % 7 + 1;
            let len = s.handle(&r, &mut od, &mut reply).unwrap();
            let cmd = sdo(&reply)[0];
            assert_eq!(cmd & 0x10 != 0, toggle);
            let data = len - 8 - 1;
            got += data.min(300 - got);
            toggle = !toggle;
            if cmd & 1 != 0 {
                break;
            }
        }
        assert_eq!(got, 300);
        // A segment request with no transfer is refused.
        let r = request(0x60, Address::new(0, 0), &[0; 4], counter);
        s.handle(&r, &mut od, &mut reply).unwrap();
        assert_eq!(sdo(&reply)[0], 0x80);
    }

    #[test]
    fn a_normal_download_in_one_mailbox_and_a_segmented_one_both_write() {
        let mut od = od();
        let mut s = CoeServer::new();
        let mut reply = [0u8; 128];
        let mut req = [0u8; 256];
        let text = [7u8; 20];
        let n = sdo_download_request(&mut req, 1, TEXT, &text);
        s.handle(&req[..n], &mut od, &mut reply).unwrap();
        assert_eq!(sdo(&reply)[0], 0x60);
        assert_eq!(od.raw(TEXT).unwrap(), &text);
        // 30 bytes: 10 in the initiate, 7 + 7 + 6 in segments.
        let mut rest = [0u8; 8];
        rest[..4].copy_from_slice(&30u32.to_le_bytes());
        let mut first = heapless::Vec::<u8, 16>::new();
        first.extend_from_slice(&rest[..4]).unwrap();
        first.extend_from_slice(&[1; 10]).unwrap();
        let r = request(0x21, TEXT, &first, 2);
        s.handle(&r, &mut od, &mut reply).unwrap();
        assert_eq!(sdo(&reply)[0], 0x60);
        let segs: [(u8, &[u8]); 3] = [
            (0x00, &[2; 7]),
            (0x10, &[3; 7]),
            // Last segment, toggle 0, one byte unused (6 of 7).
            ((1 << 1) | 1, &[4; 6]),
        ];
        for (i, (cmd, data)) in segs.iter().enumerate() {
            let mut v = heapless::Vec::<u8, 64>::new();
            v.extend_from_slice(&(2u16 + 1 + 7).to_le_bytes()).unwrap();
            v.extend_from_slice(&[0, 0, 0, TYPE_COE | ((3 + i as u8) << 4)])
                .unwrap();
            v.extend_from_slice(&0x2000u16.to_le_bytes()).unwrap();
            v.push(*cmd).unwrap();
            v.extend_from_slice(data).unwrap();
            while v.len() < 6 + 2 + 8 {
                v.push(0).unwrap();
            }
            s.handle(&v, &mut od, &mut reply).unwrap();
            assert_eq!(sdo(&reply)[0] & 0xE0, 0x20, "segment {i}");
        }
        let stored = od.raw(TEXT).unwrap();
        assert_eq!(stored.len(), 30);
        assert_eq!(&stored[..10], &[1; 10]);
        assert_eq!(&stored[24..], &[4; 6]);
    }

    #[test]
    fn other_protocols_and_services_get_mailbox_errors() {
        let mut od = od();
        let mut s = CoeServer::new();
        let mut reply = [0u8; 128];
        let mut req = [0u8; 128];
        let n = sdo_upload_request(&mut req, 1, TYPE);
        req[5] = 0x14; // FoE
        s.handle(&req[..n], &mut od, &mut reply).unwrap();
        assert_eq!(reply[5] & 0x0F, TYPE_ERROR);
        assert_eq!(&reply[8..10], &MBX_ERR_UNSUPPORTED_PROTOCOL.to_le_bytes());
        let n = sdo_upload_request(&mut req, 2, TYPE);
        req[7] = 0x80; // SDO information
        s.handle(&req[..n], &mut od, &mut reply).unwrap();
        assert_eq!(&reply[8..10], &MBX_ERR_SERVICE_NOT_SUPPORTED.to_le_bytes());
    }

    #[test]
    fn an_emergency_carries_code_register_and_data() {
        let mut s = CoeServer::new();
        let mut out = [0u8; 64];
        let n = s.emergency(0x8100, 0x11, [0x50, 0, 0, 0, 0], &mut out);
        assert_eq!(n, 16);
        assert_eq!(out[7] >> 4, SERVICE_EMERGENCY);
        assert_eq!(&out[8..11], &[0x00, 0x81, 0x11]);
    }
}
