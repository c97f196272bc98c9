//! The head's last-step gather/scatter and the pose loss vs their f64 references, and
//! the loss gradient vs central differences.

use iastgcn::gpu::DType;
use iastgcn::ops::head::{cpu as head_cpu, LastStep};
use iastgcn::ops::loss::{cpu as loss_cpu, PoseLoss};
use iastgcn::testing::{
    check_gradient, compare_tensor, gpu, rng, round_f32, to_f32, uniform, Tolerance,
};

#[test]
fn last_step_matches_reference() {
    let g = gpu();
    let s = LastStep {
        rows: 2 * 14 * 4,
        steps: 16,
    };
    let mut r = rng(1);
    let y = round_f32(&uniform(&mut r, s.rows * s.steps, -1.0, 1.0));
    let dh = round_f32(&uniform(&mut r, s.rows, -1.0, 1.0));
    let yt = g.upload("y", &[y.len()], &to_f32(&y)).unwrap();
    let dht = g.upload("dh", &[dh.len()], &to_f32(&dh)).unwrap();
    let h = g.zeros("h", &[s.rows], DType::F32);
    // Filled with garbage first: the scatter must write every element.
    let dy = g.upload("dy", &[y.len()], &to_f32(&y)).unwrap();
    g.run(&[
        s.forward(&g, &yt, &h).unwrap(),
        s.backward(&g, &dht, &dy).unwrap(),
    ])
    .unwrap();
    let exact = Tolerance::new(0.0, 0.0);
    compare_tensor(&g, "h", &h, &head_cpu::forward(&s, &y), exact).unwrap();
    compare_tensor(&g, "dy", &dy, &head_cpu::backward(&s, &dh), exact).unwrap();
}

#[test]
fn pose_loss_matches_reference_and_finite_differences() {
    let g = gpu();
    for (i, &(batch, penalty)) in [(64, 1.0), (3, 2.5), (1000, 0.5)].iter().enumerate() {
        let l = PoseLoss {
            batch,
            outputs: 6,
            penalty,
        };
        let mut r = rng(10 + i as u64);
        let pred = round_f32(&uniform(&mut r, batch * 6, -2.0, 2.0));
        let truth = round_f32(&uniform(&mut r, batch * 6, -2.0, 2.0));
        let pt = g.upload("pred", &[pred.len()], &to_f32(&pred)).unwrap();
        let tt = g.upload("truth", &[pred.len()], &to_f32(&truth)).unwrap();
        let loss = g.zeros("loss", &[1], DType::F32);
        let dpred = g.zeros("dpred", &[pred.len()], DType::F32);
        g.run(&[
            l.forward(&g, &pt, &tt, &loss).unwrap(),
            l.backward(&g, &pt, &tt, &dpred).unwrap(),
        ])
        .unwrap();
        let tol = Tolerance::new(1e-6, 1e-5);
        compare_tensor(
            &g,
            "loss",
            &loss,
            &[loss_cpu::forward(&l, &pred, &truth)],
            tol,
        )
        .unwrap();
        let grad = loss_cpu::backward(&l, &pred, &truth);
        compare_tensor(&g, "dpred", &dpred, &grad, tol).unwrap();
        if batch < 100 {
            check_gradient(
                "pose loss",
                &grad,
                |p| loss_cpu::forward(&l, p, &truth),
                &pred,
                1e-5,
                Tolerance::new(1e-9, 1e-7),
            )
            .unwrap();
        }
    }
}
