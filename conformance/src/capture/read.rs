//! The reader: classic pcap and pcapng, both byte orders, from a byte slice.
//!
//! Total over all inputs: every length field is checked against the bytes actually
//! present before anything is sliced, nothing is allocated by a length field (packets are
//! borrowed from the input), and the first fault ends the iteration with a
//! [`ReadError`] that names the byte offset and the block.

use std::fmt;

use super::write::{block, opt};
use super::Direction;

/// The kind of block or record a fault is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BlockKind {
    /// The first bytes of the file, which say its format.
    FileHeader,
    /// A classic pcap per-packet record.
    PcapRecord,
    /// A pcapng Section Header Block.
    Section,
    /// A pcapng Interface Description Block.
    Interface,
    /// A pcapng Enhanced Packet Block.
    EnhancedPacket,
    /// A pcapng Simple Packet Block.
    SimplePacket,
    /// A pcapng (obsolete) Packet Block.
    ObsoletePacket,
    /// Any other pcapng block, by its type.
    Other(u32),
    /// A block whose type the file ends before.
    Unreadable,
}

impl BlockKind {
    fn of(kind: u32) -> BlockKind {
        match kind {
            block::SHB => BlockKind::Section,
            block::IDB => BlockKind::Interface,
            block::EPB => BlockKind::EnhancedPacket,
            block::SPB => BlockKind::SimplePacket,
            block::PB => BlockKind::ObsoletePacket,
            other => BlockKind::Other(other),
        }
    }
}

impl fmt::Display for BlockKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BlockKind::FileHeader => f.write_str("file header"),
            BlockKind::PcapRecord => f.write_str("pcap record"),
            BlockKind::Section => f.write_str("Section Header Block"),
            BlockKind::Interface => f.write_str("Interface Description Block"),
            BlockKind::EnhancedPacket => f.write_str("Enhanced Packet Block"),
            BlockKind::SimplePacket => f.write_str("Simple Packet Block"),
            BlockKind::ObsoletePacket => f.write_str("Packet Block"),
            BlockKind::Other(t) => write!(f, "block of type {t:08X}H"),
            BlockKind::Unreadable => f.write_str("block (its type cut off)"),
        }
    }
}

/// Why a capture file cannot be read (further). Every variant names the byte offset of
/// the fault and the block it is in.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ReadError {
    /// Neither pcap nor pcapng.
    #[error("at byte 0: not a pcap or pcapng file: the file starts with {found}, expected A1B2C3D4H or A1B23C4DH (pcap, either byte order) or 0A0D0D0AH (pcapng)")]
    NotACapture {
        /// The first bytes, in hex.
        found: String,
    },
    /// The file ends inside a block.
    #[error("at byte {offset}: {block} cut short: it needs {needed} bytes, the file has {available} left")]
    Truncated {
        /// Where the block starts.
        offset: u64,
        /// The block.
        block: BlockKind,
        /// Bytes the block needs.
        needed: u64,
        /// Bytes left in the file.
        available: u64,
    },
    /// A block length below the block's minimum or not a multiple of 4.
    #[error("at byte {offset}: {block} has a length of {length} bytes: expected a multiple of 4, at least {minimum}")]
    BadLength {
        /// Where the block starts.
        offset: u64,
        /// The block.
        block: BlockKind,
        /// The length field.
        length: u32,
        /// The block's minimum.
        minimum: u32,
    },
    /// The length at the end of a block differs from the one at its start.
    #[error(
        "at byte {offset}: {block} says {leading} bytes at its start and {trailing} at its end"
    )]
    LengthMismatch {
        /// Where the block starts.
        offset: u64,
        /// The block.
        block: BlockKind,
        /// The leading length.
        leading: u32,
        /// The trailing length.
        trailing: u32,
    },
    /// A section header whose byte-order magic is neither order of 1A2B3C4DH.
    #[error("at byte {offset}: Section Header Block's byte-order magic is {found:08X}H, expected 1A2B3C4DH in either byte order")]
    BadByteOrder {
        /// Where the block starts.
        offset: u64,
        /// The magic as read little-endian.
        found: u32,
    },
    /// A major version this reader does not know.
    #[error("at byte {offset}: {block} has version {major}.{minor}, expected {expected}")]
    Version {
        /// Where the block starts.
        offset: u64,
        /// The block.
        block: BlockKind,
        /// Major version.
        major: u16,
        /// Minor version.
        minor: u16,
        /// What is read.
        expected: &'static str,
    },
    /// A packet on an interface its section never described.
    #[error("at byte {offset}: {block} is on interface {interface}, but its section describes {described}")]
    UnknownInterface {
        /// Where the block starts.
        offset: u64,
        /// The block.
        block: BlockKind,
        /// The interface id.
        interface: u32,
        /// Interfaces described so far in the section.
        described: usize,
    },
    /// A captured length that does not fit in its block.
    #[error("at byte {offset}: {block} says {captured} captured bytes, but has room for {room}")]
    PacketTooLong {
        /// Where the block starts.
        offset: u64,
        /// The block.
        block: BlockKind,
        /// The captured length field.
        captured: u32,
        /// Bytes the block has for the packet.
        room: u64,
    },
    /// An option that overruns its block.
    #[error("at byte {offset}: option {code} of the {block} says {length} bytes, the block has {room} left")]
    BadOption {
        /// Where the option starts.
        offset: u64,
        /// The block.
        block: BlockKind,
        /// The option code.
        code: u16,
        /// Its length field.
        length: u16,
        /// Bytes left in the block's options.
        room: u64,
    },
}

