#!/usr/bin/env bash
# #52: Table VI over model seeds (docs/polishing.md "Results"): the demo's models of
# ../run.sh (the open-loop demo of 2026-11-27, whose seed-1 models gave the first table),
# now seeds 1-3 of iastgcn-a and IASTGCN, on the same five starting surfaces, three
# iterations, the raster. Run 2026-11-28 with the build of aca6fa3 (on a CPU the
# removal and the solve are the reference's), 14.5 min on the 2-core machine beside a
# study; out/demo/report is that demo's report folder.
set -u
cd /work/main
echo "=== $(date -u +%H:%M:%S) mirror study over model seeds"
M=out/demo/report/models
target/release/iastgcn polish --calibration out/demo/report/data/calibration.toml \
  --model $M/iastgcn-a.seed1.safetensors $M/iastgcn-a.seed2.safetensors $M/iastgcn-a.seed3.safetensors \
          $M/iastgcn.seed1.safetensors $M/iastgcn.seed2.safetensors $M/iastgcn.seed3.safetensors \
  --iterations 3 --surface-seeds 1,2,3,4,5 --out docs/mirror/seeds 2>&1 | grep -vE "^\s*$" | grep -E "RMS|^\||error|written|laid"
echo "=== $(date -u +%H:%M:%S) all done"
