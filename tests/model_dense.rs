//! The dense baselines (`model::dense`, docs/model.md "Baselines"): the f64 reference's
//! hand-written backward against central differences in f64 for every parameter tensor
//! and x; the GPU network's forward, loss, parameter gradients and input gradient against
//! the reference; which inputs each model reads; and a clear error when the graph lacks
//! a joint input.

use iastgcn::graph::Graph;
use iastgcn::model::dense::reference as dense;
use iastgcn::model::dense::Architecture;
use iastgcn::model::reference::{loss, Loss};
use iastgcn::model::{param_specs, ModelConfig, Network, Parameters, Variant};
use iastgcn::testing::{compare, gpu, rng, to_f32, uniform, Tolerance};

const BATCH: usize = 3;
const LOSS: Loss = Loss {
    attitude_penalty: 1.7,
    weight_decay: 3e-3,
};
const H: f64 = 1e-6;

/// The 14-node graph, F = 3, T = 5, H = 6.
fn config(variant: Variant) -> ModelConfig {
    ModelConfig {
        variant,
        window: 5,
        hidden: 6,
        ..ModelConfig::default()
    }
}

struct Case {
    config: ModelConfig,
    inputs: Vec<usize>,
    params: Parameters,
    x: Vec<f64>,
    y: Vec<f64>,
}

/// He-initialised weights, biases moved off zero, all rounded to f32 (so that the GPU
/// sees the same values).
fn case(variant: Variant, seed: u64) -> Case {
    let config = config(variant);
    let arch = Architecture::of(&config).expect("a dense baseline");
    let inputs = arch
        .input_indices(&Graph::default_asset(), config.features)
        .unwrap();
    let mut params = Parameters::init(&config, seed);
    let mut r = rng(seed + 1);
    for (s, v) in params.specs.iter().zip(params.values.iter_mut()) {
        if s.name.ends_with(".bias") {
            *v = to_f32(&uniform(&mut r, v.len(), -0.3, 0.3));
        }
    }
    let round = |v: Vec<f64>| -> Vec<f64> { to_f32(&v).iter().map(|&x| x as f64).collect() };
    let x = round(uniform(&mut r, BATCH * 14 * 3 * 5, -1.5, 1.5));
    let y = round(uniform(&mut r, BATCH * 6, -1.0, 1.0));
    Case {
        config,
        inputs,
        params,
        x,
        y,
    }
}

fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

impl Case {
    fn params64(&self) -> Vec<Vec<f64>> {
        self.params.values.iter().map(|v| f64s(v)).collect()
    }

    /// The loss and the ReLU pattern at `params`, `x`.
    fn eval(&self, params: &[Vec<f64>], x: &[f64]) -> (f64, Vec<bool>) {
        let specs = &self.params.specs;
        let tape = dense::forward(&self.config, &self.inputs, specs, params, x, BATCH);
        let l = loss(
            &self.config,
            specs,
            params,
            &tape.output,
            &self.y,
            BATCH,
            &LOSS,
        );
        (l, tape.relu_pattern())
    }
}

#[test]
fn reference_backward_matches_finite_differences() {
    for (vi, variant) in Variant::DENSE.into_iter().enumerate() {
        let c = case(variant, 30 + vi as u64);
        let params = c.params64();
        let specs = &c.params.specs;
        let tape = dense::forward(&c.config, &c.inputs, specs, &params, &c.x, BATCH);
        let (grads, dx) = dense::backward(
            &c.config, &c.inputs, specs, &params, &tape, &c.y, BATCH, &LOSS,
        );
        let pattern = tape.relu_pattern();
        let tol = Tolerance::new(1e-7, 1e-5);
        let mut kinks = 0;
        let mut checked = 0;
        for (t, spec) in specs.iter().enumerate() {
            let (mut got, mut want) = (Vec::new(), Vec::new());
            for i in 0..spec.numel() {
                let mut p = params.clone();
                p[t][i] += H;
                let (up, pu) = c.eval(&p, &c.x);
                p[t][i] -= 2.0 * H;
                let (down, pd) = c.eval(&p, &c.x);
                if pu != pattern || pd != pattern {
                    kinks += 1;
                    continue;
                }
                got.push(grads[t][i]);
                want.push((up - down) / (2.0 * H));
            }
            checked += got.len();
            compare(&format!("{variant} d{}", spec.name), &got, &want, tol).unwrap();
        }
        // x: every element (most have a zero gradient: only the last step's selected
        // features are read).
        let (mut got, mut want) = (Vec::new(), Vec::new());
        for i in 0..c.x.len() {
            let mut x = c.x.clone();
            x[i] += H;
            let (up, pu) = c.eval(&params, &x);
            x[i] -= 2.0 * H;
            let (down, pd) = c.eval(&params, &x);
            if pu != pattern || pd != pattern {
                kinks += 1;
                continue;
            }
            got.push(dx[i]);
            want.push((up - down) / (2.0 * H));
        }
        compare(&format!("{variant} dx"), &got, &want, tol).unwrap();
        assert!(
            kinks * 20 < checked,
            "{variant}: {kinks} of {checked} differences straddle a ReLU kink"
        );
        let nonzero = dx.iter().filter(|v| **v != 0.0).count();
        assert_eq!(
            nonzero,
            BATCH * c.inputs.len(),
            "{variant}: x is read at the last step of the selected features only"
        );
    }
}

