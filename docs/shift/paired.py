#!/usr/bin/env python3
"""Paired comparison of `iastgcn scale` folders (issue 51's levers, docs/results.md
"Training on what use looks like"): for each model in two folders, the share of the
calibrated error removed on every held-out path, paired by training seed and held-out
session. "better"/"worse" when the mean paired difference exceeds the SD of the paired
differences (the demo's rule), else "within". Also the diagnosis columns per folder.

    python3 docs/shift/paired.py docs/shift/s1 docs/shift/s4 [model [model_b]] [--sessions=1,2,3]

With a second model, the first folder's `model` is compared with the second folder's
`model_b` (the same folder twice compares two models on the same data). A seed ensemble
(`<model>-ensemble`, `scale --ensemble`, recorded as seed 0) is paired with each seed of
the other side on the same held-out session. `--sessions=` keeps only the held-out
sessions listed (from 1), e.g. to leave out a folder's validation session.
"""
import statistics
import sys
import tomllib
from pathlib import Path

PATHS = ["grid", "fermat", "hilbert", "rosette"]


def records(folder, model):
    out = {}
    for f in sorted(Path(folder, "models").glob("*.job.toml")):
        r = tomllib.loads(f.read_text())
        if r["model"] != model:
            continue
        for p in r["paths"]:
            cal, comp = p["calibrated"], p["compensated"]
            removed = [100 * (cal[i] - comp[i]) / cal[i] for i in (0, 1)]
            out[(r["seed"], p.get("session", 0), p["path"])] = (removed, p)
    return out


def spread(v):
    m = statistics.fmean(v)
    return m, (statistics.stdev(v) if len(v) > 1 else float("nan"))


def main():
    only = [a.split("=", 1)[1] for a in sys.argv[1:] if a.startswith("--sessions=")]
    args = [a for a in sys.argv[1:] if not a.startswith("--sessions=")]
    a, b = args[0], args[1]
    model = args[2] if len(args) > 2 else "iastgcn"
    model_b = args[3] if len(args) > 3 else model
    ra, rb = records(a, model), records(b, model_b)
    if only:
        keep = {int(k) - 1 for k in only[0].split(",")}
        ra = {k: v for k, v in ra.items() if k[1] in keep}
        rb = {k: v for k, v in rb.items() if k[1] in keep}
    # An ensemble (seed 0) stands beside every seed of the other side, session by session.
    for one, other in ((ra, rb), (rb, ra)):
        if one and all(k[0] == 0 for k in one) and not all(k[0] == 0 for k in other):
            spread_over = {k[0] for k in other}
            for k in list(one):
                for seed in spread_over:
                    one[(seed, k[1], k[2])] = one[k]
                del one[k]
    keys = sorted(set(ra) & set(rb))
    seeds = sorted({k[0] for k in keys})
    sessions = sorted({k[1] for k in keys})
    print(f"{b} {model_b} minus {a} {model}, paired over seeds {seeds} x held-out sessions "
          f"{[s + 1 for s in sessions]}")
    print("| path | " + a + " pos / att (%) | " + b + " pos / att (%) | difference pos | "
          "difference att | verdict pos / att |")
    print("|---|---:|---:|---:|---:|---|")
    for path in PATHS:
        ks = [k for k in keys if k[2] == path]
        if not ks:
            continue
        cells = []
        for i in (0, 1):
            xa = [ra[k][0][i] for k in ks]
            xb = [rb[k][0][i] for k in ks]
            d = [y - x for x, y in zip(xa, xb)]
            cells.append((spread(xa), spread(xb), spread(d)))
        def verdict(c):
            m, sd = c[2]
            return "better" if m > sd else "worse" if -m > sd else "within"
        print(f"| {path} | {cells[0][0][0]:.1f} ± {cells[0][0][1]:.1f} / "
              f"{cells[1][0][0]:.1f} ± {cells[1][0][1]:.1f} | "
              f"{cells[0][1][0]:.1f} ± {cells[0][1][1]:.1f} / "
              f"{cells[1][1][0]:.1f} ± {cells[1][1][1]:.1f} | "
              f"{cells[0][2][0]:+.1f} ± {cells[0][2][1]:.1f} | "
              f"{cells[1][2][0]:+.1f} ± {cells[1][2][1]:.1f} | "
              f"{verdict(cells[0])} / {verdict(cells[1])} |")


if __name__ == "__main__":
    main()
