//! What a recording came from: a sidecar `<recording>.run.toml` beside each simulated CSV
//! names its path and placement, seed, machine, controller and the machine's state at
//! its start (docs/twin.md "Sessions"), so that anyone can tell which runs share data.

use std::path::{Path, PathBuf};

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::noise::gaussian;
use super::simulate::{SimConfig, DEFAULT_FEED, DEFAULT_FORCE};
use super::sources::Day;
use super::trajectory::{PathKind, PathParams};

/// The provenance of one simulated run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunInfo {
    /// `grid`, `fermat`, `hilbert`, `rosette` or `calibration`.
    pub path: String,
    /// Rotation of the pattern on the part about the mirror axis, deg.
    pub rotation_deg: f64,
    /// Whether the pattern is walked from its other end.
    pub reverse: bool,
    /// Length of the run, s (0 for a calibration set).
    pub seconds: f64,
    /// Seed of the run: force, feed modulation, sensor noise and drift.
    pub seed: u64,
    /// Seed of the machine: geometric errors, non-geometric sources, sensor mounting.
    pub machine_seed: u64,
    /// The model the controller drives with: `nominal` or the calibration file.
    pub controller: String,
    /// `cold` (the session's first run) or `warm` (after earlier runs of the session).
    pub start: String,
    /// Session time at the run's start, s.
    pub session_clock_s: f64,
    /// Temperature rise of each screw above ambient at the run's start, K.
    pub screw_rise_k: [f64; 3],
    /// The session the run belongs to, from 1 (recordings of one session: 1).
    #[serde(default = "one")]
    pub session: usize,
    /// Mean feed along the path, mm/s (the twin's default 20).
    #[serde(default = "default_feed")]
    pub feed_mm_s: f64,
    /// Mean polishing force, N (the twin's default 100).
    #[serde(default = "default_force")]
    pub force_n: f64,
    /// The session's day: mean ambient minus the calibration day's, K.
    #[serde(default)]
    pub ambient_offset_k: f64,
    /// The session's day: phase of the ambient cycle added to the machine's, rad.
    #[serde(default)]
    pub ambient_phase_shift: f64,
}

fn one() -> usize {
    1
}

fn default_feed() -> f64 {
    DEFAULT_FEED
}

fn default_force() -> f64 {
    DEFAULT_FORCE
}

impl RunInfo {
    /// A polishing run's info (`start` and the temperatures filled in by the caller).
    pub fn polishing(kind: PathKind, params: &PathParams, seconds: f64, seed: u64) -> RunInfo {
        RunInfo {
            path: kind.name().into(),
            rotation_deg: params.rotation_deg,
            reverse: params.reverse,
            seconds,
            seed,
            machine_seed: 1,
            controller: "nominal".into(),
            start: "cold".into(),
            session_clock_s: 0.0,
            screw_rise_k: [0.0; 3],
            session: 1,
            feed_mm_s: DEFAULT_FEED,
            force_n: DEFAULT_FORCE,
            ambient_offset_k: 0.0,
            ambient_phase_shift: 0.0,
        }
    }

    /// The day the run's session was on.
    pub fn day(&self) -> Day {
        Day {
            ambient_offset_k: self.ambient_offset_k,
            ambient_phase_shift: self.ambient_phase_shift,
        }
    }

    /// The run's placement on the part (default spacing and margin).
    pub fn placement(&self) -> PathParams {
        PathParams {
            rotation_deg: self.rotation_deg,
            reverse: self.reverse,
            ..PathParams::default()
        }
    }

    /// A calibration measurement set with run seed `seed` on the default machine, measured
    /// cold under the nominal controller.
    pub fn calibration(seed: u64) -> RunInfo {
        RunInfo {
            path: "calibration".into(),
            rotation_deg: 0.0,
            reverse: false,
            seconds: 0.0,
            seed,
            machine_seed: 1,
            controller: "nominal".into(),
            start: "cold".into(),
            session_clock_s: 0.0,
            screw_rise_k: [0.0; 3],
            session: 1,
            feed_mm_s: DEFAULT_FEED,
            force_n: DEFAULT_FORCE,
            ambient_offset_k: 0.0,
            ambient_phase_shift: 0.0,
        }
    }

    /// The sidecar's path for a recording at `csv`: `<csv without .csv>.run.toml`.
    pub fn sidecar(csv: &Path) -> PathBuf {
        csv.with_extension("run.toml")
    }

