#!/usr/bin/env bash
# #51 leftovers: T-GCN and the MLP at 128 min per path on the 4-session recipe (seeds 1-3,
# T-GCN seed 1 resumes from run7's state file) and their seed ensembles, for the error split
# per model; then the MLP at 32 min (s4) with its ensemble. Build of 2b59e15.
set -u
cd /work/main
BIN=out/shift/iastgcn6
for seed in 1 2 3; do
  echo "=== $(date -u +%H:%M:%S) 128 min, seed $seed"
  $BIN scale --sizes 128 --held-out-sessions 3 --placement varied --sessions 4 --seeds $seed \
    --models tgcn,mlp --out out/shift/s128 2>&1 | grep -E "jobs done|rror" | tail -3
done
echo "=== $(date -u +%H:%M:%S) ensembles 128"
$BIN scale --sizes 128 --held-out-sessions 3 --placement varied --sessions 4 --seeds 1,2,3 \
  --models tgcn,mlp --ensemble --out out/shift/s128 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) mlp at 32"
$BIN scale --sizes 32 --held-out-sessions 3 --placement varied --sessions 4 --seeds 1,2,3 \
  --models mlp --ensemble --out out/shift/s4 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) all done"
