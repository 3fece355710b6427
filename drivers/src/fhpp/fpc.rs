//! The Festo parameter channel: 8 bytes each way beside the FHPP image (CANopen PDO2, Modbus
//! registers 4..7).
//!
//! Two dialects:
//!
//! - **Classic FPC** (MTR-DCI §B.1): byte 1 reserved 0, byte 2 IND (sub-index), bytes 3..4 PKE
//!   (bits 15..12 ReqID/ResID, bit 11 reserved, bits 10..0 PNU), bytes 5..8 PWE. Word and byte
//!   values sit in the low bits of the 32-bit PWE, which is bytes 7..8 / 8 in the manual's
//!   big-endian examples. Error numbers are decimal (digest 000 §6.4: the manual's hex column is
//!   misaligned). The byte order is a setting (digest 000 E2): little-endian by default (the
//!   CANopen mapping 3012h u16 / 3013h u32), big-endian reproduces the manual's §B.1.4 example.
//! - **Enhanced EFPC** (EMCA p.224–238, CMMO-ST App. C): byte 1 FPCC/FPCS (bits 7..4 mode:
//!   0001 parameter, 0100 file; bits 3..0 ReqID/ResID), byte 2 sub-index, bytes 3..4 PNU (u16),
//!   bytes 5..8 PWE (i32, or the error number). Parameter-file transfer (mode 0100) is decoded
//!   as [`FpcError::FileMode`] and not implemented.
//!
//! The protocol rule both share ("no task in between"): the master repeats a task until the
//! matching reply arrives; the drive executes a write once and keeps presenting its reply until
//! the task changes; between two tasks the master sends "no task" (ReqID 0) and waits for "no
//! reply" (ResID 0), so an old reply is never taken for a new one. [`Server`] and [`Client`] are
//! that rule as state machines.

use super::ByteOrder;

/// Which dialect of the parameter channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Channel {
    /// Classic FPC (MTR-DCI).
    Classic,
    /// Enhanced FPC, parameter mode (EMCA, CMMO-ST).
    Enhanced,
}

/// A parameter address: PNU and sub-index (IND).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Param {
    /// The parameter number (classic: 0..=2047).
    pub pnu: u16,
    /// The sub-index; on the classic channel 0 means a simple variable and a non-zero value an
    /// array element (record n has IND n + 1).
    pub sub: u8,
}

impl Param {
    /// `pnu:sub`.
    pub const fn new(pnu: u16, sub: u8) -> Param {
        Param { pnu, sub }
    }
}

/// A parameter value with its transfer width. Signed parameters travel as two's complement;
/// [`super::pnu::DataType`] converts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Value {
    /// A byte (classic ReqID 11/12, ResID 11/12).
    Byte(u8),
    /// A word (classic ReqID 2/7, ResID 1/4).
    Word(u16),
    /// A double word (classic ReqID 3/8, ResID 2/5; every EFPC value).
    Dword(u32),
}

impl Value {
    /// The value zero-extended to 32 bits, as it sits in PWE.
    pub const fn raw(self) -> u32 {
        match self {
            Value::Byte(b) => b as u32,
            Value::Word(w) => w as u32,
            Value::Dword(d) => d,
        }
    }
}

/// A task, master → drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Request {
    /// ReqID 0: no task.
    NoTask,
    /// Request a parameter value (classic ReqID 1, or 6 for an array element; EFPC 6).
    Read(Param),
    /// Modify a parameter value (classic ReqID 2/3/11 or 7/8/12 by width and array; EFPC 8).
    Write(Param, Value),
}

/// A reply, drive → master.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Response {
    /// ResID 0: no reply.
    NoReply,
    /// The value was transferred (read) or written (the echo).
    Value(Param, Value),
    /// Classic ResID 6: the number of array elements.
    ElementCount(Param, u16),
    /// ResID 7: the task cannot be executed; the device's error number.
    Error(Param, u16),
}

/// Why a task failed, independent of the dialect's numbering (see [`ErrorKind::number`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ErrorKind {
    /// The PNU does not exist (classic 0, EFPC 0x00).
    NoSuchPnu,
    /// The parameter is read-only (classic 1, EFPC 0x01).
    ReadOnly,
    /// The parameter is write-only (EFPC 0x66; classic has no such number: 22).
    WriteOnly,
    /// Lower or upper limit exceeded (EFPC 0x02). Classic FPC lists no range error; this
    /// project answers 22 ("non-permitted attributes, number of elements, PNU or IND"), the
    /// nearest the MTR-DCI table offers.
    OutOfRange,
    /// Faulty sub-index (classic 3, EFPC 0x03).
    BadSubindex,
    /// Not an array (classic 4; EFPC: 0x03).
    NotArray,
    /// Incorrect data type / width (classic 5; EFPC: 0x65, its values are always 32 bits).
    WrongType,
    /// The fieldbus does not hold device control (classic 11, EFPC 0x0B).
    NoControl,
    /// Not possible in the current operating state, e.g. an rw2 parameter with the output stage
    /// on (EFPC 0x11; classic 22).
    NotInThisState,
    /// ReqID not supported (classic 22, EFPC 0x65).
    UnsupportedTask,
    /// A number without a kind above (classic 9, 13, 24, reserved values).
    Other(u16),
}

