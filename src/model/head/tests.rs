//! The head on random cases: the f64 reference's backward against central differences of
//! its forward (and the ST networks' form, which reads the last step of Y_L, against the
//! flat one), then both native forms (one window at a time) and the device's against the
//! reference: ŷ, the weight's and the bias's gradients, and dh, naming the backend.
#![cfg(test)]

use std::collections::BTreeMap;

use super::native;
use super::reference::{flat_head, flat_head_backward, head};
use super::wgsl::Head;
use crate::gpu::{DType, Gpu, Recorder, Tensor};
use crate::model::config::ModelConfig;
use crate::model::exact::Grads;
use crate::model::params::param_specs;
use crate::model::schedule::{ParamTable, Steps};
use crate::testing::{check_gradient, compare, rng, round_f32, to_f32, uniform, Tolerance};

/// f32 sums of a few dozen terms against f64.
const F32: Tolerance = Tolerance {
    abs: 2e-5,
    rel: 2e-4,
};

/// A small ST network's configuration (its head reads N·C = 14·4 features), three windows.
fn config() -> ModelConfig {
    ModelConfig {
        channels: 4,
        window: 6,
        blocks: 1,
        ..ModelConfig::default()
    }
}

struct Case {
    cfg: ModelConfig,
    batch: usize,
    width: usize,
    h: Vec<f64>,
    w: Vec<f64>,
    b: Vec<f64>,
    dout: Vec<f64>,
}

fn case() -> Case {
    let cfg = config();
    let (batch, width, o) = (3, cfg.nodes * cfg.channels, cfg.outputs);
    let mut g = rng(41);
    let mut f32s = |n, lo, hi| round_f32(&uniform(&mut g, n, lo, hi));
    Case {
        h: f32s(batch * width, -1.0, 1.0),
        w: f32s(o * width, -0.3, 0.3),
        b: f32s(o, -0.5, 0.5),
        dout: f32s(batch * o, -1.0, 1.0),
        cfg,
        batch,
        width,
    }
}

/// The reference's (ŷ, dW, db, dh).
fn reference(c: &Case) -> [Vec<f64>; 4] {
    let y = flat_head(&c.w, &c.b, &c.h, c.batch);
    let specs = param_specs(&c.cfg);
    let mut grads = Grads {
        specs: &specs,
        values: specs.iter().map(|s| vec![0.0; s.numel()]).collect(),
    };
    let dh = flat_head_backward(&c.w, &c.h, &c.dout, c.batch, &mut grads);
    let at = |name: &str| specs.iter().position(|s| s.name == name).unwrap();
    let (dw, db) = (
        grads.values[at("head.weight")].clone(),
        grads.values[at("head.bias")].clone(),
    );
    [y, dw, db, dh]
}

fn check(backend: &str, got: &[Vec<f64>; 4], want: &[Vec<f64>; 4]) {
    for (name, (g, w)) in ["ŷ", "d head.weight", "d head.bias", "dh"]
        .iter()
        .zip(got.iter().zip(want))
    {
        compare(&format!("head ({backend}): {name}"), g, w, F32).unwrap();
    }
}

#[test]
fn reference_backward_matches_finite_differences() {
    let c = case();
    let [_, dw, db, dh] = reference(&c);
    let pairing = |y: Vec<f64>| c.dout.iter().zip(&y).map(|(d, v)| d * v).sum::<f64>();
    let tol = Tolerance {
        abs: 1e-7,
        rel: 1e-6,
    };
    let what = "head (reference vs finite differences)";
    let loss_h = |h: &[f64]| pairing(flat_head(&c.w, &c.b, h, c.batch));
    check_gradient(&format!("{what}: dh"), &dh, loss_h, &c.h, 1e-6, tol).unwrap();
    let loss_w = |w: &[f64]| pairing(flat_head(w, &c.b, &c.h, c.batch));
    check_gradient(&format!("{what}: dW"), &dw, loss_w, &c.w, 1e-6, tol).unwrap();
    let loss_b = |b: &[f64]| pairing(flat_head(&c.w, b, &c.h, c.batch));
    check_gradient(&format!("{what}: db"), &db, loss_b, &c.b, 1e-6, tol).unwrap();
    // The ST networks' form reads h at the last step of Y_L [B, N, C, T].
    let t = c.cfg.window;
    let mut y = vec![0.0; c.h.len() * t];
    for (i, &v) in c.h.iter().enumerate() {
        y[i * t + t - 1] = v;
    }
    let st = head(&c.cfg, c.batch, &c.w, &c.b, &y);
    let flat = flat_head(&c.w, &c.b, &c.h, c.batch);
    compare("head (reference): ST form vs flat", &st, &flat, tol).unwrap();
}

