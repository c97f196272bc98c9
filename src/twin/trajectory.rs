//! Polishing paths over the mirror (raster grid, Fermat spiral, Hilbert curve) walked at
//! a modulated feed, and random static configurations for calibration.

use std::str::FromStr;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::mirror::Mirror;
use crate::robot::{Configuration, PlatformPose, Robot};

/// The tool paths of section IV-D, and a rosette that no training recording uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PathKind {
    /// Raster lines across the disk, alternating direction.
    Grid,
    /// Fermat spiral `r = a·√θ` from the centre out (constant area per turn).
    Fermat,
    /// Hilbert curve over the square inscribed in the aperture.
    Hilbert,
    /// Hypotrochoid rosette (a rotating-arm pattern): the demo keeps it out of training,
    /// so one held-out path is new in kind, not only in placement.
    Rosette,
}

impl PathKind {
    /// Every path, in the order of the variants.
    pub const ALL: [PathKind; 4] = [
        PathKind::Grid,
        PathKind::Fermat,
        PathKind::Hilbert,
        PathKind::Rosette,
    ];
    /// The paths of the paper's training recordings (section IV-D).
    pub const TRAINING: [PathKind; 3] = [PathKind::Grid, PathKind::Fermat, PathKind::Hilbert];

    /// The path's name in recordings, sidecars and on the command line; [`str::parse`]
    /// reads it back.
    ///
    /// ```
    /// use iastgcn::twin::PathKind;
    ///
    /// let kind: PathKind = "hilbert".parse()?;
    /// assert_eq!(kind, PathKind::Hilbert);
    /// assert_eq!(kind.name(), "hilbert");
    /// assert!("spiral".parse::<PathKind>().is_err());
    /// # Ok::<(), String>(())
    /// ```
    pub fn name(self) -> &'static str {
        match self {
            PathKind::Grid => "grid",
            PathKind::Fermat => "fermat",
            PathKind::Hilbert => "hilbert",
            PathKind::Rosette => "rosette",
        }
    }
}

impl FromStr for PathKind {
    type Err = String;
    fn from_str(s: &str) -> Result<PathKind, String> {
        PathKind::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| format!("unknown path {s:?}: expected grid, fermat, hilbert or rosette"))
    }
}

/// Path spacing and edge margin (mm), and where the pattern lies on the part.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathParams {
    /// Distance between neighbouring passes.
    pub spacing: f64,
    /// Distance kept from the mirror's edge.
    pub margin: f64,
    /// Rotation of the pattern about the mirror's axis, degrees.
    pub rotation_deg: f64,
    /// Walk the pattern from its other end.
    pub reverse: bool,
}

impl Default for PathParams {
    fn default() -> PathParams {
        PathParams {
            spacing: 15.0,
            margin: 10.0,
            rotation_deg: 0.0,
            reverse: false,
        }
    }
}

impl PathParams {
    /// Where the held-out runs put each pattern, so that they never retrace a training
    /// recording (made with the default placement): the raster and the Hilbert curve
    /// turned off their lattice (their passes then only cross the training ones), the
    /// spiral turned half a turn (its arms fall between the training arms) and walked
    /// inwards. The raster's turns between passes run along the rim, so its held-out
    /// placement keeps 4 mm further in. The rosette is never trained on and keeps its
    /// default placement.
    pub fn held_out(kind: PathKind) -> PathParams {
        let (rotation_deg, reverse, inset) = match kind {
            PathKind::Grid => (37.0, false, 4.0),
            PathKind::Fermat => (180.0, true, 0.0),
            PathKind::Hilbert => (53.0, true, 0.0),
            PathKind::Rosette => (0.0, false, 0.0),
        };
        let d = PathParams::default();
        PathParams {
            rotation_deg,
            reverse,
            margin: d.margin + inset,
            ..d
        }
    }

