//! Step 1 of docs/model.md, the temporal attention (eq. 35–37): E = Ve·σ((Σ_n U1[n]·X[n])ᵀ·U2
//! · (U3ᵀ·X) + be), E' its softmax over the first time index, X_t = X·(E' + I). Absent in
//! `iastgcn-a` (X_t = X).
//!
//! The contract, per window, on every backend:
//!
//! - reads the block input X `[N, C_in, T]` and `tat.U1` `[N]`, `tat.U2` `[C_in, N]`,
//!   `tat.U3` `[C_in]`, `tat.be` `[T, T]`, `tat.Ve` `[T, T]`;
//! - hands step 2 and step 3 X_t `[N, C_in, T]`, and keeps E' `[T, T]`;
//! - keeps for its backward Σ_n U1[n]·X[n] `[C_in, T]`, lhs `[T, N]`, rhs `[N, T]`,
//!   σ(lhs·rhs + be) `[T, T]` and E' (the device also E, which its softmax's backward
//!   reads);
//! - backward: from dX_t (step 3's term Qᵀ·dM and step 2's, summed) into the five
//!   parameters' gradients and dX, added to what the residual's backward left there.

pub(crate) mod native;
pub(crate) mod reference;
#[cfg(test)]
pub(super) mod tests;
pub(crate) mod wgsl;