impl ErrorKind {
    /// The error number this dialect sends for the kind.
    pub const fn number(self, channel: Channel) -> u16 {
        match channel {
            Channel::Classic => match self {
                ErrorKind::NoSuchPnu => 0,
                ErrorKind::ReadOnly => 1,
                ErrorKind::BadSubindex => 3,
                ErrorKind::NotArray => 4,
                ErrorKind::WrongType => 5,
                ErrorKind::NoControl => 11,
                ErrorKind::WriteOnly
                | ErrorKind::OutOfRange
                | ErrorKind::NotInThisState
                | ErrorKind::UnsupportedTask => 22,
                ErrorKind::Other(n) => n,
            },
            Channel::Enhanced => match self {
                ErrorKind::NoSuchPnu => 0x00,
                ErrorKind::ReadOnly => 0x01,
                ErrorKind::OutOfRange => 0x02,
                ErrorKind::BadSubindex | ErrorKind::NotArray => 0x03,
                ErrorKind::NoControl => 0x0B,
                ErrorKind::NotInThisState => 0x11,
                ErrorKind::UnsupportedTask | ErrorKind::WrongType => 0x65,
                ErrorKind::WriteOnly => 0x66,
                ErrorKind::Other(n) => n,
            },
        }
    }
    /// The kind of an error number (classic 22 covers several kinds and decodes as
    /// `UnsupportedTask`).
    pub const fn from_number(n: u16, channel: Channel) -> ErrorKind {
        match channel {
            Channel::Classic => match n {
                0 => ErrorKind::NoSuchPnu,
                1 => ErrorKind::ReadOnly,
                3 => ErrorKind::BadSubindex,
                4 => ErrorKind::NotArray,
                5 => ErrorKind::WrongType,
                11 => ErrorKind::NoControl,
                22 => ErrorKind::UnsupportedTask,
                n => ErrorKind::Other(n),
            },
            Channel::Enhanced => match n {
                0x00 => ErrorKind::NoSuchPnu,
                0x01 => ErrorKind::ReadOnly,
                0x02 => ErrorKind::OutOfRange,
                0x03 => ErrorKind::BadSubindex,
                0x0B => ErrorKind::NoControl,
                0x11 => ErrorKind::NotInThisState,
                0x65 => ErrorKind::UnsupportedTask,
                0x66 => ErrorKind::WriteOnly,
                n => ErrorKind::Other(n),
            },
        }
    }
}

/// Why 8 bytes are not a telegram this codec understands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FpcError {
    /// Not 8 bytes.
    #[error("parameter channel telegram must be 8 bytes, got {len}")]
    Length {
        /// The length received.
        len: usize,
    },
    /// A reserved bit or byte is set (classic byte 1, PKE bit 11).
    #[error("reserved bits set in parameter channel telegram: byte {byte} = {value:#04x}")]
    Reserved {
        /// The 1-based byte number.
        byte: u8,
        /// Its value.
        value: u8,
    },
    /// A ReqID/ResID the dialect reserves (the server answers "unsupported task").
    #[error("identifier {id} not defined, PNU {pnu} sub-index {sub}")]
    UnknownId {
        /// The identifier.
        id: u8,
        /// The PNU of the telegram, for the error reply.
        pnu: u16,
        /// The sub-index of the telegram.
        sub: u8,
    },
    /// An EFPC parameter-file telegram (mode 0100), which this codec does not implement.
    #[error("EFPC parameter-file transfer not supported (FPCC {fpcc:#04x})")]
    FileMode {
        /// Byte 1.
        fpcc: u8,
    },
    /// An EFPC mode nibble other than parameter (0001) or file (0100).
    #[error("EFPC mode {mode:#x} reserved")]
    UnknownMode {
        /// Bits 7..4 of byte 1.
        mode: u8,
    },
}

/// Classic task identifiers, ReqID (MTR-DCI Tab. B/4).
pub mod req_id {
    /// No task.
    pub const NO_TASK: u8 = 0;
    /// Request parameter value.
    pub const READ: u8 = 1;
    /// Modify parameter value (word).
    pub const WRITE_WORD: u8 = 2;
    /// Modify parameter value (double word).
    pub const WRITE_DWORD: u8 = 3;
    /// Request parameter value (array).
    pub const READ_ARRAY: u8 = 6;
    /// Modify parameter value (array, word).
    pub const WRITE_ARRAY_WORD: u8 = 7;
    /// Modify parameter value (array, double word).
    pub const WRITE_ARRAY_DWORD: u8 = 8;
    /// Modify parameter value (byte).
    pub const WRITE_BYTE: u8 = 11;
    /// Modify parameter value (array, byte).
    pub const WRITE_ARRAY_BYTE: u8 = 12;
}

/// Classic response identifiers, ResID (MTR-DCI Tab. B/5).
pub mod res_id {
    /// No reply.
    pub const NO_REPLY: u8 = 0;
    /// Value transferred (word).
    pub const WORD: u8 = 1;
    /// Value transferred (double word).
    pub const DWORD: u8 = 2;
    /// Array value transferred (word).
    pub const ARRAY_WORD: u8 = 4;
    /// Array value transferred (double word).
    pub const ARRAY_DWORD: u8 = 5;
    /// Number of array elements.
    pub const ELEMENT_COUNT: u8 = 6;
    /// Task cannot be executed; error number in PWE.
    pub const ERROR: u8 = 7;
    /// Value transferred (byte).
    pub const BYTE: u8 = 11;
    /// Array value transferred (byte).
    pub const ARRAY_BYTE: u8 = 12;
}

/// EFPC identifiers (byte 1 of the parameter mode: mode 0001 in bits 7..4).
pub mod efpc {
    /// Parameter-mode nibble.
    pub const MODE_PARAMETER: u8 = 0x1;
    /// Parameter-file mode nibble.
    pub const MODE_FILE: u8 = 0x4;
    /// FPCC: no job.
    pub const NO_JOB: u8 = 0x10;
    /// FPCC: request parameter value (array).
    pub const READ: u8 = 0x16;
    /// FPCC: modify parameter value (array, double word).
    pub const WRITE: u8 = 0x18;
    /// FPCS: no reply.
    pub const NO_REPLY: u8 = 0x10;
    /// FPCS: parameter transmitted (array, double word).
    pub const TRANSFERRED: u8 = 0x15;
    /// FPCS: task cannot be carried out; error number in PWE.
    pub const ERROR: u8 = 0x17;
}

