//! Seed inputs for every fuzz target: the vectors' own ([`crate::vectors::corpus`]), then
//! those of the listener, the adapter protocols and the hand-written files (issue 37),
//! which come from the monitor's, the gate's and the loaders' rooms; this module sits
//! above them all so that `vectors/` need not reach up.

use crate::vectors::corpus::{self, Seed};
use crate::vectors::model::{parse_known, Body, FileMode};
use crate::vectors::VectorSet;

/// Every target's seeds: those of [`corpus::seeds`], then the listener's, the adapter
/// protocols' and the file loaders'.
pub fn seeds(set: &VectorSet, files: &[(String, String)]) -> Vec<Seed> {
    let mut out = corpus::seeds(set, files);
    listener_and_file_seeds(set, &mut out);
    out
}

/// Seeds for the listener's, the adapter protocols' and the hand-written files' targets
/// (issue 37): each vector file's frames as a bus stream (a frame every 6.4 ms, RTU and
/// ASCII apart) and as reads for the line search, the streams and sessions of their
/// unit tests, and the expectations, catalogues and descriptions the suite ships.
fn listener_and_file_seeds(set: &VectorSet, out: &mut Vec<Seed>) {
    use crate::monitor::fuzzing::{bus_streams, encode_stream, search_scripts};
    let mut add = |target: &'static str, name: String, bytes: Vec<u8>| {
        out.push(Seed {
            target,
            name,
            bytes,
        })
    };
    for file in &set.files {
        let mut by_mode: [Vec<Vec<u8>>; 2] = [Vec::new(), Vec::new()];
        for v in &file.vectors {
            let Body::Frame(fv) = &v.body else { continue };
            let Some(bytes) = parse_known(&fv.printed).ok() else {
                continue;
            };
            by_mode[usize::from(fv.mode == FileMode::Ascii)].push(bytes);
        }
        for (control, frames) in [(0u8, &by_mode[0]), (1, &by_mode[1])] {
            if frames.is_empty() {
                continue;
            }
            let mode = if control == 0 { "rtu" } else { "ascii" };
            let pieces: Vec<(u8, &[u8])> = frames.iter().map(|f| (20u8, &f[..])).collect();
            let stream = encode_stream(control, &pieces);
            let name = format!("{}.{mode}-stream", file.document);
            add("monitor_stream", name.clone(), stream.clone());
            add("tap_framer", name, stream);
            for (i, script) in search_scripts(frames).into_iter().enumerate() {
                add(
                    "line_search",
                    format!("{}.{mode}-search-{i}", file.document),
                    script,
                );
            }
        }
    }
    for (i, s) in bus_streams().into_iter().enumerate() {
        add("monitor_stream", format!("bus-{i}"), s.clone());
        add("tap_framer", format!("bus-{i}"), s);
    }
    for (i, s) in crate::gate::fuzzing::sessions().into_iter().enumerate() {
        add("adapter_protocol", format!("session-{i}"), s);
    }
    for (i, text) in crate::expect::fuzzing::FILES.iter().enumerate() {
        add(
            "expectations_file",
            format!("file-{i}.toml"),
            text.as_bytes().to_vec(),
        );
    }
    for (doc, text) in crate::requirements::Catalogue::builtin_texts() {
        add(
            "requirements_file",
            format!("{doc}.json"),
            text.as_bytes().to_vec(),
        );
    }
    for (model, text) in crate::model::DriveModel::builtin_files() {
        add(
            "model_file",
            format!("{model}.json"),
            text.as_bytes().to_vec(),
        );
    }
}
