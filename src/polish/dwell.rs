//! Dwell time: how long the pad stays on each stretch of the path so that its removal
//! (the nominal influence function, laid along the path) best matches the measured
//! error, within the machine's feed limits (docs/polishing.md "Dwell time").
//!
//! The unknowns are the seconds spent on each segment of the path, as UDO (T. Wang et
//! al., Opt. Express 29, 38737, 2021) puts its dwell points on the path itself: a
//! raster or spiral realises a dwell map only along its passes, and a path that crowds
//! (a raster's turns along the rim, a spiral's outer arms) gives more dwell there
//! whatever the plan. The segments' time is laid into the map ([`PathRaster`]), the
//! removal is that map convolved with the influence function (by FFT), and projected
//! iterations in the manner of RIFTA (T. Wang et al., Sci. Rep. 10, 8135, 2020) reduce
//! the residual on the glass: a thresholded FFT inverse filter (`1/B̂` where
//! `|B̂| ≥ γ·max|B̂|` and below the passes' Nyquist frequency, 0 elsewhere) turns the
//! residual into a dwell correction, read back along the path and clipped to the feed
//! limits. γ is chosen from a few values, and the iterate kept, by the RMS it leaves over
//! the clear aperture, as RIFTA chooses its threshold. The wanted removal is the
//! measured error less its lowest point, plus the least layer that the fastest feed
//! everywhere still removes: the piston is free, and the path and the feed limit set it.
//!
//! Near the rim part of the pad hangs over the edge and the force presses the rest
//! harder (`Pad::contact`): a dwell's removal there is the kernel times its `gain` (the
//! pad's area over its area on the glass).

use rustfft::num_complex::Complex64;

use super::fft::Convolver;
use super::map::{Figure, Grid, HeightMap};
use crate::error::{ensure, Result};

/// Where each segment of a path lies on the map: segment `i` (from vertex `i` to `i + 1`)
/// walked in steps of at most half a pixel, each step's share of the segment's time laid
/// bilinearly onto the four pixels around it.
#[derive(Clone)]
pub struct PathRaster {
    n: usize,
    pitch: f64,
    /// Per segment: (pixel, share of its time), shares summing to 1.
    cells: Vec<Vec<(u32, f64)>>,
    /// Segment lengths, mm.
    pub lengths: Vec<f64>,
}

impl PathRaster {
    /// The segments between consecutive `points` (mm) on `grid`.
    pub fn new(grid: Grid, points: &[[f64; 2]]) -> PathRaster {
        let mut cells = Vec::with_capacity(points.len().saturating_sub(1));
        let mut lengths = Vec::with_capacity(cells.capacity());
        for w in points.windows(2) {
            let (a, b) = (w[0], w[1]);
            let len = (b[0] - a[0]).hypot(b[1] - a[1]);
            let steps = ((len / (0.5 * grid.pitch)).ceil() as usize).max(1);
            let share = 1.0 / steps as f64;
            let mut mine: Vec<(u32, f64)> = Vec::with_capacity(4 * steps);
            for k in 0..steps {
                let f = (k as f64 + 0.5) / steps as f64;
                let [fc, fr] = grid.locate(a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]));
                let (c0, r0) = (fc.floor(), fr.floor());
                let (tc, tr) = (fc - c0, fr - r0);
                for (dr, dc, wgt) in [
                    (0.0, 0.0, (1.0 - tr) * (1.0 - tc)),
                    (0.0, 1.0, (1.0 - tr) * tc),
                    (1.0, 0.0, tr * (1.0 - tc)),
                    (1.0, 1.0, tr * tc),
                ] {
                    let (r, c) = (r0 + dr, c0 + dc);
                    if wgt > 0.0
                        && (0.0..grid.n as f64).contains(&r)
                        && (0.0..grid.n as f64).contains(&c)
                    {
                        let idx = (r as usize * grid.n + c as usize) as u32;
                        match mine.iter_mut().find(|(i, _)| *i == idx) {
                            Some(cell) => cell.1 += share * wgt,
                            None => mine.push((idx, share * wgt)),
                        }
                    }
                }
            }
            cells.push(mine);
            lengths.push(len);
        }
        PathRaster {
            n: grid.n,
            pitch: grid.pitch,
            cells,
            lengths,
        }
    }

    /// The dwell density map (s/mm²) of spending `seconds[i]` on segment `i`.
    pub fn dwell_map(&self, seconds: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; self.n * self.n];
        let area = self.pitch * self.pitch;
        for (cells, &t) in self.cells.iter().zip(seconds) {
            for &(i, w) in cells {
                out[i as usize] += w * t / area;
            }
        }
        out
    }

    /// Per segment: the share-weighted mean of `map` over its cells.
    pub fn sample(&self, map: &[f64]) -> Vec<f64> {
        self.cells
            .iter()
            .map(|cells| {
                let (mut sum, mut total) = (0.0, 0.0);
                for &(i, w) in cells {
                    sum += w * map[i as usize];
                    total += w;
                }
                if total > 0.0 {
                    sum / total
                } else {
                    0.0
                }
            })
            .collect()
    }
}

