//! The demo protocol end to end on the embedded twin: the calibration set on a cold
//! machine, the EKF calibration, the training sessions under the calibrated controller
//! (cold-start days at spread placements, the second half recorded again with a round-0
//! IASTGCN compensating), the dataset, IASTGCN, its three ablations and the dense
//! baselines trained and refined the same way, then Tables III and V on held-out
//! sessions, the mirror polished with the recommended model (docs/polishing.md) and the
//! report folder.

mod jobs;
mod plan;
mod report;
mod run;

use super::evaluate::HeldOutConfig;
pub use super::polish::PolishSpec;
use super::polish_sweep::{self, Mark, SweepSpec};
pub use super::protocol::{CALIBRATION_SEED, TRAINING_SEED};
use super::recipe;
use crate::polish::StartingPoint;
use crate::train::RunConfig;
use crate::twin::Recipe;
pub use run::demo;

/// Length of each of the demo's training recordings, minutes: the most data with which
/// three seeds of its eight models fitted `make demo`'s time on 2 CPU cores when it was
/// chosen (docs/results.md "Why 8 minutes per path and L = 2"; the demo's times now:
/// "How long it takes").
pub const DEMO_MINUTES: f64 = 8.0;

/// The demo's training seeds: two, so that `make demo` stays within 10 minutes on 2 CPU
/// cores with every model, the closed-loop data and the mirror; each seed's models are
/// the same bits whichever seeds run beside them, and a third seed moved the headline by
/// under half a point (docs/results.md "How long it takes"; `--seeds 1,2,3` runs more).
pub const DEMO_SEEDS: [u64; 2] = [1, 2];

/// What the demo runs.
#[derive(Clone, Debug, PartialEq)]
pub struct DemoConfig {
    /// The run config of every model (the embedded assets/demo.toml by default).
    pub run: RunConfig,
    /// Where `run` came from, for the report.
    pub run_source: String,
    /// Length of each training recording, minutes.
    pub minutes: f64,
    /// The held-out session.
    pub held_out: HeldOutConfig,
    /// Training seeds (`[train] seed`): every model is trained with each, and Tables III
    /// and V report mean ± SD over them with IASTGCN compared seed by seed. With one seed
    /// the models keep their plain names; with more they are `<model>.seed<k>`.
    pub seeds: Vec<u64>,
    /// Also train and evaluate the spatio-temporal baselines of Table III (ConvLSTM, T-GCN,
    /// EAT-GCN, ST-GAT) at the same budget; they take longer than the demo's 10 minutes on
    /// 2 CPU cores (docs/usage.md "demo", `--all-models`), so they are off by default.
    pub all_models: bool,
    /// How the training set is recorded (docs/twin.md "Sessions").
    pub recipe: Recipe,
    /// The mirror (docs/polishing.md): the recommended model polishing a surface against
    /// the other controllers, into `polish/` and a report section; `None` leaves it out.
    pub mirror: Option<PolishSpec>,
    /// Closed-loop training data ([`ClosedLoopRound`]): a round-0 IASTGCN (the first
    /// seed, core stage) trained on the first half of the recipe's sessions compensates
    /// the other half, at the held-out session's prediction rate, as they are recorded
    /// again; every model trains on the first half open loop and the rest closed loop.
    /// Needs 2 sessions or more.
    pub closed_loop: bool,
}

/// The demo's mirror: one surface, two iterations on the raster (about a minute and a
/// half on 2 cores; `iastgcn polish` runs more).
pub fn demo_mirror() -> PolishSpec {
    PolishSpec {
        iterations: 2,
        surface_seeds: vec![1],
        seed: 501,
        warm_up_minutes: 2.0,
        every: DEMO_HELD_OUT.every,
        start: StartingPoint::default(),
        split_nominal: false,
    }
}

/// The demo's look at when compensation pays (docs/polishing.md "When compensation
/// pays"): its own pad only, four sizes around the controllers' errors, every kind and
/// both floats, one error seed (about 25 s on 2 cores; `iastgcn polish-sweep` draws the
/// whole map); `marks` beside the paper's.
pub fn demo_sweep(marks: Vec<Mark>) -> SweepSpec {
    SweepSpec {
        footprints: vec![polish_sweep::DEFAULT_FOOTPRINT],
        sizes: vec![0.03, 0.1, 0.3, 1.0],
        seeds: vec![1],
        marks: [polish_sweep::paper_marks(), marks].concat(),
        ..SweepSpec::default()
    }
}

/// How the demo records its training set: the default recipe's sessions
/// ([`recipe::DEFAULT`], the best measured).
pub const DEMO_RECIPE: Recipe = recipe::DEFAULT.sessions;

/// The demo's held-out sessions: three, of 0.5 min runs from seed 301, the first after
/// 2 min of warm-up, a prediction at the default recipe's rate (every tick: with
/// closed-loop training data recorded at that rate the models use the faster loop).
pub const DEMO_HELD_OUT: HeldOutConfig = HeldOutConfig {
    minutes: 0.5,
    seed: 301,
    warm_up_minutes: 2.0,
    every: recipe::DEFAULT.every,
    sessions: 3,
};

impl Default for DemoConfig {
    fn default() -> DemoConfig {
        DemoConfig {
            run: RunConfig::demo(),
            run_source: "assets/demo.toml (embedded)".into(),
            minutes: DEMO_MINUTES,
            held_out: DEMO_HELD_OUT,
            seeds: DEMO_SEEDS.to_vec(),
            all_models: false,
            recipe: DEMO_RECIPE,
            mirror: Some(demo_mirror()),
            closed_loop: recipe::DEFAULT.closed_loop,
        }
    }
}