#[test]
fn inputs_are_the_last_step_of_every_node_or_of_the_joints() {
    let graph = Graph::default_asset();
    let mlp = Architecture::of(&config(Variant::Mlp)).unwrap();
    assert_eq!(
        mlp.input_indices(&graph, 3).unwrap(),
        (0..42).collect::<Vec<_>>()
    );
    // Q1–Q5 are nodes 6–10 of the default graph; the offline models read their r feature.
    for v in [Variant::BklsAnn, Variant::AnnBfpa, Variant::Erc] {
        let a = Architecture::of(&config(v)).unwrap();
        assert_eq!(
            a.input_indices(&graph, 3).unwrap(),
            vec![18, 21, 24, 27, 30]
        );
    }
    for v in Variant::IASTGCN {
        assert!(Architecture::of(&config(v)).is_none());
    }
    // Parameter names: dense.i / stem / res.r.fc* layers, the head last.
    let names: Vec<String> = param_specs(&config(Variant::Erc))
        .into_iter()
        .map(|s| format!("{} {:?}", s.name, s.shape))
        .collect();
    assert_eq!(
        names,
        [
            "stem.weight [6, 5]",
            "stem.bias [6]",
            "res.0.fc1.weight [6, 6]",
            "res.0.fc1.bias [6]",
            "res.0.fc2.weight [6, 6]",
            "res.0.fc2.bias [6]",
            "res.1.fc1.weight [6, 6]",
            "res.1.fc1.bias [6]",
            "res.1.fc2.weight [6, 6]",
            "res.1.fc2.bias [6]",
            "head.weight [6, 6]",
            "head.bias [6]",
        ]
    );
}

#[test]
fn gpu_matches_reference() {
    let g = gpu();
    let graph = Graph::default_asset();
    const PENALTY: f64 = 1.7;
    for (vi, variant) in Variant::DENSE.into_iter().enumerate() {
        let c = case(variant, 50 + vi as u64);
        let params = c.params64();
        let specs = &c.params.specs;
        let net = Network::new(&g, &c.config, &graph, BATCH, 9).unwrap();
        assert!(net.is_dense() && net.blocks() == 0);
        net.load_parameters(&g, &c.params).unwrap();
        net.set_attitude_penalty(&g, PENALTY).unwrap();
        net.gradients(&g, &to_f32(&c.x), &to_f32(&c.y), 3).unwrap();

        let tape = dense::forward(&c.config, &c.inputs, specs, &params, &c.x, BATCH);
        // The GPU loss has no weight decay (the optimiser applies it).
        let no_decay = Loss {
            attitude_penalty: PENALTY,
            weight_decay: 0.0,
        };
        let (grads, dx) = dense::backward(
            &c.config, &c.inputs, specs, &params, &tape, &c.y, BATCH, &no_decay,
        );
        let scaled = |v: &[f64], rel: f64| {
            Tolerance::new(rel * v.iter().fold(1e-30f64, |m, x| m.max(x.abs())), rel)
        };
        let out = f64s(&g.read_f32(&net.output).unwrap()[..BATCH * 6]);
        compare(
            &format!("{variant} y_hat"),
            &out,
            &tape.output,
            scaled(&tape.output, 1e-5),
        )
        .unwrap();
        let want = loss(
            &c.config,
            specs,
            &params,
            &tape.output,
            &c.y,
            BATCH,
            &no_decay,
        );
        let got = g.read_f32(&net.loss).unwrap()[0] as f64;
        compare(
            &format!("{variant} loss"),
            &[got],
            &[want],
            Tolerance::new(0.0, 1e-5),
        )
        .unwrap();
        let gpu_grads = net.read_gradients(&g).unwrap();
        for ((spec, got), want) in specs.iter().zip(&gpu_grads).zip(&grads) {
            compare(
                &format!("{variant} d{}", spec.name),
                &f64s(got),
                want,
                scaled(want, 1e-4),
            )
            .unwrap();
        }
        let gdx = f64s(&g.read_f32(&net.input_grad).unwrap()[..dx.len()]);
        compare(&format!("{variant} dx"), &gdx, &dx, scaled(&dx, 1e-4)).unwrap();
        // The inference forward gives the same ŷ.
        let y = net.predict(&g, &to_f32(&c.x)).unwrap();
        compare(
            &format!("{variant} inference"),
            &f64s(&y),
            &tape.output,
            scaled(&tape.output, 1e-5),
        )
        .unwrap();
    }
}

