#!/usr/bin/env bash
# #51 leftover: closed-loop data for the MLP (whose worse closed loop is feedback, not
# prediction) at 32 min per path on 4 sessions, seeds 1-3 and their ensemble, in the c4
# folder beside IASTGCN's closed-loop jobs. Same binary as the study (iastgcn6, build
# 2b59e15).
set -u
cd /work/main
BIN=out/shift/iastgcn6
for seed in 1 2 3; do
  echo "=== $(date -u +%H:%M:%S) mlp closed loop, seed $seed"
  $BIN scale --sizes 32 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
    --seeds $seed --models mlp --out out/shift/c4 2>&1 | grep -E "jobs done|rror" | tail -3
done
echo "=== $(date -u +%H:%M:%S) mlp closed loop, ensemble"
$BIN scale --sizes 32 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
  --seeds 1,2,3 --models mlp --ensemble --out out/shift/c4 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) all done"
