//! One test for every step of the ST block on every implementation: each step's
//! [`StepTest`] (in its folder's `tests.rs`) gives random inputs and output gradients and
//! runs them through its f64 reference, its native f32 code and its WGSL launches on the
//! device; this file checks the reference's backward against central finite differences
//! of its forward, then both f32 implementations' outputs, the gradients they hand back
//! and every parameter's gradient against the reference's, and names the step, the case
//! and the implementation that broke ("gated_dcc iastgcn block 1 (wgsl): d
//! blocks.1.tcn.gate.weight: element 3 is …"). [`every_step_is_tested`] fails on a step
//! folder that [`steps`] does not list.
#![cfg(test)]

use super::gated_dcc;
use super::graph_conv;
use super::residual_layer_norm;
use super::spatial_attention;
use super::temporal_attention;
use super::testing::{case, check, uniform, wide, Backward, Case, Run, StepTest, Tensors, Where};
use crate::model::params::{param_specs, ParamSpec};
use std::path::Path;

/// Every step the test runs, one per folder of `model/block/`.
fn steps() -> Vec<Box<dyn StepTest>> {
    vec![
        Box::new(gated_dcc::tests::GatedDcc),
        Box::new(residual_layer_norm::tests::ResidualLayerNorm),
        Box::new(temporal_attention::tests::TemporalAttention1),
        Box::new(spatial_attention::tests::SpatialAttention2),
        Box::new(graph_conv::tests::GraphConv3 { gat: false }),
        Box::new(graph_conv::tests::GraphConv3 { gat: true }),
    ]
}

/// Σ over outputs of d_out · out: the scalar whose gradient the backward computes.
fn pairing(outputs: &Tensors, d_outputs: &Tensors) -> f64 {
    d_outputs
        .iter()
        .map(|(name, d)| {
            // invariant: test support: a step's output gradients name its outputs.
            let out = &outputs[name];
            assert_eq!(out.len(), d.len(), "{name}: output and gradient lengths");
            out.iter().zip(d).map(|(o, g)| o * g).sum::<f64>()
        })
        .sum()
}

/// The reference's backward against central differences of its forward, at a few
/// elements of every input and of every parameter the step has a gradient for.
fn check_reference(
    step: &dyn StepTest,
    case: &Case,
    at: Where,
    (params, inputs): (&[Vec<f64>], &Tensors),
    d_outputs: &Tensors,
    (d_inputs, d_params): (&Tensors, &[Vec<f64>]),
) {
    let what = |part: &str| {
        format!(
            "{} {at} (reference vs finite differences): {part}",
            step.name()
        )
    };
    let loss = |params: &[Vec<f64>], inputs: &Tensors| {
        pairing(&step.reference_forward(case, at, params, inputs), d_outputs)
    };
    // Five elements of each tensor, at indices drawn from the tensor's position.
    let picks = |seed: u64, len: usize| -> Vec<usize> {
        uniform(seed, 5, 0.0, len as f64)
            .into_iter()
            .map(|u| u as usize)
            .collect()
    };
    let central = |f: &dyn Fn(f64) -> f64, x: f64| {
        let h = 1e-6 * x.abs().max(1.0);
        (f(x + h) - f(x - h)) / (2.0 * h)
    };
    let close = |fd: f64, an: f64| (fd - an).abs() <= 1e-6 + 1e-5 * (fd.abs() + an.abs());
    for (k, (name, x)) in inputs.iter().enumerate() {
        // invariant: test support: the reference's backward has a gradient for every input.
        let d = &d_inputs[name];
        for i in picks(900 + k as u64, x.len()) {
            let fd = central(
                &|v| {
                    let mut moved = inputs.clone();
                    // invariant: test support: `name` is one of `inputs`.
                    moved.get_mut(name).unwrap()[i] = v;
                    loss(params, &moved)
                },
                x[i],
            );
            assert!(
                close(fd, d[i]),
                "{}",
                what(&format!(
                    "d{name}: element {i} is {}, finite differences {fd}",
                    d[i]
                ))
            );
        }
    }
    for (p, (spec, d)) in param_specs(&case.cfg).iter().zip(d_params).enumerate() {
        if d.iter().all(|&g| g == 0.0) {
            continue;
        }
        for i in picks(950 + p as u64, d.len()) {
            let fd = central(
                &|v| {
                    let mut moved = params.to_vec();
                    moved[p][i] = v;
                    loss(&moved, inputs)
                },
                params[p][i],
            );
            assert!(
                close(fd, d[i]),
                "{}",
                what(&format!(
                    "d {}: element {i} is {}, finite differences {fd}",
                    spec.name, d[i]
                ))
            );
        }
    }
}

/// An implementation's run against the reference's.
fn check_run(step: &str, at: Where, backend: &str, specs: &[ParamSpec], run: &Run, expected: &Run) {
    let what = |part: &str| format!("{step} {at} ({backend}): {part}");
    let tensors = |kind: &str, got: &Tensors, want: &Tensors| {
        let names = |t: &Tensors| t.keys().copied().collect::<Vec<_>>();
        assert_eq!(names(got), names(want), "{}", what(kind));
        for (name, e) in want {
            check(&what(&format!("{kind} {name}")), &got[name], e);
        }
    };
    tensors("output", &run.outputs, &expected.outputs);
    // invariant: test support: the reference always runs its backward.
    let want = expected
        .backward
        .as_ref()
        .expect("the reference's backward");
    let Some(got) = &run.backward else {
        return;
    };
    tensors("d", &got.d_inputs, &want.d_inputs);
    assert_eq!(
        got.d_params.len(),
        want.d_params.len(),
        "{}",
        what("parameters")
    );
    for ((spec, a), e) in specs.iter().zip(&got.d_params).zip(&want.d_params) {
        check(&what(&format!("d {}", spec.name)), a, e);
    }
}

#[test]
fn every_step_on_every_implementation_matches_its_reference() {
    for step in steps() {
        for at in step.cases() {
            let mut case = case(at.variant);
            let (inputs, d_outputs) = step.case_tensors(&case, at);
            let params: Vec<Vec<f64>> = case.params.iter().map(|v| wide(v)).collect();
            let outputs = step.reference_forward(&case, at, &params, &inputs);
            let (d_inputs, d_params) =
                step.reference_backward(&case, at, &params, &inputs, &d_outputs);
            check_reference(
                &*step,
                &case,
                at,
                (&params, &inputs),
                &d_outputs,
                (&d_inputs, &d_params),
            );
            let specs = param_specs(&case.cfg);
            let expected = Run {
                outputs,
                backward: Some(Backward {
                    d_inputs: step.handed_back(&inputs, d_inputs),
                    d_params,
                }),
            };
            let native = step.native(&mut case, at, &inputs, &d_outputs);
            let where_computed = Run {
                outputs: step.native_outputs(&case, at, expected.outputs.clone()),
                backward: expected.backward.clone(),
            };
            check_run(step.name(), at, "native", &specs, &native, &where_computed);
            let wgsl = step.wgsl(&case, at, &inputs, &d_outputs);
            check_run(step.name(), at, "wgsl", &specs, &wgsl, &expected);
        }
    }
}

#[test]
fn every_step_is_tested() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/model/block");
    let mut folders: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .filter(|e| e.path().is_dir())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    folders.sort();
    let mut listed: Vec<String> = steps().iter().map(|s| s.name().to_string()).collect();
    listed.sort();
    assert_eq!(
        folders, listed,
        "every step folder of src/model/block has a StepTest in `steps()`"
    );
}
