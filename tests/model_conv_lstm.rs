//! The ConvLSTM baseline (`model::conv_lstm`, docs/model.md "Baselines"): the f64
//! reference's backpropagation through time against central differences in f64 for every
//! parameter tensor and x, and the GPU network's forward, loss, parameter gradients and
//! input gradient against the reference.

use iastgcn::graph::Graph;
use iastgcn::model::reference::{conv_lstm, loss, Loss};
use iastgcn::model::{param_specs, ModelConfig, Network, Parameters, Variant};
use iastgcn::testing::{compare, gpu, rng, to_f32, uniform, Tolerance};

const BATCH: usize = 2;
const LOSS: Loss = Loss {
    attitude_penalty: 1.7,
    weight_decay: 3e-3,
};
const H: f64 = 1e-6;

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
    let tol = Tolerance::new(1e-7, 1e-5);
    for (t, spec) in p.specs.iter().enumerate() {
        let want: Vec<f64> = (0..spec.numel())
            .map(|i| {
                let mut q = params.clone();
                q[t][i] += H;
                let up = eval(&q, &x);
                q[t][i] -= 2.0 * H;
                (up - eval(&q, &x)) / (2.0 * H)
            })
            .collect();
        compare(&format!("d{}", spec.name), &grads[t], &want, tol).unwrap();
        assert!(
            want.iter().any(|v| v.abs() > 1e-9),
            "{} has no effect",
            spec.name
        );
    }
    let want: Vec<f64> = (0..x.len())
        .map(|i| {
            let mut q = x.clone();
            q[i] += H;
            let up = eval(&params, &q);
            q[i] -= 2.0 * H;
            (up - eval(&params, &q)) / (2.0 * H)
        })
        .collect();
    compare("dx", &dx, &want, tol).unwrap();
    // Every step of x matters (the state carries it to the end).
    for t in 0..4 {
        assert!((0..dx.len() / 4).any(|r| dx[r * 4 + t] != 0.0), "step {t}");
    }
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
    let scaled = |v: &[f64], rel: f64| {
        Tolerance::new(rel * v.iter().fold(1e-30f64, |m, x| m.max(x.abs())), rel)
    };
    let out = f64s(&g.read_f32(&net.output).unwrap()[..BATCH * 6]);
    compare("y_hat", &out, &tape.output, scaled(&tape.output, 1e-5)).unwrap();
    let want = loss(&c, &p.specs, &params, &tape.output, &y, BATCH, &no_decay);
    let got = g.read_f32(&net.loss).unwrap()[0] as f64;
    compare("loss", &[got], &[want], Tolerance::new(0.0, 1e-5)).unwrap();
    let gpu_grads = net.read_gradients(&g).unwrap();
    for ((spec, got), want) in p.specs.iter().zip(&gpu_grads).zip(&grads) {
        compare(
            &format!("d{}", spec.name),
            &f64s(got),
            want,
            scaled(want, 1e-4),
        )
        .unwrap();
    }
    let gdx = f64s(&g.read_f32(&net.input_grad).unwrap()[..dx.len()]);
    compare("dx", &gdx, &dx, scaled(&dx, 1e-4)).unwrap();
    let yi = net.predict(&g, &to_f32(&x)).unwrap();
    compare(
        "inference",
        &f64s(&yi),
        &tape.output,
        scaled(&tape.output, 1e-5),
    )
    .unwrap();
}