    /// The held-out placement of `kind` in held-out session `session` (0 is
    /// [`PathParams::held_out`]): the raster and the Hilbert curve turn a further quarter
    /// turn per session (still off the training lattice, which is symmetric under quarter
    /// turns), the spiral stays half a turn off the training arms and changes direction,
    /// the rosette turns 30° per session. `tests/twin_honest.rs` checks that none retraces
    /// any training placement ([`PathParams::training`]).
    pub fn held_out_in(kind: PathKind, session: usize) -> PathParams {
        let mut p = PathParams::held_out(kind);
        let k = session % PathParams::HELD_OUT_PLACEMENTS;
        match kind {
            PathKind::Grid | PathKind::Hilbert => p.rotation_deg += 90.0 * k as f64,
            PathKind::Fermat => p.reverse ^= k % 2 == 1,
            PathKind::Rosette => p.rotation_deg += 20.0 * k as f64,
        }
        if p.rotation_deg >= 360.0 {
            p.rotation_deg -= 360.0;
        }
        p
    }

    /// The training placement `k` (of [`PathParams::TRAINING_PLACEMENTS`], taken modulo)
    /// of a multi-session recording with varied placements (docs/twin.md "Sessions"):
    /// the Hilbert curve in quarter turns, on its own lattice, walked either way; the
    /// raster at 0°, 90° and 180° (at 270° its passes brush the held-out rosette for
    /// three windows), either way; the spiral at 0°, 90° and 270° (never at the held-out
    /// half turn), either way. Placement 0 is the default one.
    pub fn training(kind: PathKind, k: usize) -> PathParams {
        let k = k % PathParams::TRAINING_PLACEMENTS;
        let rotation_deg = match kind {
            PathKind::Grid => [0.0, 90.0, 180.0, 0.0][k],
            PathKind::Fermat => [0.0, 90.0, 270.0, 0.0][k],
            _ => 90.0 * k as f64,
        };
        PathParams {
            rotation_deg,
            reverse: k % 2 == 1,
            ..PathParams::default()
        }
    }

    /// How many distinct training placements [`PathParams::training`] has per path.
    pub const TRAINING_PLACEMENTS: usize = 4;

    /// How many distinct held-out placements [`PathParams::held_out_in`] has per path:
    /// they repeat from session 4 on.
    pub const HELD_OUT_PLACEMENTS: usize = 4;

    /// The spread training placement `k` (of [`PathParams::SPREAD_PLACEMENTS`], taken
    /// modulo) of a multi-session recording with `--placement spread` (docs/twin.md
    /// "Sessions"): the pattern turned so that the strokes' directions spread over every
    /// angle (not only the quarter turns of [`PathParams::training`]), every other one
    /// walked the other way, none retracing a held-out placement. The turns are those
    /// `twin::retrace::spread_placements` chooses by its rule (golden sections of the
    /// pattern's direction period, skipping any that retraces a held-out placement),
    /// written out here; `tests/twin_honest.rs` checks that the two agree. Placement 0 is
    /// the default one; the rosette, never trained on, keeps the default.
    pub fn spread(kind: PathKind, k: usize) -> PathParams {
        let k = k % PathParams::SPREAD_PLACEMENTS;
        let rotation_deg = match kind {
            PathKind::Grid => SPREAD_GRID_DEG[k],
            PathKind::Fermat => SPREAD_FERMAT_DEG[k],
            PathKind::Hilbert => SPREAD_HILBERT_DEG[k],
            PathKind::Rosette => return PathParams::default(),
        };
        PathParams {
            rotation_deg,
            reverse: k % 2 == 1,
            ..PathParams::default()
        }
    }

    /// How many distinct spread placements [`PathParams::spread`] has per path.
    pub const SPREAD_PLACEMENTS: usize = 16;
}

