#!/usr/bin/env bash
# #51: the paths' order rotated from session to session (--path-order rotated,
# docs/twin.md "Sessions") against the fixed grid, fermat, hilbert, on the 32-minute
# goal's recipe (cf4e1: IASTGCN with the force node, closed-loop data, a prediction every
# tick, 4 sessions at varied placements), seeds 1-3 and the ensemble, scored on the same
# three held-out sessions; paired with cf4e1 (python3 docs/shift/paired.py
# docs/shift/cf4e1 docs/shift/cf4o). Why: in the fixed order the Hilbert curve always
# runs after two thirds of a session (16 minutes into it here), while the held-out
# sessions run it 4-10 minutes into theirs; a probe (the 128-minute T-GCN of cf128e5,
# seed 1, on a fresh cold 12-minute Hilbert run) missed the roll by 7.5-10 mdeg in the
# first two minutes against about 5 once warm. Build iastgcn8 (iastgcn7 plus
# --path-order; training untouched).
set -u
cd /work/main
BIN=out/shift/iastgcn8
OUT=out/shift/cf4o
CF="--config docs/scale/force128/config.toml --graph assets/graph-force.toml"
RECIPE="--sizes 32 --held-out-sessions 3 --placement varied --path-order rotated --sessions 4 --closed-loop --every 1 --models iastgcn"
for seed in 1 2 3; do
  echo "=== $(date -u +%H:%M:%S) 32 min, rotated path order, seed $seed"
  $BIN scale $RECIPE --seeds $seed $CF --out $OUT 2>&1 | grep -E "jobs done|rror" | tail -3
done
echo "=== $(date -u +%H:%M:%S) ensemble"
$BIN scale $RECIPE --seeds 1,2,3 $CF --ensemble --out $OUT 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) all done"
