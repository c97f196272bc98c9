#!/usr/bin/env bash
# #51 leftover: the seed ensemble of the force node with closed-loop data at 32 min per
# path on 4 sessions (cf4; the best 32-minute recipe), which run11 did not score.
# Same binary as the study (iastgcn6, build 2b59e15).
set -u
cd /work/main
BIN=out/shift/iastgcn6
echo "=== $(date -u +%H:%M:%S) cf4 ensemble"
$BIN scale --sizes 32 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
  --seeds 1,2,3 --models iastgcn --config docs/scale/force128/config.toml \
  --graph assets/graph-force.toml --ensemble --out out/shift/cf4 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) all done"
