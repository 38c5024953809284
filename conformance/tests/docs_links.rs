//! The documentation's links, checked: every relative link and `#anchor` in the
//! repository's Markdown files resolves (GitHub's heading slugs), and every page of the
//! guide is in its summary. (The examples and the options of the `conformance` lines are
//! checked by tests/docs.rs.)

mod markdown;

use std::collections::{BTreeSet, HashMap};
use std::path::Path;

use markdown::{markdown_files, rel, repo, split};

/// A line with its inline code spans blanked out (links inside code are not links).
fn without_code_spans(line: &str) -> String {
    let mut out = String::with_capacity(line.len());
    let mut in_code = false;
    for c in line.chars() {
        if c == '`' {
            in_code = !in_code;
            out.push(' ');
        } else {
            out.push(if in_code { ' ' } else { c });
        }
    }
    out
}

/// The destinations of the inline links and images of a line, and of a reference
/// definition (`[name]: dest`).
fn links_of(line: &str) -> Vec<String> {
    let line = without_code_spans(line);
    let mut out = Vec::new();
    let mut rest = line.as_str();
    while let Some(at) = rest.find("](") {
        let after = &rest[at + 2..];
        let mut depth = 0;
        let mut end = after.len();
        for (i, c) in after.char_indices() {
            match c {
                '(' => depth += 1,
                ')' if depth == 0 => {
                    end = i;
                    break;
                }
                ')' => depth -= 1,
                _ => {}
            }
        }
        let dest = after[..end].trim();
        let dest = dest.split_once(" \"").map(|(d, _)| d).unwrap_or(dest);
        out.push(dest.trim_matches(['<', '>']).to_string());
        rest = &after[end.min(after.len())..];
    }
    let t = line.trim_start();
    if t.starts_with('[') {
        if let Some((_, dest)) = t.split_once("]: ") {
            out.push(dest.split_whitespace().next().unwrap_or("").to_string());
        }
    }
    out
}

/// The anchor GitHub gives a heading's text: lower case, markup and punctuation other
/// than `-` and `_` dropped, spaces as `-`. (mdBook makes the same ids.)
fn slug(heading: &str) -> String {
    // Links in a heading count by their text.
    let mut text = String::new();
    let mut rest = heading;
    while let Some(open) = rest.find('[') {
        let Some(close) = rest[open..].find("](") else {
            break;
        };
        let Some(end) = rest[open + close..].find(')') else {
            break;
        };
        text.push_str(&rest[..open]);
        text.push_str(&rest[open + 1..open + close]);
        rest = &rest[open + close + end + 1..];
    }
    text.push_str(rest);
    text.trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .collect()
}

/// The anchors of a Markdown file: its headings' slugs (repeats numbered `-1`, `-2`, as
/// GitHub numbers them) and the `id="..."` / `name="..."` of its HTML.
fn anchors(text: &str) -> BTreeSet<String> {
    let (prose, _) = split(text);
    let mut seen: HashMap<String, usize> = HashMap::new();
    let mut out = BTreeSet::new();
    for (_, line) in prose {
        let t = line.trim_start();
        let hashes = t.chars().take_while(|&c| c == '#').count();
        if (1..=6).contains(&hashes) && t[hashes..].starts_with(' ') {
            let s = slug(t[hashes..].trim().trim_end_matches('#'));
            let n = seen.entry(s.clone()).or_insert(0);
            out.insert(if *n == 0 {
                s.clone()
            } else {
                format!("{s}-{n}")
            });
            *n += 1;
        }
        for attr in ["id=\"", "name=\""] {
            let mut rest = line.as_str();
            while let Some(at) = rest.find(attr) {
                let v = &rest[at + attr.len()..];
                if let Some(end) = v.find('"') {
                    out.insert(v[..end].to_string());
                }
                rest = &rest[at + attr.len()..];
            }
        }
    }
    out
}

