#!/usr/bin/env python3
"""Paired comparison of two demo report folders' Table V (docs/results.md "Look-ahead").

Usage: compare.py BASELINE_REPORT LOOK_AHEAD_REPORT > comparison.md

Each folder's table_v.csv has one row per path, held-out session and model seed. The
share of the calibrated error removed (against hidden truth) is computed per run, both
folders' runs are paired on (path, session, seed) and the table gives, per path and
model, the mean ± sample SD of each and of the paired difference, and how many pairs the
second folder wins. Only the standard library.
"""

import csv
import statistics
import sys


def runs(folder):
    calibrated, compensated = {}, {}
    with open(f"{folder}/table_v.csv", newline="") as f:
        for r in csv.DictReader(f):
            key = (r["trajectory"], r["held_out_session"])
            errors = (float(r["true_pos_mean_um"]), float(r["true_att_mean_mdeg"]))
            if r["stage"] == "calibrated":
                calibrated[key] = errors
            elif r["stage"] == "compensated":
                model, _, seed = r["model"].rpartition(".seed")
                compensated[(key, model, seed)] = errors
    return {
        k: tuple(100.0 * (1.0 - e / c) for e, c in zip(errors, calibrated[k[0]]))
        for k, errors in compensated.items()
    }


def cell(values):
    sd = statistics.stdev(values) if len(values) > 1 else 0.0
    return f"{statistics.mean(values):.1f} ± {sd:.1f}"


def main():
    base, ahead = runs(sys.argv[1]), runs(sys.argv[2])
    paths = sorted({k[0][0] for k in base}, key=["grid", "fermat", "hilbert", "rosette"].index)
    models = sorted({k[1] for k in base})
    print("| path | model | pairs | position: before | look-ahead | paired gain | wins "
          "| attitude: before | look-ahead | paired gain | wins |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for model in models:
        for path in paths + ["all four"]:
            keys = sorted(
                k for k in base
                if k[1] == model and (path == "all four" or k[0][0] == path) and k in ahead
            )
            if path == "all four":
                # One value per (session, seed): the mean over the four paths.
                groups = sorted({(k[0][1], k[2]) for k in keys})
                pick = lambda d, q, g: statistics.mean(
                    d[k][q] for k in keys if (k[0][1], k[2]) == g
                )
                cols = []
                for q in (0, 1):
                    b = [pick(base, q, g) for g in groups]
                    a = [pick(ahead, q, g) for g in groups]
                    cols.append((b, a))
                n = len(groups)
            else:
                cols = [([base[k][q] for k in keys], [ahead[k][q] for k in keys]) for q in (0, 1)]
                n = len(keys)
            row = [path, model, str(n)]
            for b, a in cols:
                diff = [x - y for x, y in zip(a, b)]
                row += [cell(b), cell(a), cell(diff), f"{sum(d > 0 for d in diff)}/{n}"]
            print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
