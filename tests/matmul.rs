//! Batched matmul: forward vs the f64 reference, backward vs the f64 backward, and the
//! f64 backward vs central differences, on ragged shapes and every transpose/sharing mode.
//!
//! One file past 600 lines on purpose: every test draws on the shared shape list and
//! helpers at the top, and each file in tests/ is one more test binary to build and link.

use iastgcn::gpu::{DType, Gpu, Planning, Tensor};
use iastgcn::model::block::gated_dcc::kernel as gated_dcc;
use iastgcn::ops::matmul::{cpu, plan, Epilogue, Loads, Matmul, Tiling};
use iastgcn::ops::Accumulate;
use iastgcn::testing::{
    check_gradient, compare_tensor, dot, gpu, rng, round_f32, to_f32, uniform, Tolerance,
};

/// Shapes that are not multiples of the 4×4 register block or the 8×8 workgroup.
fn cases() -> Vec<Matmul> {
    let mut v = vec![
        Matmul::new(1, 1, 1),
        Matmul::new(5, 7, 3),
        Matmul::new(70, 9, 130),
        // One operand aligned for vector loads, the other not, K ragged (S'·X_t).
        Matmul::new(14, 24, 14).batched(3),
        Matmul::new(14, 24, 14).batched(2).share_a(true),
        // Aligned operands with a ragged K: vector loads, then the scalar tail.
        Matmul::new(8, 12, 10).batched(2).share_a(true),
        // One output row or column (the row kernel), aligned and ragged.
        Matmul::new(1, 24, 14).batched(3).share_a(true),
        Matmul::new(1, 40, 12).batched(2),
        Matmul::new(20, 1, 12).batched(2).share_b(true),
        Matmul::new(7, 1, 5),
        Matmul::new(16, 12, 1).batched(2),
        // Batched with whole groups of column blocks per item (the grid's z axis), and
        // ragged ones over more than one group of rows (the flat x axis).
        Matmul::new(9, 64, 10).batched(3),
        Matmul::new(70, 20, 9).batched(2).share_a(true),
        // Flat grid with more row blocks than one group holds (34 > 32): several groups
        // along y.
        Matmul::new(270, 12, 5).batched(2),
        // op(A)·(op(B) + I): the identity's term added in the epilogue from op(A) (forward,
        // dA of an untransposed A) or from dC (dA of a transposed A), read as vectors
        // (aligned) or scalars (ragged), on the block and the row kernels.
        Matmul::new(9, 12, 12).batched(2).plus_identity(true),
        Matmul::new(7, 5, 5).plus_identity(true),
        Matmul::new(16, 8, 8)
            .batched(3)
            .transpose_a(true)
            .plus_identity(true),
        Matmul::new(13, 9, 9)
            .batched(2)
            .transpose_b(true)
            .share_b(true)
            .plus_identity(true),
        Matmul::new(1, 8, 8).batched(2).plus_identity(true),
        Matmul::new(1, 6, 6).transpose_a(true).plus_identity(true),
    ];
    for (ta, tb) in [(false, false), (true, false), (false, true), (true, true)] {
        v.push(Matmul::new(33, 31, 37).transpose_a(ta).transpose_b(tb));
        // Aligned: vector loads along every axis combination.
        v.push(
            Matmul::new(12, 20, 16)
                .batched(2)
                .share_b(true)
                .transpose_a(ta)
                .transpose_b(tb),
        );
        v.push(
            Matmul::new(6, 13, 10)
                .batched(3)
                .share_b(true)
                .transpose_a(ta)
                .transpose_b(tb),
        );
        v.push(
            Matmul::new(11, 5, 9)
                .batched(4)
                .share_a(true)
                .transpose_a(ta)
                .transpose_b(tb),
        );
        v.push(
            Matmul::new(3, 18, 7)
                .batched(2)
                .transpose_a(ta)
                .transpose_b(tb),
        );
    }
    v
}

/// The kernels for products of more than one row this device runs: the block kernel,
/// and the subgroup kernel where subgroups have 8 lanes (lavapipe).
fn tilings(g: &Gpu) -> Vec<Tiling> {
    let mut t = vec![Tiling::Block];
    if g.subgroup_size() == Some(8) {
        t.push(Tiling::Subgroup);
    }
    t
}

/// Each shape on each kernel.
fn on_every_kernel(g: &Gpu, shapes: impl IntoIterator<Item = Matmul>) -> Vec<Matmul> {
    let t = tilings(g);
    shapes
        .into_iter()
        .flat_map(|mm| t.iter().map(move |&k| mm.tiling(k)))
        .collect()
}

