//! The Modbus TCP wire format as the CMMO-ST uses it: the MBAP header, a deframer for the TCP
//! byte stream, the request PDUs of the five function codes the device implements (digest 001
//! §1.2, manual §4.3.2 Tab. 4.3) and their responses.
//!
//! Everything here is pure: bytes in, values out, no allocation. The decoders are public and
//! take `&[u8]`, so fuzz targets can call them directly.

/// Length of the MBAP header: transaction id, protocol id, length, unit id.
pub const MBAP_LEN: usize = 7;
/// The largest PDU Modbus allows (function code + 252 data bytes).
pub const MAX_PDU: usize = 253;
/// The largest ADU: header + PDU.
pub const MAX_ADU: usize = MBAP_LEN + MAX_PDU;

/// FC 0x03 Read Holding Registers (returns the status image).
pub const FC_READ_HOLDING_REGISTERS: u8 = 0x03;
/// FC 0x07 Read Exception Status (returns the fault number).
pub const FC_READ_EXCEPTION_STATUS: u8 = 0x07;
/// FC 0x10 Write Multiple Registers (sets the control image).
pub const FC_WRITE_MULTIPLE_REGISTERS: u8 = 0x10;
/// FC 0x17 Read/Write Multiple Registers (the cyclic FHPP exchange).
pub const FC_READ_WRITE_MULTIPLE_REGISTERS: u8 = 0x17;
/// FC 0x2B Encapsulated Interface Transport (only MEI 0x0E is implemented).
pub const FC_ENCAPSULATED_INTERFACE: u8 = 0x2B;
/// MEI type 0x0E Read Device Identification.
pub const MEI_READ_DEVICE_IDENTIFICATION: u8 = 0x0E;

/// The MBAP header in front of every Modbus TCP PDU (manual Tab. 4.1). All fields big-endian.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct MbapHeader {
    /// Chosen by the client, echoed in the response.
    pub transaction_id: u16,
    /// 0 for Modbus; frames with anything else are not Modbus and are dropped.
    pub protocol_id: u16,
    /// Bytes that follow the length field: unit id + PDU.
    pub length: u16,
    /// Ignored by the CMMO-ST ("e.g. 0"), echoed in the response.
    pub unit_id: u8,
}

impl MbapHeader {
    /// Decodes the first [`MBAP_LEN`] bytes of `bytes`.
    pub fn from_bytes(bytes: &[u8]) -> Result<MbapHeader, FrameError> {
        let h: &[u8; MBAP_LEN] = bytes
            .get(..MBAP_LEN)
            .and_then(|b| b.try_into().ok())
            .ok_or(FrameError::Truncated { len: bytes.len() })?;
        Ok(MbapHeader {
            transaction_id: u16::from_be_bytes([h[0], h[1]]),
            protocol_id: u16::from_be_bytes([h[2], h[3]]),
            length: u16::from_be_bytes([h[4], h[5]]),
            unit_id: h[6],
        })
    }

    /// The 7 header bytes.
    pub fn to_bytes(&self) -> [u8; MBAP_LEN] {
        let t = self.transaction_id.to_be_bytes();
        let p = self.protocol_id.to_be_bytes();
        let l = self.length.to_be_bytes();
        [t[0], t[1], p[0], p[1], l[0], l[1], self.unit_id]
    }

    /// The PDU length this header announces, if it is one Modbus allows (1..=253).
    pub fn pdu_len(&self) -> Result<usize, FrameError> {
        let pdu = usize::from(self.length).wrapping_sub(1);
        if (1..=MAX_PDU).contains(&pdu) {
            Ok(pdu)
        } else {
            Err(FrameError::BadLength {
                length: self.length,
            })
        }
    }
}

/// Why bytes from the TCP stream are not a Modbus TCP frame. After such an error the stream
/// cannot be resynchronised, so the server closes the connection ("disconnected by the motor
/// controller in case of error", §4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// Fewer bytes than a header.
    #[error("{len} bytes are too few for an MBAP header ({MBAP_LEN})")]
    Truncated {
        /// Bytes available.
        len: usize,
    },
    /// The length field announces no PDU or one beyond 253 bytes.
    #[error("MBAP length {length} is outside 2..=254")]
    BadLength {
        /// The header's length field.
        length: u16,
    },
}

/// Reassembles Modbus TCP frames from the TCP byte stream: TCP may split a frame or join
/// several, so bytes are pushed as they arrive and whole ADUs are taken out.
#[derive(Debug, Clone)]
pub struct Deframer {
    buf: [u8; 2 * MAX_ADU],
    len: usize,
}

impl Default for Deframer {
    fn default() -> Self {
        Deframer {
            buf: [0; 2 * MAX_ADU],
            len: 0,
        }
    }
}

