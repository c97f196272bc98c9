#!/usr/bin/env bash
# #51: the blind check of spread placements, closed loop (docs/shift/README.md): the
# eight Hilbert turns of run32.sh (drawn at random before any result; none within 5
# degrees mod 90 of a training turn of either set), each a 2-minute run after 2 minutes
# of warm-up (seeds 5001-5008), compensated at every tick by cf4e1chk's three models
# (quarter turns) and cf4s's three (spread placements), each from the same machine state
# (`compensate --rotation`). run33.py reads the output (run33.log). Build iastgcn10
# (4490987 plus --rotation / --reverse on compensate).
cd /work/main
B=out/shift/iastgcn10
CAL=out/shift/cf4s/data/calibration.toml
M=""
for f in cf4e1chk cf4s; do for s in 1 2 3; do M="$M out/shift/$f/models/iastgcn.min32.seed$s.core.safetensors"; done; done
i=0
for tr in 230:r 336:f 35:f 68:r 236:r 221:r 31:r 224:r; do
  i=$((i+1)); t=${tr%%:*}; rev=""; [ ${tr##*:} = r ] && rev="--reverse"
  echo "=== turn $t $rev"
  $B compensate --trajectory hilbert --rotation $t $rev --minutes 2 --warm-up-minutes 2 \
    --seed $((5000+i)) --every 1 --calibration $CAL --model $M 2>/dev/null | grep -E "truth|turned"
done
