//! A planned walk with a pose error of a chosen kind and size instead of the twin's
//! robot: what an error does to the glass apart from where it comes from
//! (docs/polishing.md "When compensation pays"). The pad follows the path at the
//! plan's feed, displaced by the error in the plane, with the plan's force plus what a
//! height error makes of it through the pneumatic float.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::dwell::Dwell;
use super::map::HeightMap;
use super::process::Polisher;
use crate::error::{Error, Result};
use crate::twin::gaussian;

/// The control tick of the walk, s (the twin's 50 Hz).
pub const TICK_S: f64 = 0.02;

/// The correlation time of a slow error, s: longer than a pass of the raster (about 25 s
/// across the mirror at 20 mm/s), so that neighbouring passes move nearly together, as
/// the twin's thermal and compliance errors do.
pub const SLOW_CORRELATION_S: f64 = 60.0;

/// A slow error is smooth below this time, s: its Ornstein–Uhlenbeck process passes a
/// first-order low-pass of this time constant (a drift has no jitter; the float's seal
/// then sees it reverse only where it really turns).
pub const SLOW_SMOOTHING_S: f64 = 5.0;

/// How a pose error varies along the walk.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ErrorKind {
    /// A stationary Ornstein–Uhlenbeck process per axis with correlation time
    /// [`SLOW_CORRELATION_S`], smoothed over [`SLOW_SMOOTHING_S`]: a drift.
    Slow,
    /// Backlash: each axis off by the size's share with the sign of its direction of
    /// travel, so the offset jumps where an axis reverses (the raster's turns; the
    /// height where the sag's slope along the path changes sign).
    PassToPass,
    /// Independent per tick and axis: jitter.
    White,
}

impl ErrorKind {
    /// Every kind, in the order the map shows them.
    pub const ALL: [ErrorKind; 3] = [ErrorKind::Slow, ErrorKind::PassToPass, ErrorKind::White];

    /// The kind's name on the command line and in the tables.
    pub fn name(self) -> &'static str {
        match self {
            ErrorKind::Slow => "slow",
            ErrorKind::PassToPass => "pass-to-pass",
            ErrorKind::White => "white",
        }
    }

    /// The kind named `name`.
    pub fn parse(name: &str) -> Result<ErrorKind> {
        ErrorKind::ALL
            .into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| {
                Error::Invalid(format!(
                    "unknown pose error kind {name:?}: expected slow, pass-to-pass or white"
                ))
            })
    }
}

/// The pneumatic float that presses the pad: how a height error (along the tool axis)
/// becomes a force error. The air column is a gas spring of `stiffness`; the piston's
/// seal holds until the force across it exceeds `friction`, so a small height change is
/// taken by the pad's backing (its stiffness times its area) and a larger one slips the
/// seal (a spring and a Coulomb slider in series, the Jenkins element of hysteresis
/// models).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Float {
    /// The air column's stiffness, N/mm.
    pub stiffness: f64,
    /// The seal's friction, N.
    pub friction: f64,
}

impl Float {
    /// A float that holds its force whatever the height: the twin's and the paper's
    /// assumption (section V: the pneumatic loading takes the error along the axis).
    pub const IDEAL: Float = Float {
        stiffness: 0.0,
        friction: 0.0,
    };

    /// A float with a stiff air column and seal friction: a 32 mm bore at 0.22 MPa
    /// absolute (100 N) over 50 cm³ of cylinder and hose is a gas spring of
    /// γ·p·A²/V = 1.4 · 0.225 · 804² / 50 000 ≈ 4 N/mm (adiabatic compression); the
    /// seal's 3 N is the twin's (docs/twin.md "Sensors", an engineering estimate, not a
    /// datasheet's figure). A precision regulator on a large volume brings the stiffness
    /// towards zero.
    pub const STIFF: Float = Float {
        stiffness: 4.0,
        friction: 3.0,
    };

    /// How the tables name it.
    pub fn name(&self) -> String {
        if *self == Float::IDEAL {
            "ideal float".into()
        } else {
            format!("float {} N/mm, seal {} N", self.stiffness, self.friction)
        }
    }
}