impl Deframer {
    /// An empty deframer.
    pub fn new() -> Self {
        Self::default()
    }

    /// Forgets buffered bytes (a new connection starts clean).
    pub fn clear(&mut self) {
        self.len = 0;
    }

    /// Free space for [`push`](Self::push); reading at most this many bytes from the socket
    /// never overflows.
    pub fn space(&self) -> usize {
        self.buf.len() - self.len
    }

    /// Appends received bytes. Returns how many were taken (less than `bytes.len()` when the
    /// buffer is full: take frames out first).
    pub fn push(&mut self, bytes: &[u8]) -> usize {
        let n = bytes.len().min(self.space());
        if let (Some(dst), Some(src)) = (self.buf.get_mut(self.len..self.len + n), bytes.get(..n)) {
            dst.copy_from_slice(src);
            self.len += n;
        }
        n
    }

    /// The next complete ADU (header + PDU) copied into `out`, returning its length; `Ok(None)`
    /// while a frame is still incomplete; `Err` when the header is invalid (close the
    /// connection).
    pub fn next_frame(&mut self, out: &mut [u8; MAX_ADU]) -> Result<Option<usize>, FrameError> {
        if self.len < MBAP_LEN {
            return Ok(None);
        }
        let header = MbapHeader::from_bytes(&self.buf[..self.len])?;
        let total = MBAP_LEN + header.pdu_len()?;
        if self.len < total {
            return Ok(None);
        }
        let (Some(dst), Some(src)) = (out.get_mut(..total), self.buf.get(..total)) else {
            return Ok(None);
        };
        dst.copy_from_slice(src);
        self.buf.copy_within(total..self.len, 0);
        self.len -= total;
        Ok(Some(total))
    }
}

/// The Modbus exception codes the CMMO-ST answers with (Tab. 4.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum ExceptionCode {
    /// 0x01: the function code (or MEI type) is not implemented.
    IllegalFunction = 0x01,
    /// 0x02: the start address is not 0.
    IllegalDataAddress = 0x02,
    /// 0x03: quantity, byte count, PDU length or device-id code are wrong.
    IllegalDataValue = 0x03,
    /// 0x04: the device could not process a well-formed request.
    ServerDeviceFailure = 0x04,
}

impl ExceptionCode {
    /// The code's byte.
    pub const fn to_byte(self) -> u8 {
        self as u8
    }
}

/// A request the server refuses: the function code it answers for and the exception code.
/// The response PDU is `[function | 0x80, code]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("exception {code:?} for function code {function:#04x}")]
pub struct Exception {
    /// The request's function code.
    pub function: u8,
    /// Why it is refused.
    pub code: ExceptionCode,
}

impl Exception {
    /// The 2-byte exception PDU.
    pub const fn to_bytes(&self) -> [u8; 2] {
        [self.function | 0x80, self.code.to_byte()]
    }
}

/// Read Device Identification categories (read device ID code).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum IdCategory {
    /// 0x01: objects 0x00..=0x02.
    Basic,
    /// 0x02: the basic objects plus 0x03, 0x04 and 0x06 (the CMMO-ST has no 0x05).
    Regular,
}

impl IdCategory {
    /// The read device ID code (and the conformity level the device answers with).
    pub const fn code(self) -> u8 {
        match self {
            IdCategory::Basic => 0x01,
            IdCategory::Regular => 0x02,
        }
    }
}

/// A decoded request PDU. Register values stay bytes on the wire order (big-endian words), which
/// is exactly the FHPP byte order: FHPP byte k is the k-th data byte (digest §1.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Request<'a> {
    /// FC 0x03.
    ReadHoldingRegisters {
        /// First register.
        start: u16,
        /// Number of registers.
        quantity: u16,
    },
    /// FC 0x10.
    WriteMultipleRegisters {
        /// First register.
        start: u16,
        /// Number of registers.
        quantity: u16,
        /// `2 * quantity` bytes.
        values: &'a [u8],
    },
    /// FC 0x17 (the write happens before the read, per the Modbus specification).
    ReadWriteMultipleRegisters {
        /// First register read.
        read_start: u16,
        /// Registers read.
        read_quantity: u16,
        /// First register written.
        write_start: u16,
        /// Registers written.
        write_quantity: u16,
        /// `2 * write_quantity` bytes.
        values: &'a [u8],
    },
    /// FC 0x07.
    ReadExceptionStatus,
    /// FC 0x2B / MEI 0x0E.
    ReadDeviceIdentification {
        /// Basic or regular.
        category: IdCategory,
        /// The first object asked for.
        object_id: u8,
    },
}

fn be16(pdu: &[u8], at: usize) -> Option<u16> {
    let b = pdu.get(at..at + 2)?;
    Some(u16::from_be_bytes([*b.first()?, *b.get(1)?]))
}