    /// Writes the sidecar of the recording at `csv` (atomically).
    pub fn write(&self, csv: &Path) -> std::io::Result<()> {
        crate::atomic::write(&Self::sidecar(csv), self.to_toml()?.as_bytes())
    }

    /// The sidecar's text.
    pub fn to_toml(&self) -> std::io::Result<String> {
        toml::to_string(self).map_err(std::io::Error::other)
    }

    /// Reads the sidecar of the recording at `csv`; the error names the file (and the
    /// field, for a number that is not finite or a negative time: TOML spells `nan` and
    /// `inf`, and a NaN length would pass every comparison a resumed run makes).
    pub fn read(csv: &Path) -> Result<RunInfo, String> {
        let path = Self::sidecar(csv);
        let text =
            std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        let info: RunInfo =
            toml::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
        info.check()
            .map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(info)
    }

    /// Every number finite, and the times not negative.
    fn check(&self) -> Result<(), String> {
        let [s0, s1, s2] = self.screw_rise_k;
        let numbers = [
            ("rotation_deg", self.rotation_deg),
            ("seconds", self.seconds),
            ("session_clock_s", self.session_clock_s),
            ("screw_rise_k", s0),
            ("screw_rise_k", s1),
            ("screw_rise_k", s2),
            ("feed_mm_s", self.feed_mm_s),
            ("force_n", self.force_n),
            ("ambient_offset_k", self.ambient_offset_k),
            ("ambient_phase_shift", self.ambient_phase_shift),
        ];
        for (field, value) in numbers {
            if !value.is_finite() {
                return Err(format!("`{field}` must be a finite number, got {value}"));
            }
        }
        for (field, value) in [
            ("seconds", self.seconds),
            ("session_clock_s", self.session_clock_s),
        ] {
            if value < 0.0 {
                return Err(format!(
                    "`{field}` is a time and cannot be negative, got {value}"
                ));
            }
        }
        Ok(())
    }
}

/// Conditions of one session that differ from day to day in a shop (docs/twin.md
/// "Days"): the ambient (its mean against the calibration day's and where in its slow
/// cycle the session starts), the program's mean feed, and the polishing force the
/// pneumatic supply is set to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Conditions {
    /// The ambient of the day.
    pub day: Day,
    /// Mean feed along the path, mm/s.
    pub feed_mm_s: f64,
    /// Mean polishing force, N.
    pub force_n: f64,
}

impl Conditions {
    /// The calibration day at the twin's default feed and force: every single-session
    /// recording and the first held-out session run under these.
    pub const NOMINAL: Conditions = Conditions {
        day: Day::CALIBRATION,
        feed_mm_s: DEFAULT_FEED,
        force_n: DEFAULT_FORCE,
    };

    /// Standard deviation of a day's mean ambient about the calibration day's, K, and its
    /// clamp: a temperature-controlled optics shop held to about ±1 K.
    pub const AMBIENT_SD_K: f64 = 0.5;
    /// The clamp of a day's ambient offset, K.
    pub const AMBIENT_LIMIT_K: f64 = 1.5;
    /// The range of a program's mean feed, mm/s (the default 20 ± 20 %).
    pub const FEED_RANGE: (f64, f64) = (16.0, 24.0);
    /// Relative standard deviation of the supply's force setting, and its clamp.
    pub const FORCE_SD: f64 = 0.03;
    /// The clamp of the force setting's relative deviation.
    pub const FORCE_LIMIT: f64 = 0.1;

    /// A day's conditions drawn from `seed`: ambient offset normal (SD
    /// [`Conditions::AMBIENT_SD_K`], clamped), the cycle's phase uniform, the feed uniform
    /// in [`Conditions::FEED_RANGE`], the force 100 N times a normal factor (SD 3 %,
    /// clamped at 10 %). Training and held-out sessions draw from this one distribution.
    pub fn draw(seed: u64) -> Conditions {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x4441_5953);
        let offset = gaussian(&mut rng, Self::AMBIENT_SD_K)
            .clamp(-Self::AMBIENT_LIMIT_K, Self::AMBIENT_LIMIT_K);
        let phase = rng.random_range(0.0..std::f64::consts::TAU);
        let feed = rng.random_range(Self::FEED_RANGE.0..Self::FEED_RANGE.1);
        let force =
            1.0 + gaussian(&mut rng, Self::FORCE_SD).clamp(-Self::FORCE_LIMIT, Self::FORCE_LIMIT);
        Conditions {
            day: Day {
                ambient_offset_k: offset,
                ambient_phase_shift: phase,
            },
            feed_mm_s: feed,
            force_n: DEFAULT_FORCE * force,
        }
    }

    /// Sets a run's mean feed and force to these (its day is in the machine's state).
    pub fn apply(&self, config: &mut SimConfig) {
        config.feed = self.feed_mm_s;
        config.force_mean = self.force_n;
    }

    /// Writes these conditions into a run's info.
    pub fn stamp(&self, info: &mut RunInfo) {
        info.feed_mm_s = self.feed_mm_s;
        info.force_n = self.force_n;
        info.ambient_offset_k = self.day.ambient_offset_k;
        info.ambient_phase_shift = self.day.ambient_phase_shift;
    }
}

