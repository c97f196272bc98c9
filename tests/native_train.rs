//! Native CPU training (`model::NativeTraining`) against the f64 reference and the WGSL
//! training step: the loss and every parameter gradient with dropout in all four IASTGCN
//! variants and ST-GAT at a small shape, the dense and recurrent baselines and ConvLSTM, the ensemble loss of refinement, a deeper shape with
//! dilations beyond the window, the threads' split, the same bits on fewer threads than
//! shares, the Adam update, and refusals.
//! (The reference's own backward is checked against finite differences in
//! tests/model_reference.rs.)

mod common;

use common::parameters;
use iastgcn::graph::Graph;
use iastgcn::model::native::cores::{with_cores, Cores};
use iastgcn::model::reference::{self, DropoutStep, Loss};
use iastgcn::model::{
    graph_basis, ModelConfig, NativeAdam, NativeForward, NativeStepShape, NativeTraining, Network,
    Parameters, Variant,
};
use iastgcn::ops::adam::{cpu as adam_cpu, hyper_values, Adam};
use iastgcn::testing::{compare, gpu, rng, to_f32, uniform, Tolerance};

const SEED: u32 = 77;
const PENALTY: f64 = 1.7;
const STEP: u32 = 5;

fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

/// Tolerance `rel` of the tensor's largest element (f32 sums lose absolute precision).
fn scaled(expected: &[f64], rel: f64) -> Tolerance {
    let scale = expected.iter().fold(0f64, |m, v| m.max(v.abs()));
    Tolerance::new(rel * scale.max(1e-30), rel)
}

fn adam() -> NativeAdam {
    NativeAdam {
        beta1: 0.9,
        beta2: 0.999,
        eps: 1e-8,
        weight_decay: 1e-4,
    }
}

fn shape(batch: usize, group: usize, threads: usize) -> NativeStepShape {
    NativeStepShape {
        batch,
        group,
        seed: SEED,
        penalty: PENALTY,
        threads,
    }
}

/// A batch of random windows and labels for `config`.
fn batch(config: &ModelConfig, b: usize, seed: u64) -> (Vec<f32>, Vec<f32>) {
    let mut r = rng(seed);
    let len = config.nodes * config.features * config.window;
    let x = to_f32(&uniform(&mut r, b * len, -1.0, 1.0));
    let y = to_f32(&uniform(&mut r, b * config.outputs, -1.0, 1.0));
    (x, y)
}

/// Native loss and gradients of one step.
fn native(
    config: &ModelConfig,
    p: &Parameters,
    s: NativeStepShape,
    x: &[f32],
    y: &[f32],
) -> (f64, Vec<Vec<f32>>) {
    let mut t = NativeTraining::new(config, &Graph::default_asset(), s, adam()).unwrap();
    t.load_parameters(p).unwrap();
    let loss = t.gradients(x, y, STEP).unwrap();
    (loss, t.last_gradients().to_vec())
}

/// Every gradient tensor against `expected`, at `rel` of its largest element.
fn compare_grads(name: &str, p: &Parameters, got: &[Vec<f32>], expected: &[Vec<f64>], rel: f64) {
    let mut worst = (0.0, String::new());
    for ((spec, g), e) in p.specs.iter().zip(got).zip(expected) {
        let w = compare(
            &format!("{name} d{}", spec.name),
            &f64s(g),
            e,
            scaled(e, rel),
        )
        .unwrap();
        if w.ratio > worst.0 {
            worst = (w.ratio, spec.name.clone());
        }
    }
    println!(
        "{name}: worst gradient {} at {:.3} of tolerance",
        worst.1, worst.0
    );
}

/// eq. 39's data term with this file's attitude penalty (the update adds the decay).
const LOSS: Loss = Loss {
    attitude_penalty: PENALTY,
    weight_decay: 0.0,
};

/// The native loss (to 1e-5) and gradients (to `rel` of each tensor's scale) of one step
/// against expected ones.
fn check_step(
    name: &str,
    p: &Parameters,
    (loss, grads): (f64, &[Vec<f32>]),
    (expected_loss, expected): (f64, &[Vec<f64>]),
    rel: f64,
) {
    compare(
        &format!("{name} loss"),
        &[loss],
        &[expected_loss],
        Tolerance::new(0.0, 1e-5),
    )
    .unwrap();
    compare_grads(name, p, grads, expected, rel);
}

