//! The dense baselines (`mlp`, `bkls-ann`, `ann-bfpa`, `erc`; `model::dense`,
//! docs/model.md "Baselines") on the CPU in f32, one window at a time: the last step's
//! selected features, then every fully connected layer (activation, then the skip
//! connection's addition), and the hand-written backward pass of the same arithmetic as
//! the f64 reference `model::dense::reference`. The layers are a few dozen wide, so the
//! products are plain loops over contiguous rows.

use crate::graph::Graph;
use crate::model::config::ModelConfig;
use crate::model::cpu::{sigmoid, tanh};
use crate::model::dense::{Architecture, Layer};
use crate::model::error::ModelError;
use crate::model::params::ParamSpec;
use crate::ops::elementwise::Unary;

/// A dense baseline's layers and where their tensors and inputs are.
pub(crate) struct DenseNet {
    layers: Vec<Layer>,
    /// Each layer's (weight `[outputs, inputs]`, bias) index in the parameter list.
    slots: Vec<(usize, usize)>,
    /// Offsets in one window `[N, F, T]` of the selected inputs, `(n·F + f)·T + T − 1`.
    inputs: Vec<usize>,
}

/// One window's activations and the backward pass's working memory.
pub(crate) struct DenseTape {
    /// 0 = the selected inputs, i + 1 = layer i's output (the last is ŷ).
    acts: Vec<Vec<f32>>,
    /// Each layer's value before its activation and skip.
    pre: Vec<Vec<f32>>,
    /// ∂L/∂ each activation.
    d_acts: Vec<Vec<f32>>,
    /// ∂L/∂ a layer's pre-activation.
    dz: Vec<f32>,
}

impl DenseTape {
    /// ŷ `[O]` of the last forward pass.
    pub fn output(&self) -> &[f32] {
        // invariant: a tape has the input and at least the head's output.
        self.acts
            .last()
            .expect("a dense tape ends in the head's output")
    }
}

fn activate(op: Unary, x: f32) -> f32 {
    match op {
        Unary::Relu => x.max(0.0),
        Unary::Sigmoid => sigmoid(x),
        Unary::Tanh => tanh(x),
    }
}

/// dy/dx of `activate(op, x)` at the pre-activation `x` (ReLU's is 0 at 0, as on the
/// device).
fn slope(op: Unary, x: f32) -> f32 {
    match op {
        Unary::Relu => f32::from(x > 0.0),
        Unary::Sigmoid => {
            let s = sigmoid(x);
            s * (1.0 - s)
        }
        Unary::Tanh => {
            let t = tanh(x);
            1.0 - t * t
        }
    }
}

impl DenseNet {
    /// The layers of `config`'s dense variant, its inputs in `graph` and its tensors in
    /// `specs`; an error names a missing joint input or tensor.
    pub fn new(
        config: &ModelConfig,
        graph: &Graph,
        specs: &[ParamSpec],
    ) -> Result<DenseNet, ModelError> {
        let arch = Architecture::of(config).ok_or_else(|| {
            ModelError::Config(format!("{} is not a dense baseline", config.variant))
        })?;
        let t = config.window;
        let inputs = arch
            .input_indices(graph, config.features)
            .map_err(ModelError::Config)?
            .into_iter()
            .map(|i| i * t + t - 1)
            .collect();
        let find = |name: String| {
            specs
                .iter()
                .position(|s| s.name == name)
                .ok_or_else(|| ModelError::Config(format!("the parameters lack {name}")))
        };
        let slots = arch
            .layers
            .iter()
            .map(|l| {
                Ok((
                    find(format!("{}.weight", l.name))?,
                    find(format!("{}.bias", l.name))?,
                ))
            })
            .collect::<Result<Vec<_>, ModelError>>()?;
        Ok(DenseNet {
            layers: arch.layers,
            slots,
            inputs,
        })
    }

    /// A tape sized for this network (the only allocations).
    pub fn tape(&self) -> DenseTape {
        let widths: Vec<usize> = std::iter::once(self.inputs.len())
            .chain(self.layers.iter().map(|l| l.outputs))
            .collect();
        let zeros = |w: &usize| vec![0f32; *w];
        DenseTape {
            acts: widths.iter().map(zeros).collect(),
            pre: widths[1..].iter().map(zeros).collect(),
            d_acts: widths.iter().map(zeros).collect(),
            dz: vec![0f32; widths.iter().copied().max().unwrap_or(0)],
        }
    }

    /// The forward pass of one standardised window `x` `[N, F, T]` into `tape`.
    pub fn forward(&self, params: &[Vec<f32>], x: &[f32], tape: &mut DenseTape) {
        for (a, &at) in tape.acts[0].iter_mut().zip(&self.inputs) {
            *a = x[at];
        }
        for (i, (l, &(w, b))) in self.layers.iter().zip(&self.slots).enumerate() {
            let (before, after) = tape.acts.split_at_mut(i + 1);
            let (input, out) = (&before[i], &mut after[0]);
            let (weight, bias) = (&params[w], &params[b]);
            for (o, (z, y)) in tape.pre[i].iter_mut().zip(out.iter_mut()).enumerate() {
                let row = &weight[o * l.inputs..][..l.inputs];
                *z = bias[o] + row.iter().zip(input).map(|(w, a)| w * a).sum::<f32>();
                *y = l.activation.map_or(*z, |op| activate(op, *z));
            }
            if let Some(j) = l.skip {
                for (y, s) in out.iter_mut().zip(&before[j]) {
                    *y += s;
                }
            }
        }
    }

    /// Adds ∂L/∂ every parameter to `grads` (`param_specs` order) for the upstream
    /// gradient `dout` `[O]` of the window whose forward pass is in `tape`.
    pub fn backward(
        &self,
        params: &[Vec<f32>],
        tape: &mut DenseTape,
        dout: &[f32],
        grads: &mut [Vec<f32>],
    ) {
        for d in tape.d_acts.iter_mut() {
            d.fill(0.0);
        }
        // invariant: a tape has the input and at least the head's output.
        tape.d_acts
            .last_mut()
            .expect("the head's output")
            .copy_from_slice(dout);
        for (i, (l, &(w, b))) in self.layers.iter().zip(&self.slots).enumerate().rev() {
            let (before, after) = tape.d_acts.split_at_mut(i + 1);
            let d_out = &after[0];
            if let Some(j) = l.skip {
                for (d, g) in before[j].iter_mut().zip(d_out) {
                    *d += g;
                }
            }
            let dz = &mut tape.dz[..l.outputs];
            for ((dz, g), &z) in dz.iter_mut().zip(d_out).zip(&tape.pre[i]) {
                *dz = l.activation.map_or(*g, |op| g * slope(op, z));
            }
            let input = &tape.acts[i];
            for (o, &g) in dz.iter().enumerate() {
                grads[b][o] += g;
                for (dw, a) in grads[w][o * l.inputs..][..l.inputs].iter_mut().zip(input) {
                    *dw += g * a;
                }
            }
            // The selected inputs need no gradient.
            if i > 0 {
                let d_in = &mut before[i];
                for (o, &g) in dz.iter().enumerate() {
                    let row = &params[w][o * l.inputs..][..l.inputs];
                    for (d, wv) in d_in.iter_mut().zip(row) {
                        *d += g * wv;
                    }
                }
            }
        }
    }
}
