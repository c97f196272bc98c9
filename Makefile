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

## Main job on what exists so far: the adapter and its kernels checked against the CPU,
## then the twin's calibration set and three polishing recordings, the EKF calibration
## with its before/after report, and the dataset summary. Outputs land in $(DEMO_DIR)/.
demo: vulkan
	$(CARGO) build --release
	./target/release/iastgcn info
	./target/release/iastgcn smoke
	mkdir -p $(DEMO_DIR)
	./target/release/iastgcn simulate --trajectory calibration --poses 80 --out $(DEMO_DIR)/calibration_set.csv
	for path in grid fermat hilbert; do \
	    ./target/release/iastgcn simulate --trajectory $$path --minutes 3 --seed 11 --out $(DEMO_DIR)/$$path.csv || exit 1; \
	done
	./target/release/iastgcn calibrate --measurements $(DEMO_DIR)/calibration_set.csv \
	    --out $(DEMO_DIR)/calibration.toml \
	    --recordings $(DEMO_DIR)/grid.csv $(DEMO_DIR)/fermat.csv $(DEMO_DIR)/hilbert.csv
	./target/release/iastgcn dataset --calibration $(DEMO_DIR)/calibration.toml \
	    --recordings $(DEMO_DIR)/grid.csv $(DEMO_DIR)/fermat.csv $(DEMO_DIR)/hilbert.csv
	printf 'window = 48\nchannels = 16\nblocks = 3\n' > $(DEMO_DIR)/small.toml
	./target/release/iastgcn init --config $(DEMO_DIR)/small.toml --seed 1 --out $(DEMO_DIR)/untrained.safetensors
	$(CARGO) run --release --example predict -- $(DEMO_DIR)/untrained.safetensors

## Criterion benchmarks (matmul GFLOP/s, dispatch and submit costs).
bench: vulkan
	$(CARGO) bench

lint:
	$(CARGO) fmt --check
	$(CARGO) clippy --all-targets -- -D warnings
