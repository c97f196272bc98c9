//! Dropout: the GPU mask equals the CPU hash bit for bit, forward and backward use the
//! same mask, the kept fraction is 1 − p, and steps and seeds change the mask.

use iastgcn::gpu::DType;
use iastgcn::ops::dropout::{keep, Dropout};
use iastgcn::ops::Accumulate;
use iastgcn::testing::gpu;

#[test]
fn mask_matches_the_cpu_hash_and_scales_kept_values() {
    let g = gpu();
    let n = 100_003;
    let d = Dropout::new(n, 0.2, 1234);
    let x: Vec<f32> = (0..n).map(|i| 1.0 + (i % 7) as f32).collect();
    let xt = g.upload("x", &[n], &x).unwrap();
    let y = g.zeros("y", &[n], DType::F32).unwrap();
    g.run(&[d.apply(&g, 5, &xt, &y, Accumulate::Overwrite).unwrap()])
        .unwrap();
    let got = g.read_f32(&y).unwrap();
    let scale = (1.0 / 0.8f64) as f32;
    let mut kept = 0;
    for i in 0..n {
        let want = if keep(&d, 5, i) { x[i] * scale } else { 0.0 };
        assert_eq!(got[i], want, "element {i}");
        kept += usize::from(keep(&d, 5, i));
    }
    // Kept fraction 0.8 ± 4σ of a binomial.
    let frac = kept as f64 / n as f64;
    let sigma = (0.2 * 0.8 / n as f64).sqrt();
    assert!((frac - 0.8).abs() < 4.0 * sigma, "kept {frac}");
}

#[test]
fn backward_uses_the_forward_mask_and_steps_change_it() {
    let g = gpu();
    let n = 4096;
    let d = Dropout::new(n, 0.5, 7);
    let ones = g.upload("ones", &[n], &vec![1.0; n]).unwrap();
    let (y, dx) = (
        g.zeros("y", &[n], DType::F32).unwrap(),
        g.zeros("dx", &[n], DType::F32).unwrap(),
    );
    let fwd = d.apply(&g, 11, &ones, &y, Accumulate::Overwrite).unwrap();
    let bwd = d.apply(&g, 11, &ones, &dx, Accumulate::Overwrite).unwrap();
    g.run(&[fwd, bwd]).unwrap();
    let (a, b) = (g.read_f32(&y).unwrap(), g.read_f32(&dx).unwrap());
    assert_eq!(a, b, "forward and backward masks differ");
    // The same dispatch pointed at the next step gives another mask.
    let next = d.apply(&g, 11, &ones, &y, Accumulate::Overwrite).unwrap();
    d.set_step(&g, &next, 12, Accumulate::Overwrite).unwrap();
    g.run(&[next]).unwrap();
    let c = g.read_f32(&y).unwrap();
    let same = a.iter().zip(&c).filter(|(p, q)| p == q).count();
    assert!(
        (same as f64 / n as f64 - 0.5).abs() < 0.05,
        "step 12 agrees with step 11 on {same} of {n}"
    );
    let other_seed = Dropout { seed: 8, ..d };
    assert!((0..n).any(|i| keep(&d, 11, i) != keep(&other_seed, 11, i)));
}

#[test]
fn a_strided_subset_gets_the_bits_of_the_whole_tensor() {
    let g = gpu();
    // The last of 48 steps of [rows, 48]: what the trimmed last block drops.
    let (rows, steps) = (300, 48);
    let whole = Dropout::new(rows * steps, 0.3, 99);
    let last = whole.strided(rows, steps, steps - 1);
    let x: Vec<f32> = (0..rows * steps).map(|i| 1.0 + (i % 5) as f32).collect();
    let xt = g.upload("x", &[x.len()], &x).unwrap();
    let tail: Vec<f32> = (0..rows).map(|r| x[r * steps + steps - 1]).collect();
    let tt = g.upload("x last", &[rows], &tail).unwrap();
    let (y, yl) = (
        g.zeros("y", &[x.len()], DType::F32).unwrap(),
        g.zeros("y last", &[rows], DType::F32).unwrap(),
    );
    g.run(&[
        whole.apply(&g, 3, &xt, &y, Accumulate::Overwrite).unwrap(),
        last.apply(&g, 3, &tt, &yl, Accumulate::Overwrite).unwrap(),
    ])
    .unwrap();
    let (y, yl) = (g.read_f32(&y).unwrap(), g.read_f32(&yl).unwrap());
    let mut dropped = 0;
    for r in 0..rows {
        assert_eq!(yl[r], y[r * steps + steps - 1], "row {r}");
        assert_eq!(keep(&last, 3, r), keep(&whole, 3, r * steps + steps - 1));
        dropped += usize::from(yl[r] == 0.0);
    }
    assert!(dropped > 0 && dropped < rows, "{dropped} of {rows} dropped");
}
