#!/usr/bin/env bash
# #52: Table VI on the twin (docs/polishing.md "Results"), with the rim modelled at every
# phase of the orbit (commit b886cad): the models of a fresh `make demo` (its defaults:
# 4 sessions at spread placements, closed-loop data; iastgcn-a is its recommended model),
# seeds 1-3 of iastgcn-a and IASTGCN, five starting surfaces, three iterations on the
# raster, PV and RMS over the default 480 mm clear aperture. out/demo/report is that demo's
# report folder; out/mirror/iastgcn the build of b886cad.
set -u
cd /work/main
echo "=== $(date -u +%H:%M:%S) mirror study, 480 mm"
M=out/demo/report/models
out/mirror/iastgcn polish --calibration out/demo/report/data/calibration.toml \
  --model $M/iastgcn-a.seed1.safetensors $M/iastgcn-a.seed2.safetensors $M/iastgcn-a.seed3.safetensors \
          $M/iastgcn.seed1.safetensors $M/iastgcn.seed2.safetensors $M/iastgcn.seed3.safetensors \
  --iterations 3 --surface-seeds 1,2,3,4,5 --out docs/mirror 2>&1 | grep -vE "^\s*$" | grep -E "RMS|^\||error|written|laid"
echo "=== $(date -u +%H:%M:%S) all done"
