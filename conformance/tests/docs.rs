//! The documentation, checked: every `console` example prints what the program prints,
//! and every `conformance` line of a `sh` block uses options that its command has. (The
//! links and anchors are checked by tests/docs_links.rs.)
//!
//! How an example is written (docs/src/overview.md, "How the examples are written"):
//!
//! ````text
//! ```console
//! $ conformance decode 0103252000018ECC
//! ? 0
//! RTU frame, 8 bytes: 01 03 25 20 00 01 8E CC
//! ...
//! ```
//! ````
//!
//! - `$ ` starts a command; it runs in the block's own temporary directory, with the
//!   binary under test first on the PATH (as after `cargo install --path conformance`),
//!   and its stdout and stderr are read together, as a terminal shows them. Only
//!   `conformance` commands are run: a transcript with another program (mbpoll, python3)
//!   is a `text` block, shown as recorded.
//! - A command that ends in ` &` runs in the background for the rest of the block; the
//!   lines under it are its first lines of output (read before the next command starts,
//!   so a simulator's pty path also says it is ready), and it is ended with the block.
//! - `? N` right under a command is its exit code (0 when absent).
//! - The other lines are the output. `[..]` in a line stands for any text within that
//!   line, and a line of `...` for any number of lines (none included).
//!
//! A failure names the file and line of the command and prints the whole output, which
//! can be pasted back into the page. `DOCS_EXAMPLES=PATTERN` runs only the examples whose
//! command contains PATTERN.

mod common;
mod markdown;

use std::collections::HashMap;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use common::{Run, Scratch};
use markdown::{markdown_files, rel, repo, split, Block};

// ---- paths in code spans -----------------------------------------------------------

/// The pages that name files of the repository in code spans and diagrams (the
/// architecture page: `runner/checks/mod.rs`, `sim/drive/quirk.rs`, ...). A link is
/// checked wherever it is; a path in code only on these pages, where it is meant as a
/// path and not as an example of one.
const PAGES_WITH_PATHS: [&str; 1] = ["docs/src/architecture.md"];

/// Whether a word names a file or folder: path characters only, with a `/` or a file's
/// ending in it. A placeholder (`cli/<name>_cmd.rs`), a command line or a Rust path
/// (`conformance::oracle`) is not one.
fn is_path(word: &str) -> bool {
    !word.is_empty()
        && !word.starts_with(['.', '/', '-'])
        && word
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "_-./".contains(c))
        && (word.contains('/')
            || [".rs", ".md", ".json", ".toml", ".py", ".sh", ".c", ".js"]
                .iter()
                .any(|e| word.ends_with(e)))
}

/// The paths a page names that do not exist: `file:line: `path`: why`. A path is taken
/// from the top of the repository, or else from `conformance/src/` (where the rooms of
/// the library are); the words of a `text` block count as well as the code spans of
/// the prose.
fn missing_paths(file: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(file).unwrap();
    let (prose, blocks) = split(&text);
    let mut named: Vec<(usize, String)> = Vec::new();
    for (n, line) in &prose {
        // Between an odd and the next even backtick: a span (an unclosed one is not).
        let pieces: Vec<&str> = line.split('`').collect();
        for (i, span) in pieces.iter().enumerate() {
            if i % 2 == 1 && i + 1 < pieces.len() && is_path(span) {
                named.push((*n, span.to_string()));
            }
        }
    }
    for b in blocks.iter().filter(|b| b.lang() == "text") {
        for (k, line) in b.lines.iter().enumerate() {
            for w in line.split_whitespace() {
                let w = w.trim_matches([',', ';', '(', ')', ':']);
                if is_path(w) {
                    named.push((b.line + 1 + k, w.to_string()));
                }
            }
        }
    }
    let src = repo().join("conformance/src");
    named
        .into_iter()
        .filter(|(_, p)| !repo().join(p).exists() && !src.join(p).exists())
        .map(|(n, p)| {
            format!(
                "{}:{n}: `{p}`: neither {p} nor conformance/src/{p} exists",
                rel(file)
            )
        })
        .collect()
}

