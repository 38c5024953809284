#!/usr/bin/env python3
"""Runs the gate over every adapter in adapters/ and writes the findings table.

    python3 adapters/findings.py                 # build, run all six, write adapters/FINDINGS.md and the table in docs/src/gates.md
    python3 adapters/findings.py --count 300     # fewer differential cases (default: the gate's 1000)
    python3 adapters/findings.py --only libmodbus --no-write   # one adapter, print only
    python3 adapters/findings.py --reuse         # rewrite the tables from the last run's reports

Every adapter runs with the gate's default seed, so each reproducing command below
(`conformance gate --codec ... --only CASE`) finds the same case again. Deviations are
grouped by kind from the gate's own wording (see KINDS). Exit status: 0 when every adapter
completed (deviations are findings, not failures), 2 when one could not complete.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
from collections import OrderedDict

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TARGET = os.environ.get("CARGO_TARGET_DIR") or os.path.join(ROOT, "target")
SEED = "0x7ECC0"  # the gate's default

# name -> (language, adapter command as a reader types it from the top of the clone)
ADAPTERS = OrderedDict(
    [
        ("pymodbus", ("Python", "python3 adapters/pymodbus/adapter.py")),
        ("minimalmodbus", ("Python", "python3 adapters/minimalmodbus/adapter.py")),
        ("rmodbus", ("Rust", "target/release/rmodbus-adapter")),
        ("modbus-core", ("Rust", "target/release/modbus-core-adapter")),
        ("libmodbus", ("C", "python3 adapters/libmodbus/adapter.py")),
        ("jsmodbus", ("JavaScript", "node adapters/jsmodbus/adapter.js")),
    ]
)

# Kinds of deviation, in the order of the table; the first that matches a deviation wins.
KINDS = [
    ("panics or raises", lambda s, c: "raising an exception or panicking" in s),
    (
        "accepts a wrong checksum",
        lambda s, c: s.startswith("accepted a frame that must be rejected") and re.search(r"\b(CRC|LRC)\b", s.split(" and decoded")[0]),
    ),
    (
        "accepts a length that disagrees with the data",
        lambda s, c: s.startswith("accepted a frame that must be rejected"),
    ),
    ("rejects a valid frame", lambda s, c: s.startswith("rejected a valid frame") or "no \"accepted\"" in s),
    (
        "pads or truncates",
        lambda s, c: s.startswith("accepted the frame but decoded") and re.match(r"accepted the frame but decoded (values|data|byte_count|count) ", s),
    ),
    ("decodes a field differently", lambda s, c: s.startswith("accepted the frame but decoded")),
    ("encodes differently", lambda s, c: True),
]


def rel_target(cmd: str) -> str:
    """The command with target/ pointing at CARGO_TARGET_DIR, to run it."""
    if cmd.startswith("target/"):
        return os.path.join(TARGET, cmd[len("target/"):])
    return cmd


def conformance() -> str:
    return os.path.join(TARGET, "release", "conformance")


def build() -> None:
    subprocess.run(
        ["cargo", "build", "--release", "-q", "-p", "teco-modbus-conformance", "-p", "rmodbus-adapter", "-p", "modbus-core-adapter"],
        cwd=ROOT,
        check=True,
    )


def run_gate(name: str, cmd: str, count: int) -> dict:
    out = os.path.join(TARGET, "findings", f"{name}.json")
    os.makedirs(os.path.dirname(out), exist_ok=True)
    proc = subprocess.run(
        [conformance(), "gate", "--codec", rel_target(cmd), "--count", str(count), "--format", "json", "--quiet", "-o", out],
        cwd=ROOT,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        with open(out, encoding="utf-8") as f:
            report = json.load(f)
    except (OSError, ValueError):
        report = {}
    report["_exit"] = proc.returncode
    report["_stderr"] = proc.stderr[-2000:]
    return report


def kind_of(summary: str, check: dict) -> str:
    for kind, test in KINDS:
        if test(summary, check):
            return kind
    return KINDS[-1][0]


def shorten(text: str, n: int = 170) -> str:
    text = text.split("; reproduce:")[0]
    # Paths of the machine that ran it (crate registry, node_modules) say nothing to a reader.
    text = re.sub(r"(?<![\w.-])/[^\s\"()]*/(?=[\w.-]+\.(?:js|rs|py):\d)", "", text)
    return text if len(text) <= n else text[: n - 1] + "…"


def function_of(check: dict) -> str:
    """The function code of the frame a decode case sent ("" for other cases)."""
    try:
        frame = [int(b, 16) for b in check["exchanges"][0]["request"].split()]
        title = check.get("title", "")
        if " ascii " in title or "(ascii " in title or ".ascii." in check.get("id", ""):
            function = int(bytes(frame[3:5]).decode("ascii"), 16)
        else:
            function = frame[1]
        # Exception responses are one form whatever function they answer.
        return "exception" if function & 0x80 else f"{function:02X}"
    except (KeyError, IndexError, ValueError, UnicodeDecodeError, AttributeError):
        return ""


def form_of(check: dict) -> str:
    """A deviation's wording with its particulars (bytes, numbers, decoded JSON) taken out,
    and the frame's function code: cases of one form are one finding."""
    summary = check.get("summary", "")
    text = summary.split("; reproduce:")[0].split(" and decoded it as")[0]
    text = re.sub(r"\{.*\}", "{}", text)
    text = re.sub(r"b(['\"]).*?\1", "b''", text)
    text = re.sub(r"\b[0-9A-Fa-f]{2}( [0-9A-Fa-f]{2})+\b", "<bytes>", text)
    text = re.sub(r"\b[0-9A-Fa-f]{2,4}H?\b|\d+", "#", text)
    return function_of(check) + " " + text[:120]