/// One packet read back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Packet<'a> {
    /// Time of the packet, nanoseconds since the Unix epoch (as the file says, with its
    /// resolution); None in a Simple Packet Block, which has no time.
    pub timestamp_ns: Option<u64>,
    /// The interface (0 in a pcap file).
    pub interface: u32,
    /// The interface's link type.
    pub link_type: u16,
    /// `epb_flags` (or `pack_flags`), where the file has them.
    pub flags: Option<u32>,
    /// The direction the flags give, if any.
    pub direction: Option<Direction>,
    /// The first `opt_comment`, where it is UTF-8.
    pub comment: Option<&'a str>,
    /// The bytes captured.
    pub data: &'a [u8],
    /// The packet's length on the line (more than `data` where the capture cut it).
    pub original_len: u32,
}

/// One interface of a pcapng section.
#[derive(Debug, Clone, Copy)]
struct Iface {
    link_type: u16,
    snaplen: u32,
    tsresol: u8,
    tsoffset: i64,
}

#[derive(Debug)]
enum Format {
    Pcap {
        big: bool,
        nanos: bool,
        link_type: u16,
    },
    Pcapng {
        big: bool,
        interfaces: Vec<Iface>,
    },
}

/// Reads the packets of a pcap or pcapng file held in memory, in file order.
#[derive(Debug)]
pub struct Reader<'a> {
    data: &'a [u8],
    pos: usize,
    format: Format,
    done: bool,
}

/// The `N` bytes at `at`, least significant first whatever the file's byte order.
fn le_bytes_at<const N: usize>(d: &[u8], at: usize, big: bool) -> [u8; N] {
    let mut b: [u8; N] = d[at..at + N].try_into().unwrap_or([0; N]);
    if big {
        b.reverse();
    }
    b
}

fn u16_at(d: &[u8], at: usize, big: bool) -> u16 {
    u16::from_le_bytes(le_bytes_at(d, at, big))
}

fn u32_at(d: &[u8], at: usize, big: bool) -> u32 {
    u32::from_le_bytes(le_bytes_at(d, at, big))
}

fn pad4(n: u64) -> u64 {
    (n + 3) & !3
}

/// `ts` in units of `tsresol` (pcapng: bit 7 clear, 10^-n s; set, 2^-n s) to ns.
fn to_nanos(ts: u64, tsresol: u8, tsoffset: i64) -> u64 {
    // The usual case (a power of ten up to ns, no offset) in u64: the same, saturated.
    if tsoffset == 0 && tsresol <= 9 {
        return ts.saturating_mul(10u64.pow(9 - u32::from(tsresol)));
    }
    let n = u32::from(tsresol & 0x7F);
    let ns: u128 = if tsresol & 0x80 == 0 {
        if n <= 9 {
            u128::from(ts) * 10u128.pow(9 - n)
        } else {
            match 10u128.checked_pow(n - 9) {
                Some(d) => u128::from(ts) / d,
                None => 0,
            }
        }
    } else {
        (u128::from(ts) * 1_000_000_000) >> n
    };
    let off = i128::from(tsoffset) * 1_000_000_000;
    let total = (ns as i128).saturating_add(off);
    total.clamp(0, i128::from(u64::MAX)) as u64
}

/// What the options of a block say that the reader uses.
#[derive(Default)]
struct Options<'a> {
    flags: Option<u32>,
    comment: Option<&'a str>,
    tsresol: Option<u8>,
    tsoffset: Option<i64>,
}

