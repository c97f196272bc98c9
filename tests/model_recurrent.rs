//! The recurrent baselines T-GCN and EAT-GCN (`model::recurrent`, docs/model.md
//! "Baselines"): the f64 reference's backpropagation through time (and EAT-GCN's attention
//! over time) against central differences in f64 for every parameter tensor and x, and the
//! GPU network's forward, loss, parameter gradients and input gradient against the
//! reference.

mod common;

use iastgcn::graph::Graph;
use iastgcn::model::recurrent::reference as recurrent;
use iastgcn::model::recurrent::supports;
use iastgcn::model::reference::{loss, Loss};
use iastgcn::model::{param_specs, ModelConfig, Network, Parameters, Variant};
use iastgcn::testing::{gpu, rng, to_f32, uniform};

const BATCH: usize = 2;
const LOSS: Loss = Loss {
    attitude_penalty: 1.7,
    weight_decay: 3e-3,
};

/// The 14-node graph, F = 3, T = 4, H = 5 (and K = 3 Chebyshev supports for EAT-GCN).
fn config(variant: Variant) -> ModelConfig {
    ModelConfig {
        variant,
        window: 4,
        hidden: 5,
        ..ModelConfig::default()
    }
}

fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

/// He-initialised weights, biases moved off zero, x and y, all rounded to f32.
fn case(c: &ModelConfig, seed: u64) -> (Parameters, Vec<f64>, Vec<f64>) {
    let mut p = Parameters::init(c, seed);
    let mut r = rng(seed + 1);
    for (s, v) in p.specs.iter().zip(p.values.iter_mut()) {
        if s.name.ends_with("bias") || s.name == "attn.b" {
            *v = to_f32(&uniform(&mut r, v.len(), -0.3, 0.3));
        }
    }
    let round = |v: Vec<f64>| f64s(&to_f32(&v));
    let x = round(uniform(&mut r, BATCH * 14 * 3 * 4, -1.5, 1.5));
    let y = round(uniform(&mut r, BATCH * 6, -1.0, 1.0));
    (p, x, y)
}

fn names(variant: Variant) -> Vec<String> {
    param_specs(&config(variant))
        .into_iter()
        .map(|s| format!("{} {:?}", s.name, s.shape))
        .collect()
}

#[test]
fn parameters_are_three_gates_and_the_head() {
    assert_eq!(
        names(Variant::Tgcn),
        [
            "cell.r.wx [3, 5]",
            "cell.r.wh [5, 5]",
            "cell.r.bias [5]",
            "cell.u.wx [3, 5]",
            "cell.u.wh [5, 5]",
            "cell.u.bias [5]",
            "cell.c.wx [3, 5]",
            "cell.c.wh [5, 5]",
            "cell.c.bias [5]",
            "head.weight [6, 70]",
            "head.bias [6]",
        ]
    );
    // Â is symmetric with rows of a node and its neighbours.
    let a = supports(&Graph::default_asset(), &config(Variant::Tgcn));
    assert_eq!(a.len(), 14 * 14);
    for i in 0..14 {
        for j in 0..14 {
            assert!((a[i * 14 + j] - a[j * 14 + i]).abs() < 1e-15);
        }
        assert!(a[i * 14 + i] > 0.0);
    }
}

#[test]
fn eat_gcn_has_a_weight_per_chebyshev_term_and_the_attention() {
    let got = names(Variant::EatGcn);
    let mut want = Vec::new();
    for g in ["r", "u", "c"] {
        for (kind, rows) in [("wx", 3), ("wh", 5)] {
            for k in 0..3 {
                want.push(format!("cell.{g}.{kind}.{k} [{rows}, 5]"));
            }
        }
        want.push(format!("cell.{g}.bias [5]"));
    }
    want.extend(
        [
            "attn.W [70, 5]",
            "attn.b [5]",
            "attn.v [5]",
            "head.weight [6, 70]",
            "head.bias [6]",
        ]
        .map(String::from),
    );
    assert_eq!(got, want);
    // The supports are T_0 = I, T_1 = L̃ and T_2 = 2L̃² − I.
    let s = supports(&Graph::default_asset(), &config(Variant::EatGcn));
    assert_eq!(s.len(), 3 * 14 * 14);
    for i in 0..14 {
        for j in 0..14 {
            let l = |k: usize| s[k * 196 + i * 14 + j];
            assert_eq!(l(0), if i == j { 1.0 } else { 0.0 });
            let l2: f64 = (0..14)
                .map(|m| s[196 + i * 14 + m] * s[196 + m * 14 + j])
                .sum();
            let want = 2.0 * l2 - if i == j { 1.0 } else { 0.0 };
            assert!((l(2) - want).abs() < 1e-12, "T_2[{i},{j}]");
        }
    }
}

#[test]
fn tgcn_reference_backward_matches_finite_differences() {
    reference_backward_matches_finite_differences(Variant::Tgcn);
}

#[test]
fn eat_gcn_reference_backward_matches_finite_differences() {
    reference_backward_matches_finite_differences(Variant::EatGcn);
}

fn reference_backward_matches_finite_differences(variant: Variant) {
    let c = config(variant);
    let a = supports(&Graph::default_asset(), &c);
    let (p, x, y) = case(&c, 3);
    let params: Vec<Vec<f64>> = p.values.iter().map(|v| f64s(v)).collect();
    let eval = |params: &[Vec<f64>], x: &[f64]| {
        let tape = recurrent::forward(&c, &a, &p.specs, params, x, BATCH);
        loss(&c, &p.specs, params, &tape.output, &y, BATCH, &LOSS)
    };
    let tape = recurrent::forward(&c, &a, &p.specs, &params, &x, BATCH);
    let (grads, dx) = recurrent::backward(&c, &a, &p.specs, &params, &tape, &y, BATCH, &LOSS);
    common::check_reference_gradients(&p.specs, (&params, &x), (&grads, &dx), 4, eval);
}

#[test]
fn tgcn_gpu_matches_reference() {
    gpu_matches_reference(Variant::Tgcn);
}

#[test]
fn eat_gcn_gpu_matches_reference() {
    gpu_matches_reference(Variant::EatGcn);
}

fn gpu_matches_reference(variant: Variant) {
    let g = gpu();
    let c = config(variant);
    let a = supports(&Graph::default_asset(), &c);
    let (p, x, y) = case(&c, 7);
    const PENALTY: f64 = 1.7;
    let net = Network::new(&g, &c, &Graph::default_asset(), BATCH, 9).unwrap();
    assert_eq!(net.blocks(), 0);
    net.load_parameters(&g, &p).unwrap();
    net.set_attitude_penalty(&g, PENALTY).unwrap();
    net.gradients(&g, &to_f32(&x), &to_f32(&y), 2).unwrap();

    let params: Vec<Vec<f64>> = p.values.iter().map(|v| f64s(v)).collect();
    let tape = recurrent::forward(&c, &a, &p.specs, &params, &x, BATCH);
    let no_decay = Loss {
        attitude_penalty: PENALTY,
        weight_decay: 0.0,
    };
    let (grads, dx) = recurrent::backward(&c, &a, &p.specs, &params, &tape, &y, BATCH, &no_decay);
    let want = common::Reference {
        output: &tape.output,
        loss: loss(&c, &p.specs, &params, &tape.output, &y, BATCH, &no_decay),
        grads: &grads,
        dx: &dx,
    };
    common::compare_network(&g, &net, &x, want);
}