/// A pose error to walk with: its kind, its size (the RMS of the position error's
/// length, mm, shared equally by the three axes), the float and the seed of its draws.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseError {
    /// How it varies.
    pub kind: ErrorKind,
    /// The RMS of |error|, mm.
    pub size: f64,
    /// How a height error becomes a force error.
    pub float: Float,
    /// Seed of the error's draws.
    pub seed: u64,
}

impl PoseError {
    /// No error: the planned walk itself.
    pub const NONE: PoseError = PoseError {
        kind: ErrorKind::White,
        size: 0.0,
        float: Float::IDEAL,
        seed: 0,
    };
}

/// What a walk left.
#[derive(Clone, Debug)]
pub struct Walked {
    /// The surface after the walk.
    pub surface: HeightMap,
    /// The realised RMS of the position error's length over the walk, mm.
    pub error_rms: f64,
    /// The realised SD of the contact force about the plan's, N.
    pub force_sd: f64,
    /// Control ticks walked.
    pub ticks: usize,
}

/// The error's state along a walk.
struct Draws {
    error: PoseError,
    rng: ChaCha8Rng,
    /// The error now, mm, per axis (x, y, height).
    now: [f64; 3],
    /// A slow error's Ornstein–Uhlenbeck process before its smoothing, mm.
    drift: [f64; 3],
    /// Per-axis SD, mm.
    sd: f64,
    /// The OU step's decay.
    decay: f64,
    /// The SD of the OU step's draw, mm.
    kick: f64,
    /// The force the float's seal and the pad's backing hold, N.
    held: f64,
    /// The pad backing's stiffness, N/mm.
    backing: f64,
}

impl Draws {
    fn new(error: PoseError, backing: f64) -> Draws {
        let sd = error.size / 3f64.sqrt();
        let mut rng = ChaCha8Rng::seed_from_u64(error.seed ^ 0x706f_7365);
        // The smoothed process's SD is the drift's times √(τ / (τ + τ_s)): the drift is
        // drawn that much larger so that the error has the size asked for.
        let drift_sd = sd * (1.0 + SLOW_SMOOTHING_S / SLOW_CORRELATION_S).sqrt();
        let drift = [(); 3].map(|_| gaussian(&mut rng, drift_sd));
        let now = match error.kind {
            ErrorKind::Slow => drift,
            ErrorKind::PassToPass => [sd; 3],
            ErrorKind::White => [0.0; 3],
        };
        let decay = (-TICK_S / SLOW_CORRELATION_S).exp();
        Draws {
            error,
            rng,
            now,
            drift,
            sd,
            decay,
            kick: (1.0 - decay * decay).sqrt() * drift_sd,
            held: 0.0,
            backing,
        }
    }

    /// The error at a tick and the force error it makes, N; `heading` gives the path's
    /// direction there (unit, in the plane) and the sag's slope along it, which only
    /// backlash needs.
    fn next(&mut self, heading: impl FnOnce() -> ([f64; 2], f64)) -> ([f64; 3], f64) {
        let before = self.now[2];
        match self.error.kind {
            ErrorKind::Slow => {
                let follow = TICK_S / SLOW_SMOOTHING_S;
                for (v, d) in self.now.iter_mut().zip(&mut self.drift) {
                    *d = self.decay * *d + gaussian(&mut self.rng, self.kick);
                    *v += follow * (*d - *v);
                }
            }
            ErrorKind::White => {
                for v in &mut self.now {
                    *v = gaussian(&mut self.rng, self.sd);
                }
            }
            ErrorKind::PassToPass => {
                let (along, rise) = heading();
                // An axis takes up its backlash once it clearly moves one way: a pass
                // nearly along one axis leaves the other where it was.
                for (axis, d) in [along[0], along[1]].into_iter().enumerate() {
                    if d.abs() > 0.3 {
                        self.now[axis] = self.sd * d.signum();
                    }
                }
                if rise.abs() > 0.01 {
                    self.now[2] = self.sd * rise.signum();
                }
            }
        }
        // The float: the seal holds while the backing's force change stays within its
        // friction, and slips beyond it; the air column adds its spring.
        let float = self.error.float;
        let moved = self.now[2] - before;
        self.held = (self.held - self.backing * moved).clamp(-float.friction, float.friction);
        (self.now, self.held - float.stiffness * self.now[2])
    }
}