/// The dwell-time problem on one grid: the nominal influence function, the glass, the
/// clear aperture and the rim's gain.
pub struct DwellSolver {
    conv: Convolver,
    /// Pixels of glass (the residual's weight).
    glass: Vec<bool>,
    /// Pixels of the clear aperture (where the result is judged).
    clear: Vec<bool>,
    /// Per pixel as a dwell point: the removal's gain at the rim (≥ 1).
    gain: Vec<f64>,
    /// The highest spatial frequency a dwell correction may hold, cycles per pixel.
    cutoff: f64,
    /// Iterations per threshold.
    iterations: usize,
    /// The force the kernel was made at, N.
    force: f64,
    /// The kernel (side `2·reach + 1`) and its reach, kept for [`DwellSolver::write_problem`].
    kernel: Vec<f64>,
    reach: usize,
}

/// A solved dwell along a path.
#[derive(Clone, Debug)]
pub struct Dwell {
    /// Seconds on each segment of the path.
    pub seconds: Vec<f64>,
    /// The removal it plans, nm.
    pub removal: HeightMap,
    /// The error it leaves by plan over the clear aperture (measured less removal).
    pub planned: Figure,
    /// The threshold chosen, as a share of the largest |B̂|.
    pub gamma: f64,
    /// The pneumatic force it was planned at, N (the solver's kernel's force when the
    /// solver alone made it).
    pub force: f64,
}

/// The Gaussian-weighted mean (SD `sigma` pixels) of `values` around each pixel that
/// `region` marks, over the region's pixels only (0 off the region): separable, the
/// weights of the region's pixels normalised.
pub fn gaussian_average(n: usize, values: &[f64], region: &[bool], sigma: f64) -> Vec<f64> {
    let reach = (3.0 * sigma).ceil() as isize;
    let weights: Vec<f64> = (-reach..=reach)
        .map(|d| (-0.5 * (d as f64 / sigma).powi(2)).exp())
        .collect();
    let ni = n as isize;
    // One 1-D pass along (dr, dc): along the rows, then along the columns.
    let pass = |v: &[f64], (dr, dc): (isize, isize)| {
        let mut out = vec![0.0; n * n];
        for r in 0..ni {
            for c in 0..ni {
                let mut sum = 0.0;
                for (k, w) in weights.iter().enumerate() {
                    let d = k as isize - reach;
                    let (rr, cc) = (r + d * dr, c + d * dc);
                    if (0..ni).contains(&rr) && (0..ni).contains(&cc) {
                        sum += w * v[(rr * ni + cc) as usize];
                    }
                }
                out[(r * ni + c) as usize] = sum;
            }
        }
        out
    };
    let blur = |v: &[f64]| pass(&pass(v, (0, 1)), (1, 0));
    let masked: Vec<f64> = values
        .iter()
        .zip(region)
        .map(|(v, &m)| if m { *v } else { 0.0 })
        .collect();
    let mask: Vec<f64> = region.iter().map(|&m| if m { 1.0 } else { 0.0 }).collect();
    let (num, den) = (blur(&masked), blur(&mask));
    num.iter()
        .zip(&den)
        .zip(region)
        .map(|((a, b), &m)| if m && *b > 0.0 { a / b } else { 0.0 })
        .collect()
}

