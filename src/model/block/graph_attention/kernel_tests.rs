//! The multi-head graph attention op (`graph_attention::kernel`): GPU forward (α and the
//! aggregate, both accumulate modes) and backward (∂ℒ/∂q, ∂ℒ/∂a_src, ∂ℒ/∂a_dst) against
//! the f64 reference, and the reference backward against central differences in f64.
#![cfg(test)]

use super::kernel::{cpu, GraphAttention};
use crate::gpu::{DType, Gpu, Tensor};
use crate::graph::Graph;
use crate::ops::Accumulate;
use crate::testing::{
    check_gradient, compare_tensor, dot, gpu, rng, round_f32, to_f32, uniform, Tolerance,
};

const GPU_TOL: Tolerance = Tolerance::new(1e-5, 1e-4);
const FD_TOL: Tolerance = Tolerance::new(1e-8, 1e-6);

fn upload(g: &Gpu, name: &str, data: &[f64]) -> Tensor {
    g.upload(name, &[data.len()], &to_f32(data)).unwrap()
}

/// A ring of `n` nodes with self loops and one chord (0–n/2), so that rows differ in
/// their neighbour count.
fn ring(n: usize) -> Vec<f64> {
    let mut m = vec![0.0; n * n];
    for i in 0..n {
        for j in [i, (i + 1) % n, (i + n - 1) % n] {
            m[i * n + j] = 1.0;
        }
    }
    m[n / 2] = 1.0;
    m[(n / 2) * n] = 1.0;
    m
}

/// The default sensor graph's adjacency with self loops.
fn sensor_mask() -> Vec<f64> {
    let a = Graph::default_asset().adjacency();
    let n = a.nrows();
    (0..n * n)
        .map(|k| {
            let (i, j) = (k / n, k % n);
            if i == j || a[(i, j)] != 0.0 {
                1.0
            } else {
                0.0
            }
        })
        .collect()
}

struct Case {
    q: Vec<f64>,
    a_src: Vec<f64>,
    a_dst: Vec<f64>,
    mask: Vec<f64>,
}

fn case(op: GraphAttention, mask: Vec<f64>, seed: u64) -> Case {
    let mut r = rng(seed);
    Case {
        q: round_f32(&uniform(&mut r, op.values(), -1.5, 1.5)),
        a_src: round_f32(&uniform(&mut r, op.channels, -1.0, 1.0)),
        a_dst: round_f32(&uniform(&mut r, op.channels, -1.0, 1.0)),
        mask,
    }
}

fn shapes() -> Vec<(GraphAttention, Vec<f64>)> {
    let op = |batch, nodes, channels, steps, heads| GraphAttention {
        batch,
        nodes,
        channels,
        steps,
        heads,
    };
    vec![
        (op(1, 3, 1, 1, 1), ring(3)),
        (op(2, 5, 6, 3, 2), ring(5)),
        (op(3, 14, 8, 5, 4), sensor_mask()),
        (op(2, 14, 16, 7, 1), sensor_mask()),
    ]
}