/// The raster's spread turns, degrees ([`PathParams::spread`]).
const SPREAD_GRID_DEG: [f64; PathParams::SPREAD_PLACEMENTS] = [
    0.0, 334.0, 85.0, 196.0, 239.0, 170.0, 281.0, 186.0, 229.0, 160.0, 271.0, 22.0, 314.0, 65.0,
    356.0, 150.0,
];
/// The spiral's spread turns, degrees ([`PathParams::spread`]).
const SPREAD_FERMAT_DEG: [f64; PathParams::SPREAD_PLACEMENTS] = [
    0.0, 85.0, 307.0, 32.0, 255.0, 117.0, 340.0, 65.0, 287.0, 12.0, 97.0, 320.0, 45.0, 267.0,
    130.0, 352.0,
];
/// The Hilbert curve's spread turns, degrees ([`PathParams::spread`]).
const SPREAD_HILBERT_DEG: [f64; PathParams::SPREAD_PLACEMENTS] = [
    0.0, 201.0, 347.0, 98.0, 299.0, 85.0, 196.0, 342.0, 37.0, 93.0, 294.0, 80.0, 191.0, 337.0,
    32.0, 178.0,
];

/// A planar polyline `(x, y)` with its cumulative arc length.
#[derive(Clone, Debug)]
pub struct Path {
    points: Vec<[f64; 2]>,
    arc: Vec<f64>,
}

impl Path {
    /// The polyline through `points` (mm, in the mirror's plane), walked in their order.
    ///
    /// ```
    /// use iastgcn::twin::Path;
    ///
    /// let path = Path::new(vec![[0.0, 0.0], [3.0, 4.0]]);
    /// assert_eq!(path.length(), 5.0);
    /// assert_eq!(path.at(2.5), [1.5, 2.0]);
    /// ```
    pub fn new(points: Vec<[f64; 2]>) -> Path {
        let mut arc = Vec::with_capacity(points.len());
        let mut s = 0.0;
        for (i, p) in points.iter().enumerate() {
            if i > 0 {
                let q = points[i - 1];
                s += (p[0] - q[0]).hypot(p[1] - q[1]);
            }
            arc.push(s);
        }
        Path { points, arc }
    }

    /// Total arc length, mm.
    pub fn length(&self) -> f64 {
        *self.arc.last().unwrap_or(&0.0)
    }

    /// The polyline's vertices, mm.
    pub fn points(&self) -> &[[f64; 2]] {
        &self.points
    }

    /// The cumulative arc length at each vertex, mm (0 first).
    pub fn arc(&self) -> &[f64] {
        &self.arc
    }

    /// The point at arc length `s`; past the end the tool walks the path back
    /// (and forth again), as a polishing machine repeats its passes.
    pub fn at(&self, s: f64) -> [f64; 2] {
        let len = self.length();
        if len <= 0.0 {
            return self.points[0];
        }
        let period = 2.0 * len;
        let mut u = s.rem_euclid(period);
        if u > len {
            u = period - u;
        }
        let i = self
            .arc
            .partition_point(|&a| a <= u)
            .clamp(1, self.points.len() - 1);
        let (s0, s1) = (self.arc[i - 1], self.arc[i]);
        let f = if s1 > s0 { (u - s0) / (s1 - s0) } else { 0.0 };
        let (p, q) = (self.points[i - 1], self.points[i]);
        [p[0] + f * (q[0] - p[0]), p[1] + f * (q[1] - p[1])]
    }

