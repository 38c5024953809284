//! The CRC program the manuals print in C (`<doc>.crc-listing` vectors), compiled with the
//! machine's C compiler (`$CC`, else `cc`):
//! - as printed (for the E510, as the page prints it: the OCR repairs applied), with the
//!   typedefs it assumes, it must fail, for the two reasons the vectors record: `long`
//!   used as a parameter name, and a pointer XORed into an integer; and no other error;
//! - with every repair but one it must still fail: each recorded repair is needed;
//! - corrected, with a small `main` that reads hex lines and prints one CRC per line, it
//!   must compute exactly `crc16_reference` and `crc16` on every example frame of the
//!   manuals and on random inputs of every length 0..=255; from 256 bytes on, the printed
//!   program's UBYTE length takes the length modulo 256, which is checked too.
//!
//! Without a C compiler the tests print `SKIPPED: ...` and pass, except when the
//! environment variable `CI` is set: then they fail.

mod common;

use std::path::Path;
use std::time::Duration;

use common::{cc, need, Peer, Run, Scratch};
use conformance::codec::crc::{crc16, crc16_reference};
use conformance::rng::Rng;
use conformance::vectors::model::{CListing, FileMode};
use conformance::vectors::{listing, Body, VectorSet};

/// A compiler or the compiled program is killed after this long.
const TIMEOUT: Duration = Duration::from_secs(60);

/// The test program's `main`: one line of hex in, the CRC of those bytes out, so that
/// one process computes every case.
const MAIN: &str = r#"
#include <stdio.h>

static int nibble(int c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    return -1;
}

int main(void)
{
    static char line[8192];
    static UBYTE buf[4096];
    while (fgets(line, sizeof line, stdin)) {
        unsigned n = 0;
        char *p = line;
        while (nibble(p[0]) >= 0 && nibble(p[1]) >= 0 && n < sizeof buf) {
            buf[n++] = (UBYTE)(nibble(p[0]) * 16 + nibble(p[1]));
            p += 2;
        }
        printf("%04X\n", (unsigned)ch_sum(n, buf));
    }
    return 0;
}
"#;

/// The C compiler, or `None` (after SKIPPED, or a panic under CI) when there is none.
fn compiler() -> Option<String> {
    need(Peer::CCompiler).then(cc)
}

/// A listing to compile: its id, its id as a file name, the listing, and its text as
/// printed on the page (its OCR repairs applied).
struct Printed {
    id: String,
    name: String,
    l: CListing,
    page: String,
}

/// For a test that compiles every listing: the [`compiler`], a fresh scratch folder
/// `name` to compile in, and the listings; None (after SKIPPED) without a compiler.
fn to_compile(name: &str) -> Option<(String, Scratch, Vec<Printed>)> {
    let cc = compiler()?;
    let all = listings().into_iter().map(|(id, name, l)| {
        let page = printed(&l);
        Printed { id, name, l, page }
    });
    Some((cc, Scratch::new(name), all.collect()))
}

/// One error the compiler reported: the line of the source file and the message.
#[derive(Debug)]
struct Diagnostic {
    line: usize,
    message: String,
}

/// What compiling a source gave.
struct Compiled {
    ok: bool,
    errors: Vec<Diagnostic>,
    stderr: String,
}

/// Compiles `source` (object only, or linked into `dir/name` when `link`). Diagnostics
/// are in the C locale so that their quotes are plain ASCII.
fn compile(cc: &str, dir: &Path, name: &str, source: &str, link: bool) -> Compiled {
    let src = dir.join(format!("{name}.c"));
    std::fs::write(&src, source).expect("write the C source");
    let out = dir.join(if link {
        name.to_string()
    } else {
        format!("{name}.o")
    });
    let o = Run::program(cc, ["-std=c99", "-Wall", "-o"])
        .env("LC_ALL", "C")
        .arg(&out)
        .args(if link { None } else { Some("-c") })
        .arg(&src)
        .stdin("")
        .timeout(TIMEOUT)
        .run();
    let stderr = o.stderr;
    let prefix = format!("{}:", src.display());
    let errors = stderr
        .lines()
        .filter_map(|l| {
            // FILE:LINE:COL: error: MESSAGE (gcc and clang).
            let rest = l.strip_prefix(&prefix)?;
            let (line, rest) = rest.split_once(':')?;
            let (_col, rest) = rest.split_once(':')?;
            let message = rest.trim_start().strip_prefix("error:")?.trim().to_string();
            Some(Diagnostic {
                line: line.parse().ok()?,
                message,
            })
        })
        .collect();
    Compiled {
        ok: o.code == Some(0),
        errors,
        stderr,
    }
}

