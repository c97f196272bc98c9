//! Elementwise kernels: forward vs the f64 reference, backward vs the f64 backward, and
//! the f64 backward vs central differences, on ragged lengths.

use iastgcn::gpu::{grid_1d, DType, Gpu, Tensor};
use iastgcn::ops::elementwise::{self as ew, cpu, Binary, Unary};
use iastgcn::ops::Accumulate;
use iastgcn::testing::{
    away_from_zero, check_gradient, compare_tensor, dot, gpu, rng, round_f32, to_f32, uniform,
    Tolerance,
};

/// Lengths around the 256-wide workgroup.
const LENGTHS: [usize; 5] = [1, 255, 256, 257, 1000];

/// f32 transcendental functions on the GPU are accurate to a few ulps.
const GPU_TOL: Tolerance = Tolerance::new(2e-6, 2e-5);
/// Smooth functions, h = 1e-5: truncation ~1e-10, rounding ~1e-11.
const FD_TOL: Tolerance = Tolerance::new(1e-8, 1e-6);

fn upload(g: &Gpu, name: &str, data: &[f64]) -> Tensor {
    g.upload(name, &[data.len()], &to_f32(data)).unwrap()
}

/// Inputs in [-4, 4] (both saturated and linear regimes); ReLU's stay clear of its kink.
fn input(op: Unary, n: usize, seed: u64) -> Vec<f64> {
    let mut g = rng(seed);
    round_f32(&match op {
        Unary::Relu => away_from_zero(&mut g, n, 1e-3, 4.0),
        _ => uniform(&mut g, n, -4.0, 4.0),
    })
}

#[test]
fn unary_forward_and_backward_match_reference() {
    let g = gpu();
    for op in Unary::ALL {
        for (i, &n) in LENGTHS.iter().enumerate() {
            let x = input(op, n, i as u64);
            let dy = round_f32(&uniform(&mut rng(50 + i as u64), n, -1.0, 1.0));
            let (xt, dyt) = (upload(&g, "x", &x), upload(&g, "dy", &dy));
            let y = g.zeros("y", &[n], DType::F32).unwrap();
            let dx = g.zeros("dx", &[n], DType::F32).unwrap();
            let saved = if op.backward_uses_output() { &y } else { &xt };
            g.run(&[
                ew::unary_forward(&g, op, &xt, &y, Accumulate::Overwrite).unwrap(),
                ew::unary_backward(&g, op, saved, &dyt, &dx, Accumulate::Overwrite).unwrap(),
            ])
            .unwrap();
            compare_tensor(
                &g,
                &format!("{op:?} forward n={n}"),
                &y,
                &cpu::unary_forward(op, &x),
                GPU_TOL,
            )
            .unwrap();
            compare_tensor(
                &g,
                &format!("{op:?} backward n={n}"),
                &dx,
                &cpu::unary_backward(op, &x, &dy),
                GPU_TOL,
            )
            .unwrap();
        }
    }
}

#[test]
fn unary_reference_backward_matches_finite_differences() {
    for op in Unary::ALL {
        let x = input(op, 64, 7);
        let dy = uniform(&mut rng(8), 64, -1.0, 1.0);
        let analytic = cpu::unary_backward(op, &x, &dy);
        check_gradient(
            &format!("{op:?}"),
            &analytic,
            |x| dot(&dy, &cpu::unary_forward(op, x)),
            &x,
            1e-5,
            FD_TOL,
        )
        .unwrap();
    }
}

#[test]
fn saturated_inputs_stay_finite() {
    let g = gpu();
    let x = [-1e4, -90.0, -30.0, 0.0, 30.0, 90.0, 1e4];
    let xt = upload(&g, "x", &x);
    for op in Unary::ALL {
        let y = g.zeros("y", &[x.len()], DType::F32).unwrap();
        g.run(&[ew::unary_forward(&g, op, &xt, &y, Accumulate::Overwrite).unwrap()])
            .unwrap();
        compare_tensor(
            &g,
            &format!("{op:?} saturated"),
            &y,
            &cpu::unary_forward(op, &x),
            GPU_TOL,
        )
        .unwrap();
    }
}

