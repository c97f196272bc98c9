//! Preprocessing: hold, causal low-pass, differences, the entropy of eq. 20–22 against
//! hand-computed values, and windows/splits that never leak.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use iastgcn::data::features::{differences, entropy, hold, low_pass, node_features, Stream};
use iastgcn::data::{
    prepare, split, tracker_columns, window_ends, FeatureConfig, Recording, Row, SplitMode, Window,
    WindowConfig,
};
use iastgcn::graph::Graph;
use iastgcn::robot::{Geometry, Robot};
use iastgcn::testing::rng;
use iastgcn::twin::{draw_machine, Mirror, PathKind, SimConfig, Simulation, CHANNELS};
use rand::RngExt;

/// Counts this thread's allocations, to show that [`Stream::push`] makes none.
struct Counting;

thread_local! {
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn entropy_matches_hand_computed_values() {
    let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
    // w = 2 over D = [0, 1, 1]: [0] → 0; [0, 1] → p = (0, 1) → 0; [1, 1] → 1 bit / log2 2.
    let h = entropy(&[0.0, 1.0, 1.0], 2);
    assert!(
        close(h[0], 0.0) && close(h[1], 0.0) && close(h[2], 1.0),
        "{h:?}"
    );
    // w = 4 over D = [0, 1, 2, 1]: p = (0, ¼, ½, ¼) → 1.5 bits / log2 4 = 0.75.
    assert!(close(entropy(&[0.0, 1.0, 2.0, 1.0], 4)[3], 0.75));
    // Magnitudes count, not signs: D = [0, −3, 3], w = 3 → 1 bit / log2 3.
    assert!(close(entropy(&[0.0, -3.0, 3.0], 3)[2], 1.0 / 3f64.log2()));
    // No change at all: 0, not NaN.
    assert!(entropy(&[0.0; 30], 20).iter().all(|&v| v == 0.0));
    // A steady ramp spreads evenly: the maximum, 1.
    let ramp: Vec<f64> = (0..40).map(|i| i as f64).collect();
    assert!(close(entropy(&differences(&ramp), 20)[39], 1.0));
}

#[test]
fn hold_filter_and_differences_are_causal() {
    assert_eq!(
        hold(&[None, Some(2.0), None, None, Some(5.0), None]).unwrap(),
        [2.0, 2.0, 2.0, 2.0, 5.0, 5.0]
    );
    assert!(hold(&[None, None]).is_none());
    // Low-pass: a step rises monotonically towards its value, and a change at step k
    // never moves the output before k.
    let step: Vec<f64> = (0..100).map(|i| if i < 50 { 0.0 } else { 1.0 }).collect();
    let y = low_pass(&step, 0.02, 5.0);
    assert!(y[..50].iter().all(|&v| v == 0.0));
    assert!(y[50] > 0.0 && y.windows(2).all(|w| w[1] >= w[0]) && y[99] > 0.99);
    // First-order with τ = 1/(2π·5 Hz): after one τ (≈ 1.6 samples) about 1 − 1/e.
    assert_eq!(differences(&[1.0, 4.0, 2.0]), [0.0, 3.0, -2.0]);
}

#[test]
fn no_test_window_shares_a_step_with_a_training_window() {
    let mut r = rng(17);
    for _ in 0..200 {
        let config = WindowConfig {
            length: r.random_range(5..60),
            stride: r.random_range(1..25),
            ..WindowConfig::default()
        };
        let rows: Vec<usize> = (0..r.random_range(1..4))
            .map(|_| r.random_range(10..600))
            .collect();
        let windows: Vec<Window> = rows
            .iter()
            .enumerate()
            .flat_map(|(rec, &n)| {
                window_ends(n, &config, |_| true)
                    .into_iter()
                    .map(move |end| Window {
                        recording: rec,
                        end,
                    })
            })
            .collect();
        let s = split(&windows, &rows, &config, SplitMode::Contiguous);
        let steps = |w: &Window| (w.end + 1 - config.length)..=w.end;
        for (name, held) in [("validation", &s.validation), ("test", &s.test)] {
            for h in held {
                for t in &s.train {
                    let (a, b) = (steps(t), steps(h));
                    let overlap =
                        t.recording == h.recording && a.start() <= b.end() && b.start() <= a.end();
                    assert!(
                        !overlap,
                        "{name} window {h:?} overlaps training window {t:?} ({config:?})"
                    );
                }
            }
        }
        for v in &s.validation {
            for t in &s.test {
                assert!(
                    v.recording != t.recording || v.end < *steps(t).start(),
                    "validation {v:?} overlaps test {t:?}"
                );
            }
        }
        // Every window lands in at most one split.
        assert!(s.train.len() + s.validation.len() + s.test.len() <= windows.len());
    }
}

#[test]
fn random_mode_is_seeded_and_labelled() {
    let config = WindowConfig::default();
    let windows: Vec<Window> = (0..50)
        .map(|i| Window {
            recording: 0,
            end: 99 + 20 * i,
        })
        .collect();
    let a = split(&windows, &[2000], &config, SplitMode::Random { seed: 3 });
    assert_eq!(
        a,
        split(&windows, &[2000], &config, SplitMode::Random { seed: 3 })
    );
    assert_eq!(
        (a.train.len(), a.validation.len(), a.test.len()),
        (35, 10, 5)
    );
    assert!(SplitMode::Random { seed: 3 }.describe().contains("leak"));
}

/// 12 s of the grid path from the twin, starting `skip` ticks in so that the slow sensors
/// (tilt every 5th tick, force every 2nd) first report a few rows into the recording.
fn twin_recording(skip: usize) -> Recording {
    let g = Geometry::default_asset();
    let machine = draw_machine(g.clone(), 1);
    let nominal = Robot::nominal(g);
    let mut sim = Simulation::new(
        &machine,
        &nominal,
        Mirror::default(),
        SimConfig::new(PathKind::Grid, 12.0, 5),
    )
    .unwrap();
    let mut rows = Vec::new();
    while let Some(s) = sim.step() {
        let s = s.unwrap();
        rows.push(Row {
            t: s.t,
            values: s.channels.to_vec(),
            tracker: s.tracker.map(|p| tracker_columns(&p)),
        });
    }
    Recording {
        channels: CHANNELS.iter().map(|c| c.to_string()).collect(),
        rows: rows.split_off(skip),
    }
}

/// Streams `rec`'s graph channels tick by tick; returns `[row][n * 3 + f]` and, per row,
/// whether every node had had a sample.
fn stream(
    rec: &Recording,
    graph: &Graph,
    dt: f64,
    config: &FeatureConfig,
) -> (Vec<Vec<f64>>, Vec<bool>) {
    let columns: Vec<usize> = graph
        .nodes
        .iter()
        .map(|n| rec.channels.iter().position(|c| c == n).unwrap())
        .collect();
    let mut s = Stream::new(graph.len(), dt, config);
    let mut values = vec![None; graph.len()];
    let mut out = vec![f64::NAN; graph.len() * 3];
    let (mut features, mut ready) = (Vec::new(), Vec::new());
    for row in &rec.rows {
        for (v, &c) in values.iter_mut().zip(&columns) {
            *v = row.values[c];
        }
        let before = ALLOCATIONS.with(Cell::get);
        let all = s.push(&values, &mut out);
        assert_eq!(ALLOCATIONS.with(Cell::get), before, "push allocated");
        ready.push(all);
        features.push(out.clone());
    }
    (features, ready)
}

#[test]
fn the_stream_gives_the_batch_features_from_the_first_complete_row() {
    let skip = 3;
    let rec = twin_recording(skip);
    let graph = Graph::default_asset();
    let nominal = Robot::nominal(Geometry::default_asset());
    // `prepare` takes the control period from the first two rows' times; so does the
    // stream here, for bit-equal features.
    let dt = rec.rows[1].t - rec.rows[0].t;
    for config in [
        FeatureConfig::default(),
        FeatureConfig {
            cutoff_hz: 1.5,
            entropy_window: 7,
        },
    ] {
        let batch = prepare("grid.csv", &rec, &graph, &nominal, &config).unwrap();
        let (streamed, ready) = stream(&rec, &graph, dt, &config);
        // The tilt sensors report every 5th tick: from tick 5, row 5 − skip.
        let first = ready.iter().position(|&r| r).unwrap();
        assert_eq!(first, 5 - skip);
        assert!(ready[first..].iter().all(|&r| r));
        let (mut worst, mut identical, mut total) = (0.0f64, 0, 0);
        for (n, node) in batch.features.iter().enumerate() {
            // `prepare` is `node_features(hold(..))` per node.
            let c = rec
                .channels
                .iter()
                .position(|c| c == &graph.nodes[n])
                .unwrap();
            let held = hold(&rec.rows.iter().map(|r| r.values[c]).collect::<Vec<_>>()).unwrap();
            assert_eq!(&node_features(&held, dt, &config), node);
            // Before its first sample a node's stream features are 0.
            let own_first = rec.rows.iter().position(|r| r.values[c].is_some()).unwrap();
            for row in &streamed[..own_first] {
                assert_eq!(&row[n * 3..n * 3 + 3], &[0.0; 3]);
            }
            for (f, series) in node.iter().enumerate() {
                for (row, &want) in series.iter().enumerate().skip(first) {
                    let got = streamed[row][n * 3 + f];
                    let rel = if got == want {
                        identical += 1;
                        0.0
                    } else {
                        (got - want).abs() / want.abs().max(f64::MIN_POSITIVE)
                    };
                    total += 1;
                    worst = worst.max(rel);
                    assert!(
                        rel <= 1e-9,
                        "{config:?} node {} feature {f} row {row}: stream {got} batch {want}",
                        graph.nodes[n]
                    );
                }
            }
        }
        println!(
            "{config:?}: {identical} of {total} stream values bit-identical, worst relative difference {worst:e}"
        );
    }
}
