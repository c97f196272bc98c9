//! The f64 reference of the ConvLSTM baseline (`model::conv_lstm`, docs/model.md
//! "Baselines"): the time loop keeping every step's gates, cell and state, and
//! backpropagation through time by hand, on the ops' own references
//! (`ops::unfold2d::cpu`, `ops::lstm::cpu`). The loss is [`crate::model::reference::loss`].

use crate::model::exact::{axpy, Grads, Table};
use crate::model::head::reference::{flat_head, flat_head_backward};
use crate::model::reference::{add_weight_decay, output_gradient, Loss};
use crate::model::{ModelConfig, ParamSpec};
use crate::ops::lstm::{cpu as lstm, Lstm};
use crate::ops::unfold2d::{cpu as unfold, Unfold2d};

/// One step's values.
#[derive(Clone, Debug)]
pub struct ConvStepTape {
    /// x_t `[B, 1, N, F]`.
    pub x: Vec<f64>,
    /// The gates' pre-activations `[B, 4C, N·F]`.
    pub z: Vec<f64>,
    /// The cell c_t `[B, C, N, F]`.
    pub c: Vec<f64>,
    /// The state h_t `[B, C, N, F]`.
    pub h: Vec<f64>,
}

/// Everything the forward pass of ConvLSTM computed.
#[derive(Clone, Debug)]
pub struct ConvLstmTape {
    /// B: windows in the batch.
    pub batch: usize,
    /// One entry per time step.
    pub steps: Vec<ConvStepTape>,
    /// ŷ `[B, O]`.
    pub output: Vec<f64>,
}

struct Shape {
    b: usize,
    /// N·F: the grid's cells.
    grid: usize,
    c: usize,
    t: usize,
    x: Unfold2d,
    h: Unfold2d,
    cell: Lstm,
}

impl Shape {
    fn of(config: &ModelConfig, batch: usize) -> Shape {
        let unfold = |channels| Unfold2d {
            batch,
            channels,
            height: config.nodes,
            width: config.features,
            kernel: config.kernel,
        };
        let grid = config.nodes * config.features;
        Shape {
            b: batch,
            grid,
            c: config.channels,
            t: config.window,
            x: unfold(1),
            h: unfold(config.channels),
            cell: Lstm {
                batch,
                state: config.channels * grid,
            },
        }
    }
}

/// `z[b] += W [4C, R] · col[b] [R, N·F]`.
fn conv(s: &Shape, w: &[f64], col: &[f64], z: &mut [f64]) {
    let rows = w.len() / (4 * s.c);
    for b in 0..s.b {
        for o in 0..4 * s.c {
            let out = &mut z[(b * 4 * s.c + o) * s.grid..(b * 4 * s.c + o + 1) * s.grid];
            for r in 0..rows {
                let src = &col[(b * rows + r) * s.grid..(b * rows + r + 1) * s.grid];
                axpy(out, w[o * rows + r], src);
            }
        }
    }
}

/// (∂ℒ/∂W, ∂ℒ/∂col) of [`conv`] from ∂ℒ/∂z.
fn conv_backward(s: &Shape, w: &[f64], col: &[f64], dz: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let rows = w.len() / (4 * s.c);
    let mut dw = vec![0.0; w.len()];
    let mut dcol = vec![0.0; col.len()];
    for b in 0..s.b {
        for o in 0..4 * s.c {
            let g = &dz[(b * 4 * s.c + o) * s.grid..(b * 4 * s.c + o + 1) * s.grid];
            for r in 0..rows {
                let k = (b * rows + r) * s.grid;
                dw[o * rows + r] += g
                    .iter()
                    .zip(&col[k..k + s.grid])
                    .map(|(g, c)| g * c)
                    .sum::<f64>();
                axpy(&mut dcol[k..k + s.grid], w[o * rows + r], g);
            }
        }
    }
    (dw, dcol)
}

