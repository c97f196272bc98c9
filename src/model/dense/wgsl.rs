//! A dense baseline on the device: its tensors and its forward and backward launches for
//! one batch size, part of a [`crate::model::Network`].

use super::{Architecture, Inputs, Layer};
use crate::gpu::{DType, Gpu, GpuError, Tensor};
use crate::model::config::ModelConfig;
use crate::model::schedule::ParamTable;
use crate::model::schedule::Steps;
use crate::ops::bias::Bias;
use crate::ops::elementwise::{binary_backward, unary_backward, unary_forward, Binary};
use crate::ops::head::LastStep;
use crate::ops::matmul::Matmul;
use crate::ops::Accumulate;

/// A dense baseline's tensors and ops for one batch size (part of a [`super::Network`]).
///
/// The selected input is the last step of x, `[B, N·F]`, times a constant 0/1 selection
/// matrix `[N·F, K]` when the model reads only the joint inputs (a tiny product that
/// reuses the matmul and its backward instead of a gather op of its own).
pub(crate) struct DenseBody {
    arch: Architecture,
    /// The last step of x `[B, N·F]`, and its gradient.
    last: Tensor,
    last_grad: Tensor,
    /// The selection matrix `[N·F, K]`, when the model reads a subset.
    selection: Option<Tensor>,
    /// Activations: 0 = the selected input `[B, K]`, i + 1 = layer i's output (the last is
    /// the network's ŷ). A linear layer's output is its pre-activation.
    acts: Vec<Tensor>,
    /// Each layer's pre-activation `[B, outputs]` (the same tensor as its output when
    /// linear).
    pre: Vec<Tensor>,
    batch: usize,
    window: usize,
}

impl DenseBody {
    /// Allocates the activations of `arch` for `batch` windows reading x `[B, N, F, T]` at
    /// `indices` (from [`Architecture::input_indices`]) and writing `output` `[B, O]`.
    pub(crate) fn new(
        gpu: &Gpu,
        config: &ModelConfig,
        arch: Architecture,
        indices: &[usize],
        batch: usize,
        output: &Tensor,
    ) -> Result<DenseBody, GpuError> {
        let nf = config.nodes * config.features;
        let k = indices.len();
        let last = gpu.zeros("dense.last_step", &[batch, nf], DType::F32)?;
        let last_grad = gpu.zeros("dense.d_last_step", &[batch, nf], DType::F32)?;
        let selection = match arch.inputs {
            Inputs::EveryNode => None,
            Inputs::JointInputs(_) => {
                let mut s = vec![0f32; nf * k];
                for (j, &i) in indices.iter().enumerate() {
                    s[i * k + j] = 1.0;
                }
                Some(gpu.upload("dense.selection", &[nf, k], &s)?)
            }
        };
        let mut acts = vec![match selection {
            Some(_) => gpu.zeros("dense.input", &[batch, k], DType::F32)?,
            None => last.clone(),
        }];
        let mut pre = Vec::new();
        for (i, l) in arch.layers.iter().enumerate() {
            let is_head = i + 1 == arch.layers.len();
            let z = if is_head {
                output.clone()
            } else {
                gpu.zeros(&format!("{}.z", l.name), &[batch, l.outputs], DType::F32)?
            };
            let a = match l.activation {
                Some(_) => gpu.zeros(&format!("{}.a", l.name), &[batch, l.outputs], DType::F32)?,
                None => z.clone(),
            };
            pre.push(z);
            acts.push(a);
        }
        Ok(DenseBody {
            arch,
            last,
            last_grad,
            selection,
            acts,
            pre,
            batch,
            window: config.window,
        })
    }

    fn gather(&self) -> LastStep {
        LastStep {
            rows: self.last.numel(),
            steps: self.window,
        }
    }

    fn selector(&self) -> Matmul {
        Matmul::new(self.batch, self.acts[0].shape()[1], self.last.shape()[1])
    }

    fn linear(&self, l: &Layer) -> (Matmul, Bias) {
        (
            Matmul::new(self.batch, l.outputs, l.inputs).transpose_b(true),
            Bias {
                outer: self.batch,
                channels: l.outputs,
                inner: 1,
            },
        )
    }

