//! Every engine and kernel against a plain sum, and the engine mode.
#![cfg(test)]

use super::in_place::KC;
use super::*;

/// A deterministic pseudo-random matrix filler.
fn values(len: usize, seed: usize) -> Vec<f32> {
    (0..len)
        .map(|i| (((i * 7919 + seed * 104_729) % 2003) as f32 / 1001.5 - 1.0) * 0.9)
        .collect()
}

/// The instruction sets of the in-place kernels this CPU runs.
fn isas() -> Vec<Isa> {
    let mut isas = vec![Isa::Portable];
    #[cfg(target_arch = "x86_64")]
    {
        if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
            isas.push(Isa::Avx2);
        }
        if is_x86_feature_detected!("avx512f") {
            isas.push(Isa::Avx512);
        }
    }
    isas
}

/// The product by the gemm crate (`None`) or the in-place kernels on `isa`.
#[allow(clippy::too_many_arguments)]
fn product(
    isa: Option<Isa>,
    (m, k, n): (usize, usize, usize),
    a: View,
    b: View,
    beta: f32,
    c: &mut [f32],
    ldc: usize,
) {
    match isa {
        None => gemm(m, k, n, a, b, beta, c, ldc),
        Some(isa) => {
            check_extents((m, k, n), &a, &b, c.len(), ldc);
            // SAFETY: the checks above passed; `isa` is one this CPU runs.
            unsafe { in_place(isa, m, k, n, a, b, beta, Out::rows(c, ldc)) }
        }
    }
}

/// The gemm crate and the in-place kernels of every instruction set this CPU runs
/// against an f64 product, over shapes at and around every edge of the in-place
/// kernels (tiles of 6 × 16 and 6 × 32, panels of 256 steps of k, the dot products,
/// the transposed narrow case), every operand layout, beta 0 (C's old values ignored,
/// even NaN) and 1.
#[test]
fn every_engine_matches_an_f64_product_at_every_edge() {
    let shapes = [
        (1, 1, 1),
        (1, 300, 1),
        (7, 5, 1),
        (1, 9, 33),
        (6, 16, 16),
        (7, 17, 17),
        (13, 257, 3),
        (3, 600, 40),
        (20, 31, 12),
        (64, 100, 48),
    ];
    for (si, &(m, k, n)) in shapes.iter().enumerate() {
        for layout in 0..4 {
            let a_data = values(m * k + 3, si);
            let b_data = values(k * n + 5, si + 17);
            let a = if layout & 1 == 0 {
                rows(&a_data, k)
            } else {
                transposed(&a_data, m)
            };
            let b = if layout & 2 == 0 {
                rows(&b_data, n)
            } else {
                transposed(&b_data, k)
            };
            let ldc = n + 2;
            let old = values(m * ldc, si + 41);
            let engines = std::iter::once(None).chain(isas().into_iter().map(Some));
            for engine in engines {
                for beta in [0.0, 1.0] {
                    let mut c = old.clone();
                    if beta == 0.0 {
                        c.iter_mut().for_each(|v| *v = f32::NAN);
                    }
                    product(engine, (m, k, n), a, b, beta, &mut c, ldc);
                    for i in 0..m {
                        for j in 0..n {
                            let want: f64 = (0..k)
                                .map(|p| {
                                    a.data[i * a.rs + p * a.cs] as f64
                                        * b.data[p * b.rs + j * b.cs] as f64
                                })
                                .sum::<f64>()
                                + beta as f64 * old[i * ldc + j] as f64;
                            let got = c[i * ldc + j] as f64;
                            assert!(
                                (got - want).abs() < 2e-5 * (1.0 + k as f64).sqrt(),
                                "{engine:?} [{m}, {k}, {n}] layout {layout} beta {beta} \
                                 ({i}, {j}): {got} against {want}"
                            );
                        }
                        // The padding between C's rows is never written.
                        for j in n..ldc.min(c.len() - i * ldc) {
                            let was = if beta == 0.0 {
                                f32::NAN
                            } else {
                                old[i * ldc + j]
                            };
                            assert_eq!(c[i * ldc + j].to_bits(), was.to_bits());
                        }
                    }
                }
            }
        }
    }
}