/// The device twice: launches planned as for a CPU adapter and as for a GPU (split
/// reductions' chunk lengths, lanes adding each output's partial sums), whatever it is.
fn both_plans() -> [Gpu; 2] {
    [Planning::Cpu, Planning::Gpu].map(|p| gpu().with_planning(p))
}

/// f32 sums of `k` products of values in [-1, 1]: √k·few ulps absolute, far below the
/// O(1) error of any indexing bug.
fn gpu_tol(k: usize) -> Tolerance {
    Tolerance::new(4e-6 * (k as f64).sqrt(), 1e-4)
}

struct Inputs {
    a: Vec<f64>,
    b: Vec<f64>,
    dc: Vec<f64>,
}

fn inputs(mm: &Matmul, seed: u64) -> Inputs {
    let mut g = rng(seed);
    Inputs {
        a: round_f32(&uniform(&mut g, mm.a_len(), -1.0, 1.0)),
        b: round_f32(&uniform(&mut g, mm.b_len(), -1.0, 1.0)),
        dc: round_f32(&uniform(&mut g, mm.c_len(), -1.0, 1.0)),
    }
}

fn upload(g: &Gpu, name: &str, data: &[f64]) -> Tensor {
    g.upload(name, &[data.len()], &to_f32(data)).unwrap()
}

#[test]
fn forward_matches_reference() {
    let g = gpu();
    for (i, mm) in on_every_kernel(&g, cases()).into_iter().enumerate() {
        let x = inputs(&mm, i as u64);
        let (a, b) = (upload(&g, "a", &x.a), upload(&g, "b", &x.b));
        let c = g.zeros("c", &[mm.c_len()], DType::F32).unwrap();
        g.run(&[mm.forward(&g, &a, &b, &c, Accumulate::Overwrite).unwrap()])
            .unwrap();
        compare_tensor(
            &g,
            &format!("{mm:?} forward"),
            &c,
            &cpu::forward(&mm, &x.a, &x.b),
            gpu_tol(mm.k),
        )
        .unwrap();
    }
}

#[test]
fn backward_matches_reference() {
    let g = gpu();
    for (i, mm) in on_every_kernel(&g, cases()).into_iter().enumerate() {
        let x = inputs(&mm, 100 + i as u64);
        let (a, b, dc) = (
            upload(&g, "a", &x.a),
            upload(&g, "b", &x.b),
            upload(&g, "dc", &x.dc),
        );
        let da = g.zeros("da", &[mm.a_len()], DType::F32).unwrap();
        let db = g.zeros("db", &[mm.b_len()], DType::F32).unwrap();
        g.run(&[
            mm.backward_a(&g, &b, &dc, &da, Accumulate::Overwrite)
                .unwrap(),
            mm.backward_b(&g, &a, &dc, &db, Accumulate::Overwrite)
                .unwrap(),
        ])
        .unwrap();
        let (da_ref, db_ref) = cpu::backward(&mm, &x.a, &x.b, &x.dc);
        let ka = mm.n * if mm.shared_a { mm.batch } else { 1 };
        let kb = mm.m * if mm.shared_b { mm.batch } else { 1 };
        compare_tensor(&g, &format!("{mm:?} dA"), &da, &da_ref, gpu_tol(ka)).unwrap();
        compare_tensor(&g, &format!("{mm:?} dB"), &db, &db_ref, gpu_tol(kb)).unwrap();
    }
}

#[test]
fn reference_backward_matches_finite_differences() {
    for (i, mm) in cases().into_iter().enumerate() {
        let x = inputs(&mm, 200 + i as u64);
        let (da, db) = cpu::backward(&mm, &x.a, &x.b, &x.dc);
        // L = <dc, A·B> is bilinear: central differences are exact up to rounding.
        let tol = Tolerance::new(1e-8, 1e-7);
        check_gradient(
            &format!("{mm:?} dA"),
            &da,
            |a| dot(&x.dc, &cpu::forward(&mm, a, &x.b)),
            &x.a,
            1e-3,
            tol,
        )
        .unwrap();
        check_gradient(
            &format!("{mm:?} dB"),
            &db,
            |b| dot(&x.dc, &cpu::forward(&mm, &x.a, b)),
            &x.b,
            1e-3,
            tol,
        )
        .unwrap();
    }
}

