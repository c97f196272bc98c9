#!/usr/bin/env bash
# #73 item 1 on the study's protocol: look-ahead at 32 minutes per path on the 32-minute
# goal's best recipe (docs/shift/cf4s: IASTGCN with the force node, closed-loop data, a
# prediction every tick, 4 sessions at spread placements, seeds 1-3, three held-out
# sessions of 2-minute runs), the force node's graph with the planned motion
# (assets/graph-force-look-ahead.toml, 18 nodes) and look_ahead = 1
# (force-look-ahead.toml). Paired with cf4s:
#   python3 docs/shift/paired.py docs/shift/cf4s docs/look-ahead/cfl4s
# About 40 minutes on 2 cores. OUT (default target/look-ahead/cfl4s) is resumable.
set -eu
cd "$(dirname "$0")/../.."
cargo build --release --bin iastgcn
OUT=${OUT:-target/look-ahead/cfl4s}
CF="--config docs/look-ahead/force-look-ahead.toml --graph assets/graph-force-look-ahead.toml"
RECIPE="--sizes 32 --held-out-sessions 3 --placement spread --sessions 4 --closed-loop --every 1 --models iastgcn"
./target/release/iastgcn scale $RECIPE --seeds 1,2,3 $CF --out "$OUT"
mkdir -p docs/look-ahead/cfl4s/models
cp "$OUT"/scale.md "$OUT"/scale.csv "$OUT"/scale_summary.csv "$OUT"/study.toml docs/look-ahead/cfl4s/
cp "$OUT"/models/*.job.toml docs/look-ahead/cfl4s/models/
