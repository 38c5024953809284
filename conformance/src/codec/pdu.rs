//! Typed messages: what a frame means, independent of RTU or ASCII framing.
//!
//! A [`Message`] is a node address and a [`Pdu`]. Parsing takes the [`Direction`]
//! explicitly, since requests and responses of 03H and 10H share a function code but not
//! a layout, and an RTU frame does not say which it is. Parsing checks structure only
//! (lengths, byte counts against register counts); value ranges such as "1 to 125
//! registers" are drive-model rules, so a test suite can still build and carry a frame
//! that breaks them.

use std::fmt;

use super::error::FrameError;
use super::hex::Hex;

/// Function codes the TECO drives serve.
pub mod function {
    /// 03H: read holding registers.
    pub const READ_HOLDING_REGISTERS: u8 = 0x03;
    /// 06H: write single register.
    pub const WRITE_SINGLE_REGISTER: u8 = 0x06;
    /// 08H: loop-back (diagnostics).
    pub const LOOP_BACK: u8 = 0x08;
    /// 10H: write multiple registers.
    pub const WRITE_MULTIPLE_REGISTERS: u8 = 0x10;
    /// Added to the function code in an exception response.
    pub const EXCEPTION_BIT: u8 = 0x80;
}

use function::*;

pub use super::direction::Direction;

/// Register values as carried on the wire: big-endian 16-bit words, borrowed.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Registers<'a>(&'a [u8]);

impl<'a> Registers<'a> {
    /// Wraps big-endian register bytes; their length must be even.
    #[inline]
    pub fn new(bytes: &'a [u8]) -> Result<Self, FrameError> {
        if !bytes.len().is_multiple_of(2) {
            return Err(FrameError::OddRegisterBytes { len: bytes.len() });
        }
        Ok(Registers(bytes))
    }

    /// Number of registers.
    pub fn len(&self) -> usize {
        self.0.len() / 2
    }

    /// Whether there are no registers.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// Register `i`, if present.
    pub fn get(&self, i: usize) -> Option<u16> {
        let at = i.checked_mul(2)?;
        let pair = self.0.get(at..at.checked_add(2)?)?;
        Some(u16::from_be_bytes([pair[0], pair[1]]))
    }

    /// The values in order.
    pub fn iter(&self) -> impl ExactSizeIterator<Item = u16> + 'a {
        self.0
            .chunks_exact(2)
            .map(|p| u16::from_be_bytes([p[0], p[1]]))
    }

    /// The wire bytes.
    pub fn as_bytes(&self) -> &'a [u8] {
        self.0
    }
}

impl fmt::Debug for Registers<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list()
            .entries(self.iter().map(|v| format!("{v:04X}")))
            .finish()
    }
}

impl fmt::Display for Registers<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("[")?;
        for (i, v) in self.iter().enumerate() {
            if i > 0 {
                f.write_str(" ")?;
            }
            write!(f, "{v:04X}")?;
        }
        f.write_str("]")
    }
}

/// The protocol data unit: function code and its fields.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Pdu<'a> {
    /// 03H request: read `count` registers from `start`.
    ReadRequest {
        /// First register address.
        start: u16,
        /// Number of registers.
        count: u16,
    },
    /// 03H response: the registers read (byte count = 2 x their number).
    ReadResponse {
        /// Values read.
        values: Registers<'a>,
    },
    /// 06H request, and its normal response (an echo of the request).
    WriteSingle {
        /// Register address.
        register: u16,
        /// Value written.
        value: u16,
    },
    /// 08H loop-back request, and its normal response (an echo). The TECO manuals send a
    /// two-byte test code and two bytes of arbitrary data; other lengths of data parse too.
    LoopBack {
        /// Test (sub-function) code.
        test_code: u16,
        /// Data to echo.
        data: &'a [u8],
    },
    /// 10H request: write `values` from `start` (count and byte count are derived).
    WriteMultipleRequest {
        /// First register address.
        start: u16,
        /// Values to write.
        values: Registers<'a>,
    },
    /// 10H normal response: start and count echoed.
    WriteMultipleResponse {
        /// First register address.
        start: u16,
        /// Number of registers written.
        count: u16,
    },
    /// Exception response: function code with 80H added, then one code byte.
    Exception {
        /// The function code of the failed request (without the 80H bit).
        function: u8,
        /// The exception code (01H..05H in most manuals, 51H..55H in the legacy L510 note).
        code: u8,
    },
    /// Any other function: kept as raw bytes, so the suite can carry frames it does not model.
    Other {
        /// Function code.
        function: u8,
        /// Data bytes after the function code.
        data: &'a [u8],
    },
}