#[test]
fn epilogue_adds_one_bias_per_output_row_then_relu() {
    let g = gpu();
    // 4×4 blocks (both workgroup shapes), one row, and one column (the swapped row kernel).
    let shapes = [
        Matmul::new(36, 20, 16).batched(3).share_a(true),
        Matmul::new(14, 24, 14).batched(2),
        Matmul::new(1, 40, 12).batched(2),
        Matmul::new(20, 1, 12).batched(2).share_b(true),
    ];
    for (i, mm) in on_every_kernel(&g, shapes).into_iter().enumerate() {
        let x = inputs(&mm, 400 + i as u64);
        let bias: Vec<f64> = (0..mm.m).map(|r| 0.5 - r as f64 * 0.125).collect();
        let c0: Vec<f64> = (0..mm.c_len()).map(|j| j as f64 * 0.01).collect();
        let (a, b, tb) = (
            upload(&g, "a", &x.a),
            upload(&g, "b", &x.b),
            upload(&g, "bias", &bias),
        );
        for (accumulate, relu) in [
            (Accumulate::Overwrite, false),
            (Accumulate::Add, false),
            (Accumulate::Add, true),
        ] {
            let c = upload(&g, "c", &c0);
            let epilogue = Epilogue {
                bias: Some(&tb),
                relu,
                ..Epilogue::default()
            };
            g.run(&[mm
                .forward_with(&g, &a, &b, &c, accumulate, epilogue)
                .unwrap()])
                .unwrap();
            let want: Vec<f64> = cpu::forward(&mm, &x.a, &x.b)
                .iter()
                .enumerate()
                .map(|(j, v)| {
                    let row = (j / mm.n) % mm.m;
                    let added = accumulate == Accumulate::Add;
                    let v = v + bias[row] + if added { c0[j] } else { 0.0 };
                    if relu {
                        v.max(0.0)
                    } else {
                        v
                    }
                })
                .collect();
            compare_tensor(
                &g,
                &format!("{mm:?} accumulate={accumulate:?}"),
                &c,
                &want,
                gpu_tol(mm.k),
            )
            .unwrap();
        }
    }
    // A whole [m, n] matrix added to every batch item (Ψ + Ψ·S' in the model).
    let shapes = [
        Matmul::new(14, 14, 14).batched(3).share_a(true),
        Matmul::new(36, 20, 16).batched(2),
    ];
    for (i, mm) in on_every_kernel(&g, shapes).into_iter().enumerate() {
        let x = inputs(&mm, 500 + i as u64);
        let add: Vec<f64> = (0..mm.m * mm.n).map(|j| 0.25 - j as f64 * 0.01).collect();
        let (a, b, ta) = (
            upload(&g, "a", &x.a),
            upload(&g, "b", &x.b),
            upload(&g, "add", &add),
        );
        let c = upload(&g, "c", &vec![0.0; mm.c_len()]);
        let epilogue = Epilogue {
            matrix: Some(&ta),
            ..Epilogue::default()
        };
        g.run(&[mm
            .forward_with(&g, &a, &b, &c, Accumulate::Overwrite, epilogue)
            .unwrap()])
            .unwrap();
        let want: Vec<f64> = cpu::forward(&mm, &x.a, &x.b)
            .iter()
            .enumerate()
            .map(|(j, v)| v + add[j % (mm.m * mm.n)])
            .collect();
        compare_tensor(&g, &format!("{mm:?} + matrix"), &c, &want, gpu_tol(mm.k)).unwrap();
    }
    let mm = Matmul::new(4, 4, 4);
    let t = |n: &str, len: usize| g.zeros(n, &[len], DType::F32).unwrap();
    let bias = t("bias", 3);
    let epilogue = Epilogue {
        bias: Some(&bias),
        relu: false,
        ..Epilogue::default()
    };
    let err = mm
        .forward_with(
            &g,
            &t("a", 16),
            &t("b", 16),
            &t("c", 16),
            Accumulate::Overwrite,
            epilogue,
        )
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("tensor bias") && err.contains("4 elements"),
        "{err}"
    );
}

