//! The monitor's report in every form a user gets it: written by `monitor` itself, and read
//! back from its JSON by `conformance report` (text and HTML). The bus is a capture the
//! test writes, each frame at a time it chooses, so every figure (response times, the
//! capture's first and last packet) is the same on every run and on any host.
#![cfg(unix)]

mod common;
use common::rtu::{exception, read, values};
use common::{line, Run, Scratch};

use std::path::{Path, PathBuf};

use conformance::capture::write::{Interface, PacketMeta, PcapngWriter};
use conformance::capture::LINKTYPE_USER0;

/// 2026-11-27T10:00:00Z, the capture's first packet, in microseconds since the epoch.
const T0_US: u64 = 1_795_773_600_000_000;

/// A pcapng capture of an RTU bus at `path`: each frame at `T0_US` + its offset in ms.
fn capture(path: &Path, frames: &[(u64, Vec<u8>)]) {
    let mut w = PcapngWriter::new(std::fs::File::create(path).unwrap(), "test").unwrap();
    w.add_interface(&Interface {
        link_type: LINKTYPE_USER0,
        name: "tap".into(),
        description: "rtu 9600 8E1".into(),
    })
    .unwrap();
    for (ms, bytes) in frames {
        let meta = PacketMeta {
            timestamp_us: T0_US + ms * 1000,
            ..PacketMeta::default()
        };
        w.write_packet(&meta, bytes).unwrap();
    }
}

/// Two drives polled: 01 and 02 answer at once (11 ms after the request began, 2 ms after
/// it ended), except one reply of 02 that comes 60 ms late; the master asks 01 for 2530H,
/// past the F510's map, and 01 answers exception 02H as the manual says.
fn polled_bus(path: &Path) {
    capture(
        path,
        &[
            (0, read(1, 0x252F, 1)),
            (11, values(1, &[0x0510])),
            (100, read(2, 0x2520, 2)),
            (111, values(2, &[4, 0])),
            (200, read(1, 0x2530, 1)),
            (211, exception(1, 3, 2)),
            (300, read(2, 0x2521, 1)),
            (370, values(2, &[0])),
            (400, read(1, 0x252F, 1)),
            (411, values(1, &[0x0510])),
        ],
    );
}

/// `conformance ARGS`, which must not panic or fail to run: its exit code and stdout.
fn run(args: &[&str]) -> (i32, String) {
    let o = Run::new(args).run();
    let err = o.stderr.as_str();
    assert!(!err.contains("panicked"), "{args:?}: {err}");
    let code = o.code.unwrap_or(-1);
    assert!(code == 0 || code == 1, "{args:?} exited {code}: {err}");
    (code, o.stdout.clone())
}

/// `monitor --capture-in CAP -a 1,2 -b 9600 -P even` writing its report to `out` (the
/// format from its extension), and the report.
fn monitor(cap: &Path, out: &Path) -> String {
    run(&line(&[
        "monitor --model f510 --quiet -a 1,2 -b 9600 -P even --capture-in",
        cap.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]));
    std::fs::read_to_string(out).unwrap()
}

/// [`polled_bus`] captured in a fresh scratch folder `name` and heard by [`monitor`],
/// which writes its JSON report there: the folder, the capture and the report.
fn polled_and_heard(name: &str) -> (Scratch, PathBuf, PathBuf) {
    let d = Scratch::new(name);
    let (cap, json) = (d.join("bus.pcapng"), d.join("m.json"));
    polled_bus(&cap);
    monitor(&cap, &json);
    (d, cap, json)
}

/// The HTML's "Heard on the bus" section: from its heading to the next section's.
fn heard_section(html: &str) -> &str {
    let at = html
        .find("<h2 id=\"heard\">")
        .unwrap_or_else(|| panic!("no Heard on the bus section in {html}"));
    let rest = &html[at..];
    &rest[..rest[4..].find("<h2").map_or(rest.len(), |e| e + 4)]
}

/// Issue 33, item 4: `conformance report` of a monitor's JSON gives what the monitor's
/// own report gives under "heard:" (text) and "Heard on the bus" (HTML): the per-node
/// counts, the percentiles, the findings by kind, the histograms and the notices.
#[test]
fn a_monitor_report_read_back_keeps_what_was_heard() {
    let (d, cap, json) = polled_and_heard("readback");
    let own_text = monitor(&cap, &d.join("m.txt"));
    let own_html = monitor(&cap, &d.join("m.html"));

    let heard = |text: &str| -> Vec<String> {
        text.lines()
            .filter(|l| l.starts_with("heard:"))
            .map(str::to_string)
            .collect()
    };
    let (_, read_back) = run(&["report", json.to_str().unwrap()]);
    let own = heard(&own_text);
    assert!(
        own.iter().any(|l| l.contains("node 02: 2 requests"))
            && own.iter().any(|l| l.contains("p50")),
        "{own_text}"
    );
    assert_eq!(heard(&read_back), own, "{read_back}");

    let html = common::rendered(&json, &d.join("r.html"));
    let section = heard_section(&html);
    assert_eq!(section, heard_section(&own_html));
    // A histogram for each node that answered.
    common::assert_count(section, "<svg", 2);
}

