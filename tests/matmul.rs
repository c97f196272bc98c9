//! Batched matmul: forward vs the f64 reference, backward vs the f64 backward, and the
//! f64 backward vs central differences, on ragged shapes and every transpose/sharing mode.

use iastgcn::gpu::{DType, Gpu, Tensor};
use iastgcn::ops::matmul::{cpu, Matmul};
use iastgcn::testing::{
    check_gradient, compare_tensor, dot, gpu, rng, round_f32, to_f32, uniform, Tolerance,
};

/// Shapes that are not multiples of the 4×4 register block or the 8×8 workgroup.
fn cases() -> Vec<Matmul> {
    let mut v = vec![
        Matmul::new(1, 1, 1),
        Matmul::new(5, 7, 3),
        Matmul::new(70, 9, 130),
    ];
    for (ta, tb) in [(false, false), (true, false), (false, true), (true, true)] {
        v.push(Matmul::new(33, 31, 37).transpose_a(ta).transpose_b(tb));
        v.push(
            Matmul::new(6, 13, 10)
                .batched(3)
                .share_b(true)
                .transpose_a(ta)
                .transpose_b(tb),
        );
        v.push(
            Matmul::new(11, 5, 9)
                .batched(4)
                .share_a(true)
                .transpose_a(ta)
                .transpose_b(tb),
        );
        v.push(
            Matmul::new(3, 18, 7)
                .batched(2)
                .transpose_a(ta)
                .transpose_b(tb),
        );
    }
    v
}

/// f32 sums of `k` products of values in [-1, 1]: √k·few ulps absolute, far below the
/// O(1) error of any indexing bug.
fn gpu_tol(k: usize) -> Tolerance {
    Tolerance::new(4e-6 * (k as f64).sqrt(), 1e-4)
}

struct Inputs {
    a: Vec<f64>,
    b: Vec<f64>,
    dc: Vec<f64>,
}

fn inputs(mm: &Matmul, seed: u64) -> Inputs {
    let mut g = rng(seed);
    Inputs {
        a: round_f32(&uniform(&mut g, mm.a_len(), -1.0, 1.0)),
        b: round_f32(&uniform(&mut g, mm.b_len(), -1.0, 1.0)),
        dc: round_f32(&uniform(&mut g, mm.c_len(), -1.0, 1.0)),
    }
}

fn upload(g: &Gpu, name: &str, data: &[f64]) -> Tensor {
    g.upload(name, &[data.len()], &to_f32(data)).unwrap()
}

#[test]
fn forward_matches_reference() {
    let g = gpu();
    for (i, mm) in cases().into_iter().enumerate() {
        let x = inputs(&mm, i as u64);
        let (a, b) = (upload(&g, "a", &x.a), upload(&g, "b", &x.b));
        let c = g.zeros("c", &[mm.c_len()], DType::F32);
        g.run(&[mm.forward(&g, &a, &b, &c, false).unwrap()])
            .unwrap();
        compare_tensor(
            &g,
            &format!("{mm:?} forward"),
            &c,
            &cpu::forward(&mm, &x.a, &x.b),
            gpu_tol(mm.k),
        )
        .unwrap();
    }
}

#[test]
fn backward_matches_reference() {
    let g = gpu();
    for (i, mm) in cases().into_iter().enumerate() {
        let x = inputs(&mm, 100 + i as u64);
        let (a, b, dc) = (
            upload(&g, "a", &x.a),
            upload(&g, "b", &x.b),
            upload(&g, "dc", &x.dc),
        );
        let da = g.zeros("da", &[mm.a_len()], DType::F32);
        let db = g.zeros("db", &[mm.b_len()], DType::F32);
        g.run(&[
            mm.backward_a(&g, &b, &dc, &da, false).unwrap(),
            mm.backward_b(&g, &a, &dc, &db, false).unwrap(),
        ])
        .unwrap();
        let (da_ref, db_ref) = cpu::backward(&mm, &x.a, &x.b, &x.dc);
        let ka = mm.n * if mm.shared_a { mm.batch } else { 1 };
        let kb = mm.m * if mm.shared_b { mm.batch } else { 1 };
        compare_tensor(&g, &format!("{mm:?} dA"), &da, &da_ref, gpu_tol(ka)).unwrap();
        compare_tensor(&g, &format!("{mm:?} dB"), &db, &db_ref, gpu_tol(kb)).unwrap();
    }
}

#[test]
fn reference_backward_matches_finite_differences() {
    for (i, mm) in cases().into_iter().enumerate() {
        let x = inputs(&mm, 200 + i as u64);
        let (da, db) = cpu::backward(&mm, &x.a, &x.b, &x.dc);
        // L = <dc, A·B> is bilinear: central differences are exact up to rounding.
        let tol = Tolerance::new(1e-8, 1e-7);
        check_gradient(
            &format!("{mm:?} dA"),
            &da,
            |a| dot(&x.dc, &cpu::forward(&mm, a, &x.b)),
            &x.a,
            1e-3,
            tol,
        )
        .unwrap();
        check_gradient(
            &format!("{mm:?} dB"),
            &db,
            |b| dot(&x.dc, &cpu::forward(&mm, &x.a, b)),
            &x.b,
            1e-3,
            tol,
        )
        .unwrap();
    }
}