#[test]
fn offline_models_need_the_joint_inputs_in_the_graph() {
    let g = gpu();
    let graph = Graph::parse(
        "nodes = [\"A\", \"B\", \"Q1\"]\nedges = [[\"A\", \"B\"]]\n",
        "three.toml",
    )
    .unwrap();
    let c = ModelConfig {
        nodes: 3,
        ..config(Variant::Erc)
    };
    let e = Network::for_inference(&g, &c, &graph, 2)
        .err()
        .expect("no Q2");
    assert!(e.to_string().contains("no node named Q2"), "{e}");
    // The instantaneous MLP reads whatever nodes there are.
    let mlp = ModelConfig {
        nodes: 3,
        ..config(Variant::Mlp)
    };
    Network::for_inference(&g, &mlp, &graph, 2).unwrap();
}

#[test]
fn offline_models_read_the_joint_inputs_the_config_names() {
    // A serial arm's graph: its joints, then a sensor channel. The offline models read the
    // joints named in `joint_inputs`, in that order, whatever the graph calls them.
    let graph = Graph::parse(
        "nodes = [\"shoulder\", \"elbow\", \"wrist\", \"temp_c\"]\nedges = [[\"shoulder\", \"elbow\"]]\n",
        "arm.toml",
    )
    .unwrap();
    let names = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    let c = ModelConfig {
        nodes: 4,
        joint_inputs: names(&["wrist", "shoulder", "elbow"]),
        ..config(Variant::BklsAnn)
    };
    c.validate().unwrap();
    let arch = Architecture::of(&c).unwrap();
    assert_eq!(arch.input_indices(&graph, 3).unwrap(), vec![6, 0, 3]);
    assert_eq!(param_specs(&c)[0].shape, vec![6, 3]);
    let g = gpu();
    Network::for_inference(&g, &c, &graph, 2).unwrap();
    // The error names the field and the missing node.
    let missing = ModelConfig {
        joint_inputs: names(&["shoulder", "ankle"]),
        ..c.clone()
    };
    let e = Network::for_inference(&g, &missing, &graph, 2)
        .err()
        .expect("no ankle");
    assert!(
        e.to_string().contains("model.joint_inputs") && e.to_string().contains("ankle"),
        "{e}"
    );
    // Empty and repeated lists are refused for the offline models only.
    let empty = ModelConfig {
        joint_inputs: vec![],
        ..c.clone()
    };
    assert!(empty
        .validate()
        .unwrap_err()
        .contains("joint_inputs is empty"));
    let twice = ModelConfig {
        joint_inputs: names(&["elbow", "wrist", "elbow"]),
        ..c.clone()
    };
    assert_eq!(
        twice.validate().unwrap_err(),
        "model config: joint_inputs names \"elbow\" twice (entries 1 and 3)"
    );
    let mlp = ModelConfig {
        variant: Variant::Mlp,
        ..empty
    };
    mlp.validate().unwrap();
    // Checkpoints written before the field existed read as the hybrid's Q1–Q5.
    let old: ModelConfig = serde_json::from_str(r#"{"variant": "erc", "nodes": 14}"#).unwrap();
    assert_eq!(old.joint_inputs, ["Q1", "Q2", "Q3", "Q4", "Q5"]);
}