MAX_FORMS = 6


def analyse(name: str, cmd: str, count: int, report: dict) -> dict:
    groups: "OrderedDict[str, list]" = OrderedDict((k, []) for k, _ in KINDS)
    for c in report.get("checks", []):
        if c.get("status") == "deviation":
            groups[kind_of(c.get("summary", ""), c)].append(c)
    codec = report.get("codec") or {}
    count_opt = "" if count == 1000 else f" --count {count}"
    return {
        "name": name,
        "version": codec.get("version", "?"),
        "supports": " ".join(codec.get("supports", [])),
        "summary": report.get("summary", {}),
        "complete": report.get("complete", False) and report["_exit"] in (0, 1),
        "exit": report["_exit"],
        "stderr": report.get("_stderr", ""),
        "groups": groups,
        "repro": lambda case_id: f"conformance gate --codec \"{cmd}\"{count_opt} --only '{case_id}'",
    }


def markdown(results: list, count: int) -> tuple[str, str]:
    """(the summary table, the whole FINDINGS.md)."""
    kinds = [k for k, _ in KINDS]
    head = "| implementation | language | version | supports | pass | deviations | skipped | errors | " + " | ".join(kinds) + " |"
    rule = "|" + "---|" * (8 + len(kinds))
    rows = [head, rule]
    for r in results:
        s = r["summary"]
        lang = ADAPTERS[r["name"]][0]
        cells = [
            f"[{r['name']}](#{r['name']})",
            lang,
            r["version"],
            r["supports"].replace(" ", ", "),
            str(s.get("pass", "?")),
            str(s.get("deviation", "?")),
            str(s.get("skip", "?")),
            str(s.get("error", "?")) + ("" if r["complete"] else " (incomplete)"),
        ] + [str(len(r["groups"][k])) for k in kinds]
        rows.append("| " + " | ".join(cells) + " |")
    table = "\n".join(rows)
    lines = [
        "# What the gate finds in other Modbus implementations",
        "",
        "Generated by `python3 adapters/findings.py` (do not edit by hand): every adapter in",
        f"`adapters/` through `conformance gate` with the golden vectors and {count} differential",
        f"cases from the default seed {SEED}. A deviation is a case where the implementation",
        "did not do what this suite's codec and the manuals say; each kind below names one",
        "case and the command that runs it again (from the top of the clone, after",
        "`cargo build --release -p teco-modbus-conformance -p rmodbus-adapter -p modbus-core-adapter`",
        "and the installs in `.ci/run`). What each adapter can and cannot express, and why its",
        "skips are skips, is in its README (`adapters/<name>/README.md`).",
        "",
        table,
        "",
    ]
    for r in results:
        lines += [f"## {r['name']}", ""]
        s = r["summary"]
        lines.append(
            f"{r['name']} {r['version']} ({ADAPTERS[r['name']][0]}; adapter `{ADAPTERS[r['name']][1]}`): "
            f"{s.get('total', '?')} cases, {s.get('pass', '?')} pass, {s.get('deviation', '?')} deviations, "
            f"{s.get('skip', '?')} skipped, {s.get('error', '?')} errors"
            + ("." if r["complete"] else f"; the run did not complete (exit {r['exit']})."),
        )
        lines.append("")
        if not any(r["groups"].values()):
            lines += ["No deviation.", ""]
            continue
        lines += ["| kind | cases | one of them | reproduce |", "|---|---|---|---|"]
        for kind, cases in r["groups"].items():
            if not cases:
                continue
            forms: "OrderedDict[str, list]" = OrderedDict()
            for c in cases:
                forms.setdefault(form_of(c), []).append(c)
            ranked = sorted(forms.values(), key=len, reverse=True)
            for n, group in enumerate(ranked[:MAX_FORMS]):
                first = group[0]
                detail = shorten(first.get("summary", "")).replace("|", "\\|")
                label = f"{kind} ({len(cases)})" if n == 0 else "″"
                lines.append(f"| {label} | {len(group)} | `{first['id']}`: {detail} | `{r['repro'](first['id'])}` |")
            rest = ranked[MAX_FORMS:]
            if rest:
                lines.append(f"| ″ | {sum(len(g) for g in rest)} | {len(rest)} other forms: see the gate's report | |")
        lines.append("")
    return table, "\n".join(lines)


