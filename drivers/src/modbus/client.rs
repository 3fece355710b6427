//! The Modbus TCP client codec: requests in, checked responses out, no I/O.
//!
//! The coordinator exchanges the 8-byte FHPP image with a CMMO-ST once per cycle with FC 0x17
//! (write the 4 output registers from register 0, then read the 4 input registers from
//! register 0, in one transaction), and uses FC 0x03 / 0x10 for parameter access outside the
//! cycle. Every request carries a transaction id; [`decode_response`] checks the answer against
//! what was asked ([`Expected`]): transaction and unit id, function code, byte count, lengths.
//!
//! Sans-I/O: [`encode_request`] writes into a caller's `&mut [u8]`, [`decode_response`] reads
//! a `&[u8]`, and [`frame_len`] finds frame boundaries in a TCP byte stream. In virtual time the
//! encoded bytes can go straight to the simulated server's `Session::handle_frame` and its
//! answer straight back into [`Client::handle_response`].
//!
//! ```
//! use drivers::modbus::client::{Client, MAX_ADU};
//! let mut client = Client::new(0);
//! let mut buf = [0u8; MAX_ADU];
//! let n = client.exchange_image(&[0x43, 0, 0, 0, 0, 0, 0, 0], &mut buf).unwrap();
//! assert_eq!(&buf[7..17], &[0x17, 0, 0, 0, 4, 0, 0, 0, 4, 8]);
//! // The answer: transaction id 1, FC 0x17, 8 bytes of status.
//! let answer = [0, 1, 0, 0, 0, 11, 0, 0x17, 8, 0x17, 0x05, 0, 0, 0, 0, 0, 0];
//! let image = client.handle_response(&answer).unwrap().image();
//! assert_eq!(image, Some([0x17, 0x05, 0, 0, 0, 0, 0, 0]));
//! # let _ = n;
//! ```

/// Length of the MBAP header (transaction id, protocol id, length, unit id).
pub const MBAP_LEN: usize = 7;
/// The largest PDU Modbus allows (function code + 252 bytes).
pub const MAX_PDU: usize = 253;
/// The largest ADU; a buffer this long holds any request or response.
pub const MAX_ADU: usize = MBAP_LEN + MAX_PDU;

/// FC 0x03 Read Holding Registers.
pub const FC_READ_HOLDING_REGISTERS: u8 = 0x03;
/// FC 0x10 Write Multiple Registers.
pub const FC_WRITE_MULTIPLE_REGISTERS: u8 = 0x10;
/// FC 0x17 Read/Write Multiple Registers: the cyclic exchange.
pub const FC_READ_WRITE_MULTIPLE_REGISTERS: u8 = 0x17;
/// Set in the function code of an exception response.
pub const EXCEPTION_FLAG: u8 = 0x80;

/// First register of both images on the CMMO-ST (the register space is split by direction).
pub const IMAGE_START: u16 = 0;
/// Registers of the "FHPP standard" image, each direction.
pub const IMAGE_REGISTERS: u16 = 4;

/// The Modbus limits on quantities per request (application protocol, §6.3, 6.12, 6.17).
const MAX_READ: u16 = 125;
const MAX_WRITE: u16 = 123;
const MAX_READ_WRITE_WRITE: u16 = 121;

/// A request the client can send. Register values are big-endian register bytes (2 per
/// register), which for FHPP are exactly the image bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Request<'a> {
    /// FC 0x03: read `quantity` registers from `start`.
    ReadHoldingRegisters {
        /// First register.
        start: u16,
        /// Registers to read (1..=125).
        quantity: u16,
    },
    /// FC 0x10: write `values` (an even number of bytes) from `start`.
    WriteMultipleRegisters {
        /// First register.
        start: u16,
        /// 2..=246 bytes.
        values: &'a [u8],
    },
    /// FC 0x17: write `values` from `write_start`, then read `read_quantity` from `read_start`.
    ReadWriteMultipleRegisters {
        /// First register read.
        read_start: u16,
        /// Registers read (1..=125).
        read_quantity: u16,
        /// First register written.
        write_start: u16,
        /// 2..=242 bytes.
        values: &'a [u8],
    },
}

