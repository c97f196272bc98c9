# The two set-up commands are `make demo` and `make test` (see README.md).
# Both first make sure a Vulkan driver exists (installing Mesa lavapipe when root).

CARGO ?= cargo
export NODEVICE_SELECT ?= 1

.PHONY: vulkan test demo paper bench bench-compare lint

vulkan:
	@.ci/ensure-vulkan

## Whole test suite (on lavapipe when there is no GPU).
test: vulkan
	$(CARGO) test --no-fail-fast

DEMO_DIR ?= report

## The main job: the adapter and its kernels checked against the CPU, then `iastgcn demo`
## (twin recordings, EKF calibration, dataset, IASTGCN, its three ablations and the dense
## baselines trained with assets/demo.toml for training seeds 1–3, refinement, Table III
## on the held-out split, online compensation of held-out runs for Table V, both as
## mean ± SD over the seeds with paired comparisons, the report folder), and the Predictor
## example on seed 1's refined IASTGCN. Outputs land in $(DEMO_DIR)/ (report.md is the
## entry point).
demo: vulkan
	$(CARGO) build --release --bin iastgcn --example predict
	./target/release/iastgcn info
	./target/release/iastgcn smoke
	./target/release/iastgcn demo --out $(DEMO_DIR)
	$(CARGO) run --release --example predict -- $(DEMO_DIR)/models/iastgcn.seed1.safetensors

PAPER_DIR ?= paper
PAPER_ARGS ?=
## The paper's protocol at the paper's sizes (docs/usage.md "reproduce"): every model ×
## seeds 1–3 on ~42k windows, in resumable jobs; run it again after an interruption.
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

lint:
	$(CARGO) fmt --check
	$(CARGO) clippy --all-targets -- -D warnings
