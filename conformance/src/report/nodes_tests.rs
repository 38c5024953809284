//! The renderers on a run of several nodes, and a run of one node rendered exactly as
//! before runs of several nodes existed (golden files in `testdata/`, written by the
//! renderers of commit 0a61638; since then, additively, the requirement ids each check
//! verifies in JUnit and HTML and the HTML's requirements coverage section).

use super::diff::{Diff, DiffError};
use super::fixtures::{one_node, result, several_nodes, NODES};
use super::*;

/// The suite's version changes with every release; the golden files hold `VERSION`.
fn unversioned(s: &str) -> String {
    s.replace(env!("CARGO_PKG_VERSION"), "VERSION")
}

#[test]
fn a_run_of_one_node_renders_exactly_as_before() {
    let r = one_node();
    assert!(r.node_summaries().is_empty());
    assert_eq!(
        unversioned(&text(&r, false)),
        include_str!("testdata/one-node.txt")
    );
    assert_eq!(
        unversioned(&text(&r, true)),
        include_str!("testdata/one-node-verbose.txt")
    );
    assert_eq!(
        unversioned(&junit(&r)),
        include_str!("testdata/one-node.junit.xml")
    );
    assert_eq!(csv(&r), include_str!("testdata/one-node.csv"));
    assert_eq!(
        unversioned(&html(&r)),
        include_str!("testdata/one-node.html")
    );
}

/// `needle` is in `hay` (the failure shows where it was looked for).
#[track_caller]
fn has(hay: &str, needle: &str) {
    assert!(hay.contains(needle), "no {needle:?} in\n{hay}");
}

fn schema() -> jsonschema::Validator {
    let text = include_str!("../../../vectors/schema/report.schema.json");
    jsonschema::validator_for(&serde_json::from_str(text).unwrap()).unwrap()
}

fn schema_errors(v: &Value) -> Vec<String> {
    schema()
        .iter_errors(v)
        .map(|e| format!("{} at {}", e, e.instance_path))
        .collect()
}

#[test]
fn node_summaries_count_each_node_and_the_bus() {
    let r = several_nodes();
    let n = r.node_summaries();
    let nodes: Vec<Option<u8>> = n.iter().map(|(k, _)| *k).collect();
    assert_eq!(nodes, [Some(1), Some(2), Some(5), None]);
    let s = |i: usize| n[i].1;
    assert_eq!(
        (s(0).total, s(0).pass, s(0).observation, s(0).skip),
        (4, 2, 1, 1)
    );
    assert_eq!((s(1).total, s(1).pass, s(1).error), (4, 1, 3));
    assert_eq!((s(2).total, s(2).deviation), (4, 1));
    assert_eq!((s(3).total, s(3).pass, s(3).deviation), (3, 2, 1));
    // Every result is counted once.
    assert_eq!(
        n.iter().map(|(_, s)| s.total).sum::<usize>(),
        r.results.len()
    );
}

