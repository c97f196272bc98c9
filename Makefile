# The two set-up commands are `make demo` and `make test` (see README.md).
# Both first make sure a Vulkan driver exists (installing Mesa lavapipe when root).

CARGO ?= cargo
export NODEVICE_SELECT ?= 1

.PHONY: vulkan test demo paper bench bench-compare bench-polish bench-embed lint python c-library header cli-reference fuzz

vulkan:
	@.ci/ensure-vulkan

## Whole test suite (on lavapipe when there is no GPU): the Rust tests (the C ABI's
## example among them), then the Python package built in the same profile and its
## pytest suite against the binaries they built.
test: vulkan
	$(CARGO) test --no-fail-fast
	$(MAKE) python PYTHON_PROFILE=dev
	IASTGCN_PROFILE_DIR=target/debug $(PYTHON_VENV)/bin/python -m pytest -q python/tests

## The Python package (docs/embedding.md "Python"): a venv in $(PYTHON_VENV) with
## maturin, NumPy and pytest (python/requirements-dev.txt, from PyPI), the abi3 wheel
## built into target/wheels (compiled in target/python, apart from the plain builds: the
## module's library needs Python's symbols, the C ABI's must not) and installed there.
## `. $(PYTHON_VENV)/bin/activate`, then `import iastgcn`.
PYTHON_VENV ?= target/python-venv
PYTHON_PROFILE ?= release
python:
	@test -x $(PYTHON_VENV)/bin/python || python3 -m venv $(PYTHON_VENV)
	$(PYTHON_VENV)/bin/pip install -q -r python/requirements-dev.txt
	rm -f target/wheels/iastgcn-*.whl
	$(PYTHON_VENV)/bin/maturin build --profile $(PYTHON_PROFILE) --target-dir target/python --out target/wheels
	$(PYTHON_VENV)/bin/pip install -q --force-reinstall --no-deps target/wheels/iastgcn-*.whl

