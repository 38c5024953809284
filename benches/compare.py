#!/usr/bin/env python3
"""Tabulate criterion results, and compare them against a saved baseline.

    cargo bench -p conformance-benches -- --save-baseline main     # save a baseline
    cargo bench -p conformance-benches                              # later: a new run
    python3 benches/compare.py --baseline main                      # change per bench

Reads target/criterion/**/{new,<baseline>}/{estimates,benchmark}.json. Prints one row per
bench: mean time, throughput, and with --baseline the change of the mean; a slowdown over
the threshold (default 10%) is flagged REGRESSION and makes the exit code 1.

--peers prints the comparisons of issues 17 and 39 from the latest run instead: CRC-16 per
size (ours, with the path the dispatcher took, and each path forced, against crc-fast,
crc Table<16> and crc16) and checked decode of the F510 03H request and response (ours
RTU and ASCII against modbus-core and rmodbus), as ratios. The path is the one the bench
asked of the dispatcher (bench id crc16/ours/SIZE:PATH), never inferred from the size.
--crossover prints crc16-crossover/*: every path forced at the sizes around the
dispatcher's thresholds, the fastest marked, from which each tier's thresholds are chosen.
--stat median uses criterion's median instead of the mean (steadier on a shared machine).
"""
import argparse
import json
import os
import sys


STAT = "mean"


def load(root, which):
    out = {}
    for dirpath, _dirs, files in os.walk(root):
        if os.path.basename(dirpath) != which or not {"estimates.json", "benchmark.json"} <= set(files):
            continue
        with open(os.path.join(dirpath, "benchmark.json")) as f:
            bench = json.load(f)
        with open(os.path.join(dirpath, "estimates.json")) as f:
            est = json.load(f)
        out[bench["full_id"]] = (est[STAT]["point_estimate"], bench.get("throughput"))
    return out


def fmt_time(ns):
    for unit, scale in (("s", 1e9), ("ms", 1e6), ("us", 1e3)):
        if ns >= scale:
            return f"{ns / scale:.3g} {unit}"
    return f"{ns:.3g} ns"


def fmt_thrpt(ns, thr):
    if not thr:
        return ""
    if "Bytes" in thr:
        gbps = thr["Bytes"] / ns  # bytes per ns = GB/s
        return f"{gbps:.3g} GB/s" if gbps >= 1 else f"{gbps * 1000:.3g} MB/s"
    if "Elements" in thr:
        per_s = thr["Elements"] / ns * 1e9
        return f"{per_s / 1e6:.3g} M/s"
    return ""


def table_printer(markdown):
    def row(cells):
        if markdown:
            print("| " + " | ".join(cells) + " |")
        else:
            print("  ".join(c.ljust(12) for c in cells).rstrip())

    def head(cells):
        row(cells)
        if markdown:
            print("|" + "---|" * len(cells))

    return row, head


# The CRC paths, narrowest first (CrcPath::ALL).
CRC_PATHS = ["table", "pclmul", "avx2", "avx512"]


def ours_crc(new):
    """{size: (time, path)} of crc16/ours/SIZE:PATH, the path named by the bench."""
    out = {}
    for bid, (ns, _thr) in new.items():
        if not bid.startswith("crc16/ours/"):
            continue
        size, _, path = bid.rsplit("/", 1)[1].partition(":")
        out[int(size)] = (ns, path or "?")
    return out


def peers(new, markdown):
    """Ratios of the issue-17 and issue-39 goals; a ratio > 1 means ours is faster."""
    row, head = table_printer(markdown)
    ours = ours_crc(new)
    forced = [p for p in CRC_PATHS if any(b.startswith(f"crc16/ours-{p}/") for b in new)]
    peers_crc = ["crc-fast", "crc-table16", "crc16-crate"]
    head(["size", "path ran", "ours"] + [f"ours-{p}" for p in forced] + peers_crc
         + ["vs crc-fast", "vs Table<16>", "vs crc16"])
    for size in sorted(ours):
        t, path = ours[size]
        times = [new.get(f"crc16/{p}/{size}", (None,))[0] for p in peers_crc]
        cells = [fmt_size(size), path, fmt_time(t)]
        for p in forced:
            x = new.get(f"crc16/ours-{p}/{size}")
            cells.append(fmt_time(x[0]) if x else "-")
        cells += [fmt_time(x) if x else "-" for x in times]
        cells += [f"{x / t:.2f}x" if x else "-" for x in times]
        row(cells)
    print()
    head(["message", "ours RTU", "ours ASCII", "modbus-core", "rmodbus", "vs modbus-core", "ASCII/RTU"])
    for group in sorted({b.rsplit("/", 1)[0] for b in new if b.startswith("peers/")}):
        t = {k: new.get(f"{group}/{k}", (None,))[0] for k in ("ours", "ours-ascii", "modbus-core", "rmodbus")}
        if not t["ours"]:
            continue
        row([group.split("/", 1)[1]] + [fmt_time(v) if v else "-" for v in t.values()] + [
            f"{t['modbus-core'] / t['ours']:.2f}x" if t["modbus-core"] else "-",
            f"{t['ours-ascii'] / t['ours']:.2f}x" if t["ours-ascii"] else "-",
        ])


