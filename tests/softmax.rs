//! Softmax along an axis: forward vs the f64 reference, backward vs the f64 backward, and
//! the f64 backward vs central differences; both attention layouts; large scores.

use iastgcn::gpu::DType;
use iastgcn::ops::softmax::{cpu, Softmax};
use iastgcn::ops::Accumulate;
use iastgcn::testing::{
    check_gradient, compare_tensor, dot, gpu, rng, round_f32, to_f32, uniform, Tolerance,
};

/// (outer, len, inner): temporal attention normalises over t with t' inner, spatial over
/// j with nothing inner; plus ragged and long lines.
const SHAPES: [(usize, usize, usize); 5] = [
    (2, 100, 100),
    (3, 14, 1),
    (1, 1, 1),
    (7, 13, 5),
    (300, 3, 1),
];

#[test]
fn forward_and_backward_match_reference() {
    let g = gpu();
    for (i, &(outer, len, inner)) in SHAPES.iter().enumerate() {
        let s = Softmax { outer, len, inner };
        let mut r = rng(i as u64);
        let x = round_f32(&uniform(&mut r, s.numel(), -6.0, 6.0));
        let dy = round_f32(&uniform(&mut r, s.numel(), -1.0, 1.0));
        let xt = g.upload("x", &[s.numel()], &to_f32(&x)).unwrap();
        let dyt = g.upload("dy", &[s.numel()], &to_f32(&dy)).unwrap();
        let y = g.zeros("y", &[s.numel()], DType::F32).unwrap();
        let dx = g.zeros("dx", &[s.numel()], DType::F32).unwrap();
        g.run(&[
            s.forward(&g, &xt, &y).unwrap(),
            s.backward(&g, &y, &dyt, &dx, Accumulate::Overwrite)
                .unwrap(),
        ])
        .unwrap();
        let tol = Tolerance::new(1e-6, 2e-5);
        compare_tensor(&g, &format!("{s:?} y"), &y, &cpu::forward(&s, &x), tol).unwrap();
        compare_tensor(
            &g,
            &format!("{s:?} dx"),
            &dx,
            &cpu::backward(&s, &x, &dy),
            Tolerance::new(2e-6, 5e-5),
        )
        .unwrap();
    }
}

#[test]
fn reference_backward_matches_finite_differences() {
    for (i, &(outer, len, inner)) in SHAPES.iter().skip(1).enumerate() {
        let s = Softmax { outer, len, inner };
        let mut r = rng(30 + i as u64);
        let x = uniform(&mut r, s.numel(), -3.0, 3.0);
        let dy = uniform(&mut r, s.numel(), -1.0, 1.0);
        let dx = cpu::backward(&s, &x, &dy);
        check_gradient(
            &format!("{s:?}"),
            &dx,
            |x| dot(&dy, &cpu::forward(&s, x)),
            &x,
            1e-5,
            Tolerance::new(1e-9, 1e-6),
        )
        .unwrap();
    }
}

#[test]
fn large_scores_do_not_overflow() {
    let g = gpu();
    let s = Softmax {
        outer: 1,
        len: 4,
        inner: 1,
    };
    let x = [1000.0, 999.0, -1000.0, 1000.0];
    let xt = g.upload("x", &[4], &to_f32(&x)).unwrap();
    let y = g.zeros("y", &[4], DType::F32).unwrap();
    g.run(&[s.forward(&g, &xt, &y).unwrap()]).unwrap();
    compare_tensor(
        &g,
        "softmax of large scores",
        &y,
        &cpu::forward(&s, &x),
        Tolerance::new(1e-7, 1e-6),
    )
    .unwrap();
}