#[test]
fn text_has_a_line_and_a_section_per_node_and_one_for_the_bus() {
    let r = several_nodes();
    let t = text(&r, false);
    let summary = &t[..t.find("\n===").unwrap()];
    has(summary, "3 nodes on one bus: 01 02 05");
    has(summary, "node 01H: identification 0510H; 4 checks: 2 pass, 0 deviations, 1 observation, 1 skipped, 0 errors\n");
    has(summary, "node 02H: identification not read; 4 checks: 1 pass, 0 deviations, 0 observations, 0 skipped, 3 errors; stopped: no reply to 3 requests in a row\n");
    has(
        summary,
        "node 05H: identification 0510H, quirks: wrong-exception; 4 checks: 1 pass, 1 deviation,",
    );
    has(summary, "bus:      3 checks: 2 pass, 1 deviation,");
    // The one-node "identification" of the device line is per node here.
    assert!(!summary.contains(", identification 0510H"), "{t}");
    let at = |needle: &str| {
        t.find(needle)
            .unwrap_or_else(|| panic!("no {needle:?} in\n{t}"))
    };
    let (n1, n2, n5, bus, restore) = (
        at("\n=== node 01H: 4 checks"),
        at("\n=== node 02H: 4 checks: 1 pass, 0 deviations, 0 observations, 0 skipped, 3 errors; stopped: no reply to 3 requests in a row ==="),
        at("\n=== node 05H: 4 checks"),
        at("\n=== bus (broadcast and other-address checks, run once): 3 checks"),
        at("\nRESTORE"),
    );
    assert!(n1 < n2 && n2 < n5 && n5 < bus && bus < restore, "{t}");
    let node1 = &t[n1..n2];
    let node2 = &t[n2..n5];
    let node5 = &t[n5..bus];
    let bus_part = &t[bus..restore];
    // Deviations first within each section; a node without any has no such heading.
    assert!(!node1.contains("DEVIATIONS"), "{node1}");
    assert!(node1.find("OBSERVATIONS").unwrap() < node1.find("SKIPPED").unwrap());
    assert!(node5.find("DEVIATIONS (1)").unwrap() < node5.find("OBSERVATIONS (1)").unwrap());
    has(node5, "request  05 03 00 39");
    // The lost node's checks that never ran: one line.
    has(
        node2,
        "ERRORS (3)\n  2 checks not run: the device stopped answering",
    );
    has(bus_part, "DEVIATIONS (1)\n  [rtu.bus.other-address]");
    has(bus_part, "PASSED (2)");
    assert!(!bus_part.contains("rtu.map."), "{bus_part}");
    // Restore lines name their node.
    has(
        &t[restore..],
        "  node 02H 2502H NOT no reply to the write back",
    );
    let v = text(&r, true);
    has(&v, "  node 01H 2502H ok  read back 04D2");
    has(&v, "  node 05H 2502H =   read back 04D2");
}

#[test]
fn junit_has_a_suite_per_node_and_one_for_the_bus() {
    let r = several_nodes();
    let xml = junit(&r);
    let doc = roxmltree::Document::parse(&xml).unwrap();
    let root = doc.root_element();
    assert_eq!(root.attribute("tests"), Some("15"));
    assert_eq!(root.attribute("failures"), Some("2"));
    assert_eq!(root.attribute("errors"), Some("3"));
    let suites: Vec<roxmltree::Node> = root
        .children()
        .filter(|n| n.has_tag_name("testsuite"))
        .collect();
    let names: Vec<&str> = suites.iter().filter_map(|s| s.attribute("name")).collect();
    assert_eq!(
        names,
        ["f510.node-01", "f510.node-02", "f510.node-05", "f510.bus"]
    );
    for (suite, (node, s)) in suites.iter().zip(r.node_summaries()) {
        let attr = |k: &str| suite.attribute(k).unwrap().parse::<usize>().unwrap();
        assert_eq!(
            (
                attr("tests"),
                attr("failures"),
                attr("errors"),
                attr("skipped")
            ),
            (s.total, s.deviation, s.error, s.skip),
            "{node:?}"
        );
        let cases: Vec<&str> = suite
            .children()
            .filter(|n| n.has_tag_name("testcase"))
            .filter_map(|c| c.attribute("name"))
            .collect();
        assert_eq!(cases.len(), s.total);
        // Test cases keep the check id; the suite names the node.
        let ids: Vec<&str> = r
            .results
            .iter()
            .filter(|c| c.node == node)
            .map(|c| c.id.as_str())
            .collect();
        assert_eq!(cases, ids);
        let property = |k: &str| {
            suite
                .descendants()
                .find(|p| p.has_tag_name("property") && p.attribute("name") == Some(k))
                .and_then(|p| p.attribute("value"))
        };
        match node {
            Some(n) => assert_eq!(property("address"), Some(format!("{n:02X}").as_str())),
            None => assert_eq!(property("address"), Some("01 02 05")),
        }
        assert_eq!(
            property("stopped"),
            (node == Some(2)).then_some("no reply to 3 requests in a row")
        );
    }
}

#[test]
fn csv_has_a_node_column_for_several_nodes_only() {
    let out = csv(&several_nodes());
    let lines: Vec<&str> = out.split("\r\n").filter(|l| !l.is_empty()).collect();
    assert_eq!(lines[0], "node,id,mode,status,title,source,summary");
    assert_eq!(lines.len(), 16);
    assert!(
        lines[1].starts_with("01,rtu.map.group-0.first,rtu,PASS,"),
        "{}",
        lines[1]
    );
    assert!(
        lines[9].starts_with("05,rtu.map.group-0.first,rtu,PASS,"),
        "{}",
        lines[9]
    );
    assert!(
        lines[14].starts_with(",rtu.bus.other-address,rtu,DEVIATION,"),
        "{}",
        lines[14]
    );
    let nodes: Vec<&str> = lines[1..]
        .iter()
        .map(|l| l.split(',').next().unwrap())
        .collect();
    assert_eq!(nodes.iter().filter(|n| **n == "02").count(), 4);
    assert_eq!(nodes.iter().filter(|n| n.is_empty()).count(), 3);
    assert!(csv(&one_node()).starts_with("id,mode,status,"));
}

