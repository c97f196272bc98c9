//! Gated dilated causal convolution: the causal unfolding and the gate vs the f64
//! reference (forward and backward), the unfolding+GEMM path vs the direct convolution
//! of docs/model.md step 4, and the reference gradients (the unfolding, the gate and the
//! convolution) vs central differences.
#![cfg(test)]

use super::kernel::{cpu, gate_backward_stacked, gate_forward, ReluOutput, Unfold};
use crate::gpu::DType;
use crate::ops::matmul::Matmul;
use crate::ops::Accumulate;
use crate::testing::{
    check_gradient, compare, compare_tensor, dot, gpu, rng, round_f32, to_f32, uniform, Tolerance,
};

/// rows (B·N), channels, kernel, steps, dilation: the last block of the small shape
/// (d = 4), a dilation longer than the window, the plain convolution (d = 1).
const SHAPES: [(usize, usize, usize, usize, usize); 4] = [
    (28, 16, 3, 48, 4),
    (3, 5, 3, 7, 8),
    (6, 4, 2, 16, 1),
    (1, 1, 1, 1, 1),
];

fn unfold(
    &(rows, channels, kernel, steps, dilation): &(usize, usize, usize, usize, usize),
) -> Unfold {
    Unfold {
        rows,
        channels,
        kernel,
        steps,
        dilation,
        outputs: steps,
    }
}

#[test]
fn unfold_matches_reference() {
    let g = gpu();
    // The whole unfolding, and only its last steps (the last block's, down to one).
    let windows = SHAPES.iter().flat_map(|shape| {
        let u = unfold(shape);
        [u.steps, u.steps.div_ceil(2), 1].map(|outputs| Unfold { outputs, ..u })
    });
    let windows: Vec<Unfold> = windows.collect();
    // Both kernels: four steps per invocation, and one.
    assert!(windows.iter().any(|u| u.quads()) && windows.iter().any(|u| !u.quads()));
    for (i, u) in windows.into_iter().enumerate() {
        let mut r = rng(i as u64);
        let x = round_f32(&uniform(&mut r, u.input_len(), -1.0, 1.0));
        let dcol = round_f32(&uniform(&mut r, u.col_len(), -1.0, 1.0));
        let xt = g.upload("x", &[u.input_len()], &to_f32(&x)).unwrap();
        let dcolt = g.upload("dcol", &[u.col_len()], &to_f32(&dcol)).unwrap();
        let col = g.zeros("col", &[u.col_len()], DType::F32).unwrap();
        let dx = g.upload("dx", &[u.input_len()], &to_f32(&x)).unwrap();
        g.run(&[
            u.forward(&g, &xt, &col).unwrap(),
            u.backward(&g, &dcolt, &dx, Accumulate::Add).unwrap(),
        ])
        .unwrap();
        let exact = Tolerance::new(0.0, 0.0);
        compare_tensor(&g, &format!("{u:?} col"), &col, &cpu::unfold(&u, &x), exact).unwrap();
        let expected: Vec<f64> = cpu::unfold_backward(&u, &dcol)
            .iter()
            .zip(&x)
            .map(|(d, x)| d + x)
            .collect();
        compare_tensor(
            &g,
            &format!("{u:?} dx"),
            &dx,
            &expected,
            Tolerance::new(1e-6, 1e-6),
        )
        .unwrap();
    }
}

#[test]
fn trimmed_unfolding_is_the_tail_of_the_whole_one() {
    let u = unfold(&SHAPES[0]);
    let last = Unfold { outputs: 5, ..u };
    let x = uniform(&mut rng(9), u.input_len(), -1.0, 1.0);
    let (full, tail) = (cpu::unfold(&u, &x), cpu::unfold(&last, &x));
    for (row, chunk) in tail.chunks(last.outputs).enumerate() {
        assert_eq!(
            chunk,
            &full[row * u.steps + u.steps - last.outputs..][..last.outputs]
        );
    }
    let g = gpu();
    let bad = Unfold {
        outputs: u.steps + 1,
        ..u
    };
    let x = g.zeros("x", &[u.input_len()], DType::F32).unwrap();
    let col = g.zeros("col", &[bad.col_len()], DType::F32).unwrap();
    let err = bad.forward(&g, &x, &col).unwrap_err().to_string();
    assert!(err.contains("unfold outputs"), "{err}");
}

