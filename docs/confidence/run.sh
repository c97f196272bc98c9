#!/usr/bin/env bash
# #73 item 2: how far a seed ensemble's spread tells how far to trust its prediction, and
# the calibrated interval the predictors carry (docs/results.md "Confidence"). The demo's
# models on seeds 1-3 (the look-ahead default since 2026-11-30; trained by
# docs/morning/run.sh into WORK by the same build, or here when they are not there: about
# 6-9 min on 2 cores), IASTGCN and iastgcn-a as 3-seed ensembles on the demo's three
# held-out sessions and its validation session: the intervals, then the gates in the loop
# (about 4 min). WORK/confidence also gets each model's ensemble file
# (<model>.ensemble.toml, members relative to it), which a predictor loads.
set -eu
cd "$(dirname "$0")/../.."
cargo build --release --bin iastgcn
WORK=${WORK:-target/morning}
OUT=docs/confidence
if [ ! -f "$WORK/demo/models/iastgcn.seed3.safetensors" ]; then
  ./target/release/iastgcn demo --seeds 1,2,3 --out "$WORK/demo"
fi
models=()
for m in iastgcn-a iastgcn; do
  for s in 1 2 3; do models+=("$WORK/demo/models/$m.seed$s.safetensors"); done
done
./target/release/iastgcn confidence \
  --data "$WORK/demo/data/grid.s01.csv" --calibration "$WORK/demo/data/calibration.toml" \
  --models "${models[@]}" --out "$WORK/confidence"
cp "$WORK/confidence/confidence.md" "$OUT/"
# What could rank the misses (the spread, the correction's size, the runs' share):
python3 docs/confidence/rank.py "$WORK/confidence/ticks.csv" > "$OUT/rank.md"
