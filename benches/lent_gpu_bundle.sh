#!/usr/bin/env bash
# Here, before a call on a lent GPU machine (docs/performance.md "On an NVIDIA GPU"):
# builds everything benches/lent_gpu.sh runs there and packs it into two folders that git
# ignores, within what one call carries (64 MiB):
#   .gl/      the Vulkan loader's and glvnd's Debian packages (that machine's image has
#             the NVIDIA driver but not these), downloaded once;
#   .devbin/  this build's iastgcn and its model, kernels and polish benches, the
#             matmul and model_gpu test binaries and the library's unit tests (debug,
#             as `cargo test` builds them; lent_gpu.sh runs the library's device tests
#             of the network's steps and the matmul planner), and for each COMMIT named
#             the model bench built at that
#             commit as model-COMMIT (lent_gpu.sh times it before and after this
#             build's, in the same call); all stripped and gzipped (lent_gpu.sh unpacks).
# Usage: benches/lent_gpu_bundle.sh [COMMIT...]
# Then, with a device lent: run(command: 'benches/lent_gpu.sh .devbin "$OUT"',
# carry: [".gl", ".devbin"]). About 10 minutes of building on the 2-core machine, plus
# 5–7 per commit named.
set -euo pipefail
root=$(git rev-parse --show-toplevel)
cd "$root"
mkdir -p .git/info
for d in .gl .devbin; do
    grep -qxF "/$d/" .git/info/exclude 2>/dev/null || echo "/$d/" >> .git/info/exclude
done

if ! ls .gl/*.deb > /dev/null 2>&1; then
    mkdir -p .gl /tmp/amd64/partial
    o=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64)
    apt-get "${o[@]}" update > /dev/null
    (cd .gl && apt-get "${o[@]}" download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
fi

rm -rf .devbin
mkdir -p .devbin
# Runs a cargo command that builds one bench or test without running it, and prints the
# executable it names on its "Executable" line (cargo's output on failure).
built() {
    local out
    out=$("$@" 2>&1) || { printf '%s\n' "$out" >&2; return 1; }
    printf '%s\n' "$out" | sed -n 's/^ *Executable .*(\(.*\))$/\1/p' | tail -1
}
pack() {
    strip -o ".devbin/$2" "$1"
    gzip -9 -f ".devbin/$2"
}

cargo build --release --bin iastgcn
pack target/release/iastgcn iastgcn
for b in model kernels polish; do
    bin=$(built cargo bench --no-run --bench "$b")
    pack "$bin" "$b"
done
for t in matmul model_gpu; do
    bin=$(built cargo test --no-run --test "$t")
    pack "$bin" "$t.test"
done
# Each step's kernels are tested beside them, in the library (src/model/block/*/).
pack "$(built cargo test --no-run --lib)" lib.test
for c in "$@"; do
    tree=/tmp/lent-gpu-$c
    rm -rf "$tree"
    git worktree prune
    git worktree add --detach "$tree" "$c" > /dev/null
    # The same target folder: only the crate is built again (its path differs, so its
    # binaries get other names and this build's stay).
    bin=$(cd "$tree" && export CARGO_TARGET_DIR="$root/target" && built cargo bench --no-run --bench model)
    pack "$bin" "model-$c"
    git worktree remove --force "$tree"
done

total=$(du -cb .gl .devbin | tail -1 | cut -f1)
ls -l .devbin .gl
echo "carried: $((total / 1048576)) MiB of 64"
if [ "$total" -gt $((64 * 1048576)) ]; then
    echo "over the 64 MiB one call carries: name fewer commits" >&2
    exit 1
fi
