//! The f64 reference of T-GCN (`model::recurrent`, docs/model.md "Baselines"): the time
//! loop keeping every step's gates and state, and backpropagation through time by hand.
//! The loss is [`super::loss`].

use super::{add_weight_decay, axpy, output_gradient, Grads, Loss, Table};
use crate::model::{ModelConfig, ParamSpec};

/// One step's values, each `[B, N, ·]` row-major.
#[derive(Clone, Debug)]
pub struct StepTape {
    /// x_t `[B, N, F]`.
    pub x: Vec<f64>,
    /// The reset gate r.
    pub r: Vec<f64>,
    /// The update gate u.
    pub u: Vec<f64>,
    /// The candidate c.
    pub c: Vec<f64>,
    /// The new state h_t.
    pub h: Vec<f64>,
}

/// Everything the forward pass of T-GCN computed.
#[derive(Clone, Debug)]
pub struct RecurrentTape {
    /// B: windows in the batch.
    pub batch: usize,
    /// One entry per time step.
    pub steps: Vec<StepTape>,
    /// ŷ `[B, O]`.
    pub output: Vec<f64>,
}

struct Shape {
    b: usize,
    n: usize,
    f: usize,
    h: usize,
    t: usize,
}

impl Shape {
    fn of(config: &ModelConfig, batch: usize) -> Shape {
        Shape {
            b: batch,
            n: config.nodes,
            f: config.features,
            h: config.hidden,
            t: config.window,
        }
    }
}

/// `out[b, i, :] = Σ_j Â[i, j] · p[b, j, :]` for rows of width `w`.
fn mix(s: &Shape, a: &[f64], p: &[f64], w: usize) -> Vec<f64> {
    let mut out = vec![0.0; s.b * s.n * w];
    for b in 0..s.b {
        for i in 0..s.n {
            for j in 0..s.n {
                let (dst, src) = ((b * s.n + i) * w, (b * s.n + j) * w);
                let aij = a[i * s.n + j];
                for k in 0..w {
                    out[dst + k] += aij * p[src + k];
                }
            }
        }
    }
    out
}

/// `x [rows, k] · w [k, h]`.
fn product(x: &[f64], w: &[f64], k: usize, h: usize) -> Vec<f64> {
    let rows = x.len() / k;
    let mut out = vec![0.0; rows * h];
    for r in 0..rows {
        for i in 0..k {
            axpy(
                &mut out[r * h..(r + 1) * h],
                x[r * k + i],
                &w[i * h..(i + 1) * h],
            );
        }
    }
    out
}

fn sigmoid(v: f64) -> f64 {
    1.0 / (1.0 + (-v).exp())
}

/// Gate `g` before its activation: Â (x·Wx + h·Wh) + b.
fn gate(s: &Shape, table: &Table, a: &[f64], g: &str, x: &[f64], h: &[f64]) -> Vec<f64> {
    let p = |n: &str| table.get(&format!("cell.{g}.{n}"));
    let mut pre = product(x, p("wx"), s.f, s.h);
    axpy(&mut pre, 1.0, &product(h, p("wh"), s.h, s.h));
    let mut z = mix(s, a, &pre, s.h);
    let bias = p("bias");
    for (i, v) in z.iter_mut().enumerate() {
        *v += bias[i % s.h];
    }
    z
}

/// The forward pass on `x` `[B, N, F, T]`; `adjacency` is Â `[N, N]`
/// (`Graph::renormalized_adjacency`).
pub fn forward(
    config: &ModelConfig,
    adjacency: &[f64],
    specs: &[ParamSpec],
    params: &[Vec<f64>],
    x: &[f64],
    batch: usize,
) -> RecurrentTape {
    let s = Shape::of(config, batch);
    let table = Table::new(specs, params);
    assert_eq!(x.len(), s.b * s.n * s.f * s.t, "x is [B,N,F,T]");
    assert_eq!(adjacency.len(), s.n * s.n, "Â is [N,N]");
    let mut h = vec![0.0; s.b * s.n * s.h];
    let mut steps = Vec::with_capacity(s.t);
    for t in 0..s.t {
        let xt: Vec<f64> = (0..s.b * s.n * s.f).map(|r| x[r * s.t + t]).collect();
        let r: Vec<f64> = gate(&s, &table, adjacency, "r", &xt, &h)
            .into_iter()
            .map(sigmoid)
            .collect();
        let u: Vec<f64> = gate(&s, &table, adjacency, "u", &xt, &h)
            .into_iter()
            .map(sigmoid)
            .collect();
        let rh: Vec<f64> = r.iter().zip(&h).map(|(r, h)| r * h).collect();
        let c: Vec<f64> = gate(&s, &table, adjacency, "c", &xt, &rh)
            .into_iter()
            .map(f64::tanh)
            .collect();
        h = (0..h.len())
            .map(|i| u[i] * h[i] + (1.0 - u[i]) * c[i])
            .collect();
        steps.push(StepTape {
            x: xt,
            r,
            u,
            c,
            h: h.clone(),
        });
    }
    let (w, bias) = (table.get("head.weight"), table.get("head.bias"));
    let (nh, o) = (s.n * s.h, config.outputs);
    let output = (0..s.b * o)
        .map(|i| {
            let (b, k) = (i / o, i % o);
            bias[k]
                + w[k * nh..(k + 1) * nh]
                    .iter()
                    .zip(&h[b * nh..(b + 1) * nh])
                    .map(|(w, h)| w * h)
                    .sum::<f64>()
        })
        .collect();
    RecurrentTape {
        batch,
        steps,
        output,
    }
}

