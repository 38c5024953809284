//! Seed inputs for the fuzz targets, made from the golden vectors (the seeds of the
//! listener's, the adapters' and the file loaders' targets are added by
//! [`crate::seeds`], which sits above the rooms they come from).

use super::model::{parse_known, Body, FileMode};
use super::set::VectorSet;

/// One seed: the fuzz target it is for, a file name, and the bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Seed {
    /// Target name (as in `fuzz/Cargo.toml` and [`crate::oracle::TARGETS`]).
    pub target: &'static str,
    /// File name: the vector id and which bytes (`printed` or `corrected`).
    pub name: String,
    /// The input.
    pub bytes: Vec<u8>,
}

/// Control byte the deframer targets read first (chunk size 8).
const CHUNK_CONTROL: u8 = 7;

/// Seeds for every target from every vector: frames as printed and as corrected; the
/// deframers get each document's frames back to back; the loader gets the vector files.
pub fn seeds(set: &VectorSet, files: &[(String, String)]) -> Vec<Seed> {
    let mut out = Vec::new();
    for file in &set.files {
        let mut rtu_stream = vec![CHUNK_CONTROL];
        let mut mbap_stream = Vec::new();
        let mut ascii_stream = vec![CHUNK_CONTROL];
        // Every frame of the file, RTU on interface 0 and ASCII on 1, as a capture.
        let mut captured: Vec<(u32, Vec<u8>)> = Vec::new();
        for v in &file.vectors {
            let Body::Frame(fv) = &v.body else { continue };
            let versions = [
                ("printed", Some(&fv.printed)),
                ("corrected", fv.corrected.as_ref()),
            ];
            for (which, hex) in versions {
                let Some(bytes) = hex.and_then(|h| parse_known(h).ok()) else {
                    continue;
                };
                let name = format!("{}.{which}", v.id);
                // The drive target: a model/mode selector byte, then the frame.
                let model = crate::model::MODELS
                    .iter()
                    .position(|m| *m == file.document)
                    .unwrap_or(0) as u8;
                let mode_bit = if fv.mode == FileMode::Ascii { 0x80 } else { 0 };
                let mut drive = vec![model | mode_bit];
                drive.extend_from_slice(&bytes);
                out.push(Seed {
                    target: "drive",
                    name: name.clone(),
                    bytes: drive,
                });
                let mut stream = vec![CHUNK_CONTROL];
                stream.extend_from_slice(&bytes);
                match fv.mode {
                    FileMode::Rtu => {
                        captured.push((0, bytes.clone()));
                        rtu_stream.extend_from_slice(&bytes);
                        // What a Modbus TCP gateway makes of it: the PDU under an MBAP
                        // header, the node address as the unit id.
                        if bytes.len() >= 4 {
                            let mut mbap = [0u8; crate::codec::mbap::MAX_ADU];
                            let repr = crate::codec::mbap::MbapRepr {
                                transaction: out.len() as u16,
                                unit: bytes[0],
                                pdu: &bytes[1..bytes.len() - 2],
                            };
                            if let Ok(n) = repr.emit(&mut mbap) {
                                mbap_stream.extend_from_slice(&mbap[..n]);
                                out.push(Seed {
                                    target: "mbap_frame",
                                    name: name.clone(),
                                    bytes: mbap[..n].to_vec(),
                                });
                            }
                        }
                        out.push(Seed {
                            target: "rtu_frame",
                            name: name.clone(),
                            bytes: bytes.clone(),
                        });
                        out.push(Seed {
                            target: "rtu_deframer",
                            name: name.clone(),
                            bytes: stream,
                        });
                        let body = bytes[..bytes.len().saturating_sub(2)].to_vec();
                        out.push(Seed {
                            target: "crc_differential",
                            name,
                            bytes: body,
                        });
                    }
                    FileMode::Ascii => {
                        captured.push((1, bytes.clone()));
                        ascii_stream.extend_from_slice(&bytes);
                        out.push(Seed {
                            target: "ascii_frame",
                            name: name.clone(),
                            bytes: bytes.clone(),
                        });
                        out.push(Seed {
                            target: "ascii_deframer",
                            name,
                            bytes: stream,
                        });
                    }
                }
            }
        }
        // The document's frames back to back, one stream per target that reads streams.
        for (target, suffix, bytes) in [
            ("rtu_deframer", "all-rtu", rtu_stream),
            ("ascii_deframer", "all-ascii", ascii_stream),
            ("mbap_frame", "all-mbap", mbap_stream),
            ("capture_reader", "pcapng", capture_of(&captured)),
        ] {
            out.push(Seed {
                target,
                name: format!("{}.{suffix}", file.document),
                bytes,
            });
        }
    }
    for (model, text) in crate::model::DriveModel::builtin_files() {
        out.push(Seed {
            target: "model_lint",
            name: format!("{model}.json"),
            bytes: text.as_bytes().to_vec(),
        });
    }
    for (name, text) in files {
        out.push(Seed {
            target: "vector_loader",
            name: name.clone(),
            bytes: text.as_bytes().to_vec(),
        });
    }
    out
}

/// A pcapng file of `frames` (interface 0: RTU, 1: ASCII), alternately sent and
/// received, a millisecond apart.
fn capture_of(frames: &[(u32, Vec<u8>)]) -> Vec<u8> {
    use crate::capture::{self, Interface, PacketMeta, PcapngWriter};
    let write = || -> Result<Vec<u8>, capture::WriteError> {
        let mut w = PcapngWriter::new(Vec::new(), "vectors")?;
        for (link_type, description) in [
            (capture::LINKTYPE_USER0, "rtu"),
            (capture::LINKTYPE_USER1, "ascii"),
        ] {
            w.add_interface(&Interface {
                link_type,
                name: "vectors".into(),
                description: description.into(),
            })?;
        }
        for (i, (interface, bytes)) in frames.iter().enumerate() {
            let direction = if i % 2 == 0 {
                capture::Direction::Outbound
            } else {
                capture::Direction::Inbound
            };
            let meta = PacketMeta {
                interface: *interface,
                timestamp_us: 1_000 * i as u64,
                flags: direction.flag(),
                comment: None,
            };
            w.write_packet(&meta, bytes)?;
        }
        Ok(w.into_inner())
    };
    write().unwrap_or_default()
}