/// Where the training recordings of a multi-session recipe lie on the part.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Placement {
    /// Every session at the default placement.
    Fixed,
    /// Session s at [`PathParams::training`]`(kind, s − 1)`: quarter turns.
    Varied,
    /// Session s at [`PathParams::spread`]`(kind, s − 1)`: turns spread over every angle.
    Spread,
}

impl Placement {
    /// `fixed`, `varied` or `spread`.
    pub fn name(self) -> &'static str {
        match self {
            Placement::Fixed => "fixed",
            Placement::Varied => "varied",
            Placement::Spread => "spread",
        }
    }
}

impl std::str::FromStr for Placement {
    type Err = String;
    fn from_str(s: &str) -> Result<Placement, String> {
        match s {
            "fixed" => Ok(Placement::Fixed),
            "varied" => Ok(Placement::Varied),
            "spread" => Ok(Placement::Spread),
            _ => Err(format!(
                "unknown placement {s:?}: expected fixed, varied or spread"
            )),
        }
    }
}

/// In which order each session of a multi-session recipe runs its paths.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PathOrder {
    /// Grid, fermat, hilbert in every session.
    #[default]
    Fixed,
    /// Session s starts with path (s − 1) mod 3 of grid, fermat, hilbert and goes round:
    /// every path starts a day cold in one session of three, and runs after the other
    /// two (warm) in another.
    Rotated,
}

impl PathOrder {
    /// `fixed` or `rotated`.
    pub fn name(self) -> &'static str {
        match self {
            PathOrder::Fixed => "fixed",
            PathOrder::Rotated => "rotated",
        }
    }

    /// How a recipe's description says this order: nothing for the fixed one.
    pub fn phrase(self) -> &'static str {
        match self {
            PathOrder::Fixed => "",
            PathOrder::Rotated => ", the paths' order rotated from session to session",
        }
    }

    /// The paths session `session` (from 1; 0 reads as 1) runs, in order.
    pub fn paths(self, session: usize) -> [PathKind; 3] {
        let mut kinds = PathKind::TRAINING;
        if self == PathOrder::Rotated {
            kinds.rotate_left(session.saturating_sub(1) % PathKind::TRAINING.len());
        }
        kinds
    }
}

impl std::str::FromStr for PathOrder {
    type Err = String;
    fn from_str(s: &str) -> Result<PathOrder, String> {
        match s {
            "fixed" => Ok(PathOrder::Fixed),
            "rotated" => Ok(PathOrder::Rotated),
            _ => Err(format!(
                "unknown path order {s:?}: expected fixed or rotated"
            )),
        }
    }
}

/// How a training set is recorded (docs/twin.md "Sessions"): the minutes per path split
/// over `sessions` sessions. One session is the protocol's single session: cold on the
/// calibration day, grid, fermat and hilbert in turn at the default placement, 30 s idle
/// between runs. With several, each session is a day of its own: it starts cold under
/// conditions drawn from [`Conditions::draw`], runs the three paths for minutes/sessions
/// each at its placement, in its order, with its own seeds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Recipe {
    /// Sessions per training set (1: the single session).
    pub sessions: usize,
    /// Where each session's runs lie on the part.
    pub placement: Placement,
    /// In which order each session runs its paths (absent in a folder pinned before the
    /// choice existed: fixed).
    #[serde(default)]
    pub path_order: PathOrder,
}

impl Default for Recipe {
    fn default() -> Recipe {
        Recipe::SINGLE
    }
}

/// One session of a [`Recipe`]: its conditions and its runs' infos (path, placement,
/// length, seed, conditions; the start and temperatures are filled in when recorded).
#[derive(Clone, Debug, PartialEq)]
pub struct PlannedSession {
    /// The session's conditions.
    pub conditions: Conditions,
    /// Its runs in the order they run (grid, fermat, hilbert unless the recipe's
    /// [`PathOrder`] rotates them).
    pub runs: Vec<RunInfo>,
}