#[test]
fn gate_epilogue_applies_tanh_of_the_filter_times_sigmoid() {
    // The gated convolution's gate product with the gate fused: C = tanh(F) ⊙ σ(A·B + b),
    // on the flat grid (n = 20 per item) and the 8×8 groups (n = 64 per item).
    let g = gpu();
    let shapes = [
        Matmul::new(12, 20, 16).batched(3).share_a(true),
        Matmul::new(9, 64, 10).batched(2).share_a(true),
    ];
    for (i, mm) in on_every_kernel(&g, shapes).into_iter().enumerate() {
        let x = inputs(&mm, 450 + i as u64);
        let mut r = rng(460 + i as u64);
        let f = round_f32(&uniform(&mut r, mm.c_len(), -2.0, 2.0));
        let bias: Vec<f64> = (0..mm.m).map(|row| 0.25 - row as f64 * 0.0625).collect();
        let (a, b, tf, tb) = (
            upload(&g, "a", &x.a),
            upload(&g, "b", &x.b),
            upload(&g, "f", &f),
            upload(&g, "bias", &bias),
        );
        let c = g.zeros("h", &[mm.c_len()], DType::F32).unwrap();
        let epilogue = Epilogue {
            bias: Some(&tb),
            gate: Some(&tf),
            ..Epilogue::default()
        };
        g.run(&[mm
            .forward_with(&g, &a, &b, &c, Accumulate::Overwrite, epilogue)
            .unwrap()])
            .unwrap();
        let pre: Vec<f64> = cpu::forward(&mm, &x.a, &x.b)
            .iter()
            .enumerate()
            .map(|(j, v)| v + bias[(j / mm.n) % mm.m])
            .collect();
        let want = gated_dcc::cpu::gate(&f, &pre);
        compare_tensor(&g, &format!("{mm:?} gated"), &c, &want, gpu_tol(mm.k)).unwrap();
        // The gate input must be laid out like C.
        let short = g.zeros("f short", &[mm.c_len() - 1], DType::F32).unwrap();
        let bad = Epilogue {
            gate: Some(&short),
            ..Epilogue::default()
        };
        let err = mm
            .forward_with(&g, &a, &b, &c, Accumulate::Overwrite, bad)
            .unwrap_err()
            .to_string();
        assert!(err.contains("f short"), "{err}");
    }
}

#[test]
fn sigmoid_epilogues_give_an_attentions_scores_and_their_gradient() {
    // Forward: S = σ(op(A)·op(B) + bias matrix), the attention scores (T×T items, and the
    // spatial N×N ones with a transposed B). Backward: dB = (op(A)ᵀ·dC) ⊙ s ⊙ (1 − s) for
    // the product V·s that reads them, on shared and per-item weights.
    let g = gpu();
    let sigma = |x: f64| 1.0 / (1.0 + (-x).exp());
    let scores = [
        Matmul::new(20, 20, 14).batched(3),
        Matmul::new(14, 14, 20).batched(2).transpose_b(true),
    ];
    for (i, mm) in on_every_kernel(&g, scores).into_iter().enumerate() {
        let x = inputs(&mm, 700 + i as u64);
        let add: Vec<f64> = (0..mm.m * mm.n).map(|j| 0.3 - j as f64 * 0.002).collect();
        let (a, b, ta) = (
            upload(&g, "a", &x.a),
            upload(&g, "b", &x.b),
            upload(&g, "be", &add),
        );
        let c = g.zeros("sig", &[mm.c_len()], DType::F32).unwrap();
        let epilogue = Epilogue {
            matrix: Some(&ta),
            sigmoid: true,
            ..Epilogue::default()
        };
        g.run(&[mm
            .forward_with(&g, &a, &b, &c, Accumulate::Overwrite, epilogue)
            .unwrap()])
            .unwrap();
        let want: Vec<f64> = cpu::forward(&mm, &x.a, &x.b)
            .iter()
            .enumerate()
            .map(|(j, v)| sigma(v + add[j % (mm.m * mm.n)]))
            .collect();
        compare_tensor(&g, &format!("{mm:?} σ(· + be)"), &c, &want, gpu_tol(mm.k)).unwrap();
    }
    let weights = [
        Matmul::new(20, 20, 20).batched(3).share_a(true),
        Matmul::new(14, 14, 14).batched(2),
        Matmul::new(12, 36, 12).batched(2).share_a(true),
    ];
    for (i, mm) in on_every_kernel(&g, weights).into_iter().enumerate() {
        let x = inputs(&mm, 720 + i as u64);
        let s = round_f32(&uniform(&mut rng(740 + i as u64), mm.b_len(), 0.01, 0.99));
        let (a, dc, ts) = (
            upload(&g, "a", &x.a),
            upload(&g, "dc", &x.dc),
            upload(&g, "s", &s),
        );
        let db = g.zeros("dP", &[mm.b_len()], DType::F32).unwrap();
        let epilogue = Epilogue {
            sigmoid_backward: Some(&ts),
            ..Epilogue::default()
        };
        g.run(&[mm
            .backward_b_with(&g, &a, &dc, &db, Accumulate::Overwrite, epilogue)
            .unwrap()])
            .unwrap();
        let (_, dsig) = cpu::backward(&mm, &x.a, &x.b, &x.dc);
        let want: Vec<f64> = dsig
            .iter()
            .zip(&s)
            .map(|(d, s)| d * s * (1.0 - s))
            .collect();
        compare_tensor(&g, &format!("{mm:?} dP"), &db, &want, gpu_tol(mm.m)).unwrap();
        // Refused: onto an accumulation, two activations, a tensor not laid out like dB,
        // a bias on a gradient.
        let err = |e: Epilogue, acc| {
            mm.backward_b_with(&g, &a, &dc, &db, acc, e)
                .unwrap_err()
                .to_string()
        };
        let msg = err(epilogue, Accumulate::Add);
        assert!(msg.contains("dP") && msg.contains("accumulation"), "{msg}");
        let both = Epilogue {
            relu: true,
            ..epilogue
        };
        let msg = err(both, Accumulate::Overwrite);
        assert!(msg.contains("one of ReLU"), "{msg}");
        let short = g.zeros("s short", &[mm.b_len() - 1], DType::F32).unwrap();
        let msg = err(
            Epilogue {
                sigmoid_backward: Some(&short),
                ..Epilogue::default()
            },
            Accumulate::Overwrite,
        );
        assert!(msg.contains("s short"), "{msg}");
        let msg = err(
            Epilogue {
                bias: Some(&ts),
                ..Epilogue::default()
            },
            Accumulate::Overwrite,
        );
        assert!(msg.contains("an activation alone"), "{msg}");
    }
}