fn be16(b: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([b[at], b[at + 1]])
}

impl<'a> Pdu<'a> {
    /// Parses the data that follows function code `function`, for `direction`.
    #[inline(always)]
    pub fn parse(function: u8, data: &'a [u8], direction: Direction) -> Result<Self, FrameError> {
        let length = |fits: bool, expected: &'static str| {
            if fits {
                Ok(())
            } else {
                Err(FrameError::DataLength {
                    function,
                    direction,
                    expected,
                    found: data.len(),
                })
            }
        };
        let exact = |n: usize, expected| length(data.len() == n, expected);
        let at_least = |n: usize, expected| length(data.len() >= n, expected);
        // The byte count field against the bytes after it.
        let counted = |byte_count: u8, rest: &[u8]| {
            if usize::from(byte_count) == rest.len() {
                Ok(())
            } else {
                Err(FrameError::ByteCount {
                    function,
                    direction,
                    byte_count,
                    found: rest.len(),
                })
            }
        };
        match (direction, function) {
            (Direction::Response, f) if f & EXCEPTION_BIT != 0 => {
                if data.len() != 1 {
                    return Err(FrameError::ExceptionLength {
                        function: f,
                        found: data.len(),
                    });
                }
                Ok(Pdu::Exception {
                    function: f & !EXCEPTION_BIT,
                    code: data[0],
                })
            }
            (Direction::Request, READ_HOLDING_REGISTERS) => {
                exact(4, "4")?;
                Ok(Pdu::ReadRequest {
                    start: be16(data, 0),
                    count: be16(data, 2),
                })
            }
            (Direction::Response, READ_HOLDING_REGISTERS) => {
                at_least(1, "at least 1 (byte count)")?;
                let (byte_count, rest) = (data[0], &data[1..]);
                counted(byte_count, rest)?;
                Ok(Pdu::ReadResponse {
                    values: Registers::new(rest)?,
                })
            }
            (_, WRITE_SINGLE_REGISTER) => {
                exact(4, "4")?;
                Ok(Pdu::WriteSingle {
                    register: be16(data, 0),
                    value: be16(data, 2),
                })
            }
            (_, LOOP_BACK) => {
                at_least(2, "at least 2 (test code)")?;
                Ok(Pdu::LoopBack {
                    test_code: be16(data, 0),
                    data: &data[2..],
                })
            }
            (Direction::Request, WRITE_MULTIPLE_REGISTERS) => {
                at_least(5, "at least 5 (start, count, byte count)")?;
                let start = be16(data, 0);
                let count = be16(data, 2);
                let byte_count = data[4];
                let rest = &data[5..];
                counted(byte_count, rest)?;
                if u32::from(count) * 2 != u32::from(byte_count) {
                    return Err(FrameError::CountMismatch {
                        count,
                        byte_count,
                        expected: u32::from(count) * 2,
                    });
                }
                Ok(Pdu::WriteMultipleRequest {
                    start,
                    values: Registers::new(rest)?,
                })
            }
            (Direction::Response, WRITE_MULTIPLE_REGISTERS) => {
                exact(4, "4")?;
                Ok(Pdu::WriteMultipleResponse {
                    start: be16(data, 0),
                    count: be16(data, 2),
                })
            }
            _ => Ok(Pdu::Other { function, data }),
        }
    }

    /// The function byte on the wire (with 80H set for an exception).
    pub fn function_code(&self) -> u8 {
        match self {
            Pdu::ReadRequest { .. } | Pdu::ReadResponse { .. } => READ_HOLDING_REGISTERS,
            Pdu::WriteSingle { .. } => WRITE_SINGLE_REGISTER,
            Pdu::LoopBack { .. } => LOOP_BACK,
            Pdu::WriteMultipleRequest { .. } | Pdu::WriteMultipleResponse { .. } => {
                WRITE_MULTIPLE_REGISTERS
            }
            Pdu::Exception { function, .. } => function | EXCEPTION_BIT,
            Pdu::Other { function, .. } => *function,
        }
    }

    /// Length of the data after the function byte.
    pub fn data_len(&self) -> usize {
        match self {
            Pdu::ReadRequest { .. }
            | Pdu::WriteSingle { .. }
            | Pdu::WriteMultipleResponse { .. } => 4,
            Pdu::ReadResponse { values } => 1 + values.as_bytes().len(),
            Pdu::LoopBack { data, .. } => 2 + data.len(),
            Pdu::WriteMultipleRequest { values, .. } => 5 + values.as_bytes().len(),
            Pdu::Exception { .. } => 1,
            Pdu::Other { data, .. } => data.len(),
        }
    }

    /// Writes the data after the function byte into `out`, which must hold
    /// [`data_len`](Self::data_len) bytes; returns the bytes written.
    pub fn emit_data(&self, out: &mut [u8]) -> Result<usize, FrameError> {
        let n = self.data_len();
        if out.len() < n {
            return Err(FrameError::BufferTooSmall {
                needed: n,
                available: out.len(),
            });
        }
        let too_long = |bytes: usize| FrameError::TooLongToEncode {
            needed: bytes + 4,
            max: super::MAX_RTU_FRAME,
        };
        match *self {
            Pdu::ReadRequest { start: a, count: b }
            | Pdu::WriteSingle {
                register: a,
                value: b,
            }
            | Pdu::WriteMultipleResponse { start: a, count: b } => {
                out[0..2].copy_from_slice(&a.to_be_bytes());
                out[2..4].copy_from_slice(&b.to_be_bytes());
            }
            Pdu::ReadResponse { values } => {
                let bytes = values.as_bytes();
                out[0] = u8::try_from(bytes.len()).map_err(|_| too_long(n))?;
                out[1..n].copy_from_slice(bytes);
            }
            Pdu::LoopBack { test_code, data } => {
                out[0..2].copy_from_slice(&test_code.to_be_bytes());
                out[2..n].copy_from_slice(data);
            }
            Pdu::WriteMultipleRequest { start, values } => {
                let bytes = values.as_bytes();
                let byte_count = u8::try_from(bytes.len()).map_err(|_| too_long(n))?;
                out[0..2].copy_from_slice(&start.to_be_bytes());
                // byte_count <= 255, so the register count fits easily.
                out[2..4].copy_from_slice(&(u16::from(byte_count) / 2).to_be_bytes());
                out[4] = byte_count;
                out[5..n].copy_from_slice(bytes);
            }
            Pdu::Exception { code, .. } => out[0] = code,
            Pdu::Other { data, .. } => out[..n].copy_from_slice(data),
        }
        Ok(n)
    }

    /// The direction this PDU's layout belongs to, where it is fixed by the variant
    /// (`None` for layouts shared by request and response).
    pub fn direction(&self) -> Option<Direction> {
        match self {
            Pdu::ReadRequest { .. } | Pdu::WriteMultipleRequest { .. } => Some(Direction::Request),
            Pdu::ReadResponse { .. }
            | Pdu::WriteMultipleResponse { .. }
            | Pdu::Exception { .. } => Some(Direction::Response),
            Pdu::WriteSingle { .. } | Pdu::LoopBack { .. } | Pdu::Other { .. } => None,
        }
    }

    /// A short name of the function and layout, e.g. "read holding registers request".
    pub fn name(&self) -> &'static str {
        match self {
            Pdu::ReadRequest { .. } => "read holding registers request",
            Pdu::ReadResponse { .. } => "read holding registers response",
            Pdu::WriteSingle { .. } => "write single register",
            Pdu::LoopBack { .. } => "loop-back",
            Pdu::WriteMultipleRequest { .. } => "write multiple registers request",
            Pdu::WriteMultipleResponse { .. } => "write multiple registers response",
            Pdu::Exception { .. } => "exception response",
            Pdu::Other { .. } => "unmodelled function",
        }
    }
}

