//! The ConvLSTM baseline (`model::conv_lstm`, docs/model.md "Baselines"): the f64
//! reference's backpropagation through time against central differences in f64 for every
//! parameter tensor and x, and the GPU network's forward, loss, parameter gradients and
//! input gradient against the reference.

mod common;

use iastgcn::graph::Graph;
use iastgcn::model::conv_lstm::reference as conv_lstm;
use iastgcn::model::reference::{loss, Loss};
use iastgcn::model::{param_specs, ModelConfig, Network, Parameters, Variant};
use iastgcn::testing::{gpu, rng, to_f32, uniform};

const BATCH: usize = 2;
const LOSS: Loss = Loss {
    attitude_penalty: 1.7,
    weight_decay: 3e-3,
};

/// The 14-node graph's 14 × 3 grid, T = 4, C = 3 state channels, 3×3 kernels.
fn config() -> ModelConfig {
    ModelConfig {
        variant: Variant::ConvLstm,
        window: 4,
        channels: 3,
        kernel: 3,
        ..ModelConfig::default()
    }
}

fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

/// He-initialised weights, the bias moved off zero, x and y, all rounded to f32.
fn case(seed: u64) -> (Parameters, Vec<f64>, Vec<f64>) {
    let c = config();
    let mut p = Parameters::init(&c, seed);
    let mut r = rng(seed + 1);
    for (s, v) in p.specs.iter().zip(p.values.iter_mut()) {
        if s.name.ends_with("bias") {
            *v = to_f32(&uniform(&mut r, v.len(), -0.3, 0.3));
        }
    }
    let round = |v: Vec<f64>| f64s(&to_f32(&v));
    let x = round(uniform(&mut r, BATCH * 14 * 3 * 4, -1.5, 1.5));
    let y = round(uniform(&mut r, BATCH * 6, -1.0, 1.0));
    (p, x, y)
}

#[test]
fn parameters_are_the_two_convolutions_and_the_head() {
    let names: Vec<String> = param_specs(&config())
        .into_iter()
        .map(|s| format!("{} {:?}", s.name, s.shape))
        .collect();
    assert_eq!(
        names,
        [
            "cell.wx [12, 9]",
            "cell.wh [12, 27]",
            "cell.bias [12]",
            "head.weight [6, 126]",
            "head.bias [6]",
        ]
    );
    // An even kernel has no centre.
    let even = ModelConfig {
        kernel: 2,
        ..config()
    };
    assert!(even.validate().unwrap_err().contains("kernel"));
}

#[test]
fn reference_backward_matches_finite_differences() {
    let c = config();
    let (p, x, y) = case(3);
    let params: Vec<Vec<f64>> = p.values.iter().map(|v| f64s(v)).collect();
    let eval = |params: &[Vec<f64>], x: &[f64]| {
        let tape = conv_lstm::forward(&c, &p.specs, params, x, BATCH);
        loss(&c, &p.specs, params, &tape.output, &y, BATCH, &LOSS)
    };
    let tape = conv_lstm::forward(&c, &p.specs, &params, &x, BATCH);
    let (grads, dx) = conv_lstm::backward(&c, &p.specs, &params, &tape, &y, BATCH, &LOSS);
    common::check_reference_gradients(&p.specs, (&params, &x), (&grads, &dx), 4, eval);
}

#[test]
fn gpu_matches_reference() {
    let g = gpu();
    let c = config();
    let (p, x, y) = case(7);
    const PENALTY: f64 = 1.7;
    let net = Network::new(&g, &c, &Graph::default_asset(), BATCH, 9).unwrap();
    assert_eq!(net.blocks(), 0);
    net.load_parameters(&g, &p).unwrap();
    net.set_attitude_penalty(&g, PENALTY).unwrap();
    net.gradients(&g, &to_f32(&x), &to_f32(&y), 2).unwrap();

    let params: Vec<Vec<f64>> = p.values.iter().map(|v| f64s(v)).collect();
    let tape = conv_lstm::forward(&c, &p.specs, &params, &x, BATCH);
    let no_decay = Loss {
        attitude_penalty: PENALTY,
        weight_decay: 0.0,
    };
    let (grads, dx) = conv_lstm::backward(&c, &p.specs, &params, &tape, &y, BATCH, &no_decay);
    let want = common::Reference {
        output: &tape.output,
        loss: loss(&c, &p.specs, &params, &tape.output, &y, BATCH, &no_decay),
        grads: &grads,
        dx: &dx,
    };
    common::compare_network(&g, &net, &x, want);
}
