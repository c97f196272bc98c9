#!/usr/bin/env bash
# #51: (1) the 32-minute winning recipe (force node, closed-loop data, a prediction every
# tick: cf4e1) at the demo's 8 minutes per path, IASTGCN seeds 1-3 and their ensemble
# (cf8e1): the evidence for the demo's defaults, and the cost of a round-0 model and
# the closed-loop recordings at that size. (2) T-GCN on the same recipe at 32 minutes in
# cf4e1's folder (same data, days, placements and held-out sessions as IASTGCN there),
# seeds 1-3 and its ensemble: the ranking question on the new recipe. Same binary as the
# study (iastgcn6, build 2b59e15).
set -u
cd /work/main
BIN=out/shift/iastgcn6
CF="--config docs/scale/force128/config.toml --graph assets/graph-force.toml"
for seed in 1 2 3; do
  echo "=== $(date -u +%H:%M:%S) 8 min, force node, closed loop every tick, seed $seed"
  $BIN scale --sizes 8 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
    --every 1 --seeds $seed --models iastgcn $CF --out out/shift/cf8e1 2>&1 | grep -E "jobs done|rror" | tail -3
done
echo "=== $(date -u +%H:%M:%S) cf8e1 ensemble"
$BIN scale --sizes 8 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
  --every 1 --seeds 1,2,3 --models iastgcn $CF --ensemble --out out/shift/cf8e1 2>&1 | grep -E "jobs done|rror" | tail -3
for seed in 1 2 3; do
  echo "=== $(date -u +%H:%M:%S) T-GCN, 32 min, force node, closed loop every tick, seed $seed"
  $BIN scale --sizes 32 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
    --every 1 --seeds $seed --models tgcn $CF --out out/shift/cf4e1 2>&1 | grep -E "jobs done|rror" | tail -3
done
echo "=== $(date -u +%H:%M:%S) cf4e1 T-GCN ensemble"
$BIN scale --sizes 32 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
  --every 1 --seeds 1,2,3 --models tgcn $CF --ensemble --out out/shift/cf4e1 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) all done"
