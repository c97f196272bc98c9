//! Step 3 of docs/model.md, the graph wavelet convolution (eq. 28–29; the Chebyshev basis
//! in `iastgcn-s`): Ψ = Σ_k θ_k·basis_k, Q = Ψ·(I + S') (Ψ without attention), M = Q·X_t,
//! Z = ReLU(Wᵀ·M) per node. `st-gat` runs its graph attention (`graph_attention/`) in
//! its place.
//!
//! The contract, per window, on every backend:
//!
//! - reads X_t and S' (steps 1 and 2; X without attention), the graph basis
//!   `[terms, N, N]`, `gwc.theta` `[terms]` and `gwc.W` `[C_in, C]`;
//! - hands step 4 Z `[N, C, T]`;
//! - keeps for its backward Ψ, Q `[N, N]`, M `[N, C_in, T]` and Z;
//! - backward: from dG, the gradient past Z's ReLU (step 4's backward applies it), into
//!   d`gwc.theta` and d`gwc.W`, and with attention dS' and dX_t = Qᵀ·dM for steps 2 and
//!   1 (without, Ψᵀ·dM added into dX).
//!
//! The f64 reference takes X_s = (I + S')·X_t from its step 2 and mixes the channels
//! before the nodes: Z = ReLU(Ψ·(X_s·W)) (see `spatial_attention/`).

pub(crate) mod native;
pub(crate) mod reference;
#[cfg(test)]
pub(super) mod tests;
pub(crate) mod wgsl;
