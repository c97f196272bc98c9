//! What `iastgcn reproduce` runs (the protocol a folder is pinned to) and its jobs.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::experiment::jobs::JobRecord;
use crate::experiment::protocol::{
    check_closed_loop_sessions, check_seeds, sessions_setting, ModelFiles, MACHINE_SEED,
};
use crate::experiment::recipe;
use crate::experiment::report::seeds::seeded_name;
use crate::model::Variant;
use crate::train::RunConfig;
use crate::twin::Recipe;

/// What `iastgcn reproduce` runs: the run config of every model, the length of the
/// training recordings, the training seeds and the models.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Protocol {
    /// Length of each training recording, minutes.
    pub minutes: f64,
    /// Training seeds (`[train] seed` of each job).
    pub seeds: Vec<u64>,
    /// Models by name (docs/model.md), in the report's order.
    pub models: Vec<String>,
    /// The run config every model trains with (its variant and seed set per job).
    pub run: RunConfig,
    /// Shares of the training windows (each in (0, 1)) at which the learning curve's
    /// models are trained again, core stage only, for every seed.
    #[serde(default)]
    pub fractions: Vec<f64>,
    /// The learning curve's models.
    #[serde(default)]
    pub curve_models: Vec<String>,
    /// The twin machine (seed of its geometric and non-geometric errors) the data and
    /// the held-out session come from. One folder holds one machine; spread over
    /// machines comes from several folders merged (`reproduce --merge`).
    #[serde(default = "default_machine")]
    pub machine_seed: u64,
    /// How the training set is recorded: the minutes per path in one session, or split
    /// over several (docs/twin.md "Sessions").
    #[serde(default)]
    pub recipe: Recipe,
    /// Closed-loop training data (docs/usage.md "`reproduce`"): in the data stage a
    /// round-0 IASTGCN (the first seed, core stage) trained on the first half of the
    /// recipe's sessions compensates the other half as they are recorded again, at the
    /// held-out sessions' prediction rate, and every job trains on the first half open
    /// loop and the rest closed loop. Needs 2 sessions or more.
    #[serde(default)]
    pub closed_loop: bool,
}

fn default_machine() -> u64 {
    MACHINE_SEED
}

impl Protocol {
    /// The paper's protocol: its model and training sizes (the default run config), three
    /// 135-minute training recordings (about 42k windows of 100 steps at stride 20, the
    /// paper's count), every model, seeds 1–3; the learning curve of IASTGCN and T-GCN
    /// (the best baseline on the twin so far, docs/results.md) at 25 % and 50 %; the data
    /// recorded as the default recipe says ([`recipe::DEFAULT`], the best measured;
    /// [`recipe::PAPER`] is the paper's own single session, open loop).
    pub fn paper() -> Protocol {
        Protocol {
            minutes: 135.0,
            seeds: vec![1, 2, 3],
            models: Variant::ALL.iter().map(|v| v.name().to_string()).collect(),
            run: RunConfig::default(),
            fractions: vec![0.25, 0.5],
            curve_models: vec!["iastgcn".into(), "tgcn".into()],
            machine_seed: MACHINE_SEED,
            recipe: recipe::DEFAULT.sessions,
            closed_loop: recipe::DEFAULT.closed_loop,
        }
    }

    /// The jobs: the models of the tables seed by seed (every model of the first seed
    /// before the second seed's), then the learning curve's, share by share.
    pub fn jobs(&self) -> Result<Vec<Job>> {
        let parse = |names: &[String]| {
            names
                .iter()
                .map(|m| {
                    Variant::parse(m).ok_or_else(|| {
                        Error::Invalid(format!("unknown model {m:?} ({})", Variant::names()))
                    })
                })
                .collect::<Result<Vec<_>>>()
        };
        let (variants, curve) = (parse(&self.models)?, parse(&self.curve_models)?);
        let mut jobs: Vec<Job> = Vec::new();
        for &seed in &self.seeds {
            jobs.extend(variants.iter().map(|&variant| Job {
                variant,
                seed,
                fraction: 1.0,
            }));
        }
        for &fraction in &self.fractions {
            for &seed in &self.seeds {
                jobs.extend(curve.iter().map(|&variant| Job {
                    variant,
                    seed,
                    fraction,
                }));
            }
        }
        Ok(jobs)
    }