#[test]
fn native_forms_match_the_reference() {
    let c = case();
    let want = reference(&c);
    let o = c.cfg.outputs;
    let params = vec![to_f32(&c.w), to_f32(&c.b)];
    type Forward = fn(&[Vec<f32>], (usize, usize), &[f32], &mut [f32]);
    type Backward = fn(&[Vec<f32>], (usize, usize), &[f32], &[f32], &mut [Vec<f32>], &mut [f32]);
    let forms: [(&str, Forward, Backward); 2] = [
        ("native, products", native::forward, native::backward),
        ("native, rows", native::forward_rows, native::backward_rows),
    ];
    for (backend, forward, backward) in forms {
        let mut grads = vec![vec![0.0f32; c.w.len()], vec![0.0f32; o]];
        let (mut y, mut dh) = (Vec::new(), Vec::new());
        for b in 0..c.batch {
            let h = to_f32(&c.h[b * c.width..][..c.width]);
            let dout = to_f32(&c.dout[b * o..][..o]);
            let mut out = vec![0.0f32; o];
            forward(&params, (0, 1), &h, &mut out);
            let mut d = vec![0.0f32; c.width];
            backward(&params, (0, 1), &h, &dout, &mut grads, &mut d);
            y.extend(out);
            dh.extend(d);
        }
        let wide = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<_>>();
        let got = [wide(&y), wide(&grads[0]), wide(&grads[1]), wide(&dh)];
        check(backend, &got, &want);
    }
}

/// The head's two parameters and their gradients on the device, by name.
struct Table(BTreeMap<&'static str, (Tensor, Tensor)>);

impl ParamTable for Table {
    fn param(&self, name: &str) -> &Tensor {
        &self.0[name].0
    }
    fn grad(&self, name: &str) -> &Tensor {
        &self.0[name].1
    }
}

#[test]
fn the_device_matches_the_reference() {
    let c = case();
    let want = reference(&c);
    let o = c.cfg.outputs;
    let gpu = Gpu::new().unwrap_or_else(|e| panic!("{e}"));
    let up = |name: &str, v: &[f64]| gpu.upload(name, &[v.len()], &to_f32(v)).unwrap();
    let zeros = |name: &str, n: usize| gpu.zeros(name, &[n], DType::F32).unwrap();
    let table = Table(BTreeMap::from([
        ("head.weight", (up("W", &c.w), zeros("dW", c.w.len()))),
        ("head.bias", (up("b", &c.b), zeros("db", o))),
    ]));
    let h = gpu.upload("h", &[c.batch, c.width], &to_f32(&c.h)).unwrap();
    let dout = gpu.upload("dout", &[c.batch, o], &to_f32(&c.dout)).unwrap();
    let out = gpu.zeros("y", &[c.batch, o], DType::F32).unwrap();
    let dh = gpu.zeros("dh", &[c.batch, c.width], DType::F32).unwrap();
    let head = Head::new(&c.cfg, c.batch, c.width);
    let mut steps = Steps::default();
    head.forward(&gpu, &table, &h, &out, &mut steps).unwrap();
    head.backward(&gpu, &table, &h, &dout, &dh, &mut steps)
        .unwrap();
    let mut rec = Recorder::new(&gpu);
    steps.record(&mut rec).unwrap();
    rec.submit().unwrap();
    gpu.wait().unwrap();
    let read = |t: &Tensor| -> Vec<f64> {
        gpu.read_f32(t)
            .unwrap()
            .into_iter()
            .map(|x| x as f64)
            .collect()
    };
    let got = [
        read(&out),
        read(table.grad("head.weight")),
        read(table.grad("head.bias")),
        read(&dh),
    ];
    check("wgsl", &got, &want);
}