impl<'a> Request<'a> {
    /// The cyclic FHPP exchange: write the 8 control bytes to registers 0..4 and read the 8
    /// status bytes from registers 0..4.
    pub const fn image_exchange(output: &'a [u8; 8]) -> Request<'a> {
        Request::ReadWriteMultipleRegisters {
            read_start: IMAGE_START,
            read_quantity: IMAGE_REGISTERS,
            write_start: IMAGE_START,
            values: output,
        }
    }

    /// The function code.
    pub const fn function(&self) -> u8 {
        match self {
            Request::ReadHoldingRegisters { .. } => FC_READ_HOLDING_REGISTERS,
            Request::WriteMultipleRegisters { .. } => FC_WRITE_MULTIPLE_REGISTERS,
            Request::ReadWriteMultipleRegisters { .. } => FC_READ_WRITE_MULTIPLE_REGISTERS,
        }
    }

    /// The PDU length (function code included).
    pub const fn pdu_len(&self) -> usize {
        match self {
            Request::ReadHoldingRegisters { .. } => 5,
            Request::WriteMultipleRegisters { values, .. } => 6 + values.len(),
            Request::ReadWriteMultipleRegisters { values, .. } => 10 + values.len(),
        }
    }

    /// What a correct answer to this request looks like, once sent with these ids.
    pub const fn expected(&self, transaction_id: u16, unit_id: u8) -> Expected {
        let answer = match *self {
            Request::ReadHoldingRegisters { quantity, .. } => Answer::Registers {
                function: FC_READ_HOLDING_REGISTERS,
                quantity,
            },
            Request::WriteMultipleRegisters { start, values } => Answer::Written {
                start,
                // Checked by encode_request: at most 246 bytes.
                quantity: (values.len() / 2) as u16,
            },
            Request::ReadWriteMultipleRegisters { read_quantity, .. } => Answer::Registers {
                function: FC_READ_WRITE_MULTIPLE_REGISTERS,
                quantity: read_quantity,
            },
        };
        Expected {
            transaction_id,
            unit_id,
            answer,
        }
    }

    fn check(&self) -> Result<(), EncodeError> {
        let registers = |values: &[u8], max: u16| {
            let n = values.len() / 2;
            if !values.len().is_multiple_of(2) || n == 0 || n > usize::from(max) {
                Err(EncodeError::ValueBytes { len: values.len() })
            } else {
                Ok(())
            }
        };
        let quantity = |q: u16| {
            if (1..=MAX_READ).contains(&q) {
                Ok(())
            } else {
                Err(EncodeError::Quantity { quantity: q })
            }
        };
        match *self {
            Request::ReadHoldingRegisters { quantity: q, .. } => quantity(q),
            Request::WriteMultipleRegisters { values, .. } => registers(values, MAX_WRITE),
            Request::ReadWriteMultipleRegisters {
                read_quantity,
                values,
                ..
            } => {
                quantity(read_quantity)?;
                registers(values, MAX_READ_WRITE_WRITE)
            }
        }
    }
}

/// What the answer to a request sent must look like: [`decode_response`] checks against it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Expected {
    /// The request's transaction id, echoed by the server.
    pub transaction_id: u16,
    /// The request's unit id, echoed by the server.
    pub unit_id: u8,
    /// The answer's shape.
    pub answer: Answer,
}

/// The shape of a normal answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Answer {
    /// FC 0x03 or 0x17: a byte count of `2 * quantity`, then the register bytes.
    Registers {
        /// 0x03 or 0x17.
        function: u8,
        /// Registers read.
        quantity: u16,
    },
    /// FC 0x10: the start and quantity echoed.
    Written {
        /// First register written.
        start: u16,
        /// Registers written.
        quantity: u16,
    },
}

impl Answer {
    /// The function code the answer must carry.
    pub const fn function(&self) -> u8 {
        match self {
            Answer::Registers { function, .. } => *function,
            Answer::Written { .. } => FC_WRITE_MULTIPLE_REGISTERS,
        }
    }
}

/// Why a request could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// The output buffer is shorter than the ADU.
    #[error("the request needs {needed} bytes, the buffer has {available}")]
    BufferTooSmall {
        /// ADU length.
        needed: usize,
        /// Buffer length.
        available: usize,
    },
    /// A read quantity outside 1..=125.
    #[error("read quantity {quantity} is outside 1..=125")]
    Quantity {
        /// The quantity asked for.
        quantity: u16,
    },
    /// Register values that are not whole registers or more than one PDU carries.
    #[error("{len} value bytes are not 1..=123 (0x10) or 1..=121 (0x17) whole registers")]
    ValueBytes {
        /// Bytes given.
        len: usize,
    },
    /// [`Client`] has a request outstanding; answer or cancel it first.
    #[error("transaction {transaction_id} is still outstanding")]
    Busy {
        /// The outstanding transaction.
        transaction_id: u16,
    },
}

