//! A predictor a real-time loop can trust (docs/embedding.md "Real-time advice"): after
//! load, a control tick on the native path allocates nothing on the heap, for every
//! variant, counted by a global allocator that counts this thread's calls. A tick is
//! `push_step` + `predict_latest` (features), `SensorPredictor::push` +
//! `predict_latest` (raw sensor values, what the C ABI and Python run), and the C entry
//! points `iastgcn_predictor_push` + `iastgcn_predictor_predict_latest` on a handle
//! loaded from a file, also from an ensemble file (its members' mean and interval). The
//! predictor's forward runs its matrix products on the in-place
//! kernels of `model/cpu/product.rs` (the `gemm` crate, which training uses,
//! allocates on every call).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::ffi::CString;

use iastgcn::compensate::SensorPredictor;
use iastgcn::embed::c_api::*;
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

/// Ticks counted per case, after the window is full and one prediction has run.
const TICKS: usize = 30;

fn checkpoint(config: ModelConfig) -> Checkpoint {
    Checkpoint {
        parameters: Parameters::init(&config, 7),
        graph: Graph::default_asset(),
        normalization: Normalization::identity(&config),
        config,
    }
}

/// Raw sensor value of `node` at `tick`, NaN (no sample) on some ticks as slow sensors
/// give them.
fn sensor(node: usize, tick: usize) -> f64 {
    if !tick.is_multiple_of(1 + node % 3) {
        return f64::NAN;
    }
    20.0 + node as f64 + 0.3 * ((tick * (node + 2)) as f64 * 0.05).sin()
}

/// Heap allocations over `TICKS` ticks of `tick` after `warm` ticks.
fn counted(warm: usize, mut tick: impl FnMut(usize)) -> usize {
    for t in 0..warm {
        tick(t);
    }
    let before = allocations();
    for t in warm..warm + TICKS {
        tick(t);
    }
    allocations() - before
}

/// Allocations of the feature path and of the sensor path of `config`'s native
/// predictor.
fn rust_ticks(config: &ModelConfig) -> (usize, usize) {
    let ck = checkpoint(config.clone());
    let (n, f, t) = (config.nodes, config.features, config.window);
    let mut p = Predictor::native(&ck).unwrap();
    let step: Vec<f32> = (0..n * f).map(|i| (i as f32 * 0.37).sin()).collect();
    let features = counted(t + 1, |_| {
        p.push_step(&step).unwrap();
        std::hint::black_box(p.predict_latest().unwrap());
    });
    let mut s = SensorPredictor::native(&ck, 0.02).unwrap();
    let frames: Vec<Vec<f64>> = (0..t + 1 + TICKS)
        .map(|tick| (0..n).map(|node| sensor(node, tick)).collect())
        .collect();
    let sensors = counted(t + 1, |tick| {
        s.push(&frames[tick]).unwrap();
        std::hint::black_box(s.predict_latest().unwrap());
    });
    (features, sensors)
}

#[test]
fn the_native_tick_allocates_nothing_for_any_variant() {
    let mut allocating = Vec::new();
    for variant in Variant::ALL {
        let (features, sensors) = rust_ticks(&ModelConfig::gradient_check(variant));
        if features + sensors > 0 {
            allocating.push(format!(
                "{}: {features} (features) and {sensors} (sensor values) in {TICKS} ticks",
                variant.name()
            ));
        }
    }
    assert!(allocating.is_empty(), "{allocating:?}");
}

/// The paper's shape (C 64, T 100, L 5): its products span several panels of k and
/// tiles, and the gated convolution's is the size the thread split would take.
#[test]
fn the_native_tick_allocates_nothing_at_the_papers_shape() {
    let (features, sensors) = rust_ticks(&ModelConfig::default());
    assert_eq!((features, sensors), (0, 0), "allocations in {TICKS} ticks");
}

