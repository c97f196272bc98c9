#!/usr/bin/env bash
# Does the new build (iastgcn7: HEAD 0fe0739 + --placement spread) train and score as the study's build did? cf4e1's seed 1 again.
set -u
cd /work/main
out/shift/iastgcn7 scale --sizes 32 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
    --every 1 --seeds 1 --models iastgcn --config docs/scale/force128/config.toml \
    --graph assets/graph-force.toml --out out/shift/cf4e1chk 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) done"
