//! The mirror's starting surface error, seeded: low-order Zernike terms (figure), a
//! mid-spatial-frequency field (periods 8–60 mm, the ripple earlier sub-aperture tools
//! leave) and a few local zones (a pit or bump from an earlier dwell), scaled to the
//! paper's starting point: RMS 13–16 nm and PV 250–280 nm over the clear aperture
//! (docs/polishing.md "The surface").

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rustfft::num_complex::Complex64;

use super::fft::Fft2;
use super::map::{Grid, HeightMap};
use crate::twin::gaussian;

/// What the drawn surface is scaled to, over the clear aperture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StartingPoint {
    /// RMS, nm, drawn uniformly from this range.
    pub rms: [f64; 2],
    /// PV, nm, drawn uniformly from this range.
    pub pv: [f64; 2],
}

impl Default for StartingPoint {
    /// The paper's two mirrors before fine polishing: 277 nm / 13.4 nm and 246 nm /
    /// 15.7 nm (section V, Fig. 14).
    fn default() -> StartingPoint {
        StartingPoint {
            rms: [13.0, 16.0],
            pv: [250.0, 280.0],
        }
    }
}

/// Zernike polynomials (Noll's low orders past piston and tilt) at normalised radius
/// `rho` and angle `theta`.
fn zernike(rho: f64, theta: f64) -> [f64; 8] {
    let r2 = rho * rho;
    [
        2.0 * r2 - 1.0,                       // defocus (power)
        r2 * (2.0 * theta).cos(),             // astigmatism 0°
        r2 * (2.0 * theta).sin(),             // astigmatism 45°
        (3.0 * r2 - 2.0) * rho * theta.cos(), // coma x
        (3.0 * r2 - 2.0) * rho * theta.sin(), // coma y
        r2 * rho * (3.0 * theta).cos(),       // trefoil
        r2 * rho * (3.0 * theta).sin(),       // trefoil
        6.0 * r2 * r2 - 6.0 * r2 + 1.0,       // spherical
    ]
}

/// A zero-mean field over `grid` with spatial periods between `periods` mm, its
/// amplitude falling as 1/f: white noise filtered in the Fourier domain.
fn band_limited(grid: Grid, periods: [f64; 2], rng: &mut ChaCha8Rng) -> Vec<f64> {
    let n = grid.n;
    let mut data: Vec<Complex64> = (0..n * n)
        .map(|_| Complex64::new(gaussian(rng, 1.0), 0.0))
        .collect();
    let mut fft = Fft2::new(n);
    fft.forward(&mut data);
    let extent = n as f64 * grid.pitch;
    let (f_lo, f_hi) = (1.0 / periods[1], 1.0 / periods[0]);
    for r in 0..n {
        for c in 0..n {
            let k = |i: usize| {
                (if i <= n / 2 {
                    i as f64
                } else {
                    i as f64 - n as f64
                }) / extent
            };
            let f = k(r).hypot(k(c));
            let gain = if f >= f_lo && f <= f_hi { 1.0 / f } else { 0.0 };
            data[r * n + c] *= gain;
        }
    }
    fft.inverse(&mut data);
    data.iter().map(|v| v.re).collect()
}

/// Scales `v` to RMS 1 over `inside` (about its mean there).
fn normalised(mut v: Vec<f64>, inside: &[bool]) -> Vec<f64> {
    let (mut n, mut sum) = (0.0, 0.0);
    for (x, _) in v.iter().zip(inside).filter(|(_, &m)| m) {
        n += 1.0;
        sum += x;
    }
    let mean = sum / n;
    let ss: f64 = v
        .iter()
        .zip(inside)
        .filter(|(_, &m)| m)
        .map(|(x, _)| (x - mean).powi(2))
        .sum();
    let s = 1.0 / (ss / n).sqrt().max(1e-300);
    for x in v.iter_mut() {
        *x = (*x - mean) * s;
    }
    v
}

