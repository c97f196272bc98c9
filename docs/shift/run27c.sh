#!/usr/bin/env bash
# #51: the control of run27.sh and run28.sh: cf4e1's recipe unchanged (--placement varied,
# the fixed path order) retrained with the new build. The study's build (iastgcn6,
# 2b59e15) and this one (iastgcn7) train the same round-0 model bit for bit, but its
# closed-loop recordings part from tick 51 on (the native predictor's sums run in another
# order since then), so cf4e1's own records are not the baseline for a lever trained with
# the new build: this folder is (seed 1 is run27chk.sh's job). Seeds 2-3 and the ensemble.
set -u
cd /work/main
while pgrep -f run27.sh > /dev/null; do sleep 20; done
BIN=out/shift/iastgcn7
OUT=out/shift/cf4e1chk
CF="--config docs/scale/force128/config.toml --graph assets/graph-force.toml"
RECIPE="--sizes 32 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop --every 1 --models iastgcn"
for seed in 2 3; do
  echo "=== $(date -u +%H:%M:%S) 32 min, the control, seed $seed"
  $BIN scale $RECIPE --seeds $seed $CF --out $OUT 2>&1 | grep -E "jobs done|rror" | tail -3
done
echo "=== $(date -u +%H:%M:%S) ensemble"
$BIN scale $RECIPE --seeds 1,2,3 $CF --ensemble --out $OUT 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) all done"
