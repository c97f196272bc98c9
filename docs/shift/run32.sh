#!/usr/bin/env bash
# #51: the blind check of spread placements (docs/shift/README.md); run32.py reads its log
# (docs/shift/run32.log, this run of 2026-11-28, build iastgcn7).
# Blind check of spread placements (decided before any result): 8 Hilbert turns drawn
# from random.Random(20261128) (uniform 0-360, reversed by coin), dropping turns within 5
# degrees (mod 90) of any training turn of either set; 6-minute cold runs recorded with
# simulate (seeds 4001-4008), open-loop prediction error of cf4e1chk's and cf4s's seeds
# 1-3 against the tracker's labels (predict, every 5 ticks). The turns:
#   r = random.Random(20261128); keep (round(r.uniform(0, 360)), r.random() < 0.5) unless
#   the turn mod 90 lies within 5 degrees of 0, 21, 77 or 8 (the two sets' Hilbert turns
#   mod 90), until 8 are kept.
cd /work/main && mkdir -p out/shift/blind
B=out/shift/iastgcn7
CAL=out/shift/cf4s/data/calibration.toml
i=0
for tr in 230:r 336:f 35:f 68:r 236:r 221:r 31:r 224:r; do
  i=$((i+1)); t=${tr%%:*}; rev=""; [ ${tr##*:} = r ] && rev="--reverse"
  $B simulate --trajectory hilbert --rotation $t $rev --calibration $CAL --minutes 6 --seed $((4000+i)) --out out/shift/blind/b$i.csv >/dev/null 2>&1
  for f in cf4e1chk cf4s; do for s in 1 2 3; do
    line=$($B predict --data out/shift/blind/b$i.csv --calibration $CAL --graph assets/graph-force.toml --model out/shift/$f/models/iastgcn.min32.seed$s.core.safetensors --out out/shift/blind/bp.csv --stride 5 2>&1 | grep "^  all")
    echo "$t $rev $f $s $line"
  done; done
done