fn listings() -> Vec<(String, String, CListing)> {
    let set = VectorSet::builtin().expect("built-in vectors load");
    let out: Vec<(String, String, CListing)> = set
        .iter()
        .filter_map(|(_, v)| match &v.body {
            Body::CListing(l) => Some((v.id.clone(), v.id.replace('.', "_"), l.clone())),
            _ => None,
        })
        .collect();
    assert_eq!(out.len(), 5, "one CRC listing per document");
    out
}

/// The listing's source with its typedefs in front; the source line of a diagnostic is
/// looked up in the same text.
fn with_typedefs(l: &CListing, body: &str) -> String {
    format!("{}{body}\n", l.typedefs())
}

/// The listing as printed on the page (its OCR repairs applied).
fn printed(l: &CListing) -> String {
    l.as_printed_on_page().expect("OCR repairs apply")
}

fn line_of(source: &str, n: usize) -> &str {
    source.lines().nth(n.saturating_sub(1)).unwrap_or("")
}

#[test]
fn the_printed_listings_do_not_compile_for_the_recorded_reasons() {
    let Some((cc, dir, all)) = to_compile("printed") else {
        return;
    };
    for Printed { id, name, l, page } in all {
        let source = with_typedefs(&l, &page);
        let c = compile(&cc, &dir, &name, &source, false);
        // Shown with `--nocapture`.
        println!("{id} as printed, {cc} says:\n{}", c.stderr.trim_end());
        assert!(!c.ok, "{id}: the printed listing compiled:\n{source}");
        // `long` as the parameter's name: an error on a line that uses it, which names
        // `long` (gcc) or the declaration it breaks (gcc, clang).
        let on_long = c.errors.iter().any(|d| {
            line_of(&source, d.line).contains("long")
                && ["long", "data types", "cannot combine", "expected"]
                    .iter()
                    .any(|w| d.message.contains(w))
        });
        assert!(on_long, "{id}: no error about `long`:\n{}", c.stderr);
        // The pointer XORed into an integer: "invalid operands to binary ^" (gcc) or
        // "invalid operands to binary expression" (clang).
        let on_pointer = c.errors.iter().any(|d| {
            line_of(&source, d.line).contains("rxdbuff++")
                && (d.message.contains("invalid operands") || d.message.contains("pointer"))
        });
        assert!(
            on_pointer,
            "{id}: no error about the pointer XORed into the CRC:\n{}",
            c.stderr
        );
        // And nothing else is wrong: every error is on a line a repair touches.
        for d in &c.errors {
            let text = line_of(&source, d.line);
            assert!(
                l.repairs.iter().any(|r| text.contains(&r.find)),
                "{id}: an error no repair accounts for, line {} {text:?}: {}",
                d.line,
                d.message
            );
        }
    }
}

#[test]
fn each_repair_is_needed_and_together_they_compile() {
    let Some((cc, dir, all)) = to_compile("repairs") else {
        return;
    };
    for Printed { id, name, l, page } in all {
        for skip in 0..l.repairs.len() {
            let some: Vec<_> = l
                .repairs
                .iter()
                .enumerate()
                .filter(|(i, _)| *i != skip)
                .map(|(_, r)| r.clone())
                .collect();
            let text = listing::apply_repairs(&page, &some).expect("repairs apply");
            let c = compile(
                &cc,
                &dir,
                &format!("{name}_{skip}"),
                &with_typedefs(&l, &text),
                false,
            );
            assert!(
                !c.ok,
                "{id}: compiles without repair {:?} -> {:?}, so it is not needed",
                l.repairs[skip].find, l.repairs[skip].replace
            );
        }
        let c = compile(&cc, &dir, &name, &with_typedefs(&l, &l.corrected), false);
        assert!(
            c.ok,
            "{id}: the corrected listing does not compile:\n{}",
            c.stderr
        );
        assert!(c.errors.is_empty(), "{id}: {:?}", c.errors);
    }
}