#[test]
fn gradients_match_reference_in_every_variant() {
    let graph = Graph::default_asset();
    // B = 3 over 2 threads: an uneven split.
    let b = 3;
    let st_blocks = Variant::IASTGCN.into_iter().chain([Variant::StGat]);
    for (vi, variant) in st_blocks.enumerate() {
        let config = ModelConfig::gradient_check(variant);
        let p = parameters(&config, 10 + vi as u64);
        let (x, y) = batch(&config, b, 100 + vi as u64);
        let (loss, grads) = native(&config, &p, shape(b, 1, 2), &x, &y);

        let basis = graph_basis(&graph, &config);
        let params: Vec<Vec<f64>> = p.values.iter().map(|v| f64s(v)).collect();
        let dropout = Some(DropoutStep {
            seed: SEED,
            step: STEP,
        });
        let tape = reference::forward(&config, &basis, &p.specs, &params, &f64s(&x), b, dropout);
        let y64 = f64s(&y);
        let (expected, _) =
            reference::backward(&config, &basis, &p.specs, &params, &tape, &y64, b, &LOSS);
        let expected_loss =
            reference::loss(&config, &p.specs, &params, &tape.output, &y64, b, &LOSS);
        let name = variant.to_string();
        check_step(&name, &p, (loss, &grads), (expected_loss, &expected), 1e-4);
    }
}

#[test]
fn dense_baselines_match_the_reference_and_the_device() {
    use iastgcn::model::dense::Architecture;
    let graph = Graph::default_asset();
    // B = 3 over 2 threads: an uneven split.
    let b = 3;
    for (vi, variant) in Variant::DENSE.into_iter().enumerate() {
        let config = ModelConfig {
            variant,
            window: 5,
            hidden: 6,
            ..ModelConfig::default()
        };
        let p = parameters(&config, 40 + vi as u64);
        let (x, y) = batch(&config, b, 140 + vi as u64);
        let (loss, grads) = native(&config, &p, shape(b, 1, 2), &x, &y);
        let inputs = Architecture::of(&config)
            .unwrap()
            .input_indices(&graph, config.features)
            .unwrap();
        let params: Vec<Vec<f64>> = p.values.iter().map(|v| f64s(v)).collect();
        let tape = iastgcn::model::dense::reference::forward(
            &config,
            &inputs,
            &p.specs,
            &params,
            &f64s(&x),
            b,
        );
        let y64 = f64s(&y);
        let (expected, _) = iastgcn::model::dense::reference::backward(
            &config, &inputs, &p.specs, &params, &tape, &y64, b, &LOSS,
        );
        let expected_loss =
            reference::loss(&config, &p.specs, &params, &tape.output, &y64, b, &LOSS);
        let name = variant.to_string();
        check_step(&name, &p, (loss, &grads), (expected_loss, &expected), 1e-4);
        // And the WGSL step's.
        let (dl, dg) = device(&config, &p, b, 1, &x, &y);
        let name = format!("{variant} vs device");
        check_step(&name, &p, (loss, &grads), (dl, &dg), 1e-4);
    }
}

