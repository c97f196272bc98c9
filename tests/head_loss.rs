//! The head's last-step gather/scatter and the pose loss (plain and over ensembles) vs
//! their f64 references, the loss gradient vs central differences, and the ensemble loss
//! of a whole `Network::for_ensembles`.

use iastgcn::gpu::{DType, Gpu};
use iastgcn::graph::Graph;
use iastgcn::model::{ModelConfig, Network, Parameters, Variant};
use iastgcn::ops::head::{cpu as head_cpu, LastStep};
use iastgcn::ops::loss::PoseLoss;
use iastgcn::testing::{
    check_gradient, compare, compare_tensor, gpu, rng, round_f32, to_f32, uniform, Tolerance,
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
    let h = g.zeros("h", &[s.rows], DType::F32).unwrap();
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
            group: 1,
        };
        let mut r = rng(10 + i as u64);
        let pred = round_f32(&uniform(&mut r, batch * 6, -2.0, 2.0));
        let truth = round_f32(&uniform(&mut r, batch * 6, -2.0, 2.0));
        let pt = g.upload("pred", &[pred.len()], &to_f32(&pred)).unwrap();
        let tt = g.upload("truth", &[pred.len()], &to_f32(&truth)).unwrap();
        let loss = g.zeros("loss", &[1], DType::F32).unwrap();
        let dpred = g.zeros("dpred", &[pred.len()], DType::F32).unwrap();
        g.run(&[
            l.forward(&g, &pt, &tt, &loss).unwrap(),
            l.backward(&g, &pt, &tt, &dpred).unwrap(),
        ])
        .unwrap();
        let tol = Tolerance::new(1e-6, 1e-5);
        compare_tensor(&g, "loss", &loss, &[l.value(&pred, &truth)], tol).unwrap();
        let grad = l.gradient(&pred, &truth);
        compare_tensor(&g, "dpred", &dpred, &grad, tol).unwrap();
        if batch < 100 {
            check_gradient(
                "pose loss",
                &grad,
                |p| l.value(p, &truth),
                &pred,
                1e-5,
                Tolerance::new(1e-9, 1e-7),
            )
            .unwrap();
        }
    }
}

/// ℓ(a, b) = Σ_j w_j (a_j − b_j)² of one window (docs/model.md eq. 39's bracket).
fn window_loss(penalty: f64, a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .enumerate()
        .map(|(j, (x, y))| if j < 3 { 1.0 } else { penalty } * (x - y) * (x - y))
        .sum()
}

/// The ensemble loss written straight from docs/model.md "Refinement", independent of the
/// reference's rearrangement: (1/G) Σ_g [ (1/m) Σ_k ℓ(ŷ_gk, y_gk) + ℓ(mean ŷ, mean y) ].
fn ensemble_loss_by_definition(l: &PoseLoss, pred: &[f64], truth: &[f64]) -> f64 {
    let (m, o) = (l.group, l.outputs);
    let groups = l.batch / m;
    let mut total = 0.0;
    for g in 0..groups {
        let rows = g * m * o..(g + 1) * m * o;
        let (p, t) = (&pred[rows.clone()], &truth[rows]);
        let per_window: f64 = (0..m)
            .map(|k| window_loss(l.penalty, &p[k * o..(k + 1) * o], &t[k * o..(k + 1) * o]))
            .sum::<f64>()
            / m as f64;
        let mean = |v: &[f64]| -> Vec<f64> {
            (0..o)
                .map(|j| (0..m).map(|k| v[k * o + j]).sum::<f64>() / m as f64)
                .collect()
        };
        total += per_window + window_loss(l.penalty, &mean(p), &mean(t));
    }
    total / groups as f64
}

