#!/usr/bin/env python3
"""The recommendation rule of `experiment::recommend` (docs/usage.md "Recommended model")
applied to an `iastgcn scale` folder scored on one more held-out session than its
tables use (issue 51: the model is chosen on a validation session that is not the
test data). For every model in the folder (its seeds grouped; a seed ensemble,
`<model>-ensemble`, is a model of its own), the share of the calibrated error removed on
the validation session, position and attitude, each the mean over the session's paths
and the model's seeds; the model with the highest mean of the two is recommended.

    python3 docs/shift/recommend.py docs/shift/cf128e1v [validation_session]

The validation session is given from 1 (default: the last one the records hold); the
test figures (mean ± SD over seeds and the other sessions, Hilbert) are printed beside.
"""
import statistics
import sys
import tomllib
from pathlib import Path


def main():
    folder = Path(sys.argv[1])
    rows = {}
    for f in sorted((folder / "models").glob("*.job.toml")):
        r = tomllib.loads(f.read_text())
        model = r["model"]
        for p in r["paths"]:
            cal, comp = p["calibrated"], p["compensated"]
            removed = [100 * (cal[i] - comp[i]) / cal[i] for i in (0, 1)]
            rows.setdefault(model, []).append((r["seed"], p.get("session", 0), p["path"], removed))
    if not rows:
        sys.exit(f"{folder}: no job records")
    last = max(s for v in rows.values() for (_, s, _, _) in v)
    validation = int(sys.argv[2]) - 1 if len(sys.argv) > 2 else last
    print(f"{folder}: validation session {validation + 1}; test sessions the others")
    print("| model | seeds | validation pos / att (%) | score | test Hilbert pos / att (%) |")
    print("|---|---:|---:|---:|---:|")
    scores = []
    for model, v in sorted(rows.items()):
        val = [x for x in v if x[1] == validation]
        if not val:
            continue
        pos = statistics.fmean(x[3][0] for x in val)
        att = statistics.fmean(x[3][1] for x in val)
        test = [x[3] for x in v if x[1] != validation and x[2] == "hilbert"]
        cell = "n/a"
        if len(test) > 1:
            tp = [t[0] for t in test]
            ta = [t[1] for t in test]
            cell = (f"{statistics.fmean(tp):.1f} ± {statistics.stdev(tp):.1f} / "
                    f"{statistics.fmean(ta):.1f} ± {statistics.stdev(ta):.1f}")
        seeds = len({x[0] for x in val})
        scores.append((0.5 * (pos + att), model))
        print(f"| {model} | {seeds} | {pos:.1f} / {att:.1f} | {0.5 * (pos + att):.2f} | {cell} |")
    best = max(scores)
    singles = [s for s in scores if not s[1].endswith("-ensemble")]
    print(f"\nRecommended: {best[1]} (score {best[0]:.2f})")
    if singles and max(singles) != best:
        print(f"Recommended among single models: {max(singles)[1]} (score {max(singles)[0]:.2f})")


if __name__ == "__main__":
    main()