/// `monitor --capture-in` of `frames` with `extra` arguments, its JSON report read.
fn monitor_json(name: &str, frames: &[(u64, Vec<u8>)], extra: &[&str]) -> serde_json::Value {
    let d = Scratch::new(name);
    let cap = d.join("bus.pcapng");
    capture(&cap, frames);
    let json = d.join("m.json");
    let mut args = vec![
        "monitor",
        "--model",
        "f510",
        "--quiet",
        "-b",
        "9600",
        "-P",
        "even",
        "--capture-in",
        cap.to_str().unwrap(),
        "-o",
        json.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    run(&args);
    serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap()
}

/// The text and HTML of `conformance report` of a saved report.
fn both(name: &str, v: &serde_json::Value) -> (String, String) {
    let d = Scratch::new(name);
    let json = d.join("r.json");
    std::fs::write(&json, v.to_string()).unwrap();
    let (_, text) = run(&["report", json.to_str().unwrap()]);
    let html = common::rendered(&json, &d.join("r.html"));
    (text, html)
}

/// Issue 33, item 9: a monitor's report carries nothing of `check`'s. Its run is the
/// capture's, from the first packet to the end of the last (not the time of the
/// analysis); it says how long a reply is waited for, not a timeout and retries it never
/// had; it has no restore journal (it never writes), and its page is titled as a bus
/// monitor's report.
#[test]
fn a_monitor_report_says_what_a_monitor_did() {
    let (_d, _, json) = polled_and_heard("fields");
    let v = common::json_file(&json);
    assert_eq!(v["started"], "2026-11-27T10:00:00.000Z");
    // The last reply's first byte at 411 ms, its 7 bytes at 9600 8E1 after it.
    let finished = v["finished"].as_str().unwrap();
    assert!(
        finished.starts_with("2026-11-27T10:00:00.41")
            || finished.starts_with("2026-11-27T10:00:00.42"),
        "{finished}"
    );
    assert_eq!(v["monitor"]["searched_s"], serde_json::Value::Null);
    let (text, html) = both("fields-r", &v);
    let run_line = text.lines().find(|l| l.starts_with("run:")).unwrap();
    assert!(run_line.contains("reply window 1000 ms"), "{run_line}");
    assert!(
        !run_line.contains("retries") && !run_line.contains("timeout"),
        "{run_line}"
    );
    common::assert_contains_all(
        &html,
        &[
            "<title>Bus monitor report: f510</title>",
            "<h1>Modbus bus monitor report: ",
        ],
    );
    common::assert_contains_none(&html, &["Restore journal", " retries"]);
    assert_eq!(
        conformance::report::unresolved_links(&html),
        Vec::<String>::new()
    );
}

/// Issue 33, item 12: a finding on the master's side shows its request and the drive's
/// reply, not the model's prediction of that reply as an "expected" frame beside the
/// same bytes "received"; the nodes are counted in words that agree ("1 node"); the
/// nodes of -a are named whether heard or not, and no empty line for checks of the
/// whole bus (a monitor has none).
#[test]
fn a_monitor_report_shows_why_the_master_deviates_and_names_its_nodes() {
    let v = monitor_json(
        "master",
        &[(0, read(1, 0x2530, 1)), (11, exception(1, 3, 2))],
        &["-a", "1"],
    );
    let id = "rtu.node01.master.register-not-in-map";
    let check = common::check_of(&v, id);
    let e = &check["exchanges"][0];
    assert_eq!(e["received"], "01 83 02 C0 F1", "{e:#}");
    assert_eq!(e["expected"], serde_json::Value::Null, "{e:#}");
    let (text, _) = both("master-r", &v);
    let block: Vec<&str> = text
        .lines()
        .skip_while(|l| !l.contains(id))
        .take_while(|l| l.starts_with("  [") && l.contains(id) || l.starts_with("      "))
        .collect();
    assert!(
        block
            .iter()
            .any(|l| l.starts_with("      received 01 83 02 C0 F1")),
        "{text}"
    );
    assert!(
        !block.iter().any(|l| l.starts_with("      expected ")),
        "{text}"
    );
    assert!(text.contains("1 node on one bus: 01"), "{text}");
    assert!(!text.contains("1 nodes"), "{text}");
    assert!(!text.lines().any(|l| l.starts_with("bus:")), "{text}");

    // Nothing heard at all, -a 1,2: both nodes named, neither heard.
    let quiet = monitor_json("quiet", &[], &["-a", "1,2"]);
    let (text, html) = both("quiet-r", &quiet);
    common::assert_contains_all(
        &text,
        &[
            "2 nodes on one bus: 01 02",
            "node 02H: nothing heard to or from it",
        ],
    );
    assert!(!text.lines().any(|l| l.starts_with("bus:")), "{text}");
    assert!(html.contains("01H, 02H"), "{html}");
    // The table of the nodes: a monitor reads no identification, and says which node
    // it never heard.
    let table = &html[html.find("<table id=\"nodes\">").unwrap()..];
    let table = &table[..table.find("</table>").unwrap()];
    common::assert_count(table, "nothing heard to or from it", 2);
    assert!(!table.contains(">not read<"), "{table}");
}

/// Issue 33, item 12: each node's histogram of response times has its axes, its unit
/// and the manual's limits drawn: the response time (10 ms) and the time beyond which a
/// reply is late (with the default allowance of 20 ms, 30 ms); node 02's late reply
/// lies beyond it.
#[test]
fn the_response_time_histogram_has_axes_units_and_the_manuals_limits() {
    let (d, _, json) = polled_and_heard("hist");
    let html = common::rendered(&json, &d.join("r.html"));
    let at = html
        .find("<svg id=\"hist-02\"")
        .unwrap_or_else(|| panic!("{html}"));
    let svg = &html[at..at + html[at..].find("</svg>").unwrap()];
    common::assert_count(svg, "class=\"axis\"", 2);
    common::assert_contains_all(svg, &["(ms)", ">replies</text>"]);
    assert!(
        svg.contains("class=\"limit\"") && svg.contains(">manual 10 ms</text>"),
        "{svg}"
    );
    assert!(
        svg.contains("class=\"limit late\"") && svg.contains(">late beyond 30 ms</text>"),
        "{svg}"
    );
    // The 60 ms reply: a bar beyond the late limit.
    common::assert_count(svg, "class=\"bar late\"", 1);
}