/// Decodes a request PDU (function code first). Structural checks follow the Modbus
/// application protocol: an unknown function code (or MEI type) is 0x01; a wrong PDU length,
/// a quantity outside what one PDU can carry or a byte count that does not match is 0x03.
/// Device-specific checks (start 0, quantity 4 or 8) belong to the server.
pub fn decode_request(pdu: &[u8]) -> Result<Request<'_>, Exception> {
    let Some(&function) = pdu.first() else {
        // An empty PDU cannot happen after the deframer (length >= 2); answer it anyway.
        return Err(Exception {
            function: 0,
            code: ExceptionCode::IllegalFunction,
        });
    };
    let value = Exception {
        function,
        code: ExceptionCode::IllegalDataValue,
    };
    match function {
        FC_READ_HOLDING_REGISTERS => {
            if pdu.len() != 5 {
                return Err(value);
            }
            let start = be16(pdu, 1).ok_or(value)?;
            let quantity = be16(pdu, 3).ok_or(value)?;
            if !(1..=125).contains(&quantity) {
                return Err(value);
            }
            Ok(Request::ReadHoldingRegisters { start, quantity })
        }
        FC_WRITE_MULTIPLE_REGISTERS => {
            let start = be16(pdu, 1).ok_or(value)?;
            let quantity = be16(pdu, 3).ok_or(value)?;
            let count = *pdu.get(5).ok_or(value)?;
            let values = pdu.get(6..).ok_or(value)?;
            if !(1..=123).contains(&quantity)
                || usize::from(count) != 2 * usize::from(quantity)
                || values.len() != usize::from(count)
            {
                return Err(value);
            }
            Ok(Request::WriteMultipleRegisters {
                start,
                quantity,
                values,
            })
        }
        FC_READ_WRITE_MULTIPLE_REGISTERS => {
            let read_start = be16(pdu, 1).ok_or(value)?;
            let read_quantity = be16(pdu, 3).ok_or(value)?;
            let write_start = be16(pdu, 5).ok_or(value)?;
            let write_quantity = be16(pdu, 7).ok_or(value)?;
            let count = *pdu.get(9).ok_or(value)?;
            let values = pdu.get(10..).ok_or(value)?;
            if !(1..=125).contains(&read_quantity)
                || !(1..=121).contains(&write_quantity)
                || usize::from(count) != 2 * usize::from(write_quantity)
                || values.len() != usize::from(count)
            {
                return Err(value);
            }
            Ok(Request::ReadWriteMultipleRegisters {
                read_start,
                read_quantity,
                write_start,
                write_quantity,
                values,
            })
        }
        FC_READ_EXCEPTION_STATUS => {
            if pdu.len() != 1 {
                return Err(value);
            }
            Ok(Request::ReadExceptionStatus)
        }
        FC_ENCAPSULATED_INTERFACE => {
            let mei = *pdu.get(1).ok_or(value)?;
            if mei != MEI_READ_DEVICE_IDENTIFICATION {
                return Err(Exception {
                    function,
                    code: ExceptionCode::IllegalFunction,
                });
            }
            if pdu.len() != 4 {
                return Err(value);
            }
            // Extended (0x03) and individual (0x04) access are not listed in Tab. 4.3.
            let category = match pdu.get(2) {
                Some(0x01) => IdCategory::Basic,
                Some(0x02) => IdCategory::Regular,
                _ => return Err(value),
            };
            let object_id = *pdu.get(3).ok_or(value)?;
            Ok(Request::ReadDeviceIdentification {
                category,
                object_id,
            })
        }
        _ => Err(Exception {
            function,
            code: ExceptionCode::IllegalFunction,
        }),
    }
}