impl fmt::Display for Pdu<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let fc = self.function_code();
        match self {
            Pdu::ReadRequest { start, count } => {
                write!(f, "{fc:02X} read request start={start:04X} count={count}")
            }
            Pdu::ReadResponse { values } => write!(
                f,
                "{fc:02X} read response byte_count={} values={values}",
                values.as_bytes().len()
            ),
            Pdu::WriteSingle { register, value } => {
                write!(f, "{fc:02X} write single register={register:04X} value={value:04X}")
            }
            Pdu::LoopBack { test_code, data } => {
                write!(f, "{fc:02X} loop-back test_code={test_code:04X} data=[{}]", Hex(data))
            }
            Pdu::WriteMultipleRequest { start, values } => write!(
                f,
                "{fc:02X} write multiple request start={start:04X} count={} byte_count={} values={values}",
                values.len(),
                values.as_bytes().len()
            ),
            Pdu::WriteMultipleResponse { start, count } => {
                write!(f, "{fc:02X} write multiple response start={start:04X} count={count}")
            }
            Pdu::Exception { function, code } => {
                write!(f, "{fc:02X} exception function={function:02X} code={code:02X}")
            }
            Pdu::Other { data, .. } => write!(f, "{fc:02X} unmodelled data=[{}]", Hex(data)),
        }
    }
}

