#!/usr/bin/env bash
# #51: what ran of run34.sh in the session of 2026-11-28 (fourth): T-GCN's seed 3 would
# have finished after the session's end (a new checkout loses out/, state files and all),
# so run34.sh is stopped once seed 2's record is written, and seed 2 alone is scored on
# the three fresh held-out sessions of cf128e5h (seeds from 501), paired there with
# cf128e5h's T-GCN seed 2 (the same seed trained on quarter turns).
set -u
cd /work/main
BIN=out/shift/iastgcn6s
OUT=out/shift/cf128sp
FRESH=out/shift/cf128sph
CF="--config docs/scale/force128/config.toml --graph assets/graph-force.toml"
while [ ! -e $OUT/models/tgcn.min128.seed2.job.toml ]; do sleep 10; done
pkill -f run34.sh; sleep 1; pkill -f "iastgcn6s scale" ; sleep 2
rm -f $OUT/models/tgcn.min128.seed3.*
mkdir -p $FRESH/models
[ -e $FRESH/data ] || ln -s ../cf128sp/data $FRESH/data
for f in $OUT/models/tgcn.min128.seed2*; do
  case $f in *.job.toml) ;; *) cp -r "$f" $FRESH/models/ ;; esac
done
echo "=== $(date -u +%H:%M:%S) fresh sessions (seed 501): T-GCN seed 2"
$BIN scale --sizes 128 --placement spread --sessions 4 --closed-loop --every 1 --held-out-sessions 3 \
  --held-out-seed 501 --models tgcn --seeds 2 $CF --out $FRESH 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) all done"
