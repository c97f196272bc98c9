#!/usr/bin/env bash
# #51: T-GCN's seeds 2 and 3 on spread placements at 128 minutes per path, the rest of
# run29.sh. A new checkout had lost out/ (data, checkpoints, state files), so the study's
# folder is rebuilt from its committed job records (docs/shift/cf128sp/models/*.job.toml:
# IASTGCN seeds 1-3 and their ensemble, T-GCN seed 1), the data are recorded again (the
# same seed gives the same recordings bit for bit) and only the missing T-GCN jobs train.
# T-GCN's ensemble needs seed 1's checkpoint, which is gone: it is not run here.
# Build iastgcn6s as run29.sh says: 2b59e15 with ea132f6 applied (in a worktree, the
# cherry-pick's three import conflicts resolved by taking both sides' names).
set -u
cd /work/main
BIN=out/shift/iastgcn6s
OUT=out/shift/cf128sp
CF="--config docs/scale/force128/config.toml --graph assets/graph-force.toml"
RECIPE="--sizes 128 --placement spread --sessions 4 --closed-loop --every 1 --held-out-sessions 4"
mkdir -p $OUT/models
for f in docs/shift/cf128sp/models/*.job.toml; do
  [ -e $OUT/models/$(basename $f) ] || cp $f $OUT/models/
done
for seed in 2 3; do
  echo "=== $(date -u +%H:%M:%S) 128 min, spread placements, tgcn seed $seed"
  $BIN scale $RECIPE --models tgcn --seeds $seed $CF --out $OUT 2>&1 | grep -E "jobs done|rror|recorded|== job" | tail -5
done
# The new checkpoints on the three fresh held-out sessions of cf128e5h (seeds from 501),
# paired there with the same seeds trained on quarter turns; nothing retrained (a folder
# with the checkpoints and no records only evaluates).
FRESH=out/shift/cf128sph
if [ ! -d $FRESH ]; then
  mkdir -p $FRESH/models
  ln -s ../cf128sp/data $FRESH/data
  for f in $OUT/models/tgcn.min128.seed[23]*; do
    case $f in *.job.toml) ;; *) cp -r "$f" $FRESH/models/ ;; esac
  done
fi
echo "=== $(date -u +%H:%M:%S) fresh sessions (seed 501): T-GCN seeds 2 and 3"
$BIN scale ${RECIPE/--held-out-sessions 4/--held-out-sessions 3} --held-out-seed 501 --models tgcn --seeds 2,3 $CF --out $FRESH 2>&1 | grep -E "jobs done|rror" | tail -3
echo "=== $(date -u +%H:%M:%S) all done"