impl Recipe {
    /// The protocol's single session at the default placement.
    pub const SINGLE: Recipe = Recipe {
        sessions: 1,
        placement: Placement::Fixed,
        path_order: PathOrder::Fixed,
    };
    /// The most sessions a recipe may have.
    pub const MAX_SESSIONS: usize = 64;
    /// The shortest run a session may have, minutes: 750 control ticks, whose 10 % test
    /// block still holds a 48-tick window (the demo's).
    pub const MIN_RUN_MINUTES: f64 = 0.25;

    /// The training data in words, for reports: `minutes` per path recorded with this
    /// recipe, seeds from `first_seed` (a multi-session recipe's from 100 × `first_seed`).
    pub fn describe(&self, minutes: f64, first_seed: u64) -> String {
        if self.sessions == 1 && self.placement == Placement::Fixed {
            return format!(
                "one session starting cold, grid, fermat and hilbert at their training \
                 placement, {minutes} min each, seeds {first_seed}–{}",
                first_seed + 2
            );
        }
        let order = self.path_order.phrase();
        format!(
            "{minutes} min per path in {} session(s), each a day of its own starting cold \
             (its ambient, feed and force drawn as docs/twin.md \"Days\" says), placements {}{order}, \
             seeds from {}",
            self.sessions,
            self.placement.name(),
            first_seed * 100
        )
    }

    /// Refuses what cannot be recorded at `minutes` per path: the message says what the
    /// number of sessions may be (the caller names the setting).
    pub fn validate(&self, minutes: f64) -> Result<(), String> {
        if self.sessions == 0 || self.sessions > Self::MAX_SESSIONS {
            return Err(format!(
                "1 to {} sessions per training set, got {}",
                Self::MAX_SESSIONS,
                self.sessions
            ));
        }
        if self.sessions > 1 && minutes / (self.sessions as f64) < Self::MIN_RUN_MINUTES {
            return Err(format!(
                "{} sessions of {minutes} min per path leave {:.3} min per run; \
                 each run needs at least {} min, so at most {} sessions",
                self.sessions,
                minutes / self.sessions as f64,
                Self::MIN_RUN_MINUTES,
                (minutes / Self::MIN_RUN_MINUTES).floor()
            ));
        }
        Ok(())
    }

    /// The recording file name of `kind` in session `session` (from 1): `grid.csv` for a
    /// single session, `grid.s03.csv` otherwise.
    pub fn file_name(&self, kind: PathKind, session: usize) -> String {
        if self.sessions == 1 {
            format!("{}.csv", kind.name())
        } else {
            format!("{}.s{session:02}.csv", kind.name())
        }
    }

    /// The sessions to record with `minutes` per path in all, from `first_seed` on the
    /// machine `machine_seed` (in every run's info). A single session's runs take seeds
    /// `first_seed`, +1, +2 and run under [`Conditions::NOMINAL`]; with several, session
    /// s's run of path i (grid 0, fermat 1, hilbert 2, whatever the order it runs in)
    /// takes seed `first_seed · 100 + 3(s − 1) + i` (apart from the held-out sessions'
    /// seeds), and session s draws its conditions from `first_seed · 1000 + s`.
    pub fn plan(&self, minutes: f64, first_seed: u64, machine_seed: u64) -> Vec<PlannedSession> {
        let seconds = minutes * 60.0 / self.sessions as f64;
        (1..=self.sessions)
            .map(|s| {
                let conditions = if self.sessions == 1 {
                    Conditions::NOMINAL
                } else {
                    Conditions::draw(first_seed * 1000 + s as u64)
                };
                let runs = self
                    .path_order
                    .paths(s)
                    .into_iter()
                    .map(|kind| {
                        // A run's seed follows its path, whatever the order.
                        let i = PathKind::TRAINING
                            .iter()
                            .position(|k| *k == kind)
                            .unwrap_or(0);
                        let params = match self.placement {
                            Placement::Fixed => PathParams::default(),
                            Placement::Varied => PathParams::training(kind, s - 1),
                            Placement::Spread => PathParams::spread(kind, s - 1),
                        };
                        let seed = if self.sessions == 1 {
                            first_seed + i as u64
                        } else {
                            first_seed * 100 + (3 * (s - 1) + i) as u64
                        };
                        let mut info = RunInfo::polishing(kind, &params, seconds, seed);
                        info.machine_seed = machine_seed;
                        info.session = s;
                        conditions.stamp(&mut info);
                        info
                    })
                    .collect();
                PlannedSession { conditions, runs }
            })
            .collect()
    }
}