/// Why received bytes are not the answer expected. Everything a peer can send maps to one of
/// these; nothing panics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ResponseError {
    /// Fewer bytes than an MBAP header and a function code.
    #[error("{len} bytes are too few for a Modbus TCP response")]
    Truncated {
        /// Bytes received.
        len: usize,
    },
    /// The MBAP length field announces no PDU or one beyond 253 bytes.
    #[error("MBAP length {length} is outside 2..=254")]
    BadLength {
        /// The length field.
        length: u16,
    },
    /// The frame is shorter or longer than its MBAP length field says.
    #[error("MBAP length {length} means {expected} bytes, the frame has {received}")]
    FrameLength {
        /// The length field.
        length: u16,
        /// 6 + length.
        expected: usize,
        /// Bytes received.
        received: usize,
    },
    /// The protocol id is not 0: not Modbus.
    #[error("protocol id {id} is not Modbus (0)")]
    ProtocolId {
        /// The protocol id received.
        id: u16,
    },
    /// An answer to another transaction (a late answer to an abandoned request, or garbage).
    #[error("transaction id {got}, expected {expected}")]
    WrongTransaction {
        /// The id sent.
        expected: u16,
        /// The id received.
        got: u16,
    },
    /// The unit id is not echoed.
    #[error("unit id {got}, expected {expected}")]
    WrongUnit {
        /// The id sent.
        expected: u8,
        /// The id received.
        got: u8,
    },
    /// A function code that is neither the request's nor its exception.
    #[error("function code {got:#04x}, expected {expected:#04x}")]
    WrongFunction {
        /// The request's function code.
        expected: u8,
        /// The function code received.
        got: u8,
    },
    /// The server refused the request with an exception code (0x01 illegal function, 0x02
    /// illegal data address, 0x03 illegal data value, 0x04 server device failure, ...).
    #[error("exception {code:#04x} for function code {function:#04x}")]
    Exception {
        /// The request's function code.
        function: u8,
        /// The exception code.
        code: u8,
    },
    /// A register answer whose byte count is not twice the quantity asked for.
    #[error("byte count {got}, expected {expected}")]
    ByteCount {
        /// 2 * quantity.
        expected: usize,
        /// The byte count received.
        got: u8,
    },
    /// The PDU is shorter or longer than its function code (and byte count) say.
    #[error("PDU of {got} bytes, expected {expected}")]
    PduLength {
        /// What the function code and byte count imply.
        expected: usize,
        /// What the frame carries.
        got: usize,
    },
    /// A write answer that does not echo the start and quantity written.
    #[error("write echo start {start} quantity {quantity} does not match the request")]
    WriteEcho {
        /// Start echoed.
        start: u16,
        /// Quantity echoed.
        quantity: u16,
    },
    /// [`Client::handle_response`] with no request outstanding.
    #[error("no request is outstanding")]
    NotPending,
}

/// Encodes `request` as a whole ADU into `out` and returns its length and what its answer
/// must look like.
pub fn encode_request(
    transaction_id: u16,
    unit_id: u8,
    request: &Request<'_>,
    out: &mut [u8],
) -> Result<(usize, Expected), EncodeError> {
    request.check()?;
    let pdu_len = request.pdu_len();
    let needed = MBAP_LEN + pdu_len;
    let available = out.len();
    let adu = out
        .get_mut(..needed)
        .ok_or(EncodeError::BufferTooSmall { needed, available })?;
    let mut w = Writer { buf: adu, at: 0 };
    w.u16(transaction_id);
    w.u16(0);
    // pdu_len <= 10 + 242, so the length field cannot overflow.
    w.u16((pdu_len + 1) as u16);
    w.bytes(&[unit_id, request.function()]);
    match *request {
        Request::ReadHoldingRegisters { start, quantity } => {
            w.u16(start);
            w.u16(quantity);
        }
        Request::WriteMultipleRegisters { start, values } => {
            w.u16(start);
            w.u16((values.len() / 2) as u16);
            w.bytes(&[values.len() as u8]);
            w.bytes(values);
        }
        Request::ReadWriteMultipleRegisters {
            read_start,
            read_quantity,
            write_start,
            values,
        } => {
            w.u16(read_start);
            w.u16(read_quantity);
            w.u16(write_start);
            w.u16((values.len() / 2) as u16);
            w.bytes(&[values.len() as u8]);
            w.bytes(values);
        }
    }
    Ok((needed, request.expected(transaction_id, unit_id)))
}

/// Writes into a buffer already checked to be long enough; a short one drops bytes instead of
/// panicking.
struct Writer<'b> {
    buf: &'b mut [u8],
    at: usize,
}

impl Writer<'_> {
    fn bytes(&mut self, b: &[u8]) {
        if let Some(dst) = self.buf.get_mut(self.at..self.at + b.len()) {
            dst.copy_from_slice(b);
        }
        self.at += b.len();
    }
    fn u16(&mut self, v: u16) {
        self.bytes(&v.to_be_bytes());
    }
}