/// Runs the loss forward and backward on the device: (loss tensor, dpred tensor).
fn run_loss(
    g: &Gpu,
    l: &PoseLoss,
    pred: &[f64],
    truth: &[f64],
) -> (iastgcn::gpu::Tensor, iastgcn::gpu::Tensor) {
    let pt = g.upload("pred", &[pred.len()], &to_f32(pred)).unwrap();
    let tt = g.upload("truth", &[pred.len()], &to_f32(truth)).unwrap();
    let loss = g.zeros("loss", &[1], DType::F32).unwrap();
    // Garbage first: backward must overwrite every element.
    let dpred = g.upload("dpred", &[pred.len()], &to_f32(pred)).unwrap();
    g.run(&[
        l.forward(g, &pt, &tt, &loss).unwrap(),
        l.backward(g, &pt, &tt, &dpred).unwrap(),
    ])
    .unwrap();
    (loss, dpred)
}

#[test]
fn ensemble_loss_matches_reference_definition_and_finite_differences() {
    let g = gpu();
    let mut worst = [0.0f64; 3];
    for (i, &(batch, group, penalty)) in [(60, 10, 1.7), (20, 5, 0.6), (60, 5, 2.5)]
        .iter()
        .enumerate()
    {
        let l = PoseLoss {
            batch,
            outputs: 6,
            penalty,
            group,
        };
        let mut r = rng(30 + i as u64);
        // A per-ensemble offset so the mean prediction error is not ~0 (the ensemble
        // term then carries weight comparable to the per-window terms).
        let mut pred = uniform(&mut r, batch * 6, -1.0, 1.0);
        for (j, p) in pred.iter_mut().enumerate() {
            *p += 0.5 * ((j / 6 / group) % 3) as f64 - 0.4 * (j % 6) as f64 / 5.0;
        }
        let pred = round_f32(&pred);
        let truth = round_f32(&uniform(&mut r, batch * 6, -1.0, 1.0));
        let expected = l.value(&pred, &truth);
        let by_definition = ensemble_loss_by_definition(&l, &pred, &truth);
        compare(
            &format!("B {batch} M {group}: reference vs definition"),
            &[expected],
            &[by_definition],
            Tolerance::new(0.0, 1e-12),
        )
        .unwrap();
        // The ensemble term matters: the plain loss of the same batch is clearly smaller.
        let plain = PoseLoss { group: 1, ..l }.value(&pred, &truth);
        assert!(
            expected > 1.1 * plain,
            "B {batch} M {group}: ensemble loss {expected} vs plain {plain}"
        );

        let (loss, dpred) = run_loss(&g, &l, &pred, &truth);
        let tol = Tolerance::new(1e-6, 1e-5);
        let w = compare_tensor(&g, "ensemble loss", &loss, &[expected], tol).unwrap();
        worst[0] = worst[0].max(w.rel_err);
        let grad = l.gradient(&pred, &truth);
        let w = compare_tensor(&g, "ensemble dpred", &dpred, &grad, tol).unwrap();
        worst[1] = worst[1].max(w.abs_err);
        let w = check_gradient(
            &format!("B {batch} M {group}: ensemble loss"),
            &grad,
            |p| l.value(p, &truth),
            &pred,
            1e-5,
            Tolerance::new(1e-9, 1e-7),
        )
        .unwrap();
        worst[2] = worst[2].max(w.abs_err);
    }
    eprintln!(
        "ensemble loss: worst GPU loss rel {:.3e}, worst GPU dpred abs {:.3e}, worst reference vs central differences abs {:.3e}",
        worst[0], worst[1], worst[2]
    );
}

#[test]
fn group_one_is_the_plain_loss() {
    let g = gpu();
    let l = PoseLoss {
        batch: 37,
        outputs: 6,
        penalty: 1.3,
        group: 1,
    };
    let mut r = rng(50);
    let pred = round_f32(&uniform(&mut r, 37 * 6, -2.0, 2.0));
    let truth = round_f32(&uniform(&mut r, 37 * 6, -2.0, 2.0));
    // (1/B) Σ_b ℓ(ŷ_b, y_b) and (2/B) w_j (ŷ − y), as before ensembles existed.
    let plain = (0..37)
        .map(|b| window_loss(1.3, &pred[b * 6..b * 6 + 6], &truth[b * 6..b * 6 + 6]))
        .sum::<f64>()
        / 37.0;
    let plain_grad: Vec<f64> = (0..37 * 6)
        .map(|i| 2.0 / 37.0 * if i % 6 < 3 { 1.0 } else { 1.3 } * (pred[i] - truth[i]))
        .collect();
    let exact = Tolerance::new(0.0, 1e-14);
    compare(
        "group 1 reference loss",
        &[l.value(&pred, &truth)],
        &[plain],
        exact,
    )
    .unwrap();
    compare(
        "group 1 reference gradient",
        &l.gradient(&pred, &truth),
        &plain_grad,
        exact,
    )
    .unwrap();
    let (loss, dpred) = run_loss(&g, &l, &pred, &truth);
    let tol = Tolerance::new(1e-6, 1e-5);
    compare_tensor(&g, "group 1 loss", &loss, &[plain], tol).unwrap();
    compare_tensor(&g, "group 1 dpred", &dpred, &plain_grad, tol).unwrap();
}

