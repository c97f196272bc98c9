#!/usr/bin/env bash
# #51: does the demo's recipe gain from spread placements too? The demo's size and recipe
# (8 minutes per path in 4 sessions, the paper's graph and run config, closed-loop data,
# a prediction every tick; IASTGCN seeds 1-3 and the ensemble, three held-out sessions of
# 2-minute runs) with --placement varied (cf8v, the control) and --placement spread
# (cf8s), both trained with build iastgcn8. Starts when run27c.sh has finished.
set -u
cd /work/main
while pgrep -f run27c.sh > /dev/null; do sleep 20; done
BIN=out/shift/iastgcn8
for placement in varied spread; do
  OUT=out/shift/cf8${placement:0:1}
  RECIPE="--sizes 8 --held-out-sessions 3 --placement $placement --sessions 4 --closed-loop --every 1 --models iastgcn"
  for seed in 1 2 3; do
    echo "=== $(date -u +%H:%M:%S) 8 min, $placement placements, seed $seed"
    $BIN scale $RECIPE --seeds $seed --out $OUT 2>&1 | grep -E "jobs done|rror" | tail -3
  done
  echo "=== $(date -u +%H:%M:%S) $placement ensemble"
  $BIN scale $RECIPE --seeds 1,2,3 --ensemble --out $OUT 2>&1 | grep -E "jobs done|rror" | tail -3
done
echo "=== $(date -u +%H:%M:%S) all done"