#[test]
fn every_path_the_architecture_page_names_exists() {
    let bad: Vec<String> = PAGES_WITH_PATHS
        .iter()
        .flat_map(|p| missing_paths(&repo().join(p)))
        .collect();
    assert!(
        bad.is_empty(),
        "{} path(s) that do not exist:\n{}",
        bad.len(),
        bad.join("\n")
    );
}

/// Every room of the library (a folder or a file of `conformance/src/`, less `lib.rs`
/// and `main.rs`, which the page names by their whole paths) has its row in the
/// architecture page's table, so that a room added is a room described.
#[test]
fn every_room_of_the_library_is_on_the_architecture_page() {
    let page = std::fs::read_to_string(repo().join("docs/src/architecture.md")).unwrap();
    let mut missing = Vec::new();
    for e in std::fs::read_dir(repo().join("conformance/src"))
        .unwrap()
        .flatten()
    {
        let name = e.file_name().to_string_lossy().to_string();
        let room = if e.path().is_dir() {
            format!("{name}/")
        } else if name.ends_with(".rs") && name != "lib.rs" && name != "main.rs" {
            name
        } else {
            continue;
        };
        if !page.contains(&format!("\n| `{room}` |")) {
            missing.push(room);
        }
    }
    missing.sort();
    assert!(
        missing.is_empty(),
        "rooms of conformance/src/ with no row in docs/src/architecture.md: {missing:?}"
    );
}

#[test]
fn the_path_checker_catches_what_it_should() {
    assert!(is_path("runner/checks/mod.rs") && is_path("seeds.rs") && is_path("gate/"));
    assert!(!is_path("cli/<name>_cmd.rs") && !is_path("conformance::oracle"));
    assert!(!is_path("farm-studio look") && !is_path("TARGETS") && !is_path("/dev/ttyUSB0"));
    let dir = repo().join("target/tmp/docs-paths");
    std::fs::create_dir_all(&dir).unwrap();
    let f = dir.join("page.md");
    std::fs::write(
        &f,
        "# Top\n\n`sim/drive/mod.rs` and `conformance/tests/docs.rs`, `no/such/room.rs`\n\
         ```text\n  floor 1   codec/   nowhere.rs\n```\n`an unclosed span no/such.rs\n",
    )
    .unwrap();
    let bad = missing_paths(&f);
    assert_eq!(bad.len(), 2, "{bad:?}");
    assert!(bad[0].contains("page.md:3: `no/such/room.rs`"), "{bad:?}");
    assert!(bad[1].contains("page.md:5: `nowhere.rs`"), "{bad:?}");
}

// ---- examples ----------------------------------------------------------------------

/// Splits a command line as a POSIX shell would for the cases the examples use: words,
/// single quotes (literal), double quotes and backslashes. Pipes, redirections and
/// command lists are refused, since the example could not be pasted as it is checked.
fn words(line: &str) -> Result<Vec<String>, String> {
    let mut out = Vec::new();
    let mut cur = String::new();
    let mut have = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '\'' => {
                have = true;
                loop {
                    match chars.next() {
                        Some('\'') => break,
                        Some(c) => cur.push(c),
                        None => return Err("unclosed '".into()),
                    }
                }
            }
            '"' => {
                have = true;
                loop {
                    match chars.next() {
                        Some('"') => break,
                        Some('\\') if matches!(chars.peek(), Some('"' | '\\' | '$')) => {
                            cur.push(chars.next().unwrap())
                        }
                        Some(c) => cur.push(c),
                        None => return Err("unclosed \"".into()),
                    }
                }
            }
            '\\' => {
                have = true;
                if let Some(c) = chars.next() {
                    cur.push(c);
                }
            }
            '|' | '>' | '<' | ';' | '&' | '$' | '`' => {
                return Err(format!("{c} is not supported in a checked example"))
            }
            c if c.is_whitespace() => {
                if have {
                    out.push(std::mem::take(&mut cur));
                    have = false;
                }
            }
            c => {
                have = true;
                cur.push(c)
            }
        }
    }
    if have {
        out.push(cur);
    }
    Ok(out)
}

