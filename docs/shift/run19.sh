#!/usr/bin/env bash
# #51: cf4e1's models (the force node, closed-loop data, a prediction every tick; seeds
# 1-3) rescored on three fresh held-out sessions (--held-out-seed 501: other seeds, and
# sessions 2-3 on days drawn from that seed), since cf4e1 was the best of about twenty
# recipes scored on the sessions from seed 301. The folder is seeded with cf4e1's data and
# finished core checkpoints (not its job records), so nothing is retrained. Same binary as
# the study (iastgcn6, build 2b59e15).
set -u
cd /work/main
BIN=out/shift/iastgcn6
echo "=== $(date -u +%H:%M:%S) cf4e1 on fresh held-out sessions"
$BIN scale --sizes 32 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
  --every 1 --seeds 1,2,3 --models iastgcn --config docs/scale/force128/config.toml \
  --graph assets/graph-force.toml --held-out-seed 501 --out out/shift/cf4e1h 2>&1 | grep -E "jobs done|rror|epoch" | tail -5
echo "=== $(date -u +%H:%M:%S) ensemble"
$BIN scale --sizes 32 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
  --every 1 --seeds 1,2,3 --models iastgcn --config docs/scale/force128/config.toml \
  --graph assets/graph-force.toml --held-out-seed 501 --ensemble --out out/shift/cf4e1h 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) all done"