/// A node address and a PDU: the meaning of one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Message<'a> {
    /// Node address: 00H broadcast, 01H..F7H in Modbus (the TECO manuals allow up to FEH).
    pub address: u8,
    /// The protocol data unit.
    pub pdu: Pdu<'a>,
}

impl<'a> Message<'a> {
    /// Parses address, function and data (no checksum) for `direction`.
    #[inline(always)]
    pub fn parse_body(body: &'a [u8], direction: Direction) -> Result<Self, FrameError> {
        match body {
            [address, function, data @ ..] => Ok(Message {
                address: *address,
                pdu: Pdu::parse(*function, data, direction)?,
            }),
            _ => Err(FrameError::RtuTooShort {
                len: body.len() + 2,
            }),
        }
    }

    /// Length of address, function and data.
    pub fn body_len(&self) -> usize {
        2 + self.pdu.data_len()
    }

    /// Writes address, function and data into `out`; returns the bytes written.
    pub fn emit_body(&self, out: &mut [u8]) -> Result<usize, FrameError> {
        let n = self.body_len();
        if n + 2 > super::MAX_RTU_FRAME {
            return Err(FrameError::TooLongToEncode {
                needed: n + 2,
                max: super::MAX_RTU_FRAME,
            });
        }
        if out.len() < n {
            return Err(FrameError::BufferTooSmall {
                needed: n,
                available: out.len(),
            });
        }
        out[0] = self.address;
        out[1] = self.pdu.function_code();
        self.pdu.emit_data(&mut out[2..n])?;
        Ok(n)
    }
}

impl fmt::Display for Message<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "node {:02X} {}", self.address, self.pdu)
    }
}

impl Message<'_> {
    /// The message as labelled fields, for reports and the command line
    /// (`[("address", "01"), ("function", "03 read holding registers request"), ...]`).
    pub fn fields(&self) -> Vec<(&'static str, String)> {
        let mut out = vec![
            ("address", format!("{:02X}", self.address)),
            (
                "function",
                format!("{:02X} {}", self.pdu.function_code(), self.pdu.name()),
            ),
        ];
        match self.pdu {
            Pdu::ReadRequest { start, count } | Pdu::WriteMultipleResponse { start, count } => {
                out.push(("start", format!("{start:04X}")));
                out.push(("count", format!("{count}")));
            }
            Pdu::ReadResponse { values } => {
                out.push(("byte count", format!("{}", values.as_bytes().len())));
                out.push(("values", values.to_string()));
            }
            Pdu::WriteSingle { register, value } => {
                out.push(("register", format!("{register:04X}")));
                out.push(("value", format!("{value:04X} ({value})")));
            }
            Pdu::LoopBack { test_code, data } => {
                out.push(("test code", format!("{test_code:04X}")));
                out.push(("data", Hex(data).to_string()));
            }
            Pdu::WriteMultipleRequest { start, values } => {
                out.push(("start", format!("{start:04X}")));
                out.push(("count", format!("{}", values.len())));
                out.push(("byte count", format!("{}", values.as_bytes().len())));
                out.push(("values", values.to_string()));
            }
            Pdu::Exception { function, code } => {
                out.push(("failed function", format!("{function:02X}")));
                out.push(("exception code", format!("{code:02X}")));
            }
            Pdu::Other { data, .. } => out.push(("data", Hex(data).to_string())),
        }
        out
    }
}
