//! The step's kernels on the device. Channel LayerNorm: forward vs the f64 reference,
//! input and parameter gradients vs the f64 backward, and the f64 backward vs central
//! differences, on ragged shapes. Dropout: the GPU mask equals the CPU hash bit for bit,
//! forward and backward use the same mask, the kept fraction is 1 − p, and steps and
//! seeds change the mask.
#![cfg(test)]

use super::dropout_kernel::{keep, keep_run, Dropout};
use super::layer_norm_kernel::{cpu, LayerNorm};
use crate::gpu::{DType, Gpu, Tensor};
use crate::ops::Accumulate;
use crate::testing::{
    check_gradient, compare_tensor, dot, gpu, rng, round_f32, to_f32, uniform, Tolerance,
};

fn upload(g: &Gpu, name: &str, data: &[f64]) -> Tensor {
    g.upload(name, &[data.len()], &to_f32(data)).unwrap()
}

/// Ragged shapes, including C = 64 and T not a multiple of anything, and more rows than
/// one workgroup; then T multiples of 4 (four rows per invocation), again past one
/// workgroup; last, rows enough for the parameter gradients to be split into 6 slices
/// of the outer axis, the last one short (`LayerNorm::grad_slices`).
const SHAPES: [(usize, usize, usize); 9] = [
    (1, 1, 1),
    // Steps longer than, and equal to, the 256 rows a parameter-gradient group strides by.
    (3, 6, 300),
    (2, 5, 256),
    (3, 5, 7),
    (2, 64, 13),
    (29, 16, 11),
    (3, 16, 8),
    (100, 8, 16),
    (29, 8, 1700),
];

#[test]
fn forward_and_backward_match_reference() {
    let g = gpu();
    let quads = SHAPES.map(|(o, c, t)| LayerNorm::new(o, c, t).quads());
    assert!(quads.contains(&true) && quads.contains(&false));
    for (i, &(outer, channels, steps)) in SHAPES.iter().enumerate() {
        let ln = LayerNorm::new(outer, channels, steps);
        let mut r = rng(i as u64);
        let x = round_f32(&uniform(&mut r, ln.len(), -2.0, 3.0));
        let gamma = round_f32(&uniform(&mut r, channels, 0.5, 1.5));
        let beta = round_f32(&uniform(&mut r, channels, -0.5, 0.5));
        let dy = round_f32(&uniform(&mut r, ln.len(), -1.0, 1.0));
        let (xt, gt, bt, dyt) = (
            upload(&g, "x", &x),
            upload(&g, "gamma", &gamma),
            upload(&g, "beta", &beta),
            upload(&g, "dy", &dy),
        );
        let z = |n: &str, len: usize| g.zeros(n, &[len], DType::F32).unwrap();
        let (y, mean, rstd) = (z("y", ln.len()), z("mean", ln.rows()), z("rstd", ln.rows()));
        let (dx, dg, db) = (
            z("dx", ln.len()),
            z("dgamma", channels),
            z("dbeta", channels),
        );
        g.run(&[
            ln.forward(&g, &xt, &gt, &bt, &y, &mean, &rstd).unwrap(),
            ln.backward_input(&g, &xt, &gt, &dyt, &mean, &rstd, &dx, Accumulate::Overwrite)
                .unwrap(),
            ln.backward_params(&g, &xt, &dyt, &mean, &rstd, &dg, &db, Accumulate::Overwrite)
                .unwrap(),
        ])
        .unwrap();
        let what = format!("{ln:?}");
        // Normalised values are O(1); sums over C of O(1) terms.
        let tol = Tolerance::new(2e-5, 2e-5);
        compare_tensor(
            &g,
            &format!("{what} y"),
            &y,
            &cpu::forward(&ln, &x, &gamma, &beta),
            tol,
        )
        .unwrap();
        let (dx_ref, dg_ref, db_ref) = cpu::backward(&ln, &x, &gamma, &dy);
        // With C = 1 every normalised value is 0 and dx is 0: only rounding is left.
        compare_tensor(
            &g,
            &format!("{what} dx"),
            &dx,
            &dx_ref,
            Tolerance::new(5e-5, 5e-5),
        )
        .unwrap();
        let rows = (outer * steps) as f64;
        let sum_tol = Tolerance::new(2e-6 * rows.sqrt() * 4.0, 1e-4);
        compare_tensor(&g, &format!("{what} dgamma"), &dg, &dg_ref, sum_tol).unwrap();
        compare_tensor(&g, &format!("{what} dbeta"), &db, &db_ref, sum_tol).unwrap();
    }
}

