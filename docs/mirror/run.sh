#!/usr/bin/env bash
# #52 study: the demo's models (iastgcn-a, the recommended one, and IASTGCN, seed 1)
# polishing five starting surfaces for three iterations on the raster, against the
# nominal controller (and its position and attitude errors alone), the calibrated one,
# the oracle and a perfect machine (docs/polishing.md "Results").
set -u
cd /work/main
echo "=== $(date -u +%H:%M:%S) mirror study"
out/mirror/iastgcn polish --calibration out/demo/report/data/calibration.toml \
  --model out/demo/report/models/iastgcn-a.seed1.safetensors out/demo/report/models/iastgcn.seed1.safetensors \
  --iterations 3 --surface-seeds 1,2,3,4,5 --out out/mirror/grid5f 2>&1 | grep -vE "^\s*$" | grep -E "RMS|^\||error|written" 
echo "=== $(date -u +%H:%M:%S) all done"
