//! Man pages and shell completions that the binary generates from its own clap
//! definitions (`conformance generate man|completions DIR`, `conformance completions
//! SHELL`): a page for every subcommand, found by walking `--help` as a user would, and
//! completion scripts the shells load.

mod common;
use common::{Run, Scratch};

use std::collections::BTreeSet;

fn conformance(args: &[&str]) -> String {
    let o = Run::new(args).run();
    assert_eq!(o.code, Some(0), "conformance {args:?}: {o:?}");
    o.stdout.clone()
}

/// The subcommands a `--help` lists under "Commands:" (without `help`).
fn listed(help: &str) -> Vec<String> {
    help.lines()
        .skip_while(|l| *l != "Commands:")
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.split_whitespace().next())
        .filter(|c| *c != "help")
        .map(str::to_string)
        .collect()
}

/// Every command path under `conformance`, as `conformance-a-b` page names.
fn every_page(path: &mut Vec<String>, out: &mut BTreeSet<String>) {
    out.insert(format!("{}.1", path.join("-")));
    let mut args: Vec<&str> = path[1..].iter().map(String::as_str).collect();
    args.push("--help");
    for sub in listed(&conformance(&args)) {
        path.push(sub);
        every_page(path, out);
        path.pop();
    }
}

#[test]
fn every_subcommand_gets_a_man_page_that_man_renders() {
    let dir = Scratch::new("man");
    let out = conformance(&["generate", "man", dir.to_str().unwrap()]);
    let mut expected = BTreeSet::new();
    every_page(&mut vec!["conformance".into()], &mut expected);
    assert!(expected.contains("conformance-check.1"), "{expected:?}");
    assert!(
        expected.contains("conformance-model-lint.1"),
        "{expected:?}"
    );
    let written: BTreeSet<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(written, expected);
    assert_eq!(
        out,
        format!("{} files written under {}\n", expected.len(), dir.display())
    );
    // The page says what --help says: the options of check, from the same definitions.
    let page = std::fs::read_to_string(dir.join("conformance-check.1")).unwrap();
    assert!(
        page.starts_with(".ie \\n(.g .ds Aq"),
        "not roff: {}",
        &page[..80]
    );
    assert!(
        page.contains("\\-\\-no\\-pace"),
        "check's page lacks --no-pace"
    );
    if common::tool_or_skip(
        common::runs("man", &["--version"]),
        "man (Debian package man-db)",
    ) {
        let o = Run::program("man", ["-l"])
            .arg(dir.join("conformance-check.1"))
            .env("MANPAGER", "cat")
            .env("MANWIDTH", "100")
            .run();
        // man justifies its lines: the words are compared, not the spaces.
        let text = o.stdout.as_str();
        let words = text.split_whitespace().collect::<Vec<_>>().join(" ");
        assert_eq!(o.code, Some(0), "{o:?}");
        assert!(
            words.contains("NAME conformance-check - Probe a real or simulated drive"),
            "{text}"
        );
    }
}

fn bash(script: &str) -> String {
    let o = Run::program("bash", ["-c", script]).run();
    assert_eq!(o.code, Some(0), "{script}: {o:?}");
    o.stdout
}

#[test]
fn the_bash_completion_loads_and_completes_subcommands_and_options() {
    let dir = Scratch::new("completions");
    conformance(&["generate", "completions", dir.to_str().unwrap()]);
    for f in ["conformance.bash", "_conformance", "conformance.fish"] {
        assert!(dir.join(f).is_file(), "{f} missing");
    }
    // `completions bash` prints the same script the package carries.
    assert_eq!(
        conformance(&["completions", "bash"]),
        std::fs::read_to_string(dir.join("conformance.bash")).unwrap()
    );
    let file = dir.join("conformance.bash");
    let source = format!("source {}", file.display());
    assert!(
        bash(&format!("{source}; complete -p conformance")).contains("-F _conformance conformance"),
        "the completion is not registered"
    );
    let complete = |words: &str| {
        bash(&format!(
            "{source}; COMP_WORDS=({words}); COMP_CWORD=$((${{#COMP_WORDS[@]}} - 1)); \
             _conformance conformance \"${{COMP_WORDS[-1]}}\" \"${{COMP_WORDS[-2]}}\"; \
             echo \"${{COMPREPLY[@]}}\""
        ))
    };
    assert_eq!(complete("conformance po").trim(), "ports");
    assert!(complete("conformance check --no-p").contains("--no-pace"));
    // The other shells' scripts parse, where those shells are here.
    // (Neither is a peer CI installs: where one is missing, this part says so and passes.)
    for (shell, file) in [("zsh", "_conformance"), ("fish", "conformance.fish")] {
        if !common::runs(shell, &["-c", "true"]) {
            common::note(&format!(
                "generated: {shell} is not here; its script was not parsed"
            ));
        } else {
            assert!(
                common::runs(shell, &["-n", dir.join(file).to_str().unwrap()]),
                "{shell} -n {file} fails"
            );
        }
    }
}

#[test]
fn completions_refuses_an_unknown_shell() {
    let o = Run::words("completions tcsh").run();
    assert_eq!(o.code, Some(2));
    assert!(o.stderr.contains("possible values: bash"));
}
