#!/usr/bin/env bash
# #51: T-GCN's seed 3 of cf128sp on the three fresh held-out sessions (seeds from 501),
# as run35.sh scored seed 2; paired in cf128e5h with the same seed on quarter turns.
set -u
cd /work/main
for f in out/shift/cf128sp/models/tgcn.min128.seed3*; do
  case $f in *.job.toml) ;; *) cp -r "$f" out/shift/cf128sph/models/ ;; esac
done
out/shift/iastgcn6s scale --sizes 128 --placement spread --sessions 4 --closed-loop --every 1 \
  --held-out-sessions 3 --held-out-seed 501 --models tgcn --seeds 2,3 \
  --config docs/scale/force128/config.toml --graph assets/graph-force.toml \
  --out out/shift/cf128sph 2>&1 | grep -E "jobs done|rror" | tail -3
