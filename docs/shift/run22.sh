#!/usr/bin/env bash
# #51: the ablation without attention (`iastgcn-a`, the model the demo recommends) on the
# 32-minute goal's recipe (force node, closed-loop data, a prediction every tick) in
# cf4e1's folder beside IASTGCN and T-GCN, seeds 1-3 and the ensemble: the paper's
# ranking question on the new recipe. Then run21 (T-GCN at 128 minutes), which resumes
# from its state files. Same binary as the study (iastgcn6, build 2b59e15).
set -u
cd /work/main
BIN=out/shift/iastgcn6
CF="--config docs/scale/force128/config.toml --graph assets/graph-force.toml"
for seed in 1 2 3; do
  echo "=== $(date -u +%H:%M:%S) iastgcn-a, 32 min, force node, closed loop every tick, seed $seed"
  $BIN scale --sizes 32 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
    --every 1 --seeds $seed --models iastgcn-a $CF --out out/shift/cf4e1 2>&1 | grep -E "jobs done|rror" | tail -3
done
echo "=== $(date -u +%H:%M:%S) cf4e1 iastgcn-a ensemble"
$BIN scale --sizes 32 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
  --every 1 --seeds 1,2,3 --models iastgcn-a $CF --ensemble --out out/shift/cf4e1 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) run21"
bash out/shift/run21.sh
