//! The renderers on a run of several nodes, and a run of one node rendered exactly as
//! before runs of several nodes existed (golden files in `testdata/`, written by the
//! renderers of commit 0a61638).

use super::fixtures::{one_node, several_nodes};
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
    let _ = several_nodes();
}

#[test]
fn show_several() {
    println!("{}", text(&several_nodes(), false));
}