    /// Checks sizes, seeds, models and the run config.
    pub fn validate(&self) -> Result<()> {
        let seconds = self.minutes * 60.0;
        if !(seconds.is_finite() && seconds > 0.0 && seconds <= crate::data::MAX_RUN_SECONDS) {
            return Err(Error::Invalid(format!(
                "minutes: a training recording lasts more than 0 and at most {} min, got {}",
                crate::data::MAX_RUN_SECONDS / 60.0,
                self.minutes
            )));
        }
        self.recipe
            .validate(self.minutes)
            .map_err(sessions_setting)?;
        if self.closed_loop {
            check_closed_loop_sessions(self.recipe.sessions, " (or closed_loop = false)")?;
        }
        check_seeds(&self.seeds)?;
        if self.models.is_empty() {
            return Err(Error::Invalid("reproduce needs at least one model".into()));
        }
        for (field, list) in [
            ("models", &self.models),
            ("curve models", &self.curve_models),
        ] {
            for (i, m) in list.iter().enumerate() {
                if list[..i].contains(m) {
                    return Err(Error::Invalid(format!("{field}: {m} is listed twice")));
                }
            }
        }
        for (i, f) in self.fractions.iter().enumerate() {
            if !(*f > 0.0 && *f < 1.0) || self.fractions[..i].contains(f) {
                return Err(Error::Invalid(format!(
                    "fractions: {f} must be in (0, 1) and listed once (the full set is \
                     the tables' models)"
                )));
            }
        }
        if !self.fractions.is_empty() && self.curve_models.is_empty() {
            return Err(Error::Invalid(
                "fractions given but no curve models to train at them".into(),
            ));
        }
        self.jobs()?;
        self.run.validate().map_err(Error::Invalid)
    }

    /// Whether `other` is this protocol on another twin machine (or the same): every
    /// setting but the machine and where the steps run agrees.
    pub fn same_but_machine(&self, other: &Protocol) -> bool {
        let (mut a, mut b) = (self.comparable(), other.comparable());
        a.machine_seed = 0;
        b.machine_seed = 0;
        a == b
    }

    /// The protocol with what may change between runs of one output folder cleared:
    /// where and on how many threads the steps run.
    pub(super) fn comparable(&self) -> Protocol {
        let mut p = self.clone();
        p.run.train.backend.clear();
        p.run.train.threads = 0;
        p
    }
}

/// One model trained with one seed on a share of the training windows: the whole set
/// for the tables' models (trained, refined, evaluated), less for the learning curve's
/// (core stage only, scored on the validation and test splits).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Job {
    /// The model.
    pub variant: Variant,
    /// Its `[train] seed`.
    pub seed: u64,
    /// Share of the training windows (1 for the tables' models).
    pub fraction: f64,
}

impl Job {
    /// Whether it is one of the learning curve's jobs.
    pub fn is_curve(&self) -> bool {
        self.fraction < 1.0
    }

    /// `<model>.seed<k>` (the name of its files and of its rows in the tables), with
    /// `.train<percent>` for the learning curve's jobs.
    pub fn name(&self) -> String {
        let name = seeded_name(self.variant.name(), self.seed);
        if self.is_curve() {
            format!("{name}.train{}", (100.0 * self.fraction).round())
        } else {
            name
        }
    }

    pub(super) fn dir(&self, out: &Path) -> PathBuf {
        if self.is_curve() {
            out.join("models").join("curve")
        } else {
            out.join("models")
        }
    }

    /// Its files in the output folder `out` (the learning curve's in `models/curve/`).
    pub fn files(&self, out: &Path) -> ModelFiles {
        ModelFiles::named(&self.dir(out), &self.name(), true)
    }

    /// The record written when the job has finished.
    pub fn record_path(&self, out: &Path) -> PathBuf {
        self.dir(out).join(format!("{}.job.toml", self.name()))
    }
}

impl crate::experiment::runner::Job for Job {
    type Record = JobRecord;

    fn record_path(&self, out: &Path) -> PathBuf {
        Job::record_path(self, out)
    }

    fn describe(&self) -> String {
        format!(
            "{} seed {}{}",
            self.variant,
            self.seed,
            if self.is_curve() {
                format!(" on {:.0} % of the training windows", 100.0 * self.fraction)
            } else {
                String::new()
            }
        )
    }

    fn set_wall_seconds(record: &mut JobRecord, seconds: f64) {
        record.wall_seconds = seconds;
    }
}