#[test]
fn accumulate_adds_to_existing_values() {
    let g = gpu();
    let shape = Matmul::new(9, 6, 5)
        .batched(2)
        .share_b(true)
        .transpose_b(true);
    for mm in on_every_kernel(&g, [shape]) {
        let x = inputs(&mm, 300);
        let (a, b, dc) = (
            upload(&g, "a", &x.a),
            upload(&g, "b", &x.b),
            upload(&g, "dc", &x.dc),
        );
        let c0: Vec<f64> = (0..mm.c_len()).map(|i| i as f64 * 0.25).collect();
        let db0: Vec<f64> = (0..mm.b_len()).map(|i| 1.0 - i as f64 * 0.5).collect();
        let (c, db) = (upload(&g, "c", &c0), upload(&g, "db", &db0));
        g.run(&[
            mm.forward(&g, &a, &b, &c, Accumulate::Add).unwrap(),
            mm.backward_b(&g, &a, &dc, &db, Accumulate::Add).unwrap(),
        ])
        .unwrap();
        let c_ref: Vec<f64> = cpu::forward(&mm, &x.a, &x.b)
            .iter()
            .zip(&c0)
            .map(|(p, q)| p + q)
            .collect();
        let db_ref: Vec<f64> = cpu::backward(&mm, &x.a, &x.b, &x.dc)
            .1
            .iter()
            .zip(&db0)
            .map(|(p, q)| p + q)
            .collect();
        compare_tensor(&g, &format!("{mm:?} accumulated C"), &c, &c_ref, gpu_tol(5)).unwrap();
        compare_tensor(
            &g,
            &format!("{mm:?} accumulated dB"),
            &db,
            &db_ref,
            gpu_tol(18),
        )
        .unwrap();
    }
}

/// The gradient of A (`grad_a`) or B of `mm` on the device, over a gradient that starts
/// non-zero, with and without accumulation: recorded as `launches` launches (2: a split
/// product and the sum of its partial results) and equal to the f64 reference.
/// What a launch leaves in a tensor that held `start`: `result`, plus `start` when it
/// accumulates.
fn onto_start(result: &[f64], start: &[f64], accumulate: Accumulate) -> Vec<f64> {
    let add = accumulate == Accumulate::Add;
    result
        .iter()
        .zip(start)
        .map(|(r, s)| r + if add { *s } else { 0.0 })
        .collect()
}

fn check_gradient_launches(g: &Gpu, mm: &Matmul, grad_a: bool, launches: usize, seed: u64) {
    let x = inputs(mm, seed);
    let (a, b, dc) = (
        upload(g, "a", &x.a),
        upload(g, "b", &x.b),
        upload(g, "dc", &x.dc),
    );
    let (da_ref, db_ref) = cpu::backward(mm, &x.a, &x.b, &x.dc);
    let (grad_ref, len, k) = if grad_a {
        (da_ref, mm.a_len(), mm.n * mm.batch)
    } else {
        (db_ref, mm.b_len(), mm.m * mm.batch)
    };
    for accumulate in Accumulate::ALL {
        let g0: Vec<f64> = (0..len).map(|j| 0.5 - j as f64 * 0.01).collect();
        let grad = upload(g, "dw", &g0);
        let d = if grad_a {
            mm.backward_a(g, &b, &dc, &grad, accumulate)
        } else {
            mm.backward_b(g, &a, &dc, &grad, accumulate)
        }
        .unwrap();
        assert_eq!(d.launches(), launches, "{mm:?}");
        assert_eq!(d.target(), "dw");
        g.run(&[d]).unwrap();
        let want = onto_start(&grad_ref, &g0, accumulate);
        let what = format!("{mm:?} gradient, accumulate {accumulate:?}");
        compare_tensor(g, &what, &grad, &want, gpu_tol(k)).unwrap();
    }
}