/// Through the C ABI, as a controller in C calls it, for an IASTGCN variant and the
/// recurrent baselines (a handle loaded from a checkpoint file, backend native).
#[test]
fn the_c_tick_allocates_nothing() {
    let dir = std::env::temp_dir().join(format!("iastgcn-zero-alloc-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for variant in [
        Variant::Iastgcn,
        Variant::NoAttention,
        Variant::Tgcn,
        Variant::ConvLstm,
    ] {
        let config = ModelConfig::gradient_check(variant);
        let (n, t) = (config.nodes, config.window);
        let path = dir.join(format!("{}.safetensors", variant.name()));
        checkpoint(config).save(&path).unwrap();
        let path = CString::new(path.to_str().unwrap()).unwrap();
        let mut handle = std::ptr::null_mut();
        // SAFETY: a NUL-terminated path and a writable handle pointer.
        let status = unsafe {
            iastgcn_predictor_load(path.as_ptr(), 0.02, IastgcnBackend::Native, &mut handle)
        };
        assert_eq!(status, IastgcnStatus::Ok, "{}", variant.name());
        let frames: Vec<Vec<f64>> = (0..t + 1 + TICKS)
            .map(|tick| (0..n).map(|node| sensor(node, tick)).collect())
            .collect();
        let mut out = [0f64; 6];
        let mut statuses = Vec::with_capacity(t + 1 + TICKS);
        let allocated = counted(t + 1, |tick| {
            // SAFETY: a live handle, a frame of N doubles, room for 6.
            unsafe {
                let pushed = iastgcn_predictor_push(handle, frames[tick].as_ptr(), n);
                let predicted = iastgcn_predictor_predict_latest(handle, out.as_mut_ptr());
                statuses.push((pushed, predicted));
            }
        });
        // Every tick counted predicted (the window was full before them).
        let counted_statuses = &statuses[t + 1..];
        assert!(
            counted_statuses
                .iter()
                .all(|&s| s == (IastgcnStatus::Ok, IastgcnStatus::Ok)),
            "{}: {counted_statuses:?}",
            variant.name()
        );
        assert!(out.iter().all(|v| v.is_finite()));
        // SAFETY: the live handle from above, not used again.
        unsafe { iastgcn_predictor_free(handle) };
        assert_eq!(
            allocated,
            0,
            "{}: allocations in {TICKS} ticks",
            variant.name()
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// An ensemble file through the C ABI: each tick pushes into every member, predicts
/// their mean and reads the interval, allocating nothing.
#[test]
fn the_ensemble_tick_allocates_nothing() {
    use iastgcn::compensate::{EnsembleFile, IntervalCalibration, Radius};
    let dir = std::env::temp_dir().join(format!("iastgcn-zero-alloc-e-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let config = ModelConfig::gradient_check(Variant::Iastgcn);
    let (n, t) = (config.nodes, config.window);
    let mut members = Vec::new();
    for seed in [7, 8] {
        let mut ck = checkpoint(config.clone());
        ck.parameters = Parameters::init(&config, seed);
        let name = format!("m.seed{seed}.safetensors");
        ck.save(&dir.join(&name)).unwrap();
        members.push(name.into());
    }
    let file = EnsembleFile {
        members,
        calibrated_on: String::new(),
        interval: Some(IntervalCalibration {
            level: 0.9,
            position: Radius {
                scale: 3.0,
                constant: 0.0,
            },
            attitude: Radius {
                scale: 0.0,
                constant: 20.0,
            },
        }),
    };
    let path = dir.join("m.ensemble.toml");
    file.write(&path).unwrap();
    let path = CString::new(path.to_str().unwrap()).unwrap();
    let mut handle = std::ptr::null_mut();
    // SAFETY: a NUL-terminated path and a writable handle pointer.
    let status =
        unsafe { iastgcn_predictor_load(path.as_ptr(), 0.02, IastgcnBackend::Native, &mut handle) };
    assert_eq!(status, IastgcnStatus::Ok);
    let frames: Vec<Vec<f64>> = (0..t + 1 + TICKS)
        .map(|tick| (0..n).map(|node| sensor(node, tick)).collect())
        .collect();
    let (mut out, mut radii) = ([0f64; 6], [0f64; 3]);
    let mut statuses = Vec::with_capacity(t + 1 + TICKS);
    let allocated = counted(t + 1, |tick| {
        // SAFETY: a live handle, a frame of N doubles, room for 6 and for 3.
        unsafe {
            let pushed = iastgcn_predictor_push(handle, frames[tick].as_ptr(), n);
            let predicted = iastgcn_predictor_predict_latest(handle, out.as_mut_ptr());
            let [p, a, l] = &mut radii;
            let interval = iastgcn_predictor_interval(handle, p, a, l);
            statuses.push((pushed, predicted, interval));
        }
    });
    let ok = (IastgcnStatus::Ok, IastgcnStatus::Ok, IastgcnStatus::Ok);
    assert!(statuses[t + 1..].iter().all(|&s| s == ok), "{statuses:?}");
    assert!(
        radii[0] > 0.0 && radii[1] == 20.0 && radii[2] == 0.9,
        "{radii:?}"
    );
    // SAFETY: the live handle from above, not used again.
    unsafe { iastgcn_predictor_free(handle) };
    assert_eq!(allocated, 0, "allocations in {TICKS} ticks");
    std::fs::remove_dir_all(&dir).unwrap();
}
