//! The f64 reference of the dense baselines (`model::dense`, docs/model.md "Baselines"):
//! the forward pass keeping every activation, and its hand-written backward pass. The
//! loss is [`crate::model::reference::loss`], the same as IASTGCN's.

use crate::model::dense::Architecture;
use crate::model::exact::{axpy, Grads, Table};
use crate::model::reference::{add_weight_decay, output_gradient, Loss};
use crate::model::{ModelConfig, ParamSpec};
use crate::ops::elementwise::cpu as act;

/// Everything the forward pass of a dense baseline computed.
#[derive(Clone, Debug)]
pub struct DenseTape {
    /// B: windows in the batch.
    pub batch: usize,
    /// Activations: 0 = the selected inputs `[B, K]`, i + 1 = layer i's output
    /// `[B, outputs]` (the last is ŷ).
    pub acts: Vec<Vec<f64>>,
    /// Each layer's value before its activation (and before the skip is added).
    pub pre: Vec<Vec<f64>>,
    /// ŷ `[B, O]`.
    pub output: Vec<f64>,
}

impl DenseTape {
    /// The on/off state of every ReLU (for finite differences that must not straddle a
    /// kink).
    pub fn relu_pattern(&self) -> Vec<bool> {
        self.pre.iter().flatten().map(|&v| v > 0.0).collect()
    }
}

fn architecture(config: &ModelConfig) -> Architecture {
    // invariant: the f64 reference is a test oracle, called for dense variants only.
    Architecture::of(config).unwrap_or_else(|| panic!("{} is not a dense baseline", config.variant))
}

/// The forward pass on `x` `[B, N, F, T]`: the last step's features at `inputs` (flat
/// `n·F + f` positions, `Architecture::input_indices`), then the layers.
pub fn forward(
    config: &ModelConfig,
    inputs: &[usize],
    specs: &[ParamSpec],
    params: &[Vec<f64>],
    x: &[f64],
    batch: usize,
) -> DenseTape {
    let arch = architecture(config);
    let table = Table::new(specs, params);
    let (nf, t) = (config.nodes * config.features, config.window);
    assert_eq!(x.len(), batch * nf * t, "x is [B,N,F,T]");
    assert_eq!(inputs.len(), arch.input_width(), "one index per input");
    let selected: Vec<f64> = (0..batch)
        .flat_map(|b| inputs.iter().map(move |&i| x[(b * nf + i) * t + t - 1]))
        .collect();
    let mut acts = vec![selected];
    let mut pre = Vec::new();
    for l in &arch.layers {
        let w = table.get(&format!("{}.weight", l.name));
        let bias = table.get(&format!("{}.bias", l.name));
        // invariant: acts starts with the input.
        let input = acts.last().expect("the input is activation 0");
        let mut z = vec![0.0; batch * l.outputs];
        for b in 0..batch {
            for o in 0..l.outputs {
                let row = &w[o * l.inputs..(o + 1) * l.inputs];
                let a = &input[b * l.inputs..(b + 1) * l.inputs];
                z[b * l.outputs + o] = bias[o] + row.iter().zip(a).map(|(w, a)| w * a).sum::<f64>();
            }
        }
        let mut out = match l.activation {
            Some(op) => act::unary_forward(op, &z),
            None => z.clone(),
        };
        if let Some(j) = l.skip {
            axpy(&mut out, 1.0, &acts[j]);
        }
        pre.push(z);
        acts.push(out);
    }
    // invariant: acts starts with the input.
    let output = acts.last().expect("the head's output").clone();
    DenseTape {
        batch,
        acts,
        pre,
        output,
    }
}

/// The gradient of [`crate::model::reference::loss`]`(forward(..))` with respect to every parameter (in
/// spec order) and to x, from the tape of [`forward`].
#[allow(clippy::too_many_arguments)]
pub fn backward(
    config: &ModelConfig,
    inputs: &[usize],
    specs: &[ParamSpec],
    params: &[Vec<f64>],
    tape: &DenseTape,
    y: &[f64],
    batch: usize,
    loss: &Loss,
) -> (Vec<Vec<f64>>, Vec<f64>) {
    let arch = architecture(config);
    let table = Table::new(specs, params);
    let (no, nf, t) = (
        config.outputs,
        config.nodes * config.features,
        config.window,
    );
    assert_eq!(tape.batch, batch, "tape of another batch size");
    assert_eq!(y.len(), batch * no, "y is [B,O]");
    let mut grads = Grads {
        specs,
        values: specs.iter().map(|s| vec![0.0; s.numel()]).collect(),
    };
    let mut d_acts: Vec<Vec<f64>> = tape.acts.iter().map(|a| vec![0.0; a.len()]).collect();
    // invariant: acts starts with the input.
    *d_acts.last_mut().expect("the head's output") =
        output_gradient(&tape.output, y, no, batch, loss);
    for (i, l) in arch.layers.iter().enumerate().rev() {
        let d_out = d_acts[i + 1].clone();
        if let Some(j) = l.skip {
            axpy(&mut d_acts[j], 1.0, &d_out);
        }
        let dz = match l.activation {
            Some(op) => act::unary_backward(op, &tape.pre[i], &d_out),
            None => d_out,
        };
        let w = table.get(&format!("{}.weight", l.name));
        let mut dw = vec![0.0; l.outputs * l.inputs];
        let mut db = vec![0.0; l.outputs];
        let input = &tape.acts[i];
        for b in 0..batch {
            for o in 0..l.outputs {
                let g = dz[b * l.outputs + o];
                db[o] += g;
                axpy(
                    &mut dw[o * l.inputs..(o + 1) * l.inputs],
                    g,
                    &input[b * l.inputs..(b + 1) * l.inputs],
                );
                axpy(
                    &mut d_acts[i][b * l.inputs..(b + 1) * l.inputs],
                    g,
                    &w[o * l.inputs..(o + 1) * l.inputs],
                );
            }
        }
        grads.add(&format!("{}.weight", l.name), &dw);
        grads.add(&format!("{}.bias", l.name), &db);
    }
    // The selected inputs came from the last step of x.
    let mut dx = vec![0.0; batch * nf * t];
    let k = inputs.len();
    for b in 0..batch {
        for (j, &i) in inputs.iter().enumerate() {
            dx[(b * nf + i) * t + t - 1] += d_acts[0][b * k + j];
        }
    }
    add_weight_decay(specs, params, &mut grads.values, loss);
    (grads.values, dx)
}