/// The broken relative links of one file: `file:line: link: why`.
fn broken_links(file: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(file).unwrap();
    let (prose, _) = split(&text);
    let mut bad = Vec::new();
    for (n, line) in prose {
        for dest in links_of(&line) {
            if dest.is_empty() || dest.contains("://") || dest.starts_with("mailto:") {
                continue;
            }
            let (path, anchor) = match dest.split_once('#') {
                Some((p, a)) => (p, Some(a)),
                None => (dest.as_str(), None),
            };
            let target = if path.is_empty() {
                file.to_path_buf()
            } else if let Some(abs) = path.strip_prefix('/') {
                repo().join(abs)
            } else {
                file.parent().unwrap().join(path)
            };
            let why = if !target.exists() {
                Some(format!("{} does not exist", rel(&target)))
            } else if let Some(a) = anchor {
                if target.extension().is_some_and(|e| e == "md") {
                    let have = anchors(&std::fs::read_to_string(&target).unwrap());
                    (!have.contains(a)).then(|| {
                        format!(
                            "{} has no heading #{a} (it has: {})",
                            rel(&target),
                            have.iter().cloned().collect::<Vec<_>>().join(" ")
                        )
                    })
                } else {
                    None
                }
            } else {
                None
            };
            if let Some(why) = why {
                bad.push(format!("{}:{n}: ({dest}): {why}", rel(file)));
            }
        }
    }
    bad
}

#[test]
fn every_relative_link_and_anchor_resolves() {
    let files = markdown_files();
    assert!(
        files.iter().any(|f| f.ends_with("docs/src/SUMMARY.md")),
        "the guide is missing: {files:?}"
    );
    let bad: Vec<String> = files.iter().flat_map(|f| broken_links(f)).collect();
    assert!(
        bad.is_empty(),
        "{} broken link(s):\n{}",
        bad.len(),
        bad.join("\n")
    );
}

#[test]
fn every_page_of_the_guide_is_in_its_summary() {
    let src = repo().join("docs/src");
    let summary = std::fs::read_to_string(src.join("SUMMARY.md")).unwrap();
    let listed: BTreeSet<String> = summary.lines().flat_map(links_of).collect();
    for e in std::fs::read_dir(&src).unwrap().flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        if name.ends_with(".md") && name != "SUMMARY.md" {
            assert!(
                listed.contains(&name),
                "docs/src/{name} is not in SUMMARY.md"
            );
        }
    }
}

#[test]
fn the_link_checker_catches_what_it_should() {
    // The checker itself: slugs as GitHub makes them, links in code ignored, a heading
    // repeated gets a number.
    assert_eq!(
        slug("Checking a drive: the `--only` option"),
        "checking-a-drive-the---only-option"
    );
    assert_eq!(slug("Gates [(and more)](x.md)"), "gates-and-more");
    assert_eq!(slug("What is `fuzz_targets/`?"), "what-is-fuzz_targets");
    assert_eq!(links_of("see [a](b.md#c) and `[x](y)`"), vec!["b.md#c"]);
    let a = anchors("# A\n## A\n```\n# not a heading\n```\n<a id=\"z\"></a>\n");
    assert_eq!(
        a.into_iter().collect::<Vec<_>>(),
        vec!["a".to_string(), "a-1".to_string(), "z".to_string()]
    );
    let dir = repo().join("target/tmp/docs-links");
    std::fs::create_dir_all(&dir).unwrap();
    let f = dir.join("page.md");
    std::fs::write(
        &f,
        "# Top\n\n[ok](#top) [bad](#nowhere)\n[gone](missing.md) [self](page.md#top)\n",
    )
    .unwrap();
    let bad = broken_links(&f);
    assert_eq!(bad.len(), 2, "{bad:?}");
    assert!(bad[0].contains("page.md:3: (#nowhere)"), "{bad:?}");
    assert!(bad[1].contains(":4: (missing.md)"), "{bad:?}");
}