#[test]
fn recurrent_baselines_match_the_reference_and_the_device() {
    use iastgcn::model::recurrent::supports;
    let graph = Graph::default_asset();
    // B = 3 over 2 threads: an uneven split.
    let b = 3;
    for (vi, variant) in Variant::RECURRENT.into_iter().enumerate() {
        let config = ModelConfig {
            variant,
            window: 5,
            hidden: 6,
            ..ModelConfig::default()
        };
        let p = parameters(&config, 60 + vi as u64);
        let params: Vec<Vec<f64>> = p.values.iter().map(|v| f64s(v)).collect();
        let s = supports(&graph, &config);
        // The native step of `b` windows over `threads` against the f64 reference.
        let against_reference = |name: &str, b: usize, threads: usize, seed: u64| {
            let (x, y) = batch(&config, b, seed);
            let (loss, grads) = native(&config, &p, shape(b, 1, threads), &x, &y);
            let tape = iastgcn::model::recurrent::reference::forward(
                &config,
                &s,
                &p.specs,
                &params,
                &f64s(&x),
                b,
            );
            let y64 = f64s(&y);
            let (expected, _) = iastgcn::model::recurrent::reference::backward(
                &config, &s, &p.specs, &params, &tape, &y64, b, &LOSS,
            );
            let expected_loss =
                reference::loss(&config, &p.specs, &params, &tape.output, &y64, b, &LOSS);
            check_step(name, &p, (loss, &grads), (expected_loss, &expected), 1e-4);
            (x, y, loss, grads)
        };
        let (x, y, loss, grads) = against_reference(&variant.to_string(), b, 2, 160 + vi as u64);
        // And the WGSL step's, plain and over ensembles of 3 (refinement's loss).
        let (dl, dg) = device(&config, &p, b, 1, &x, &y);
        check_step(
            &format!("{variant} vs device"),
            &p,
            (loss, &grads),
            (dl, &dg),
            1e-4,
        );
        let (x6, y6) = batch(&config, 6, 170 + vi as u64);
        let (loss, grads) = native(&config, &p, shape(6, 3, 2), &x6, &y6);
        let (dl, dg) = device(&config, &p, 6, 3, &x6, &y6);
        let name = format!("{variant} ensembles vs device");
        check_step(&name, &p, (loss, &grads), (dl, &dg), 2e-4);
        // More windows than the native step runs together (32): two runs on one thread.
        let name = format!("{variant} over two runs of windows");
        against_reference(&name, 35, 1, 180 + vi as u64);
    }
}

#[test]
fn conv_lstm_matches_the_reference_and_the_device() {
    // B = 3 over 2 threads: an uneven split.
    let b = 3;
    let config = ModelConfig {
        variant: Variant::ConvLstm,
        window: 5,
        channels: 3,
        ..ModelConfig::default()
    };
    let p = parameters(&config, 65);
    let (x, y) = batch(&config, b, 165);
    let (loss, grads) = native(&config, &p, shape(b, 1, 2), &x, &y);
    let params: Vec<Vec<f64>> = p.values.iter().map(|v| f64s(v)).collect();
    let tape =
        iastgcn::model::conv_lstm::reference::forward(&config, &p.specs, &params, &f64s(&x), b);
    let y64 = f64s(&y);
    let (expected, _) = iastgcn::model::conv_lstm::reference::backward(
        &config, &p.specs, &params, &tape, &y64, b, &LOSS,
    );
    let expected_loss = reference::loss(&config, &p.specs, &params, &tape.output, &y64, b, &LOSS);
    check_step(
        "convlstm",
        &p,
        (loss, &grads),
        (expected_loss, &expected),
        1e-4,
    );
    let (dl, dg) = device(&config, &p, b, 1, &x, &y);
    check_step("convlstm vs device", &p, (loss, &grads), (dl, &dg), 1e-4);
    let (x6, y6) = batch(&config, 6, 175);
    let (loss, grads) = native(&config, &p, shape(6, 3, 2), &x6, &y6);
    let (dl, dg) = device(&config, &p, 6, 3, &x6, &y6);
    check_step(
        "convlstm ensembles vs device",
        &p,
        (loss, &grads),
        (dl, &dg),
        2e-4,
    );
}

/// The WGSL training step's loss and gradients (`group` = 1: `Network::new`).
fn device(
    config: &ModelConfig,
    p: &Parameters,
    b: usize,
    group: usize,
    x: &[f32],
    y: &[f32],
) -> (f64, Vec<Vec<f64>>) {
    let g = gpu();
    let graph = Graph::default_asset();
    let net = if group == 1 {
        Network::new(&g, config, &graph, b, SEED).unwrap()
    } else {
        Network::for_ensembles(&g, config, &graph, b, group, SEED).unwrap()
    };
    net.load_parameters(&g, p).unwrap();
    net.set_attitude_penalty(&g, PENALTY).unwrap();
    net.gradients(&g, x, y, STEP).unwrap();
    let loss = g.read_f32(&net.loss).unwrap()[0] as f64;
    let grads = net.read_gradients(&g).unwrap();
    (loss, grads.iter().map(|v| f64s(v)).collect())
}

#[test]
fn ensemble_loss_matches_the_device() {
    // Refinement's loss over ensembles of m = 3 consecutive windows, 2 ensembles.
    let config = ModelConfig::gradient_check(Variant::Iastgcn);
    let p = parameters(&config, 21);
    let (x, y) = batch(&config, 6, 22);
    let (loss, grads) = native(&config, &p, shape(6, 3, 2), &x, &y);
    let (dl, dg) = device(&config, &p, 6, 3, &x, &y);
    compare("ensemble loss", &[loss], &[dl], Tolerance::new(0.0, 1e-5)).unwrap();
    compare_grads("ensemble", &p, &grads, &dg, 2e-4);
}

