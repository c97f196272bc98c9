//! The tool influence function: Preston's law (removal rate = K · pressure · relative
//! speed) for the twin's orbital pad, the pressure under the pad taken from its true pose
//! (docs/polishing.md "Tool influence function").
//!
//! The pad (radius `R`) is driven on an orbit of radius `e` without turning, so every
//! point of it slides at the same speed `V = 2π·e·n`. A point of the glass at offset `d`
//! from the orbit's centre is under the pad for the part `β/π` of an orbit, with
//! `cos β = (|d|² + e² − R²) / (2·|d|·e)` (β = π within `R − e`, 0 beyond `R + e`). The
//! pressure is linear over the pad, `p(u) = p₀ − g·u` at offset `u` from the pad's centre
//! (a compliant backing of stiffness `k` under a face tilted against the glass: `g = k·a_t`,
//! `a_t` the tool axis's component across the surface normal). Averaged over the orbit
//! the integral of `u` over the arc in contact is closed-form, so the removal rate is
//!
//! ```text
//! rate(d) = K·V·[ p₀·β/π − (g·d)·(β − e·sin β / |d|)/π ]
//! ```
//!
//! `p₀` balances the contact force over the part of the pad on the glass, at every phase
//! of the orbit: where the pad overhangs the rim, the part on the glass is pressed harder
//! and `p₀` changes along the orbit, so the `p₀·β` above becomes its integral over the arc
//! (`ops::removal`; in the manner of Kim & Burge's edge model with the force balanced and
//! the moment taken by the head, which holds the tool's attitude).

use super::map::{Grid, HeightMap};
use crate::ops::removal::{Footprint, Tick};

/// The polishing pad and its removal constants.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Pad {
    /// Pad radius, mm.
    pub radius: f64,
    /// Orbit radius, mm.
    pub orbit_radius: f64,
    /// Orbit speed, revolutions per minute.
    pub orbit_rpm: f64,
    /// Stiffness of the compliant backing, N/mm³ (pressure per mm of compression).
    pub stiffness: f64,
    /// Preston's coefficient K, mm²/N (removal depth per unit pressure and sliding
    /// distance).
    pub preston: f64,
}

impl Default for Pad {
    /// A 30 mm polyurethane pad on a 2 MPa, 10 mm backing, orbiting 6 mm at 300 rpm,
    /// with K set so that one pass at the twin's mean feed (20 mm/s) over its 15 mm
    /// spacing removes about 150 nm, the size of the figure error it is to correct
    /// (docs/polishing.md).
    fn default() -> Pad {
        Pad {
            radius: 15.0,
            orbit_radius: 6.0,
            orbit_rpm: 300.0,
            stiffness: 0.2,
            preston: 2.4e-6,
        }
    }
}

/// How the pad is pressed at one instant: the contact force and the pressure's gradient
/// across the pad (`p(u) = p₀ − gradient·u`, p₀ the force over the part of the pad on
/// the glass, [`Footprint::centre_pressure`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Contact {
    /// The contact force, N.
    pub force: f64,
    /// The pressure's gradient across the pad in the map's xy plane, N/mm³.
    pub gradient: [f64; 2],
}

impl Pad {
    /// How far from the orbit's centre the pad reaches, mm.
    pub fn reach(&self) -> f64 {
        self.radius + self.orbit_radius
    }

    /// The sliding speed of every point of the pad, mm/s.
    pub fn speed(&self) -> f64 {
        std::f64::consts::TAU * self.orbit_radius * self.orbit_rpm / 60.0
    }

    /// The pad's area, mm².
    pub fn area(&self) -> f64 {
        std::f64::consts::PI * self.radius * self.radius
    }

    /// The contact of the pad pressed with `force` N, its face tilted by `tilt` (the tool
    /// axis's component across the surface normal, rad, in the map's plane): the tilt's
    /// gradient `k·tilt`, limited so that the pad's rim never lifts off the glass where
    /// the whole pad is on it (`|g|·R ≤ F/(πR²)`).
    pub fn contact(&self, tilt: [f64; 2], force: f64) -> Contact {
        let mean = force.max(0.0) / self.area();
        let mut gradient = [self.stiffness * tilt[0], self.stiffness * tilt[1]];
        let size = gradient[0].hypot(gradient[1]) * self.radius;
        if size > mean {
            let s = mean / size;
            gradient = [gradient[0] * s, gradient[1] * s];
        }
        Contact { force, gradient }
    }