/// The backward of gate `g` given ∂ℒ/∂(pre-activation) `dz`: adds its parameter
/// gradients, and returns (∂ℒ/∂x_t, ∂ℒ/∂h_in).
fn gate_backward(
    s: &Shape,
    table: &Table,
    grads: &mut Grads,
    a: &[f64],
    g: &str,
    (x, h): (&[f64], &[f64]),
    dz: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let name = |n: &str| format!("cell.{g}.{n}");
    let mut db = vec![0.0; s.h];
    for (i, v) in dz.iter().enumerate() {
        db[i % s.h] += v;
    }
    grads.add(&name("bias"), &db);
    // ∂ℒ/∂pre = Âᵀ dz.
    let mut at = vec![0.0; s.n * s.n];
    for i in 0..s.n {
        for j in 0..s.n {
            at[j * s.n + i] = a[i * s.n + j];
        }
    }
    let dp = mix(s, &at, dz, s.h);
    let weight_grad = |input: &[f64], k: usize| {
        let mut dw = vec![0.0; k * s.h];
        for r in 0..input.len() / k {
            for i in 0..k {
                axpy(
                    &mut dw[i * s.h..(i + 1) * s.h],
                    input[r * k + i],
                    &dp[r * s.h..(r + 1) * s.h],
                );
            }
        }
        dw
    };
    grads.add(&name("wx"), &weight_grad(x, s.f));
    grads.add(&name("wh"), &weight_grad(h, s.h));
    let input_grad = |w: &[f64], k: usize| {
        let rows = dp.len() / s.h;
        let mut d = vec![0.0; rows * k];
        for r in 0..rows {
            for i in 0..k {
                d[r * k + i] = w[i * s.h..(i + 1) * s.h]
                    .iter()
                    .zip(&dp[r * s.h..(r + 1) * s.h])
                    .map(|(w, g)| w * g)
                    .sum();
            }
        }
        d
    };
    (
        input_grad(table.get(&name("wx")), s.f),
        input_grad(table.get(&name("wh")), s.h),
    )
}

/// The gradient of [`super::loss`]`(forward(..))` with respect to every parameter (in
/// spec order) and to x, from the tape of [`forward`].
#[allow(clippy::too_many_arguments)]
pub fn backward(
    config: &ModelConfig,
    adjacency: &[f64],
    specs: &[ParamSpec],
    params: &[Vec<f64>],
    tape: &RecurrentTape,
    y: &[f64],
    batch: usize,
    loss: &Loss,
) -> (Vec<Vec<f64>>, Vec<f64>) {
    let s = Shape::of(config, batch);
    let table = Table::new(specs, params);
    let o = config.outputs;
    assert_eq!(tape.batch, batch, "tape of another batch size");
    let mut grads = Grads {
        specs,
        values: specs.iter().map(|s| vec![0.0; s.numel()]).collect(),
    };
    let dout = output_gradient(&tape.output, y, o, batch, loss);
    // Head.
    let nh = s.n * s.h;
    let last = &tape.steps[s.t - 1].h;
    let w = table.get("head.weight");
    let mut dw = vec![0.0; o * nh];
    let mut db = vec![0.0; o];
    let mut dh = vec![0.0; s.b * nh];
    for b in 0..s.b {
        for k in 0..o {
            let g = dout[b * o + k];
            db[k] += g;
            axpy(
                &mut dw[k * nh..(k + 1) * nh],
                g,
                &last[b * nh..(b + 1) * nh],
            );
            axpy(&mut dh[b * nh..(b + 1) * nh], g, &w[k * nh..(k + 1) * nh]);
        }
    }
    grads.add("head.weight", &dw);
    grads.add("head.bias", &db);
    // Through time.
    let mut dx = vec![0.0; s.b * s.n * s.f * s.t];
    let zeros = vec![0.0; s.b * nh];
    for t in (0..s.t).rev() {
        let st = &tape.steps[t];
        let h = if t == 0 { &zeros } else { &tape.steps[t - 1].h };
        let mut dh_prev: Vec<f64> = (0..dh.len()).map(|i| st.u[i] * dh[i]).collect();
        let du: Vec<f64> = (0..dh.len()).map(|i| (h[i] - st.c[i]) * dh[i]).collect();
        let dzc: Vec<f64> = (0..dh.len())
            .map(|i| (1.0 - st.u[i]) * dh[i] * (1.0 - st.c[i] * st.c[i]))
            .collect();
        let rh: Vec<f64> = st.r.iter().zip(h).map(|(r, h)| r * h).collect();
        let (mut dxt, drh) =
            gate_backward(&s, &table, &mut grads, adjacency, "c", (&st.x, &rh), &dzc);
        let mut dzr = vec![0.0; dh.len()];
        for i in 0..dh.len() {
            dh_prev[i] += drh[i] * st.r[i];
            dzr[i] = drh[i] * h[i] * st.r[i] * (1.0 - st.r[i]);
        }
        let dzu: Vec<f64> = (0..dh.len())
            .map(|i| du[i] * st.u[i] * (1.0 - st.u[i]))
            .collect();
        for (g, dz) in [("r", &dzr), ("u", &dzu)] {
            let (dxg, dhg) = gate_backward(&s, &table, &mut grads, adjacency, g, (&st.x, h), dz);
            axpy(&mut dxt, 1.0, &dxg);
            axpy(&mut dh_prev, 1.0, &dhg);
        }
        for (r, v) in dxt.iter().enumerate() {
            dx[r * s.t + t] += v;
        }
        dh = dh_prev;
    }
    add_weight_decay(specs, params, &mut grads.values, loss);
    (grads.values, dx)
}