/// The raw fields of an 8-byte telegram, dialect-independent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
struct Raw {
    id: u8,
    sub: u8,
    pnu: u16,
    pwe: u32,
}

/// A parameter-channel codec: a dialect and a byte order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Codec {
    /// The dialect.
    pub channel: Channel,
    /// The byte order of PKE/PNU and PWE.
    pub order: ByteOrder,
}

impl Codec {
    /// A codec.
    pub const fn new(channel: Channel, order: ByteOrder) -> Codec {
        Codec { channel, order }
    }

    fn raw_to_bytes(&self, r: Raw) -> [u8; 8] {
        let mut out = [0u8; 8];
        match self.channel {
            Channel::Classic => {
                let pke = (u16::from(r.id & 0x0F) << 12) | (r.pnu & 0x07FF);
                out[1] = r.sub;
                out[2..4].copy_from_slice(&self.order.u16_bytes(pke));
            }
            Channel::Enhanced => {
                out[0] = r.id;
                out[1] = r.sub;
                out[2..4].copy_from_slice(&self.order.u16_bytes(r.pnu));
            }
        }
        out[4..8].copy_from_slice(&self.order.u32_bytes(r.pwe));
        out
    }

    /// Splits 8 bytes into raw fields; for EFPC `id` is the low nibble after the mode check.
    fn raw_from_bytes(&self, bytes: &[u8]) -> Result<Raw, FpcError> {
        let b: &[u8; 8] = bytes
            .try_into()
            .map_err(|_| FpcError::Length { len: bytes.len() })?;
        let pwe = self.order.u32_from([b[4], b[5], b[6], b[7]]);
        let word = self.order.u16_from([b[2], b[3]]);
        match self.channel {
            Channel::Classic => {
                if b[0] != 0 {
                    return Err(FpcError::Reserved {
                        byte: 1,
                        value: b[0],
                    });
                }
                if word & 0x0800 != 0 {
                    let high = (word >> 8) as u8;
                    return Err(FpcError::Reserved {
                        byte: match self.order {
                            ByteOrder::Big => 3,
                            ByteOrder::Little => 4,
                        },
                        value: high,
                    });
                }
                Ok(Raw {
                    id: (word >> 12) as u8,
                    sub: b[1],
                    pnu: word & 0x07FF,
                    pwe,
                })
            }
            Channel::Enhanced => {
                let mode = b[0] >> 4;
                // "No job" may also come as 0x00 (CMMO-ST digest §6.3).
                if b[0] == 0 {
                    return Ok(Raw {
                        id: 0,
                        sub: b[1],
                        pnu: word,
                        pwe,
                    });
                }
                match mode {
                    efpc::MODE_PARAMETER => Ok(Raw {
                        id: b[0] & 0x0F,
                        sub: b[1],
                        pnu: word,
                        pwe,
                    }),
                    efpc::MODE_FILE => Err(FpcError::FileMode { fpcc: b[0] }),
                    mode => Err(FpcError::UnknownMode { mode }),
                }
            }
        }
    }

    /// Encodes a task.
    pub fn encode_request(&self, req: Request) -> [u8; 8] {
        let raw = match (self.channel, req) {
            (Channel::Classic, Request::NoTask) => Raw {
                id: 0,
                sub: 0,
                pnu: 0,
                pwe: 0,
            },
            (Channel::Enhanced, Request::NoTask) => Raw {
                id: efpc::NO_JOB,
                sub: 0,
                pnu: 0,
                pwe: 0,
            },
            (Channel::Classic, Request::Read(p)) => Raw {
                id: if p.sub == 0 {
                    req_id::READ
                } else {
                    req_id::READ_ARRAY
                },
                sub: p.sub,
                pnu: p.pnu,
                pwe: 0,
            },
            (Channel::Enhanced, Request::Read(p)) => Raw {
                id: efpc::READ,
                sub: p.sub,
                pnu: p.pnu,
                pwe: 0,
            },
            (Channel::Classic, Request::Write(p, v)) => {
                let array = p.sub != 0;
                let id = match (v, array) {
                    (Value::Byte(_), false) => req_id::WRITE_BYTE,
                    (Value::Byte(_), true) => req_id::WRITE_ARRAY_BYTE,
                    (Value::Word(_), false) => req_id::WRITE_WORD,
                    (Value::Word(_), true) => req_id::WRITE_ARRAY_WORD,
                    (Value::Dword(_), false) => req_id::WRITE_DWORD,
                    (Value::Dword(_), true) => req_id::WRITE_ARRAY_DWORD,
                };
                Raw {
                    id,
                    sub: p.sub,
                    pnu: p.pnu,
                    pwe: v.raw(),
                }
            }
            (Channel::Enhanced, Request::Write(p, v)) => Raw {
                id: efpc::WRITE,
                sub: p.sub,
                pnu: p.pnu,
                pwe: v.raw(),
            },
        };
        self.raw_to_bytes(raw)
    }