    /// Appends the forward pass from x (`input`) to ŷ.
    pub(crate) fn forward(
        &self,
        gpu: &Gpu,
        table: &dyn ParamTable,
        input: &Tensor,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        steps.run(self.gather().forward(gpu, input, &self.last))?;
        if let Some(s) = &self.selection {
            steps.run(self.selector().forward(
                gpu,
                &self.last,
                s,
                &self.acts[0],
                Accumulate::Overwrite,
            ))?;
        }
        for (i, l) in self.arch.layers.iter().enumerate() {
            let (mm, bias) = self.linear(l);
            let z = &self.pre[i];
            let accumulate = match l.skip {
                Some(j) => {
                    let n = z.numel();
                    steps.copy_range((&self.acts[j], 0), (z, 0), n);
                    Accumulate::Add
                }
                None => Accumulate::Overwrite,
            };
            let weight = table.param(&format!("{}.weight", l.name));
            steps.run(mm.forward(gpu, &self.acts[i], weight, z, accumulate))?;
            steps.run(bias.forward(gpu, table.param(&format!("{}.bias", l.name)), z))?;
            if let Some(act) = l.activation {
                steps.run(unary_forward(
                    gpu,
                    act,
                    z,
                    &self.acts[i + 1],
                    Accumulate::Overwrite,
                ))?;
            }
        }
        Ok(())
    }

    /// Appends the backward pass from ∂ℒ/∂ŷ (`d_output`) to the parameter gradients and
    /// ∂ℒ/∂x (`input_grad`).
    pub(crate) fn backward(
        &self,
        gpu: &Gpu,
        table: &dyn ParamTable,
        d_output: &Tensor,
        input_grad: &Tensor,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        let layers = &self.arch.layers;
        // ∂ℒ/∂ activation i; the first contribution overwrites, later ones add.
        let d_acts: Vec<Tensor> = (0..=layers.len())
            .map(|i| {
                if i == layers.len() {
                    Ok(d_output.clone())
                } else if i == 0 && self.selection.is_none() {
                    Ok(self.last_grad.clone())
                } else {
                    gpu.zeros(&format!("dense.d_act{i}"), self.acts[i].shape(), DType::F32)
                }
            })
            .collect::<Result<_, GpuError>>()?;
        let mut written = vec![false; layers.len() + 1];
        written[layers.len()] = true;
        let mode = |written: &mut Vec<bool>, i: usize| {
            let m = if written[i] {
                Accumulate::Add
            } else {
                Accumulate::Overwrite
            };
            written[i] = true;
            m
        };
        for (i, l) in layers.iter().enumerate().rev() {
            let (mm, bias) = self.linear(l);
            let d_out = &d_acts[i + 1];
            if let Some(j) = l.skip {
                let m = mode(&mut written, j);
                steps.run(binary_backward(
                    gpu,
                    Binary::Add,
                    d_out,
                    d_out,
                    &d_acts[j],
                    m,
                ))?;
            }
            let dz = match l.activation {
                Some(act) => {
                    let dz = gpu.zeros(
                        &format!("{}.dz", l.name),
                        &[self.batch, l.outputs],
                        DType::F32,
                    )?;
                    let saved = if act.backward_uses_output() {
                        &self.acts[i + 1]
                    } else {
                        &self.pre[i]
                    };
                    steps.run(unary_backward(
                        gpu,
                        act,
                        saved,
                        d_out,
                        &dz,
                        Accumulate::Overwrite,
                    ))?;
                    dz
                }
                None => d_out.clone(),
            };
            steps.run(bias.backward(
                gpu,
                &dz,
                table.grad(&format!("{}.bias", l.name)),
                Accumulate::Overwrite,
            ))?;
            steps.run(mm.backward_b(
                gpu,
                &self.acts[i],
                &dz,
                table.grad(&format!("{}.weight", l.name)),
                Accumulate::Overwrite,
            ))?;
            let m = mode(&mut written, i);
            steps.run(mm.backward_a(
                gpu,
                table.param(&format!("{}.weight", l.name)),
                &dz,
                &d_acts[i],
                m,
            ))?;
        }
        if let Some(s) = &self.selection {
            steps.run(self.selector().backward_a(
                gpu,
                s,
                &d_acts[0],
                &self.last_grad,
                Accumulate::Overwrite,
            ))?;
        }
        steps.run(self.gather().backward(gpu, &self.last_grad, input_grad))?;
        Ok(())
    }
}
