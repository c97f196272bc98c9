//! A predictor a real-time loop can trust (docs/embedding.md "Real-time advice"): after
//! load, `push_step` + `predict_latest` on the native path should allocate nothing on the
//! heap, for every variant, counted by a global allocator that counts this thread's calls.
//!
//! Ignored until it holds (issue 54): every matrix product of the native path goes
//! through the `gemm` crate, which allocates on each call (its `did_pack_lhs` flags, and
//! a packing buffer when it packs), so the IASTGCN variants, T-GCN, EAT-GCN, ST-GAT and
//! ConvLSTM allocate once or twice per product; the dense models, whose products are
//! written out, allocate nothing. `cargo test --test zero_alloc -- --ignored` prints the
//! count per variant.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use iastgcn::graph::Graph;
use iastgcn::model::{Checkpoint, ModelConfig, Normalization, Parameters, Predictor, Variant};

struct Counting;

thread_local! {
    static COUNT: Cell<usize> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = COUNT.try_with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, size: usize) -> *mut u8 {
        let _ = COUNT.try_with(|c| c.set(c.get() + 1));
        unsafe { System.realloc(ptr, layout, size) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

fn allocations() -> usize {
    COUNT.with(|c| c.get())
}

/// Heap allocations per tick of `variant`'s native predictor, over `ticks` ticks after
/// its window is full and one prediction has run.
fn per_tick(variant: Variant, ticks: usize) -> f64 {
    let config = ModelConfig::gradient_check(variant);
    let ck = Checkpoint {
        parameters: Parameters::init(&config, 7),
        graph: Graph::default_asset(),
        normalization: Normalization::identity(&config),
        config,
    };
    let mut p = Predictor::native(&ck).unwrap();
    let step: Vec<f32> = (0..ck.config.nodes * ck.config.features)
        .map(|i| (i as f32 * 0.37).sin())
        .collect();
    for _ in 0..ck.config.window {
        p.push_step(&step).unwrap();
    }
    p.predict_latest().unwrap().unwrap();
    let before = allocations();
    for _ in 0..ticks {
        p.push_step(&step).unwrap();
        std::hint::black_box(p.predict_latest().unwrap());
    }
    (allocations() - before) as f64 / ticks as f64
}

#[test]
#[ignore = "issue 54: the gemm crate allocates on every product"]
fn the_native_tick_allocates_nothing_for_any_variant() {
    let counts: Vec<(Variant, f64)> = Variant::ALL.iter().map(|&v| (v, per_tick(v, 50))).collect();
    let allocating: Vec<String> = counts
        .iter()
        .filter(|(_, n)| *n > 0.0)
        .map(|(v, n)| format!("{}: {n} per tick", v.name()))
        .collect();
    assert!(allocating.is_empty(), "{allocating:?}");
}