#[test]
fn json_of_several_nodes_reads_back_and_matches_the_schema() {
    let r = several_nodes();
    let v = r.to_json();
    assert_eq!(schema_errors(&v), Vec::<String>::new());
    assert_eq!(v["checks"][8]["node"], "05");
    assert!(
        v["checks"][12].get("node").is_none(),
        "a bus check has no node"
    );
    assert_eq!(v["restore"][1]["node"], "02");
    assert_eq!(
        v["device"]["nodes"][1]["stopped"],
        "no reply to 3 requests in a row"
    );
    let back = Report::from_json(&v).unwrap();
    assert_eq!(back.to_json(), v);
    assert_eq!(back.device.nodes, r.device.nodes);
    assert_eq!(back.node_summaries(), r.node_summaries());
    let keys = |r: &Report| r.results.iter().map(|c| c.key()).collect::<Vec<_>>();
    assert_eq!(keys(&back), keys(&r));
    // Re-rendered from the JSON, every format is the same.
    assert_eq!(text(&back, true), text(&r, true));
    assert_eq!(junit(&back), junit(&r));
    assert_eq!(csv(&back), csv(&r));
    assert_eq!(html(&back), html(&r));
    // A one-node report has no node anywhere, and matches too.
    let one = one_node().to_json();
    assert_eq!(schema_errors(&one), Vec::<String>::new());
    assert!(one["device"].get("nodes").is_none());
    assert!(one["checks"]
        .as_array()
        .unwrap()
        .iter()
        .all(|c| c.get("node").is_none()));
}

#[test]
fn the_schema_checks_the_node_fields() {
    let v = several_nodes().to_json();
    let broken = |f: &dyn Fn(&mut Value)| {
        let mut w = v.clone();
        f(&mut w);
        schema_errors(&w)
    };
    assert!(!broken(&|w| w["checks"][0]["node"] = json!("5")).is_empty());
    assert!(!broken(&|w| w["restore"][0]["node"] = json!(5)).is_empty());
    assert!(!broken(&|w| w["device"]["nodes"][0]["address"] = json!("1")).is_empty());
    assert!(!broken(&|w| w["device"]["nodes"][0]["colour"] = json!("red")).is_empty());
    assert!(!broken(&|w| w["device"]["nodes"] = json!([])).is_empty());
    assert!(!broken(&|w| {
        w["device"]["nodes"][2]
            .as_object_mut()
            .unwrap()
            .remove("stopped");
    })
    .is_empty());
}

#[test]
fn html_of_several_nodes_has_a_node_table_column_and_filter() {
    let r = several_nodes();
    let page = html(&r);
    assert!(page.contains("<table id=\"nodes\">"));
    for n in NODES {
        assert!(page.contains(&format!("<a href=\"#node={n:02X}\">node {n:02X}H</a>")));
        assert!(page.contains(&format!("<option value=\"{n:02X}\">{n:02X}H</option>")));
    }
    assert!(page.contains("<option value=\"bus\">bus</option>"));
    assert!(page.contains("STOPPED</span> no reply to 3 requests in a row"));
    let rows = page.matches("<tr class=").count() - r.node_summaries().len();
    assert_eq!(rows, r.results.len());
    assert_eq!(
        page.matches("data-mode=\"rtu\" data-node=\"05\">").count(),
        4
    );
    assert_eq!(
        page.matches("data-mode=\"rtu\" data-node=\"bus\">").count(),
        3
    );
    // The same deviation on two nodes: two blocks, two anchors.
    let mut two = several_nodes();
    two.results[1].status = Status::Deviation;
    let page2 = html(&two);
    assert!(page2.contains("id=\"f-rtu.map.group-0.past-end@1\""));
    assert!(page2.contains("id=\"f-rtu.map.group-0.past-end@5\""));
    assert!(page2.contains("<a href=\"#f-rtu.map.group-0.past-end@5\">"));
    // The restore journal names the node.
    assert!(page.contains("<table id=\"restore-t\"><thead><tr><th>node</th>"));
    assert!(page.contains("<tr><td class=\"id\">02H</td><td class=\"id\">2502H</td>"));
    assert!(!html(&one_node()).contains("data-node"));
    // The plots' tooltips name the node of a check.
    assert!(page.contains("rtu.map.group-0.past-end@5: DEVIATION"));
    assert!(page.contains("<title>rtu.map.group-0.past-end@2 (ERROR)"));
}

