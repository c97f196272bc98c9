#!/usr/bin/env bash
# One call on a lent NVIDIA GPU machine that has no cargo (docs/performance.md "On an
# NVIDIA GPU"): the engine's GPU measurements and PyTorch CUDA's in the same call, so
# that their ratio holds although every call may land on another machine.
#
# Here: `benches/lent_gpu_bundle.sh [COMMIT...]` does all of the following (compressed,
# within the 64 MiB a call carries); by hand:
# Once, the Vulkan loader and glvnd's libraries as Debian packages (the machine's
# image has the NVIDIA driver but not these), in a folder git ignores:
#   echo /.gl/ >> .git/info/exclude; mkdir -p .gl /tmp/amd64/partial
#   o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
#   apt-get $o update; (cd .gl && apt-get $o download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
# Then build and collect the binaries (also ignored), and carry both folders:
#   cargo build --release --bin iastgcn
#   cargo bench --no-run --bench model --bench kernels --bench polish
#   echo /.devbin/ >> .git/info/exclude; mkdir -p .devbin && cp target/release/iastgcn .devbin/ &&
#     for b in model kernels polish; do cp "$(ls -t target/release/deps/$b-* | grep -v '\.d$' | head -1)" .devbin/$b; done
#   (there) benches/lent_gpu.sh .devbin "$OUT"
# Test binaries built here (`cargo test --no-run`, then target/debug/deps/NAME-*,
# stripped) and copied into the folder as NAME.test run first, on the GPU: e.g. the
# matmul tests, whose planner splits reductions differently on a GPU than on lavapipe;
# lib.test (the library's unit tests) runs only its kernels' tests.
#
# In order: the adapter (`iastgcn info`), `iastgcn smoke` (every kernel against its CPU
# reference on the GPU), the model bench's device rows (the baseline product, forward at
# B = 1 and 64, the training step at B = 64, both shapes; IASTGCN_BENCH_CSV), the kernels
# bench of both shapes' training step (in one submit, each launch between timestamps),
# compare.py (the interop check and PyTorch on the same GPU through CUDA against those
# rows), then the mirror's removal and dwell solve natively and as WGSL kernels (the polish
# bench, when carried). Everything lands in OUTDIR (log.txt holds all of it). About 2
# minutes on an H200 without earlier builds and test binaries; with two earlier builds'
# model benches, the tests and the polish bench more than 8: give such a call 10.
set -u
BIN=${1:?usage: lent_gpu.sh BINDIR OUTDIR}
OUTDIR=${2:?usage: lent_gpu.sh BINDIR OUTDIR}
mkdir -p "$OUTDIR"
exec > >(tee "$OUTDIR/log.txt") 2>&1
# The bundle's binaries come gzipped (benches/lent_gpu_bundle.sh); Python's gzip where
# the machine has no gunzip.
for f in "$BIN"/*.gz; do
    [ -e "$f" ] || continue
    if command -v gunzip > /dev/null; then
        gunzip -f "$f"
    else
        python3 -c 'import gzip, shutil, sys
with gzip.open(sys.argv[1]) as i, open(sys.argv[1][:-3], "wb") as o:
    shutil.copyfileobj(i, o)' "$f" && rm "$f"
    fi
    chmod +x "${f%.gz}"
done
if [ -d .gl ]; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
fi
# The driver's Vulkan ICD file is outside the loader's search path there.
icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
if [ -z "${VK_DRIVER_FILES:-}" ] && [ -f "$icd" ]; then
    export VK_DRIVER_FILES=$icd
fi
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv
"$BIN/iastgcn" info || exit 1
for t in "$BIN"/*.test; do
    [ -e "$t" ] || continue
    # The library's unit tests: only those that run kernels (each step's, beside it, and
    # the matmul planner's).
    filters=()
    [ "$(basename "$t")" = lib.test ] && filters=(model::block:: model::head:: ops::matmul::)
    echo "== tests on the GPU: $(basename "$t") ${filters[*]}"
    "$t" --test-threads 4 "${filters[@]}" 2>&1 | grep -E '^test |test result|panicked' || exit 1
done
"$BIN/iastgcn" smoke || exit 1
# Another build's model bench copied in as model-NAME (the code before a change) is run
# after this build's, and again before it, so that the two are compared within the call.
bench_model() {
    local name
    name=$(basename "$1")
    echo "== model bench, device rows: $name"
    IASTGCN_BENCH_CSV="$OUTDIR/$name.csv" IASTGCN_BENCH_GROUPS='baseline,small C16,paper C64' \
        "$1" --bench '/(matmul|forward B=1$|forward B=64|train step)' 2>&1 |
        grep -E '^(baseline|small|paper).*mean'
}
others=$(ls "$BIN"/model-* 2>/dev/null)
for m in $others; do bench_model "$m"; done
bench_model "$BIN/model"
for m in $others; do bench_model "$m"; done
for shape in paper small; do
    echo "== kernels bench, $shape training step"
    "$BIN/kernels" "$shape" train
done
echo "== against PyTorch (CUDA)"
PYTHONUNBUFFERED=1 python3 benches/pytorch/compare.py --binary "$BIN/iastgcn" \
    --engine-csv "$OUTDIR/model.csv" --torch-device cuda --out "$OUTDIR"
# Last: the part a short call can do without (on 2026-11-30 it had not finished when an
# 8-minute call ran out, compare.py not yet run; it ran in a second call, 33 s).
if [ -x "$BIN/polish" ]; then
    echo "== polish bench: the mirror's removal and dwell solve, native f64 against WGSL"
    "$BIN/polish" --bench 2>&1 | grep -E '^(dwell_solve|removal_tick)|time:|thrpt:|planned RMS|skipped| on '
fi
