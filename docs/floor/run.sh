#!/usr/bin/env bash
# #73 item 1, its first step: the look-ahead floor (docs/results.md "The look-ahead
# floor"). The oracle of the tick just measured and the look-ahead oracle on the demo's
# three held-out sessions, on the machine and calibration of the demo's data (WORK, as
# docs/morning/run.sh leaves it; `iastgcn demo` there first when it is missing). 10 s.
set -eu
cd "$(dirname "$0")/../.."
cargo build --release --bin iastgcn
WORK=${WORK:-target/morning}
if [ ! -f "$WORK/demo/data/calibration.toml" ]; then
  ./target/release/iastgcn demo --seeds 1,2,3 --out "$WORK/demo"
fi
./target/release/iastgcn floor --data "$WORK/demo/data/grid.s01.csv" \
  --calibration "$WORK/demo/data/calibration.toml" --out docs/floor
