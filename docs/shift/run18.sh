#!/usr/bin/env bash
# #51: the 32-minute goal's recipe at 128 minutes per path: the force node with
# closed-loop data and a prediction every tick (cf4e1 at --sizes 128; the folder seeded
# with s128's data, whose recordings hold the force channel as f4's do), seeds 1-3 and
# their ensemble. Hours on the 2-core machine; every job resumes from its state files
# when the script is run again. Same binary as the study (iastgcn6, build 2b59e15).
set -u
cd /work/main
BIN=out/shift/iastgcn6
for seed in 1 2 3; do
  echo "=== $(date -u +%H:%M:%S) 128 min, force node, closed loop every tick, seed $seed"
  $BIN scale --sizes 128 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
    --every 1 --seeds $seed --models iastgcn --config docs/scale/force128/config.toml \
    --graph assets/graph-force.toml --out out/shift/cf128e1 2>&1 | grep -E "jobs done|rror" | tail -3
done
echo "=== $(date -u +%H:%M:%S) cf128e1 ensemble"
$BIN scale --sizes 128 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
  --every 1 --seeds 1,2,3 --models iastgcn --config docs/scale/force128/config.toml \
  --graph assets/graph-force.toml --ensemble --out out/shift/cf128e1 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) all done"
