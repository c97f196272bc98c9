#!/usr/bin/env bash
# #51: after run16 (closed loop every tick, c4e1), its seed ensemble; then the same with
# the force node (cf4 with --every 1; the folder seeded with f4's data), seeds 1-3 and
# their ensemble. Same binary as the study (iastgcn6, build 2b59e15).
set -u
cd /work/main
BIN=out/shift/iastgcn6
while pgrep -f run16.sh > /dev/null; do sleep 20; done
echo "=== $(date -u +%H:%M:%S) c4e1 ensemble"
$BIN scale --sizes 32 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
  --every 1 --seeds 1,2,3 --models iastgcn --ensemble --out out/shift/c4e1 2>&1 | grep -E "jobs done|rror" | tail -3
for seed in 1 2 3; do
  echo "=== $(date -u +%H:%M:%S) force node, closed loop every tick, seed $seed"
  $BIN scale --sizes 32 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
    --every 1 --seeds $seed --models iastgcn --config docs/scale/force128/config.toml \
    --graph assets/graph-force.toml --out out/shift/cf4e1 2>&1 | grep -E "jobs done|rror" | tail -3
done
echo "=== $(date -u +%H:%M:%S) cf4e1 ensemble"
$BIN scale --sizes 32 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
  --every 1 --seeds 1,2,3 --models iastgcn --config docs/scale/force128/config.toml \
  --graph assets/graph-force.toml --ensemble --out out/shift/cf4e1 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) all done"
