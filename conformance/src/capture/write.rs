//! The pcapng writer.
//!
//! Blocks are little-endian (the byte-order magic says so; readers of both orders accept
//! it). Each block is built in a buffer and handed to the sink with one `write_all`, then
//! flushed: a file cut short by a crash or a kill ends on a block boundary.

use std::io::Write;

/// Block types.
pub(crate) mod block {
    /// Section Header Block.
    pub const SHB: u32 = 0x0A0D_0D0A;
    /// Interface Description Block.
    pub const IDB: u32 = 0x0000_0001;
    /// Obsolete Packet Block.
    pub const PB: u32 = 0x0000_0002;
    /// Simple Packet Block.
    pub const SPB: u32 = 0x0000_0003;
    /// Enhanced Packet Block.
    pub const EPB: u32 = 0x0000_0006;
    /// The byte-order magic of a section header.
    pub const BYTE_ORDER_MAGIC: u32 = 0x1A2B_3C4D;
}

/// Option codes.
pub(crate) mod opt {
    pub const END: u16 = 0;
    pub const COMMENT: u16 = 1;
    pub const SHB_USERAPPL: u16 = 4;
    pub const IF_NAME: u16 = 2;
    pub const IF_DESCRIPTION: u16 = 3;
    pub const IF_TSRESOL: u16 = 9;
    pub const IF_TSOFFSET: u16 = 14;
    pub const EPB_FLAGS: u16 = 2;
}

/// Why a capture could not be written.
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    /// The sink failed.
    #[error("cannot write the capture: {0}")]
    Io(#[from] std::io::Error),
    /// A packet names an interface that was never described.
    #[error("packet on interface {interface}, but only {described} interfaces are described")]
    NoInterface {
        /// The interface asked for.
        interface: u32,
        /// How many were described.
        described: u32,
    },
    /// A packet or option longer than a block can hold.
    #[error("{what} of {len} bytes does not fit a pcapng block")]
    TooLong {
        /// What was too long.
        what: &'static str,
        /// Its length.
        len: usize,
    },
}

/// One link: an Interface Description Block.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Interface {
    /// Link type ([`super::LINKTYPE_USER0`] for RTU, ...).
    pub link_type: u16,
    /// `if_name`: the port or address ("/dev/ttyUSB0", "pty /dev/pts/3").
    pub name: String,
    /// `if_description`: port, mode and line settings.
    pub description: String,
}

/// What is known of one packet besides its bytes.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PacketMeta {
    /// The interface index (the order of [`PcapngWriter::add_interface`] calls).
    pub interface: u32,
    /// Time of the first byte, microseconds since the Unix epoch.
    pub timestamp_us: u64,
    /// `epb_flags`: direction and link-layer error bits; 0 writes no flags option.
    pub flags: u32,
    /// `opt_comment`: why the frame is as it is (a check or fuzz case that damaged it).
    pub comment: Option<String>,
}

/// Writes a pcapng file to `W`, a whole block at a time.
pub struct PcapngWriter<W: Write> {
    sink: W,
    interfaces: u32,
    block: Vec<u8>,
}

fn pad4(n: usize) -> usize {
    (n + 3) & !3
}

fn put_u16(v: &mut Vec<u8>, x: u16) {
    v.extend_from_slice(&x.to_le_bytes());
}

fn put_u32(v: &mut Vec<u8>, x: u32) {
    v.extend_from_slice(&x.to_le_bytes());
}

/// Appends one option (code, length, value padded to 4 bytes).
fn put_option(v: &mut Vec<u8>, code: u16, value: &[u8]) -> Result<(), WriteError> {
    let len = u16::try_from(value.len()).map_err(|_| WriteError::TooLong {
        what: "an option",
        len: value.len(),
    })?;
    put_u16(v, code);
    put_u16(v, len);
    v.extend_from_slice(value);
    v.resize(v.len() + pad4(value.len()) - value.len(), 0);
    Ok(())
}