#[test]
fn backward_through_relu_masks_by_the_unfolded_relu_output() {
    let g = gpu();
    for u in [unfold(&SHAPES[0]), unfold(&SHAPES[1])] {
        let mut r = rng(31);
        let z: Vec<f64> = round_f32(&uniform(&mut r, u.input_len(), -1.0, 1.0))
            .iter()
            .map(|v| v.max(0.0))
            .collect();
        let dcol = round_f32(&uniform(&mut r, u.col_len(), -1.0, 1.0));
        let (zt, dcolt) = (
            g.upload("z", &[z.len()], &to_f32(&z)).unwrap(),
            g.upload("dcol", &[dcol.len()], &to_f32(&dcol)).unwrap(),
        );
        let dg = g.zeros("dg", &[u.input_len()], DType::F32).unwrap();
        g.run(&[u
            .backward_through_relu(&g, &dcolt, ReluOutput(&zt), &dg)
            .unwrap()])
            .unwrap();
        let want: Vec<f64> = cpu::unfold_backward(&u, &dcol)
            .iter()
            .zip(&z)
            .map(|(d, z)| if *z > 0.0 { *d } else { 0.0 })
            .collect();
        assert!(want.contains(&0.0) && want.iter().any(|v| *v != 0.0));
        let tol = Tolerance::new(1e-6, 1e-6);
        compare_tensor(&g, &format!("{u:?} dG"), &dg, &want, tol).unwrap();
    }
}

/// The GPU path of the model (unfold, then weight [C, C·K] · col per row) equals the
/// direct dilated causal convolution.
#[test]
fn unfold_then_gemm_is_the_causal_convolution() {
    let g = gpu();
    let u = unfold(&SHAPES[0]);
    let outputs = 8;
    let mut r = rng(5);
    let x = round_f32(&uniform(&mut r, u.input_len(), -1.0, 1.0));
    let w = round_f32(&uniform(&mut r, outputs * u.channels * u.kernel, -0.5, 0.5));
    let xt = g.upload("x", &[u.input_len()], &to_f32(&x)).unwrap();
    let wt = g.upload("w", &[w.len()], &to_f32(&w)).unwrap();
    let col = g.zeros("col", &[u.col_len()], DType::F32).unwrap();
    let out = g
        .zeros("out", &[u.rows * outputs * u.steps], DType::F32)
        .unwrap();
    let mm = Matmul::new(outputs, u.steps, u.channels * u.kernel)
        .batched(u.rows)
        .share_a(true);
    g.run(&[
        u.forward(&g, &xt, &col).unwrap(),
        mm.forward(&g, &wt, &col, &out, Accumulate::Overwrite)
            .unwrap(),
    ])
    .unwrap();
    let expected = cpu::conv(&u, outputs, &w, &vec![0.0; outputs], &x);
    compare_tensor(&g, "conv", &out, &expected, Tolerance::new(1e-5, 1e-5)).unwrap();
}

#[test]
fn gate_matches_reference() {
    let g = gpu();
    let n = 5000;
    let mut r = rng(7);
    let f = round_f32(&uniform(&mut r, n, -12.0, 12.0));
    let gg = round_f32(&uniform(&mut r, n, -40.0, 40.0));
    let dh = round_f32(&uniform(&mut r, n, -1.0, 1.0));
    let [ft, gt, dht] = [&f, &gg, &dh].map(|v| g.upload("in", &[n], &to_f32(v)).unwrap());
    let h = g.zeros("h", &[n], DType::F32).unwrap();
    // The gradients stacked per item of 250 elements, [df; dg] for each, as the model's
    // backward reads them.
    let dfg = g.zeros("dfg", &[2 * n], DType::F32).unwrap();
    g.run(&[
        gate_forward(&g, &ft, &gt, &h).unwrap(),
        gate_backward_stacked(&g, &ft, &gt, &dht, &dfg, 250).unwrap(),
    ])
    .unwrap();
    let tol = Tolerance::new(1e-6, 1e-5);
    compare_tensor(&g, "h", &h, &cpu::gate(&f, &gg), tol).unwrap();
    let (edf, edg) = cpu::gate_backward(&f, &gg, &dh);
    let got: Vec<f64> = g.read_f32(&dfg).unwrap()[..2 * n]
        .iter()
        .map(|&v| v as f64)
        .collect();
    let (df, dg): (Vec<f64>, Vec<f64>) = (
        got.chunks(250).step_by(2).flatten().copied().collect(),
        got.chunks(250)
            .skip(1)
            .step_by(2)
            .flatten()
            .copied()
            .collect(),
    );
    compare("df", &df, &edf, tol).unwrap();
    compare("dg", &dg, &edg, tol).unwrap();
    let stacked = cpu::stack(&edf, &edg, 250);
    assert_eq!(stacked[250..500], edg[..250]);
    compare_tensor(&g, "[df; dg]", &dfg, &stacked, tol).unwrap();
    let err = gate_backward_stacked(&g, &ft, &gt, &dht, &dfg, 3).unwrap_err();
    assert!(err.to_string().contains("items of 3 elements"), "{err}");
}