    /// Decodes a task. Never panics, whatever the bytes.
    pub fn decode_request(&self, bytes: &[u8]) -> Result<Request, FpcError> {
        let r = self.raw_from_bytes(bytes)?;
        let p = Param::new(r.pnu, r.sub);
        let unknown = FpcError::UnknownId {
            id: r.id,
            pnu: r.pnu,
            sub: r.sub,
        };
        match self.channel {
            Channel::Classic => Ok(match r.id {
                req_id::NO_TASK => Request::NoTask,
                req_id::READ | req_id::READ_ARRAY => Request::Read(p),
                req_id::WRITE_WORD | req_id::WRITE_ARRAY_WORD => {
                    Request::Write(p, Value::Word(r.pwe as u16))
                }
                req_id::WRITE_DWORD | req_id::WRITE_ARRAY_DWORD => {
                    Request::Write(p, Value::Dword(r.pwe))
                }
                req_id::WRITE_BYTE | req_id::WRITE_ARRAY_BYTE => {
                    Request::Write(p, Value::Byte(r.pwe as u8))
                }
                _ => return Err(unknown),
            }),
            Channel::Enhanced => Ok(match r.id {
                0 => Request::NoTask,
                6 => Request::Read(p),
                8 => Request::Write(p, Value::Dword(r.pwe)),
                _ => return Err(unknown),
            }),
        }
    }

    /// Encodes a reply. On the classic channel the ResID follows the value's width and whether
    /// the parameter is an array element (sub-index ≠ 0).
    pub fn encode_response(&self, resp: Response) -> [u8; 8] {
        let raw = match (self.channel, resp) {
            (Channel::Classic, Response::NoReply) => Raw {
                id: 0,
                sub: 0,
                pnu: 0,
                pwe: 0,
            },
            (Channel::Enhanced, Response::NoReply) => Raw {
                id: efpc::NO_REPLY,
                sub: 0,
                pnu: 0,
                pwe: 0,
            },
            (Channel::Classic, Response::Value(p, v)) => {
                let array = p.sub != 0;
                let id = match (v, array) {
                    (Value::Byte(_), false) => res_id::BYTE,
                    (Value::Byte(_), true) => res_id::ARRAY_BYTE,
                    (Value::Word(_), false) => res_id::WORD,
                    (Value::Word(_), true) => res_id::ARRAY_WORD,
                    (Value::Dword(_), false) => res_id::DWORD,
                    (Value::Dword(_), true) => res_id::ARRAY_DWORD,
                };
                Raw {
                    id,
                    sub: p.sub,
                    pnu: p.pnu,
                    pwe: v.raw(),
                }
            }
            (Channel::Enhanced, Response::Value(p, v)) => Raw {
                id: efpc::TRANSFERRED,
                sub: p.sub,
                pnu: p.pnu,
                pwe: v.raw(),
            },
            // EFPC has no element-count reply; the count travels as a value.
            (Channel::Enhanced, Response::ElementCount(p, n)) => Raw {
                id: efpc::TRANSFERRED,
                sub: p.sub,
                pnu: p.pnu,
                pwe: u32::from(n),
            },
            (Channel::Classic, Response::ElementCount(p, n)) => Raw {
                id: res_id::ELEMENT_COUNT,
                sub: p.sub,
                pnu: p.pnu,
                pwe: u32::from(n),
            },
            (Channel::Classic, Response::Error(p, n)) => Raw {
                id: res_id::ERROR,
                sub: p.sub,
                pnu: p.pnu,
                pwe: u32::from(n),
            },
            (Channel::Enhanced, Response::Error(p, n)) => Raw {
                id: efpc::ERROR,
                sub: p.sub,
                pnu: p.pnu,
                pwe: u32::from(n),
            },
        };
        self.raw_to_bytes(raw)
    }

    /// Decodes a reply. Never panics, whatever the bytes.
    pub fn decode_response(&self, bytes: &[u8]) -> Result<Response, FpcError> {
        let r = self.raw_from_bytes(bytes)?;
        let p = Param::new(r.pnu, r.sub);
        let unknown = FpcError::UnknownId {
            id: r.id,
            pnu: r.pnu,
            sub: r.sub,
        };
        match self.channel {
            Channel::Classic => Ok(match r.id {
                res_id::NO_REPLY => Response::NoReply,
                res_id::WORD | res_id::ARRAY_WORD => Response::Value(p, Value::Word(r.pwe as u16)),
                res_id::DWORD | res_id::ARRAY_DWORD => Response::Value(p, Value::Dword(r.pwe)),
                res_id::BYTE | res_id::ARRAY_BYTE => Response::Value(p, Value::Byte(r.pwe as u8)),
                res_id::ELEMENT_COUNT => Response::ElementCount(p, r.pwe as u16),
                // The error number is in the low word (bytes 7..8 in the manual's order).
                res_id::ERROR => Response::Error(p, r.pwe as u16),
                _ => return Err(unknown),
            }),
            Channel::Enhanced => Ok(match r.id {
                0 => Response::NoReply,
                5 => Response::Value(p, Value::Dword(r.pwe)),
                7 => Response::Error(p, r.pwe as u16),
                _ => return Err(unknown),
            }),
        }
    }
}

/// The device's parameters, as the [`Server`] reaches them.
pub trait Parameters {
    /// Reads `param`; the value's width is the parameter's transfer width.
    fn read(&mut self, param: Param) -> Result<Value, ErrorKind>;
    /// Writes `value` to `param` after checking access, type and range.
    fn write(&mut self, param: Param, value: Value) -> Result<(), ErrorKind>;
}

/// Device side of the channel: executes each new task once and keeps presenting the reply
/// while the task repeats (MTR-DCI Tab. B/6 rules 5 and 6a; EMCA p.227).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Server {
    codec: Codec,
    last: Option<[u8; 8]>,
    reply: [u8; 8],
}

impl Server {
    /// A server presenting "no reply".
    pub fn new(codec: Codec) -> Server {
        Server {
            codec,
            last: None,
            reply: codec.encode_response(Response::NoReply),
        }
    }

    /// The codec.
    pub const fn codec(&self) -> Codec {
        self.codec
    }