#[test]
fn reference_backward_matches_finite_differences() {
    for (i, &(outer, channels, steps)) in SHAPES.iter().take(3).enumerate() {
        let ln = LayerNorm::new(outer, channels, steps);
        let mut r = rng(40 + i as u64);
        let x = uniform(&mut r, ln.len(), -2.0, 3.0);
        let gamma = uniform(&mut r, channels, 0.5, 1.5);
        let beta = uniform(&mut r, channels, -0.5, 0.5);
        let dy = uniform(&mut r, ln.len(), -1.0, 1.0);
        let (dx, dg, db) = cpu::backward(&ln, &x, &gamma, &dy);
        let tol = Tolerance::new(1e-7, 1e-6);
        let what = format!("{ln:?}");
        check_gradient(
            &format!("{what} dx"),
            &dx,
            |x| dot(&dy, &cpu::forward(&ln, x, &gamma, &beta)),
            &x,
            1e-5,
            tol,
        )
        .unwrap();
        check_gradient(
            &format!("{what} dgamma"),
            &dg,
            |gm| dot(&dy, &cpu::forward(&ln, &x, gm, &beta)),
            &gamma,
            1e-5,
            tol,
        )
        .unwrap();
        check_gradient(
            &format!("{what} dbeta"),
            &db,
            |b| dot(&dy, &cpu::forward(&ln, &x, &gamma, b)),
            &beta,
            1e-5,
            tol,
        )
        .unwrap();
    }
}

#[test]
fn gradients_accumulate_when_asked() {
    let g = gpu();
    // Unsplit, and split into 2 slices (the slices' sum accumulates, not each slice).
    for (outer, steps) in [(4, 5), (30, 600)] {
        let ln = LayerNorm::new(outer, 8, steps);
        assert_eq!(ln.grad_slices().0, if outer == 4 { 1 } else { 2 });
        accumulates(&g, ln);
    }
}

fn accumulates(g: &Gpu, ln: LayerNorm) {
    let mut r = rng(9);
    let x = round_f32(&uniform(&mut r, ln.len(), -1.0, 1.0));
    let gamma = round_f32(&uniform(&mut r, 8, 0.5, 1.5));
    let dy = round_f32(&uniform(&mut r, ln.len(), -1.0, 1.0));
    let (xt, gt, dyt) = (
        upload(g, "x", &x),
        upload(g, "gamma", &gamma),
        upload(g, "dy", &dy),
    );
    let beta = g.zeros("beta", &[8], DType::F32).unwrap();
    let z = |n: &str, len: usize| g.zeros(n, &[len], DType::F32).unwrap();
    let (y, mean, rstd) = (z("y", ln.len()), z("mean", ln.rows()), z("rstd", ln.rows()));
    let dx = upload(g, "dx", &vec![1.0; ln.len()]);
    let (dg, db) = (
        upload(g, "dgamma", &[2.0; 8]),
        upload(g, "dbeta", &[3.0; 8]),
    );
    g.run(&[
        ln.forward(g, &xt, &gt, &beta, &y, &mean, &rstd).unwrap(),
        ln.backward_input(g, &xt, &gt, &dyt, &mean, &rstd, &dx, Accumulate::Add)
            .unwrap(),
        ln.backward_params(g, &xt, &dyt, &mean, &rstd, &dg, &db, Accumulate::Add)
            .unwrap(),
    ])
    .unwrap();
    let (dx_ref, dg_ref, db_ref) = cpu::backward(&ln, &x, &gamma, &dy);
    let plus = |v: &[f64], c: f64| v.iter().map(|a| a + c).collect::<Vec<_>>();
    let tol = Tolerance::new(3e-5, 3e-5);
    compare_tensor(g, "dx", &dx, &plus(&dx_ref, 1.0), tol).unwrap();
    compare_tensor(g, "dgamma", &dg, &plus(&dg_ref, 2.0), tol).unwrap();
    compare_tensor(g, "dbeta", &db, &plus(&db_ref, 3.0), tol).unwrap();
}

