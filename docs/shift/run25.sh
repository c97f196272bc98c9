#!/usr/bin/env bash
# #51: does a larger seed ensemble close the 128-minute attitude gap? cf128e1's recipe
# (IASTGCN and T-GCN, the force node, closed-loop data, a prediction every tick, 128 min
# per path) with seeds 4 and 5 trained beside seeds 1-3, scored on the study's three
# held-out sessions and the validation session (cf128e5, seeded with cf128e1v: its data,
# checkpoints and job records, so seeds 1-3 are not retrained), then each model's
# 5-seed ensemble; then every model rescored on the three fresh sessions of run23.sh
# (cf128e5h, seeded with cf128e1h and the new checkpoints). The 3-seed ensembles' records
# stay in cf128e1v / cf128e1h. Same binary as the study (iastgcn6, build 2b59e15).
set -u
cd /work/main
BIN=out/shift/iastgcn6
OUT=out/shift/cf128e5
FRESH=out/shift/cf128e5h
if [ ! -d $OUT ]; then
  mkdir -p $OUT/models
  cp -r out/shift/cf128e1v/data out/shift/cf128e1v/study.toml $OUT/
  for f in out/shift/cf128e1v/models/*; do
    case $f in *.ensemble.job.toml) ;; *) cp -r "$f" $OUT/models/ ;; esac
  done
fi
CF="--config docs/scale/force128/config.toml --graph assets/graph-force.toml"
RECIPE="--sizes 128 --placement varied --sessions 4 --closed-loop --every 1 --seeds 1,2,3,4,5 --models iastgcn,tgcn"
echo "=== $(date -u +%H:%M:%S) seeds 4 and 5 on four held-out sessions (the fourth: validation)"
$BIN scale $RECIPE --held-out-sessions 4 $CF --out $OUT 2>&1 | grep -E "jobs done|rror|== job" | tail -8
echo "=== $(date -u +%H:%M:%S) 5-seed ensembles"
$BIN scale $RECIPE --held-out-sessions 4 $CF --ensemble --out $OUT 2>&1 | grep -E "jobs done|rror" | tail -3
if [ ! -d $FRESH ]; then
  mkdir -p $FRESH/models
  cp -r out/shift/cf128e1h/data out/shift/cf128e1h/study.toml $FRESH/
  for f in out/shift/cf128e1h/models/*; do
    case $f in *.ensemble.job.toml) ;; *) cp -r "$f" $FRESH/models/ ;; esac
  done
  for f in $OUT/models/*seed[45]*; do
    case $f in *.job.toml) ;; *) cp -r "$f" $FRESH/models/ ;; esac
  done
fi
echo "=== $(date -u +%H:%M:%S) fresh sessions (seed 501): seeds 4 and 5, then the ensembles"
$BIN scale $RECIPE --held-out-sessions 3 $CF --held-out-seed 501 --out $FRESH 2>&1 | grep -E "jobs done|rror" | tail -3
$BIN scale $RECIPE --held-out-sessions 3 $CF --held-out-seed 501 --ensemble --out $FRESH 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) all done"