/// The in-place engine's sums follow the documented order: k in order from zero, a
/// fused multiply-add where the CPU has FMA (else a multiply then an add), the running
/// sum added to C every 256 steps.
#[test]
fn the_in_place_sums_follow_their_documented_order() {
    let (m, k, n) = (3, 600, 5);
    let a_data = values(m * k, 3);
    let b_data = values(k * n, 4);
    let old = vec![0.5f32; m * n];
    for isa in isas() {
        let mut c = old.clone();
        let fused = isa != Isa::Portable;
        product(
            Some(isa),
            (m, k, n),
            rows(&a_data, k),
            rows(&b_data, n),
            1.0,
            &mut c,
            n,
        );
        for i in 0..m {
            for j in 0..n {
                let mut want = old[i * n + j];
                for k0 in (0..k).step_by(KC) {
                    let mut s = 0f32;
                    for p in k0..(k0 + KC).min(k) {
                        let (x, y) = (a_data[i * k + p], b_data[p * n + j]);
                        s = if fused { x.mul_add(y, s) } else { s + x * y };
                    }
                    want += s;
                }
                assert_eq!(c[i * n + j].to_bits(), want.to_bits(), "{isa:?} ({i}, {j})");
            }
        }
    }
}

/// The dot-product path's sums follow their documented order: 16 partial sums (k mod
/// 16) of the whole sixteens, added first to last, then the rest of k in order.
#[test]
fn the_in_place_dot_products_follow_their_documented_order() {
    let (m, k, n) = (5, 37, 2);
    let a_data = values(m * k, 5);
    let b_data = values(k * n, 6);
    for isa in isas() {
        let mut c = vec![0f32; m * n];
        // B seen transposed: both operands run along k, and n < 16.
        product(
            Some(isa),
            (m, k, n),
            rows(&a_data, k),
            transposed(&b_data, k),
            0.0,
            &mut c,
            n,
        );
        let fused = isa != Isa::Portable;
        let step = |x: f32, y: f32, s: f32| if fused { x.mul_add(y, s) } else { s + x * y };
        for i in 0..m {
            for j in 0..n {
                let (row, col) = (&a_data[i * k..][..k], &b_data[j * k..][..k]);
                let mut lanes = [0f32; 16];
                for p in 0..32 {
                    lanes[p % 16] = step(row[p], col[p], lanes[p % 16]);
                }
                let mut want: f32 = lanes.iter().sum();
                for p in 32..k {
                    want = step(row[p], col[p], want);
                }
                assert_eq!(c[i * n + j].to_bits(), want.to_bits(), "{isa:?} ({i}, {j})");
            }
        }
    }
}

/// The engine the predictor's forward sets is the one its products run on.
#[test]
fn with_products_routes_gemm_to_the_in_place_kernels() {
    let (m, k, n) = (7, 33, 20);
    let a_data = values(m * k, 8);
    let b_data = values(k * n, 9);
    let mut routed = vec![0f32; m * n];
    with_products(Products::InPlace, || {
        gemm(
            m,
            k,
            n,
            rows(&a_data, k),
            rows(&b_data, n),
            0.0,
            &mut routed,
            n,
        )
    });
    let mut direct = vec![0f32; m * n];
    let isa = Some(Isa::detected());
    product(
        isa,
        (m, k, n),
        rows(&a_data, k),
        rows(&b_data, n),
        0.0,
        &mut direct,
        n,
    );
    assert_eq!(routed, direct);
}

#[test]
fn the_engine_is_restored_after_a_panic() {
    let caught = std::panic::catch_unwind(|| {
        with_products(Products::InPlace, || panic!("inside"));
    });
    assert!(caught.is_err());
    assert_eq!(PRODUCTS.with(|p| p.get()), Products::Packed);
}
