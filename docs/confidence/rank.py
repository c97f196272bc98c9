#!/usr/bin/env python3
"""What could rank the misses (issue 73 item 2; docs/results.md "Confidence"): reads the
`ticks.csv` of `iastgcn confidence` (one row per open-loop prediction: its miss, its
members' spread and the correction's size) and writes, per model and quantity:

- how much of the misses' variance lies between the held-out runs (session x path), and
  how much of that between sessions and between paths alone;
- the misses' autocorrelation within a run at 1, 50 and 250 ticks (the demo's tick is
  20 ms);
- Spearman's rank correlation of the miss with the spread and with the size, and the
  mean miss where each is in its widest tenth against the rest;
- the coverage of a 90 % constant radius calibrated on the validation session (the last)
  pooled over its four paths, against one calibrated per path on that session's run of
  the path alone.

    python3 docs/confidence/rank.py TICKS.csv > docs/confidence/rank.md
"""
import csv
import math
import statistics as st
import sys
from collections import defaultdict

PATHS = ["grid", "fermat", "hilbert", "rosette"]
QUANTITIES = [("position", "um", "µm"), ("attitude", "mdeg", "mdeg")]


def quantile(values, level):
    v = sorted(values)
    return v[min(len(v) - 1, math.ceil(level * len(v)) - 1)]


def ranks(x):
    order = sorted(range(len(x)), key=lambda i: x[i])
    r = [0.0] * len(x)
    for k, i in enumerate(order):
        r[i] = float(k)
    return r


def spearman(a, b):
    ra, rb = ranks(a), ranks(b)
    ma, mb = st.fmean(ra), st.fmean(rb)
    num = sum((x - ma) * (y - mb) for x, y in zip(ra, rb))
    den = math.sqrt(sum((x - ma) ** 2 for x in ra) * sum((y - mb) ** 2 for y in rb))
    return num / den


def between_share(groups, mean, total):
    return 100 * sum(len(v) * (st.fmean(v) - mean) ** 2 for v in groups.values()) / total


def autocorrelation(runs, lag):
    num = den = 0.0
    for xs in runs.values():
        mu = st.fmean(xs)
        num += sum((xs[i] - mu) * (xs[i + lag] - mu) for i in range(len(xs) - lag))
        den += sum((x - mu) ** 2 for x in xs)
    return num / den


def widest_tenth(miss, x):
    cut = quantile(x, 0.9)
    top = [m for m, v in zip(miss, x) if v >= cut]
    rest = [m for m, v in zip(miss, x) if v < cut]
    return st.fmean(top), st.fmean(rest)


def coverage(values, radius):
    return 100 * sum(v <= radius for v in values) / len(values)


def main(path):
    rows = list(csv.DictReader(open(path)))
    models = list(dict.fromkeys(r["model"] for r in rows))
    validation = max(r["session"] for r in rows)
    print("# What could rank the misses\n")
    print(f"From `{path}` (docs/confidence/rank.py); session {validation} is the "
          "validation session, the others are scored. Every prediction of every run.\n")
    print("| model | quantity | between runs % | sessions % | paths % | autocorrelation "
          "1 / 50 / 250 ticks | ρ(miss, spread) | ρ(miss, size) | widest tenth of the "
          "spread: miss there / elsewhere | of the size |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for model in models:
        rs = [r for r in rows if r["model"] == model]
        for name, unit, shown in QUANTITIES:
            miss = [float(r[f"miss_{unit}"]) for r in rs]
            spread = [float(r[f"spread_{unit}"]) for r in rs]
            size = [float(r[f"size_{unit}"]) for r in rs]
            mean = st.fmean(miss)
            total = sum((m - mean) ** 2 for m in miss)
            runs, sessions, paths = defaultdict(list), defaultdict(list), defaultdict(list)
            for r, m in zip(rs, miss):
                runs[(r["session"], r["path"])].append(m)
                sessions[r["session"]].append(m)
                paths[r["path"]].append(m)
            ac = " / ".join(f"{autocorrelation(runs, lag):.2f}" for lag in (1, 50, 250))
            ts, es = widest_tenth(miss, spread)
            tz, ez = widest_tenth(miss, size)
            print(f"| {model} | {name} | {between_share(runs, mean, total):.0f} | "
                  f"{between_share(sessions, mean, total):.0f} | "
                  f"{between_share(paths, mean, total):.0f} | {ac} | "
                  f"{spearman(miss, spread):+.2f} | {spearman(miss, size):+.2f} | "
                  f"{ts:.1f} / {es:.1f} {shown} | {tz:.1f} / {ez:.1f} {shown} |")
    print("\nCoverage of a 90 % constant radius on the scored sessions, per path, mean ± "
          "population SD over them: calibrated on the whole validation session (pooled, what "
          "`confidence` does) or on its run of that path alone (per path).\n")
    print("| model | quantity | path | pooled radius | coverage | per-path radius | coverage |")
    print("|---|---|---|---|---|---|---|")
    for model in models:
        rs = [r for r in rows if r["model"] == model]
        for name, unit, shown in QUANTITIES:
            key = f"miss_{unit}"
            pooled = quantile([float(r[key]) for r in rs if r["session"] == validation], 0.9)
            scored = sorted({r["session"] for r in rs} - {validation})
            for p in PATHS:
                own = quantile([float(r[key]) for r in rs
                                if r["session"] == validation and r["path"] == p], 0.9)
                cells = []
                for radius in (pooled, own):
                    c = [coverage([float(r[key]) for r in rs
                                   if r["session"] == s and r["path"] == p], radius)
                         for s in scored]
                    sd = st.pstdev(c)
                    cells.append(f"{radius:.1f} {shown} | {st.fmean(c):.1f} ± {sd:.1f}")
                print(f"| {model} | {name} | {p} | {cells[0]} | {cells[1]} |")


if __name__ == "__main__":
    main(sys.argv[1])
