//! The GPU's DFTs (`ops::fft`): the 2-D transform of any side, forward and inverse, against
//! the f64 DFT by its definition, the reference against hand-worked transforms, and the
//! GPU convolution and inverse filter against the dwell solver's f64 `polish::Convolver`.

use iastgcn::gpu::{DType, Recorder};
use iastgcn::ops::fft::{dft2, dft_rows, Convolution, Transform2};
use iastgcn::polish::Convolver;
use iastgcn::testing::{compare, gpu, Tolerance};
use rand::{RngExt, SeedableRng};
use rustfft::num_complex::Complex64;

fn random(len: usize, seed: u64) -> Vec<Complex64> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..len)
        .map(|_| Complex64::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)))
        .collect()
}

/// Real and imaginary parts, interleaved.
fn flat(v: &[Complex64]) -> Vec<f64> {
    v.iter().flat_map(|c| [c.re, c.im]).collect()
}

/// The reference by hand: a delta's transform is all ones, a pure frequency's is a delta
/// of height n at that frequency (exp(+2πi·3k/n) → X[3] = n), and the inverse undoes the
/// forward.
#[test]
fn the_reference_is_the_dft() {
    let n = 7;
    let mut delta = vec![Complex64::default(); n];
    delta[0] = Complex64::new(1.0, 0.0);
    for v in dft_rows(&delta, n, false) {
        assert!((v - Complex64::new(1.0, 0.0)).norm() < 1e-12, "{v}");
    }
    let wave: Vec<Complex64> = (0..n)
        .map(|k| Complex64::from_polar(1.0, std::f64::consts::TAU * 3.0 * k as f64 / n as f64))
        .collect();
    for (j, v) in dft_rows(&wave, n, false).iter().enumerate() {
        let want = if j == 3 { n as f64 } else { 0.0 };
        assert!(
            (v - Complex64::new(want, 0.0)).norm() < 1e-12,
            "X[{j}] = {v}"
        );
    }
    let x = random(25, 1);
    let back = dft2(&dft2(&x, 5, false), 5, true);
    compare(
        "inverse(forward(x))",
        &flat(&back),
        &flat(&x),
        Tolerance::new(1e-12, 0.0),
    )
    .unwrap_or_else(|e| panic!("{e}"));
}

/// Sides that are 1, powers of two, primes and mixed: the GPU's 2-D transform both ways.
#[test]
fn the_gpu_transform_matches_the_reference_at_any_side() {
    let g = gpu();
    for size in [1, 2, 3, 5, 8, 12, 17, 31, 40] {
        let x = random(size * size, size as u64);
        let data = g.zeros("x", &[size * size, 2], DType::F32).unwrap();
        let t = Transform2::new(&g, &data, size).unwrap();
        for inverse in [false, true] {
            let host: Vec<f32> = flat(&x).iter().map(|v| *v as f32).collect();
            g.write(&data, &host).unwrap();
            let mut rec = Recorder::new(&g);
            if inverse {
                t.record_inverse(&mut rec);
            } else {
                t.record_forward(&mut rec);
            }
            rec.submit().unwrap();
            let got: Vec<f64> = g.read_f32(&data).unwrap()[..2 * size * size]
                .iter()
                .map(|v| f64::from(*v))
                .collect();
            let want = flat(&dft2(&x, size, inverse));
            let peak = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let worst = compare(
                &format!(
                    "{} DFT, side {size}",
                    if inverse { "inverse" } else { "forward" }
                ),
                &got,
                &want,
                Tolerance::new(2e-6 * peak, 2e-6),
            )
            .unwrap_or_else(|e| panic!("{e}"));
            eprintln!("side {size}, inverse {inverse}: {worst}");
        }
    }
}