/// Walks `polisher`'s path once along `dwell`'s feed from `start`, the pad displaced by
/// `error` in the plane and pressed by the plan's force plus what the error's height
/// makes of it through the float; the pad square to the glass (a tilt's share is
/// measured apart, docs/polishing.md "Results").
pub fn walk(
    polisher: &Polisher,
    start: &HeightMap,
    dwell: &Dwell,
    error: &PoseError,
) -> Result<Walked> {
    let plan = polisher.feed(dwell)?;
    let path = polisher.path();
    let length = path.length();
    let pad = polisher.setup.pad;
    let footprint = pad.footprint(polisher.mirror.radius());
    let (n, pitch) = (polisher.grid.n, polisher.grid.pitch);
    // The backing under the whole pad, N/mm.
    let mut draws = Draws::new(*error, pad.stiffness * pad.area());
    let mut surface = start.clone();
    let (mut arc, mut ticks) = (0.0, 0usize);
    let (mut squared, mut force_squared) = (0.0, 0.0);
    while arc < length {
        let [x, y] = path.at(arc);
        // The path's direction over the next millimetre and the sag's slope along it.
        let heading = || {
            let [ax, ay] = path.at((arc + 1.0).min(length));
            let step = (ax - x).hypot(ay - y);
            if step > 0.0 {
                let sag = |x: f64, y: f64| polisher.mirror.target(x, y).position.z;
                let rise = (sag(ax, ay) - sag(x, y)) / step;
                ([(ax - x) / step, (ay - y) / step], rise)
            } else {
                ([0.0, 0.0], 0.0)
            }
        };
        let (e, force_error) = if error.size > 0.0 {
            draws.next(heading)
        } else {
            ([0.0; 3], 0.0)
        };
        squared += e.iter().map(|v| v * v).sum::<f64>();
        force_squared += force_error * force_error;
        let contact = pad.contact([0.0, 0.0], (dwell.force + force_error).max(0.0));
        let tick = pad.tick([x + e[0], y + e[1]], &contact, TICK_S);
        footprint.remove_tick(n, pitch, &polisher.glass, &tick, &mut surface.values);
        arc += plan.feed_at(arc) * TICK_S;
        ticks += 1;
    }
    let count = ticks.max(1) as f64;
    Ok(Walked {
        surface,
        error_rms: (squared / count).sqrt(),
        force_sd: (force_squared / count).sqrt(),
        ticks,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::polish::surface::{draw, StartingPoint};
    use crate::polish::Setup;
    use crate::twin::PathKind;

    /// A polisher on `kind` at `pitch` mm with its first plan for surface 1.
    fn planned(kind: PathKind, pitch: f64) -> (Polisher, HeightMap, Dwell) {
        let mut setup = Setup::new(kind);
        setup.pitch = pitch;
        let mut polisher = Polisher::new(setup).unwrap();
        let surface = draw(
            polisher.grid,
            polisher.mirror.radius(),
            &polisher.clear,
            &StartingPoint::default(),
            1,
        );
        let dwell = polisher.plan(&surface).unwrap();
        (polisher, surface, dwell)
    }

    /// The glass an error-free walk takes off, as a map of depths removed.
    fn removed(polisher: &Polisher, dwell: &Dwell, error: &PoseError) -> (HeightMap, Walked) {
        let zero = HeightMap::zeros(polisher.grid);
        let walked = walk(polisher, &zero, dwell, error).unwrap();
        (
            HeightMap {
                grid: polisher.grid,
                values: walked.surface.values.iter().map(|v| -v).collect(),
            },
            walked,
        )
    }

    /// Walking the planned feed along each path with the pad square to the glass at the
    /// plan's force removes what the plan said (the feed realises the dwell); on the
    /// raster the plan removes most of the error.
    #[test]
    fn the_feed_realises_the_plan() {
        for kind in PathKind::ALL {
            let (polisher, surface, dwell) = planned(kind, 4.0);
            let (walked, _) = removed(&polisher, &dwell, &PoseError::NONE);
            let miss = HeightMap {
                grid: polisher.grid,
                values: walked
                    .values
                    .iter()
                    .zip(&dwell.removal.values)
                    .map(|(w, p)| w - p)
                    .collect(),
            }
            .figure(&polisher.clear);
            assert!(
                miss.rms < 2.5,
                "{kind:?}: walked less planned removal {miss:?}"
            );
            if kind == PathKind::Grid {
                let start = surface.figure(&polisher.clear);
                assert!(
                    dwell.planned.rms < 0.5 * start.rms,
                    "{start:?} → {:?}",
                    dwell.planned
                );
            }
        }
    }

    /// Each kind realises its size (backlash exactly; jitter and drift as their draws
    /// allow), the same seed gives the same glass bit for bit, an ideal float keeps the
    /// force and a slow error's imprint grows with its size.
    #[test]
    fn errors_have_their_size_and_their_imprint_grows_with_it() {
        let (polisher, _, dwell) = planned(PathKind::Grid, 6.0);
        let (reference, _) = removed(&polisher, &dwell, &PoseError::NONE);
        let imprint = |error: &PoseError| {
            let (map, walked) = removed(&polisher, &dwell, error);
            let mut diff = HeightMap {
                grid: polisher.grid,
                values: map
                    .values
                    .iter()
                    .zip(&reference.values)
                    .map(|(a, b)| a - b)
                    .collect(),
            };
            diff.remove_plane(&polisher.clear);
            (diff.figure(&polisher.clear).rms, walked)
        };
        let mut seen = Vec::new();
        for (kind, tolerance) in [
            (ErrorKind::PassToPass, 1e-12),
            (ErrorKind::White, 0.03),
            (ErrorKind::Slow, 0.4),
        ] {
            let error = PoseError {
                kind,
                size: 0.5,
                float: Float::IDEAL,
                seed: 7,
            };
            let (rms, walked) = imprint(&error);
            assert!(
                (walked.error_rms / 0.5 - 1.0).abs() <= tolerance,
                "{kind:?}: RMS {} mm for 0.5",
                walked.error_rms
            );
            assert_eq!(walked.force_sd, 0.0, "{kind:?}: an ideal float");
            let (again, _) = imprint(&error);
            assert_eq!(rms.to_bits(), again.to_bits(), "{kind:?}: the same seed");
            seen.push(rms);
        }
        let slow = |size| PoseError {
            kind: ErrorKind::Slow,
            size,
            float: Float::IDEAL,
            seed: 7,
        };
        let (small, _) = imprint(&slow(0.05));
        let (large, _) = imprint(&slow(2.0));
        assert!(
            small > 0.0 && large > 4.0 * small,
            "a slow error's imprint: {small} nm at 0.05 mm, {large} nm at 2 mm"
        );
        // White jitter is blurred away by the footprint: less imprint than the drift.
        assert!(
            seen[1] < seen[2],
            "white {} against slow {} nm",
            seen[1],
            seen[2]
        );
    }

    /// A stiff float turns a height error into a force error: the seal's friction once
    /// the backing's force exceeds it, the air column's spring beside it.
    #[test]
    fn a_stiff_float_makes_force_errors() {
        let (polisher, _, dwell) = planned(PathKind::Grid, 6.0);
        let error = PoseError {
            kind: ErrorKind::White,
            size: 0.1,
            float: Float::STIFF,
            seed: 3,
        };
        let (_, walked) = removed(&polisher, &dwell, &error);
        // Per tick the height jumps by about 0.058·√2 mm: the backing (0.2 N/mm³ over
        // the pad's 707 mm²) would take 11 N, so the seal slips and holds ±3 N; the air
        // column adds 4 N/mm × 0.058 mm = 0.23 N.
        let expected = (3.0f64.powi(2) + (4.0 * 0.1 / 3f64.sqrt()).powi(2)).sqrt();
        assert!(
            (walked.force_sd / expected - 1.0).abs() < 0.1,
            "force SD {} N, expected about {expected}",
            walked.force_sd
        );
    }
}
