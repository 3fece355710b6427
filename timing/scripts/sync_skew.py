#!/usr/bin/env python3
"""SYNC skew between buses, from a `coordinator run --capture DIR` of several buses.

Usage: sync_skew.py DIR/BUS1.log DIR/BUS2.log [...] [--csv OUT.csv]

Every cycle the coordinator sends SYNC (080h) on each bus, first thing, back to back. This
pairs the k-th SYNC of every bus and reports, per cycle, the spread of their timestamps (the
latest minus the earliest): median, p99, p99.9 and max in microseconds. With --csv, the raw
per-cycle spread is written for plots.
"""
import re
import sys


def syncs(path):
    out = []
    with open(path) as f:
        for line in f:
            m = re.match(r"\((\d+)\.(\d+)\) \S+ 080#", line)
            if m:
                out.append(int(m.group(1)) * 1_000_000 + int(m.group(2)))
    return out


def quantile(xs, q):
    return xs[min(len(xs) - 1, int(q * len(xs)))]


def main():
    args = sys.argv[1:]
    csv = None
    if "--csv" in args:
        i = args.index("--csv")
        csv = args[i + 1]
        del args[i : i + 2]
    if len(args) < 2:
        sys.exit(__doc__)
    buses = [syncs(p) for p in args]
    n = min(len(b) for b in buses)
    if n == 0:
        sys.exit("no SYNC in one of the logs")
    spread = [max(b[k] for b in buses) - min(b[k] for b in buses) for k in range(n)]
    s = sorted(spread)
    print(
        f"{len(args)} buses, {n} cycles: SYNC skew median {quantile(s, 0.5)} us, "
        f"p99 {quantile(s, 0.99)} us, p99.9 {quantile(s, 0.999)} us, max {s[-1]} us"
    )
    if csv:
        with open(csv, "w") as f:
            f.write("cycle,skew_us\n")
            for k, v in enumerate(spread):
                f.write(f"{k},{v}\n")


if __name__ == "__main__":
    main()
