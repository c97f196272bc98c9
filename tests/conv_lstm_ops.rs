//! The ConvLSTM cell's two ops: the 2-D unfolding of a "same" convolution
//! (`ops::unfold2d`) and the LSTM cell update (`ops::lstm`). GPU forward and backward
//! against the f64 reference (both accumulate modes where there are two), and the
//! reference backward against central differences in f64.

use iastgcn::gpu::{DType, Gpu, Tensor};
use iastgcn::ops::lstm::{self, Lstm};
use iastgcn::ops::unfold2d::{self, Unfold2d};
use iastgcn::ops::Accumulate;
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
fn unfold2d_matches_reference_and_is_the_transpose_of_its_backward() {
    let g = gpu();
    let shape = |batch, channels, height, width, kernel| Unfold2d {
        batch,
        channels,
        height,
        width,
        kernel,
    };
    // The ConvLSTM grid (14 nodes × 3 features) with 1 and 4 channels, a 1×1 kernel, a
    // kernel wider than the image, and a case past one 256-wide workgroup.
    for (k, u) in [
        shape(2, 1, 14, 3, 3),
        shape(3, 4, 14, 3, 3),
        shape(1, 2, 5, 4, 1),
        shape(2, 3, 4, 2, 5),
        shape(5, 7, 9, 6, 3),
    ]
    .into_iter()
    .enumerate()
    {
        let img = round_f32(&uniform(&mut rng(k as u64), u.image_len(), -1.0, 1.0));
        let d_col = round_f32(&uniform(&mut rng(20 + k as u64), u.col_len(), -1.0, 1.0));
        let prior = round_f32(&uniform(&mut rng(40 + k as u64), u.image_len(), -1.0, 1.0));
        let (img_t, dcol_t) = (upload(&g, "img", &img), upload(&g, "d col", &d_col));
        let col = g.zeros("col", &[u.col_len()], DType::F32).unwrap();
        let over = g.zeros("d img", &[u.image_len()], DType::F32).unwrap();
        let add = upload(&g, "d img (added to)", &prior);
        g.run(&[
            u.forward(&g, &img_t, &col).unwrap(),
            u.backward(&g, &dcol_t, &over, Accumulate::Overwrite)
                .unwrap(),
            u.backward(&g, &dcol_t, &add, Accumulate::Add).unwrap(),
        ])
        .unwrap();
        let what = format!("{u:?}");
        let want_col = unfold2d::cpu::forward(&u, &img);
        compare_tensor(&g, &format!("{what} col"), &col, &want_col, EXACT).unwrap();
        let want = unfold2d::cpu::backward(&u, &d_col);
        compare_tensor(&g, &format!("{what} d img"), &over, &want, GPU_TOL).unwrap();
        let added: Vec<f64> = prior.iter().zip(&want).map(|(p, w)| p + w).collect();
        compare_tensor(&g, &format!("{what} d img (add)"), &add, &added, GPU_TOL).unwrap();
        // The backward is the derivative of Σ d_col ⊙ unfold(img).
        let loss = |x: &[f64]| dot(&d_col, &unfold2d::cpu::forward(&u, x));
        check_gradient(&format!("{what} fd"), &want, loss, &img, 1e-3, FD_TOL).unwrap();
    }
    // The centre tap of a 3×3 unfolding is the image itself.
    let u = shape(1, 1, 4, 3, 3);
    let img: Vec<f64> = (0..12).map(f64::from).collect();
    let col = unfold2d::cpu::forward(&u, &img);
    assert_eq!(&col[4 * 12..5 * 12], &img[..]);
    // An even kernel has no centre: refused.
    let even = shape(1, 1, 4, 3, 2);
    let (a, b) = (
        g.zeros("img", &[12], DType::F32).unwrap(),
        g.zeros("col", &[48], DType::F32).unwrap(),
    );
    assert!(even.forward(&g, &a, &b).is_err());
}

#[test]
fn lstm_cell_matches_reference_and_finite_differences() {
    let g = gpu();
    for (k, &(batch, state)) in [(1, 1), (2, 129), (3, 256), (4, 300)].iter().enumerate() {
        let s = Lstm { batch, state };
        let n = batch * state;
        let mut r = rng(300 + k as u64);
        let z = round_f32(&uniform(&mut r, 4 * n, -2.0, 2.0));
        let c_prev = round_f32(&uniform(&mut r, n, -1.5, 1.5));
        let d_h = round_f32(&uniform(&mut r, n, -1.0, 1.0));
        let d_c = round_f32(&uniform(&mut r, n, -1.0, 1.0));
        let t = |name, v: &[f64]| upload(&g, name, v);
        let (zt, cpt, dht, dct) = (
            t("z", &z),
            t("c prev", &c_prev),
            t("d h", &d_h),
            t("d c", &d_c),
        );
        let (c, h) = (
            g.zeros("c", &[n], DType::F32).unwrap(),
            g.zeros("h", &[n], DType::F32).unwrap(),
        );
        let (dz, dcp) = (
            g.zeros("d z", &[4 * n], DType::F32).unwrap(),
            g.zeros("d c prev", &[n], DType::F32).unwrap(),
        );
        g.run(&[
            s.forward(&g, &zt, &cpt, &c, &h).unwrap(),
            s.backward(&g, [&zt, &cpt, &c], &dht, &dct, &dz, &dcp)
                .unwrap(),
        ])
        .unwrap();
        let what = format!("{s:?}");
        let (wc, wh) = lstm::cpu::forward(&s, &z, &c_prev);
        compare_tensor(&g, &format!("{what} c"), &c, &wc, GPU_TOL).unwrap();
        compare_tensor(&g, &format!("{what} h"), &h, &wh, GPU_TOL).unwrap();
        let (wdz, wdc) = lstm::cpu::backward(&s, &z, &c_prev, &d_h, &d_c);
        compare_tensor(&g, &format!("{what} d z"), &dz, &wdz, GPU_TOL).unwrap();
        compare_tensor(&g, &format!("{what} d c prev"), &dcp, &wdc, GPU_TOL).unwrap();
        // The reference backward is the derivative of Σ d_h ⊙ h' + d_c ⊙ c'.
        let loss = |z: &[f64], c_prev: &[f64]| {
            let (c, h) = lstm::cpu::forward(&s, z, c_prev);
            dot(&d_h, &h) + dot(&d_c, &c)
        };
        check_gradient(
            &format!("{what} dz fd"),
            &wdz,
            |x| loss(x, &c_prev),
            &z,
            1e-5,
            FD_TOL,
        )
        .unwrap();
        check_gradient(
            &format!("{what} dc fd"),
            &wdc,
            |x| loss(&z, x),
            &c_prev,
            1e-5,
            FD_TOL,
        )
        .unwrap();
    }
}