impl<W: Write> PcapngWriter<W> {
    /// Starts a section on `sink`, naming `application` (`shb_userappl`).
    pub fn new(sink: W, application: &str) -> Result<Self, WriteError> {
        let mut w = PcapngWriter {
            sink,
            interfaces: 0,
            block: Vec::with_capacity(512),
        };
        let mut body = Vec::new();
        put_u32(&mut body, block::BYTE_ORDER_MAGIC);
        put_u16(&mut body, 1);
        put_u16(&mut body, 0);
        // Section length: not known (-1).
        body.extend_from_slice(&u64::MAX.to_le_bytes());
        put_option(&mut body, opt::SHB_USERAPPL, application.as_bytes())?;
        put_option(&mut body, opt::END, &[])?;
        w.emit(block::SHB, &body)?;
        Ok(w)
    }

    /// Describes one more link; returns its interface index.
    pub fn add_interface(&mut self, iface: &Interface) -> Result<u32, WriteError> {
        let mut body = Vec::new();
        put_u16(&mut body, iface.link_type);
        put_u16(&mut body, 0);
        // Snap length: 0, no limit.
        put_u32(&mut body, 0);
        put_option(&mut body, opt::IF_NAME, iface.name.as_bytes())?;
        put_option(&mut body, opt::IF_DESCRIPTION, iface.description.as_bytes())?;
        // 10^-6 s: microseconds.
        put_option(&mut body, opt::IF_TSRESOL, &[6])?;
        put_option(&mut body, opt::END, &[])?;
        self.emit(block::IDB, &body)?;
        self.interfaces += 1;
        Ok(self.interfaces - 1)
    }

    /// Writes one packet (an Enhanced Packet Block) and flushes it.
    pub fn write_packet(&mut self, meta: &PacketMeta, data: &[u8]) -> Result<(), WriteError> {
        if meta.interface >= self.interfaces {
            return Err(WriteError::NoInterface {
                interface: meta.interface,
                described: self.interfaces,
            });
        }
        let len = u32::try_from(data.len())
            .ok()
            .filter(|&l| l < 0x00FF_0000)
            .ok_or(WriteError::TooLong {
                what: "a packet",
                len: data.len(),
            })?;
        let mut body = std::mem::take(&mut self.block);
        body.clear();
        put_u32(&mut body, meta.interface);
        put_u32(&mut body, (meta.timestamp_us >> 32) as u32);
        put_u32(&mut body, meta.timestamp_us as u32);
        put_u32(&mut body, len);
        put_u32(&mut body, len);
        body.extend_from_slice(data);
        body.resize(body.len() + pad4(data.len()) - data.len(), 0);
        let mut res = Ok(());
        if meta.flags != 0 {
            res = put_option(&mut body, opt::EPB_FLAGS, &meta.flags.to_le_bytes());
        }
        if let (Ok(()), Some(c)) = (&res, &meta.comment) {
            res = put_option(&mut body, opt::COMMENT, c.as_bytes());
        }
        if res.is_ok() && (meta.flags != 0 || meta.comment.is_some()) {
            res = put_option(&mut body, opt::END, &[]);
        }
        let res = res.and_then(|()| self.emit(block::EPB, &body));
        self.block = body;
        res
    }

    /// The sink, after the last block.
    pub fn into_inner(self) -> W {
        self.sink
    }

    /// Frames `body` as a block of type `kind` and writes it whole, then flushes.
    fn emit(&mut self, kind: u32, body: &[u8]) -> Result<(), WriteError> {
        let total = body.len() + 12;
        let total32 = u32::try_from(total).map_err(|_| WriteError::TooLong {
            what: "a block",
            len: total,
        })?;
        let mut out = Vec::with_capacity(total);
        put_u32(&mut out, kind);
        put_u32(&mut out, total32);
        out.extend_from_slice(body);
        put_u32(&mut out, total32);
        self.sink.write_all(&out)?;
        self.sink.flush()?;
        Ok(())
    }
}