/// The forward pass on `x` `[B, N, F, T]`.
pub fn forward(
    config: &ModelConfig,
    specs: &[ParamSpec],
    params: &[Vec<f64>],
    x: &[f64],
    batch: usize,
) -> ConvLstmTape {
    let s = Shape::of(config, batch);
    let table = Table::new(specs, params);
    let cells = s.b * s.grid;
    assert_eq!(x.len(), cells * s.t, "x is [B,N,F,T]");
    let (wx, wh, bias) = (
        table.get("cell.wx"),
        table.get("cell.wh"),
        table.get("cell.bias"),
    );
    let state = s.b * s.c * s.grid;
    let (mut h, mut c) = (vec![0.0; state], vec![0.0; state]);
    let mut steps = Vec::with_capacity(s.t);
    for t in 0..s.t {
        let xt: Vec<f64> = (0..cells).map(|r| x[r * s.t + t]).collect();
        let mut z = vec![0.0; 4 * state];
        conv(&s, wx, &unfold::forward(&s.x, &xt), &mut z);
        conv(&s, wh, &unfold::forward(&s.h, &h), &mut z);
        for (i, v) in z.iter_mut().enumerate() {
            *v += bias[(i / s.grid) % (4 * s.c)];
        }
        (c, h) = lstm::forward(&s.cell, &z, &c);
        steps.push(ConvStepTape {
            x: xt,
            z,
            c: c.clone(),
            h: h.clone(),
        });
    }
    let output = flat_head(table.get("head.weight"), table.get("head.bias"), &h, s.b);
    ConvLstmTape {
        batch,
        steps,
        output,
    }
}

/// The gradient of [`crate::model::reference::loss`]`(forward(..))` with respect to every parameter (in
/// spec order) and to x, from the tape of [`forward`].
pub fn backward(
    config: &ModelConfig,
    specs: &[ParamSpec],
    params: &[Vec<f64>],
    tape: &ConvLstmTape,
    y: &[f64],
    batch: usize,
    loss: &Loss,
) -> (Vec<Vec<f64>>, Vec<f64>) {
    let s = Shape::of(config, batch);
    let table = Table::new(specs, params);
    assert_eq!(tape.batch, batch, "tape of another batch size");
    let mut grads = Grads {
        specs,
        values: specs.iter().map(|s| vec![0.0; s.numel()]).collect(),
    };
    let o = config.outputs;
    let dout = output_gradient(&tape.output, y, o, batch, loss);
    // Head.
    let m = s.c * s.grid;
    let last = &tape.steps[s.t - 1].h;
    let mut dh = flat_head_backward(table.get("head.weight"), last, &dout, s.b, &mut grads);
    // Through time.
    let (wx, wh) = (table.get("cell.wx"), table.get("cell.wh"));
    let cells = s.b * s.grid;
    let mut dx = vec![0.0; cells * s.t];
    let mut dc = vec![0.0; s.b * m];
    let zeros = vec![0.0; s.b * m];
    for t in (0..s.t).rev() {
        let st = &tape.steps[t];
        let (h, c) = match t {
            0 => (&zeros, &zeros),
            _ => (&tape.steps[t - 1].h, &tape.steps[t - 1].c),
        };
        let (dz, dc_prev) = lstm::backward(&s.cell, &st.z, c, &dh, &dc);
        let mut dbias = vec![0.0; 4 * s.c];
        for (i, g) in dz.iter().enumerate() {
            dbias[(i / s.grid) % (4 * s.c)] += g;
        }
        grads.add("cell.bias", &dbias);
        let (dwx, dcol_x) = conv_backward(&s, wx, &unfold::forward(&s.x, &st.x), &dz);
        grads.add("cell.wx", &dwx);
        for (r, v) in unfold::backward(&s.x, &dcol_x).iter().enumerate() {
            dx[r * s.t + t] += v;
        }
        let (dwh, dcol_h) = conv_backward(&s, wh, &unfold::forward(&s.h, h), &dz);
        grads.add("cell.wh", &dwh);
        dh = unfold::backward(&s.h, &dcol_h);
        dc = dc_prev;
    }
    add_weight_decay(specs, params, &mut grads.values, loss);
    (grads.values, dx)
}
