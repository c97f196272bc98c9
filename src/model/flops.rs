//! FLOP counts of the network (docs/model.md), per contraction family, for GFLOP/s figures.
//!
//! What is counted: the GEMM-like contractions only, a multiply-add being 2 FLOPs —
//! the attention score products (U1, U2, U3, lhs·rhs, Ve; W1, W2, W3, lhs·rhsᵀ, Vs),
//! the temporal attention application X·E', Ψ = Σ θ_i basis_i, the graph mix Ψ·X_s,
//! the channel mix W, the K-tap causal convolutions (filter and gate), the residual 1×1
//! convolution and the head. Elementwise work (biases, σ, tanh, ReLU, softmax,
//! LayerNorm, dropout, the loss, the causal unfold and the copies) is **not** counted:
//! it is O(B·N·C·T) against the O(B·N·C²·K·T) of the convolutions.
//!
//! The spatial attention's application and the graph mix run as M = Ψ·X_s = Q·X_t with
//! Q = Ψ·(I + S') (`model::block`): the family "sat Q = Psi·S'" counts Ψ·S' (N³ per
//! window) and "gwc mix" the one product Q·X_t, so S'·X_t (N²·C·T) is not computed.
//!
//! The convolutions are counted as the schedule runs them: one dense GEMM over the
//! unfolded input, `[C, C·K] · [C·K, T]` per (b, n), so the taps that fall before t = 0
//! (zeros, docs/model.md step 4) are counted as the GPU multiplies them too. The last block
//! computes its convolutions and residual only at the last step (all the head reads;
//! `model::block`), and is counted so.
//!
//! Training = forward + backward. A contraction's backward computes the gradients with
//! respect to both of its operands, each as costly as the forward, so it costs 2× the
//! forward — everywhere, since the schedule also computes ∂ℒ/∂x of the first block
//! (`Network::input_grad`). The one exception is Ψ = θ·basis, whose basis is a
//! constant: its backward (∂ℒ/∂θ only) costs 1×.

use super::config::{ModelConfig, Variant};

/// One family of contractions: its forward FLOPs and its backward cost in forwards.
struct Family {
    name: &'static str,
    forward: f64,
    backward_factor: f64,
}

/// Family names, in schedule order (every variant lists all of them; absent ones are 0).
pub const FAMILIES: [&str; 12] = [
    "tat scores (U1,U2,U3,lhs·rhs,Ve)",
    "tat apply X·E'",
    "sat scores (W1,W2,W3,lhs·rhsT,Vs)",
    "sat Q = Psi·S'",
    "gwc Psi = theta·basis",
    "gwc mix Psi·X_s",
    "gwc W",
    "tcn filter conv",
    "tcn gate conv",
    "res 1x1 conv",
    "head",
    "dense layers / recurrent cell",
];

fn families(config: &ModelConfig, batch: usize) -> Vec<Family> {
    let f = |x: usize| x as f64;
    let (b, n, t, c, k) = (
        f(batch),
        f(config.nodes),
        f(config.window),
        f(config.channels),
        f(config.kernel),
    );
    let mut sums = [0.0f64; FAMILIES.len()];
    if config.variant.family() == super::config::Family::Recurrent {
        // The GRU's gate products and graph mixes and the head, all in one family.
        sums[11] = super::recurrent::forward_flops(config, batch);
        return named(sums);
    }
    if config.variant.family() == super::config::Family::ConvRecurrent {
        // ConvLSTM's convolution products and the head.
        sums[11] = super::conv_lstm::forward_flops(config, batch);
        return named(sums);
    }
    if let Some(arch) = super::dense::Architecture::of(config) {
        // A dense baseline: its layers (head included) and input selection, nothing else.
        sums[11] = arch.forward_flops(config, batch);
        return named(sums);
    }
    for l in 0..config.blocks {
        let ci = f(config.block_input(l));
        let mut fam = [0.0f64; FAMILIES.len()];
        if config.variant.attention() {
            // xu1 = Σ_n U1·X, lhs = xu1ᵀ·U2, rhs = U3·X, P = lhs·rhs, E = Ve·σ(P + be).
            fam[0] = 2.0 * b * (ci * t * n + t * n * ci + n * t * ci + t * t * n + t * t * t);
            fam[1] = 2.0 * b * n * ci * t * t;
            // xw1 = X_t·W1, lhs = xw1·W2, rhs = W3·X_t, P = lhs·rhsᵀ, S = Vs·σ(P + bs).
            fam[2] = 2.0 * b * (n * ci * t + n * t * ci + n * t * ci + n * n * t + n * n * n);
            fam[3] = 2.0 * b * n * n * n;
        }
        if config.variant.graph_attention() {
            // st-gat: no Ψ; the mix is the graph attention's aggregate Σ_j α_ij q_j over
            // C channels (its scores, O(B·T·N²·C/heads), are not counted).
            fam[5] = 2.0 * b * t * n * n * c;
        } else {
            // Ψ [N, N] from the graph_terms() basis matrices (N wavelets or the Chebyshev
            // order): the same for every batch size.
            fam[4] = 2.0 * f(config.graph_terms()) * n * n;
            fam[5] = 2.0 * b * n * ci * t * n;
        }
        fam[6] = 2.0 * b * n * c * t * ci;
        let steps = if l + 1 == config.blocks { 1.0 } else { t };
        let conv = 2.0 * b * n * c * steps * c * k;
        fam[7] = conv;
        if config.variant.gated() {
            fam[8] = conv;
        }
        fam[9] = 2.0 * b * n * c * steps * ci;
        for (s, v) in sums.iter_mut().zip(fam) {
            *s += v;
        }
    }
    sums[10] = 2.0 * b * f(config.outputs) * n * c;
    named(sums)
}

