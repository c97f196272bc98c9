#!/usr/bin/env bash
# #73 item 1: look-ahead prediction against the demo's recipe before it (docs/results.md
# "Look-ahead"). The demo on seeds 1-3 twice, with the config it had before look-ahead
# (demo-no-look-ahead.toml: the residual of the window's last tick, Table II's 14 nodes)
# and with its default config (assets/demo.toml: the residual of the next tick, the
# planned motion as three more nodes), on the same data, held-out sessions and seeds;
# then the paired comparison of their Table V. About 5 min per demo on 2 cores; WORK
# (default target/look-ahead) keeps both report folders.
set -eu
cd "$(dirname "$0")/../.."
cargo build --release --bin iastgcn
WORK=${WORK:-target/look-ahead}
OUT=docs/look-ahead
./target/release/iastgcn demo --seeds 1,2,3 --config "$OUT/demo-no-look-ahead.toml" --out "$WORK/before"
./target/release/iastgcn demo --seeds 1,2,3 --out "$WORK/look-ahead"
python3 "$OUT/compare.py" "$WORK/before" "$WORK/look-ahead" > "$OUT/comparison.md"
for run in before look-ahead; do
  mkdir -p "$OUT/$run"
  cp "$WORK/$run/report.md" "$WORK/$run/table_v.csv" "$WORK/$run/table_iii.csv" "$OUT/$run/"
done
