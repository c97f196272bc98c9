//! The recurrent baselines of Table III (docs/model.md "Baselines"): a GRU whose gates are
//! graph convolutions, run over the window's T steps, then the head. Per step t, with
//! x_t `[B, N, F]` and the graph supports S_0..S_{K−1}:
//!
//! ```text
//! gate(x, h) = Σ_k S_k (x·Wx_k + h·Wh_k) + b
//! r = σ(gate_r(x_t, h))        u = σ(gate_u(x_t, h))        c = tanh(gate_c(x_t, r ⊙ h))
//! h' = u ⊙ h + (1 − u) ⊙ c     (h = 0 before step 0)
//! ```
//!
//! * T-GCN (Zhao et al. [23]): one support, the renormalised adjacency Â; the head reads
//!   the last state h_{T−1}.
//! * EAT-GCN [26]: the Chebyshev polynomials T_0..T_{K−1}(L̃) as supports, and an
//!   attention over the steps: per window, e_t = v · tanh(h_t·Wa + ba) on the flattened
//!   state h_t `[N·H]`, α = softmax_t(e), and the head reads Σ_t α_t h_t.
//!
//! The time loop is one dispatch chain per step, recorded into the same schedule, with
//! every step's state on the device. The backward pass runs through time in reverse:
//! weight gradients accumulate over the steps, and ∂ℒ/∂h ping-pongs between two tensors.
//!
//! This folder holds all of it: the gates' names and supports here, the device schedule
//! and its time loop in `wgsl.rs`, the f64 reference in `reference.rs`, the native f32
//! forward and backward in `native.rs` (tested in tests/model_recurrent.rs and
//! tests/native_*.rs).

pub(crate) mod native;
pub mod reference;
pub(crate) mod wgsl;

use super::config::{ModelConfig, Variant};
use crate::graph::Graph;

/// The gates, in parameter order: reset, update, candidate.
pub const GATES: [&str; 3] = ["r", "u", "c"];

/// True when `variant` weighs every step's state by an attention over time (EAT-GCN);
/// otherwise the head reads the last state (T-GCN).
pub fn attends_over_time(variant: Variant) -> bool {
    variant == Variant::EatGcn
}

/// The graph supports S_k of the gates, `[K, N, N]` row-major f64: Â for T-GCN, the
/// Chebyshev polynomials T_0..T_{K−1}(L̃) (K = `chebyshev_order`) for EAT-GCN.
pub fn supports(graph: &Graph, config: &ModelConfig) -> Vec<f64> {
    let matrices = if attends_over_time(config.variant) {
        graph.spectral().chebyshev(config.chebyshev_order)
    } else {
        vec![graph.renormalized_adjacency()]
    };
    let n = graph.len();
    matrices
        .iter()
        .flat_map(|m| (0..n * n).map(move |i| m[(i / n, i % n)]))
        .collect()
}

/// The name of gate `g`'s weight `kind` (`wx` or `wh`) for support `k` of `terms`:
/// `cell.r.wx` with one support, `cell.r.wx.0`, `cell.r.wx.1`, … with several.
pub fn weight_name(g: &str, kind: &str, k: usize, terms: usize) -> String {
    if terms == 1 {
        format!("cell.{g}.{kind}")
    } else {
        format!("cell.{g}.{kind}.{k}")
    }
}

/// How many graph supports the gates sum over: 1 (T-GCN) or `chebyshev_order` (EAT-GCN).
pub fn support_count(config: &ModelConfig) -> usize {
    if attends_over_time(config.variant) {
        config.chebyshev_order
    } else {
        1
    }
}

/// Forward FLOPs of a recurrent baseline for `batch` windows: per step and gate the two
/// products per support and the graph mixes, the attention over time, then the head.
pub fn forward_flops(config: &ModelConfig, batch: usize) -> f64 {
    let f = |x: usize| x as f64;
    let (b, n, h) = (f(batch), f(config.nodes), f(config.hidden));
    let terms = f(support_count(config));
    // T_0 = I needs no mix; Â does.
    let mixes = if attends_over_time(config.variant) {
        terms - 1.0
    } else {
        1.0
    };
    let per_gate = 2.0 * b * n * h * (terms * (f(config.features) + h) + mixes * n);
    let attention = if attends_over_time(config.variant) {
        // h_t·Wa, ·v and α_t h_t per step.
        2.0 * b * (n * h * h + h + n * h)
    } else {
        0.0
    };
    f(config.window) * (3.0 * per_gate + attention) + 2.0 * b * f(config.outputs) * n * h
}