/// A checked normal answer. Register bytes are big-endian registers: for FHPP, the image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Response<'a> {
    /// FC 0x03 or 0x17: the register bytes read (2 per register).
    Registers(&'a [u8]),
    /// FC 0x10: the write was done.
    Written {
        /// First register written.
        start: u16,
        /// Registers written.
        quantity: u16,
    },
}

impl Response<'_> {
    /// The 8-byte FHPP image, if this is a read of exactly 4 registers.
    pub fn image(&self) -> Option<[u8; 8]> {
        match self {
            Response::Registers(bytes) => (*bytes).try_into().ok(),
            Response::Written { .. } => None,
        }
    }

    /// The registers read into `regs` (see [`super::bytes_to_registers`]); 0 for a write.
    pub fn registers(&self, regs: &mut [u16]) -> usize {
        match self {
            Response::Registers(bytes) => super::bytes_to_registers(bytes, regs),
            Response::Written { .. } => 0,
        }
    }
}

fn be16(bytes: &[u8], at: usize) -> Option<u16> {
    match bytes.get(at..at + 2) {
        Some([hi, lo]) => Some(u16::from_be_bytes([*hi, *lo])),
        _ => None,
    }
}

/// The length of the first whole ADU at the front of `stream` (bytes received so far):
/// `Ok(None)` while it is incomplete; `Err` when its header is impossible (the stream cannot be
/// resynchronised: close the connection).
pub fn frame_len(stream: &[u8]) -> Result<Option<usize>, ResponseError> {
    let Some(length) = be16(stream, 4) else {
        return Ok(None);
    };
    if !(2..=MAX_PDU as u16 + 1).contains(&length) {
        return Err(ResponseError::BadLength { length });
    }
    let total = 6 + usize::from(length);
    Ok((stream.len() >= total).then_some(total))
}

/// Decodes one whole response ADU (exactly one frame, as [`frame_len`] delimits it) and checks
/// it against the request it answers.
pub fn decode_response<'a>(
    adu: &'a [u8],
    expected: &Expected,
) -> Result<Response<'a>, ResponseError> {
    let (Some(tid), Some(protocol), Some(length), Some(&unit), Some(&function)) = (
        be16(adu, 0),
        be16(adu, 2),
        be16(adu, 4),
        adu.get(6),
        adu.get(MBAP_LEN),
    ) else {
        return Err(ResponseError::Truncated { len: adu.len() });
    };
    if protocol != 0 {
        return Err(ResponseError::ProtocolId { id: protocol });
    }
    if !(2..=MAX_PDU as u16 + 1).contains(&length) {
        return Err(ResponseError::BadLength { length });
    }
    let total = 6 + usize::from(length);
    if adu.len() != total {
        return Err(ResponseError::FrameLength {
            length,
            expected: total,
            received: adu.len(),
        });
    }
    if tid != expected.transaction_id {
        return Err(ResponseError::WrongTransaction {
            expected: expected.transaction_id,
            got: tid,
        });
    }
    if unit != expected.unit_id {
        return Err(ResponseError::WrongUnit {
            expected: expected.unit_id,
            got: unit,
        });
    }
    let pdu = adu.get(MBAP_LEN..).unwrap_or(&[]);
    let want = expected.answer.function();
    if function == want | EXCEPTION_FLAG {
        return match pdu {
            [_, code] => Err(ResponseError::Exception {
                function: want,
                code: *code,
            }),
            _ => Err(ResponseError::PduLength {
                expected: 2,
                got: pdu.len(),
            }),
        };
    }
    if function != want {
        return Err(ResponseError::WrongFunction {
            expected: want,
            got: function,
        });
    }
    match expected.answer {
        Answer::Registers { quantity, .. } => {
            let count = *pdu.get(1).ok_or(ResponseError::PduLength {
                expected: 2,
                got: pdu.len(),
            })?;
            let bytes = 2 * usize::from(quantity);
            if usize::from(count) != bytes {
                return Err(ResponseError::ByteCount {
                    expected: bytes,
                    got: count,
                });
            }
            match pdu.get(2..) {
                Some(values) if values.len() == bytes => Ok(Response::Registers(values)),
                _ => Err(ResponseError::PduLength {
                    expected: 2 + bytes,
                    got: pdu.len(),
                }),
            }
        }
        Answer::Written { start, quantity } => {
            if pdu.len() != 5 {
                return Err(ResponseError::PduLength {
                    expected: 5,
                    got: pdu.len(),
                });
            }
            let (s, q) = (be16(pdu, 1).unwrap_or(0), be16(pdu, 3).unwrap_or(0));
            if (s, q) != (start, quantity) {
                return Err(ResponseError::WriteEcho {
                    start: s,
                    quantity: q,
                });
            }
            Ok(Response::Written { start, quantity })
        }
    }
}