/// Writes a whole response ADU (header with the request's transaction and unit id, then `pdu`)
/// into `out` and returns its length.
pub fn encode_response(request: &MbapHeader, pdu: &[u8], out: &mut [u8; MAX_ADU]) -> usize {
    let pdu = pdu.get(..MAX_PDU).unwrap_or(pdu);
    let header = MbapHeader {
        transaction_id: request.transaction_id,
        protocol_id: 0,
        // pdu.len() <= 253, so this cannot truncate.
        length: (pdu.len() + 1) as u16,
        unit_id: request.unit_id,
    };
    let total = MBAP_LEN + pdu.len();
    out[..MBAP_LEN].copy_from_slice(&header.to_bytes());
    out[MBAP_LEN..total].copy_from_slice(pdu);
    total
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_round_trips_and_rejects_bad_lengths() {
        let bytes = [0x12, 0x34, 0, 0, 0x00, 0x13, 0x07];
        let h = MbapHeader::from_bytes(&bytes).unwrap();
        assert_eq!(h.transaction_id, 0x1234);
        assert_eq!(h.length, 19);
        assert_eq!(h.unit_id, 7);
        assert_eq!(h.pdu_len(), Ok(18));
        assert_eq!(h.to_bytes(), bytes);
        for length in [0u16, 1, 255, 0xFFFF] {
            let h = MbapHeader { length, ..h };
            assert_eq!(h.pdu_len(), Err(FrameError::BadLength { length }));
        }
        assert_eq!(
            MbapHeader::from_bytes(&bytes[..6]),
            Err(FrameError::Truncated { len: 6 })
        );
    }

    #[test]
    fn deframer_splits_joined_frames_and_waits_for_partial_ones() {
        let a = [0, 1, 0, 0, 0, 2, 0, 0x07];
        let b = [0, 2, 0, 0, 0, 6, 0, 0x03, 0, 0, 0, 4];
        let mut d = Deframer::new();
        let mut out = [0; MAX_ADU];
        d.push(&a);
        d.push(&b[..5]);
        assert_eq!(d.next_frame(&mut out), Ok(Some(8)));
        assert_eq!(&out[..8], &a);
        assert_eq!(d.next_frame(&mut out), Ok(None));
        d.push(&b[5..]);
        assert_eq!(d.next_frame(&mut out), Ok(Some(12)));
        assert_eq!(&out[..12], &b);
        assert_eq!(d.next_frame(&mut out), Ok(None));
    }

    #[test]
    fn deframer_reports_an_impossible_length() {
        let mut d = Deframer::new();
        let mut out = [0; MAX_ADU];
        d.push(&[0, 1, 0, 0, 0x01, 0x00, 0]);
        assert_eq!(
            d.next_frame(&mut out),
            Err(FrameError::BadLength { length: 256 })
        );
    }

    #[test]
    fn deframer_push_stops_at_capacity() {
        let mut d = Deframer::new();
        let big = [0u8; 3 * MAX_ADU];
        assert_eq!(d.push(&big), 2 * MAX_ADU);
        assert_eq!(d.space(), 0);
        assert_eq!(d.push(&[1]), 0);
    }

    #[test]
    fn decodes_the_digest_example_read_write_request() {
        let pdu = [
            0x17, 0, 0, 0, 4, 0, 0, 0, 4, 8, 0x23, 0x01, 0, 0, 0, 0, 0, 0,
        ];
        let values = &pdu[10..];
        assert_eq!(
            decode_request(&pdu),
            Ok(Request::ReadWriteMultipleRegisters {
                read_start: 0,
                read_quantity: 4,
                write_start: 0,
                write_quantity: 4,
                values,
            })
        );
    }

    #[test]
    fn structural_errors_are_illegal_data_value_and_unknown_codes_illegal_function() {
        let value = |function| {
            Err(Exception {
                function,
                code: ExceptionCode::IllegalDataValue,
            })
        };
        // Byte count disagrees with the quantity.
        assert_eq!(
            decode_request(&[0x10, 0, 0, 0, 4, 6, 0, 0, 0, 0, 0, 0]),
            value(0x10)
        );
        // Byte count right, data short.
        assert_eq!(decode_request(&[0x10, 0, 0, 0, 1, 2, 0]), value(0x10));
        // Quantity 0.
        assert_eq!(decode_request(&[0x03, 0, 0, 0, 0]), value(0x03));
        // Trailing byte.
        assert_eq!(decode_request(&[0x07, 0]), value(0x07));
        // Device-id code 0x04 (individual access).
        assert_eq!(decode_request(&[0x2B, 0x0E, 0x04, 0x00]), value(0x2B));
        // MEI 0x0D (CANopen general reference) is not implemented.
        assert_eq!(
            decode_request(&[0x2B, 0x0D, 0x01, 0x00]),
            Err(Exception {
                function: 0x2B,
                code: ExceptionCode::IllegalFunction
            })
        );
        assert_eq!(
            decode_request(&[0x06, 0, 0, 0, 1]),
            Err(Exception {
                function: 0x06,
                code: ExceptionCode::IllegalFunction
            })
        );
        assert_eq!(
            Exception {
                function: 0x06,
                code: ExceptionCode::IllegalFunction
            }
            .to_bytes(),
            [0x86, 0x01]
        );
    }

    #[test]
    fn response_echoes_transaction_and_unit() {
        let req = MbapHeader {
            transaction_id: 0xBEEF,
            protocol_id: 0,
            length: 2,
            unit_id: 0x11,
        };
        let mut out = [0; MAX_ADU];
        let n = encode_response(&req, &[0x07, 0x00], &mut out);
        assert_eq!(&out[..n], &[0xBE, 0xEF, 0, 0, 0, 3, 0x11, 0x07, 0x00]);
    }
}
