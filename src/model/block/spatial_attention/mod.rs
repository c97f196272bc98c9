//! Step 2 of docs/model.md, the spatial attention (eq. 32–34): S = Vs·σ((X_t·W1)·W2 ·
//! (W3ᵀ·X_t)ᵀ + bs), S' its softmax over nodes. Absent in `iastgcn-a`.
//!
//! The contract, per window, on every backend:
//!
//! - reads X_t `[N, C_in, T]` (step 1's) and `sat.W1` `[T]`, `sat.W2` `[C_in, T]`,
//!   `sat.W3` `[C_in]`, `sat.bs` `[N, N]`, `sat.Vs` `[N, N]`;
//! - hands step 3 S' `[N, N]` (step 3 mixes the nodes with it: Q = Ψ·(I + S'));
//! - keeps for its backward X_t·W1 `[N, C_in]`, lhs `[N, T]`, rhs `[N, T]`,
//!   σ(lhs·rhsᵀ + bs) `[N, N]` and S' (the device also S);
//! - backward: from dS' (step 3's) into the five parameters' gradients, and its two
//!   rank-1 terms of dX_t *added* to dX_t, which step 3's backward started with Qᵀ·dM.
//!
//! The f64 reference block cuts steps 2 and 3 one product apart: its step 2 hands on
//! X_s = (I + S')·X_t and takes dX_s. Its backward is the node mixing's
//! (`reference::node_mix_backward`) and then the attention's from dS'
//! (`reference::weights_backward`), which is step 2 as the implementations cut it and
//! what `tests.rs` checks them against.

pub(crate) mod native;
pub(crate) mod reference;
#[cfg(test)]
pub(super) mod tests;
pub(crate) mod wgsl;