/// One connection's client: numbers transactions and keeps the one outstanding request.
///
/// One request at a time is what the CMMO-ST needs (it answers in order, one client), and it
/// makes a stale answer (to a request given up on) recognisable by its transaction id.
#[derive(Debug, Clone)]
pub struct Client {
    unit_id: u8,
    next_tid: u16,
    pending: Option<Expected>,
}

impl Client {
    /// A client whose first transaction id is 1. The CMMO-ST ignores the unit id (use 0).
    pub const fn new(unit_id: u8) -> Client {
        Client {
            unit_id,
            next_tid: 1,
            pending: None,
        }
    }

    /// The outstanding request, if any.
    pub fn pending(&self) -> Option<&Expected> {
        self.pending.as_ref()
    }

    /// Encodes `request` with the next transaction id into `out`; returns the ADU length.
    pub fn request(&mut self, request: &Request<'_>, out: &mut [u8]) -> Result<usize, EncodeError> {
        if let Some(p) = self.pending {
            return Err(EncodeError::Busy {
                transaction_id: p.transaction_id,
            });
        }
        let (n, expected) = encode_request(self.next_tid, self.unit_id, request, out)?;
        self.next_tid = self.next_tid.wrapping_add(1);
        self.pending = Some(expected);
        Ok(n)
    }

    /// The cyclic exchange ([`Request::image_exchange`]).
    pub fn exchange_image(
        &mut self,
        output: &[u8; 8],
        out: &mut [u8],
    ) -> Result<usize, EncodeError> {
        self.request(&Request::image_exchange(output), out)
    }