/// The share of each correction taken per iteration: a full step overshoots where the
/// clipping or the path's crowding keeps the rest from following.
const RELAXATION: f64 = 0.5;

/// Thresholds tried, as shares of the largest |B̂|.
pub const GAMMAS: [f64; 4] = [0.01, 0.03, 0.1, 0.3];

impl DwellSolver {
    /// The problem for maps `n` pixels a side with kernel `kernel` (side `2·reach + 1`,
    /// nm per s/mm²); `glass` and `clear` mark pixels as above; `gain` is each pixel's
    /// removal gain as a dwell point (1 inside, more where the pad overhangs the rim);
    /// `spacing` the path's pitch in pixels: dwell corrections stay below its Nyquist
    /// frequency, since the path realises them only along its passes; `force` the force
    /// the kernel was made at, N.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        n: usize,
        kernel: &[f64],
        reach: usize,
        glass: Vec<bool>,
        clear: Vec<bool>,
        gain: Vec<f64>,
        spacing: f64,
        force: f64,
    ) -> Result<DwellSolver> {
        ensure(spacing.is_finite() && spacing >= 1.0, || {
            format!("the path's passes must lie at least a pixel apart, got {spacing} pixels")
        })?;
        ensure(
            gain.len() == n * n && gain.iter().all(|g| *g >= 1.0),
            || format!("the dwell solver needs {} gains of at least 1", n * n),
        )?;
        Ok(DwellSolver {
            conv: Convolver::new(n, kernel, reach),
            glass,
            clear,
            gain,
            cutoff: 0.5 / spacing,
            iterations: 8,
            force,
            kernel: kernel.to_vec(),
            reach,
        })
    }

    /// Writes the problem that [`DwellSolver::solve`] solved for `measured` along `path`
    /// within `bounds` over `area`, with its `solution`, to the safetensors file `out`
    /// (atomically), for an implementation outside the engine to solve and check against
    /// (`benches/numpy/dwell.py`, `make bench-polish`): f64 tensors `kernel`, `gain`,
    /// `measured`, `cell_weight`, `bounds`, `area`, `seconds` and `removal`, u8 `glass`
    /// and `clear`, and the path's cells as `segment_start` (i64, one more than the
    /// segments) and `cell_pixel` (i64); the scalars (`n`, `reach`, `pitch`, `cutoff`,
    /// `iterations`, `relaxation`, `gammas`, `force`, the solution's `gamma` and
    /// `planned_rms`) in its metadata.
    pub fn write_problem(
        &self,
        out: &std::path::Path,
        measured: &HeightMap,
        path: &PathRaster,
        (bounds, area): (&[[f64; 2]], &[f64]),
        solution: &Dwell,
    ) -> Result<()> {
        use safetensors::tensor::{Dtype, TensorView};
        let n = self.glass.len().isqrt();
        let side = 2 * self.reach + 1;
        let mask = |m: &[bool]| m.iter().map(|&b| u8::from(b)).collect::<Vec<u8>>();
        let (glass, clear) = (mask(&self.glass), mask(&self.clear));
        let mut starts = vec![0i64];
        let (mut pixels, mut weights) = (Vec::new(), Vec::new());
        for cells in &path.cells {
            for &(i, w) in cells {
                pixels.push(i64::from(i));
                weights.push(w);
            }
            starts.push(pixels.len() as i64);
        }
        let flat_bounds: Vec<f64> = bounds.iter().flatten().copied().collect();
        let segments = bounds.len();
        let f64s: [(&str, Vec<usize>, &[f64]); 8] = [
            ("kernel", vec![side, side], &self.kernel),
            ("gain", vec![n, n], &self.gain),
            ("measured", vec![n, n], &measured.values),
            ("cell_weight", vec![weights.len()], &weights),
            ("bounds", vec![segments, 2], &flat_bounds),
            ("area", vec![segments], area),
            ("seconds", vec![segments], &solution.seconds),
            ("removal", vec![n, n], &solution.removal.values),
        ];
        let err = |e: safetensors::SafeTensorError| {
            crate::error::Error::Invalid(format!("{}: {e}", out.display()))
        };
        let mut views = Vec::new();
        for (name, shape, values) in f64s {
            let bytes: &[u8] = bytemuck::cast_slice(values);
            views.push((
                name,
                TensorView::new(Dtype::F64, shape, bytes).map_err(err)?,
            ));
        }
        for (name, values) in [("glass", &glass), ("clear", &clear)] {
            let view = TensorView::new(Dtype::U8, vec![n, n], values).map_err(err)?;
            views.push((name, view));
        }
        for (name, values) in [("segment_start", &starts), ("cell_pixel", &pixels)] {
            let bytes: &[u8] = bytemuck::cast_slice(values);
            views.push((
                name,
                TensorView::new(Dtype::I64, vec![values.len()], bytes).map_err(err)?,
            ));
        }
        let metadata = [
            ("n", n.to_string()),
            ("reach", self.reach.to_string()),
            ("pitch", path.pitch.to_string()),
            ("cutoff", self.cutoff.to_string()),
            ("iterations", self.iterations.to_string()),
            ("relaxation", RELAXATION.to_string()),
            ("gammas", GAMMAS.map(|g| g.to_string()).join(",")),
            ("force", self.force.to_string()),
            ("gamma", solution.gamma.to_string()),
            ("planned_rms", solution.planned.rms.to_string()),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect();
        let bytes = safetensors::serialize(views, Some(metadata)).map_err(err)?;
        crate::error::write_file(out, &bytes)
    }

    /// The removal (nm) of the dwell density map `t` (s/mm²): the kernel convolved with
    /// `gain · t`.
    pub fn removal(&mut self, t: &[f64]) -> Result<Vec<f64>> {
        let u: Vec<f64> = t.iter().zip(&self.gain).map(|(t, g)| t * g).collect();
        let mut out = vec![0.0; u.len()];
        self.conv.convolve(&u, &mut out)?;
        Ok(out)
    }

    /// A solver of its own for the same problem on the same adapter, for another thread.
    pub fn fork(&self) -> Result<DwellSolver> {
        Ok(DwellSolver {
            conv: self.conv.fork()?,
            glass: self.glass.clone(),
            clear: self.clear.clone(),
            gain: self.gain.clone(),
            cutoff: self.cutoff,
            iterations: self.iterations,
            force: self.force,
            kernel: self.kernel.clone(),
            reach: self.reach,
        })
    }

    /// The adapter its convolutions run on, or `None` on the CPU.
    pub fn gpu(&self) -> Option<&crate::gpu::Gpu> {
        self.conv.gpu()
    }

    /// Runs the convolutions and inverse filters on `gpu` (WGSL, f32) from now on, or on
    /// the CPU (f64, the default) with `None`.
    pub fn run_on(&mut self, gpu: Option<std::sync::Arc<crate::gpu::Gpu>>) -> Result<()> {
        Ok(self.conv.run_on(gpu)?)
    }

    /// What `measured` less `removal` leaves over the clear aperture.
    fn left(&self, measured: &HeightMap, removal: &[f64]) -> Figure {
        HeightMap {
            grid: measured.grid,
            values: measured
                .values
                .iter()
                .zip(removal)
                .map(|(m, r)| m - r)
                .collect(),
        }
        .figure(&self.clear)
    }

    /// The seconds on each segment of `path` (between `bounds[i]`: the segment's length
    /// over the fastest and the slowest feed) whose removal best matches `measured` (nm);
    /// `area[i]` is the area segment `i` stands for (its length times the local spacing
    /// between passes), mm².
    pub fn solve(
        &mut self,
        measured: &HeightMap,
        path: &PathRaster,
        bounds: &[[f64; 2]],
        area: &[f64],
    ) -> Result<Dwell> {
        let n = measured.values.len();
        let lowest = measured
            .values
            .iter()
            .zip(&self.clear)
            .filter(|(_, &m)| m)
            .fold(f64::INFINITY, |m, (v, _)| m.min(*v));
        let least: Vec<f64> = bounds.iter().map(|b| b[0]).collect();
        let floor = self.removal(&path.dwell_map(&least))?;
        // The least piston for which the wanted removal is at least what the fastest
        // feed everywhere removes.
        let layer = measured
            .values
            .iter()
            .zip(&floor)
            .zip(&self.clear)
            .filter(|(_, &c)| c)
            .map(|((v, f), _)| f - (v - lowest))
            .fold(0.0f64, f64::max);
        let wanted: Vec<f64> = measured
            .values
            .iter()
            .zip(&self.glass)
            .map(|(v, &g)| if g { v - lowest + layer } else { 0.0 })
            .collect();
        let gain = path.sample(&self.gain);
        let largest = self
            .conv
            .spectrum()
            .iter()
            .fold(0.0f64, |m, s| m.max(s.norm()));
        let (size, cutoff) = (self.conv.size(), self.cutoff);
        let mut best = Dwell {
            seconds: least.clone(),
            planned: self.left(measured, &floor),
            removal: HeightMap {
                grid: measured.grid,
                values: floor,
            },
            gamma: f64::NAN,
            force: self.force,
        };
        let (mut residual, mut step) = (vec![0.0; n], vec![0.0; n]);
        for &gamma in &GAMMAS {
            let floor = gamma * largest;
            let inverse = move |s: Complex64, i: usize| {
                let k = |j: usize| j.min(size - j) as f64 / size as f64;
                if s.norm() >= floor && k(i / size).hypot(k(i % size)) <= cutoff {
                    s.inv()
                } else {
                    Complex64::default()
                }
            };
            let mut seconds = least.clone();
            for _ in 0..=self.iterations {
                let removal = self.removal(&path.dwell_map(&seconds))?;
                let left = self.left(measured, &removal);
                if left.rms < best.planned.rms {
                    best = Dwell {
                        seconds: seconds.clone(),
                        planned: left,
                        removal: HeightMap {
                            grid: measured.grid,
                            values: removal.clone(),
                        },
                        gamma,
                        force: self.force,
                    };
                }
                for i in 0..n {
                    residual[i] = if self.glass[i] {
                        wanted[i] - removal[i]
                    } else {
                        0.0
                    };
                }
                self.conv.filter(&residual, &mut step, inverse)?;
                let along = path.sample(&step);
                for (((t, d), b), (a, g)) in seconds
                    .iter_mut()
                    .zip(&along)
                    .zip(bounds)
                    .zip(area.iter().zip(&gain))
                {
                    *t = (*t + RELAXATION * d * a / g).clamp(b[0], b[1]);
                }
            }
        }
        Ok(best)
    }
}
#[cfg(test)]
mod tests {
    use super::*;
    use crate::polish::Pad;