/// The starting surface of surface seed `seed` on `grid`, for glass of radius `glass` mm
/// (zero beyond), scaled to `start` over the pixels `clear` marks. The same seed gives
/// the same surface bit for bit.
pub fn draw(grid: Grid, glass: f64, clear: &[bool], start: &StartingPoint, seed: u64) -> HeightMap {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5355_5246);
    let rms = rng.random_range(start.rms[0]..=start.rms[1]);
    let pv = rng.random_range(start.pv[0]..=start.pv[1]);
    // Figure: Zernike coefficients falling with order.
    let sd = [1.0, 0.8, 0.8, 0.5, 0.5, 0.4, 0.4, 0.5];
    let coef: Vec<f64> = sd.iter().map(|&s| gaussian(&mut rng, s)).collect();
    let mut figure = vec![0.0; grid.len()];
    for r in 0..grid.n {
        for c in 0..grid.n {
            let [x, y] = grid.centre(r, c);
            let rho = x.hypot(y) / glass;
            if rho <= 1.0 {
                let z = zernike(rho, y.atan2(x));
                figure[r * grid.n + c] = z.iter().zip(&coef).map(|(a, b)| a * b).sum();
            }
        }
    }
    let ripple = band_limited(grid, [8.0, 60.0], &mut rng);
    // Local zones: one or two Gaussian pits or bumps, 10–18 mm wide (σ), inside 0.85 of
    // the radius.
    let zones = rng.random_range(1..=2);
    let mut local = vec![0.0; grid.len()];
    for _ in 0..zones {
        let (rad, ang) = (
            0.85 * glass * rng.random_range(0.0f64..1.0).sqrt(),
            rng.random_range(0.0..std::f64::consts::TAU),
        );
        let (cx, cy) = (rad * ang.cos(), rad * ang.sin());
        let width = rng.random_range(10.0..18.0);
        let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        let height = sign * rng.random_range(0.6..1.0);
        for r in 0..grid.n {
            for c in 0..grid.n {
                let [x, y] = grid.centre(r, c);
                let d2 = (x - cx).powi(2) + (y - cy).powi(2);
                local[r * grid.n + c] += height * (-0.5 * d2 / (width * width)).exp();
            }
        }
    }
    let smooth: Vec<f64> = normalised(figure, clear)
        .iter()
        .zip(normalised(ripple, clear))
        .map(|(f, m)| 0.85 * f + 0.5 * m)
        .collect();
    // Piston and tilt out of each part first, so that the sum has none either and the
    // figures scaled to are the ones the interferometer reports.
    let flat = |values: Vec<f64>| {
        let mut m = HeightMap { grid, values };
        m.remove_plane(clear);
        m.values
    };
    let smooth = normalised(flat(smooth), clear);
    let local = flat(local);
    let on_glass = grid.disc(glass);
    // Heights a·smooth + b·local: for each b the RMS fixes a (a quadratic, the smooth
    // part having RMS 1), and the PV rises with b: bisect b for the PV.
    let local = normalised(local, clear);
    let cov = {
        let (mut n, mut sum) = (0.0, 0.0);
        for ((x, y), _) in smooth.iter().zip(&local).zip(clear).filter(|(_, &m)| m) {
            n += 1.0;
            sum += x * y;
        }
        sum / n
    };
    // a² + 2·a·b·cov + b² = rms², the root a ≥ 0 (b ≤ rms).
    let a_for = |b: f64| -b * cov + ((b * cov).powi(2) - b * b + rms * rms).max(0.0).sqrt();
    let compose = |b: f64| {
        let a = a_for(b);
        let values = smooth
            .iter()
            .zip(&local)
            .zip(&on_glass)
            .map(|((s, l), &g)| if g { a * s + b * l } else { 0.0 })
            .collect();
        HeightMap { grid, values }
    };
    let (mut lo, mut hi) = (0.0, rms);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if compose(mid).figure(clear).pv < pv {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let b = 0.5 * (lo + hi);
    compose(b)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The same seed draws the same surface bit for bit; the RMS is the one drawn from
    /// the paper's range, the PV within it where the zones reach it (never above), and
    /// the map carries no piston or tilt.
    #[test]
    fn surfaces_are_seeded_and_scaled() {
        let grid = Grid::covering(276.0, 4.0).unwrap();
        let clear = grid.disc(240.0);
        let start = StartingPoint::default();
        for seed in 1..=4 {
            let a = draw(grid, 255.0, &clear, &start, seed);
            assert_eq!(a, draw(grid, 255.0, &clear, &start, seed));
            let f = a.figure(&clear);
            eprintln!("seed {seed}: {f:?}");
            assert!(
                f.rms >= 13.0 - 1e-6 && f.rms <= 16.0 + 1e-6,
                "seed {seed}: {f:?}"
            );
            assert!(f.pv <= 280.0 + 1e-6 && f.pv >= 125.0, "seed {seed}: {f:?}");
            let mut flat = a.clone();
            flat.remove_plane(&clear);
            let moved = flat
                .values
                .iter()
                .zip(&a.values)
                .zip(&clear)
                .filter(|(_, &c)| c)
                .fold(0.0f64, |m, ((x, y), _)| m.max((x - y).abs()));
            assert!(moved < 1e-6, "seed {seed}: plane of {moved} nm left");
        }
        assert_ne!(
            draw(grid, 255.0, &clear, &start, 1),
            draw(grid, 255.0, &clear, &start, 2)
        );
    }
}
