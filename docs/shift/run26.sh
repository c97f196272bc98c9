#!/usr/bin/env bash
# #51: the sessions lever at 128 minutes per path. cf128e1's recipe (IASTGCN and T-GCN,
# the force node, closed-loop data, a prediction every tick) with the same 128 minutes
# per path split into 16 sessions of 8 minutes instead of 4 of 32: sixteen days, each
# starting cold or after its own idle, with its own placement, feed and seed (round 0
# trains on sessions 1-8 and compensates 9-16 as they are recorded again). At 32
# minutes, 16 sessions of 2 minutes were no better than 4 (s16); at 128 minutes each
# session is 8 minutes long, and the models' error left on new days is what stands
# between them and the attitude goal. Scored on the study's three held-out sessions and
# the validation session (--held-out-sessions 4, the fourth read as the validation
# session as in cf128e5), seeds 1-3 and each model's ensemble; paired with cf128e1v
# (the same seeds on 4 sessions). Same binary as the study (iastgcn6, build 2b59e15);
# every job resumes from its state files when the script is run again.
set -u
cd /work/main
BIN=out/shift/iastgcn6
OUT=out/shift/cf128s16
CF="--config docs/scale/force128/config.toml --graph assets/graph-force.toml"
RECIPE="--sizes 128 --placement varied --sessions 16 --closed-loop --every 1 --held-out-sessions 4 --models iastgcn,tgcn"
for seed in 1 2 3; do
  echo "=== $(date -u +%H:%M:%S) 128 min in 16 sessions, seed $seed"
  $BIN scale $RECIPE --seeds $seed $CF --out $OUT 2>&1 | grep -E "jobs done|rror|== job" | tail -8
done
echo "=== $(date -u +%H:%M:%S) ensembles"
$BIN scale $RECIPE --seeds 1,2,3 $CF --ensemble --out $OUT 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) all done"
