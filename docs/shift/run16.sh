#!/usr/bin/env bash
# #51 leftover: closed loop every tick. s4e1 showed that predicting every tick halves
# Hilbert's loop floor but an open-loop-trained model then chases its own corrections;
# here each job's round-0 model compensates sessions 3-4 at every tick while they are
# recorded again, the job trains on both, and it is scored at every tick (c4 with
# --every 1; the folder seeded with s4's data). Same binary as the study (iastgcn6,
# build 2b59e15).
set -u
cd /work/main
BIN=out/shift/iastgcn6
for seed in 1 2 3; do
  echo "=== $(date -u +%H:%M:%S) closed loop every tick, seed $seed"
  $BIN scale --sizes 32 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
    --every 1 --seeds $seed --models iastgcn --out out/shift/c4e1 2>&1 | grep -E "jobs done|rror" | tail -3
done
echo "=== $(date -u +%H:%M:%S) all done"