#[test]
fn diff_matches_checks_by_node() {
    let old = several_nodes();
    let mut new = several_nodes();
    // Node 01H's past-end now deviates like node 05H's; node 05H's bus sibling is fine.
    new.results[1].status = Status::Deviation;
    let d = Diff::new(&old, &new).unwrap();
    let ids: Vec<&str> = d.status.iter().map(|c| c.id.as_str()).collect();
    assert_eq!(ids, ["rtu.map.group-0.past-end@1"]);
    assert!(d.worse());
    assert!(d.only_old.is_empty() && d.only_new.is_empty());
    assert!(Diff::new(&old, &old).unwrap().is_empty());
    // A node in one run only: its checks are in that run only, keyed by node.
    let mut fewer = several_nodes();
    fewer.device.nodes.retain(|n| n.address != 5);
    fewer.results.retain(|c| c.node != Some(5));
    let d = Diff::new(&old, &fewer).unwrap();
    assert_eq!(d.only_old.len(), 4);
    assert!(
        d.only_old.iter().all(|(k, _)| k.ends_with("@5")),
        "{:?}",
        d.only_old
    );
}

#[test]
fn diff_of_one_node_against_several_needs_a_node() {
    let one = one_node();
    let several = several_nodes();
    let e = Diff::new(&one, &several).unwrap_err();
    assert!(matches!(
        e,
        DiffError::OneAndSeveralNodes {
            several: "new",
            one: 1,
            ..
        }
    ));
    assert!(e.to_string().contains("--node N"), "{e}");
    assert!(e.to_string().contains("01H 02H 05H"), "{e}");
    assert!(matches!(
        Diff::new(&several, &one),
        Err(DiffError::OneAndSeveralNodes { several: "old", .. })
    ));
    assert!(matches!(
        Diff::for_node(&one, &several, 9),
        Err(DiffError::NoSuchNode {
            node: 9,
            which: "new",
            ..
        })
    ));
    // The run of one node against node 05H of the bus: node 05H's checks and the bus
    // checks, keyed by id as in the run of one node.
    let single = Report {
        results: vec![
            result("rtu.map.group-0.first", Status::Pass, None),
            result("rtu.map.group-0.past-end", Status::Pass, None),
            result("rtu.timing.silence", Status::Observation, None),
            result("rtu.write.single", Status::Skip, None),
            result("rtu.bus.broadcast-write", Status::Pass, None),
            result("rtu.bus.other-address", Status::Pass, None),
            result("rtu.bus.preflight", Status::Pass, None),
        ],
        ..one_node()
    };
    let d = Diff::for_node(&single, &several, 5).unwrap();
    let ids: Vec<&str> = d.status.iter().map(|c| c.id.as_str()).collect();
    assert_eq!(ids, ["rtu.bus.other-address", "rtu.map.group-0.past-end"]);
    assert!(d.only_old.is_empty() && d.only_new.is_empty(), "{d:?}");
    assert!(
        d.new_label.starts_with(
            "node 05H (its checks and the bus checks) of a run of nodes 01H 02H 05H: f510"
        ),
        "{}",
        d.new_label
    );
    // Node 02H stopped: its checks that never ran are new in its section.
    let d = Diff::for_node(&single, &several, 2).unwrap();
    assert_eq!(d.only_new.len(), 2, "{:?}", d.only_new);
    // The section of a run of several nodes is a run of one node.
    let s = diff::node_section(&several, 2, "new").unwrap();
    assert!(s.device.nodes.is_empty());
    assert_eq!((s.device.address, s.device.identification), (2, None));
    assert_eq!(s.results.len(), 7);
    assert_eq!(s.restore.len(), 1);
    assert!(s.results.iter().all(|c| c.node.is_none()));
}
