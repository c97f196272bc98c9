//! Elementwise ops the model needs (ReLU, sigmoid, tanh, add, mul), forward and
//! backward, with their CPU reference. Backward kernels can accumulate into an existing
//! gradient, so a tensor used twice simply receives two dispatches.

use crate::gpu::{grid_1d, Binding, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};
use crate::ops::Accumulate;

/// The WGSL module of this family (`shaders/elementwise.wgsl`: one forward and one
/// backward entry per op).
pub static SHADER: Shader = Shader {
    name: "elementwise",
    source: include_str!("../../shaders/elementwise.wgsl"),
    base: None,
};

const WORKGROUP: u32 = 256;

const IN0: Binding = Binding::read(1);
const IN1: Binding = Binding::read(2);
const OUT: Binding = Binding::read_write(3);
const UNARY: &[Binding] = &[IN0, OUT];
const BINARY: &[Binding] = &[IN0, IN1, OUT];

macro_rules! kernel {
    ($name:ident, $entry:literal, $bindings:expr) => {
        static $name: Kernel = Kernel {
            shader: &SHADER,
            entry: $entry,
            bindings: $bindings,
        };
    };
}

kernel!(RELU_FWD, "relu_forward", UNARY);
kernel!(SIGMOID_FWD, "sigmoid_forward", UNARY);
kernel!(TANH_FWD, "tanh_forward", UNARY);
kernel!(ADD_FWD, "add_forward", BINARY);
kernel!(MUL_FWD, "mul_forward", BINARY);
kernel!(RELU_BWD, "relu_backward", BINARY);
kernel!(SIGMOID_BWD, "sigmoid_backward", BINARY);
kernel!(TANH_BWD, "tanh_backward", BINARY);
kernel!(ADD_BWD, "add_backward", UNARY);
kernel!(MUL_BWD, "mul_backward", BINARY);

/// A one-input activation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Unary {
    /// `max(x, 0)`; its derivative is taken as 0 at x = 0.
    Relu,
    /// The logistic sigmoid σ(x) = 1/(1 + e^(−x)).
    Sigmoid,
    /// The hyperbolic tangent.
    Tanh,
}

/// A two-input elementwise op on equal shapes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Binary {
    /// `c = a + b`.
    Add,
    /// `c = a · b` (Hadamard product).
    Mul,
}

impl Unary {
    /// Every activation, for tests that check each.
    pub const ALL: [Unary; 3] = [Unary::Relu, Unary::Sigmoid, Unary::Tanh];

    /// Whether the backward pass needs the forward *output* (sigmoid, tanh) rather than
    /// the input (ReLU).
    pub fn backward_uses_output(self) -> bool {
        !matches!(self, Unary::Relu)
    }

    fn kernels(self) -> (&'static Kernel, &'static Kernel) {
        match self {
            Unary::Relu => (&RELU_FWD, &RELU_BWD),
            Unary::Sigmoid => (&SIGMOID_FWD, &SIGMOID_BWD),
            Unary::Tanh => (&TANH_FWD, &TANH_BWD),
        }
    }
}

impl Binary {
    /// Both ops, for tests that check each.
    pub const ALL: [Binary; 2] = [Binary::Add, Binary::Mul];
}

crate::gpu::uniform! {
    pub(crate) struct Params = EwParams in SHADER {
        n: u32,
        accumulate: u32,
        _pad0: u32,
        _pad1: u32,
    }
}

fn launch(
    gpu: &Gpu,
    kernel: &Kernel,
    inputs: &[&Tensor],
    out: &Tensor,
    accumulate: Accumulate,
) -> Result<Dispatch, GpuError> {
    let n = out.numel();
    for t in inputs {
        t.expect_len(n)?;
    }
    out.expect_distinct(inputs.iter().copied())?;
    let params = Params {
        n: n as u32,
        accumulate: accumulate.flag(),
        _pad0: 0,
        _pad1: 0,
    };
    let mut tensors = inputs.to_vec();
    tensors.push(out);
    let groups = grid_1d(
        n,
        WORKGROUP,
        gpu.limits().max_compute_workgroups_per_dimension,
    );
    gpu.dispatch(kernel, &[], &params, &tensors, groups)
}

