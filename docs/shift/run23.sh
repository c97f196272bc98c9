#!/usr/bin/env bash
# #51: cf128e1's models (IASTGCN and T-GCN, the force node, closed-loop data, a
# prediction every tick, 128 min per path; seeds 1-3 and each ensemble) rescored on three
# fresh held-out sessions (--held-out-seed 501), as run19.sh did for cf4e1: the best
# recipe and the best model at 128 minutes were both chosen on the sessions from seed
# 301. The folder is seeded with cf128e1's data and finished checkpoints (not its job
# records), so nothing is retrained. Same binary as the study (iastgcn6, build 2b59e15).
set -u
cd /work/main
BIN=out/shift/iastgcn6
OUT=out/shift/cf128e1h
if [ ! -d $OUT ]; then
  mkdir -p $OUT/models
  cp -r out/shift/cf128e1/data $OUT/
  for f in out/shift/cf128e1/models/*; do
    case $f in *.job.toml) ;; *) cp -r "$f" $OUT/models/ ;; esac
  done
fi
CF="--config docs/scale/force128/config.toml --graph assets/graph-force.toml"
echo "=== $(date -u +%H:%M:%S) cf128e1 on fresh held-out sessions"
$BIN scale --sizes 128 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
  --every 1 --seeds 1,2,3 --models iastgcn,tgcn $CF --held-out-seed 501 --out $OUT 2>&1 | grep -E "jobs done|rror|epoch" | tail -5
echo "=== $(date -u +%H:%M:%S) ensembles"
$BIN scale --sizes 128 --held-out-sessions 3 --placement varied --sessions 4 --closed-loop \
  --every 1 --seeds 1,2,3 --models iastgcn,tgcn $CF --held-out-seed 501 --ensemble --out $OUT 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) all done"
