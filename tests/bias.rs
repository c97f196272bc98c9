//! Per-channel bias: broadcast add and gradient reduction vs the f64 reference, and the
//! reference gradient vs central differences; the conv, attention-score and head layouts.

use iastgcn::gpu::DType;
use iastgcn::ops::bias::{cpu, Bias};
use iastgcn::ops::Accumulate;
use iastgcn::testing::{
    check_gradient, compare_tensor, dot, gpu, rng, round_f32, to_f32, uniform, Tolerance,
};

/// (outer, channels, inner): conv bias over B·N rows and T steps, be broadcast over the
/// batch (T·T channels), the head bias, ragged; steps longer than, equal to and
/// shorter than the 64 invocations of a channel's workgroup; sums long enough to be split
/// over workgroups along the outer axis (3 slices of 100 rows, 2 of 19 and 18, 2 of 1).
const SHAPES: [(usize, usize, usize); 11] = [
    (300, 4, 100),
    (37, 3, 500),
    (2, 2, 9000),
    (9, 5, 100),
    (6, 3, 64),
    (28, 16, 48),
    (4, 10000, 1),
    (64, 6, 1),
    (1, 1, 1),
    (3, 7, 5),
    (5, 300, 3),
];

#[test]
fn forward_and_backward_match_reference() {
    let g = gpu();
    // Both gradient kernels: a workgroup per channel, and an invocation per channel.
    let columns = SHAPES.map(|(outer, channels, inner)| {
        Bias {
            outer,
            channels,
            inner,
        }
        .per_channel_invocations()
    });
    assert!(columns.contains(&true) && columns.contains(&false));
    let slices = SHAPES.map(|(outer, channels, inner)| {
        Bias {
            outer,
            channels,
            inner,
        }
        .grad_slices()
    });
    assert_eq!(slices[..3], [(3, 100), (2, 19), (2, 1)]);
    assert!(slices[3..].iter().all(|&(s, _)| s == 1), "{slices:?}");
    for (i, &(outer, channels, inner)) in SHAPES.iter().enumerate() {
        let b = Bias {
            outer,
            channels,
            inner,
        };
        let mut r = rng(i as u64);
        let bias = round_f32(&uniform(&mut r, channels, -1.0, 1.0));
        let y0 = round_f32(&uniform(&mut r, b.numel(), -1.0, 1.0));
        let dy = round_f32(&uniform(&mut r, b.numel(), -1.0, 1.0));
        let bt = g.upload("bias", &[channels], &to_f32(&bias)).unwrap();
        let yt = g.upload("y", &[b.numel()], &to_f32(&y0)).unwrap();
        let dyt = g.upload("dy", &[b.numel()], &to_f32(&dy)).unwrap();
        let db = g.zeros("dbias", &[channels], DType::F32).unwrap();
        let db_acc = g.upload("dbias+", &[channels], &to_f32(&bias)).unwrap();
        g.run(&[
            b.forward(&g, &bt, &yt).unwrap(),
            b.backward(&g, &dyt, &db, Accumulate::Overwrite).unwrap(),
            b.backward(&g, &dyt, &db_acc, Accumulate::Add).unwrap(),
        ])
        .unwrap();
        let tol = Tolerance::new(1e-6, 1e-6);
        compare_tensor(
            &g,
            &format!("{b:?} y"),
            &yt,
            &cpu::forward(&b, &bias, &y0),
            tol,
        )
        .unwrap();
        let expected = cpu::backward(&b, &dy);
        // A sum of outer·inner terms of size ~1: f32 error grows like its square root.
        let sum_tol = Tolerance::new(1e-6 * ((outer * inner) as f64).sqrt(), 1e-5);
        compare_tensor(&g, &format!("{b:?} dbias"), &db, &expected, sum_tol).unwrap();
        let accumulated: Vec<f64> = expected.iter().zip(&bias).map(|(e, b)| e + b).collect();
        compare_tensor(&g, &format!("{b:?} dbias+"), &db_acc, &accumulated, sum_tol).unwrap();
    }
}

#[test]
fn reference_backward_matches_finite_differences() {
    let b = Bias {
        outer: 3,
        channels: 7,
        inner: 5,
    };
    let mut r = rng(9);
    let y = uniform(&mut r, b.numel(), -1.0, 1.0);
    let bias = uniform(&mut r, b.channels, -1.0, 1.0);
    let dy = uniform(&mut r, b.numel(), -1.0, 1.0);
    check_gradient(
        "bias",
        &cpu::backward(&b, &dy),
        |bias| dot(&dy, &cpu::forward(&b, bias, &y)),
        &bias,
        1e-5,
        Tolerance::new(1e-9, 1e-7),
    )
    .unwrap();
}