    /// The reply currently presented.
    pub const fn reply(&self) -> [u8; 8] {
        self.reply
    }

    /// Feeds the 8 bytes received this cycle; returns the 8 bytes to send back. A repeated task
    /// is not executed again; a changed one (including "no task" in between) is.
    pub fn handle<P: Parameters>(&mut self, request: &[u8], params: &mut P) -> [u8; 8] {
        let Ok(bytes) = <[u8; 8]>::try_from(request) else {
            // A short or long telegram cannot be echoed; keep the last reply.
            return self.reply;
        };
        if self.last == Some(bytes) {
            return self.reply;
        }
        self.last = Some(bytes);
        let ch = self.codec.channel;
        let resp = match self.codec.decode_request(&bytes) {
            Ok(Request::NoTask) => Response::NoReply,
            Ok(Request::Read(p)) => match params.read(p) {
                Ok(v) => Response::Value(p, v),
                Err(k) => Response::Error(p, k.number(ch)),
            },
            Ok(Request::Write(p, v)) => match params.write(p, v) {
                Ok(()) => Response::Value(p, v),
                Err(k) => Response::Error(p, k.number(ch)),
            },
            Err(FpcError::UnknownId { pnu, sub, .. }) => {
                Response::Error(Param::new(pnu, sub), ErrorKind::UnsupportedTask.number(ch))
            }
            Err(FpcError::FileMode { .. }) => {
                // "Job cannot be carried out in this operating status" (no file transfer).
                Response::Error(Param::default(), ErrorKind::NotInThisState.number(ch))
            }
            Err(_) => Response::Error(Param::default(), ErrorKind::UnsupportedTask.number(ch)),
        };
        self.reply = self.codec.encode_response(resp);
        self.reply
    }
}

/// Why a [`Client::submit`] was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ClientError {
    /// A task is running or the "no task" exchange after it has not finished.
    #[error("parameter channel busy")]
    Busy,
}

/// How a task ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum TaskError {
    /// The drive answered ResID 7.
    #[error("PNU {pnu}:{sub}: error number {number} ({kind:?})")]
    Refused {
        /// The PNU.
        pnu: u16,
        /// The sub-index.
        sub: u8,
        /// The device's error number.
        number: u16,
        /// Its kind.
        kind: ErrorKind,
    },
    /// No matching reply within the allowed number of cycles.
    #[error("no reply after {cycles} cycles")]
    Timeout {
        /// Cycles waited.
        cycles: u32,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
enum ClientState {
    /// Sending "no task", waiting for "no reply" before the next task may start.
    Closing,
    /// Sending "no task"; a task may be submitted.
    Idle,
    /// Repeating the task until its reply arrives.
    Waiting(Request),
}

/// Master side of the channel: one task at a time, repeated until the reply matches by ResID,
/// PNU, sub-index (and, for a write, the echoed value); then "no task" until "no reply", before
/// the next task (MTR-DCI Tab. B/6 rules 3, 4, 6b; EMCA p.227). It starts by waiting for "no
/// reply", so a reply the drive still holds from before is never taken for a new task's.
/// Time is counted in cycles (calls to [`Client::handle_input`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Client {
    codec: Codec,
    state: ClientState,
    cycles: u32,
    timeout_cycles: u32,
}

impl Client {
    /// A client whose tasks time out after `timeout_cycles` cycles without a matching reply
    /// (0 = never).
    pub const fn new(codec: Codec, timeout_cycles: u32) -> Client {
        Client {
            codec,
            state: ClientState::Closing,
            cycles: 0,
            timeout_cycles,
        }
    }

    /// Whether a task may be submitted.
    pub const fn is_idle(&self) -> bool {
        matches!(self.state, ClientState::Idle)
    }

    /// Starts a task.
    pub fn submit(&mut self, req: Request) -> Result<(), ClientError> {
        if !self.is_idle() || req == Request::NoTask {
            return Err(ClientError::Busy);
        }
        self.state = ClientState::Waiting(req);
        self.cycles = 0;
        Ok(())
    }

    /// The 8 bytes to send this cycle.
    pub fn output(&self) -> [u8; 8] {
        match self.state {
            ClientState::Waiting(req) => self.codec.encode_request(req),
            _ => self.codec.encode_request(Request::NoTask),
        }
    }