    /// The pad as the removal sees it on a disc of glass of radius `glass` mm
    /// (`ops::removal`, which holds the removal's arithmetic for the native path and the
    /// WGSL kernel alike; `f64::INFINITY`: no rim).
    pub fn footprint(&self, glass: f64) -> Footprint {
        Footprint {
            radius: self.radius,
            orbit: self.orbit_radius,
            preston: self.preston,
            speed: self.speed(),
            glass,
        }
    }

    /// The removal rate, nm/s, at offset `(dx, dy)` mm from the orbit's centre under
    /// `contact`, clear of any rim ([`Footprint::rate`]).
    pub fn rate(&self, contact: &Contact, dx: f64, dy: f64) -> f64 {
        let footprint = self.footprint(f64::INFINITY);
        let tick = self.tick([0.0, 0.0], contact, 1.0);
        footprint.rate(&tick, footprint.orbit_pressure(&tick), dx, dy)
    }

    /// One control tick's removal: `seconds` at orbit centre `centre` (mm) under `contact`.
    pub fn tick(&self, centre: [f64; 2], contact: &Contact, seconds: f64) -> Tick {
        Tick {
            centre,
            force: contact.force,
            gradient: contact.gradient,
            seconds,
        }
    }

    /// Removes `seconds` of the pad's removal at orbit centre `centre` (mm) from `map`,
    /// on the pixels `on_glass` marks, the glass a disc of radius `glass` mm
    /// ([`Footprint::remove_tick`]).
    pub fn remove(
        &self,
        map: &mut HeightMap,
        on_glass: &[bool],
        glass: f64,
        centre: [f64; 2],
        contact: &Contact,
        seconds: f64,
    ) {
        let g = map.grid;
        self.footprint(glass).remove_tick(
            g.n,
            g.pitch,
            on_glass,
            &self.tick(centre, contact, seconds),
            &mut map.values,
        );
    }