/// `y (+)= f(x)`.
pub fn unary_forward(
    gpu: &Gpu,
    op: Unary,
    x: &Tensor,
    y: &Tensor,
    accumulate: Accumulate,
) -> Result<Dispatch, GpuError> {
    launch(gpu, op.kernels().0, &[x], y, accumulate)
}

/// `dx (+)= dy · f'(·)`; `saved` is `x` for ReLU and `y` for sigmoid/tanh
/// (see [`Unary::backward_uses_output`]).
pub fn unary_backward(
    gpu: &Gpu,
    op: Unary,
    saved: &Tensor,
    dy: &Tensor,
    dx: &Tensor,
    accumulate: Accumulate,
) -> Result<Dispatch, GpuError> {
    launch(gpu, op.kernels().1, &[saved, dy], dx, accumulate)
}

/// `c (+)= a ∘ b`.
pub fn binary_forward(
    gpu: &Gpu,
    op: Binary,
    a: &Tensor,
    b: &Tensor,
    c: &Tensor,
    accumulate: Accumulate,
) -> Result<Dispatch, GpuError> {
    let kernel = match op {
        Binary::Add => &ADD_FWD,
        Binary::Mul => &MUL_FWD,
    };
    launch(gpu, kernel, &[a, b], c, accumulate)
}

/// `d_self (+)= ∂(self ∘ other)/∂self · dc` for either operand: for `Add` that is `dc`
/// (`other` is not read), for `Mul` it is `other · dc`.
pub fn binary_backward(
    gpu: &Gpu,
    op: Binary,
    other: &Tensor,
    dc: &Tensor,
    d_self: &Tensor,
    accumulate: Accumulate,
) -> Result<Dispatch, GpuError> {
    match op {
        Binary::Add => launch(gpu, &ADD_BWD, &[dc], d_self, accumulate),
        Binary::Mul => launch(gpu, &MUL_BWD, &[other, dc], d_self, accumulate),
    }
}

/// f64 reference, for tests.
pub mod cpu {
    use super::{Binary, Unary};

    /// The activation `op` of one value.
    pub fn unary(op: Unary, x: f64) -> f64 {
        match op {
            Unary::Relu => x.max(0.0),
            Unary::Sigmoid => 1.0 / (1.0 + (-x).exp()),
            Unary::Tanh => x.tanh(),
        }
    }

    /// `y = f(x)` element by element, as a new vector.
    pub fn unary_forward(op: Unary, x: &[f64]) -> Vec<f64> {
        x.iter().map(|&v| unary(op, v)).collect()
    }

    /// `dx` from the forward input `x` and upstream `dy`.
    pub fn unary_backward(op: Unary, x: &[f64], dy: &[f64]) -> Vec<f64> {
        x.iter()
            .zip(dy)
            .map(|(&x, &g)| {
                g * match op {
                    Unary::Relu => f64::from(x > 0.0),
                    Unary::Sigmoid => {
                        let s = unary(op, x);
                        s * (1.0 - s)
                    }
                    Unary::Tanh => 1.0 - x.tanh().powi(2),
                }
            })
            .collect()
    }

    /// `c = a ∘ b` element by element over equal lengths, as a new vector.
    pub fn binary_forward(op: Binary, a: &[f64], b: &[f64]) -> Vec<f64> {
        a.iter()
            .zip(b)
            .map(|(&a, &b)| match op {
                Binary::Add => a + b,
                Binary::Mul => a * b,
            })
            .collect()
    }

    /// `(da, db)` for upstream `dc`.
    pub fn binary_backward(op: Binary, a: &[f64], b: &[f64], dc: &[f64]) -> (Vec<f64>, Vec<f64>) {
        match op {
            Binary::Add => (dc.to_vec(), dc.to_vec()),
            Binary::Mul => (
                dc.iter().zip(b).map(|(g, b)| g * b).collect(),
                dc.iter().zip(a).map(|(g, a)| g * a).collect(),
            ),
        }
    }
}
