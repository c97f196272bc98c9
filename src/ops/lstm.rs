//! The LSTM cell update of the ConvLSTM baseline (docs/model.md "Baselines"), element by
//! element, with the f64 CPU reference. The gates' pre-activations z are `[B, 4, M]`
//! (i, f, o, g for each window's M state elements); the kernel applies σ to i, f, o and
//! tanh to g: `c' = f ⊙ c + i ⊙ g`, `h' = o ⊙ tanh(c')`.

use crate::gpu::{grid_1d, Binding, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};

/// The WGSL module of this family (`shaders/lstm.wgsl`: `lstm_forward`, `lstm_backward`).
pub static SHADER: Shader = Shader {
    name: "lstm",
    source: include_str!("../../shaders/lstm.wgsl"),
    base: None,
};

static FORWARD: Kernel = Kernel {
    shader: &SHADER,
    entry: "lstm_forward",
    bindings: &[
        Binding::read(1),
        Binding::read(2),
        Binding::read_write(3),
        Binding::read_write(4),
    ],
};
static BACKWARD: Kernel = Kernel {
    shader: &SHADER,
    entry: "lstm_backward",
    bindings: &[
        Binding::read(1),
        Binding::read(2),
        Binding::read(3),
        Binding::read(4),
        Binding::read(5),
        Binding::read_write(6),
        Binding::read_write(7),
    ],
};

crate::gpu::uniform! {
    pub(crate) struct Params = LstmParams in SHADER {
        n: u32,
        m: u32,
        _pad0: u32,
        _pad1: u32,
    }
}

/// The shape of one cell update: `batch` windows of `state` elements each.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Lstm {
    /// B: windows.
    pub batch: usize,
    /// M: state elements per window (C_h·N·F for ConvLSTM).
    pub state: usize,
}

impl Lstm {
    fn launch(
        &self,
        gpu: &Gpu,
        kernel: &Kernel,
        tensors: &[&Tensor],
    ) -> Result<Dispatch, GpuError> {
        let n = self.batch * self.state;
        let params = Params {
            n: n as u32,
            m: self.state as u32,
            _pad0: 0,
            _pad1: 0,
        };
        let max = gpu.limits().max_compute_workgroups_per_dimension;
        gpu.dispatch(kernel, &[], &params, tensors, grid_1d(n, 256, max))
    }

    /// `c` and `h` (overwritten) from the gates' pre-activations `z` `[B, 4, M]` and the
    /// previous cell `c_prev` `[B, M]`.
    pub fn forward(
        &self,
        gpu: &Gpu,
        z: &Tensor,
        c_prev: &Tensor,
        c: &Tensor,
        h: &Tensor,
    ) -> Result<Dispatch, GpuError> {
        let n = self.batch * self.state;
        z.expect_len(4 * n)?;
        for t in [c_prev, c, h] {
            t.expect_len(n)?;
        }
        for written in [c, h] {
            written.expect_distinct([z, c_prev])?;
        }
        self.launch(gpu, &FORWARD, &[z, c_prev, c, h])
    }

    /// `d_z` `[B, 4, M]` and `d_c_prev` (both overwritten) from ∂ℒ/∂h' (`d_h`) and ∂ℒ/∂c'
    /// (`d_c`, the next step's; zeros at the last step).
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        gpu: &Gpu,
        [z, c_prev, c]: [&Tensor; 3],
        d_h: &Tensor,
        d_c: &Tensor,
        d_z: &Tensor,
        d_c_prev: &Tensor,
    ) -> Result<Dispatch, GpuError> {
        let n = self.batch * self.state;
        z.expect_len(4 * n)?;
        d_z.expect_len(4 * n)?;
        for t in [c_prev, c, d_h, d_c, d_c_prev] {
            t.expect_len(n)?;
        }
        for written in [d_z, d_c_prev] {
            written.expect_distinct([z, c_prev, c, d_h, d_c])?;
        }
        self.launch(gpu, &BACKWARD, &[z, c_prev, c, d_h, d_c, d_z, d_c_prev])
    }
}

/// f64 reference, for tests.
pub mod cpu {
    use super::Lstm;

    fn sigmoid(x: f64) -> f64 {
        1.0 / (1.0 + (-x).exp())
    }

    /// (i, f, o, g) of state element k, activated.
    fn gates(s: &Lstm, z: &[f64], k: usize) -> [f64; 4] {
        let at = |q: usize| z[((k / s.state) * 4 + q) * s.state + k % s.state];
        [sigmoid(at(0)), sigmoid(at(1)), sigmoid(at(2)), at(3).tanh()]
    }

    /// (c', h').
    pub fn forward(s: &Lstm, z: &[f64], c_prev: &[f64]) -> (Vec<f64>, Vec<f64>) {
        (0..c_prev.len())
            .map(|k| {
                let [i, f, o, g] = gates(s, z, k);
                let c = f * c_prev[k] + i * g;
                (c, o * c.tanh())
            })
            .unzip()
    }

    /// (∂ℒ/∂z, ∂ℒ/∂c_prev) from ∂ℒ/∂h' and ∂ℒ/∂c'.
    pub fn backward(
        s: &Lstm,
        z: &[f64],
        c_prev: &[f64],
        d_h: &[f64],
        d_c: &[f64],
    ) -> (Vec<f64>, Vec<f64>) {
        let mut d_z = vec![0.0; z.len()];
        let mut d_prev = vec![0.0; c_prev.len()];
        for k in 0..c_prev.len() {
            let [i, f, o, g] = gates(s, z, k);
            let c = f * c_prev[k] + i * g;
            let tc = c.tanh();
            let dc = d_c[k] + d_h[k] * o * (1.0 - tc * tc);
            let at = |q: usize| ((k / s.state) * 4 + q) * s.state + k % s.state;
            d_z[at(0)] = dc * g * i * (1.0 - i);
            d_z[at(1)] = dc * c_prev[k] * f * (1.0 - f);
            d_z[at(2)] = d_h[k] * tc * o * (1.0 - o);
            d_z[at(3)] = dc * i * (1.0 - g * g);
            d_prev[k] = dc * f;
        }
        (d_z, d_prev)
    }
}