/// Whether `actual` matches the pattern `expected`, where `[..]` is any text within a
/// line and a line `...` any number of lines.
fn lines_match(expected: &[String], actual: &[String]) -> bool {
    fn line_matches(pattern: &str, line: &str) -> bool {
        let parts: Vec<&str> = pattern.split("[..]").collect();
        if parts.len() == 1 {
            return pattern == line;
        }
        let (first, last) = (parts[0], parts[parts.len() - 1]);
        if !line.starts_with(first) || line.len() < first.len() + last.len() {
            return false;
        }
        let mut at = first.len();
        for mid in &parts[1..parts.len() - 1] {
            match line[at..].find(mid) {
                Some(i) => at += i + mid.len(),
                None => return false,
            }
        }
        line.len() - last.len() >= at && line.ends_with(last)
    }
    fn go(e: &[String], a: &[String], memo: &mut HashMap<(usize, usize), bool>) -> bool {
        if let Some(&m) = memo.get(&(e.len(), a.len())) {
            return m;
        }
        let r = match e.first() {
            None => a.is_empty(),
            Some(p) if p == "..." => (0..=a.len()).any(|k| go(&e[1..], &a[k..], memo)),
            Some(p) => !a.is_empty() && line_matches(p, &a[0]) && go(&e[1..], &a[1..], memo),
        };
        memo.insert((e.len(), a.len()), r);
        r
    }
    go(expected, actual, &mut HashMap::new())
}

/// One command of an example.
struct Step {
    line: usize,
    command: String,
    background: bool,
    exit: i32,
    output: Vec<String>,
}

fn steps_of(file: &str, block: &Block) -> Vec<Step> {
    let mut steps: Vec<Step> = Vec::new();
    for (i, l) in block.lines.iter().enumerate() {
        let line = block.line + 1 + i;
        let l = l.trim_end();
        if let Some(cmd) = l.strip_prefix("$ ") {
            let (cmd, background) = match cmd.strip_suffix(" &") {
                Some(c) => (c, true),
                None => (cmd, false),
            };
            steps.push(Step {
                line,
                command: cmd.to_string(),
                background,
                exit: 0,
                output: Vec::new(),
            });
        } else {
            let step = steps.last_mut().unwrap_or_else(|| {
                panic!("{file}:{line}: a console block must start with a `$ ` command")
            });
            match l.strip_prefix("? ") {
                Some(code) if step.output.is_empty() => {
                    step.exit = code
                        .parse()
                        .unwrap_or_else(|_| panic!("{file}:{line}: `? {code}` is no exit code"))
                }
                _ => step.output.push(l.to_string()),
            }
        }
    }
    steps
}

/// Children of one block, ended when the block is done (or its test failed).
struct Background(Vec<Child>);

impl Drop for Background {
    fn drop(&mut self) {
        for c in &mut self.0 {
            // SIGTERM first (a simulator removes its link then), then a kill.
            terminate(c);
        }
    }
}