#[test]
fn relu_input_masks_the_input_gradient() {
    let g = gpu();
    // Four rows per invocation and one.
    for (outer, channels, steps) in [(6, 16, 8), (5, 7, 3)] {
        let ln = LayerNorm {
            relu_input: true,
            ..LayerNorm::new(outer, channels, steps)
        };
        let mut r = rng(77 + steps as u64);
        // A ReLU's output: about half exact zeros.
        let x: Vec<f64> = round_f32(&uniform(&mut r, ln.len(), -1.0, 1.0))
            .iter()
            .map(|v| v.max(0.0))
            .collect();
        let gamma = round_f32(&uniform(&mut r, channels, 0.5, 1.5));
        let dy = round_f32(&uniform(&mut r, ln.len(), -1.0, 1.0));
        let (xt, gt, dyt) = (
            upload(&g, "x", &x),
            upload(&g, "gamma", &gamma),
            upload(&g, "dy", &dy),
        );
        let z = |n: &str, len: usize| g.zeros(n, &[len], DType::F32).unwrap();
        let beta = z("beta", channels);
        let (y, mean, rstd, dx) = (
            z("y", ln.len()),
            z("mean", ln.rows()),
            z("rstd", ln.rows()),
            z("dx", ln.len()),
        );
        g.run(&[
            ln.forward(&g, &xt, &gt, &beta, &y, &mean, &rstd).unwrap(),
            ln.backward_input(&g, &xt, &gt, &dyt, &mean, &rstd, &dx, Accumulate::Overwrite)
                .unwrap(),
        ])
        .unwrap();
        let (dx_ref, _, _) = cpu::backward(&ln, &x, &gamma, &dy);
        let masked: Vec<f64> = dx_ref
            .iter()
            .zip(&x)
            .map(|(d, x)| if *x > 0.0 { *d } else { 0.0 })
            .collect();
        assert!(masked.iter().zip(&dx_ref).any(|(m, d)| m != d));
        compare_tensor(&g, "dx masked", &dx, &masked, Tolerance::new(3e-5, 3e-5)).unwrap();
    }
}

