#!/usr/bin/env bash
# #73 item 3: the morning minute (docs/results.md "The morning minute"). Trains the demo's
# models on seeds 1-3 (`iastgcn demo --seeds 1,2,3`, about 6 min on 2 cores), then on each
# of its three held-out sessions and the validation session records a morning run first
# and compares the trained IASTGCN and iastgcn-a with the ways of adapting them to it:
# a minute of the Fermat spiral, two minutes of it (the default), and a minute of the
# raster. About 12 minutes in all; WORK (default target/morning) keeps the demo's folder,
# which a second run reuses.
set -eu
cd "$(dirname "$0")/../.."
cargo build --release --bin iastgcn
WORK=${WORK:-target/morning}
OUT=docs/morning
if [ ! -f "$WORK/demo/models/iastgcn.seed3.safetensors" ]; then
  ./target/release/iastgcn demo --seeds 1,2,3 --out "$WORK/demo"
fi
models=()
for m in iastgcn-a iastgcn; do
  for s in 1 2 3; do models+=("$WORK/demo/models/$m.seed$s.safetensors"); done
done
study() {
  name=$1; shift
  ./target/release/iastgcn morning --config assets/demo.toml \
    --data "$WORK/demo/data/grid.s01.csv" --calibration "$WORK/demo/data/calibration.toml" \
    --models "${models[@]}" --out "$WORK/$name" "$@"
  mkdir -p "$OUT/$name"
  cp "$WORK/$name/morning.md" "$WORK/$name/morning_table_v.csv" "$WORK/$name/adaptations.csv" "$OUT/$name/"
}
study fermat-1min --path fermat --minutes 1
study fermat-2min --path fermat --minutes 2
study grid-1min --path grid --minutes 1