fn named(sums: [f64; FAMILIES.len()]) -> Vec<Family> {
    FAMILIES
        .iter()
        .zip(sums)
        .enumerate()
        .map(|(i, (&name, forward))| Family {
            name,
            forward,
            backward_factor: if i == 4 { 1.0 } else { 2.0 },
        })
        .collect()
}

/// Forward FLOPs per contraction family ([`FAMILIES`] order) for `batch` windows.
pub fn breakdown(config: &ModelConfig, batch: usize) -> Vec<(&'static str, f64)> {
    families(config, batch)
        .into_iter()
        .map(|f| (f.name, f.forward))
        .collect()
}

/// Training-step (forward + backward) FLOPs per contraction family.
pub fn training_breakdown(config: &ModelConfig, batch: usize) -> Vec<(&'static str, f64)> {
    families(config, batch)
        .into_iter()
        .map(|f| (f.name, f.forward * (1.0 + f.backward_factor)))
        .collect()
}

/// FLOPs of one inference (or training) forward pass over `batch` windows.
pub fn forward_flops(config: &ModelConfig, batch: usize) -> f64 {
    breakdown(config, batch).iter().map(|(_, v)| v).sum()
}

/// FLOPs of one training step without the optimiser: training forward + backward.
pub fn training_flops(config: &ModelConfig, batch: usize) -> f64 {
    training_breakdown(config, batch)
        .iter()
        .map(|(_, v)| v)
        .sum()
}