#[test]
fn deeper_shape_matches_the_device() {
    // Four blocks of dilation 1, 2, 4, 8 on T = 12: the last two reach past the window.
    for variant in [Variant::Iastgcn, Variant::NoAttention, Variant::StGat] {
        let config = ModelConfig {
            variant,
            window: 12,
            channels: 8,
            blocks: 4,
            ..ModelConfig::default()
        };
        let p = parameters(&config, 31);
        let (x, y) = batch(&config, 4, 32);
        let (loss, grads) = native(&config, &p, shape(4, 1, 2), &x, &y);
        let (dl, dg) = device(&config, &p, 4, 1, &x, &y);
        compare(
            &format!("{variant} deep loss"),
            &[loss],
            &[dl],
            Tolerance::new(0.0, 1e-5),
        )
        .unwrap();
        compare_grads(&format!("{variant} deep"), &p, &grads, &dg, 2e-4);
    }
}

#[test]
fn threads_change_only_the_summation_order() {
    let config = ModelConfig::gradient_check(Variant::Iastgcn);
    let p = parameters(&config, 41);
    let (x, y) = batch(&config, 8, 42);
    let (l1, g1) = native(&config, &p, shape(8, 1, 1), &x, &y);
    let (l2, g2) = native(&config, &p, shape(8, 1, 2), &x, &y);
    let (l2b, g2b) = native(&config, &p, shape(8, 1, 2), &x, &y);
    // The same thread count gives the same bits.
    assert_eq!(l2.to_bits(), l2b.to_bits());
    assert_eq!(g2, g2b);
    compare(
        "loss 1 vs 2 threads",
        &[l1],
        &[l2],
        Tolerance::new(0.0, 1e-6),
    )
    .unwrap();
    let g1: Vec<Vec<f64>> = g1.iter().map(|v| f64s(v)).collect();
    compare_grads("1 vs 2 threads", &p, &g2, &g1, 1e-5);
}

/// A training step's shares run on as many threads as a [`Cores`] budget allows (the
/// demo trains two models side by side): fewer threads, the same bits.
#[test]
fn shares_give_the_same_bits_on_fewer_threads() {
    for variant in [Variant::Iastgcn, Variant::Mlp] {
        let config = ModelConfig::gradient_check(variant);
        let p = parameters(&config, 43);
        let (x, y) = batch(&config, 9, 44);
        // Three shares, two steps with their updates: the weights after them.
        let train = || {
            let mut t =
                NativeTraining::new(&config, &Graph::default_asset(), shape(9, 1, 3), adam())
                    .unwrap();
            t.load_parameters(&p).unwrap();
            let losses = [
                t.step(&x, &y, 0, 1e-2).unwrap().to_bits(),
                t.step(&x, &y, 1, 1e-2).unwrap().to_bits(),
            ];
            (losses, t.parameters().values)
        };
        let alone = train();
        for spare in [0, 1] {
            // `spare` cores beside this thread's own: 1 and 2 threads for 3 shares.
            let cores = Cores::new(spare);
            let shared = with_cores(&cores, train);
            assert_eq!(shared, alone, "{variant:?} with {spare} spare core(s)");
            assert_eq!(cores.spare(), spare, "every borrowed core given back");
        }
    }
}

