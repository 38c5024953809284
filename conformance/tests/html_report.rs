//! The reports people read: `check --format html|csv`, `report FILE.json` and `diff`,
//! on a clean run and a run with a quirk of the simulated F510; the HTML pages loaded in
//! headless Chromium (the DOM it dumps, its console, a screenshot).

mod common;
use common::{words, Ran, Run, Scratch};

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde_json::Value;

fn conformance(args: &[&str]) -> Ran {
    let o = Run::new(args).run();
    let stderr = o.stderr.as_str();
    assert!(!stderr.contains("panicked"), "{stderr}");
    o
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn chromium() -> Option<&'static str> {
    common::need(common::Peer::Chromium)
        .then(common::chromium)
        .flatten()
}

/// Headless Chromium on `page`: the DOM after the page's script ran, and the browser's
/// log (console messages are logged as `:CONSOLE`).
fn browse(chromium: &str, page: &Path, extra: &[&str]) -> (String, String) {
    let profile = page.with_extension("profile");
    let o = Run::program("timeout", ["120", chromium])
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--enable-logging=stderr",
            "--v=0",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(extra)
        .arg(format!("file://{}", page.display()))
        .run();
    assert_eq!(o.code, Some(0), "chromium failed on {}", page.display());
    (o.stdout, o.stderr)
}

fn no_console_errors(log: &str, page: &Path) {
    let bad: Vec<&str> = log
        .lines()
        .filter(|l| l.contains(":CONSOLE") || l.contains("Uncaught"))
        .collect();
    assert!(bad.is_empty(), "{}: console: {bad:#?}", page.display());
}

