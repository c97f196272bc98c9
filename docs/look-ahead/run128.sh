#!/usr/bin/env bash
# #73 item 1 on the study's protocol at 128 minutes per path: docs/shift/cf128sp's recipe
# (IASTGCN with the force node, closed-loop data, a prediction every tick, 4 sessions at
# spread placements, seeds 1-3, the three held-out sessions and the validation session)
# looking ahead a tick (assets/graph-force-look-ahead.toml, force-look-ahead.toml).
# Paired with cf128sp:
#   python3 docs/shift/paired.py docs/shift/cf128sp docs/look-ahead/cfl128sp iastgcn --sessions=1,2,3
# First it retrains cf4s's seed 1 (32 minutes, no look-ahead) with this build into
# target/look-ahead/cf4s-check, whose job record must equal docs/shift/cf4s's: the
# controls were made by earlier builds. About 45 minutes on 2 cores; resumable.
set -eu
cd "$(dirname "$0")/../.."
cargo build --release --bin iastgcn
WORK=${WORK:-target/look-ahead}
./target/release/iastgcn scale --sizes 32 --held-out-sessions 3 --placement spread --sessions 4 \
  --closed-loop --every 1 --models iastgcn --seeds 1 \
  --config docs/scale/force128/config.toml --graph assets/graph-force.toml --out "$WORK/cf4s-check"
CF="--config docs/look-ahead/force-look-ahead.toml --graph assets/graph-force-look-ahead.toml"
RECIPE="--sizes 128 --placement spread --sessions 4 --closed-loop --every 1 --held-out-sessions 4 --models iastgcn"
./target/release/iastgcn scale $RECIPE --seeds 1,2,3 $CF --out "$WORK/cfl128sp"
mkdir -p docs/look-ahead/cfl128sp/models
cp "$WORK"/cfl128sp/scale.md "$WORK"/cfl128sp/scale.csv "$WORK"/cfl128sp/scale_summary.csv \
  "$WORK"/cfl128sp/study.toml docs/look-ahead/cfl128sp/
cp "$WORK"/cfl128sp/models/*.job.toml docs/look-ahead/cfl128sp/models/