#[test]
fn batch_not_a_multiple_of_the_group_is_an_error() {
    let g = gpu();
    let n = 61 * 6;
    let pred = g.zeros("pred", &[n], DType::F32).unwrap();
    let truth = g.zeros("truth", &[n], DType::F32).unwrap();
    let loss = g.zeros("loss", &[1], DType::F32).unwrap();
    let dpred = g.zeros("dpred", &[n], DType::F32).unwrap();
    for group in [10, 0] {
        let l = PoseLoss {
            batch: 61,
            outputs: 6,
            penalty: 1.0,
            group,
        };
        for err in [
            l.forward(&g, &pred, &truth, &loss).unwrap_err(),
            l.backward(&g, &pred, &truth, &dpred).unwrap_err(),
        ] {
            let msg = err.to_string();
            assert!(msg.contains("pose loss") && msg.contains("61"), "{msg}");
        }
    }
}

#[test]
fn network_for_ensembles_uses_the_ensemble_loss() {
    let g = gpu();
    let graph = Graph::default_asset();
    let mut config = ModelConfig::gradient_check(Variant::Iastgcn);
    // No dropout, so the training forward equals the inference forward `predict` runs.
    config.dropout = 0.0;
    let (batch, group, penalty) = (4, 2, 1.7);
    for (b, m) in [(4, 0), (5, 2)] {
        let err = Network::for_ensembles(&g, &config, &graph, b, m, 3)
            .err()
            .unwrap_or_else(|| panic!("batch {b}, group {m} accepted"));
        assert!(err.to_string().contains("ensembles"), "{err}");
    }
    let net = Network::for_ensembles(&g, &config, &graph, batch, group, 3).unwrap();
    assert_eq!(net.group, group);
    net.load_parameters(&g, &Parameters::init(&config, 1))
        .unwrap();
    // set_attitude_penalty must rebuild the ensemble loss, not the plain one.
    net.set_attitude_penalty(&g, penalty).unwrap();
    let mut r = rng(90);
    let x = to_f32(&uniform(&mut r, batch * 14 * 3 * 16, -1.0, 1.0));
    let y: Vec<f64> = round_f32(&uniform(&mut r, batch * 6, -1.0, 1.0));
    let y_hat: Vec<f64> = net
        .predict(&g, &x)
        .unwrap()
        .iter()
        .map(|&v| v as f64)
        .collect();
    net.gradients(&g, &x, &to_f32(&y), 0).unwrap();
    let l = PoseLoss {
        batch,
        outputs: 6,
        penalty,
        group,
    };
    let expected = l.value(&y_hat, &y);
    let plain = PoseLoss { group: 1, ..l }.value(&y_hat, &y);
    let got = g.read_f32(&net.loss).unwrap()[0] as f64;
    let w = compare(
        "network ensemble loss",
        &[got],
        &[expected],
        Tolerance::new(0.0, 1e-5),
    )
    .unwrap();
    assert!(
        (expected - plain).abs() > 1e-3 * expected,
        "ensemble {expected} vs plain {plain}: the test cannot tell them apart"
    );
    eprintln!(
        "network ensemble loss {got:.7e} vs reference {expected:.7e} (rel {:.3e}; plain loss {plain:.7e})",
        w.rel_err
    );
}