/// Whether `variant` has any FLOPs in family `name` (for tables that skip empty rows).
pub fn has_family(variant: Variant, name: &str) -> bool {
    let dense = variant.family() != super::config::Family::StBlocks;
    match name {
        "dense layers / recurrent cell" => dense,
        _ if dense => false,
        n if n.starts_with("tat") || n.starts_with("sat") => variant.attention(),
        "tcn gate conv" => variant.gated(),
        "gwc Psi = theta·basis" => !variant.graph_attention(),
        _ => true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// B 2, N 2, F 1, T 3, C 2, L 2, K 2, O 1.
    fn tiny(variant: Variant) -> ModelConfig {
        ModelConfig {
            variant,
            nodes: 2,
            features: 1,
            window: 3,
            channels: 2,
            blocks: 2,
            kernel: 2,
            chebyshev_order: 3,
            outputs: 1,
            ..ModelConfig::default()
        }
    }

    fn family(config: &ModelConfig, name: &str) -> f64 {
        breakdown(config, 2)
            .into_iter()
            .find(|(n, _)| *n == name)
            .unwrap()
            .1
    }

    // Hand count, B = 2, multiply-add = 2.
    // Block 0 (C_in = 1):
    //   tat: U1 2·2·(1·3)·2 = 24, U2 2·2·(3·2)·1 = 24, U3 2·2·(2·3)·1 = 24,
    //        P 2·2·(3·3)·2 = 72, Ve 2·2·27 = 108            → 252; X·E' 2·2·(2·1·3)·3 = 72
    //   sat: W1 24, W2 24, W3 24, P 2·2·(2·2)·3 = 48, Vs 2·2·8 = 32 → 152; Ψ·S' 2·2·8 = 32
    //   Ψ 2·2·4 = 16 (N = 2 wavelets), mix 48, W 2·2·(2·2·3)·1 = 48,
    //   filter 2·2·(2·2·3)·(2·2) = 192, gate 192, res 48     → block 0: 1052
    // Block 1 (C_in = 2, the last: convolutions and residual at the last step only):
    //   tat 48·3 + 72 + 108 = 324, X·E' 144, sat 48·3 + 48 + 32 = 224, Ψ·S' 32, Ψ 16,
    //   mix 96, W 96, filter 2·2·(2·2·1)·(2·2) = 64, gate 64, res 2·2·(2·2·1)·2 = 32
    //   → block 1: 1092
    // Head 2·2·1·(2·2) = 16.
    const FORWARD: f64 = 1052.0 + 1092.0 + 16.0;

    #[test]
    fn tiny_forward_matches_hand_count() {
        let c = tiny(Variant::Iastgcn);
        assert_eq!(forward_flops(&c, 2), 2160.0);
        assert_eq!(FORWARD, 2160.0);
        assert_eq!(
            family(&c, "tat scores (U1,U2,U3,lhs·rhs,Ve)"),
            252.0 + 324.0
        );
        assert_eq!(family(&c, "tat apply X·E'"), 72.0 + 144.0);
        assert_eq!(
            family(&c, "sat scores (W1,W2,W3,lhs·rhsT,Vs)"),
            152.0 + 224.0
        );
        assert_eq!(family(&c, "sat Q = Psi·S'"), 32.0 + 32.0);
        assert_eq!(family(&c, "gwc Psi = theta·basis"), 32.0);
        assert_eq!(family(&c, "gwc mix Psi·X_s"), 48.0 + 96.0);
        assert_eq!(family(&c, "gwc W"), 48.0 + 96.0);
        assert_eq!(family(&c, "tcn filter conv"), 192.0 + 64.0);
        assert_eq!(family(&c, "tcn gate conv"), 192.0 + 64.0);
        assert_eq!(family(&c, "res 1x1 conv"), 48.0 + 32.0);
        assert_eq!(family(&c, "head"), 16.0);
    }

    #[test]
    fn tiny_training_is_three_forwards_but_psi() {
        // Backward 2× everywhere except Ψ (∂θ only): 3·2160 − 32 = 6448.
        assert_eq!(training_flops(&tiny(Variant::Iastgcn), 2), 6448.0);
    }

    #[test]
    fn tiny_variants() {
        // iastgcn-a: no tat/sat (block 0: 508, block 1: 724).
        let a = tiny(Variant::NoAttention);
        assert_eq!(forward_flops(&a, 2), 2160.0 - 508.0 - 724.0);
        assert_eq!(training_flops(&a, 2), 3.0 * 928.0 - 32.0);
        // iastgcn-t: no gate convolution (192 + 64).
        let t = tiny(Variant::PlainTemporal);
        assert_eq!(forward_flops(&t, 2), 2160.0 - 256.0);
        // iastgcn-s: Ψ from 3 Chebyshev terms: 2·3·4 = 24 per block instead of 16.
        let s = tiny(Variant::Chebyshev);
        assert_eq!(forward_flops(&s, 2), 2160.0 + 16.0);
        assert_eq!(training_flops(&s, 2), 3.0 * 2176.0 - 48.0);
        // st-gat: iastgcn-a without Ψ (16 per block), its graph mix the attention's
        // aggregate 2·B·T·N·N·C = 96 per block instead of 48 + 96.
        let g = tiny(Variant::StGat);
        assert_eq!(forward_flops(&g, 2), 928.0 - 32.0 - 144.0 + 192.0);
        for v in Variant::ALL {
            for (name, value) in breakdown(&tiny(v), 2) {
                assert_eq!(value > 0.0, has_family(v, name), "{v} {name}");
            }
        }
    }

    #[test]
    fn dense_baselines() {
        let dense = |variant| ModelConfig {
            hidden: 3,
            ..tiny(variant)
        };
        // mlp: 2→3, 3→3, head 3→1 on B 2: 2·2·(6 + 9 + 3).
        let mlp = dense(Variant::Mlp);
        assert_eq!(forward_flops(&mlp, 2), 72.0);
        assert_eq!(training_flops(&mlp, 2), 216.0);
        assert_eq!(family(&mlp, "dense layers / recurrent cell"), 72.0);
        // erc: the selection [2, 2]·[2, 5] (2·2·2·5 = 40), stem 5→3, two residual
        // blocks of 3→3 twice, head 3→1: 2·2·(15 + 36 + 3) = 216.
        assert_eq!(forward_flops(&dense(Variant::Erc), 2), 256.0);
    }

    #[test]
    fn linear_in_batch_but_psi() {
        let c = ModelConfig::default();
        let psi = 2.0 * 5.0 * 14.0 * 14.0 * 14.0;
        let one = forward_flops(&c, 1) - psi;
        assert_eq!(forward_flops(&c, 64) - psi, 64.0 * one);
        // The paper shape's biggest term: 2 convs × 2·B·N·C·C·K × steps, the steps being
        // T in four blocks and 1 in the last.
        let convs = 2.0 * 2.0 * 64.0 * 14.0 * 64.0 * 64.0 * 3.0 * (4.0 * 100.0 + 1.0);
        let bd = breakdown(&c, 64);
        assert_eq!(bd[7].1 + bd[8].1, convs);
    }
}