    /// Decodes an answer to the outstanding request. A frame of another transaction leaves the
    /// request outstanding (a late answer to an abandoned one); any other outcome, error or
    /// not, completes it.
    pub fn handle_response<'a>(&mut self, adu: &'a [u8]) -> Result<Response<'a>, ResponseError> {
        let expected = self.pending.ok_or(ResponseError::NotPending)?;
        let result = decode_response(adu, &expected);
        if !matches!(
            result,
            Err(ResponseError::WrongTransaction { .. } | ResponseError::Truncated { .. })
        ) {
            self.pending = None;
        }
        result
    }

    /// Gives up on the outstanding request (timeout, reconnection). Its answer, should it still
    /// come, is then a [`ResponseError::WrongTransaction`] for the next one.
    pub fn cancel(&mut self) {
        self.pending = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn exchange_expected(tid: u16) -> Expected {
        Request::image_exchange(&[0; 8]).expected(tid, 0)
    }

    #[test]
    fn encodes_the_image_exchange_byte_for_byte() {
        let mut out = [0u8; MAX_ADU];
        let image = [0x43, 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07];
        let (n, exp) =
            encode_request(0x1234, 0x05, &Request::image_exchange(&image), &mut out).unwrap();
        assert_eq!(
            &out[..n],
            &[
                0x12, 0x34, 0, 0, 0, 19, 0x05, 0x17, 0, 0, 0, 4, 0, 0, 0, 4, 8, 0x43, 0x01, 0x02,
                0x03, 0x04, 0x05, 0x06, 0x07
            ]
        );
        assert_eq!(
            exp.answer,
            Answer::Registers {
                function: 0x17,
                quantity: 4
            }
        );
    }

    #[test]
    fn encodes_read_and_write() {
        let mut out = [0u8; MAX_ADU];
        let r = Request::ReadHoldingRegisters {
            start: 0,
            quantity: 4,
        };
        let (n, _) = encode_request(7, 0, &r, &mut out).unwrap();
        assert_eq!(&out[..n], &[0, 7, 0, 0, 0, 6, 0, 0x03, 0, 0, 0, 4]);
        let w = Request::WriteMultipleRegisters {
            start: 0,
            values: &[0xAA, 0xBB, 0xCC, 0xDD],
        };
        let (n, exp) = encode_request(8, 0, &w, &mut out).unwrap();
        assert_eq!(
            &out[..n],
            &[
                0, 8, 0, 0, 0, 11, 0, 0x10, 0, 0, 0, 2, 4, 0xAA, 0xBB, 0xCC, 0xDD
            ]
        );
        assert_eq!(
            exp.answer,
            Answer::Written {
                start: 0,
                quantity: 2
            }
        );
    }

    #[test]
    fn refuses_what_cannot_be_encoded() {
        let mut out = [0u8; MAX_ADU];
        let r = Request::ReadHoldingRegisters {
            start: 0,
            quantity: 0,
        };
        assert_eq!(
            encode_request(1, 0, &r, &mut out),
            Err(EncodeError::Quantity { quantity: 0 })
        );
        let odd = Request::WriteMultipleRegisters {
            start: 0,
            values: &[1, 2, 3],
        };
        assert_eq!(
            encode_request(1, 0, &odd, &mut out),
            Err(EncodeError::ValueBytes { len: 3 })
        );
        let big = [0u8; 244];
        let too_many = Request::ReadWriteMultipleRegisters {
            read_start: 0,
            read_quantity: 4,
            write_start: 0,
            values: &big,
        };
        assert_eq!(
            encode_request(1, 0, &too_many, &mut out),
            Err(EncodeError::ValueBytes { len: 244 })
        );
        let mut short = [0u8; 20];
        assert_eq!(
            encode_request(1, 0, &Request::image_exchange(&[0; 8]), &mut short),
            Err(EncodeError::BufferTooSmall {
                needed: 25,
                available: 20
            })
        );
    }

    #[test]
    fn decodes_registers_and_every_kind_of_wrong_answer() {
        let exp = exchange_expected(0x0102);
        let good = [1, 2, 0, 0, 0, 11, 0, 0x17, 8, 0x17, 0x05, 1, 2, 3, 4, 5, 6];
        assert_eq!(
            decode_response(&good, &exp),
            Ok(Response::Registers(&good[9..]))
        );
        let mut regs = [0u16; 4];
        assert_eq!(Response::Registers(&good[9..]).registers(&mut regs), 4);
        assert_eq!(regs, [0x1705, 0x0102, 0x0304, 0x0506]);

        let mut bad = good;
        bad[1] = 3;
        assert_eq!(
            decode_response(&bad, &exp),
            Err(ResponseError::WrongTransaction {
                expected: 0x0102,
                got: 0x0103
            })
        );
        let mut bad = good;
        bad[3] = 1;
        assert_eq!(
            decode_response(&bad, &exp),
            Err(ResponseError::ProtocolId { id: 1 })
        );
        let mut bad = good;
        bad[6] = 9;
        assert_eq!(
            decode_response(&bad, &exp),
            Err(ResponseError::WrongUnit {
                expected: 0,
                got: 9
            })
        );
        let mut bad = good;
        bad[7] = 0x03;
        assert_eq!(
            decode_response(&bad, &exp),
            Err(ResponseError::WrongFunction {
                expected: 0x17,
                got: 0x03
            })
        );
        // Byte count 6 in a frame that still carries 8.
        let mut bad = good;
        bad[8] = 6;
        assert_eq!(
            decode_response(&bad, &exp),
            Err(ResponseError::ByteCount {
                expected: 8,
                got: 6
            })
        );
        // Short frame: one register byte missing, MBAP length still says 11.
        assert_eq!(
            decode_response(&good[..16], &exp),
            Err(ResponseError::FrameLength {
                length: 11,
                expected: 17,
                received: 16
            })
        );
        // Long frame, consistently announced: PDU longer than the byte count says.
        let mut long = [0u8; 18];
        long[..17].copy_from_slice(&good);
        long[5] = 12;
        assert_eq!(
            decode_response(&long, &exp),
            Err(ResponseError::PduLength {
                expected: 10,
                got: 11
            })
        );
        assert_eq!(
            decode_response(&good[..5], &exp),
            Err(ResponseError::Truncated { len: 5 })
        );
        let mut bad = good;
        bad[5] = 1;
        assert_eq!(
            decode_response(&bad, &exp),
            Err(ResponseError::BadLength { length: 1 })
        );
    }

    #[test]
    fn decodes_exceptions_and_write_echoes() {
        let exp = exchange_expected(5);
        let exc = [0, 5, 0, 0, 0, 3, 0, 0x97, 0x02];
        assert_eq!(
            decode_response(&exc, &exp),
            Err(ResponseError::Exception {
                function: 0x17,
                code: 0x02
            })
        );
        let exc_long = [0, 5, 0, 0, 0, 4, 0, 0x97, 0x02, 0];
        assert_eq!(
            decode_response(&exc_long, &exp),
            Err(ResponseError::PduLength {
                expected: 2,
                got: 3
            })
        );
        let w = Request::WriteMultipleRegisters {
            start: 0,
            values: &[0; 8],
        }
        .expected(6, 0);
        let echo = [0, 6, 0, 0, 0, 6, 0, 0x10, 0, 0, 0, 4];
        assert_eq!(
            decode_response(&echo, &w),
            Ok(Response::Written {
                start: 0,
                quantity: 4
            })
        );
        let wrong = [0, 6, 0, 0, 0, 6, 0, 0x10, 0, 1, 0, 4];
        assert_eq!(
            decode_response(&wrong, &w),
            Err(ResponseError::WriteEcho {
                start: 1,
                quantity: 4
            })
        );
    }

    #[test]
    fn frame_len_finds_boundaries_in_a_stream() {
        let two = [
            0, 1, 0, 0, 0, 3, 0, 0x97, 0x02, 0, 2, 0, 0, 0, 6, 0, 0x10, 0, 0, 0, 4,
        ];
        assert_eq!(frame_len(&two[..5]), Ok(None));
        assert_eq!(frame_len(&two[..8]), Ok(None));
        assert_eq!(frame_len(&two), Ok(Some(9)));
        assert_eq!(frame_len(&two[9..]), Ok(Some(12)));
        assert_eq!(
            frame_len(&[0, 1, 0, 0, 1, 0]),
            Err(ResponseError::BadLength { length: 256 })
        );
    }

    #[test]
    fn client_numbers_transactions_and_recognises_stale_answers() {
        let mut c = Client::new(0);
        let mut out = [0u8; MAX_ADU];
        c.exchange_image(&[0; 8], &mut out).unwrap();
        assert_eq!(c.pending().map(|p| p.transaction_id), Some(1));
        assert_eq!(
            c.exchange_image(&[0; 8], &mut out),
            Err(EncodeError::Busy { transaction_id: 1 })
        );
        // Give up on 1, send 2; the late answer to 1 is recognised and 2 stays outstanding.
        c.cancel();
        c.exchange_image(&[0; 8], &mut out).unwrap();
        let late = [0, 1, 0, 0, 0, 11, 0, 0x17, 8, 0, 0, 0, 0, 0, 0, 0, 0];
        assert_eq!(
            c.handle_response(&late),
            Err(ResponseError::WrongTransaction {
                expected: 2,
                got: 1
            })
        );
        assert!(c.pending().is_some());
        let answer = [0, 2, 0, 0, 0, 11, 0, 0x17, 8, 0x17, 0, 0, 0, 0, 0, 0, 0];
        assert_eq!(
            c.handle_response(&answer).unwrap().image(),
            Some([0x17, 0, 0, 0, 0, 0, 0, 0])
        );
        assert_eq!(c.handle_response(&answer), Err(ResponseError::NotPending));
    }

    #[test]
    fn transaction_ids_wrap() {
        let mut c = Client::new(0);
        c.next_tid = u16::MAX;
        let mut out = [0u8; MAX_ADU];
        c.exchange_image(&[0; 8], &mut out).unwrap();
        assert_eq!(&out[..2], &[0xFF, 0xFF]);
        c.cancel();
        c.exchange_image(&[0; 8], &mut out).unwrap();
        assert_eq!(&out[..2], &[0, 0]);
    }

    proptest::proptest! {
        /// Any bytes against any expectation: an answer or an error, never a panic; an accepted
        /// register answer is exactly the quantity asked for.
        #[test]
        fn decode_never_panics(
            adu in proptest::collection::vec(proptest::num::u8::ANY, 0..40),
            tid in 0u16..4,
            quantity in 1u16..6,
            fc in proptest::sample::select(vec![0x03u8, 0x17]),
        ) {
            let exp = Expected {
                transaction_id: tid,
                unit_id: 0,
                answer: Answer::Registers { function: fc, quantity },
            };
            if let Ok(Response::Registers(b)) = decode_response(&adu, &exp) {
                proptest::prop_assert_eq!(b.len(), 2 * usize::from(quantity));
            }
            let _ = frame_len(&adu);
        }
    }

    /// Checked against the simulated server's codec, written independently.
    #[cfg(feature = "std")]
    mod against_the_server {
        use super::super::*;
        use crate::sim::cmmo_st::mbap::{self, MbapHeader};
        use crate::sim::cmmo_st::{Config, FhppDevice, Identification, Session};
        use crate::time::Instant;

        #[test]
        fn client_requests_decode_as_the_server_reads_them() {
            let mut out = [0u8; MAX_ADU];
            let image = [0x43, 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07];
            let (n, _) = encode_request(9, 0, &Request::image_exchange(&image), &mut out).unwrap();
            let h = MbapHeader::from_bytes(&out[..n]).unwrap();
            assert_eq!(h.transaction_id, 9);
            assert_eq!(h.pdu_len().unwrap() + mbap::MBAP_LEN, n);
            assert_eq!(
                mbap::decode_request(&out[mbap::MBAP_LEN..n]),
                Ok(mbap::Request::ReadWriteMultipleRegisters {
                    read_start: 0,
                    read_quantity: 4,
                    write_start: 0,
                    write_quantity: 4,
                    values: &image,
                })
            );
            let r = Request::ReadHoldingRegisters {
                start: 0,
                quantity: 4,
            };
            let (n, _) = encode_request(10, 0, &r, &mut out).unwrap();
            assert_eq!(
                mbap::decode_request(&out[mbap::MBAP_LEN..n]),
                Ok(mbap::Request::ReadHoldingRegisters {
                    start: 0,
                    quantity: 4
                })
            );
            let w = Request::WriteMultipleRegisters {
                start: 0,
                values: &image,
            };
            let (n, _) = encode_request(11, 0, &w, &mut out).unwrap();
            assert_eq!(
                mbap::decode_request(&out[mbap::MBAP_LEN..n]),
                Ok(mbap::Request::WriteMultipleRegisters {
                    start: 0,
                    quantity: 4,
                    values: &image,
                })
            );
        }

        #[test]
        fn server_responses_decode_as_the_client_expects() {
            let req = MbapHeader {
                transaction_id: 0x0A0B,
                protocol_id: 0,
                length: 0,
                unit_id: 3,
            };
            let mut out = [0u8; mbap::MAX_ADU];
            let n = mbap::encode_response(&req, &[0x17, 8, 0x17, 0x05, 0, 0, 0, 0, 0, 0], &mut out);
            let exp = Request::image_exchange(&[0; 8]).expected(0x0A0B, 3);
            assert_eq!(frame_len(&out[..n]), Ok(Some(n)));
            assert_eq!(
                decode_response(&out[..n], &exp).unwrap().image(),
                Some([0x17, 0x05, 0, 0, 0, 0, 0, 0])
            );
            let exc = mbap::Exception {
                function: 0x17,
                code: mbap::ExceptionCode::IllegalDataAddress,
            };
            let n = mbap::encode_response(&req, &exc.to_bytes(), &mut out);
            assert_eq!(
                decode_response(&out[..n], &exp),
                Err(ResponseError::Exception {
                    function: 0x17,
                    code: 0x02
                })
            );
        }

        /// Echoes the output's CCON into SCON, so the round trip shows which bytes went where.
        struct Echo;
        impl FhppDevice for Echo {
            fn exchange(&mut self, o: &[u8; 8], _now: Instant) -> [u8; 8] {
                [o[0], 0x04, o[2], 0, o[4], o[5], o[6], o[7]]
            }
            fn parameter(&mut self, _r: &[u8; 8], _now: Instant) -> [u8; 8] {
                [0; 8]
            }
            fn step_to(&mut self, _now: Instant) {}
            fn fault_number(&self) -> u16 {
                0
            }
            fn identification(&self) -> Identification<'_> {
                Identification::default()
            }
            fn master_control(&self) -> bool {
                true
            }
        }

        #[test]
        fn client_and_session_exchange_images_in_virtual_time() {
            let mut session = Session::new(Config::default()).unwrap();
            let mut dev = Echo;
            assert!(session.connect(&mut dev, Instant::ZERO));
            let mut client = Client::new(0);
            let mut req = [0u8; MAX_ADU];
            let mut resp = [0u8; mbap::MAX_ADU];
            for k in 0..5u8 {
                let image = [0x40 | k, 0, k, 0, 1, 2, 3, k];
                let n = client.exchange_image(&image, &mut req).unwrap();
                let m = session
                    .handle_frame(
                        &req[..n],
                        &mut dev,
                        Instant::from_millis(k.into()),
                        &mut resp,
                    )
                    .unwrap()
                    .unwrap();
                let input = client.handle_response(&resp[..m]).unwrap().image().unwrap();
                assert_eq!(input, [0x40 | k, 0x04, k, 0, 1, 2, 3, k]);
                assert_eq!(session.output_image(), &image);
            }
            // A quantity the device refuses: its exception reaches the caller typed.
            let r = Request::ReadHoldingRegisters {
                start: 1,
                quantity: 4,
            };
            let n = client.request(&r, &mut req).unwrap();
            let m = session
                .handle_frame(&req[..n], &mut dev, Instant::from_millis(9), &mut resp)
                .unwrap()
                .unwrap();
            assert_eq!(
                client.handle_response(&resp[..m]),
                Err(ResponseError::Exception {
                    function: 0x03,
                    code: 0x02
                })
            );
        }
    }
}