#[test]
fn split_weight_gradients_match_reference() {
    // Shared operands whose batch-summed gradient is split into chunks and summed by a
    // second launch: chunks of at most 1024 steps of k per invocation (k = 100 over 35
    // items: chunks of 10, the last one short), and chunks of ~1 MiB of operands where
    // rows and columns of C are many (m + n > 256: 268 rows, 24 items per chunk of 30);
    // ragged output blocks, every transpose, with and without accumulation.
    for g in both_plans() {
        for (i, (ta, tb)) in [(false, false), (true, false), (false, true), (true, true)]
            .into_iter()
            .enumerate()
        {
            for (j, (rows, k, items)) in [(12, 100, 35), (260, 40, 30)].into_iter().enumerate() {
                let shared_a = i % 2 == 0;
                // The gradient is [rows, 8] (or its transpose), reduced over k steps of `items`.
                let (m, n, kk) = if shared_a { (rows, k, 8) } else { (k, 8, rows) };
                let shape = Matmul::new(m, n, kk)
                    .batched(items)
                    .transpose_a(ta)
                    .transpose_b(tb)
                    .share_a(shared_a)
                    .share_b(!shared_a);
                for mm in on_every_kernel(&g, [shape]) {
                    check_gradient_launches(&g, &mm, shared_a, 2, 500 + (2 * i + j) as u64);
                }
            }
        }
    }
}

#[test]
fn single_row_gradients_are_split_into_chunks() {
    // One row of C reduced over many items or a long k (the attentions' rank-1 weights:
    // U1, U3, W3 summed over the batch, each item's long k in slices; W1 over B·N·C_in
    // rows of one product): the row kernel sums chunks of ~4096 multiply-adds (512 on a
    // GPU) into partial rows, and a second launch adds them. Ragged chunk counts, both layouts of each operand, with and without
    // accumulation; a k with no divisor to split at stays one launch.
    let mut shapes = Vec::new();
    for (ta, tb) in [(false, false), (true, false), (false, true), (true, true)] {
        // dA: m = 1, n = 10, k = 700 summed over 12 items in chunks of 5 (the last short).
        let by_items = Matmul::new(1, 700, 10)
            .batched(12)
            .share_a(true)
            .transpose_a(ta)
            .transpose_b(tb);
        // dB: op(B) is [20, 1], its gradient one row of k = 12 288 = 24 chunks of 512.
        let by_k = Matmul::new(12288, 1, 20).transpose_a(ta).transpose_b(tb);
        // dA: m = 1, n = 14, a long k = 6 400 per item over 3 items (U1's gradient): each
        // item's k cut into 16 slices of 400, the 48 slices summed in chunks.
        let long_items = Matmul::new(1, 6400, 14)
            .batched(3)
            .share_a(true)
            .transpose_a(ta)
            .transpose_b(tb);
        shapes.push((by_items, true, 2));
        shapes.push((by_k, false, 2));
        shapes.push((long_items, true, 2));
    }
    // 12 289 is prime: no chunk length divides it.
    shapes.push((Matmul::new(12289, 1, 20), false, 1));
    for (i, (mm, grad_a, launches)) in shapes.into_iter().enumerate() {
        for g in both_plans() {
            check_gradient_launches(&g, &mm, grad_a, launches, 700 + i as u64);
        }
    }
}

#[test]
fn many_partial_sums_are_added_by_lanes() {
    // A shared A's gradient ([3, 5] summed over many items of k = 4) split into chunks of
    // 64 items by the GPU's plan (256 on a CPU's): 20 to 601 partial sums per output, which
    // the GPU's plan adds with 2 to 64 lanes each (at least 8 sums per lane; a count no
    // multiple of the lanes, a last chunk 7 items short), 15 outputs in one workgroup, with
    // and without accumulation; the CPU's plan adds them with one lane, in order.
    let plans = both_plans();
    for (i, partials) in [20, 40, 70, 130, 300, 601].into_iter().enumerate() {
        let shape = Matmul::new(3, 4, 5)
            .batched(64 * partials - 7)
            .share_a(true);
        for g in &plans {
            check_gradient_launches(g, &shape, true, 2, 950 + i as u64);
        }
    }
}

