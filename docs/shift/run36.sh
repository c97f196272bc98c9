#!/usr/bin/env bash
# #51: T-GCN's seed 3 on spread placements at 128 minutes (cf128sp), started when seed 2
# and its fresh-session scoring (run35.sh) had finished, 70 minutes before the session's
# end: it is recorded if it finishes in time, else lost with out/ (a new checkout has none).
set -u
cd /work/main
out/shift/iastgcn6s scale --sizes 128 --placement spread --sessions 4 --closed-loop --every 1 \
  --held-out-sessions 4 --models tgcn --seeds 3 --config docs/scale/force128/config.toml \
  --graph assets/graph-force.toml --out out/shift/cf128sp 2>&1 | grep -E "jobs done|rror|== " | tail -5
echo "=== $(date -u +%H:%M:%S) all done"
