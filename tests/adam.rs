//! The Adam update (with the weight decay folded into the gradient) against its f64
//! reference over consecutive steps, the reference's first step against the closed
//! form, and the decay term acting exactly as 2λw, and only when λ > 0.

use iastgcn::gpu::{DType, Gpu, Tensor};
use iastgcn::ops::adam::{cpu as adam_cpu, hyper_values, Adam};
use iastgcn::testing::{compare, compare_tensor, gpu, rng, round_f32, to_f32, uniform, Tolerance};

const LR: f64 = 1e-2;

fn adam(numel: usize, decay: f64) -> Adam {
    Adam {
        numel,
        beta1: 0.9,
        beta2: 0.999,
        eps: 1e-8,
        decay,
    }
}

fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

/// The hyper tensor's values as the GPU sees them (f32), for the reference.
fn hyper_f64(t: u64) -> [f64; 4] {
    hyper_values(LR, 0.9, 0.999, t).map(|x| x as f64)
}

/// Device state of one parameter tensor under Adam.
struct State {
    param: Tensor,
    grad: Tensor,
    m: Tensor,
    v: Tensor,
}

impl State {
    fn new(g: &Gpu, param: &[f64]) -> State {
        let n = param.len();
        State {
            param: g.upload("param", &[n], &to_f32(param)).unwrap(),
            grad: g.zeros("grad", &[n], DType::F32).unwrap(),
            m: g.zeros("m", &[n], DType::F32).unwrap(),
            v: g.zeros("v", &[n], DType::F32).unwrap(),
        }
    }

    fn read(&self, g: &Gpu, t: &Tensor) -> Vec<f64> {
        f64s(&g.read_f32(t).unwrap()[..self.param.numel()])
    }
}

#[test]
fn adam_matches_reference_over_five_steps() {
    let g = gpu();
    let hyper = g.zeros("adam hyper", &[4], DType::F32).unwrap();
    let mut worst = [0.0f64; 3];
    for (case, &(numel, decay)) in [(7, 0.0), (7, 3e-3), (4099, 0.0), (4099, 3e-3)]
        .iter()
        .enumerate()
    {
        let a = adam(numel, decay);
        let mut r = rng(40 + case as u64);
        let mut w = round_f32(&uniform(&mut r, numel, -1.0, 1.0));
        let mut m = vec![0.0; numel];
        let mut v = vec![0.0; numel];
        let s = State::new(&g, &w);
        let step = a.step(&g, &s.param, &s.grad, &s.m, &s.v, &hyper).unwrap();
        for t in 1..=5u64 {
            // Gradients of mixed scales, so some elements are dominated by the decay term.
            let scale = [1.0, 1e-2, 0.3, 1e-3, 2.0][t as usize - 1];
            let grad = round_f32(&uniform(&mut r, numel, -scale, scale));
            g.write(&s.grad, &to_f32(&grad)).unwrap();
            g.write(&hyper, &hyper_values(LR, 0.9, 0.999, t)).unwrap();
            g.run(std::slice::from_ref(&step)).unwrap();
            adam_cpu::step(&a, hyper_f64(t), &mut w, &grad, &mut m, &mut v);
        }
        let what = format!("numel {numel}, decay {decay}");
        // After 5 steps of at most ~lr each the parameters moved by O(5·lr); f32 keeps
        // them to ~1e-7, so an update wrong by 0.1% (1e-5 absolute) fails.
        let tol_w = Tolerance::new(1e-6, 1e-5);
        let got = compare_tensor(&g, &format!("{what}: param"), &s.param, &w, tol_w).unwrap();
        worst[0] = worst[0].max(got.abs_err);
        let max_m = m.iter().fold(0.0f64, |x, y| x.max(y.abs()));
        let max_v = v.iter().fold(0.0f64, |x, y| x.max(y.abs()));
        let got = compare_tensor(
            &g,
            &format!("{what}: m"),
            &s.m,
            &m,
            Tolerance::new(1e-6 * max_m, 1e-5),
        )
        .unwrap();
        worst[1] = worst[1].max(got.abs_err / max_m);
        let got = compare_tensor(
            &g,
            &format!("{what}: v"),
            &s.v,
            &v,
            Tolerance::new(1e-6 * max_v, 1e-5),
        )
        .unwrap();
        worst[2] = worst[2].max(got.abs_err / max_v);
    }
    eprintln!(
        "adam 5 steps: worst |Δparam| {:.3e}, worst |Δm|/max|m| {:.3e}, worst |Δv|/max|v| {:.3e}",
        worst[0], worst[1], worst[2]
    );
}