fn terminate(c: &mut Child) {
    let _ = Command::new("kill")
        .arg("-TERM")
        .arg(c.id().to_string())
        .status();
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(3) {
        if let Ok(Some(_)) = c.try_wait() {
            return;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = c.kill();
    let _ = c.wait();
}

/// How long one example command may take before it counts as hung.
const LIMIT: Duration = Duration::from_secs(180);

/// Runs the `console` blocks of one Markdown file (relative to the repository) and
/// returns the failures.
fn run_examples(page: &str) -> Vec<String> {
    let path = repo().join(page);
    let text = std::fs::read_to_string(&path).unwrap();
    let (_, blocks) = split(&text);
    let bin = PathBuf::from(env!("CARGO_BIN_EXE_conformance"));
    let path_var = format!(
        "{}:{}",
        bin.parent().unwrap().display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let only = std::env::var("DOCS_EXAMPLES").ok();
    // The directories of earlier runs (kept where an example failed) go once their
    // process is gone.
    if let Ok(dirs) = std::fs::read_dir(repo().join("target/tmp/docs-examples")) {
        for d in dirs.flatten() {
            let pid = d.file_name().to_string_lossy().to_string();
            if !Path::new("/proc").join(&pid).exists() {
                let _ = std::fs::remove_dir_all(d.path());
            }
        }
    }
    let mut failures = Vec::new();
    let mut ran = 0;
    for block in blocks.iter().filter(|b| b.lang() == "console") {
        let steps = steps_of(page, block);
        if let Some(pat) = &only {
            if !steps.iter().any(|s| s.command.contains(pat.as_str())) {
                continue;
            }
        }
        // The process id keeps two test runs at once (a loaded CI host) apart.
        let dir = repo().join(format!(
            "target/tmp/docs-examples/{}/{}-{}",
            std::process::id(),
            page.replace('/', "_"),
            block.line
        ));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let mut background = Background(Vec::new());
        let failed_before = failures.len();
        for step in &steps {
            ran += 1;
            let here = format!("{page}:{}: $ {}", step.line, step.command);
            let argv = match words(&step.command) {
                Ok(w) => w,
                Err(e) => {
                    failures.push(format!("{here}\n  {e}"));
                    break;
                }
            };
            if argv.first().map(String::as_str) != Some("conformance") {
                failures.push(format!(
                    "{here}\n  only `conformance` commands are run in a console block; \
                     write a transcript of another program as a text block"
                ));
                break;
            }
            let (reader, writer) = std::io::pipe().unwrap();
            let mut child = Command::new(&bin)
                .args(&argv[1..])
                .current_dir(&dir)
                .env("PATH", &path_var)
                .env_remove("CI")
                .stdin(Stdio::null())
                .stdout(writer.try_clone().unwrap())
                .stderr(writer)
                .spawn()
                .unwrap();
            let t0 = Instant::now();
            let (actual, exit) = if step.background {
                // Read as many lines as the page shows, then leave it running.
                let (tx, rx) = mpsc::channel();
                let want = step.output.len();
                std::thread::spawn(move || {
                    let mut lines = BufReader::new(reader).lines();
                    for _ in 0..want {
                        match lines.next() {
                            Some(Ok(l)) => {
                                if tx.send(l).is_err() {
                                    return;
                                }
                            }
                            _ => return,
                        }
                    }
                    // Keep draining, so the child never blocks on a full pipe.
                    for _ in lines {}
                });
                let mut got = Vec::new();
                while got.len() < want {
                    match rx.recv_timeout(Duration::from_secs(30)) {
                        Ok(l) => got.push(l),
                        Err(_) => break,
                    }
                }
                background.0.push(child);
                (got, step.exit)
            } else {
                let (tx, rx) = mpsc::channel();
                std::thread::spawn(move || {
                    let mut s = Vec::new();
                    let mut r = reader;
                    let _ = r.read_to_end(&mut s);
                    let _ = tx.send(s);
                });
                let out = match rx.recv_timeout(LIMIT) {
                    Ok(o) => o,
                    Err(_) => {
                        let _ = child.kill();
                        failures.push(format!("{here}\n  still running after {LIMIT:?}"));
                        break;
                    }
                };
                let status = child.wait().unwrap();
                let text = String::from_utf8_lossy(&out).to_string();
                (
                    text.lines().map(|l| l.trim_end().to_string()).collect(),
                    status.code().unwrap_or(-1),
                )
            };
            let expected: Vec<String> = step
                .output
                .iter()
                .map(|l| l.trim_end().to_string())
                .collect();
            eprintln!("  {:5.1} s  {here}", t0.elapsed().as_secs_f64());
            if exit != step.exit || !lines_match(&expected, &actual) {
                failures.push(format!(
                    "{here}\n  expected exit {} and:\n{}\n  got exit {exit} and:\n{}\n",
                    step.exit,
                    expected.join("\n"),
                    actual.join("\n")
                ));
                break;
            }
        }
        drop(background);
        if failures.len() == failed_before {
            let _ = std::fs::remove_dir_all(&dir);
        }
    }
    if only.is_none() {
        assert!(ran > 0, "{page} has no console example");
    }
    failures
}

/// One page's examples at a time: the pages' tests run on the harness's threads, and the
/// paced simulator of one example should not share two cores with another's.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn check_page(page: &str) {
    let failures = {
        let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        run_examples(page)
    };
    assert!(
        failures.is_empty(),
        "{} example(s) of {page} do not print what the page shows:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

#[test]
fn the_matcher_takes_wildcards_and_nothing_else() {
    let s = |v: &[&str]| v.iter().map(|x| x.to_string()).collect::<Vec<_>>();
    assert!(lines_match(&s(&["a [..] c"]), &s(&["a b c"])));
    assert!(!lines_match(&s(&["a [..] c"]), &s(&["a b d"])));
    assert!(lines_match(
        &s(&["x", "...", "z"]),
        &s(&["x", "1", "2", "z"])
    ));
    assert!(lines_match(&s(&["x", "...", "z"]), &s(&["x", "z"])));
    assert!(!lines_match(&s(&["x", "z"]), &s(&["x", "y", "z"])));
    assert!(!lines_match(&s(&["x"]), &s(&["x", "more"])));
    assert!(lines_match(&s(&["[..]ab[..]ab"]), &s(&["abab"])));
    assert!(!lines_match(&s(&["ab[..]ba"]), &s(&["aba"])));
    assert_eq!(
        words(r#"conformance gate --codec "conformance adapter" --only 'rtu.*' a\ b"#).unwrap(),
        vec![
            "conformance",
            "gate",
            "--codec",
            "conformance adapter",
            "--only",
            "rtu.*",
            "a b"
        ]
    );
    assert!(words("conformance report r.json > r.txt").is_err());
    assert!(words("conformance decode ':01\\r\\n'").unwrap()[2] == ":01\\r\\n");
}

#[test]
fn requirements_examples() {
    check_page("docs/src/requirements.md");
}

#[test]
fn readme_examples() {
    check_page("README.md");
}

#[test]
fn tour_examples() {
    check_page("docs/src/tour.md");
}

#[test]
fn from_the_box_examples() {
    check_page("docs/src/from-the-box.md");
}

/// The `sh` blocks list commands for a real drive, a gateway or a long campaign, which
/// cannot run here; each of their `conformance` lines must at least use options its
/// command has (so a renamed option cannot leave the guide behind).
#[test]
fn sh_blocks_use_options_that_exist() {
    let mut help_of = HashMap::new();
    let mut bad = Vec::new();
    let mut seen = 0;
    for file in markdown_files() {
        let text = std::fs::read_to_string(&file).unwrap();
        let (n, b) = unknown_options(&rel(&file), &text, &mut help_of);
        seen += n;
        bad.extend(b);
    }
    assert!(seen > 20, "only {seen} conformance lines found");
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

#[test]
fn the_option_checker_catches_what_it_should() {
    let page = "```sh\nconformance check --sim f510 --no-such-option   # a comment\n\
                conformance nosuch --x\nconformance vectors export --format json\n```\n\
                ```text\nconformance check --not-a-command-here\n$ conformance scan --bad\n```\n";
    let (seen, bad) = unknown_options("page.md", page, &mut HashMap::new());
    assert_eq!(seen, 4);
    assert_eq!(bad.len(), 3, "{bad:?}");
    assert!(bad[0].contains("page.md:2:") && bad[0].contains("has no --no-such-option"));
    assert!(bad[1].contains("page.md:3:") && bad[1].contains("no such command"));
    assert!(bad[2].contains("page.md:8:") && bad[2].contains("`conformance scan` has no --bad"));
}

/// The `conformance` lines of the `sh` and `console` blocks of one page (and the
/// `$ conformance` lines of its `text` transcripts), counted, and
/// those that name a command or an option that does not exist (`label:line: why`).
/// `help_of` caches `conformance CMD --help` by command path.
fn unknown_options(
    label: &str,
    text: &str,
    help_of: &mut HashMap<Vec<String>, String>,
) -> (usize, Vec<String>) {
    let mut bad = Vec::new();
    let mut seen = 0;
    let (_, blocks) = split(text);
    for b in blocks
        .iter()
        .filter(|b| matches!(b.lang(), "sh" | "console" | "text"))
    {
        for (i, l) in b.lines.iter().enumerate() {
            let at = format!("{label}:{}", b.line + 1 + i);
            // A text block is output, but a `$ conformance` line in it is a recorded
            // command (a transcript with mbpoll).
            if b.lang() == "text" && !l.trim_start().starts_with("$ conformance ") {
                continue;
            }
            // In a console block only the `$` lines are commands (`conformance --version`
            // prints a line that starts with `conformance`).
            if b.lang() == "console" && !l.trim_start().starts_with("$ ") {
                continue;
            }
            let l = l.trim().trim_start_matches("$ ");
            let l = l.split(" #").next().unwrap().trim().trim_end_matches(" &");
            let Some(args) = l.strip_prefix("conformance ") else {
                continue;
            };
            let Ok(w) = words(args) else { continue };
            seen += 1;
            // The command path: the leading words that `--help` accepts.
            let mut path: Vec<String> = Vec::new();
            for word in w.iter().take_while(|x| !x.starts_with('-')).take(2) {
                let mut p = path.clone();
                p.push(word.clone());
                let help = help_of.entry(p.clone()).or_insert_with(|| {
                    let o = Run::new(&p).arg("--help").run();
                    if o.code == Some(0) {
                        o.stdout
                    } else {
                        String::new()
                    }
                });
                if help.is_empty() {
                    break;
                }
                path = p;
            }
            // Options of the program itself (`conformance --version`) are in its own help.
            if path.is_empty() && w.first().is_some_and(|x| x.starts_with('-')) {
                help_of
                    .entry(Vec::new())
                    .or_insert_with(|| Run::words("--help").run().stdout);
            } else if path.is_empty() {
                bad.push(format!("{at}: {l}: no such command"));
                continue;
            }
            let help = &help_of[&path];
            for flag in w.iter().filter(|x| x.starts_with("--") && x.len() > 2) {
                let name = flag.split('=').next().unwrap();
                let known = [" ", ",", "\n", "=", "]"]
                    .iter()
                    .any(|end| help.contains(&format!("{name}{end}")));
                if !known {
                    bad.push(format!(
                        "{at}: {l}: `conformance {}` has no {name}",
                        path.join(" ")
                    ));
                }
            }
        }
    }
    (seen, bad)
}

#[test]
fn several_drives_examples() {
    check_page("docs/src/several-drives.md");
}

#[test]
fn identify_and_scan_examples() {
    check_page("docs/src/identify-and-scan.md");
}

#[test]
fn parameters_examples() {
    check_page("docs/src/parameters.md");
}

#[test]
fn fuzzing_a_drive_examples() {
    check_page("docs/src/fuzzing-a-drive.md");
}

#[test]
fn checking_a_drive_examples() {
    check_page("docs/src/checking-a-drive.md");
}

#[test]
fn reports_examples() {
    check_page("docs/src/reports.md");
}

#[test]
fn expectations_examples() {
    check_page("docs/src/expectations.md");
}

#[test]
fn gates_examples() {
    check_page("docs/src/gates.md");
}

#[test]
fn simulator_examples() {
    check_page("docs/src/simulator.md");
}

#[test]
fn watching_a_drive_examples() {
    check_page("docs/src/watching-a-drive.md");
}

#[test]
fn master_gate_examples() {
    check_page("docs/src/master-gate.md");
}

/// Issue 33, item 8: the monitor's page and the monitor agree on what it does with no
/// `-b`. The monitor finds the baud rate and parity by listening (its help says so, and
/// the page has a section on it), so no paragraph of the page may call that "not yet"
/// done.
#[test]
fn the_monitor_page_does_not_call_the_line_search_not_yet_done() {
    let help = Run::words("monitor --help").run().stdout;
    assert!(
        help.contains("with no -b, the monitor finds them by listening"),
        "{help}"
    );
    let page = std::fs::read_to_string(repo().join("docs/src/monitor.md")).unwrap();
    assert!(page.contains("\n## Line settings found by listening\n"));
    let contradictions: Vec<&str> = page
        .split("\n\n")
        .filter(|p| {
            let p = p.to_lowercase();
            p.contains("not yet")
                && (p.contains("baud") || p.contains("parity") || p.contains("`-b`"))
        })
        .collect();
    assert!(contradictions.is_empty(), "{contradictions:#?}");
}

/// The blocks of `lang` in a guide page (relative to the repository).
fn blocks_of(page: &str, lang: &str) -> Vec<Block> {
    let text = std::fs::read_to_string(repo().join(page)).unwrap();
    split(&text)
        .1
        .into_iter()
        .filter(|b| b.lang() == lang)
        .collect()
}

const DESCRIBING: &str = "docs/src/describing-a-device.md";
const ACME: &str = "vectors/models/examples/acme-x100.json";

/// Issue 34: the complete description on "Describing your own device" is the example file,
/// byte for byte, so the page cannot drift from the file the tests load.
#[test]
fn the_describing_a_device_page_shows_the_example_file() {
    let file = std::fs::read_to_string(repo().join(ACME)).unwrap();
    let complete: Vec<String> = blocks_of(DESCRIBING, "json")
        .into_iter()
        .map(|b| b.lines.join("\n"))
        .filter(|t| t.trim_start().starts_with('{'))
        .collect();
    assert_eq!(complete.len(), 1, "one complete description on the page");
    assert_eq!(complete[0].trim_end(), file.trim_end());
}

/// The page's `model lint` transcript is what lint prints for the example with the two
/// slips the page names (a lower-case hex digit, a misspelt `access`).
#[test]
fn the_describing_a_device_lint_transcript_is_what_lint_prints() {
    let file = std::fs::read_to_string(repo().join(ACME)).unwrap();
    let broken = file
        .replacen("\"first\": \"2500\"", "\"first\": \"2500h\"", 1)
        .replacen("\"access\": \"read-only\"", "\"acess\": \"read-only\"", 1);
    assert_ne!(broken, file);
    let dir = Scratch::new("lint");
    std::fs::write(dir.join("acme-x100.json"), broken).unwrap();
    let o = Run::words("model lint acme-x100.json")
        .in_dir(&dir)
        .run()
        .expect(1);
    let transcript = blocks_of(DESCRIBING, "text")
        .into_iter()
        .find(|b| {
            b.lines.first().map(String::as_str) == Some("$ conformance model lint acme-x100.json")
        })
        .expect("the page shows a lint transcript");
    let printed: Vec<String> = o.stdout.lines().map(str::to_string).collect();
    assert_eq!(transcript.lines[1..], printed[..]);
}

/// Issue 34: the example description lints clean (no error, no warning).
#[test]
fn the_example_description_lints_clean() {
    let text = std::fs::read_to_string(repo().join(ACME)).unwrap();
    let findings = conformance::model::lint::lint(ACME, &text);
    assert!(findings.is_empty(), "{findings:#?}");
}
