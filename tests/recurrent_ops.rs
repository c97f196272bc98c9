//! The recurrent cell's two ops: the time-step gather (`ops::time_step`) and the GRU state
//! update (`ops::gru`). GPU forward and backward against the f64 reference (both
//! accumulate modes), and the reference backward against central differences in f64.

use iastgcn::gpu::{DType, Gpu, Tensor};
use iastgcn::ops::time_step::{self, TimeStep};
use iastgcn::ops::{gru, Accumulate};
use iastgcn::testing::{
    check_gradient, compare_tensor, dot, gpu, rng, round_f32, to_f32, uniform, Tolerance,
};

const EXACT: Tolerance = Tolerance::new(0.0, 0.0);
const GPU_TOL: Tolerance = Tolerance::new(1e-6, 1e-5);
const FD_TOL: Tolerance = Tolerance::new(1e-8, 1e-6);

fn upload(g: &Gpu, name: &str, data: &[f64]) -> Tensor {
    g.upload(name, &[data.len()], &to_f32(data)).unwrap()
}

#[test]
fn time_step_gathers_and_scatters_one_step() {
    let g = gpu();
    // Rows around the 256-wide workgroup; the first, a middle and the last step.
    for (i, &(rows, steps)) in [(1, 1), (7, 5), (257, 3), (300, 48)].iter().enumerate() {
        for step in [0, steps / 2, steps - 1] {
            let s = TimeStep { rows, steps, step };
            let y = round_f32(&uniform(&mut rng(i as u64), rows * steps, -1.0, 1.0));
            let dh = round_f32(&uniform(&mut rng(50 + i as u64), rows, -1.0, 1.0));
            let prior = round_f32(&uniform(&mut rng(90 + i as u64), rows * steps, -1.0, 1.0));
            let (yt, dht) = (upload(&g, "y", &y), upload(&g, "dh", &dh));
            let h = g.zeros("h", &[rows], DType::F32).unwrap();
            let over = upload(&g, "dy (overwritten)", &prior);
            let add = upload(&g, "dy (added to)", &prior);
            g.run(&[
                s.forward(&g, &yt, &h).unwrap(),
                s.backward(&g, &dht, &over, Accumulate::Overwrite).unwrap(),
                s.backward(&g, &dht, &add, Accumulate::Add).unwrap(),
            ])
            .unwrap();
            let what = format!("rows {rows} steps {steps} step {step}");
            compare_tensor(&g, &what, &h, &time_step::cpu::forward(&s, &y), EXACT).unwrap();
            let mut want = vec![0.0; rows * steps];
            time_step::cpu::backward(&s, &dh, &mut want);
            compare_tensor(&g, &format!("{what} overwrite"), &over, &want, EXACT).unwrap();
            let mut want = prior.clone();
            time_step::cpu::backward(&s, &dh, &mut want);
            compare_tensor(&g, &format!("{what} add"), &add, &want, GPU_TOL).unwrap();
        }
    }
    // A step past the end is refused.
    let s = TimeStep {
        rows: 2,
        steps: 3,
        step: 3,
    };
    let (y, h) = (
        g.zeros("y", &[6], DType::F32).unwrap(),
        g.zeros("h", &[2], DType::F32).unwrap(),
    );
    assert!(s.forward(&g, &y, &h).is_err());
}

#[test]
fn gru_update_matches_reference_and_finite_differences() {
    let g = gpu();
    for (i, &n) in [1usize, 255, 256, 257, 1000].iter().enumerate() {
        let mut r = rng(200 + i as u64);
        let u = round_f32(&uniform(&mut r, n, 0.0, 1.0));
        let h = round_f32(&uniform(&mut r, n, -1.0, 1.0));
        let c = round_f32(&uniform(&mut r, n, -1.0, 1.0));
        let d = round_f32(&uniform(&mut r, n, -1.0, 1.0));
        let prior = round_f32(&uniform(&mut r, n, -1.0, 1.0));
        let t = |name, v: &[f64]| upload(&g, name, v);
        let (ut, ht, ct, dt) = (t("u", &u), t("h", &h), t("c", &c), t("d out", &d));
        let out = g.zeros("out", &[n], DType::F32).unwrap();
        let (du, dc) = (
            g.zeros("du", &[n], DType::F32).unwrap(),
            g.zeros("dc", &[n], DType::F32).unwrap(),
        );
        let (dh_over, dh_add) = (t("dh over", &prior), t("dh add", &prior));
        g.run(&[
            gru::forward(&g, &ut, &ht, &ct, &out).unwrap(),
            gru::backward(
                &g,
                &ut,
                &ht,
                &ct,
                &dt,
                &du,
                &dc,
                &dh_over,
                Accumulate::Overwrite,
            )
            .unwrap(),
        ])
        .unwrap();
        // The add-mode run overwrites du and dc with the same values.
        g.run(&[
            gru::backward(&g, &ut, &ht, &ct, &dt, &du, &dc, &dh_add, Accumulate::Add).unwrap(),
        ])
        .unwrap();
        let what = format!("gru n={n}");
        compare_tensor(&g, &what, &out, &gru::cpu::forward(&u, &h, &c), GPU_TOL).unwrap();
        let (wu, wc, wh) = gru::cpu::backward(&u, &h, &c, &d);
        compare_tensor(&g, &format!("{what} du"), &du, &wu, GPU_TOL).unwrap();
        compare_tensor(&g, &format!("{what} dc"), &dc, &wc, GPU_TOL).unwrap();
        compare_tensor(&g, &format!("{what} dh"), &dh_over, &wh, GPU_TOL).unwrap();
        let added: Vec<f64> = prior.iter().zip(&wh).map(|(p, w)| p + w).collect();
        compare_tensor(&g, &format!("{what} dh (add)"), &dh_add, &added, GPU_TOL).unwrap();
        // The reference backward is the derivative of Σ d ⊙ forward.
        let l = |u: &[f64], h: &[f64], c: &[f64]| dot(&d, &gru::cpu::forward(u, h, c));
        check_gradient(
            &format!("{what} du fd"),
            &wu,
            |x| l(x, &h, &c),
            &u,
            1e-5,
            FD_TOL,
        )
        .unwrap();
        check_gradient(
            &format!("{what} dh fd"),
            &wh,
            |x| l(&u, x, &c),
            &h,
            1e-5,
            FD_TOL,
        )
        .unwrap();
        check_gradient(
            &format!("{what} dc fd"),
            &wc,
            |x| l(&u, &h, x),
            &c,
            1e-5,
            FD_TOL,
        )
        .unwrap();
    }
}
