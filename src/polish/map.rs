//! The height map of the mirror's surface error on a square grid over its projection on
//! the base xy plane, and the paper's figures of merit over the clear aperture
//! (eqs. 40–41): PV and RMS.

use crate::error::{ensure, Result};

/// A square grid of `n × n` pixels of side `pitch` mm, centred on the mirror's axis:
/// pixel `(row, col)` has its centre at `x = (col + ½ − n/2)·pitch`,
/// `y = (row + ½ − n/2)·pitch`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid {
    /// Pixels per side.
    pub n: usize,
    /// Pixel side, mm.
    pub pitch: f64,
}

impl Grid {
    /// The smallest even grid of pixel side `pitch` mm that covers a disc of radius
    /// `radius` mm.
    ///
    /// ```
    /// use iastgcn::polish::Grid;
    ///
    /// let g = Grid::covering(10.0, 2.0).unwrap();
    /// assert_eq!(g.n, 10);
    /// assert_eq!(g.centre(0, 0), [-9.0, -9.0]);
    /// assert!(Grid::covering(10.0, 0.0).is_err());
    /// ```
    pub fn covering(radius: f64, pitch: f64) -> Result<Grid> {
        ensure(pitch.is_finite() && pitch > 0.0, || {
            format!("the map's pixel size must be a positive number of mm, got {pitch}")
        })?;
        let n = (2.0 * radius / pitch).ceil() as usize;
        let n = n + n % 2;
        ensure(n <= 8192, || {
            format!(
                "a {pitch} mm pixel makes a {n} × {n} map: more than 8192 pixels a side; use a coarser map"
            )
        })?;
        Ok(Grid { n, pitch })
    }

    /// The centre of pixel `(row, col)`, mm.
    pub fn centre(&self, row: usize, col: usize) -> [f64; 2] {
        let half = 0.5 * self.n as f64;
        [
            (col as f64 + 0.5 - half) * self.pitch,
            (row as f64 + 0.5 - half) * self.pitch,
        ]
    }

    /// The (fractional) column and row of point `(x, y)`: pixel centres at whole numbers.
    pub fn locate(&self, x: f64, y: f64) -> [f64; 2] {
        let half = 0.5 * self.n as f64;
        [x / self.pitch + half - 0.5, y / self.pitch + half - 0.5]
    }

    /// Pixels in all.
    pub fn len(&self) -> usize {
        self.n * self.n
    }

    /// Whether the grid has no pixel.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Per pixel: whether its centre lies within `radius` mm of the axis.
    pub fn disc(&self, radius: f64) -> Vec<bool> {
        let mut out = Vec::with_capacity(self.len());
        for r in 0..self.n {
            for c in 0..self.n {
                let [x, y] = self.centre(r, c);
                out.push(x.hypot(y) <= radius);
            }
        }
        out
    }
}

/// A surface-error height map, nm, row-major on its [`Grid`].
#[derive(Clone, Debug, PartialEq)]
pub struct HeightMap {
    /// The grid.
    pub grid: Grid,
    /// Heights, nm, `grid.n × grid.n`, row-major.
    pub values: Vec<f64>,
}

/// PV and RMS of a map over an aperture (the paper's eqs. 40–41; the RMS about the
/// aperture's mean, as interferometer software reports it).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Figure {
    /// Peak to valley, nm.
    pub pv: f64,
    /// Root mean square about the mean, nm.
    pub rms: f64,
}

impl HeightMap {
    /// A flat map.
    pub fn zeros(grid: Grid) -> HeightMap {
        HeightMap {
            grid,
            values: vec![0.0; grid.len()],
        }
    }

    /// PV and RMS over the pixels `inside` marks.
    ///
    /// ```
    /// use iastgcn::polish::{Grid, HeightMap};
    ///
    /// let grid = Grid { n: 2, pitch: 1.0 };
    /// let map = HeightMap { grid, values: vec![1.0, 3.0, 1.0, 3.0] };
    /// let f = map.figure(&[true; 4]);
    /// assert_eq!((f.pv, f.rms), (2.0, 1.0));
    /// ```
    pub fn figure(&self, inside: &[bool]) -> Figure {
        let (mut n, mut sum, mut lo, mut hi) = (0usize, 0.0, f64::INFINITY, f64::NEG_INFINITY);
        for (&v, _) in self.values.iter().zip(inside).filter(|(_, &m)| m) {
            n += 1;
            sum += v;
            lo = lo.min(v);
            hi = hi.max(v);
        }
        if n == 0 {
            return Figure { pv: 0.0, rms: 0.0 };
        }
        let mean = sum / n as f64;
        let ss: f64 = self
            .values
            .iter()
            .zip(inside)
            .filter(|(_, &m)| m)
            .map(|(v, _)| (v - mean).powi(2))
            .sum();
        Figure {
            pv: hi - lo,
            rms: (ss / n as f64).sqrt(),
        }
    }

    /// Subtracts the least-squares plane (piston and tilt) fitted over the pixels `inside`
    /// marks, from every pixel: what an interferometer's software removes, since
    /// neither is a property of the surface but of its alignment.
    pub fn remove_plane(&mut self, inside: &[bool]) {
        // Normal equations of v ≈ a + b·x + c·y over the aperture.
        let mut m = nalgebra::Matrix3::<f64>::zeros();
        let mut rhs = nalgebra::Vector3::<f64>::zeros();
        let g = self.grid;
        for r in 0..g.n {
            for c in 0..g.n {
                let i = r * g.n + c;
                if !inside[i] {
                    continue;
                }
                let [x, y] = g.centre(r, c);
                let basis = nalgebra::Vector3::new(1.0, x, y);
                m += basis * basis.transpose();
                rhs += basis * self.values[i];
            }
        }
        let Some(coef) = m.lu().solve(&rhs) else {
            return;
        };
        for r in 0..g.n {
            for c in 0..g.n {
                let [x, y] = g.centre(r, c);
                self.values[r * g.n + c] -= coef[0] + coef[1] * x + coef[2] * y;
            }
        }
    }

    /// The value at point `(x, y)` interpolated bilinearly between pixel centres (the
    /// nearest edge pixel beyond the grid).
    pub fn at(&self, x: f64, y: f64) -> f64 {
        let n = self.grid.n;
        let [fc, fr] = self.grid.locate(x, y);
        let clamp = |v: f64| v.clamp(0.0, (n - 1) as f64);
        let (fc, fr) = (clamp(fc), clamp(fr));
        let (c0, r0) = (fc.floor() as usize, fr.floor() as usize);
        let (c1, r1) = ((c0 + 1).min(n - 1), (r0 + 1).min(n - 1));
        let (tc, tr) = (fc - c0 as f64, fr - r0 as f64);
        let v = |r: usize, c: usize| self.values[r * n + c];
        (1.0 - tr) * ((1.0 - tc) * v(r0, c0) + tc * v(r0, c1))
            + tr * ((1.0 - tc) * v(r1, c0) + tc * v(r1, c1))
    }
}
