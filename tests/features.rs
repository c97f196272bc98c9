//! Preprocessing: hold, causal low-pass, differences, the entropy of eq. 20–22 against
//! hand-computed values, and windows/splits that never leak.

use iastgcn::data::features::{differences, entropy, hold, low_pass};
use iastgcn::data::{split, window_ends, SplitMode, Window, WindowConfig};
use iastgcn::testing::rng;
use rand::RngExt;

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
