#!/usr/bin/env python3
"""Reads run33.log (`iastgcn compensate` at eight random Hilbert turns, cf4e1chk's three
models then cf4s's three in each run) and pairs the share of the calibrated error
removed, spread minus quarter turns, by turn and seed (positive: spread removes more)."""
import statistics as st
import sys
from pathlib import Path

log = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).with_name("run33.log"))
turns, cur = [], None
for line in log.read_text().splitlines():
    p = line.split()
    if line.startswith("=== turn"):
        cur = {"turn": " ".join(p[2:]), "comp": []}
        turns.append(cur)
    elif len(p) > 4 and p[1] == "calibrated" and p[3] == "truth":
        cur["cal"] = (float(p[4]), float(p[7]))
    elif len(p) > 4 and p[1] == "compensated" and p[3] == "truth":
        cur["comp"].append((float(p[4]), float(p[7])))
diff, quarter, spread = ([], []), ([], []), ([], [])
for t in turns:
    if len(t["comp"]) != 6:
        continue
    rem = [tuple(100 * (1 - c[i] / t["cal"][i]) for i in (0, 1)) for c in t["comp"]]
    for s in range(3):
        for i in (0, 1):
            quarter[i].append(rem[s][i])
            spread[i].append(rem[3 + s][i])
            diff[i].append(rem[3 + s][i] - rem[s][i])
    print(f"turn {t['turn']:>14}: quarter turns {st.fmean(r[0] for r in rem[:3]):.1f} / "
          f"{st.fmean(r[1] for r in rem[:3]):.1f} %, spread {st.fmean(r[0] for r in rem[3:]):.1f}"
          f" / {st.fmean(r[1] for r in rem[3:]):.1f} %")
n = len(diff[0])
for i, what in enumerate(("position", "attitude")):
    m, sd = st.fmean(diff[i]), st.stdev(diff[i])
    verdict = "better" if m > sd else "worse" if -m > sd else "within"
    print(f"{what}: quarter turns {st.fmean(quarter[i]):.1f} ± {st.stdev(quarter[i]):.1f} %, "
          f"spread {st.fmean(spread[i]):.1f} ± {st.stdev(spread[i]):.1f} %, difference "
          f"{m:+.1f} ± {sd:.1f} over {n} pairs, spread ahead in {sum(d > 0 for d in diff[i])}: {verdict}")
