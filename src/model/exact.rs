//! The f64 reference's arithmetic (`model::reference`, and the ST block's steps'
//! references in `model::block`): row helpers, parameters looked up by name, gradients
//! accumulated by name, and the backward of the attention scores' gate.

use super::ParamSpec;

/// y += a·x over the common length.
#[inline]
pub(crate) fn axpy(y: &mut [f64], a: f64, x: &[f64]) {
    for (y, x) in y.iter_mut().zip(x) {
        *y += a * x;
    }
}

#[inline]
pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(a, b)| a * b).sum()
}

#[inline]
pub(crate) fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

/// Row `r` of length `len` of a row-major buffer.
#[inline]
pub(crate) fn row(x: &[f64], r: usize, len: usize) -> &[f64] {
    &x[r * len..(r + 1) * len]
}

#[inline]
pub(crate) fn row_mut(x: &mut [f64], r: usize, len: usize) -> &mut [f64] {
    &mut x[r * len..(r + 1) * len]
}

/// Parameters looked up by name (docs/model.md names, `param_specs` order).
#[derive(Clone, Copy)]
pub(crate) struct Table<'a> {
    pub(crate) specs: &'a [ParamSpec],
    pub(crate) values: &'a [Vec<f64>],
}

impl<'a> Table<'a> {
    pub(crate) fn new(specs: &'a [ParamSpec], values: &'a [Vec<f64>]) -> Table<'a> {
        assert_eq!(specs.len(), values.len(), "one value tensor per spec");
        for (s, v) in specs.iter().zip(values) {
            assert_eq!(
                v.len(),
                s.numel(),
                "parameter {} has the wrong size",
                s.name
            );
        }
        Table { specs, values }
    }

    pub(crate) fn get(&self, name: &str) -> &'a [f64] {
        &self.values[index(self.specs, name)]
    }
}

pub(crate) fn index(specs: &[ParamSpec], name: &str) -> usize {
    // invariant: the f64 reference is a test oracle; it looks up the names of param_specs(config).
    specs
        .iter()
        .position(|s| s.name == name)
        .unwrap_or_else(|| panic!("no parameter named {name}"))
}

/// Gradients in spec order, accumulated by name.
pub(crate) struct Grads<'a> {
    pub(crate) specs: &'a [ParamSpec],
    pub(crate) values: Vec<Vec<f64>>,
}

impl Grads<'_> {
    pub(crate) fn add(&mut self, name: &str, g: &[f64]) {
        let slot = &mut self.values[index(self.specs, name)];
        assert_eq!(slot.len(), g.len(), "gradient of {name} has the wrong size");
        axpy(slot, 1.0, g);
    }
}

/// Backward of the attention scores `S[b] = V · σ(P[b] + bias)` (`[len, len]` per batch
/// item, both attentions): returns (dV, dP, dbias) from dS and the saved σ.
pub(crate) fn score_gate_backward(
    v: &[f64],
    sig: &[f64],
    dscores: &[f64],
    nb: usize,
    len: usize,
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let mut dv = vec![0.0; len * len];
    let mut dpre = vec![0.0; nb * len * len];
    for b in 0..nb {
        for i in 0..len {
            let dr = row(dscores, b * len + i, len);
            for k in 0..len {
                dv[i * len + k] += dot(dr, row(sig, b * len + k, len));
                axpy(row_mut(&mut dpre, b * len + k, len), v[i * len + k], dr);
            }
        }
    }
    let mut dbias = vec![0.0; len * len];
    for (dm, sm) in dpre
        .chunks_exact_mut(len * len)
        .zip(sig.chunks_exact(len * len))
    {
        for ((g, s), db) in dm.iter_mut().zip(sm).zip(dbias.iter_mut()) {
            *g *= s * (1.0 - s);
            *db += *g;
        }
    }
    (dv, dpre, dbias)
}