    /// A smooth error over a small part (160 mm, the pad's reach a quarter of it), a
    /// raster path over it: the plan leaves less than half the error, within the feed
    /// limits; the part's rim, which the pad cannot shape finely, keeps it from more.
    #[test]
    fn plans_a_feasible_removal() {
        let pad = Pad::default();
        let grid = Grid { n: 96, pitch: 2.0 };
        let (kernel, reach) = pad.kernel(grid, 100.0);
        let glass = grid.disc(80.0);
        let clear = grid.disc(75.0);
        let spacing = 6.0;
        let mut points = Vec::new();
        let mut y = -78.0;
        let mut flip = false;
        while y <= 78.0 {
            let half = (80.0f64 * 80.0 - y * y).sqrt();
            let (a, b) = if flip { (half, -half) } else { (-half, half) };
            let steps = ((b - a).abs() / 2.0).ceil() as usize;
            for k in 0..=steps {
                points.push([a + (b - a) * k as f64 / steps as f64, y]);
            }
            y += spacing;
            flip = !flip;
        }
        let raster = PathRaster::new(grid, &points);
        let bounds: Vec<[f64; 2]> = raster.lengths.iter().map(|l| [l / 40.0, l / 5.0]).collect();
        let area: Vec<f64> = raster.lengths.iter().map(|l| l * spacing).collect();
        let mut solver = DwellSolver::new(
            grid.n,
            &kernel,
            reach,
            glass.clone(),
            clear.clone(),
            vec![1.0; grid.len()],
            spacing / grid.pitch,
            100.0,
        )
        .unwrap();
        let mut measured = HeightMap::zeros(grid);
        for r in 0..grid.n {
            for c in 0..grid.n {
                let [x, y] = grid.centre(r, c);
                if glass[r * grid.n + c] {
                    measured.values[r * grid.n + c] = 20.0 * (x / 40.0).sin() * (y / 55.0).cos()
                        + 30.0 * (-(x * x + (y - 20.0).powi(2)) / 600.0).exp();
                }
            }
        }
        let before = measured.figure(&clear);
        let dwell = solver.solve(&measured, &raster, &bounds, &area).unwrap();
        assert!(
            dwell.planned.rms < 0.5 * before.rms,
            "{before:?} → {:?}",
            dwell.planned
        );
        for (t, b) in dwell.seconds.iter().zip(&bounds) {
            assert!(*t >= b[0] && *t <= b[1]);
        }
        // The plan's removal is its seconds laid on the path and convolved.
        let again = solver.removal(&raster.dwell_map(&dwell.seconds)).unwrap();
        assert_eq!(again, dwell.removal.values);

        // The problem written for outside implementations reads back as solved: the
        // path's cells lay the solution's seconds into the same dwell map.
        let file = std::env::temp_dir().join(format!("dwell-{}.safetensors", std::process::id()));
        solver
            .write_problem(&file, &measured, &raster, (&bounds, &area), &dwell)
            .unwrap();
        let bytes = std::fs::read(&file).unwrap();
        std::fs::remove_file(&file).unwrap();
        let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
        let meta = meta.metadata().clone().unwrap();
        assert_eq!(meta["n"], "96");
        assert_eq!(meta["gammas"], "0.01,0.03,0.1,0.3");
        assert_eq!(
            meta["planned_rms"].parse::<f64>().unwrap(),
            dwell.planned.rms
        );
        let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        let f64s = |name: &str| -> Vec<f64> {
            let t = st.tensor(name).unwrap();
            t.data()
                .chunks(8)
                .map(|b| f64::from_le_bytes(b.try_into().unwrap()))
                .collect()
        };
        let i64s = |name: &str| -> Vec<i64> {
            let t = st.tensor(name).unwrap();
            t.data()
                .chunks(8)
                .map(|b| i64::from_le_bytes(b.try_into().unwrap()))
                .collect()
        };
        assert_eq!(f64s("seconds"), dwell.seconds);
        assert_eq!(st.tensor("kernel").unwrap().shape(), [2 * reach + 1; 2]);
        let (starts, pixels, weights) = (
            i64s("segment_start"),
            i64s("cell_pixel"),
            f64s("cell_weight"),
        );
        assert_eq!(starts.len(), bounds.len() + 1);
        let mut laid = vec![0.0; grid.len()];
        for (s, t) in dwell.seconds.iter().enumerate() {
            for k in starts[s] as usize..starts[s + 1] as usize {
                laid[pixels[k] as usize] += weights[k] * t / (grid.pitch * grid.pitch);
            }
        }
        assert_eq!(laid, raster.dwell_map(&dwell.seconds));
    }
}