def write_guide_table(table: str) -> None:
    path = os.path.join(ROOT, "docs", "src", "gates.md")
    with open(path, encoding="utf-8") as f:
        text = f.read()
    start, end = "<!-- findings:start -->", "<!-- findings:end -->"
    i, j = text.find(start), text.find(end)
    if i < 0 or j < i:
        sys.exit(f"docs/src/gates.md has no {start} ... {end} block to fill")
    # The rows link to their sections, which are in FINDINGS.md.
    table = table.replace("](#", "](../../adapters/FINDINGS.md#")
    text = text[: i + len(start)] + "\n" + table + "\n" + text[j:]
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--count", type=int, default=1000, help="differential cases per adapter (default 1000)")
    ap.add_argument("--only", action="append", choices=list(ADAPTERS), help="run only this adapter (repeatable)")
    ap.add_argument("--no-build", action="store_true", help="use the binaries already in target/release")
    ap.add_argument("--no-write", action="store_true", help="print the table; write no file")
    ap.add_argument(
        "--reuse",
        action="store_true",
        help="write the tables from the last run's reports (target/findings/*.json) without running the gate",
    )
    args = ap.parse_args()
    if not args.no_build and not args.reuse:
        build()
    results = []
    incomplete = False
    for name, (_, cmd) in ADAPTERS.items():
        if args.only and name not in args.only:
            continue
        if args.reuse:
            with open(os.path.join(TARGET, "findings", f"{name}.json"), encoding="utf-8") as f:
                report = json.load(f)
            report["_exit"] = 1 if report.get("summary", {}).get("deviation") else 0
            report["_exit"] = report["_exit"] if report.get("complete") else 2
            args.count = (report.get("codec") or {}).get("count", args.count)
        else:
            report = run_gate(name, cmd, args.count)
        r = analyse(name, cmd, args.count, report)
        s = r["summary"]
        print(
            f"{name:14} {r['version']:10} pass {s.get('pass', '?'):>4}  deviations {s.get('deviation', '?'):>4}  "
            f"skipped {s.get('skip', '?'):>4}  errors {s.get('error', '?'):>3}  exit {r['exit']}",
            flush=True,
        )
        if r["exit"] >= 2 or not r["complete"]:
            incomplete = True
            sys.stderr.write(f"{name}: the gate could not complete (exit {r['exit']})\n{r['stderr']}\n")
        results.append(r)
    table, doc = markdown(results, args.count)
    if args.no_write or args.only:
        print(table)
    else:
        with open(os.path.join(ROOT, "adapters", "FINDINGS.md"), "w", encoding="utf-8") as f:
            f.write(doc)
        write_guide_table(table)
        print("wrote adapters/FINDINGS.md and the table in docs/src/gates.md")
    return 2 if incomplete else 0


if __name__ == "__main__":
    sys.exit(main())
