#!/usr/bin/env bash
# #73 item 4: when a pose error starts to cost the glass (docs/polishing.md "When
# compensation pays"). The sweep's defaults: pads of 14-84 mm footprint, errors of
# 10 µm to 3 mm of three kinds, the ideal and the stiff float, error seeds 1-3, surface 1;
# marked: the paper's errors and those the twin's controllers showed the glass in the
# mirror study of docs/mirror/ (its polish.csv).
set -eu
cd "$(dirname "$0")/../../.."
cargo build --release --bin iastgcn
./target/release/iastgcn polish-sweep --marks-from docs/mirror/polish.csv --out docs/mirror/sweep