#[test]
fn reference_gradients_match_finite_differences() {
    let u = unfold(&SHAPES[1]);
    let mut r = rng(11);
    let x = uniform(&mut r, u.input_len(), -1.0, 1.0);
    let dcol = uniform(&mut r, u.col_len(), -1.0, 1.0);
    check_gradient(
        "unfold",
        &cpu::unfold_backward(&u, &dcol),
        |x| dot(&dcol, &cpu::unfold(&u, x)),
        &x,
        1e-5,
        Tolerance::new(1e-9, 1e-7),
    )
    .unwrap();
    let n = 40;
    let f = uniform(&mut r, n, -3.0, 3.0);
    let gg = uniform(&mut r, n, -3.0, 3.0);
    let dh = uniform(&mut r, n, -1.0, 1.0);
    let (df, dg) = cpu::gate_backward(&f, &gg, &dh);
    let tol = Tolerance::new(1e-9, 1e-6);
    check_gradient(
        "gate f",
        &df,
        |f| dot(&dh, &cpu::gate(f, &gg)),
        &f,
        1e-5,
        tol,
    )
    .unwrap();
    check_gradient(
        "gate g",
        &dg,
        |gg| dot(&dh, &cpu::gate(&f, gg)),
        &gg,
        1e-5,
        tol,
    )
    .unwrap();
    // Causality: the convolution output at step t never depends on x after t.
    let w = uniform(&mut r, 2 * u.channels * u.kernel, -1.0, 1.0);
    let base = cpu::conv(&u, 2, &w, &[0.0, 0.0], &x);
    let mut late = x.clone();
    for rc in 0..u.rows * u.channels {
        late[rc * u.steps + u.steps - 1] += 1.0;
    }
    let moved = cpu::conv(&u, 2, &w, &[0.0, 0.0], &late);
    let early = |v: &[f64]| -> Vec<f64> {
        v.chunks(u.steps)
            .flat_map(|row| row[..u.steps - 1].to_vec())
            .collect()
    };
    compare(
        "causal",
        &early(&moved),
        &early(&base),
        Tolerance::new(0.0, 0.0),
    )
    .unwrap();
}

/// The convolution's backward (`cpu::conv_backward`, which the network reference's
/// step 4 composes) against central differences of Σ dg ⊙ conv, for the whole window
/// and for its last steps only (dilation 2, two output channels, a bias).
#[test]
fn conv_backward_matches_finite_differences() {
    let mut r = rng(12);
    for outputs in [7, 3] {
        let u = Unfold {
            outputs,
            ..unfold(&(3, 4, 3, 7, 2))
        };
        let out_channels = 2;
        let x = uniform(&mut r, u.input_len(), -1.0, 1.0);
        let w = uniform(&mut r, out_channels * u.channels * u.kernel, -1.0, 1.0);
        let b = uniform(&mut r, out_channels, -1.0, 1.0);
        let dg = uniform(&mut r, u.rows * out_channels * outputs, -1.0, 1.0);
        let (dx, dw, db) = cpu::conv_backward(&u, out_channels, &w, &x, &dg);
        let tol = Tolerance::new(1e-9, 1e-7);
        let conv =
            |x: &[f64], w: &[f64], b: &[f64]| dot(&dg, &cpu::conv(&u, out_channels, w, b, x));
        check_gradient("conv dx", &dx, |x| conv(x, &w, &b), &x, 1e-5, tol).unwrap();
        check_gradient("conv dw", &dw, |w| conv(&x, w, &b), &w, 1e-5, tol).unwrap();
        check_gradient("conv db", &db, |b| conv(&x, &w, b), &b, 1e-5, tol).unwrap();
    }
}
