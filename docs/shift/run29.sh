#!/usr/bin/env bash
# #51: spread placements at 128 minutes per path. cf128e5's recipe (IASTGCN and T-GCN, the
# force node, closed-loop data, a prediction every tick, 4 sessions) with --placement
# spread instead of varied, seeds 1-3 and each model's ensemble,
# scored on the study's three held-out sessions and the validation session
# (--held-out-sessions 4, the fourth read as the validation session as in cf128e5);
# paired with cf128e5 (the same seeds on quarter turns). Build iastgcn6s: the study's
# build 2b59e15 with the spread and path-order commit (ea132f6) applied, so that training
# and the predictor are the study's bit for bit (its predictions on a Hilbert recording
# match iastgcn6's byte for byte; the later build's do not) and cf128e5 is the control.
# Every job resumes from its state files when the script is run again.
set -u
cd /work/main
BIN=out/shift/iastgcn6s
OUT=out/shift/cf128sp
CF="--config docs/scale/force128/config.toml --graph assets/graph-force.toml"
RECIPE="--sizes 128 --placement spread --sessions 4 --closed-loop --every 1 --held-out-sessions 4"
# IASTGCN's seeds first (a job takes half as long as T-GCN's), then T-GCN's.
for model in iastgcn tgcn; do
  for seed in 1 2 3; do
    echo "=== $(date -u +%H:%M:%S) 128 min, spread placements, $model seed $seed"
    $BIN scale $RECIPE --models $model --seeds $seed $CF --out $OUT 2>&1 | grep -E "jobs done|rror" | tail -3
  done
  echo "=== $(date -u +%H:%M:%S) $model ensemble"
  $BIN scale $RECIPE --models $model --seeds 1,2,3 $CF --ensemble --out $OUT 2>&1 | grep -E "jobs done|rror" | tail -3
done
echo "=== $(date -u +%H:%M:%S) all done"