    /// The nominal influence function on `grid`'s pixels (square, side `2·reach + 1`,
    /// centred) for a pad pressed with `force` N square to the glass, as depth removed
    /// (nm) per unit dwell density (s/mm²): the rate times the pixel's area. Returns the
    /// kernel and its half-width `reach` in pixels.
    pub fn kernel(&self, grid: Grid, force: f64) -> (Vec<f64>, usize) {
        let reach = (self.reach() / grid.pitch).ceil() as usize;
        let side = 2 * reach + 1;
        let contact = Contact {
            force,
            gradient: [0.0, 0.0],
        };
        let area = grid.pitch * grid.pitch;
        let mut k = Vec::with_capacity(side * side);
        for r in 0..side {
            for c in 0..side {
                let dx = (c as f64 - reach as f64) * grid.pitch;
                let dy = (r as f64 - reach as f64) * grid.pitch;
                k.push(self.rate(&contact, dx, dy) * area);
            }
        }
        (k, reach)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The closed form against the orbit averaged by brute force: the pad's pressure
    /// integrated over many orbit positions.
    #[test]
    fn rate_matches_the_orbit_average() {
        let pad = Pad::default();
        let contact = Contact {
            force: 0.08 * pad.area(),
            gradient: [3e-4, -2e-4],
        };
        let mean = 0.08;
        let steps = 200_000;
        for &(dx, dy) in &[
            (0.0, 0.0),
            (5.0, 3.0),
            (-11.0, 4.0),
            (16.0, -10.0),
            (0.0, 26.5),
        ] {
            let mut sum = 0.0;
            for k in 0..steps {
                let phi = std::f64::consts::TAU * (k as f64 + 0.5) / steps as f64;
                let (ux, uy) = (
                    dx - pad.orbit_radius * phi.cos(),
                    dy - pad.orbit_radius * phi.sin(),
                );
                if ux.hypot(uy) < pad.radius {
                    sum += mean - contact.gradient[0] * ux - contact.gradient[1] * uy;
                }
            }
            let want = pad.preston * pad.speed() * sum / steps as f64 * 1e6;
            let got = pad.rate(&contact, dx, dy);
            assert!(
                (got - want).abs() <= 1e-3 * want.abs().max(1e-3),
                "({dx}, {dy}): {got} against {want}"
            );
        }
    }

    /// The removal volume is Preston's K·V·F whatever the tilt (the gradient's moment
    /// integrates to zero), and the tilt moves the footprint's centroid against it.
    #[test]
    fn volume_is_kvf_and_tilt_moves_the_centroid() {
        let pad = Pad::default();
        let grid = Grid { n: 200, pitch: 0.5 };
        let on_glass = vec![true; grid.len()];
        for tilt in [[0.0, 0.0], [2e-3, 0.0]] {
            let contact = pad.contact(tilt, 100.0);
            let mut map = HeightMap::zeros(grid);
            pad.remove(
                &mut map,
                &on_glass,
                f64::INFINITY,
                [0.0, 0.0],
                &contact,
                1.0,
            );
            let (mut vol, mut mx) = (0.0, 0.0);
            for r in 0..grid.n {
                for c in 0..grid.n {
                    let d = -map.values[r * grid.n + c] * 1e-6 * grid.pitch * grid.pitch;
                    vol += d;
                    mx += d * grid.centre(r, c)[0];
                }
            }
            let kvf = pad.preston * pad.speed() * 100.0;
            assert!((vol - kvf).abs() < 2e-3 * kvf, "volume {vol} against {kvf}");
            let centroid = mx / vol;
            if tilt[0] == 0.0 {
                assert!(centroid.abs() < 1e-6, "square pad centroid {centroid}");
            } else {
                // Linear pressure over a disc moves the centroid by −g·R²/(4·p₀) for a
                // still pad; the orbit spreads it further out, at the same shift.
                let want =
                    -contact.gradient[0] * pad.radius.powi(2) / (4.0 * contact.force / pad.area());
                assert!(
                    (centroid - want).abs() < 0.02 * want.abs(),
                    "tilted centroid {centroid} against {want}"
                );
            }
        }
    }

    /// The removal moves with the pad: dwell points moved by a pixel give the map moved
    /// by a pixel (so a pose offset `d` changes the glass by `R(x − d) − R(x) ≈ −d·∇R`,
    /// the rule docs/polishing.md builds on), and a tilt changes no volume.
    #[test]
    fn removal_moves_with_the_pad() {
        let pad = Pad::default();
        let grid = Grid { n: 160, pitch: 0.5 };
        let on_glass = vec![true; grid.len()];
        let contact = pad.contact([1e-3, -2e-3], 100.0);
        let walk = |d: f64| {
            let mut map = HeightMap::zeros(grid);
            for i in -4..=4 {
                for j in -4..=4 {
                    let (x, y) = (3.0 * i as f64 + 0.2, 3.0 * j as f64 - 0.1);
                    let seconds = 1.0 + 0.04 * x + 0.01 * y;
                    pad.remove(
                        &mut map,
                        &on_glass,
                        f64::INFINITY,
                        [x + d, y],
                        &contact,
                        seconds,
                    );
                }
            }
            map
        };
        let (base, moved) = (walk(0.0), walk(grid.pitch));
        for r in 0..grid.n {
            for c in 1..grid.n {
                let (a, b) = (
                    moved.values[r * grid.n + c],
                    base.values[r * grid.n + c - 1],
                );
                assert!(
                    (a - b).abs() < 1e-9 * a.abs().max(1.0),
                    "({r}, {c}): {a} against {b}"
                );
            }
        }
    }

    /// The other rule docs/polishing.md uses: a fast random position error of SD σ on
    /// every dwell point scales a removal pattern of spatial frequency f by
    /// exp(−2π²σ²f²) (the removal is convolved with the jitter's Gaussian).
    #[test]
    fn jitter_scales_each_frequency_by_its_gaussian() {
        use rand::SeedableRng;
        let pad = Pad::default();
        let grid = Grid { n: 128, pitch: 1.0 };
        let on_glass = vec![true; grid.len()];
        let contact = pad.contact([0.0, 0.0], 100.0);
        let period = 20.0;
        let k = std::f64::consts::TAU / period;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        // Dwell points every mm over the map, their seconds a sinusoid along x, each
        // visited 12 times with its own jitter (an average over visits, so that the
        // sampling noise of the pad's sharp rim stays below the effect).
        let visits = 12;
        let walk = |sigma: f64, rng: &mut rand_chacha::ChaCha8Rng| {
            let mut map = HeightMap::zeros(grid);
            for i in -64..64 {
                for j in -64..64 {
                    let (x, y) = (i as f64 + 0.5, j as f64 + 0.5);
                    let seconds = 0.02 * (1.0 + 0.5 * (k * x).sin()) / visits as f64;
                    for _ in 0..visits {
                        let (dx, dy) = (
                            crate::twin::gaussian(rng, sigma),
                            crate::twin::gaussian(rng, sigma),
                        );
                        pad.remove(
                            &mut map,
                            &on_glass,
                            f64::INFINITY,
                            [x + dx, y + dy],
                            &contact,
                            seconds,
                        );
                    }
                }
            }
            map
        };
        // The pattern's amplitude at frequency 1/period over three periods at the centre.
        let amplitude = |m: &HeightMap| {
            let (mut s, mut c, mut n) = (0.0, 0.0, 0.0);
            for r in 34..94 {
                for col in 34..94 {
                    let [x, _] = grid.centre(r, col);
                    let v = m.values[r * grid.n + col];
                    s += v * (k * x).sin();
                    c += v * (k * x).cos();
                    n += 1.0;
                }
            }
            2.0 * (s * s + c * c).sqrt() / n
        };
        let sigma = 2.0;
        let (still, jittered) = (walk(0.0, &mut rng), walk(sigma, &mut rng));
        let ratio = amplitude(&jittered) / amplitude(&still);
        let want = (-2.0 * std::f64::consts::PI.powi(2) * sigma * sigma / (period * period)).exp();
        assert!(
            (ratio - want).abs() < 0.03,
            "jitter σ = {sigma} mm at a {period} mm period: ratio {ratio}, the rule says {want}"
        );
    }

    /// The part of the pad on the glass, in closed form, against the pad's disc summed
    /// on a fine lattice: its area and first moment, on the glass, astride the rim and
    /// mostly off it.
    #[test]
    fn the_part_on_the_glass_matches_a_lattice_sum() {
        use crate::ops::removal::on_glass;
        let (a, big) = (15.0, 255.0);
        let steps = 1500;
        let h = 2.0 * a / steps as f64;
        for p in [
            [0.0, 0.0],
            [230.0, 0.0],
            [176.0, 176.0],
            [-250.0, 9.0],
            [0.0, -262.0],
        ] {
            let (mut area, mut m) = (0.0, [0.0, 0.0]);
            for i in 0..steps {
                for j in 0..steps {
                    let (u, v) = (-a + (i as f64 + 0.5) * h, -a + (j as f64 + 0.5) * h);
                    if u.hypot(v) < a && (p[0] + u).hypot(p[1] + v) < big {
                        area += h * h;
                        m[0] += u * h * h;
                        m[1] += v * h * h;
                    }
                }
            }
            let (got, s) = on_glass(a, p, big);
            let full = std::f64::consts::PI * a * a;
            assert!(
                (got - area).abs() < 2e-4 * full,
                "{p:?}: area {got} against {area}"
            );
            for k in 0..2 {
                assert!(
                    (s[k] - m[k]).abs() < 2e-4 * full * a,
                    "{p:?}: moment {s:?} against {m:?}"
                );
            }
        }
        assert_eq!(on_glass(a, [0.0, 300.0], big).0, 0.0);
    }

    /// Near the rim the rate's quadrature over the arc against the orbit averaged by
    /// brute force (200 000 phases, the pad's part on the glass at each): a tilted pad
    /// whose orbit crosses the rim, at points on and beyond its footprint.
    #[test]
    fn rate_at_the_rim_matches_the_orbit_average() {
        let pad = Pad::default();
        let big = 255.0;
        let footprint = pad.footprint(big);
        let contact = pad.contact([2e-3, -1e-3], 90.0);
        let steps = 200_000;
        for centre in [[240.0, 0.0], [0.0, -246.0], [170.0, 175.0]] {
            let tick = pad.tick(centre, &contact, 1.0);
            assert!(footprint.touches_rim(centre));
            let mean = footprint.orbit_pressure(&tick);
            let mut peak = 0.0f64;
            let mut worst = 0.0f64;
            for &(dx, dy) in &[
                (0.0, 0.0),
                (5.0, 3.0),
                (-11.0, 4.0),
                (12.0, -10.0),
                (-3.0, 18.5),
                (19.0, 2.0),
                (6.0, -16.0),
            ] {
                let mut sum = 0.0;
                for k in 0..steps {
                    let phi = std::f64::consts::TAU * (k as f64 + 0.5) / steps as f64;
                    let (ox, oy) = (pad.orbit_radius * phi.cos(), pad.orbit_radius * phi.sin());
                    let (ux, uy) = (dx - ox, dy - oy);
                    if ux.hypot(uy) < pad.radius {
                        let p0 = footprint.centre_pressure(&tick, [centre[0] + ox, centre[1] + oy]);
                        sum += p0 - contact.gradient[0] * ux - contact.gradient[1] * uy;
                    }
                }
                let want = pad.preston * pad.speed() * sum / steps as f64 * 1e6;
                let got = footprint.rate(&tick, mean, dx, dy);
                peak = peak.max(want.abs());
                worst = worst.max((got - want).abs());
            }
            assert!(
                worst < 1e-4 * peak,
                "{centre:?}: worst {worst} of {peak} nm/s"
            );
        }
    }

    /// Where the pad overhangs the rim, the whole force still presses on the glass: the
    /// volume removed from the glass is Preston's K·V·F, tilted or not, and the depth
    /// under the overhanging pad is larger than clear of the rim.
    #[test]
    fn at_the_rim_the_force_removes_kvf_from_the_glass() {
        let pad = Pad::default();
        let grid = Grid {
            n: 720,
            pitch: 0.25,
        };
        let big = 80.0;
        let on_glass = grid.disc(big);
        let kvf = pad.preston * pad.speed() * 100.0;
        let depth = |map: &HeightMap, x: f64| {
            let (r, c) = (
                grid.n / 2,
                ((x / grid.pitch) + 0.5 * grid.n as f64) as usize,
            );
            -map.values[r * grid.n + c]
        };
        let mut clear = HeightMap::zeros(grid);
        pad.remove(
            &mut clear,
            &on_glass,
            big,
            [0.0, 0.0],
            &pad.contact([0.0, 0.0], 100.0),
            1.0,
        );
        for (centre, tilt) in [
            ([70.0, 0.0], [0.0, 0.0]),
            ([75.0, 0.0], [3e-3, 1e-3]),
            ([0.0, 80.0], [-2e-3, 2e-3]),
        ] {
            let contact = pad.contact(tilt, 100.0);
            let mut map = HeightMap::zeros(grid);
            pad.remove(&mut map, &on_glass, big, centre, &contact, 1.0);
            let vol: f64 = map
                .values
                .iter()
                .map(|v| -v * 1e-6 * grid.pitch * grid.pitch)
                .sum();
            assert!(
                (vol - kvf).abs() < 5e-3 * kvf,
                "{centre:?}: volume {vol} against {kvf}"
            );
            if centre[1] == 0.0 {
                let (at, inside) = (depth(&map, centre[0]), depth(&clear, 0.0));
                assert!(
                    at > 1.02 * inside,
                    "{centre:?}: {at} nm against {inside} clear of the rim"
                );
            }
        }
    }
}