#[test]
fn long_reductions_are_split_within_batch_items() {
    // A batched product with few blocks of C and a long k (the graph convolution's
    // dQ = dM·X_tᵀ, 14 × 14 per window over k = C·T) is cut along k into slices of a
    // multiple-of-4 divisor of k in [256, 1024] (in [64, 256] when planned for a GPU),
    // each slice summed by its own invocations and an item's slices added by a second
    // launch.
    for g in both_plans() {
        for (ta, tb) in [(false, false), (true, false), (false, true), (true, true)] {
            // k = 4160 = 5 slices of 832 (20 of 208 for a GPU): the row kernel for m = 1, every tiled kernel the
            // device has for the others (subgroup ones from 32 columns).
            let shapes = [(6, 7), (1, 5), (6, 40), (20, 40)].map(|(m, n)| {
                Matmul::new(m, n, 4160)
                    .batched(3)
                    .transpose_a(ta)
                    .transpose_b(tb)
            });
            for (i, mm) in on_every_kernel(&g, shapes).into_iter().enumerate() {
                let x = inputs(&mm, 900 + i as u64);
                let (a, b) = (upload(&g, "a", &x.a), upload(&g, "b", &x.b));
                let want = cpu::forward(&mm, &x.a, &x.b);
                for accumulate in Accumulate::ALL {
                    let c0: Vec<f64> = (0..mm.c_len()).map(|j| 0.25 - j as f64 * 0.01).collect();
                    let c = upload(&g, "c", &c0);
                    let d = mm.forward(&g, &a, &b, &c, accumulate).unwrap();
                    assert_eq!(d.launches(), 2, "{mm:?}");
                    g.run(&[d]).unwrap();
                    let want = onto_start(&want, &c0, accumulate);
                    let what = format!("{mm:?}, accumulate {accumulate:?}");
                    compare_tensor(&g, &what, &c, &want, gpu_tol(4160)).unwrap();
                }
            }
            // dQ of M = Q·X_t: [2, 14, 14] from dM and X_t over k = 6400 (8 slices of 800,
            // 25 of 256 for a GPU).
            let mix = Matmul::new(14, 6400, 14)
                .batched(2)
                .transpose_a(ta)
                .transpose_b(tb);
            check_gradient_launches(&g, &mix, true, 2, 910);
        }
        // No multiple of 4 in either range divides 4099: one launch, as before.
        check_gradient_launches(&g, &Matmul::new(6, 4099, 7).batched(2), true, 1, 920);
    }
}

#[test]
fn model_sized_product_matches_reference() {
    // One window of the 1×1 residual convolution: [14·100, 64] × [64, 64], plus dW.
    let g = gpu();
    for mm in on_every_kernel(&g, [Matmul::new(1400, 64, 64)]) {
        let x = inputs(&mm, 400);
        let (a, b, dc) = (
            upload(&g, "x", &x.a),
            upload(&g, "w", &x.b),
            upload(&g, "dy", &x.dc),
        );
        let c = g.zeros("y", &[mm.c_len()], DType::F32).unwrap();
        let db = g.zeros("dw", &[mm.b_len()], DType::F32).unwrap();
        g.run(&[
            mm.forward(&g, &a, &b, &c, Accumulate::Overwrite).unwrap(),
            mm.backward_b(&g, &a, &dc, &db, Accumulate::Overwrite)
                .unwrap(),
        ])
        .unwrap();
        compare_tensor(&g, "y", &c, &cpu::forward(&mm, &x.a, &x.b), gpu_tol(64)).unwrap();
        compare_tensor(
            &g,
            "dw",
            &db,
            &cpu::backward(&mm, &x.a, &x.b, &x.dc).1,
            gpu_tol(1400),
        )
        .unwrap();
    }
}