/// Parses the options in `d[start..end]` of a block of `kind` (options of interface
/// blocks and of packet blocks share codes, so `kind` says which apply).
fn options(
    d: &[u8],
    start: usize,
    end: usize,
    big: bool,
    kind: BlockKind,
) -> Result<Options<'_>, ReadError> {
    let mut o = Options::default();
    let mut at = start;
    while end - at >= 4 {
        let code = u16_at(d, at, big);
        let len = u16_at(d, at + 2, big);
        let room = (end - at - 4) as u64;
        if u64::from(len) > room {
            return Err(ReadError::BadOption {
                offset: at as u64,
                block: kind,
                code,
                length: len,
                room,
            });
        }
        if code == opt::END {
            break;
        }
        let v = &d[at + 4..at + 4 + usize::from(len)];
        match (kind, code) {
            (_, opt::COMMENT) if o.comment.is_none() => {
                o.comment = std::str::from_utf8(v).ok();
            }
            (BlockKind::Interface, opt::IF_TSRESOL) if !v.is_empty() => o.tsresol = Some(v[0]),
            (BlockKind::Interface, opt::IF_TSOFFSET) if v.len() == 8 => {
                let b = [v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7]];
                o.tsoffset = Some(if big {
                    i64::from_be_bytes(b)
                } else {
                    i64::from_le_bytes(b)
                });
            }
            (BlockKind::EnhancedPacket | BlockKind::ObsoletePacket, opt::EPB_FLAGS)
                if v.len() == 4 =>
            {
                o.flags = Some(u32_at(v, 0, big));
            }
            _ => {}
        }
        // The last option may leave out its padding where the block ends.
        at = (at + 4 + pad4(u64::from(len)) as usize).min(end);
    }
    Ok(o)
}

/// A reader's knowledge of its file, between two parts of it (see
/// [`Reader::into_state`]).
#[derive(Debug)]
pub struct ReaderState {
    format: Format,
}

impl ReadError {
    /// Whether the bytes ended inside a block, record or header (more of the file may
    /// hold the rest).
    pub fn is_truncated(&self) -> bool {
        matches!(self, ReadError::Truncated { .. })
    }

    /// Where in the file the fault is, in bytes from its start (0 where the file is no
    /// capture at all).
    pub fn offset(&self) -> u64 {
        self.clone().offset_mut().map_or(0, |o| *o)
    }

    /// The same fault in a part of the file that begins `base` bytes into it: its
    /// offset counted from the file's start.
    pub fn at_base(mut self, base: u64) -> ReadError {
        if let Some(offset) = self.offset_mut() {
            *offset = offset.saturating_add(base);
        }
        self
    }

    /// The offset every variant but [`ReadError::NotACapture`] carries: one list of the
    /// variants for reading it and for moving it.
    fn offset_mut(&mut self) -> Option<&mut u64> {
        match self {
            ReadError::NotACapture { .. } => None,
            ReadError::Truncated { offset, .. }
            | ReadError::BadLength { offset, .. }
            | ReadError::LengthMismatch { offset, .. }
            | ReadError::BadByteOrder { offset, .. }
            | ReadError::Version { offset, .. }
            | ReadError::UnknownInterface { offset, .. }
            | ReadError::PacketTooLong { offset, .. }
            | ReadError::BadOption { offset, .. } => Some(offset),
        }
    }
}

impl<'a> Reader<'a> {
    /// Reads the file header of `data`, a whole pcap or pcapng file.
    pub fn new(data: &'a [u8]) -> Result<Self, ReadError> {
        // The file header is the only block read before its length is known: a short
        // file is truncated at offset 0, whichever length the header needed.
        let header_needs = |needed: u64| {
            if (data.len() as u64) < needed {
                Err(ReadError::Truncated {
                    offset: 0,
                    block: BlockKind::FileHeader,
                    needed,
                    available: data.len() as u64,
                })
            } else {
                Ok(())
            }
        };
        header_needs(4)?;
        let magic = [data[0], data[1], data[2], data[3]];
        let le = u32::from_le_bytes(magic);
        let pcap = match le {
            0xA1B2_C3D4 => Some((false, false)),
            0xA1B2_3C4D => Some((false, true)),
            0xD4C3_B2A1 => Some((true, false)),
            0x4D3C_B2A1 => Some((true, true)),
            _ => None,
        };
        let format = if let Some((big, nanos)) = pcap {
            header_needs(24)?;
            let (major, minor) = (u16_at(data, 4, big), u16_at(data, 6, big));
            if major != 2 {
                return Err(ReadError::Version {
                    offset: 0,
                    block: BlockKind::FileHeader,
                    major,
                    minor,
                    expected: "2.x",
                });
            }
            // The upper bits of the link type field carry FCS information.
            let link_type = u32_at(data, 20, big) as u16;
            Format::Pcap {
                big,
                nanos,
                link_type,
            }
        } else if le == block::SHB {
            Format::Pcapng {
                big: false,
                interfaces: Vec::new(),
            }
        } else {
            return Err(ReadError::NotACapture {
                found: magic.iter().map(|b| format!("{b:02X}")).collect(),
            });
        };
        let pos = if matches!(format, Format::Pcap { .. }) {
            24
        } else {
            0
        };
        Ok(Reader {
            data,
            pos,
            format,
            done: false,
        })
    }