def crossover(new, markdown):
    """crc16-crossover/PATH/SIZE: each forced path per size, the fastest starred."""
    row, head = table_printer(markdown)
    runs = {}
    for bid, (ns, _thr) in new.items():
        parts = bid.split("/")
        if len(parts) == 3 and parts[0] == "crc16-crossover":
            runs.setdefault(int(parts[2]), {})[parts[1]] = ns
    if not runs:
        sys.exit("no crc16-crossover results: run the crc bench with the filter crc16-crossover")
    paths = [p for p in CRC_PATHS if any(p in r for r in runs.values())]
    head(["size"] + paths + ["fastest"])
    for size in sorted(runs):
        r = runs[size]
        best = min(r, key=r.get)
        cells = [fmt_size(size)]
        cells += [("*" if p == best else "") + fmt_time(r[p]) if p in r else "-" for p in paths]
        row(cells + [best])


def fmt_size(n):
    return f"{n // 1024} KiB" if n >= 1024 and n % 1024 == 0 else f"{n} B"


def main():
    global STAT
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--criterion-dir",
        default=None,
        help="default: target/criterion, else benches/target/criterion (where criterion "
        "writes when CARGO_TARGET_DIR is a relative path: cargo bench runs in benches/)",
    )
    ap.add_argument("--baseline", help="name given to --save-baseline")
    ap.add_argument("--threshold", type=float, default=10.0, help="regression threshold in percent")
    ap.add_argument("--filter", default="", help="only benches whose id contains this")
    ap.add_argument("--markdown", action="store_true", help="print a Markdown table")
    ap.add_argument("--peers", action="store_true", help="print the issue-17/39 comparisons with ratios")
    ap.add_argument("--crossover", action="store_true", help="print the CRC paths forced around the thresholds")
    ap.add_argument("--stat", choices=["mean", "median"], default="mean", help="criterion estimate to use")
    args = ap.parse_args()
    STAT = args.stat

    if args.criterion_dir is None:
        here = os.path.dirname(os.path.abspath(__file__))
        candidates = ["target/criterion", os.path.join(here, "target", "criterion")]
        args.criterion_dir = next((c for c in candidates if os.path.isdir(c)), candidates[0])
    new = load(args.criterion_dir, "new")
    if not new:
        sys.exit(f"no criterion results under {args.criterion_dir}: run cargo bench first")
    if args.peers:
        peers(new, args.markdown)
        return
    if args.crossover:
        crossover(new, args.markdown)
        return
    base = load(args.criterion_dir, args.baseline) if args.baseline else {}
    if args.baseline and not base:
        sys.exit(f"no baseline named {args.baseline!r} under {args.criterion_dir}")

    rows = []
    regressions = 0
    for bid in sorted(new):
        if args.filter not in bid:
            continue
        ns, thr = new[bid]
        row = [bid, fmt_time(ns), fmt_thrpt(ns, thr)]
        if args.baseline:
            if bid in base:
                change = (ns / base[bid][0] - 1) * 100
                flag = "REGRESSION" if change > args.threshold else ("faster" if change < -args.threshold else "")
                regressions += flag == "REGRESSION"
                row += [f"{change:+.1f}%", flag]
            else:
                row += ["new", ""]
        rows.append(row)

    head = ["bench", "mean", "throughput"] + (["change", ""] if args.baseline else [])
    if args.markdown:
        print("| " + " | ".join(head) + " |")
        print("|" + "---|" * len(head))
        for r in rows:
            print("| " + " | ".join(r) + " |")
    else:
        widths = [max(len(str(r[i])) for r in rows + [head]) for i in range(len(head))]
        for r in [head] + rows:
            print("  ".join(str(c).ljust(w) for c, w in zip(r, widths)).rstrip())
    if args.baseline:
        print(f"\n{regressions} regression(s) over {args.threshold:g}% against baseline {args.baseline!r}")
    sys.exit(1 if regressions else 0)


if __name__ == "__main__":
    main()