fn ids(v: &Value) -> Vec<String> {
    v["checks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["id"].as_str().unwrap().to_string())
        .collect()
}

/// A clean and a quirky RTU run of the simulated F510 as JSON.
fn runs(d: &Path) -> [(PathBuf, Value, Option<i32>); 2] {
    let limit = Duration::from_secs(240);
    let clean_dir = d.join("clean");
    let quirk_dir = d.join("quirk");
    std::fs::create_dir_all(&clean_dir).unwrap();
    std::fs::create_dir_all(&quirk_dir).unwrap();
    // One after the other: the simulator is paced at the line's character time, and two
    // at once on a busy host add timing deviations to the clean run.
    let (clean_code, clean) =
        common::check_device(&clean_dir, &["--sim", "f510", "--mode", "rtu"], limit);
    let (quirk_code, quirk) = common::check_device(
        &quirk_dir,
        &words("--sim f510 --mode rtu --quirk wrong-exception"),
        limit,
    );
    [
        (clean_dir.join("check.json"), clean, clean_code),
        (quirk_dir.join("check.json"), quirk, quirk_code),
    ]
}

#[test]
fn html_csv_and_diff_of_a_clean_and_a_quirky_run() {
    let d = Scratch::kept("runs");
    let [(clean_json, clean, clean_code), (quirk_json, quirk, quirk_code)] = runs(&d);
    // The clean simulator has no deviations of its own; on a loaded host a timing check
    // may still find one, so the test asserts what the quirk adds.
    let deviating = |v: &Value| common::ids_with_status(v, "deviation");
    let (clean_devs, quirk_devs) = (deviating(&clean), deviating(&quirk));
    let added: Vec<&String> = quirk_devs
        .iter()
        .filter(|id| !clean_devs.contains(id))
        .collect();
    // Exit 1; or 2 where only this host stalled sending a request (a busy machine: an
    // ERROR that judges nothing), never for anything else.
    let stalls_only = |v: &Value| {
        v["checks"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|c| c["status"] == "error")
            .all(|c| {
                c["summary"]
                    .as_str()
                    .is_some_and(|s| s.contains("could not send the request"))
            })
    };
    assert!(
        clean_code == Some(0)
            || !clean_devs.is_empty()
            || (clean_code == Some(2) && stalls_only(&clean)),
        "{clean_code:?}"
    );
    assert!(
        quirk_code == Some(1) || (quirk_code == Some(2) && stalls_only(&quirk)),
        "{quirk_code:?}"
    );
    assert!(added.len() >= 30, "{added:?}");
    assert!(quirk_devs.contains(&"rtu.map.group-0.past-end".to_string()));
    assert!(clean["options"]["response_time_ms"].as_f64().unwrap() >= 10.0);

    // `report` renders the saved JSON in every format; its JSON is the JSON it read.
    let again = conformance(&["report", path(&clean_json), "--format", "json"]);
    assert_eq!(again.code, Some(0));
    let again: Value = serde_json::from_slice(&again.bytes).unwrap();
    assert_eq!(again["checks"], clean["checks"]);
    assert_eq!(again["summary"], clean["summary"]);
    let text = conformance(&["report", path(&quirk_json), "--format", "text"]);
    assert!(text.stdout.contains("rtu.map.group-0.past-end"));
    let junit = conformance(&["report", path(&quirk_json), "--format", "junit"]);
    roxmltree::Document::parse(&junit.stdout).unwrap();

    // CSV: a header and one row per check.
    let csv = conformance(&["report", path(&quirk_json), "--format", "csv"]);
    assert_eq!(csv.code, Some(0));
    let csv = csv.stdout;
    assert!(csv.starts_with("id,mode,status,title,source,summary\r\n"));
    for id in ids(&quirk) {
        assert!(csv.contains(&format!("\r\n{id},")), "{id} not in the CSV");
    }
    let deviations = csv.matches(",rtu,DEVIATION,").count();
    assert_eq!(
        deviations as u64,
        quirk["summary"]["deviation"].as_u64().unwrap()
    );

    // diff: the quirk made things worse (exit 1), new deviations first; the way back is
    // better (exit 0 unless the host's timing moved beyond noise); a run against itself
    // shows nothing.
    let worse = conformance(&["diff", path(&clean_json), path(&quirk_json)]);
    assert_eq!(worse.code, Some(1));
    let worse_text = worse.stdout.as_str();
    assert!(worse_text.contains("WORSE"), "{worse_text}");
    let first_change = worse_text
        .lines()
        .find(|l| l.trim_start().starts_with("worse ") || l.trim_start().starts_with("better "))
        .unwrap();
    assert!(first_change.contains("PASS -> DEVIATION"), "{first_change}");
    let dj = conformance(&[
        "diff",
        path(&clean_json),
        path(&quirk_json),
        "--format",
        "json",
    ]);
    let dj: Value = serde_json::from_slice(&dj.bytes).unwrap();
    let worse_ids: Vec<&str> = dj["status_changes"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["worse"] == true)
        .map(|c| c["id"].as_str().unwrap())
        .collect();
    for id in &added {
        assert!(worse_ids.contains(&id.as_str()), "{id} not a worse change");
    }
    let same = conformance(&["diff", path(&quirk_json), path(&quirk_json)]);
    assert_eq!(same.code, Some(0));
    assert!(same.stdout.contains("No differences."));
    let diff_html = d.join("diff.html");
    let dh = conformance(&[
        "diff",
        path(&clean_json),
        path(&quirk_json),
        "--format",
        "html",
        "-o",
        path(&diff_html),
    ]);
    assert_eq!(dh.code, Some(1));

    // A report whose strings came from a hostile device or file: escaped.
    let mut hostile = quirk.clone();
    hostile["checks"][0]["summary"] = "<script>alert('x')</script>".into();
    hostile["device"]["model"] = "<b onmouseover=alert(1)>f510</b>".into();
    let hostile_json = d.join("hostile.json");
    std::fs::write(&hostile_json, serde_json::to_string(&hostile).unwrap()).unwrap();

    let mut pages = Vec::new();
    for (name, json) in [
        ("clean", &clean_json),
        ("quirk", &quirk_json),
        ("hostile", &hostile_json),
    ] {
        let page = d.join(format!("{name}.html"));
        let o = conformance(&["report", path(json), "--format", "html", "-o", path(&page)]);
        assert_eq!(o.code, Some(0), "{}", o.stderr);
        pages.push((name, page));
    }
    let hostile_page = std::fs::read_to_string(&pages[2].1).unwrap();
    assert!(!hostile_page.contains("<script>alert"));
    assert!(hostile_page.contains("&lt;script&gt;alert(&#39;x&#39;)&lt;/script&gt;"));
    assert!(!hostile_page.contains("<b onmouseover"));

    let Some(chromium) = chromium() else {
        return;
    };
    for ((name, page), report) in pages.iter().zip([&clean, &quirk, &hostile]) {
        let (dom, log) = browse(chromium, page, &["--dump-dom"]);
        no_console_errors(&log, page);
        // Every check is in the table, and the filter script ran and counted them all.
        for id in ids(report) {
            assert!(
                dom.contains(&format!("data-id=\"{id}\"")),
                "{name}: {id} missing from the DOM"
            );
        }
        let total = report["summary"]["total"].as_u64().unwrap();
        assert!(
            dom.contains(&format!("<span id=\"shown\">{total}</span>")),
            "{name}: filter script"
        );
        // The plots.
        for plot in ["plot-latency", "plot-timeline", "plot-map"] {
            assert!(
                dom.contains(&format!("<svg id=\"{plot}\"")),
                "{name}: {plot}"
            );
        }
        assert!(dom.contains("<rect class=\"bar"), "{name}: histogram bars");
        assert!(
            dom.contains("<circle class=\"dot\""),
            "{name}: timeline dots"
        );
        assert!(
            dom.contains("<rect class=\"cell pass\""),
            "{name}: map cells"
        );
        let deviations = report["summary"]["deviation"].as_u64().unwrap() as usize;
        assert_eq!(
            dom.matches("<article class=\"finding deviation\"").count(),
            deviations,
            "{name}: one block per deviation"
        );
        let errors = report["summary"]["error"].as_u64().unwrap();
        if deviations == 0 && errors > 0 {
            // A run a busy host made stall (checked above: stalls only).
            assert!(
                dom.contains("check could not tell") || dom.contains("checks could not tell"),
                "{name}"
            );
        } else if deviations == 0 {
            assert!(dom.contains("No deviations from the manual"), "{name}");
        } else {
            assert!(dom.contains("from the manual</div>"), "{name}");
        }
        if *name != "clean" {
            // The differing bytes of the past-end check: code 03 where 02 was expected.
            assert!(dom.contains("01 83 <span class=\"d\">03</span>"), "{name}");
            assert!(dom.contains("01 83 <span class=\"d\">02</span>"), "{name}");
            assert!(dom.contains("<rect class=\"cell deviation\""), "{name}");
            assert!(
                dom.contains("with quirks: <b>wrong-exception</b>"),
                "{name}"
            );
        }
        if *name == "hostile" {
            // The script in a summary is text, not an element.
            assert!(dom.contains("&lt;script&gt;alert('x')&lt;/script&gt;"));
            assert!(!dom.contains("onmouseover=\"alert"));
        }
        let shot = page.with_extension("png");
        let shot_arg = format!("--screenshot={}", shot.display());
        let (_, log) = browse(chromium, page, &[&shot_arg, "--window-size=1280,2000"]);
        no_console_errors(&log, page);
        let png = std::fs::read(&shot).unwrap();
        assert!(
            png.starts_with(b"\x89PNG") && png.len() > 20_000,
            "{}",
            shot.display()
        );
        common::note(&format!("screenshot: {}", shot.display()));
    }
    // The filter: a link preselects it; the rows it hides are hidden.
    let quirk_page = &pages[1].1;
    let filtered = PathBuf::from(format!(
        "{}#status=deviation&mode=rtu&id=past-end",
        quirk_page.display()
    ));
    let (dom, log) = browse(chromium, &filtered, &["--dump-dom"]);
    no_console_errors(&log, quirk_page);
    let past_end_deviations = quirk["checks"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["status"] == "deviation" && c["id"].as_str().unwrap().contains("past-end"))
        .count();
    assert!(past_end_deviations > 0);
    assert!(
        dom.contains(&format!("<span id=\"shown\">{past_end_deviations}</span>")),
        "filtered count"
    );
    let rows = dom.matches("<tr class=").count();
    let hidden = dom.matches("style=\"display: none;\"").count();
    assert_eq!(rows - hidden, past_end_deviations);
    // Printable: Chromium prints it to PDF.
    let pdf = quirk_page.with_extension("pdf");
    let (_, log) = browse(
        chromium,
        quirk_page,
        &[
            &format!("--print-to-pdf={}", pdf.display()),
            "--no-pdf-header-footer",
        ],
    );
    no_console_errors(&log, quirk_page);
    assert!(std::fs::read(&pdf).unwrap().starts_with(b"%PDF"));

    let (dom, log) = browse(chromium, &diff_html, &["--dump-dom"]);
    no_console_errors(&log, &diff_html);
    assert!(dom.contains("Something got worse"));
    assert!(dom.contains("rtu.map.group-0.past-end"));
}

#[test]
fn check_writes_html_and_csv_directly() {
    let d = Scratch::new("direct");
    for (format, marker) in [
        ("html", "<svg id=\"plot-map\""),
        ("csv", "\r\nrtu.identification,rtu,"),
    ] {
        let out = d.join(format!("report.{format}"));
        let o = conformance(&[
            "check",
            "--sim",
            "f510",
            "--mode",
            "rtu",
            "--only",
            "identification",
            "--only",
            "*map.group-0.*",
            "--quiet",
            "--format",
            format,
            "-o",
            path(&out),
        ]);
        assert_eq!(o.code, Some(0), "{}", o.stderr);
        let text = std::fs::read_to_string(&out).unwrap();
        assert!(text.contains(marker), "{format}: {marker} missing");
    }
}

#[test]
fn a_file_that_is_not_a_report_is_refused_by_name() {
    let d = Scratch::new("bad");
    let cases = [
        ("not-json.json", "{ this is not json", "not JSON"),
        ("other.json", "{\"schema\": \"something/else\"}", "not a conformance report"),
        (
            "broken.json",
            "{\"schema\": \"teco-modbus-conformance/report\", \"schema_version\": 1, \"kind\": \"drive\", \"device\": null, \"options\": {}}",
            ".options.modes: missing",
        ),
    ];
    for (file, contents, problem) in cases {
        let p = d.join(file);
        std::fs::write(&p, contents).unwrap();
        for args in [
            vec!["report", path(&p), "--format", "html"],
            vec!["diff", path(&p), path(&p)],
        ] {
            let o = conformance(&args);
            assert_eq!(o.code, Some(2), "{args:?}");
            let err = o.stderr.as_str();
            assert!(
                err.contains(file) && err.contains(problem),
                "{args:?}: {err}"
            );
        }
    }
    let missing = d.join("missing.json");
    let o = conformance(&["diff", path(&missing), path(&missing)]);
    assert_eq!(o.code, Some(2));
    assert!(o.stderr.contains("cannot read"));
}

/// A run of several nodes as `check -a 1,5` writes it, made from a real run of one node:
/// its checks once for node 01H and once for node 05H (which stopped answering after its
/// first check), the preflight as a check of the whole bus, a restore record per node.
fn several_nodes_json(one: &Value) -> Value {
    let mut v = one.clone();
    let checks = one["checks"].as_array().unwrap();
    let (bus, per_node): (Vec<&Value>, Vec<&Value>) = checks
        .iter()
        .partition(|c| c["id"].as_str().unwrap().ends_with("preflight"));
    let mut out = Vec::new();
    for node in ["01", "05"] {
        for (i, c) in per_node.iter().enumerate() {
            let mut c = (*c).clone();
            c["node"] = node.into();
            if node == "05" && i > 0 {
                c["status"] = "error".into();
                c["summary"] = "not run: the device stopped answering".into();
                c["findings"] = serde_json::json!([]);
            }
            out.push(c);
        }
    }
    out.extend(bus.into_iter().cloned());
    v["checks"] = Value::Array(out);
    v["restore"] = serde_json::json!([
        { "node": "01", "register": "2502", "original": "04D2", "restored": true, "changed": true, "detail": "read back 04D2" },
        { "node": "05", "register": "2502", "original": "04D2", "restored": false, "changed": true, "detail": "no reply to the write back" }
    ]);
    v["device"]["nodes"] = serde_json::json!([
        { "address": "01", "identification": one["device"]["identification"], "stopped": null, "quirks": [] },
        { "address": "05", "identification": null, "stopped": "no reply to 3 requests in a row", "quirks": ["wrong-exception"] }
    ]);
    v
}

#[test]
fn a_report_of_several_nodes_renders_per_node_and_diffs_by_node() {
    let args = "--sim f510 --mode rtu --only *map.group-0.* --quirk wrong-exception";
    let (d, code, one) = common::check_in("nodes", args, Duration::from_secs(120));
    assert_eq!(code, Some(1));
    let one_json = d.join("check.json");
    let bus = several_nodes_json(&one);
    let schema = jsonschema::validator_for(
        &serde_json::from_str(include_str!("../../vectors/schema/report.schema.json")).unwrap(),
    )
    .unwrap();
    assert!(
        schema.is_valid(&bus),
        "the report of several nodes does not match its schema"
    );
    let bus_json = d.join("bus.json");
    std::fs::write(&bus_json, serde_json::to_string_pretty(&bus).unwrap()).unwrap();
    let per_node = one["checks"].as_array().unwrap().len() - 1;

    // JSON back as it was (nodes and all); text, JUnit and CSV per node.
    let again = conformance(&["report", path(&bus_json), "--format", "json"]);
    let again: Value = serde_json::from_slice(&again.bytes).unwrap();
    assert_eq!(again["checks"], bus["checks"]);
    assert_eq!(again["device"]["nodes"], bus["device"]["nodes"]);
    assert_eq!(again["restore"], bus["restore"]);
    let text = conformance(&["report", path(&bus_json), "--format", "text"]);
    let text = text.stdout.as_str();
    let n1 = text.find("\n=== node 01H: ").expect(text);
    let n5 = text.find("\n=== node 05H: ").expect(text);
    let b = text.find("\n=== bus (").expect(text);
    assert!(n1 < n5 && n5 < b, "{text}");
    assert!(
        text[n1..n5].contains("[rtu.map.group-0.past-end]"),
        "{text}"
    );
    common::assert_contains_all(
        text,
        &[
            "stopped: no reply to 3 requests in a row",
            "  node 05H 2502H NOT no reply to the write back",
        ],
    );
    let junit = conformance(&["report", path(&bus_json), "--format", "junit"]);
    let junit = junit.stdout.as_str();
    let doc = roxmltree::Document::parse(junit).unwrap();
    let suites: Vec<(String, String)> = doc
        .descendants()
        .filter(|n| n.has_tag_name("testsuite"))
        .map(|s| {
            (
                s.attribute("name").unwrap().to_string(),
                s.attribute("tests").unwrap().to_string(),
            )
        })
        .collect();
    assert_eq!(
        suites,
        [
            ("f510.node-01".to_string(), per_node.to_string()),
            ("f510.node-05".to_string(), per_node.to_string()),
            ("f510.bus".to_string(), "1".to_string()),
        ]
    );
    let csv = conformance(&["report", path(&bus_json), "--format", "csv"]);
    let csv = csv.stdout;
    assert!(csv.starts_with("node,id,mode,status,title,source,summary\r\n"));
    common::assert_contains_all(
        &csv,
        &[
            "\r\n05,rtu.map.group-0.past-end,rtu,ERROR,",
            "\r\n,rtu.preflight,rtu,PASS,",
        ],
    );

    // diff: a run of one node against the bus needs --node; node 01H's section is the
    // run of one node again; node 05H's lost checks got worse.
    let refused = conformance(&["diff", path(&one_json), path(&bus_json)]);
    assert_eq!(refused.code, Some(2));
    assert!(refused.stderr.contains("give --node N"));
    let same = conformance(&["diff", path(&one_json), path(&bus_json), "--node", "1"]);
    let same_text = same.stdout.as_str();
    assert_eq!(same.code, Some(0), "{same_text}");
    assert!(same_text.contains("No differences."), "{same_text}");
    let lost = conformance(&["diff", path(&one_json), path(&bus_json), "--node", "05H"]);
    let lost_text = lost.stdout.as_str();
    assert_eq!(lost.code, Some(1), "{lost_text}");
    assert!(
        lost_text.contains("new: node 05H (its checks and the bus checks)"),
        "{lost_text}"
    );
    let both = conformance(&["diff", path(&bus_json), path(&bus_json), "--format", "json"]);
    assert_eq!(both.code, Some(0));

    // HTML: the node table, and the filter by node (a link preselects it).
    let page = d.join("bus.html");
    let o = conformance(&[
        "report",
        path(&bus_json),
        "--format",
        "html",
        "-o",
        path(&page),
    ]);
    assert_eq!(o.code, Some(0));
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(html.contains("<table id=\"nodes\">"));
    let Some(chromium) = chromium() else {
        return;
    };
    let linked = format!("{}#node=05&status=error", page.display());
    let (dom, log) = browse(chromium, Path::new(&linked), &["--dump-dom"]);
    no_console_errors(&log, &page);
    assert!(
        dom.contains(&format!("<span id=\"shown\">{}</span>", per_node - 1)),
        "the node filter did not run"
    );
    let (_, log) = browse(
        chromium,
        &page,
        &[
            "--window-size=1300,2000",
            &format!("--screenshot={}", d.join("bus.png").display()),
        ],
    );
    no_console_errors(&log, &page);
    assert!(std::fs::metadata(d.join("bus.png")).unwrap().len() > 10_000);
}

/// A run with an ERROR and a deviation (issue 33): the HTML puts the ERROR first, since
/// it is what makes the exit code 2, and its header gives the exit code with its reason.
#[test]
fn html_puts_errors_first_and_says_why_the_exit_code_is_what_it_is() {
    let (d, code, _) = common::check_in(
        "errors-first",
        "--sim f510 --mode rtu --quirk wrong-exception \
        --only rtu.map.group-0.past-end --only rtu.map.command.first --inject-host-stall \
        rtu.map.command.first:3",
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(2));
    let page = common::rendered(&d.join("check.json"), &d.join("check.html"));
    let error = page
        .find("<article class=\"finding error\" id=\"f-rtu.map.command.first\"")
        .expect("the ERROR's card");
    let deviation = page
        .find("<article class=\"finding deviation\" id=\"f-rtu.map.group-0.past-end\"")
        .expect("the deviation's card");
    assert!(error < deviation, "the ERROR comes after the deviation");
    assert!(
        page.contains("<h2 id=\"deviations\">Errors (1) and deviations (1)</h2>"),
        "{}",
        &page[page.find("id=\"deviations\"").unwrap_or(0)..][..80]
    );
    assert!(
        page.contains(
            "exit code 2: 1 check ended in ERROR (nothing could be judged from it)</span>"
        ),
        "{}",
        &page[page.find("exit code").unwrap()..][..120]
    );
}