#[test]
fn forward_matches_reference() {
    let g = gpu();
    for (k, (op, mask)) in shapes().into_iter().enumerate() {
        let c = case(op, mask, 10 + k as u64);
        let (alpha, out) = cpu::forward(&op, &c.q, &c.a_src, &c.a_dst, &c.mask);
        // Each row of α sums to 1 over the neighbours and is 0 elsewhere.
        for (r, row) in alpha.chunks(op.nodes).enumerate() {
            let i = r % op.nodes;
            assert!((row.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            for (j, a) in row.iter().enumerate() {
                assert_eq!(*a == 0.0, c.mask[i * op.nodes + j] == 0.0, "α[{r}, {j}]");
            }
        }
        let t = |name, v: &[f64]| upload(&g, name, v);
        let (q, a_src, a_dst, m) = (
            t("q", &c.q),
            t("a_src", &c.a_src),
            t("a_dst", &c.a_dst),
            t("mask", &c.mask),
        );
        let alpha_t = g.zeros("alpha", &[op.weights()], DType::F32).unwrap();
        let out_t = g.zeros("out", &[op.values()], DType::F32).unwrap();
        let prior = round_f32(&uniform(&mut rng(90 + k as u64), op.values(), -1.0, 1.0));
        let added = t("out (added to)", &prior);
        g.run(&[
            op.attention_weights(&g, &q, &a_src, &a_dst, &m, &alpha_t)
                .unwrap(),
            op.aggregate(&g, &q, &alpha_t, &out_t, Accumulate::Overwrite)
                .unwrap(),
            op.aggregate(&g, &q, &alpha_t, &added, Accumulate::Add)
                .unwrap(),
        ])
        .unwrap();
        let what = format!("{op:?}");
        compare_tensor(&g, &format!("{what} alpha"), &alpha_t, &alpha, GPU_TOL).unwrap();
        compare_tensor(&g, &format!("{what} out"), &out_t, &out, GPU_TOL).unwrap();
        let want: Vec<f64> = prior.iter().zip(&out).map(|(p, o)| p + o).collect();
        compare_tensor(&g, &format!("{what} out added"), &added, &want, GPU_TOL).unwrap();
    }
}

#[test]
fn reference_backward_matches_finite_differences() {
    for (k, (op, mask)) in shapes().into_iter().take(3).enumerate() {
        let c = case(op, mask, 30 + k as u64);
        let d_out = uniform(&mut rng(40 + k as u64), op.values(), -1.0, 1.0);
        let (dq, da_src, da_dst) = cpu::backward(&op, &c.q, &c.a_src, &c.a_dst, &c.mask, &d_out);
        let what = format!("{op:?}");
        let loss_q = |q: &[f64]| dot(&cpu::forward(&op, q, &c.a_src, &c.a_dst, &c.mask).1, &d_out);
        check_gradient(&format!("{what} dq"), &dq, loss_q, &c.q, 1e-6, FD_TOL).unwrap();
        let loss_src = |a: &[f64]| dot(&cpu::forward(&op, &c.q, a, &c.a_dst, &c.mask).1, &d_out);
        check_gradient(
            &format!("{what} da_src"),
            &da_src,
            loss_src,
            &c.a_src,
            1e-6,
            FD_TOL,
        )
        .unwrap();
        let loss_dst = |a: &[f64]| dot(&cpu::forward(&op, &c.q, &c.a_src, a, &c.mask).1, &d_out);
        check_gradient(
            &format!("{what} da_dst"),
            &da_dst,
            loss_dst,
            &c.a_dst,
            1e-6,
            FD_TOL,
        )
        .unwrap();
        // The scores matter: the attention vectors get a gradient.
        assert!(
            da_src.iter().chain(&da_dst).any(|v| v.abs() > 1e-6),
            "{what}"
        );
    }
}

#[test]
fn backward_matches_reference() {
    let g = gpu();
    for (k, (op, mask)) in shapes().into_iter().enumerate() {
        let c = case(op, mask, 50 + k as u64);
        let d_out = round_f32(&uniform(&mut rng(60 + k as u64), op.values(), -1.0, 1.0));
        let (dq, da_src, da_dst) = cpu::backward(&op, &c.q, &c.a_src, &c.a_dst, &c.mask, &d_out);
        let t = |name, v: &[f64]| upload(&g, name, v);
        let (q, a_src, a_dst, m) = (
            t("q", &c.q),
            t("a_src", &c.a_src),
            t("a_dst", &c.a_dst),
            t("mask", &c.mask),
        );
        let dout_t = t("d out", &d_out);
        let alpha = g.zeros("alpha", &[op.weights()], DType::F32).unwrap();
        let d_score = g.zeros("d score", &[op.weights()], DType::F32).unwrap();
        let prior_q = round_f32(&uniform(&mut rng(70 + k as u64), op.values(), -1.0, 1.0));
        let prior_a = round_f32(&uniform(
            &mut rng(80 + k as u64),
            2 * op.channels,
            -1.0,
            1.0,
        ));
        let (dq_over, da_over) = (t("dq over", &prior_q), t("da over", &prior_a));
        let (dq_add, da_add) = (t("dq add", &prior_q), t("da add", &prior_a));
        let inputs = [&q, &a_src, &a_dst, &m];
        let mut dispatches = vec![op
            .attention_weights(&g, &q, &a_src, &a_dst, &m, &alpha)
            .unwrap()];
        for (dq_t, da_t, acc) in [
            (&dq_over, &da_over, Accumulate::Overwrite),
            (&dq_add, &da_add, Accumulate::Add),
        ] {
            let d = op
                .backward(&g, inputs, &alpha, &dout_t, &d_score, dq_t, da_t, acc)
                .unwrap();
            dispatches.extend(d);
        }
        g.run(&dispatches).unwrap();
        let what = format!("{op:?}");
        let da: Vec<f64> = da_src.iter().chain(&da_dst).copied().collect();
        // The parameter gradients sum over B·N·T terms: scale the tolerance to their size.
        let sum_tol = Tolerance::new(1e-5 * (op.batch * op.nodes * op.steps) as f64, 1e-4);
        compare_tensor(&g, &format!("{what} dq"), &dq_over, &dq, GPU_TOL).unwrap();
        compare_tensor(&g, &format!("{what} da"), &da_over, &da, sum_tol).unwrap();
        let plus =
            |p: &[f64], v: &[f64]| -> Vec<f64> { p.iter().zip(v).map(|(p, v)| p + v).collect() };
        compare_tensor(
            &g,
            &format!("{what} dq added"),
            &dq_add,
            &plus(&prior_q, &dq),
            GPU_TOL,
        )
        .unwrap();
        compare_tensor(
            &g,
            &format!("{what} da added"),
            &da_add,
            &plus(&prior_a, &da),
            sum_tol,
        )
        .unwrap();
    }
}

#[test]
fn heads_must_divide_the_channels() {
    let g = gpu();
    let op = GraphAttention {
        batch: 1,
        nodes: 3,
        channels: 5,
        steps: 2,
        heads: 2,
    };
    let z = |n: usize| g.zeros("t", &[n], DType::F32).unwrap();
    let (q, a, m, alpha) = (z(op.values()), z(5), z(9), z(op.weights()));
    let err = op
        .attention_weights(&g, &q, &a, &a, &m, &alpha)
        .unwrap_err()
        .to_string();
    assert!(err.contains("heads"), "{err}");
}
