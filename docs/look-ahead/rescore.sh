#!/usr/bin/env bash
# Scores the look-ahead study folders again with this build's Table V oracle, which looks
# ahead with the models (the floor that applies; docs/look-ahead/README.md), and adds
# iastgcn-a looking ahead beside IASTGCN. Needs the folders run32.sh and run128.sh made
# (WORK/cfl4s, WORK/cfl128sp, with their checkpoints and data): works on copies,
# WORK/<folder>-floor. About 10 minutes for the rescoring, then 7 min (32) and 26 min (128)
# of training for iastgcn-a on 2 cores.
set -eu
cd "$(dirname "$0")/../.."
cargo build --release --bin iastgcn
WORK=${WORK:-target/look-ahead}
CF="--config docs/look-ahead/force-look-ahead.toml --graph assets/graph-force-look-ahead.toml"
LOOP="--placement spread --sessions 4 --closed-loop --every 1"
for s in cfl4s cfl128sp; do
  F=$WORK/$s-floor
  rm -rf "$F" && mkdir -p "$F/old-records"
  cp -al "$WORK/$s/data" "$F/data"
  cp -a "$WORK/$s/models" "$WORK/$s/study.toml" "$F/"
  mv "$F"/models/*.job.toml "$F/old-records/"
done
./target/release/iastgcn scale --sizes 32 --held-out-sessions 3 $LOOP --models iastgcn --seeds 1,2,3 $CF --out "$WORK/cfl4s-floor"
./target/release/iastgcn scale --sizes 128 --held-out-sessions 4 $LOOP --models iastgcn --seeds 1,2,3 $CF --out "$WORK/cfl128sp-floor"
for s in cfl4s cfl128sp; do
  python3 docs/look-ahead/rescore.py "$WORK/$s-floor" "$WORK/$s-floor/old-records"
done
./target/release/iastgcn scale --sizes 32 --held-out-sessions 3 $LOOP --models iastgcn,iastgcn-a --seeds 1,2,3 $CF --out "$WORK/cfl4s-floor"
./target/release/iastgcn scale --sizes 128 --held-out-sessions 4 $LOOP --models iastgcn,iastgcn-a --seeds 1,2,3 $CF --out "$WORK/cfl128sp-floor"
for s in cfl4s cfl128sp; do
  F=$WORK/$s-floor D=docs/look-ahead/$s
  rm -f "$D"/models/*.job.toml
  cp "$F"/scale.md "$F"/scale.csv "$F"/scale_summary.csv "$F"/study.toml "$D/"
  cp "$F"/models/*.job.toml "$D/models/"
done