/// The GPU convolution and an inverse filter against `polish::Convolver` (f64, rustfft)
/// on the same map, kernel and factor.
#[test]
fn the_gpu_convolution_matches_the_convolver() {
    let g = std::sync::Arc::new(gpu());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    for (n, reach) in [(20, 3), (33, 5)] {
        let side = 2 * reach + 1;
        // A kernel shaped like a pad's footprint (a bump), a map with structure at all
        // scales.
        let kernel: Vec<f64> = (0..side * side)
            .map(|i| {
                let (r, c) = (
                    (i / side) as f64 - reach as f64,
                    (i % side) as f64 - reach as f64,
                );
                (1.0 - r.hypot(c) / (reach as f64 + 1.0)).max(0.0)
                    + 0.01 * rng.random_range(0.0..1.0)
            })
            .collect();
        let map: Vec<f64> = (0..n * n).map(|_| rng.random_range(-10.0..10.0)).collect();
        let mut cpu = Convolver::new(n, &kernel, reach);
        let mut gpu_conv = Convolution::new(g.clone(), n, cpu.spectrum()).unwrap();
        assert_eq!(gpu_conv.size(), cpu.size());
        let (mut want, mut got) = (vec![0.0; n * n], vec![0.0; n * n]);
        cpu.convolve(&map, &mut want).unwrap();
        gpu_conv.convolve(&map, &mut got).unwrap();
        let peak = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        compare(
            &format!("convolution n = {n}"),
            &got,
            &want,
            Tolerance::new(2e-6 * peak, 2e-6),
        )
        .map(|w| eprintln!("convolution n = {n}: {w}"))
        .unwrap_or_else(|e| panic!("{e}"));
        // The dwell solver's kind of inverse filter: 1/B̂ where |B̂| is large enough.
        let largest = cpu.spectrum().iter().fold(0.0f64, |m, s| m.max(s.norm()));
        let inverse = |s: Complex64, _: usize| {
            if s.norm() >= 0.1 * largest {
                s.inv()
            } else {
                Complex64::default()
            }
        };
        let factor: Vec<Complex64> = cpu
            .spectrum()
            .iter()
            .enumerate()
            .map(|(i, s)| inverse(*s, i))
            .collect();
        cpu.filter(&map, &mut want, inverse).unwrap();
        gpu_conv.filter(&map, &mut got, &factor).unwrap();
        let peak = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        compare(
            &format!("inverse filter n = {n}"),
            &got,
            &want,
            Tolerance::new(2e-6 * peak, 2e-6),
        )
        .map(|w| eprintln!("inverse filter n = {n}: {w}"))
        .unwrap_or_else(|e| panic!("{e}"));
        // And the convolution again after the filter (the spectrum restored).
        cpu.convolve(&map, &mut want).unwrap();
        gpu_conv.convolve(&map, &mut got).unwrap();
        let peak = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        compare(
            "convolution after a filter",
            &got,
            &want,
            Tolerance::new(2e-6 * peak, 2e-6),
        )
        .unwrap_or_else(|e| panic!("{e}"));
    }
}

/// The mirror's dwell solved with the GPU's FFTs plans what the CPU's plans: the same
/// threshold, the seconds and the planned figure within f32's rounding.
#[test]
fn the_dwell_solved_on_the_gpu_matches_the_cpu() {
    use iastgcn::polish::{draw_surface, Polisher, Setup, StartingPoint};
    use iastgcn::twin::PathKind;
    for kind in PathKind::ALL {
        let mut setup = Setup::new(kind);
        setup.pitch = 4.0;
        let mut polisher = Polisher::new(setup).unwrap();
        let start = draw_surface(
            polisher.grid,
            polisher.mirror.radius(),
            &polisher.clear,
            &StartingPoint::default(),
            5,
        );
        let measured = polisher.measure(&start, 2);
        let cpu = polisher.plan_at(&measured, 100.0).unwrap();
        assert_eq!(polisher.solve_device(), "native CPU (f64)");
        polisher
            .solve_with_kernels(Some(std::sync::Arc::new(gpu())))
            .unwrap();
        assert!(polisher.solve_device().ends_with("(WGSL, f32)"));
        let gpu_dwell = polisher.plan_at(&measured, 100.0).unwrap();
        // NaN: no iteration bettered the fastest feed everywhere.
        assert_eq!(
            gpu_dwell.gamma.to_bits(),
            cpu.gamma.to_bits(),
            "{kind:?}: the threshold chosen"
        );
        if kind == PathKind::Grid {
            assert!(cpu.gamma.is_finite(), "the raster's plan iterates");
        }
        let peak = cpu.seconds.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let worst = compare(
            &format!("{kind:?} dwell seconds"),
            &gpu_dwell.seconds,
            &cpu.seconds,
            Tolerance::new(2e-6 * peak, 2e-6),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        eprintln!(
            "{kind:?}: {worst}; planned RMS {} (GPU) against {} nm",
            gpu_dwell.planned.rms, cpu.planned.rms
        );
        assert!(
            (gpu_dwell.planned.rms - cpu.planned.rms).abs() < 1e-5 * cpu.planned.rms,
            "{kind:?}: planned RMS {} against {}",
            gpu_dwell.planned.rms,
            cpu.planned.rms
        );
    }
}