#[test]
fn reference_first_step_is_closed_form() {
    // At t = 1: m̂ = g', v̂ = g'², so w₁ = w − lr·g'/(|g'| + ε) with g' = g + 2λw.
    for decay in [0.0, 3e-3] {
        let a = adam(64, decay);
        let mut r = rng(60);
        let w0 = uniform(&mut r, 64, -1.0, 1.0);
        let mut grad = uniform(&mut r, 64, -1e-2, 1e-2);
        grad[0] = 0.0;
        grad[1] = 1e-9;
        let hyper = [LR, 1.0 - 0.9, 1.0 - 0.999, 0.0];
        let (mut w, mut m, mut v) = (w0.clone(), vec![0.0; 64], vec![0.0; 64]);
        adam_cpu::step(&a, hyper, &mut w, &grad, &mut m, &mut v);
        let expected: Vec<f64> = w0
            .iter()
            .zip(&grad)
            .map(|(w, g)| {
                let gp = g + 2.0 * decay * w;
                w - LR * gp / (gp.abs() + a.eps)
            })
            .collect();
        compare(
            &format!("first step, decay {decay}"),
            &w,
            &expected,
            Tolerance::new(1e-15, 1e-14),
        )
        .unwrap();
    }
    // hyper_values: [lr, 1 − β1^t, 1 − β2^t, 0].
    let h = hyper_values(1e-3, 0.9, 0.999, 3);
    assert_eq!(
        h,
        [
            1e-3,
            (1.0 - 0.9f64.powi(3)) as f32,
            (1.0 - 0.999f64.powi(3)) as f32,
            0.0
        ]
    );
}

#[test]
fn decay_is_two_lambda_w_and_only_when_positive() {
    let g = gpu();
    let n = 1001;
    let lambda = 3e-3;
    let hyper = g.zeros("adam hyper", &[4], DType::F32).unwrap();
    let mut r = rng(70);
    let w0 = round_f32(&uniform(&mut r, n, -1.0, 1.0));
    let grads: Vec<Vec<f64>> = (0..3)
        .map(|_| round_f32(&uniform(&mut r, n, -1e-2, 1e-2)))
        .collect();

    // A: decay λ fed g. B: decay 0 fed g + 2λ·w_A (computed on the host). C: decay 0 fed g.
    let (a, b, c) = (
        State::new(&g, &w0),
        State::new(&g, &w0),
        State::new(&g, &w0),
    );
    let step_a = adam(n, lambda)
        .step(&g, &a.param, &a.grad, &a.m, &a.v, &hyper)
        .unwrap();
    let step_b = adam(n, 0.0)
        .step(&g, &b.param, &b.grad, &b.m, &b.v, &hyper)
        .unwrap();
    let step_c = adam(n, 0.0)
        .step(&g, &c.param, &c.grad, &c.m, &c.v, &hyper)
        .unwrap();
    let steps = [step_a, step_b, step_c];
    let mut worst = 0.0f64;
    for (t, grad) in (1..).zip(&grads) {
        let wa = a.read(&g, &a.param);
        let folded: Vec<f64> = grad
            .iter()
            .zip(&wa)
            .map(|(g, w)| g + 2.0 * lambda * w)
            .collect();
        g.write(&a.grad, &to_f32(grad)).unwrap();
        g.write(&b.grad, &to_f32(&folded)).unwrap();
        g.write(&c.grad, &to_f32(grad)).unwrap();
        g.write(&hyper, &hyper_values(LR, 0.9, 0.999, t)).unwrap();
        g.run(&steps).unwrap();
    }
    let (wa, wb, wc) = (
        a.read(&g, &a.param),
        b.read(&g, &b.param),
        c.read(&g, &c.param),
    );
    // Same update up to the f32 rounding of g + 2λw: at most a few ulps of lr per step.
    let got = compare(
        "decay λ vs folded gradient",
        &wa,
        &wb,
        Tolerance::new(1e-6, 0.0),
    )
    .unwrap();
    worst = worst.max(got.abs_err);
    // Without decay the result differs by O(lr) where 2λw competes with g.
    let moved = wa
        .iter()
        .zip(&wc)
        .filter(|(x, y)| (*x - *y).abs() > 1e-3)
        .count();
    assert!(
        moved > n / 10,
        "decay λ changed only {moved} of {n} parameters by more than 1e-3"
    );

    // Zero gradient: decay 0 leaves the parameters exactly; decay λ pulls each |w| > lr
    // towards 0 by ≈ lr (g' = 2λw, so g'/(|g'| + ε) ≈ sign(w)).
    let z = State::new(&g, &w0);
    let zd = State::new(&g, &w0);
    g.write(&hyper, &hyper_values(LR, 0.9, 0.999, 1)).unwrap();
    g.run(&[
        adam(n, 0.0)
            .step(&g, &z.param, &z.grad, &z.m, &z.v, &hyper)
            .unwrap(),
        adam(n, lambda)
            .step(&g, &zd.param, &zd.grad, &zd.m, &zd.v, &hyper)
            .unwrap(),
    ])
    .unwrap();
    compare(
        "zero gradient, decay 0",
        &z.read(&g, &z.param),
        &w0,
        Tolerance::new(0.0, 0.0),
    )
    .unwrap();
    let shrunk: Vec<f64> = w0
        .iter()
        .map(|w| w - LR * w.signum() * (2.0 * lambda * w.abs()) / (2.0 * lambda * w.abs() + 1e-8))
        .collect();
    compare(
        "zero gradient, decay λ",
        &zd.read(&g, &zd.param),
        &shrunk,
        Tolerance::new(1e-7, 1e-6),
    )
    .unwrap();
    eprintln!("adam decay: worst |decay λ − folded| {worst:.3e}");
}