#[test]
fn fused_dropout_gives_the_dropout_ops_mask_forward_and_backward() {
    // The dropout of a training step fused into the LayerNorm (docs/model.md step 7): the
    // forward writes mask ⊙ y/(1 − p), the backward kernels read the gradient of that
    // output through the same mask, bit for bit `dropout_kernel`'s, at the step set by
    // `set_step`; a strided mask (the trimmed last block's) as well. Four rows per
    // invocation and one.
    let g = gpu();
    // The last shape's parameter gradients are split into 2 slices: `set_step` moves the
    // mask of the launch that reads the gradient, the first.
    let shapes = [
        (6, 16, 8, false),
        (5, 7, 3, false),
        (9, 5, 1, true),
        (30, 4, 600, false),
    ];
    for (outer, channels, steps, strided) in shapes {
        let plain = LayerNorm::new(outer, channels, steps);
        let whole = Dropout::new(plain.len() * 7, 0.3, 11);
        let dropout = if strided {
            whole.strided(plain.len(), 7, 6)
        } else {
            Dropout::new(plain.len(), 0.3, 11)
        };
        let mut r = rng(90 + steps as u64);
        let x = round_f32(&uniform(&mut r, plain.len(), -2.0, 3.0));
        let gamma = round_f32(&uniform(&mut r, channels, 0.5, 1.5));
        let beta = round_f32(&uniform(&mut r, channels, -0.5, 0.5));
        let dy = round_f32(&uniform(&mut r, plain.len(), -1.0, 1.0));
        let (xt, gt, bt, dyt) = (
            upload(&g, "x", &x),
            upload(&g, "gamma", &gamma),
            upload(&g, "beta", &beta),
            upload(&g, "d output", &dy),
        );
        let z = |n: &str, len: usize| g.zeros(n, &[len], DType::F32).unwrap();
        let (y, mean, rstd) = (
            z("output", plain.len()),
            z("mean", plain.rows()),
            z("rstd", plain.rows()),
        );
        let (dx, dg, db) = (
            z("dx", plain.len()),
            z("dgamma", channels),
            z("dbeta", channels),
        );
        let ln = LayerNorm {
            dropout: Some(dropout),
            ..plain
        };
        let run = [
            ln.forward(&g, &xt, &gt, &bt, &y, &mean, &rstd).unwrap(),
            ln.backward_input(&g, &xt, &gt, &dyt, &mean, &rstd, &dx, Accumulate::Overwrite)
                .unwrap(),
            ln.backward_params(&g, &xt, &dyt, &mean, &rstd, &dg, &db, Accumulate::Overwrite)
                .unwrap(),
        ];
        let tol = Tolerance::new(3e-5, 3e-5);
        let mut dropped_at = Vec::new();
        for step in [3, 4] {
            for d in &run {
                ln.set_step(&g, d, step, Accumulate::Overwrite).unwrap();
            }
            g.run(&run).unwrap();
            let kept: Vec<bool> = (0..ln.len()).map(|i| keep(&dropout, step, i)).collect();
            let scale = 1.0 / (1.0 - dropout.p);
            let mask = |v: &[f64]| -> Vec<f64> {
                v.iter()
                    .zip(&kept)
                    .map(|(v, &k)| if k { v * scale } else { 0.0 })
                    .collect()
            };
            let what = format!("{ln:?} step {step}");
            let want = mask(&cpu::forward(&plain, &x, &gamma, &beta));
            compare_tensor(&g, &format!("{what} output"), &y, &want, tol).unwrap();
            let (dx_ref, dg_ref, db_ref) = cpu::backward(&plain, &x, &gamma, &mask(&dy));
            compare_tensor(&g, &format!("{what} dx"), &dx, &dx_ref, tol).unwrap();
            compare_tensor(&g, &format!("{what} dgamma"), &dg, &dg_ref, tol).unwrap();
            compare_tensor(&g, &format!("{what} dbeta"), &db, &db_ref, tol).unwrap();
            let got = g.read_f32(&y).unwrap();
            let zeros: Vec<bool> = got.iter().map(|&v| v == 0.0).collect();
            assert!(
                zeros.iter().zip(&kept).all(|(z, k)| *z != *k),
                "{what}: exactly the dropped elements are zero"
            );
            dropped_at.push(zeros);
        }
        assert_ne!(dropped_at[0], dropped_at[1], "the mask follows the step");
        // A dropout over another number of elements is refused, naming it.
        let wrong = LayerNorm {
            dropout: Some(Dropout::new(plain.len() + 1, 0.3, 11)),
            ..plain
        };
        let err = wrong
            .forward(&g, &xt, &gt, &bt, &y, &mean, &rstd)
            .unwrap_err()
            .to_string();
        assert!(err.contains("dropout fused"), "{err}");
    }
}

// The dropout kernel on its own (dropout_kernel.rs).

#[test]
fn mask_matches_the_cpu_hash_and_scales_kept_values() {
    let g = gpu();
    let n = 100_003;
    let d = Dropout::new(n, 0.2, 1234);
    let x: Vec<f32> = (0..n).map(|i| 1.0 + (i % 7) as f32).collect();
    let xt = g.upload("x", &[n], &x).unwrap();
    let y = g.zeros("y", &[n], DType::F32).unwrap();
    g.run(&[d.apply(&g, 5, &xt, &y, Accumulate::Overwrite).unwrap()])
        .unwrap();
    let got = g.read_f32(&y).unwrap();
    let scale = (1.0 / 0.8f64) as f32;
    let mut kept = 0;
    for i in 0..n {
        let want = if keep(&d, 5, i) { x[i] * scale } else { 0.0 };
        assert_eq!(got[i], want, "element {i}");
        kept += usize::from(keep(&d, 5, i));
    }
    // Kept fraction 0.8 ± 4σ of a binomial.
    let frac = kept as f64 / n as f64;
    let sigma = (0.2 * 0.8 / n as f64).sqrt();
    assert!((frac - 0.8).abs() < 4.0 * sigma, "kept {frac}");
}