    /// Builds the path of `kind` over the usable disk of `mirror`.
    pub fn generate(kind: PathKind, mirror: &Mirror, params: &PathParams) -> Path {
        let r = mirror.radius() - params.margin;
        let h = params.spacing;
        let points = match kind {
            PathKind::Grid => {
                let lines = (2.0 * r / h).floor() as usize;
                let mut pts = Vec::new();
                for i in 0..lines {
                    let y = -r + h * (i as f64 + 0.5);
                    let half = (r * r - y * y).max(0.0).sqrt();
                    let (a, b) = if i % 2 == 0 {
                        (-half, half)
                    } else {
                        (half, -half)
                    };
                    pts.push([a, y]);
                    pts.push([b, y]);
                }
                densify(&pts, 2.0)
            }
            PathKind::Fermat => {
                // Arms are ~π a² / r apart: match the spacing at mid-radius.
                let a = (h * 0.5 * r / std::f64::consts::PI).sqrt();
                let theta_max = (r / a).powi(2);
                let mut pts = Vec::new();
                let mut theta: f64 = 0.0;
                while theta <= theta_max {
                    let rr = a * theta.sqrt();
                    pts.push([rr * theta.cos(), rr * theta.sin()]);
                    // Steps of about 2 mm along the curve.
                    theta += (2.0 / rr.max(2.0)).min(0.5);
                }
                densify(&pts, 2.0)
            }
            PathKind::Hilbert => {
                let side = r * std::f64::consts::SQRT_2;
                let order = ((side / h).log2().ceil().max(1.0)) as u32;
                let n = 1usize << order;
                let cell = side / n as f64;
                let mut pts = Vec::new();
                for d in 0..n * n {
                    let (i, j) = hilbert_d2xy(n, d);
                    let c = [
                        -0.5 * side + (i as f64 + 0.5) * cell,
                        -0.5 * side + (j as f64 + 0.5) * cell,
                    ];
                    pts.push(c);
                }
                densify(&pts, 2.0)
            }
            PathKind::Rosette => {
                // Hypotrochoid: an arm of length d on a wheel of radius ρ rolling inside
                // a circle of radius R; ρ/R irrational enough that the petals precess
                // instead of closing. Scaled so that it reaches the usable radius.
                let (big, small, arm) = (1.0, 0.382, 0.55);
                let k = (big - small) / small;
                let scale = r / (big - small + arm);
                let mut pts = Vec::new();
                let mut t: f64 = 0.0;
                // Six turns of the wheel centre (about a full coverage), steps of ~2 mm.
                while t <= 6.0 * std::f64::consts::TAU {
                    pts.push([
                        scale * ((big - small) * t.cos() + arm * (k * t).cos()),
                        scale * ((big - small) * t.sin() - arm * (k * t).sin()),
                    ]);
                    t += 2.0 / (scale * (big - small + arm * k));
                }
                densify(&pts, 2.0)
            }
        };
        let mut points = points;
        if params.reverse {
            points.reverse();
        }
        if params.rotation_deg != 0.0 {
            let (s, c) = params.rotation_deg.to_radians().sin_cos();
            for p in &mut points {
                *p = [c * p[0] - s * p[1], s * p[0] + c * p[1]];
            }
        }
        Path::new(points)
    }
}

/// A feed planned along a path: `feed[i]` mm/s over arc lengths `[arc[i], arc[i + 1])`
/// (the last holds to the end and beyond). The polishing stage turns a dwell-time map into
/// one (docs/polishing.md "Dwell time").
#[derive(Clone, Debug, PartialEq)]
pub struct FeedPlan {
    arc: Vec<f64>,
    feed: Vec<f64>,
    /// With `Some(f0)`, the controller scales the planned feed by its latest force reading
    /// over `f0` (N), so that force × dwell, the removal, stays as planned.
    pub force_reference: Option<f64>,
    /// The run ends where the path does (its duration only bounds it): a feed scaled by
    /// the force walks the path in its own time.
    pub walk_once: bool,
}

impl FeedPlan {
    /// The feed `feed[i]` from arc length `arc[i]` on; `arc` starts at 0 and rises, every
    /// feed is positive and finite.
    ///
    /// ```
    /// use iastgcn::twin::FeedPlan;
    ///
    /// let plan = FeedPlan::new(vec![0.0, 10.0], vec![5.0, 20.0]).unwrap();
    /// assert_eq!(plan.feed_at(3.0), 5.0);
    /// assert_eq!(plan.feed_at(10.0), 20.0);
    /// assert_eq!(plan.duration(30.0), 2.0 + 1.0);
    /// assert!(FeedPlan::new(vec![0.0], vec![0.0]).is_err());
    /// ```
    pub fn new(arc: Vec<f64>, feed: Vec<f64>) -> Result<FeedPlan, String> {
        if arc.is_empty() || arc.len() != feed.len() || arc[0] != 0.0 {
            return Err(format!(
                "a feed plan needs one feed per breakpoint from arc length 0, got {} breakpoints and {} feeds",
                arc.len(),
                feed.len()
            ));
        }
        if arc.windows(2).any(|w| w[1] <= w[0] || !w[1].is_finite()) {
            return Err("a feed plan's arc lengths must rise".into());
        }
        if let Some(f) = feed.iter().find(|f| !(f.is_finite() && **f > 0.0)) {
            return Err(format!(
                "a feed plan's feeds must be positive, got {f} mm/s"
            ));
        }
        Ok(FeedPlan {
            arc,
            feed,
            force_reference: None,
            walk_once: false,
        })
    }