    /// What the reader knows of the file (its format, byte order, interfaces), to go
    /// on in a later part of it ([`Reader::resume`]) from the next block or record,
    /// which is at this reader's [`offset`](Reader::offset) in its bytes.
    pub fn into_state(self) -> ReaderState {
        ReaderState {
            format: self.format,
        }
    }

    /// Reads on in `data`, the part of the file that begins at the next block or record
    /// of the reader `state` came from.
    pub fn resume(data: &'a [u8], state: ReaderState) -> Self {
        Reader {
            data,
            pos: 0,
            format: state.format,
            done: false,
        }
    }

    /// Whether the file is pcapng (else classic pcap).
    pub fn is_pcapng(&self) -> bool {
        matches!(self.format, Format::Pcapng { .. })
    }

    /// The byte offset of the next block or record.
    pub fn offset(&self) -> u64 {
        self.pos as u64
    }

    fn next_pcap(
        &mut self,
        big: bool,
        nanos: bool,
        link_type: u16,
    ) -> Option<Result<Packet<'a>, ReadError>> {
        let d = self.data;
        let at = self.pos;
        let left = d.len() - at;
        if left == 0 {
            return None;
        }
        if left < 16 {
            return Some(Err(ReadError::Truncated {
                offset: at as u64,
                block: BlockKind::PcapRecord,
                needed: 16,
                available: left as u64,
            }));
        }
        let sec = u64::from(u32_at(d, at, big));
        let frac = u64::from(u32_at(d, at + 4, big));
        let incl = u32_at(d, at + 8, big);
        let orig = u32_at(d, at + 12, big);
        if u64::from(incl) > (left - 16) as u64 {
            return Some(Err(ReadError::Truncated {
                offset: at as u64,
                block: BlockKind::PcapRecord,
                needed: 16 + u64::from(incl),
                available: left as u64,
            }));
        }
        let data = &d[at + 16..at + 16 + incl as usize];
        self.pos = at + 16 + incl as usize;
        let ns = sec.saturating_mul(1_000_000_000).saturating_add(if nanos {
            frac
        } else {
            frac.saturating_mul(1000)
        });
        Some(Ok(Packet {
            timestamp_ns: Some(ns),
            interface: 0,
            link_type,
            flags: None,
            direction: None,
            comment: None,
            data,
            original_len: orig,
        }))
    }

    /// The next pcapng block: Ok(Some(packet)), Ok(None) for a block that is no packet.
    fn pcapng_block(&mut self) -> Result<Option<Packet<'a>>, ReadError> {
        let d = self.data;
        let at = self.pos;
        let left = d.len() - at;
        let Format::Pcapng { big, interfaces } = &mut self.format else {
            return Ok(None);
        };
        if left < 8 {
            let kind = if left >= 4 {
                BlockKind::of(u32_at(d, at, *big))
            } else {
                BlockKind::Unreadable
            };
            return Err(ReadError::Truncated {
                offset: at as u64,
                block: kind,
                needed: 12,
                available: left as u64,
            });
        }
        let kind_raw = u32_at(d, at, *big);
        if kind_raw == block::SHB {
            if left < 12 {
                return Err(ReadError::Truncated {
                    offset: at as u64,
                    block: BlockKind::Section,
                    needed: 28,
                    available: left as u64,
                });
            }
            *big = match u32_at(d, at + 8, false) {
                block::BYTE_ORDER_MAGIC => false,
                0x4D3C_2B1A => true,
                found => {
                    return Err(ReadError::BadByteOrder {
                        offset: at as u64,
                        found,
                    })
                }
            };
        }
        let big = *big;
        let kind = BlockKind::of(kind_raw);
        let length = u32_at(d, at + 4, big);
        let minimum: u32 = match kind {
            BlockKind::Section => 28,
            BlockKind::Interface => 20,
            BlockKind::EnhancedPacket => 32,
            BlockKind::ObsoletePacket => 32,
            BlockKind::SimplePacket => 16,
            _ => 12,
        };
        if length < minimum || !length.is_multiple_of(4) {
            return Err(ReadError::BadLength {
                offset: at as u64,
                block: kind,
                length,
                minimum,
            });
        }
        if u64::from(length) > left as u64 {
            return Err(ReadError::Truncated {
                offset: at as u64,
                block: kind,
                needed: u64::from(length),
                available: left as u64,
            });
        }
        let len = length as usize;
        let trailing = u32_at(d, at + len - 4, big);
        if trailing != length {
            return Err(ReadError::LengthMismatch {
                offset: at as u64,
                block: kind,
                leading: length,
                trailing,
            });
        }
        // The body: d[body..end].
        let body = at + 8;
        let end = at + len - 4;
        self.pos = at + len;
        match kind {
            BlockKind::Section => {
                let (major, minor) = (u16_at(d, body + 4, big), u16_at(d, body + 6, big));
                if major != 1 {
                    return Err(ReadError::Version {
                        offset: at as u64,
                        block: kind,
                        major,
                        minor,
                        expected: "1.x",
                    });
                }
                options(d, body + 16, end, big, kind)?;
                interfaces.clear();
                Ok(None)
            }
            BlockKind::Interface => {
                let link_type = u16_at(d, body, big);
                let snaplen = u32_at(d, body + 4, big);
                let o = options(d, body + 8, end, big, kind)?;
                interfaces.push(Iface {
                    link_type,
                    snaplen,
                    tsresol: o.tsresol.unwrap_or(6),
                    tsoffset: o.tsoffset.unwrap_or(0),
                });
                Ok(None)
            }
            BlockKind::EnhancedPacket | BlockKind::ObsoletePacket => {
                let obsolete = kind == BlockKind::ObsoletePacket;
                let interface = if obsolete {
                    u32::from(u16_at(d, body, big))
                } else {
                    u32_at(d, body, big)
                };
                let Some(iface) = interfaces.get(interface as usize).copied() else {
                    return Err(ReadError::UnknownInterface {
                        offset: at as u64,
                        block: kind,
                        interface,
                        described: interfaces.len(),
                    });
                };
                let ts = (u64::from(u32_at(d, body + 4, big)) << 32)
                    | u64::from(u32_at(d, body + 8, big));
                let captured = u32_at(d, body + 12, big);
                let original_len = u32_at(d, body + 16, big);
                let room = (end - (body + 20)) as u64;
                if pad4(u64::from(captured)) > room {
                    return Err(ReadError::PacketTooLong {
                        offset: at as u64,
                        block: kind,
                        captured,
                        room,
                    });
                }
                let start = body + 20;
                let data = &d[start..start + captured as usize];
                let o = options(
                    d,
                    start + pad4(u64::from(captured)) as usize,
                    end,
                    big,
                    kind,
                )?;
                Ok(Some(Packet {
                    timestamp_ns: Some(to_nanos(ts, iface.tsresol, iface.tsoffset)),
                    interface,
                    link_type: iface.link_type,
                    flags: o.flags,
                    direction: o.flags.and_then(Direction::from_flags),
                    comment: o.comment,
                    data,
                    original_len,
                }))
            }
            BlockKind::SimplePacket => {
                let Some(iface) = interfaces.first().copied() else {
                    return Err(ReadError::UnknownInterface {
                        offset: at as u64,
                        block: kind,
                        interface: 0,
                        described: 0,
                    });
                };
                let original_len = u32_at(d, body, big);
                let room = end - (body + 4);
                let mut n = original_len as usize;
                if iface.snaplen != 0 {
                    n = n.min(iface.snaplen as usize);
                }
                if n > room {
                    return Err(ReadError::PacketTooLong {
                        offset: at as u64,
                        block: kind,
                        captured: n as u32,
                        room: room as u64,
                    });
                }
                Ok(Some(Packet {
                    timestamp_ns: None,
                    interface: 0,
                    link_type: iface.link_type,
                    flags: None,
                    direction: None,
                    comment: None,
                    data: &d[body + 4..body + 4 + n],
                    original_len,
                }))
            }
            _ => Ok(None),
        }
    }
}

impl<'a> Iterator for Reader<'a> {
    type Item = Result<Packet<'a>, ReadError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        let r = match self.format {
            Format::Pcap {
                big,
                nanos,
                link_type,
            } => self.next_pcap(big, nanos, link_type),
            Format::Pcapng { .. } => loop {
                if self.pos >= self.data.len() {
                    break None;
                }
                match self.pcapng_block() {
                    Ok(Some(p)) => break Some(Ok(p)),
                    Ok(None) => continue,
                    Err(e) => break Some(Err(e)),
                }
            },
        };
        if !matches!(r, Some(Ok(_))) {
            self.done = true;
        }
        r
    }
}