#[test]
fn binary_forward_and_backward_match_reference() {
    let g = gpu();
    for op in Binary::ALL {
        for (i, &n) in LENGTHS.iter().enumerate() {
            let mut r = rng(90 + i as u64);
            let a = round_f32(&uniform(&mut r, n, -2.0, 2.0));
            let b = round_f32(&uniform(&mut r, n, -2.0, 2.0));
            let dc = round_f32(&uniform(&mut r, n, -1.0, 1.0));
            let (at, bt, dct) = (
                upload(&g, "a", &a),
                upload(&g, "b", &b),
                upload(&g, "dc", &dc),
            );
            let c = g.zeros("c", &[n], DType::F32).unwrap();
            let da = g.zeros("da", &[n], DType::F32).unwrap();
            let db = g.zeros("db", &[n], DType::F32).unwrap();
            g.run(&[
                ew::binary_forward(&g, op, &at, &bt, &c, Accumulate::Overwrite).unwrap(),
                ew::binary_backward(&g, op, &bt, &dct, &da, Accumulate::Overwrite).unwrap(),
                ew::binary_backward(&g, op, &at, &dct, &db, Accumulate::Overwrite).unwrap(),
            ])
            .unwrap();
            let (da_ref, db_ref) = cpu::binary_backward(op, &a, &b, &dc);
            compare_tensor(
                &g,
                &format!("{op:?} forward n={n}"),
                &c,
                &cpu::binary_forward(op, &a, &b),
                GPU_TOL,
            )
            .unwrap();
            compare_tensor(&g, &format!("{op:?} da n={n}"), &da, &da_ref, GPU_TOL).unwrap();
            compare_tensor(&g, &format!("{op:?} db n={n}"), &db, &db_ref, GPU_TOL).unwrap();
        }
    }
}

#[test]
fn binary_reference_backward_matches_finite_differences() {
    for op in Binary::ALL {
        let mut r = rng(11);
        let a = uniform(&mut r, 40, -2.0, 2.0);
        let b = uniform(&mut r, 40, -2.0, 2.0);
        let dc = uniform(&mut r, 40, -1.0, 1.0);
        let (da, db) = cpu::binary_backward(op, &a, &b, &dc);
        check_gradient(
            &format!("{op:?} da"),
            &da,
            |a| dot(&dc, &cpu::binary_forward(op, a, &b)),
            &a,
            1e-5,
            FD_TOL,
        )
        .unwrap();
        check_gradient(
            &format!("{op:?} db"),
            &db,
            |b| dot(&dc, &cpu::binary_forward(op, &a, b)),
            &b,
            1e-5,
            FD_TOL,
        )
        .unwrap();
    }
}

#[test]
fn backward_accumulates_when_asked() {
    // x used twice (y = x ⊙ x): both gradient contributions land in one buffer.
    let g = gpu();
    let x = round_f32(&uniform(&mut rng(3), 300, -2.0, 2.0));
    let dy = round_f32(&uniform(&mut rng(4), 300, -1.0, 1.0));
    let (xt, dyt) = (upload(&g, "x", &x), upload(&g, "dy", &dy));
    let dx = g.zeros("dx", &[300], DType::F32).unwrap();
    g.run(&[
        ew::binary_backward(&g, Binary::Mul, &xt, &dyt, &dx, Accumulate::Overwrite).unwrap(),
        ew::binary_backward(&g, Binary::Mul, &xt, &dyt, &dx, Accumulate::Add).unwrap(),
    ])
    .unwrap();
    let want: Vec<f64> = x.iter().zip(&dy).map(|(x, g)| 2.0 * x * g).collect();
    compare_tensor(&g, "d(x*x)/dx", &dx, &want, GPU_TOL).unwrap();
}

#[test]
fn grid_folds_into_two_dimensions_past_the_limit() {
    assert_eq!(grid_1d(1, 256, 65535), [1, 1, 1]);
    assert_eq!(grid_1d(65535 * 256, 256, 65535), [65535, 1, 1]);
    let [x, y, _] = grid_1d(65535 * 256 + 1, 256, 65535);
    assert!(x <= 65535 && y == 2 && (x as usize) * (y as usize) * 256 > 65535 * 256);
    let [x, y, _] = grid_1d(1000, 4, 10);
    assert!(x <= 10 && y <= 25 && x * y * 4 >= 1000);
}

#[test]
fn folded_grid_covers_every_element_on_the_device() {
    // More workgroups than one dimension allows: the kernel must recover the flat index.
    let g = gpu();
    let limit = g.limits().max_compute_workgroups_per_dimension as usize;
    let n = limit * 256 + 3 * 256 + 5;
    let x: Vec<f32> = (0..n)
        .map(|i| if i % 3 == 0 { -1.0 } else { (i % 1000) as f32 })
        .collect();
    let xt = g.upload("x", &[n], &x).unwrap();
    let y = g.zeros("y", &[n], DType::F32).unwrap();
    let d = ew::unary_forward(&g, Unary::Relu, &xt, &y, Accumulate::Overwrite).unwrap();
    assert!(
        d.workgroups()[1] > 1,
        "grid should fold: {:?}",
        d.workgroups()
    );
    g.run(&[d]).unwrap();
    let got = g.read_f32(&y).unwrap();
    let bad = got.iter().zip(&x).position(|(g, x)| *g != x.max(0.0));
    assert_eq!(bad, None, "first wrong element");
}
