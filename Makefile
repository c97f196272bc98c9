# The two set-up commands are `make demo` and `make test` (see README.md).
# Both first make sure a Vulkan driver exists (installing Mesa lavapipe when root).

CARGO ?= cargo
export NODEVICE_SELECT ?= 1

.PHONY: vulkan test demo bench lint

vulkan:
	@.ci/ensure-vulkan

## Whole test suite (on lavapipe when there is no GPU).
test: vulkan
	$(CARGO) test --no-fail-fast

DEMO_DIR ?= report

## The main job: the adapter and its kernels checked against the CPU, then `iastgcn demo`
## (twin recordings, EKF calibration, dataset, IASTGCN and its three ablations trained
## with assets/demo.toml, refinement, Table III on the held-out split, online compensation
## of held-out runs for Table V, the report folder), and the Predictor example on the
## refined model. Outputs land in $(DEMO_DIR)/ (report.md is the entry point).
demo: vulkan
	$(CARGO) build --release --bin iastgcn --example predict
	./target/release/iastgcn info
	./target/release/iastgcn smoke
	./target/release/iastgcn demo --out $(DEMO_DIR)
	$(CARGO) run --release --example predict -- $(DEMO_DIR)/models/iastgcn-refined.safetensors

## Criterion benchmarks (matmul GFLOP/s, dispatch and submit costs).
bench: vulkan
	$(CARGO) bench

lint:
	$(CARGO) fmt --check
	$(CARGO) clippy --all-targets -- -D warnings
