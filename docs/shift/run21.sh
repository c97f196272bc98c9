#!/usr/bin/env bash
# #51: after run20, T-GCN on the 32-minute goal's recipe (force node, closed-loop data, a
# prediction every tick) at 128 minutes per path, in cf128e1's folder beside IASTGCN (the
# same data, days, placements and held-out sessions), seeds 1-3 and their ensemble: at
# 128 minutes on the open-loop recipe T-GCN was ahead of IASTGCN in all 8 cells, and the
# 128-minute attitude goal is still 2 points short. Hours on the 2-core machine; every
# job resumes from its state files when the script is run again. Same binary as the
# study (iastgcn6, build 2b59e15).
set -u
cd /work/main
BIN=out/shift/iastgcn6
while pgrep -f run20.sh > /dev/null; do sleep 20; done
CF="--config docs/scale/force128/config.toml --graph assets/graph-force.toml"
for seed in 1 2 3; do
  echo "=== $(date -u +%H:%M:%S) T-GCN, 128 min, force node, closed loop every tick, seed $seed"
  $BIN scale --sizes 128 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
    --every 1 --seeds $seed --models tgcn $CF --out out/shift/cf128e1 2>&1 | grep -E "jobs done|rror" | tail -3
done
echo "=== $(date -u +%H:%M:%S) cf128e1 T-GCN ensemble"
$BIN scale --sizes 128 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
  --every 1 --seeds 1,2,3 --models tgcn $CF --ensemble --out out/shift/cf128e1 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) all done"
