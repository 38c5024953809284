//! The loaders of files people and other tools write: vector files, the hex on them, and
//! captures.

/// Vector-file loader, and the hex reader on the same text: never panics on any text; a
/// file that loads verifies (in the
/// built-in set, in the place of its document's file) and renders without panicking, and
/// exports. The export maps each file on its own, so the file is exported alone: the
/// built-in files' export is the same on every run and is not repeated.
pub fn vector_loader(data: &[u8]) {
    use crate::vectors::{export::export_json, render, verify_vector, VectorFile, VectorSet};
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    hex_text(text);
    thread_local! {
        // The built-in set, and whether a run that panicked left a file swapped in.
        static BUILTIN: std::cell::RefCell<(VectorSet, bool)> = std::cell::RefCell::new((
            VectorSet::builtin().expect("the built-in vectors must load"),
            false,
        ));
    }
    BUILTIN.with_borrow_mut(|(set, dirty)| {
        if *dirty {
            *set = VectorSet::builtin().expect("the built-in vectors must load");
        }
        let Ok(file) = VectorFile::from_json("fuzz.json", text, &set.flags) else {
            return;
        };
        *dirty = true;
        let slot = set.files.iter().position(|f| f.document == file.document);
        let (i, displaced) = match slot {
            Some(i) => (i, Some(std::mem::replace(&mut set.files[i], file))),
            None => {
                set.files.push(file);
                (set.files.len() - 1, None)
            }
        };
        for v in &set.files[i].vectors {
            let _ = verify_vector(set, v);
            let _ = render(v);
        }
        let file = match displaced {
            Some(d) => std::mem::replace(&mut set.files[i], d),
            None => set.files.pop().expect("the file pushed above"),
        };
        let builtin_files = std::mem::replace(&mut set.files, vec![file]);
        let _ = export_json(set);
        set.files = builtin_files;
        *dirty = false;
    });
}

/// The hex reader for text typed by a person (vector files, the command line), on any
/// text: never panics; what it reads, printed canonically, reads back the same; an error
/// names a character or token that is where its column says.
fn hex_text(text: &str) {
    use crate::codec::hex::{parse_hex, Hex, HexError};
    match parse_hex(text) {
        Ok(bytes) => assert_eq!(
            parse_hex(&Hex(&bytes).to_string()).as_deref(),
            Ok(&bytes[..]),
            "hex printed canonically reads back"
        ),
        Err(HexError::BadChar { found, column }) => assert!(
            text.get(column - 1..).is_some_and(|t| t.starts_with(found)),
            "a bad character where its column says"
        ),
        Err(HexError::OddDigits { token, column }) => {
            assert!(token.len() % 2 == 1);
            assert!(
                text.get(column - 1..)
                    .is_some_and(|t| t.starts_with(&token)),
                "an odd token where its column says"
            );
        }
    }
}

/// The capture reader (pcap and pcapng) on arbitrary bytes: it never panics; every
/// packet is a slice of the input; the first error ends the packets and names an offset
/// inside the file; and the packets read, written again by the pcapng writer, read back
/// the same (bytes, interfaces, link types, flags, comments, times to the microsecond).
/// Then the monitor judges the file as `monitor --capture-in` would, in RTU and in ASCII,
/// with its laws ([`crate::monitor::fuzzing::capture_replay`]).
pub fn capture_reader(data: &[u8]) {
    use crate::capture::{Interface, PacketMeta, PcapngWriter, Reader};
    let Ok(reader) = Reader::new(data) else {
        return;
    };
    let mut packets = Vec::new();
    let mut failed = false;
    for item in reader {
        assert!(!failed, "a packet after an error");
        match item {
            Ok(p) => {
                let start = p.data.as_ptr() as usize;
                let base = data.as_ptr() as usize;
                assert!(start >= base && start + p.data.len() <= base + data.len());
                // The writer takes packets under 16 MiB.
                if p.data.len() < 0x00FF_0000 {
                    packets.push(p);
                }
            }
            Err(e) => {
                let offset = e.offset();
                assert!(offset < data.len() as u64 || data.is_empty(), "{e}");
                failed = true;
            }
        }
    }
    let mut w = PcapngWriter::new(Vec::new(), "oracle").expect("a Vec takes every write");
    let mut links: Vec<(u32, u16)> = Vec::new();
    for p in &packets {
        if !links.contains(&(p.interface, p.link_type)) {
            links.push((p.interface, p.link_type));
            w.add_interface(&Interface {
                link_type: p.link_type,
                name: String::new(),
                description: String::new(),
            })
            .expect("an interface");
        }
    }
    for p in &packets {
        let interface = links
            .iter()
            .position(|l| *l == (p.interface, p.link_type))
            .expect("described above") as u32;
        let meta = PacketMeta {
            interface,
            timestamp_us: p.timestamp_ns.unwrap_or(0) / 1000,
            flags: p.flags.unwrap_or(0),
            comment: p.comment.map(str::to_string),
        };
        w.write_packet(&meta, p.data)
            .expect("a packet read is a packet written");
    }
    let again = w.into_inner();
    let back: Vec<_> = Reader::new(&again)
        .expect("the writer's header")
        .collect::<Result<_, _>>()
        .expect("the writer's file reads back");
    assert_eq!(back.len(), packets.len());
    for (a, b) in packets.iter().zip(&back) {
        assert_eq!(a.data, b.data);
        assert_eq!(a.link_type, b.link_type);
        assert_eq!(a.flags.filter(|f| *f != 0), b.flags);
        assert_eq!(a.comment, b.comment);
        assert_eq!(
            b.timestamp_ns,
            Some(a.timestamp_ns.unwrap_or(0) / 1000 * 1000)
        );
    }
    // What the reader takes, the monitor judges (`monitor --capture-in`).
    crate::monitor::fuzzing::capture_replay(data);
}