    /// Feeds the 8 bytes received this cycle. Returns the task's outcome once: the value read or
    /// written, or why it failed.
    pub fn handle_input(&mut self, input: &[u8]) -> Option<Result<Value, TaskError>> {
        let resp = self.codec.decode_response(input).ok();
        match self.state {
            ClientState::Idle => None,
            ClientState::Closing => {
                if resp == Some(Response::NoReply) {
                    self.state = ClientState::Idle;
                }
                None
            }
            ClientState::Waiting(req) => {
                let outcome = match (req, resp) {
                    (Request::Read(p), Some(Response::Value(q, v))) if p == q => Some(Ok(v)),
                    (Request::Write(p, v), Some(Response::Value(q, w)))
                        if p == q && v.raw() == w.raw() =>
                    {
                        Some(Ok(w))
                    }
                    (Request::Read(p) | Request::Write(p, _), Some(Response::Error(q, n)))
                        if p == q =>
                    {
                        Some(Err(TaskError::Refused {
                            pnu: p.pnu,
                            sub: p.sub,
                            number: n,
                            kind: ErrorKind::from_number(n, self.codec.channel),
                        }))
                    }
                    _ => None,
                };
                if outcome.is_some() {
                    self.state = ClientState::Closing;
                    return outcome;
                }
                self.cycles = self.cycles.saturating_add(1);
                if self.timeout_cycles != 0 && self.cycles >= self.timeout_cycles {
                    self.state = ClientState::Closing;
                    return Some(Err(TaskError::Timeout {
                        cycles: self.cycles,
                    }));
                }
                None
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const CLASSIC_LE: Codec = Codec::new(Channel::Classic, ByteOrder::Little);
    const CLASSIC_BE: Codec = Codec::new(Channel::Classic, ByteOrder::Big);
    const EFPC_LE: Codec = Codec::new(Channel::Enhanced, ByteOrder::Little);
    const EFPC_BE: Codec = Codec::new(Channel::Enhanced, ByteOrder::Big);

    #[test]
    fn mtr_dci_b14_examples_big_endian() {
        // `00 02 C1 91 xx xx xx 00`: ReqID 12, PNU 401, IND 2 (record 1), byte value 0.
        let req = Request::Write(Param::new(401, 2), Value::Byte(0));
        assert_eq!(
            CLASSIC_BE.encode_request(req),
            [0x00, 0x02, 0xC1, 0x91, 0, 0, 0, 0x00]
        );
        assert_eq!(
            CLASSIC_BE.decode_request(&[0x00, 0x02, 0xC1, 0x91, 0xAA, 0xBB, 0xCC, 0x00]),
            Ok(req)
        );
        // `00 02 81 94 00 00 12 34`: ReqID 8, PNU 404, value 0x1234.
        let req = Request::Write(Param::new(404, 2), Value::Dword(0x1234));
        assert_eq!(
            CLASSIC_BE.encode_request(req),
            [0x00, 0x02, 0x81, 0x94, 0x00, 0x00, 0x12, 0x34]
        );
        // The reply per Tab. B/5 (digest E3): ReqID 8 → ResID 5.
        let resp =
            CLASSIC_BE.encode_response(Response::Value(Param::new(404, 2), Value::Dword(0x1234)));
        assert_eq!(resp, [0x00, 0x02, 0x51, 0x94, 0x00, 0x00, 0x12, 0x34]);
    }

    #[test]
    fn classic_little_endian_is_the_canopen_mapping() {
        // 3012h u16 PKE and 3013h u32 PWE, little-endian.
        let req = Request::Write(Param::new(404, 2), Value::Dword(0x1234));
        assert_eq!(
            CLASSIC_LE.encode_request(req),
            [0x00, 0x02, 0x94, 0x81, 0x34, 0x12, 0x00, 0x00]
        );
        let req = Request::Read(Param::new(1022, 0));
        assert_eq!(
            CLASSIC_LE.encode_request(req),
            [0x00, 0x00, 0xFE, 0x13, 0, 0, 0, 0]
        );
        // Error reply 7 with number 0 (PNU does not exist) in the low word.
        let b = CLASSIC_LE.encode_response(Response::Error(Param::new(999, 0), 0));
        assert_eq!(b, [0x00, 0x00, 0xE7, 0x73, 0, 0, 0, 0]);
        assert_eq!(
            CLASSIC_LE.decode_response(&b),
            Ok(Response::Error(Param::new(999, 0), 0))
        );
    }

    #[test]
    fn classic_req_and_res_ids_follow_width_and_array() {
        let cases = [
            (Request::Read(Param::new(400, 0)), 1),
            (Request::Read(Param::new(404, 5)), 6),
            (Request::Write(Param::new(1023, 0), Value::Word(1)), 2),
            (Request::Write(Param::new(1022, 0), Value::Dword(1)), 3),
            (Request::Write(Param::new(401, 1), Value::Word(1)), 7),
            (Request::Write(Param::new(404, 1), Value::Dword(1)), 8),
            (Request::Write(Param::new(520, 0), Value::Byte(1)), 11),
            (Request::Write(Param::new(401, 1), Value::Byte(1)), 12),
        ];
        for (req, id) in cases {
            for codec in [CLASSIC_LE, CLASSIC_BE] {
                let b = codec.encode_request(req);
                let pke = codec.order.u16_from([b[2], b[3]]);
                assert_eq!(pke >> 12, id, "{req:?}");
                assert_eq!(codec.decode_request(&b), Ok(req));
            }
        }
        let res = [
            (Response::Value(Param::new(1, 0), Value::Word(7)), 1),
            (Response::Value(Param::new(1, 0), Value::Dword(7)), 2),
            (Response::Value(Param::new(1, 3), Value::Word(7)), 4),
            (Response::Value(Param::new(1, 3), Value::Dword(7)), 5),
            (Response::ElementCount(Param::new(1, 0), 32), 6),
            (Response::Error(Param::new(1, 0), 22), 7),
            (Response::Value(Param::new(1, 0), Value::Byte(7)), 11),
            (Response::Value(Param::new(1, 3), Value::Byte(7)), 12),
        ];
        for (r, id) in res {
            let b = CLASSIC_LE.encode_response(r);
            assert_eq!(u16::from_le_bytes([b[2], b[3]]) >> 12, id);
            assert_eq!(CLASSIC_LE.decode_response(&b), Ok(r));
        }
    }

    #[test]
    fn classic_rejects_reserved_ids_and_bits() {
        for id in [4u16, 5, 9, 10, 13, 14, 15] {
            let pke = (id << 12) | 401;
            let mut b = [0u8; 8];
            b[2..4].copy_from_slice(&pke.to_le_bytes());
            assert_eq!(
                CLASSIC_LE.decode_request(&b),
                Err(FpcError::UnknownId {
                    id: id as u8,
                    pnu: 401,
                    sub: 0
                })
            );
        }
        assert_eq!(
            CLASSIC_LE.decode_request(&[1, 0, 0, 0, 0, 0, 0, 0]),
            Err(FpcError::Reserved { byte: 1, value: 1 })
        );
        assert!(matches!(
            CLASSIC_BE.decode_request(&[0, 0, 0x18, 0, 0, 0, 0, 0]),
            Err(FpcError::Reserved { byte: 3, .. })
        ));
    }

    #[test]
    fn efpc_example_write_pnu_440_sub_2() {
        // EMCA p.227: FPCC 0x18, sub 2, PNU 0x01B8, value 0x1234; reply 0x15 echoed.
        let req = Request::Write(Param::new(440, 2), Value::Dword(0x1234));
        assert_eq!(
            EFPC_LE.encode_request(req),
            [0x18, 0x02, 0xB8, 0x01, 0x34, 0x12, 0x00, 0x00]
        );
        assert_eq!(
            EFPC_BE.encode_request(req),
            [0x18, 0x02, 0x01, 0xB8, 0x00, 0x00, 0x12, 0x34]
        );
        let reply =
            EFPC_BE.encode_response(Response::Value(Param::new(440, 2), Value::Dword(0x1234)));
        assert_eq!(reply, [0x15, 0x02, 0x01, 0xB8, 0x00, 0x00, 0x12, 0x34]);
        assert_eq!(
            EFPC_BE.encode_request(Request::Read(Param::new(312, 1)))[0],
            0x16
        );
        assert_eq!(EFPC_BE.encode_request(Request::NoTask)[0], 0x10);
        assert_eq!(
            EFPC_BE.encode_response(Response::Error(Param::new(1, 1), 0x02))[0],
            0x17
        );
        // "No job" as 0x00 is accepted too.
        assert_eq!(EFPC_BE.decode_request(&[0; 8]), Ok(Request::NoTask));
        assert_eq!(
            EFPC_BE.decode_request(&[0x44, 0, 0, 0, 0, 0, 0, 0]),
            Err(FpcError::FileMode { fpcc: 0x44 })
        );
        assert_eq!(
            EFPC_BE.decode_request(&[0x24, 0, 0, 0, 0, 0, 0, 0]),
            Err(FpcError::UnknownMode { mode: 2 })
        );
    }

    #[test]
    fn error_numbers_round_trip_per_dialect() {
        for n in 0..=300u16 {
            for ch in [Channel::Classic, Channel::Enhanced] {
                assert_eq!(ErrorKind::from_number(n, ch).number(ch), n);
            }
        }
        assert_eq!(ErrorKind::OutOfRange.number(Channel::Classic), 22);
        assert_eq!(ErrorKind::OutOfRange.number(Channel::Enhanced), 0x02);
        assert_eq!(ErrorKind::NoControl.number(Channel::Classic), 11);
        assert_eq!(ErrorKind::NoControl.number(Channel::Enhanced), 0x0B);
    }

    /// A store with one word parameter (PNU 1023, 1..=30000) and one read-only PNU 1041.
    struct Store {
        window_time: u16,
        writes: u32,
    }

    impl Parameters for Store {
        fn read(&mut self, p: Param) -> Result<Value, ErrorKind> {
            match p.pnu {
                1023 => Ok(Value::Word(self.window_time)),
                1041 => Ok(Value::Dword(0xFFFF_FF9C)),
                _ => Err(ErrorKind::NoSuchPnu),
            }
        }
        fn write(&mut self, p: Param, v: Value) -> Result<(), ErrorKind> {
            match p.pnu {
                1023 => match v.raw() {
                    n @ 1..=30000 => {
                        self.window_time = n as u16;
                        self.writes += 1;
                        Ok(())
                    }
                    _ => Err(ErrorKind::OutOfRange),
                },
                1041 => Err(ErrorKind::ReadOnly),
                _ => Err(ErrorKind::NoSuchPnu),
            }
        }
    }

    #[test]
    fn server_executes_a_repeated_write_once_and_holds_its_reply() {
        let mut store = Store {
            window_time: 100,
            writes: 0,
        };
        let mut s = Server::new(CLASSIC_LE);
        let w = CLASSIC_LE.encode_request(Request::Write(Param::new(1023, 0), Value::Word(250)));
        let r1 = s.handle(&w, &mut store);
        for _ in 0..5 {
            assert_eq!(s.handle(&w, &mut store), r1);
        }
        assert_eq!(store.writes, 1);
        assert_eq!(
            CLASSIC_LE.decode_response(&r1),
            Ok(Response::Value(Param::new(1023, 0), Value::Word(250)))
        );
        // No task → no reply; the same write again then executes again.
        let none = s.handle(&CLASSIC_LE.encode_request(Request::NoTask), &mut store);
        assert_eq!(CLASSIC_LE.decode_response(&none), Ok(Response::NoReply));
        s.handle(&w, &mut store);
        assert_eq!(store.writes, 2);
        // Errors carry the dialect's number.
        let bad = CLASSIC_LE.encode_request(Request::Write(Param::new(1023, 0), Value::Word(0)));
        let r = s.handle(&bad, &mut store);
        assert_eq!(
            CLASSIC_LE.decode_response(&r),
            Ok(Response::Error(Param::new(1023, 0), 22))
        );
        let mut e = Server::new(EFPC_LE);
        let ro = EFPC_LE.encode_request(Request::Write(Param::new(1041, 1), Value::Dword(5)));
        let r = e.handle(&ro, &mut store);
        assert_eq!(
            EFPC_LE.decode_response(&r),
            Ok(Response::Error(Param::new(1041, 1), 0x01))
        );
        // An unsupported ReqID: classic error 22 with PNU and IND echoed.
        let mut b = [0u8; 8];
        b[1] = 3;
        b[2..4].copy_from_slice(&((4u16 << 12) | 1023).to_le_bytes());
        let r = s.handle(&b, &mut store);
        assert_eq!(
            CLASSIC_LE.decode_response(&r),
            Ok(Response::Error(Param::new(1023, 3), 22))
        );
        let r = e.handle(&[0x41, 0, 0, 0, 0, 0, 0, 0], &mut store);
        assert_eq!(
            EFPC_LE.decode_response(&r),
            Ok(Response::Error(Param::default(), 0x11))
        );
    }

    #[test]
    fn client_and_server_read_then_write_with_no_task_in_between() {
        for codec in [CLASSIC_LE, CLASSIC_BE, EFPC_LE, EFPC_BE] {
            let mut store = Store {
                window_time: 100,
                writes: 0,
            };
            let mut server = Server::new(codec);
            let mut client = Client::new(codec, 10);
            let mut reply = server.reply();
            // The client first waits for "no reply".
            assert_eq!(
                client.submit(Request::Read(Param::new(1023, 0))),
                Err(ClientError::Busy)
            );
            client.handle_input(&reply);
            assert!(client.is_idle());
            let sub = if codec.channel == Channel::Enhanced {
                1
            } else {
                0
            };
            let value = |v: u16| match codec.channel {
                Channel::Classic => Value::Word(v),
                Channel::Enhanced => Value::Dword(u32::from(v)),
            };
            let mut results = heapless::Vec::<Result<Value, TaskError>, 4>::new();
            let tasks = [
                Request::Read(Param::new(1023, sub)),
                Request::Write(Param::new(1023, sub), value(300)),
                Request::Write(Param::new(1023, sub), value(300)),
                Request::Write(Param::new(1041, sub), value(1)),
            ];
            let mut next = 0;
            let mut sent_tasks = 0;
            for _ in 0..60 {
                if client.is_idle() && next < tasks.len() {
                    client.submit(tasks[next]).unwrap();
                    next += 1;
                }
                let out = client.output();
                if codec.decode_request(&out) != Ok(Request::NoTask) {
                    sent_tasks += 1;
                }
                reply = server.handle(&out, &mut store);
                if let Some(r) = client.handle_input(&reply) {
                    results.push(r).unwrap();
                }
            }
            assert!(sent_tasks >= 4);
            let ch = codec.channel;
            assert_eq!(
                results.as_slice(),
                &[
                    Ok(value(100)),
                    Ok(value(300)),
                    Ok(value(300)),
                    Err(TaskError::Refused {
                        pnu: 1041,
                        sub,
                        number: ErrorKind::ReadOnly.number(ch),
                        kind: ErrorKind::ReadOnly
                    })
                ],
                "{codec:?}"
            );
            // The identical write ran twice because "no task" separated the two tasks.
            assert_eq!(store.writes, 2);
        }
    }

    #[test]
    fn client_ignores_stale_and_mismatched_replies_and_times_out() {
        let mut c = Client::new(EFPC_BE, 3);
        c.handle_input(&EFPC_BE.encode_response(Response::NoReply));
        c.submit(Request::Read(Param::new(1022, 1))).unwrap();
        // A reply for another parameter does not complete the task.
        let other = EFPC_BE.encode_response(Response::Value(Param::new(1023, 1), Value::Dword(1)));
        assert_eq!(c.handle_input(&other), None);
        assert_eq!(c.handle_input(&[0xFF; 3]), None);
        assert_eq!(
            c.handle_input(&other),
            Some(Err(TaskError::Timeout { cycles: 3 }))
        );
        assert!(!c.is_idle());
        // A write reply with another value is not a match either.
        let mut c = Client::new(CLASSIC_LE, 0);
        c.handle_input(&[0; 8]);
        c.submit(Request::Write(Param::new(1023, 0), Value::Word(5)))
            .unwrap();
        let wrong =
            CLASSIC_LE.encode_response(Response::Value(Param::new(1023, 0), Value::Word(6)));
        assert_eq!(c.handle_input(&wrong), None);
    }

    proptest! {
        #[test]
        fn decoders_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..12)) {
            for codec in [CLASSIC_LE, CLASSIC_BE, EFPC_LE, EFPC_BE] {
                let _ = codec.decode_request(&bytes);
                let _ = codec.decode_response(&bytes);
            }
        }

        #[test]
        fn requests_and_responses_round_trip(pnu in 0u16..2048, sub: u8, v: u32, kind in 0u8..3) {
            let value = match kind { 0 => Value::Byte(v as u8), 1 => Value::Word(v as u16), _ => Value::Dword(v) };
            let p = Param::new(pnu, sub);
            for codec in [CLASSIC_LE, CLASSIC_BE] {
                prop_assert_eq!(codec.decode_request(&codec.encode_request(Request::Write(p, value))), Ok(Request::Write(p, value)));
                prop_assert_eq!(codec.decode_response(&codec.encode_response(Response::Value(p, value))), Ok(Response::Value(p, value)));
            }
            for codec in [EFPC_LE, EFPC_BE] {
                let d = Value::Dword(value.raw());
                prop_assert_eq!(codec.decode_request(&codec.encode_request(Request::Write(p, value))), Ok(Request::Write(p, d)));
                prop_assert_eq!(codec.decode_response(&codec.encode_response(Response::Value(p, value))), Ok(Response::Value(p, d)));
            }
        }
    }

    #[test]
    fn every_first_and_pke_byte_decodes_without_panic() {
        for a in 0..=255u8 {
            for b in 0..=255u8 {
                let t = [a, 1, b, a, 0xFF, 0, b, 7];
                for codec in [CLASSIC_LE, CLASSIC_BE, EFPC_LE, EFPC_BE] {
                    let _ = codec.decode_request(&t);
                    let _ = codec.decode_response(&t);
                }
            }
        }
    }
}
