#!/usr/bin/env python3
"""Tabulate criterion results, and compare them against a saved baseline.

    cargo bench -p conformance-benches -- --save-baseline main     # save a baseline
    cargo bench -p conformance-benches                              # later: a new run
    python3 benches/compare.py --baseline main                      # change per bench

Reads target/criterion/**/{new,<baseline>}/{estimates,benchmark}.json. Prints one row per
bench: mean time, throughput, and with --baseline the change of the mean; a slowdown over
the threshold (default 10%) is flagged REGRESSION and makes the exit code 1.
"""
import argparse
import json
import os
import sys


def load(root, which):
    out = {}
    for dirpath, _dirs, files in os.walk(root):
        if os.path.basename(dirpath) != which or "estimates.json" not in files:
            continue
        with open(os.path.join(dirpath, "benchmark.json")) as f:
            bench = json.load(f)
        with open(os.path.join(dirpath, "estimates.json")) as f:
            est = json.load(f)
        out[bench["full_id"]] = (est["mean"]["point_estimate"], bench.get("throughput"))
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


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--criterion-dir", default="target/criterion")
    ap.add_argument("--baseline", help="name given to --save-baseline")
    ap.add_argument("--threshold", type=float, default=10.0, help="regression threshold in percent")
    ap.add_argument("--filter", default="", help="only benches whose id contains this")
    ap.add_argument("--markdown", action="store_true", help="print a Markdown table")
    args = ap.parse_args()

    new = load(args.criterion_dir, "new")
    if not new:
        sys.exit(f"no criterion results under {args.criterion_dir}: run cargo bench first")
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
