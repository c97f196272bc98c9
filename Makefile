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

## Main job on what exists so far: adapter report, then every kernel checked and timed.
demo: vulkan
	$(CARGO) build --release
	./target/release/iastgcn info
	./target/release/iastgcn smoke

## Criterion benchmarks (matmul GFLOP/s, dispatch and submit costs).
bench: vulkan
	$(CARGO) bench

lint:
	$(CARGO) fmt --check
	$(CARGO) clippy --all-targets -- -D warnings