/// Every RTU example frame body of the manuals (the correct frame where one is recorded).
fn example_bodies() -> Vec<(String, Vec<u8>)> {
    let set = VectorSet::builtin().expect("built-in vectors load");
    let mut out = Vec::new();
    for (_, v) in set.iter() {
        let Body::Frame(fv) = &v.body else { continue };
        if fv.mode != FileMode::Rtu {
            continue;
        }
        if let Some(bytes) = fv.correct_bytes() {
            if bytes.len() >= 2 {
                out.push((v.id.clone(), bytes));
            }
        }
    }
    out
}

#[test]
fn the_corrected_listings_compute_crc16() {
    let Some((cc, dir, all)) = to_compile("run") else {
        return;
    };
    let frames = example_bodies();
    assert!(frames.len() >= 60, "{} RTU example frames", frames.len());
    let mut rng = Rng::new(0x7EC0_0510);
    let mut inputs: Vec<Vec<u8>> = frames
        .iter()
        .map(|(_, f)| f[..f.len() - 2].to_vec())
        .collect();
    let random_from = inputs.len();
    for len in 0..=300usize {
        for _ in 0..2 {
            inputs.push((0..len).map(|_| rng.byte()).collect());
        }
    }
    let stdin: String = inputs
        .iter()
        .map(|i| {
            let mut line: String = i.iter().map(|b| format!("{b:02X}")).collect();
            line.push('\n');
            line
        })
        .collect();
    for Printed { id, name, l, .. } in all {
        let source = format!("{}{}\n{MAIN}", l.typedefs(), l.corrected);
        let c = compile(&cc, &dir, &name, &source, true);
        assert!(c.ok, "{id}: the test program does not build:\n{}", c.stderr);
        let o = Run::program(dir.join(&name), [""; 0])
            .stdin(stdin.as_bytes())
            .timeout(TIMEOUT)
            .run();
        assert_eq!(o.code, Some(0), "{id}: the program failed: {o}");
        let got: Vec<u16> = o
            .stdout
            .lines()
            .map(|l| u16::from_str_radix(l, 16).expect("a CRC per line"))
            .collect();
        assert_eq!(got.len(), inputs.len(), "{id}: one CRC per input");
        for (k, ((frame_id, frame), crc)) in frames.iter().zip(&got).enumerate() {
            let body = &inputs[k];
            assert_eq!(*crc, crc16_reference(body), "{id} on {frame_id}");
            assert_eq!(*crc, crc16(body), "{id} on {frame_id}");
            // The frame's own CRC, low byte first, is what the listing computes.
            assert_eq!(
                frame[frame.len() - 2..],
                crc.to_le_bytes(),
                "{id} on {frame_id}"
            );
        }
        let mut truncated_differs = 0;
        for (input, crc) in inputs[random_from..].iter().zip(&got[random_from..]) {
            let n = input.len();
            if n <= 255 {
                assert_eq!(*crc, crc16_reference(input), "{id}, {n} random bytes");
                assert_eq!(*crc, crc16(input), "{id}, {n} random bytes");
            } else {
                // The length is a UBYTE: the program sees n mod 256 bytes.
                assert_eq!(*crc, crc16_reference(&input[..n % 256]), "{id}, {n} bytes");
                if *crc != crc16(input) {
                    truncated_differs += 1;
                }
            }
        }
        assert!(
            truncated_differs >= 80,
            "{id}: inputs over 255 bytes should mostly not get their own CRC ({truncated_differs} of 90 differ)"
        );
    }
}

/// The five documents print one program: after the OCR repairs, the listings differ only
/// in white space. (This needs no compiler.)
#[test]
fn every_document_prints_the_same_program() {
    let squeeze = |s: &str| -> String { s.chars().filter(|c| !c.is_whitespace()).collect() };
    let all = listings();
    let (first_id, _, first) = &all[0];
    let want = squeeze(&printed(first));
    for (id, _, l) in &all {
        let page = printed(l);
        assert_eq!(squeeze(&page), want, "{id} differs from {first_id}");
        assert_eq!(
            squeeze(&l.corrected),
            squeeze(&first.corrected),
            "{id} differs from {first_id}"
        );
        assert_eq!(l.repairs, first.repairs, "{id}: the same repairs");
    }
}
