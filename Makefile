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
## with its before/after report, the dataset summary, IASTGCN trained with the demo
## config, refined (Algorithm 2), run on the held-out split and through the Predictor
## example. Outputs land in $(DEMO_DIR)/.
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
	./target/release/iastgcn train --config assets/demo.toml --calibration $(DEMO_DIR)/calibration.toml \
	    --data $(DEMO_DIR)/grid.csv $(DEMO_DIR)/fermat.csv $(DEMO_DIR)/hilbert.csv \
	    --out $(DEMO_DIR)/iastgcn.safetensors
	./target/release/iastgcn refine --config assets/demo.toml --calibration $(DEMO_DIR)/calibration.toml \
	    --data $(DEMO_DIR)/grid.csv $(DEMO_DIR)/fermat.csv $(DEMO_DIR)/hilbert.csv \
	    --model $(DEMO_DIR)/iastgcn.safetensors --out $(DEMO_DIR)/iastgcn-refined.safetensors
	./target/release/iastgcn predict --model $(DEMO_DIR)/iastgcn-refined.safetensors \
	    --calibration $(DEMO_DIR)/calibration.toml --split test \
	    --data $(DEMO_DIR)/grid.csv $(DEMO_DIR)/fermat.csv $(DEMO_DIR)/hilbert.csv \
	    --out $(DEMO_DIR)/residuals.csv
	$(CARGO) run --release --example predict -- $(DEMO_DIR)/iastgcn-refined.safetensors

## Criterion benchmarks (matmul GFLOP/s, dispatch and submit costs).
bench: vulkan
	$(CARGO) bench

lint:
	$(CARGO) fmt --check
	$(CARGO) clippy --all-targets -- -D warnings