## Coverage-guided fuzzing of every reader and the C ABI (docs/robustness.md "Fuzzing"):
## cargo-afl (from crates.io when missing; it builds AFL++ for this rustc) instruments the
## targets of tests/fuzz/targets.rs on stable Rust, they write their seeds, and afl-fuzz
## runs each for FUZZ_SECONDS. Crashes land in $(FUZZ_DIR)/out/<target>/default/crashes;
## the command fails when there is any. Not part of `make test`.
FUZZ_SECONDS ?= 60
FUZZ_DIR ?= target/fuzz
FUZZ_BIN = target/afl/release/fuzz-targets
fuzz:
	@command -v cargo-afl >/dev/null || $(CARGO) install cargo-afl
	CARGO_TARGET_DIR=target/afl $(CARGO) afl build --release --features fuzz --bin fuzz-targets
	$(FUZZ_BIN) seeds $(FUZZ_DIR)/seeds
	mkdir -p $(FUZZ_DIR)/out
	@for t in $$($(FUZZ_BIN) list); do \
	  echo "== $$t: $(FUZZ_SECONDS) s"; \
	  AFL_NO_UI=1 AFL_SKIP_CPUFREQ=1 AFL_I_DONT_CARE_ABOUT_MISSING_CRASHES=1 \
	    $(CARGO) afl fuzz -V $(FUZZ_SECONDS) -i $(FUZZ_DIR)/seeds/$$t -o $(FUZZ_DIR)/out/$$t \
	    $(FUZZ_BIN) $$t > $(FUZZ_DIR)/$$t.log 2>&1 || { tail -n 20 $(FUZZ_DIR)/$$t.log; exit 1; }; \
	  grep -E "execs_done|corpus_count|saved_crashes|saved_hangs" $(FUZZ_DIR)/out/$$t/default/fuzzer_stats | tr -s ' ' | paste -sd' '; \
	done
	@crashes=$$(ls $(FUZZ_DIR)/out/*/default/crashes 2>/dev/null | grep -c '^id:'); \
	  echo "crashes found: $$crashes"; test "$$crashes" -eq 0

## The C ABI's libraries (docs/embedding.md "C"): target/release/libiastgcn.so and
## target/release/libiastgcn.a. The crate's own builds make only the Rust library.
c-library:
	$(CARGO) rustc --release --lib --crate-type cdylib,staticlib

## Regenerates the C header include/iastgcn.h from src/embed/c_api.rs (cbindgen).
header:
	IASTGCN_WRITE_HEADER=1 $(CARGO) test --test c_abi checked_in_header

## Regenerates the command-line reference docs/cli.md from the CLI's definitions
## (clap-markdown); `make test` fails while it differs.
cli-reference:
	IASTGCN_WRITE_CLI_REFERENCE=1 $(CARGO) test --bin iastgcn checked_in_cli_reference

DEMO_DIR ?= report

## The main job: the adapter and its kernels checked against the CPU, then `iastgcn demo`
## (twin recordings, EKF calibration, dataset, IASTGCN, its three ablations and the dense
## baselines trained with assets/demo.toml for training seeds 1–2, refinement, Table III
## on the held-out split, online compensation of held-out runs for Table V, both as
## mean ± SD over the seeds with paired comparisons, the mirror, the report folder).
## Outputs land in $(DEMO_DIR)/ (report.md is the entry point). Only the binary is built:
## the Predictor example (docs/embedding.md) would compile the test tools with it.
demo: vulkan
	$(CARGO) build --release --bin iastgcn
	./target/release/iastgcn info
	./target/release/iastgcn smoke
	./target/release/iastgcn demo --out $(DEMO_DIR)
	@echo "the forward pass embedded in Rust on these weights: cargo run --release --example predict -- $(DEMO_DIR)/models/iastgcn.seed1.safetensors (docs/embedding.md)"

PAPER_DIR ?= paper
PAPER_ARGS ?=
## The paper's protocol at the paper's sizes (docs/usage.md "reproduce"): every model ×
## seeds 1–3 on ~42k windows, in resumable jobs; run it again after an interruption.
## The data as the default recipe records them (docs/usage.md "Recipes"; PAPER_ARGS=
## "--recipe paper" for the paper's own single session).
## Days on lavapipe (docs/results.md "Reproduce"); meant for a real GPU or a cluster
## (PAPER_ARGS="--shard k/n" per machine, then once without).
paper: vulkan
	$(CARGO) build --release --bin iastgcn
	./target/release/iastgcn reproduce --out $(PAPER_DIR) $(PAPER_ARGS)

## Criterion benchmarks (matmul GFLOP/s, dispatch and submit costs).
bench: vulkan
	$(CARGO) bench

## The engine against PyTorch on the same CPU, in one run (docs/performance.md): a pinned
## PyTorch in a local venv (benches/pytorch/requirements.txt; from PyPI that is ~5 GB
## with its CUDA libraries, TORCH_INDEX=https://download.pytorch.org/whl/cpu fetches the
## CPU-only build where that index is reachable), an interop check of the PyTorch model
## on the engine's checkpoints, then `cargo bench --bench model` for the two shapes and
## the same measurements in PyTorch. Table in target/bench-compare/compare.md.
BENCH_VENV ?= target/bench-venv
TORCH_INDEX ?=
bench-compare: vulkan
	@test -x $(BENCH_VENV)/bin/python || python3 -m venv $(BENCH_VENV)
	$(BENCH_VENV)/bin/pip install -q $(if $(TORCH_INDEX),--extra-index-url $(TORCH_INDEX)) -r benches/pytorch/requirements.txt
	$(BENCH_VENV)/bin/python benches/pytorch/compare.py

## The mirror's heavy parts against NumPy on the same cores, in one call (docs/polishing.md
## "Compute"): `cargo bench --bench polish` (the dwell solve and a control tick's removal on
## 512² and 1024² maps; it writes each dwell problem with the engine's solution), then the
## same solver in NumPy (benches/numpy/dwell.py, in a local venv with numpy) on those
## problems: it checks it finds the same dwell, then times itself. Table in
## target/bench-polish/compare.md.
NUMPY_VENV ?= target/numpy-venv
bench-polish:
	$(CARGO) bench --bench polish
	@test -x $(NUMPY_VENV)/bin/python || python3 -m venv $(NUMPY_VENV)
	$(NUMPY_VENV)/bin/pip install -q -r benches/numpy/requirements.txt
	$(NUMPY_VENV)/bin/python benches/numpy/dwell.py

## Per-tick latency of the predictor from Rust, C and Python in one run (benches/embed.rs,
## docs/embedding.md "Latency"): the mean tick per language, then 10^6 ticks per language
## each timed alone (p50, p99, p99.9, max, resident memory, page faults); tables in
## target/bench-embed/latency.md.
bench-embed: python c-library
	$(CARGO) bench --bench embed

lint:
	$(CARGO) fmt --check
	$(CARGO) clippy --all-targets -- -D warnings
	$(CARGO) clippy --lib --features python -- -D warnings
	$(CARGO) clippy --features fuzz --bin fuzz-targets -- -D warnings
