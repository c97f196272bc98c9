//! The whole network on the GPU (`model::Network`) against the f64 reference
//! (`model::reference`): training forward with dropout, loss, every parameter gradient
//! and the input gradient in all four variants at small shapes; inference forward; and
//! the forward pass at the paper's shape. (The reference's own backward is checked
//! against finite differences in tests/model_reference.rs.)

use common::parameters;
use iastgcn::gpu::{Gpu, Planning};
use iastgcn::graph::Graph;
use iastgcn::model::reference::{self, DropoutStep, Loss};
use iastgcn::model::{graph_basis, ModelConfig, Network, Pass, Timing, Variant};
use iastgcn::testing::{compare, gpu, rng, to_f32, uniform, Tolerance};

mod common;

const DROPOUT_SEED: u32 = 77;
/// A non-default attitude penalty P, set through `Network::set_attitude_penalty`.
const PENALTY: f64 = 1.7;

fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |m, x| m.max(x.abs()))
}

/// Per-tensor tolerance: relative to the tensor's largest element (f32 sums of many
/// terms lose absolute, not relative, precision on small elements).
fn scaled(expected: &[f64], rel: f64) -> Tolerance {
    Tolerance::new(rel * max_abs(expected).max(1e-30), rel)
}

#[test]
fn gradients_match_reference_in_every_variant() {
    gradients_match_reference(&gpu());
}

#[test]
fn gradients_match_reference_when_planned_for_a_gpu() {
    // The split reductions' chunks and lanes as a GPU runs them (on any device).
    gradients_match_reference(&gpu().with_planning(Planning::Gpu));
}

fn gradients_match_reference(g: &Gpu) {
    let graph = Graph::default_asset();
    let batch = 2;
    for (vi, variant) in Variant::IASTGCN
        .into_iter()
        .chain([Variant::StGat])
        .enumerate()
    {
        let config = ModelConfig::gradient_check(variant);
        let p = parameters(&config, 10 + vi as u64);
        let mut r = rng(100 + vi as u64);
        let x = to_f32(&uniform(&mut r, batch * 14 * 3 * 16, -1.0, 1.0));
        let y = to_f32(&uniform(&mut r, batch * 6, -1.0, 1.0));
        let net = Network::new(g, &config, &graph, batch, DROPOUT_SEED).unwrap();
        net.load_parameters(g, &p).unwrap();
        net.set_attitude_penalty(g, PENALTY).unwrap();
        let step = 5;
        net.gradients(g, &x, &y, step).unwrap();

        let basis = graph_basis(&graph, &config);
        let params: Vec<Vec<f64>> = p.values.iter().map(|v| f64s(v)).collect();
        let dropout = Some(DropoutStep {
            seed: DROPOUT_SEED,
            step,
        });
        let tape = reference::forward(
            &config,
            &basis,
            &p.specs,
            &params,
            &f64s(&x),
            batch,
            dropout,
        );
        // The GPU loss has no weight decay (the optimiser applies it).
        let loss = Loss {
            attitude_penalty: PENALTY,
            weight_decay: 0.0,
        };
        let (grads, dx) = reference::backward(
            &config,
            &basis,
            &p.specs,
            &params,
            &tape,
            &f64s(&y),
            batch,
            &loss,
        );
        let expected_loss = reference::loss(
            &config,
            &p.specs,
            &params,
            &tape.output,
            &f64s(&y),
            batch,
            &loss,
        );

        let out = f64s(&g.read_f32(&net.output).unwrap()[..batch * 6]);
        compare(
            &format!("{variant} y_hat"),
            &out,
            &tape.output,
            scaled(&tape.output, 1e-5),
        )
        .unwrap();
        let l = g.read_f32(&net.loss).unwrap()[0] as f64;
        compare(
            &format!("{variant} loss"),
            &[l],
            &[expected_loss],
            Tolerance::new(0.0, 1e-5),
        )
        .unwrap();
        let got = net.read_gradients(g).unwrap();
        let mut worst = (0.0, String::new());
        for ((spec, gpu_grad), cpu_grad) in p.specs.iter().zip(&got).zip(&grads) {
            let w = compare(
                &format!("{variant} d{}", spec.name),
                &f64s(gpu_grad),
                cpu_grad,
                scaled(cpu_grad, 1e-4),
            )
            .unwrap();
            if w.ratio > worst.0 {
                worst = (w.ratio, spec.name.clone());
            }
        }
        let gdx = f64s(&g.read_f32(&net.input_grad).unwrap()[..dx.len()]);
        compare(&format!("{variant} dx"), &gdx, &dx, scaled(&dx, 1e-4)).unwrap();
        println!(
            "{variant}: worst gradient {} at {:.3} of tolerance",
            worst.1, worst.0
        );
    }
}