#[test]
fn backward_uses_the_forward_mask_and_steps_change_it() {
    let g = gpu();
    let n = 4096;
    let d = Dropout::new(n, 0.5, 7);
    let ones = g.upload("ones", &[n], &vec![1.0; n]).unwrap();
    let (y, dx) = (
        g.zeros("y", &[n], DType::F32).unwrap(),
        g.zeros("dx", &[n], DType::F32).unwrap(),
    );
    let fwd = d.apply(&g, 11, &ones, &y, Accumulate::Overwrite).unwrap();
    let bwd = d.apply(&g, 11, &ones, &dx, Accumulate::Overwrite).unwrap();
    g.run(&[fwd, bwd]).unwrap();
    let (a, b) = (g.read_f32(&y).unwrap(), g.read_f32(&dx).unwrap());
    assert_eq!(a, b, "forward and backward masks differ");
    // The same dispatch pointed at the next step gives another mask.
    let next = d.apply(&g, 11, &ones, &y, Accumulate::Overwrite).unwrap();
    d.set_step(&g, &next, 12, Accumulate::Overwrite).unwrap();
    g.run(&[next]).unwrap();
    let c = g.read_f32(&y).unwrap();
    let same = a.iter().zip(&c).filter(|(p, q)| p == q).count();
    assert!(
        (same as f64 / n as f64 - 0.5).abs() < 0.05,
        "step 12 agrees with step 11 on {same} of {n}"
    );
    let other_seed = Dropout { seed: 8, ..d };
    assert!((0..n).any(|i| keep(&d, 11, i) != keep(&other_seed, 11, i)));
}

#[test]
fn a_strided_subset_gets_the_bits_of_the_whole_tensor() {
    let g = gpu();
    // The last of 48 steps of [rows, 48]: what the trimmed last block drops.
    let (rows, steps) = (300, 48);
    let whole = Dropout::new(rows * steps, 0.3, 99);
    let last = whole.strided(rows, steps, steps - 1);
    let x: Vec<f32> = (0..rows * steps).map(|i| 1.0 + (i % 5) as f32).collect();
    let xt = g.upload("x", &[x.len()], &x).unwrap();
    let tail: Vec<f32> = (0..rows).map(|r| x[r * steps + steps - 1]).collect();
    let tt = g.upload("x last", &[rows], &tail).unwrap();
    let (y, yl) = (
        g.zeros("y", &[x.len()], DType::F32).unwrap(),
        g.zeros("y last", &[rows], DType::F32).unwrap(),
    );
    g.run(&[
        whole.apply(&g, 3, &xt, &y, Accumulate::Overwrite).unwrap(),
        last.apply(&g, 3, &tt, &yl, Accumulate::Overwrite).unwrap(),
    ])
    .unwrap();
    let (y, yl) = (g.read_f32(&y).unwrap(), g.read_f32(&yl).unwrap());
    let mut dropped = 0;
    for r in 0..rows {
        assert_eq!(yl[r], y[r * steps + steps - 1], "row {r}");
        assert_eq!(keep(&last, 3, r), keep(&whole, 3, r * steps + steps - 1));
        dropped += usize::from(yl[r] == 0.0);
    }
    assert!(dropped > 0 && dropped < rows, "{dropped} of {rows} dropped");
}

/// The native forward's run of the mask is [`keep`] element by element, also where the
/// index passes 2³² (the hash reads it cut to 32 bits).
#[test]
fn a_run_of_the_mask_is_keep_element_by_element() {
    let whole = Dropout::new(5000, 0.3, 17);
    let strided = Dropout::new(1 << 20, 0.5, 9).strided(300, 48, 47);
    for (d, first) in [
        (whole, 0),
        (whole, 1234),
        (strided, 7),
        (strided, (1usize << 32) - 100),
    ] {
        for step in [0, 1, 77] {
            let mut kept = vec![false; 250];
            keep_run(&d, step, first, &mut kept);
            for (tau, &k) in kept.iter().enumerate() {
                assert_eq!(
                    k,
                    keep(&d, step, first + tau),
                    "step {step}, element {}",
                    first + tau
                );
            }
        }
    }
}
