//! The last test binary of `cargo test --workspace` (cargo runs a package's test binaries
//! in the order of their names, and this name sorts last; the workspace's libraries have
//! no doc tests after it): it prints which tests of this run were skipped for want of a
//! peer, and the one command that installs every peer.
//!
//! Each skip was recorded by `common::missing` under `target/tmp/skips/<cargo's pid>/`, so
//! only this run's skips are read (test binaries run by one `cargo test` share their
//! parent). Folders of runs whose cargo has ended are removed.

mod common;

use std::collections::BTreeMap;

/// The skips recorded under `dir`: test -> reason, and the reasons with their counts.
fn read_skips(dir: &std::path::Path) -> BTreeMap<String, String> {
    let mut skips = BTreeMap::new();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return skips;
    };
    for e in entries.flatten() {
        let text = std::fs::read_to_string(e.path()).unwrap_or_default();
        for line in text.lines() {
            if let Some((test, why)) = line.split_once('\t') {
                skips.insert(test.to_string(), why.to_string());
            }
        }
    }
    skips
}

/// The summary of `skips`, as printed at the end of the run.
fn summary(skips: &BTreeMap<String, String>) -> String {
    if skips.is_empty() {
        return "SKIPPED: none; every test of this run that uses a peer ran".into();
    }
    // The peer each skip names, for the count per peer.
    let mut per_need: BTreeMap<&str, usize> = BTreeMap::new();
    for why in skips.values() {
        // "needs mbpoll (Debian package mbpoll) [...]": the peer is what comes before " (".
        let need = why
            .strip_prefix("needs ")
            .map(|w| w.split(" (").next().unwrap_or(w))
            .unwrap_or(why.as_str());
        *per_need.entry(need).or_default() += 1;
    }
    let mut out = format!(
        "\n========================================================================\n\
         SKIPPED: {} of this run left out what needs a peer ({})\n",
        match skips.len() {
            1 => "1 test".to_string(),
            n => format!("{n} tests"),
        },
        per_need
            .iter()
            .map(|(n, c)| format!("{n}: {c}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    for (test, why) in skips {
        out.push_str(&format!("  {test}: {why}\n"));
    }
    out.push_str(&format!(
        "Install every peer with `{}` (Debian packages, a Python venv under target/peers, \
         npm ci), then run `cargo test --workspace` again.\n\
         ========================================================================",
        common::INSTALL
    ));
    out
}

/// Removes the skip folders of `cargo test` runs that have ended.
fn remove_stale(root: &std::path::Path, current: u32) {
    let Ok(entries) = std::fs::read_dir(root) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let alive = name.parse::<u32>().is_ok_and(|pid| {
            pid == current || std::path::Path::new(&format!("/proc/{pid}")).exists()
        });
        if !alive {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

#[test]
fn the_skipped_tests_of_this_run_and_how_to_run_them() {
    let parent = std::os::unix::process::parent_id();
    let dir = common::skips_dir_of(parent);
    let skips = read_skips(&dir);
    common::note(&summary(&skips));
    if let Some(root) = dir.parent() {
        remove_stale(root, parent);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_recorded_skip_is_read_back_and_counted_per_peer() {
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("skips-selftest-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(
        dir.join("1.tsv"),
        "interop::mbpoll_rtu_f510\tneeds mbpoll (Debian package mbpoll)\n\
         gate::pymodbus\tneeds pymodbus==3.16.1 and pyserial==3.5 (PyPI)\n\
         c_listing::c\tneeds a C compiler ($CC, else cc; Debian package gcc)\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("2.tsv"),
        "interop::mbpoll_ascii_f510\tneeds mbpoll (Debian package mbpoll) [cannot run mbpoll]\n",
    )
    .unwrap();
    let skips = read_skips(&dir);
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(skips.len(), 4);
    let text = summary(&skips);
    common::assert_contains_all(
        &text,
        &[
            "SKIPPED: 4 tests",
            "a C compiler: 1",
            "(a C compiler: 1, mbpoll: 2, pymodbus==3.16.1 and pyserial==3.5: 1)",
            "  interop::mbpoll_ascii_f510: needs mbpoll",
        ],
    );
    assert!(text.contains(common::INSTALL), "{text}");
    assert_eq!(
        summary(&BTreeMap::new()),
        "SKIPPED: none; every test of this run that uses a peer ran"
    );
}