#[test]
fn aligned_operands_take_vector_loads_and_single_rows_the_row_kernel() {
    let vec = |p: (&'static str, Loads)| (p.0, p.1.a_vec, p.1.b_vec);
    for (ta, tb) in [(false, false), (true, false), (false, true), (true, true)] {
        let mm = Matmul::new(12, 20, 16)
            .batched(2)
            .share_b(true)
            .transpose_a(ta)
            .transpose_b(tb);
        assert_eq!(plan(&mm).map(vec), [("matmul", true, true); 3], "{mm:?}");
    }
    // Row count 13 is fine when A is contiguous along k (forward), not for dA's layout.
    assert_eq!(
        vec(plan(&Matmul::new(13, 8, 12))[0]),
        ("matmul", true, true)
    );
    assert_eq!(
        plan(&Matmul::new(5, 7, 3)).map(vec),
        [("matmul", false, false); 3]
    );
    // A ragged K no longer rules out vector loads of an aligned operand.
    assert_eq!(
        vec(plan(&Matmul::new(12, 8, 14))[0]),
        ("matmul", false, true)
    );
    // S'·X_t: S' [14, 14] is scalar, X_t [14, C·T] vector along n.
    let sx = Matmul::new(14, 6400, 14).batched(64);
    assert_eq!(vec(plan(&sx)[0]), ("matmul", false, true));
    // xw1 = X_t · W1 has one output column: the row kernel on the transposed views,
    // reading X_t along T.
    let xw1 = plan(&Matmul::new(57344, 1, 100))[0];
    assert_eq!(xw1.0, "matmul_row");
    assert!(xw1.1.b_vec && !xw1.1.b_along_n, "{xw1:?}");
    assert_eq!(
        plan(&Matmul::new(1, 6400, 14).batched(64).share_a(true))[0].0,
        "matmul_row"
    );
}

#[test]
fn wrong_lengths_name_the_tensor() {
    let g = gpu();
    let mm = Matmul::new(4, 4, 4);
    let a = g.zeros("activations", &[15], DType::F32).unwrap();
    let b = g.zeros("weights", &[16], DType::F32).unwrap();
    let c = g.zeros("out", &[16], DType::F32).unwrap();
    let err = mm
        .forward(&g, &a, &b, &c, Accumulate::Overwrite)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("tensor activations") && err.contains("16 elements"),
        "{err}"
    );
}

/// The temporal attention's use: X_t = X·(E' + I) written fresh, and dX accumulated with
/// dX_t·(E' + I)ᵀ onto an existing gradient, with the model's n = 100 (flat grid, vector
/// stores and loads) and a ragged n = 7 (scalar path).
#[test]
fn identity_term_accumulates_onto_existing_gradient() {
    let g = gpu();
    let shapes = [
        Matmul::new(24, 100, 100).batched(2),
        Matmul::new(10, 7, 7).batched(3),
    ];
    let shapes = shapes.map(|mm| mm.plus_identity(true));
    for (i, mm) in on_every_kernel(&g, shapes).into_iter().enumerate() {
        let x = inputs(&mm, 400 + i as u64);
        let (a, b, dc) = (
            upload(&g, "a", &x.a),
            upload(&g, "b", &x.b),
            upload(&g, "dc", &x.dc),
        );
        let da0: Vec<f64> = (0..mm.a_len()).map(|i| (i % 7) as f64 - 3.0).collect();
        let da = upload(&g, "da", &da0);
        let c = g.zeros("c", &[mm.c_len()], DType::F32).unwrap();
        g.run(&[
            mm.forward(&g, &a, &b, &c, Accumulate::Overwrite).unwrap(),
            mm.backward_a(&g, &b, &dc, &da, Accumulate::Add).unwrap(),
        ])
        .unwrap();
        // The identity's term by hand: C = A·B + A, dA = dC·Bᵀ + dC.
        let plain = Matmul {
            plus_identity: false,
            ..mm
        };
        let c_ref: Vec<f64> = cpu::forward(&plain, &x.a, &x.b)
            .iter()
            .zip(&x.a)
            .map(|(p, q)| p + q)
            .collect();
        let (da_plain, _) = cpu::backward(&plain, &x.a, &x.b, &x.dc);
        let da_ref: Vec<f64> = (0..mm.a_len())
            .map(|i| da_plain[i] + x.dc[i] + da0[i])
            .collect();
        compare_tensor(&g, &format!("{mm:?} C"), &c, &c_ref, gpu_tol(mm.k)).unwrap();
        compare_tensor(&g, &format!("{mm:?} dA"), &da, &da_ref, gpu_tol(mm.n)).unwrap();
    }
}

#[test]
fn identity_term_needs_a_square_operand() {
    let g = gpu();
    let mm = Matmul::new(4, 6, 5).plus_identity(true);
    let a = g.zeros("x", &[20], DType::F32).unwrap();
    let b = g.zeros("e", &[30], DType::F32).unwrap();
    let c = g.zeros("x_t", &[24], DType::F32).unwrap();
    let err = mm
        .forward(&g, &a, &b, &c, Accumulate::Overwrite)
        .unwrap_err()
        .to_string();
    assert!(err.contains("x_t") && err.contains("square"), "{err}");
    let shared = Matmul::new(4, 5, 5).share_a(true).plus_identity(true);
    let (e, dc) = (
        g.zeros("e", &[25], DType::F32).unwrap(),
        g.zeros("dc", &[20], DType::F32).unwrap(),
    );
    let dx = g.zeros("dx", &[20], DType::F32).unwrap();
    let err = shared
        .backward_a(&g, &e, &dc, &dx, Accumulate::Overwrite)
        .unwrap_err()
        .to_string();
    assert!(err.contains("unshared"), "{err}");
}
