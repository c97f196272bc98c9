#!/usr/bin/env bash
# #51: training placements spread over every angle (--placement spread, docs/twin.md
# "Sessions") against the quarter turns of --placement varied, on the 32-minute goal's
# recipe (cf4e1: IASTGCN with the force node, closed-loop data, a prediction every tick,
# 4 sessions), seeds 1-3 and the ensemble, scored on the same three held-out sessions;
# paired with cf4e1 (python3 docs/shift/paired.py docs/shift/cf4e1 docs/shift/cf4s).
# Why: with the quarter turns the Hilbert curve's and the raster's strokes run along two
# axes only, while every held-out placement is turned off that lattice; a probe (the
# 128-minute T-GCN of cf128e5, seed 1, on fresh 12-minute cold Hilbert runs) missed the
# roll by 7-8 mdeg once warm at the held-out turn of 53 degrees against 5 at 0 degrees
# (the test block: 4.2). Build iastgcn7 (0fe0739 plus --placement spread), checked to
# retrain cf4e1's seed 1 as the study's build did (run27chk.sh).
set -u
cd /work/main
BIN=out/shift/iastgcn7
OUT=out/shift/cf4s
CF="--config docs/scale/force128/config.toml --graph assets/graph-force.toml"
RECIPE="--sizes 32 --held-out-sessions 3 --placement spread --sessions 4 --closed-loop --every 1 --models iastgcn"
for seed in 1 2 3; do
  echo "=== $(date -u +%H:%M:%S) 32 min, spread placements, seed $seed"
  $BIN scale $RECIPE --seeds $seed $CF --out $OUT 2>&1 | grep -E "jobs done|rror" | tail -3
done
echo "=== $(date -u +%H:%M:%S) ensemble"
$BIN scale $RECIPE --seeds 1,2,3 $CF --ensemble --out $OUT 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) all done"