#[test]
fn accumulate_adds_to_existing_values() {
    let g = gpu();
    let mm = Matmul::new(9, 6, 5)
        .batched(2)
        .share_b(true)
        .transpose_b(true);
    let x = inputs(&mm, 300);
    let (a, b, dc) = (
        upload(&g, "a", &x.a),
        upload(&g, "b", &x.b),
        upload(&g, "dc", &x.dc),
    );
    let c0: Vec<f64> = (0..mm.c_len()).map(|i| i as f64 * 0.25).collect();
    let db0: Vec<f64> = (0..mm.b_len()).map(|i| 1.0 - i as f64 * 0.5).collect();
    let (c, db) = (upload(&g, "c", &c0), upload(&g, "db", &db0));
    g.run(&[
        mm.forward(&g, &a, &b, &c, true).unwrap(),
        mm.backward_b(&g, &a, &dc, &db, true).unwrap(),
    ])
    .unwrap();
    let c_ref: Vec<f64> = cpu::forward(&mm, &x.a, &x.b)
        .iter()
        .zip(&c0)
        .map(|(p, q)| p + q)
        .collect();
    let db_ref: Vec<f64> = cpu::backward(&mm, &x.a, &x.b, &x.dc)
        .1
        .iter()
        .zip(&db0)
        .map(|(p, q)| p + q)
        .collect();
    compare_tensor(&g, "accumulated C", &c, &c_ref, gpu_tol(5)).unwrap();
    compare_tensor(&g, "accumulated dB", &db, &db_ref, gpu_tol(18)).unwrap();
}

#[test]
fn model_sized_product_matches_reference() {
    // One window of the 1×1 residual convolution: [14·100, 64] × [64, 64], plus dW.
    let g = gpu();
    let mm = Matmul::new(1400, 64, 64);
    let x = inputs(&mm, 400);
    let (a, b, dc) = (
        upload(&g, "x", &x.a),
        upload(&g, "w", &x.b),
        upload(&g, "dy", &x.dc),
    );
    let c = g.zeros("y", &[mm.c_len()], DType::F32);
    let db = g.zeros("dw", &[mm.b_len()], DType::F32);
    g.run(&[
        mm.forward(&g, &a, &b, &c, false).unwrap(),
        mm.backward_b(&g, &a, &dc, &db, false).unwrap(),
    ])
    .unwrap();
    compare_tensor(&g, "y", &c, &cpu::forward(&mm, &x.a, &x.b), gpu_tol(64)).unwrap();
    compare_tensor(
        &g,
        "dw",
        &db,
        &cpu::backward(&mm, &x.a, &x.b, &x.dc).1,
        gpu_tol(1400),
    )
    .unwrap();
}

#[test]
fn aligned_shapes_take_the_vector_kernel_and_ragged_ones_the_scalar_kernel() {
    let g = gpu();
    let kernel = |mm: Matmul| {
        let a = g.zeros("a", &[mm.a_len()], DType::F32);
        let b = g.zeros("b", &[mm.b_len()], DType::F32);
        let c = g.zeros("c", &[mm.c_len()], DType::F32);
        let da = g.zeros("da", &[mm.a_len()], DType::F32);
        let db = g.zeros("db", &[mm.b_len()], DType::F32);
        [
            mm.forward(&g, &a, &b, &c, false)
                .unwrap()
                .label()
                .to_string(),
            mm.backward_a(&g, &b, &c, &da, false)
                .unwrap()
                .label()
                .to_string(),
            mm.backward_b(&g, &a, &c, &db, false)
                .unwrap()
                .label()
                .to_string(),
        ]
    };
    for (ta, tb) in [(false, false), (true, false), (false, true), (true, true)] {
        let mm = Matmul::new(12, 20, 16)
            .batched(2)
            .share_b(true)
            .transpose_a(ta)
            .transpose_b(tb);
        assert_eq!(kernel(mm), ["matmul::matmul_vec4"; 3], "{mm:?}");
    }
    // Row count 13 is fine when A is contiguous along k (forward), not for dA's layout.
    assert_eq!(kernel(Matmul::new(13, 8, 12))[0], "matmul::matmul_vec4");
    assert_eq!(kernel(Matmul::new(5, 7, 3)), ["matmul::matmul"; 3]);
    assert_eq!(kernel(Matmul::new(12, 8, 14))[0], "matmul::matmul");
}

#[test]
fn wrong_lengths_name_the_tensor() {
    let g = gpu();
    let mm = Matmul::new(4, 4, 4);
    let a = g.zeros("activations", &[15], DType::F32);
    let b = g.zeros("weights", &[16], DType::F32);
    let c = g.zeros("out", &[16], DType::F32);
    let err = mm.forward(&g, &a, &b, &c, false).unwrap_err().to_string();
    assert!(
        err.contains("tensor activations") && err.contains("16 elements"),
        "{err}"
    );
}