    /// The feed at arc length `s`, mm/s.
    pub fn feed_at(&self, s: f64) -> f64 {
        let i = self.arc.partition_point(|&a| a <= s).max(1) - 1;
        self.feed[i]
    }

    /// Seconds to walk the first `length` mm at the plan's feed.
    pub fn duration(&self, length: f64) -> f64 {
        let mut t = 0.0;
        for (i, (&a, &f)) in self.arc.iter().zip(&self.feed).enumerate() {
            let end = self
                .arc
                .get(i + 1)
                .copied()
                .unwrap_or(f64::INFINITY)
                .min(length);
            if end > a {
                t += (end - a) / f;
            }
        }
        t
    }
}

/// Inserts points so that no segment is longer than `step` (arc-length sampling then
/// follows straight lines between the corners at an even pace).
fn densify(corners: &[[f64; 2]], step: f64) -> Vec<[f64; 2]> {
    let mut out = Vec::with_capacity(corners.len());
    for (i, &c) in corners.iter().enumerate() {
        if i > 0 {
            let p = corners[i - 1];
            let n = ((c[0] - p[0]).hypot(c[1] - p[1]) / step).ceil() as usize;
            for k in 1..n {
                let f = k as f64 / n as f64;
                out.push([p[0] + f * (c[0] - p[0]), p[1] + f * (c[1] - p[1])]);
            }
        }
        out.push(c);
    }
    out
}

/// Index `d` along a Hilbert curve of side `n` (a power of two) to cell `(x, y)`.
fn hilbert_d2xy(n: usize, d: usize) -> (usize, usize) {
    let (mut x, mut y, mut t) = (0, 0, d);
    let mut s = 1;
    while s < n {
        let rx = 1 & (t / 2);
        let ry = 1 & (t ^ rx);
        if ry == 0 {
            if rx == 1 {
                x = s - 1 - x;
                y = s - 1 - y;
            }
            std::mem::swap(&mut x, &mut y);
        }
        x += s * rx;
        y += s * ry;
        t /= 4;
        s *= 2;
    }
    (x, y)
}

/// Random static configurations spread over the workspace (limb strokes, tilt and head
/// ranges respected, with a margin), for geometric calibration.
pub fn calibration_configurations(robot: &Robot, n: usize, seed: u64) -> Vec<Configuration> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let g = &robot.geometry;
    let tilt = 0.9 * g.parallel.tilt_limit_deg.to_radians();
    let [wlo, whi] = g.parallel.extension;
    let [slo, shi] = g.parallel.stroke;
    let mut out = Vec::with_capacity(n);
    while out.len() < n {
        let platform = PlatformPose {
            alpha: rng.random_range(-tilt..tilt),
            beta: rng.random_range(-tilt..tilt),
            w: rng.random_range(wlo + 10.0..whi - 10.0),
        };
        let head = [0, 1].map(|j| {
            let [lo, hi] = g.serial.joints[j].limits_deg.unwrap_or([-180.0, 180.0]);
            rng.random_range(0.9 * lo.to_radians()..0.9 * hi.to_radians())
        });
        let lengths = robot.limb_lengths(&platform);
        if lengths.iter().all(|l| (slo + 5.0..shi - 5.0).contains(l)) {
            out.push(Configuration { platform, head });
        }
    }
    out
}