#[test]
fn inference_forward_matches_reference() {
    let g = gpu();
    let graph = Graph::default_asset();
    let batch = 3;
    for (vi, variant) in Variant::IASTGCN
        .into_iter()
        .chain([Variant::StGat])
        .enumerate()
    {
        let config = ModelConfig::gradient_check(variant);
        let p = parameters(&config, 20 + vi as u64);
        let mut r = rng(200 + vi as u64);
        let x = to_f32(&uniform(&mut r, batch * 14 * 3 * 16, -1.0, 1.0));
        let net = Network::new(&g, &config, &graph, batch, DROPOUT_SEED).unwrap();
        net.load_parameters(&g, &p).unwrap();
        let out = f64s(&net.predict(&g, &x).unwrap());
        let basis = graph_basis(&graph, &config);
        let params: Vec<Vec<f64>> = p.values.iter().map(|v| f64s(v)).collect();
        let tape = reference::forward(&config, &basis, &p.specs, &params, &f64s(&x), batch, None);
        compare(
            &format!("{variant} y_hat"),
            &out,
            &tape.output,
            scaled(&tape.output, 1e-5),
        )
        .unwrap();
    }
}

/// docs/model.md's paper shape (B = 64, T = 100, C = 64, L = 5): the inference forward
/// matches the f64 reference to 1e-4 of the output scale.
#[test]
fn paper_shape_forward_matches_reference() {
    let g = gpu();
    let graph = Graph::default_asset();
    let config = ModelConfig::default();
    let batch = 64;
    let p = parameters(&config, 3);
    let mut r = rng(300);
    let x = to_f32(&uniform(&mut r, batch * 14 * 3 * 100, -1.0, 1.0));
    let net = Network::new(&g, &config, &graph, batch, DROPOUT_SEED).unwrap();
    net.load_parameters(&g, &p).unwrap();
    let t0 = std::time::Instant::now();
    let out = f64s(&net.predict(&g, &x).unwrap());
    let gpu_time = t0.elapsed();
    let basis = graph_basis(&graph, &config);
    let params: Vec<Vec<f64>> = p.values.iter().map(|v| f64s(v)).collect();
    let t0 = std::time::Instant::now();
    let tape = reference::forward(&config, &basis, &p.specs, &params, &f64s(&x), batch, None);
    let cpu_time = t0.elapsed();
    let w = compare(
        "paper y_hat",
        &out,
        &tape.output,
        scaled(&tape.output, 1e-4),
    )
    .unwrap();
    println!("paper shape: {w}; GPU forward {gpu_time:?} (first run, incl. pipeline creation), f64 reference {cpu_time:?}");
}

#[test]
fn a_profile_times_every_step_of_the_training_step_in_one_submit() {
    let g = gpu();
    let graph = Graph::default_asset();
    let config = ModelConfig::gradient_check(Variant::Iastgcn);
    let batch = 4;
    let net = Network::new(&g, &config, &graph, batch, DROPOUT_SEED).unwrap();
    net.load_parameters(&g, &parameters(&config, 5)).unwrap();
    let (_, forward, backward) = net.schedule_sizes();
    for timing in [Timing::Timestamps, Timing::Alone] {
        let p = net.profile(&g, Pass::Train, timing, 2).unwrap();
        assert_eq!(p.timing, timing);
        assert_eq!(
            p.steps.len(),
            forward + backward,
            "{timing:?}: one row per step"
        );
        let kernels = p.steps.iter().filter(|s| s.kernel != "copy");
        assert!(
            kernels.clone().all(|s| s.time > std::time::Duration::ZERO),
            "{timing:?}: every launch takes time"
        );
        assert!(kernels.clone().any(|s| s.kernel.ends_with("loss_forward")));
        assert!(
            kernels.filter(|s| s.flops > 0.0).count() > 10,
            "{timing:?}: the products"
        );
        assert!(
            p.span >= p.launches(),
            "{timing:?}: the span holds every launch"
        );
    }
    let infer = net
        .profile(&g, Pass::Inference, Timing::Timestamps, 1)
        .unwrap();
    assert_eq!(infer.steps.len(), net.schedule_sizes().0);
}
