//! Assertions on what a command wrote: every one of some texts in its output, or none of
//! them, with a failure that names the texts at fault and prints the whole output.

/// Asserts that `text` holds each of `wanted`; a failure names every one it lacks, then
/// prints the whole text.
#[track_caller]
pub fn assert_contains_all(text: &str, wanted: &[&str]) {
    let missing: Vec<&str> = wanted
        .iter()
        .copied()
        .filter(|w| !text.contains(w))
        .collect();
    assert!(missing.is_empty(), "missing {missing:?} in:\n{text}");
}

/// Asserts that `text` holds none of `unwanted`; a failure names every one it holds,
/// then prints the whole text.
#[track_caller]
pub fn assert_contains_none(text: &str, unwanted: &[&str]) {
    let found: Vec<&str> = unwanted
        .iter()
        .copied()
        .filter(|u| text.contains(u))
        .collect();
    assert!(found.is_empty(), "unexpected {found:?} in:\n{text}");
}

/// Asserts that `text` holds `needle` exactly `n` times; a failure says how many times it
/// does, then prints the whole text.
#[track_caller]
pub fn assert_count(text: &str, needle: &str, n: usize) {
    let found = text.matches(needle).count();
    assert_eq!(found, n, "{needle:?} {found} times, not {n}, in:\n{text}");
}
