//! Plain f64 reference of the same contract, written from the definition (no strides
//! shared with the GPU path), for tests.

use super::Matmul;

/// Element `(i, kk)` of `op(A)` for batch item `z`.
fn a_at(mm: &Matmul, a: &[f64], z: usize, i: usize, kk: usize) -> f64 {
    let base = if mm.shared_a { 0 } else { z * mm.m * mm.k };
    if mm.trans_a {
        a[base + kk * mm.m + i]
    } else {
        a[base + i * mm.k + kk]
    }
}

/// Element `(kk, j)` of `op(B)`, plus the identity's when `plus_identity`.
fn b_at(mm: &Matmul, b: &[f64], z: usize, kk: usize, j: usize) -> f64 {
    let base = if mm.shared_b { 0 } else { z * mm.k * mm.n };
    let identity = if mm.plus_identity && kk == j {
        1.0
    } else {
        0.0
    };
    identity
        + if mm.trans_b {
            b[base + j * mm.k + kk]
        } else {
            b[base + kk * mm.n + j]
        }
}

/// `C [batch, m, n] = op(A) · op(B)` (plus op(A) when `plus_identity`), from A and B
/// stored as `mm` describes.
pub fn forward(mm: &Matmul, a: &[f64], b: &[f64]) -> Vec<f64> {
    let mut c = vec![0.0; mm.c_len()];
    for z in 0..mm.batch {
        for i in 0..mm.m {
            for j in 0..mm.n {
                let s: f64 = (0..mm.k)
                    .map(|kk| a_at(mm, a, z, i, kk) * b_at(mm, b, z, kk, j))
                    .sum();
                c[(z * mm.m + i) * mm.n + j] = s;
            }
        }
    }
    c
}

/// Returns `(da, db)` for upstream gradient `dc`.
pub fn backward(mm: &Matmul, a: &[f64], b: &[f64], dc: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let mut da = vec![0.0; mm.a_len()];
    let mut db = vec![0.0; mm.b_len()];
    for z in 0..mm.batch {
        let abase = if mm.shared_a { 0 } else { z * mm.m * mm.k };
        let bbase = if mm.shared_b { 0 } else { z * mm.k * mm.n };
        for i in 0..mm.m {
            for kk in 0..mm.k {
                let g: f64 = (0..mm.n)
                    .map(|j| dc[(z * mm.m + i) * mm.n + j] * b_at(mm, b, z, kk, j))
                    .sum();
                let idx = if mm.trans_a {
                    kk * mm.m + i
                } else {
                    i * mm.k + kk
                };
                da[abase + idx] += g;
            }
        }
        for kk in 0..mm.k {
            for j in 0..mm.n {
                let g: f64 = (0..mm.m)
                    .map(|i| a_at(mm, a, z, i, kk) * dc[(z * mm.m + i) * mm.n + j])
                    .sum();
                let idx = if mm.trans_b {
                    j * mm.k + kk
                } else {
                    kk * mm.n + j
                };
                db[bbase + idx] += g;
            }
        }
    }
    (da, db)
}