#[test]
fn adam_update_is_the_device_formula() {
    let config = ModelConfig::gradient_check(Variant::NoAttention);
    let p = parameters(&config, 51);
    let (x, y) = batch(&config, 2, 52);
    let mut t =
        NativeTraining::new(&config, &Graph::default_asset(), shape(2, 1, 1), adam()).unwrap();
    t.load_parameters(&p).unwrap();
    // Moments from a first step, then a second step checked against the f64 reference.
    t.step(&x, &y, 0, 1e-3).unwrap();
    let before = t.parameters();
    let (m0, v0) = t.moments();
    t.gradients(&x, &y, 1).unwrap();
    let grads = t.last_gradients().to_vec();
    t.update(2e-3, 2);
    let after = t.parameters();
    let (m1, _) = t.moments();
    let a = adam();
    for (i, spec) in p.specs.iter().enumerate() {
        let step = Adam {
            numel: spec.numel(),
            beta1: a.beta1,
            beta2: a.beta2,
            eps: a.eps,
            decay: if spec.decay { a.weight_decay } else { 0.0 },
        };
        let hyper = hyper_values(2e-3, a.beta1, a.beta2, 2).map(|v| v as f64);
        let mut w = f64s(&before.values[i]);
        let (mut m, mut v) = (f64s(&m0[i]), f64s(&v0[i]));
        adam_cpu::step(&step, hyper, &mut w, &f64s(&grads[i]), &mut m, &mut v);
        compare(
            &format!("{} after Adam", spec.name),
            &f64s(&after.values[i]),
            &w,
            Tolerance::new(1e-6, 1e-5),
        )
        .unwrap();
        compare(
            &format!("{} first moment", spec.name),
            &f64s(&m1[i]),
            &m,
            Tolerance::new(1e-7, 1e-5),
        )
        .unwrap();
    }
    assert_ne!(before.values, after.values, "the update moved nothing");
}

#[test]
fn refuses_what_it_cannot_train() {
    let graph = Graph::default_asset();
    let config = ModelConfig::gradient_check(Variant::Iastgcn);
    let err = NativeTraining::new(&config, &graph, shape(5, 2, 1), adam())
        .err()
        .expect("a batch that is not a multiple of the ensemble");
    assert!(
        err.to_string().contains("multiple of the ensemble size 2"),
        "{err}"
    );
    let mut t = NativeTraining::new(&config, &graph, shape(2, 1, 1), adam()).unwrap();
    let (x, y) = batch(&config, 1, 1);
    let err = t.gradients(&x, &y, 0).unwrap_err();
    assert!(err.to_string().contains("a batch of 2"), "{err}");
    let other = parameters(&ModelConfig::gradient_check(Variant::NoAttention), 1);
    let err = t.load_parameters(&other).unwrap_err();
    assert!(err.to_string().contains("tensors given"), "{err}");
    let mut wrong = parameters(&config, 1);
    wrong.values[3].pop();
    let err = t.load_parameters(&wrong).unwrap_err();
    assert!(err.to_string().contains(&wrong.specs[3].name), "{err}");
}

/// Subnormal weights are read as zero on x86-64 (the native passes run with DAZ and FTZ:
/// trained weights drift there, and x86 takes a microcode assist per subnormal
/// operation): a network whose every weight is subnormal gives the loss, the gradients
/// and the forward output of the all-zero network, bit for bit, in every family.
#[cfg(target_arch = "x86_64")]
#[test]
fn subnormal_weights_read_as_zero() {
    let tiny = f32::MIN_POSITIVE / 4.0;
    assert!(tiny.is_subnormal());
    for variant in [Variant::Iastgcn, Variant::Tgcn, Variant::Mlp] {
        let config = ModelConfig {
            hidden: 6,
            ..ModelConfig::gradient_check(variant)
        };
        let zero = parameters(&config, 1);
        let zero = Parameters {
            values: zero.values.iter().map(|v| vec![0.0; v.len()]).collect(),
            ..zero
        };
        let subnormal = Parameters {
            values: zero.values.iter().map(|v| vec![tiny; v.len()]).collect(),
            ..zero.clone()
        };
        let (x, y) = batch(&config, 2, 190);
        let (l0, g0) = native(&config, &zero, shape(2, 1, 1), &x, &y);
        let (l1, g1) = native(&config, &subnormal, shape(2, 1, 1), &x, &y);
        assert_eq!(l0.to_bits(), l1.to_bits(), "{variant}: loss");
        assert_eq!(g0, g1, "{variant}: gradients");
        let graph = Graph::default_asset();
        let len = config.nodes * config.features * config.window;
        let (mut o0, mut o1) = (vec![0f32; config.outputs], vec![0f32; config.outputs]);
        let mut f0 = NativeForward::new(&config, &graph, &zero).unwrap();
        let mut f1 = NativeForward::new(&config, &graph, &subnormal).unwrap();
        f0.forward(&x[..len], &mut o0).unwrap();
        f1.forward(&x[..len], &mut o1).unwrap();
        assert_eq!(o0, o1, "{variant}: forward");
    }
}
