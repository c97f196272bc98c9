//! The fused pair of outer products: GPU vs the f64 reference on the vector and scalar
//! paths, with and without accumulation, across workgroup edges; the reference vs the
//! matmul backward of the two projections it replaces in the spatial attention.

use iastgcn::gpu::{Gpu, Tensor};
use iastgcn::ops::matmul::{self, Matmul};
use iastgcn::ops::outer::{cpu, OuterPair, Second};
use iastgcn::ops::Accumulate;
use iastgcn::testing::{compare, compare_tensor, gpu, rng, round_f32, to_f32, uniform, Tolerance};

/// One product and one sum of f32 values in [-1, 1]: a few ulps.
const GPU_TOL: Tolerance = Tolerance::new(1e-6, 1e-5);

fn upload(g: &Gpu, name: &str, data: &[f64]) -> Tensor {
    g.upload(name, &[data.len()], &to_f32(data)).unwrap()
}

struct Inputs {
    u: Vec<f64>,
    v: Vec<f64>,
    w: Vec<f64>,
    q: Vec<f64>,
}

fn inputs(op: &OuterPair, seed: u64) -> Inputs {
    let mut g = rng(seed);
    let mut draw = |n| round_f32(&uniform(&mut g, n, -1.0, 1.0));
    let (w, q) = match op.second {
        Second::RowsByCols => (op.items * op.rows, op.cols),
        Second::NodeByMatrix { nodes } => (nodes, op.items / nodes * op.rows * op.cols),
    };
    Inputs {
        u: draw(op.rows),
        v: draw(op.items * op.cols),
        w: draw(w),
        q: draw(q),
    }
}

#[test]
fn matches_reference_with_and_without_accumulation() {
    let g = gpu();
    // cols a multiple of 4 (vector path) or not; rows·items around the 64-wide workgroup;
    // both forms of the second term (by node where items divide into batches of 7 or 2).
    let shapes = [
        (3, 5, 8),
        (2, 7, 9),
        (14, 5, 100),
        (1, 1, 1),
        (9, 7, 12),
        (4, 16, 6),
    ];
    let mut cases = Vec::new();
    for (items, rows, cols) in shapes {
        cases.push((items, rows, cols, Second::RowsByCols));
        for nodes in [7, 2].into_iter().filter(|n| items % n == 0) {
            cases.push((items, rows, cols, Second::NodeByMatrix { nodes }));
        }
    }
    for (s, &(items, rows, cols, second)) in cases.iter().enumerate() {
        let op = OuterPair {
            items,
            rows,
            cols,
            second,
        };
        let x = inputs(&op, s as u64);
        let reference = cpu::apply(&op, &x.u, &x.v, &x.w, &x.q);
        let (u, v, w, q) = (
            upload(&g, "u", &x.u),
            upload(&g, "v", &x.v),
            upload(&g, "w", &x.w),
            upload(&g, "q", &x.q),
        );
        for accumulate in Accumulate::ALL {
            let start: Vec<f64> = (0..reference.len()).map(|i| (i % 5) as f64 - 2.0).collect();
            let out = upload(&g, "out", &start);
            g.run(&[op.apply(&g, [&u, &v, &w, &q], &out, accumulate).unwrap()])
                .unwrap();
            let expected: Vec<f64> = reference
                .iter()
                .zip(&start)
                .map(|(r, s0)| {
                    r + if accumulate == Accumulate::Add {
                        *s0
                    } else {
                        0.0
                    }
                })
                .collect();
            let what = format!("{op:?} accumulate {accumulate:?}");
            compare_tensor(&g, &what, &out, &expected, GPU_TOL).unwrap();
        }
    }
}

/// What the model relies on: for rhs[b, n] = W3·X_t[b, n] and xw1 = X_t·W1, the pair
/// with u = W3, v = d rhs, w = d xw1, q = W1 is the sum of the two products' dX_t.
#[test]
fn reference_equals_the_spatial_projections_backward() {
    let (b, n, c, t) = (2, 3, 4, 5);
    let op = OuterPair {
        items: b * n,
        rows: c,
        cols: t,
        second: Second::RowsByCols,
    };
    let x = inputs(&op, 77);
    let xt = round_f32(&uniform(&mut rng(78), b * n * c * t, -1.0, 1.0));
    let w3 = Matmul::new(1, t, c).batched(b * n).share_a(true);
    let w1 = Matmul::new(b * n * c, 1, t);
    let (_, from_rhs) = matmul::cpu::backward(&w3, &x.u, &xt, &x.v);
    let (from_xw1, _) = matmul::cpu::backward(&w1, &xt, &x.q, &x.w);
    let sum: Vec<f64> = from_rhs.iter().zip(&from_xw1).map(|(p, q)| p + q).collect();
    let got = cpu::apply(&op, &x.u, &x.v, &x.w, &x.q);
    compare(
        "pair vs projections' dX_t",
        &got,
        &sum,
        Tolerance::new(1e-12, 1e-12),
    )
    .unwrap();
}

/// And for the temporal attention's rhs[b, n] = U3·X[b, n] and xu1[b] = U1·X[b] (over the
/// nodes), the pair with u = U3, v = d rhs, w = U1, q = d xu1 is the sum of their dX.
#[test]
fn reference_equals_the_temporal_projections_backward() {
    let (b, n, c, t) = (2, 3, 4, 5);
    let op = OuterPair {
        items: b * n,
        rows: c,
        cols: t,
        second: Second::NodeByMatrix { nodes: n },
    };
    let x = inputs(&op, 79);
    let xs = round_f32(&uniform(&mut rng(80), b * n * c * t, -1.0, 1.0));
    let u3 = Matmul::new(1, t, c).batched(b * n).share_a(true);
    let u1 = Matmul::new(1, c * t, n).batched(b).share_a(true);
    let (_, from_rhs) = matmul::cpu::backward(&u3, &x.u, &xs, &x.v);
    let (_, from_xu1) = matmul::cpu::backward(&u1, &x.w, &xs, &x.q);
    let sum: Vec<f64> = from_rhs.iter().zip(&from_xu1).map(|(p, q)| p + q).collect();
    let got = cpu::apply(&op, &x.u, &x.v, &x.w, &x.q);
    compare(
        "pair vs projections' dX",
        &got,
        &sum,
        Tolerance::new(1e-12, 1e-12),
    )
    .unwrap();
}

#[test]
fn wrong_lengths_and_aliasing_name_the_tensor() {
    let g = gpu();
    let op = OuterPair {
        items: 2,
        rows: 3,
        cols: 4,
        second: Second::RowsByCols,
    };
    let zeros = |name, n| upload(&g, name, &vec![0.0; n]);
    let (u, v, w, q) = (
        zeros("W3", 3),
        zeros("d rhs", 8),
        zeros("d xw1", 5),
        zeros("W1", 4),
    );
    let out = zeros("dX_t", 24);
    let err = op
        .apply(&g, [&u, &v, &w, &q], &out, Accumulate::Overwrite)
        .unwrap_err();
    assert!(err.to_string().contains("d xw1"), "{err}");
    let w = zeros("d xw1", 6);
    let err = op
        .apply(&g, [&u, &v, &w, &q], &v, Accumulate::Overwrite)
        .unwrap_err();
    assert!(err.to_string().contains("d rhs"), "{err}");
    let by_node = OuterPair {
        second: Second::NodeByMatrix { nodes: 3 },
        ..op
    };
    let err = by_node
        .apply(&g, [&u, &v, &w, &q], &out, Accumulate::Overwrite)
        .unwrap_err();
    assert!(err.to_string().contains("nodes"), "{err}");
}
