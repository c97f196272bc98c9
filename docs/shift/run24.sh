#!/usr/bin/env bash
# #51: the recommendation rule at 128 minutes: cf128e1's models (IASTGCN and T-GCN,
# seeds 1-3 and each ensemble) scored on four held-out sessions from seed 301, the
# study's three and the next one, which `experiment::recommend` takes as the validation
# session (never in the study's tables); docs/shift/recommend.py applies the rule to the
# records. The folder is seeded with cf128e1's data and finished checkpoints (not its job
# records), so nothing is retrained. Same binary as the study (iastgcn6, build 2b59e15).
set -u
cd /work/main
BIN=out/shift/iastgcn6
OUT=out/shift/cf128e1v
if [ ! -d $OUT ]; then
  mkdir -p $OUT/models
  cp -r out/shift/cf128e1/data $OUT/
  for f in out/shift/cf128e1/models/*; do
    case $f in *.job.toml) ;; *) cp -r "$f" $OUT/models/ ;; esac
  done
fi
CF="--config docs/scale/force128/config.toml --graph assets/graph-force.toml"
echo "=== $(date -u +%H:%M:%S) cf128e1 on four held-out sessions"
$BIN scale --sizes 128 --held-out-sessions 4 --placement varied --sessions 4 --closed-loop \
  --every 1 --seeds 1,2,3 --models iastgcn,tgcn $CF --out $OUT 2>&1 | grep -E "jobs done|rror|epoch" | tail -5
echo "=== $(date -u +%H:%M:%S) ensembles"
$BIN scale --sizes 128 --held-out-sessions 4 --placement varied --sessions 4 --closed-loop \
  --every 1 --seeds 1,2,3 --models iastgcn,tgcn $CF --ensemble --out $OUT 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) all done"
python3 docs/shift/recommend.py $OUT
