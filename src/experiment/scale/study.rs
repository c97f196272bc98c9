//! The scaling study's setup: what a folder holds ([`Study`], pinned in `study.toml`)
//! and one of its jobs ([`ScaleJob`]).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::experiment::evaluate::{HeldOutConfig, MAX_HELD_OUT_SESSIONS};
use crate::experiment::protocol::{
    check_closed_loop_sessions, check_seeds, sessions_setting, ModelFiles, MACHINE_SEED,
};
use crate::experiment::recipe;
use crate::experiment::recommend::validation_session;
use crate::experiment::report::seeds::seeded_name;
use crate::graph::Graph;
use crate::model::Variant;
use crate::train::RunConfig;
use crate::twin::Recipe;

/// The paper's Table V on its Hilbert run (its only compensated path): the share of the
/// calibrated error its IASTGCN removed, position and attitude, % (0.1393 → 0.0591 mm,
/// 0.0811 → 0.0183°).
pub const PAPER_HILBERT_REMOVED: [f64; 2] = [57.6, 77.4];

/// What `iastgcn scale` runs. A folder holds one setup (the recordings' length, the run
/// config, the machine and the held-out session, pinned in `study.toml`); sizes, seeds
/// and models may grow from one call to the next, since each job stands alone.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Study {
    /// Length of each training recording, minutes: the largest size there can be.
    pub recording_minutes: f64,
    /// Training data per path, minutes of recording, ascending, each at most
    /// `recording_minutes`.
    pub sizes: Vec<f64>,
    /// Training seeds.
    pub seeds: Vec<u64>,
    /// Models by name.
    pub models: Vec<String>,
    /// The run config every model trains with (its variant, seed and training share set
    /// per job).
    pub run: RunConfig,
    /// The twin machine of the data and the held-out session.
    pub machine_seed: u64,
    /// Length of each held-out run, minutes.
    pub held_out_minutes: f64,
    /// Seed of the first held-out run.
    pub held_out_seed: u64,
    /// Minutes of polishing before the held-out session's first scored run.
    pub warm_up_minutes: f64,
    /// Predict every this many control ticks during compensation.
    pub every: usize,
    /// How the training set is recorded (docs/twin.md "Sessions"); a study's sizes are
    /// the first m/M of each recording, of every session.
    #[serde(default)]
    pub recipe: Recipe,
    /// Held-out sessions every job is scored on ([`HeldOutConfig::session`]); studies
    /// pinned before there were several have one.
    #[serde(default = "one_session")]
    pub held_out_sessions: usize,
    /// Refine every job after its core stage (the paper's Algorithm 2, as `demo` does:
    /// the refined weights are kept only where they lower the per-window validation
    /// loss) and score the result.
    #[serde(default)]
    pub refine: bool,
    /// The sensor graph every model reads (the embedded assets/graph.toml when absent;
    /// `[model] nodes` of the run config must match it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub graph: Option<PathBuf>,
    /// Also score each model and size whose seeds have all finished as an ensemble: the
    /// controller averages the seeds' predictions (record `<model>.min<m>.ensemble`,
    /// model `<model>-ensemble`). May change between calls of one folder.
    #[serde(default)]
    pub ensemble: bool,
    /// Closed-loop data (docs/usage.md "scale", `--closed-loop`): each job first trains a
    /// round-0 model on the first half of the recipe's sessions, records the other
    /// sessions again (the same days, placements and seeds) with it compensating, and
    /// trains on the first half plus those: the same minutes as the open-loop recipe.
    /// Needs 2 or more sessions; a folder keeps this choice.
    #[serde(default)]
    pub closed_loop: bool,
    /// Also score every job on a validation session (the next held-out session,
    /// [`validation_session`], never in the tables) and name the model recommended at
    /// each size there by `experiment::recommend`'s rule, as `evaluate` does. A folder
    /// keeps this choice.
    #[serde(default)]
    pub validation: bool,
}

pub(super) fn one_session() -> usize {
    1
}

impl Study {
    /// The study of issue 39 at the demo's model and training settings: 2, 8, 32 and 128
    /// minutes per path, IASTGCN, its Chebyshev ablation, T-GCN and the MLP, seeds 1–3,
    /// a held-out session of 2-minute runs; the data and the loop as the default recipe
    /// says ([`recipe::DEFAULT`]).
    pub fn demo_shape() -> Study {
        let held = HeldOutConfig::default();
        Study {
            recording_minutes: 128.0,
            sizes: vec![2.0, 8.0, 32.0, 128.0],
            seeds: vec![1, 2, 3],
            models: ["iastgcn", "iastgcn-s", "tgcn", "mlp"]
                .map(String::from)
                .to_vec(),
            run: RunConfig::demo(),
            machine_seed: MACHINE_SEED,
            held_out_minutes: 2.0,
            held_out_seed: held.seed,
            warm_up_minutes: held.warm_up_minutes,
            every: recipe::DEFAULT.every,
            recipe: recipe::DEFAULT.sessions,
            held_out_sessions: 3,
            refine: false,
            graph: None,
            ensemble: false,
            closed_loop: recipe::DEFAULT.closed_loop,
            validation: false,
        }
    }

    /// The held-out sessions every job is scored on: the test sessions, then the
    /// validation session when there is one.
    pub fn scored_sessions(&self) -> usize {
        self.held_out_sessions + usize::from(self.validation)
    }

    /// The validation session's index, if the study has one.
    pub fn validation_index(&self) -> Option<usize> {
        self.validation
            .then(|| validation_session(self.held_out_sessions))
    }

    /// The held-out session every job is scored on.
    pub fn held_out(&self) -> HeldOutConfig {
        HeldOutConfig {
            minutes: self.held_out_minutes,
            seed: self.held_out_seed,
            warm_up_minutes: self.warm_up_minutes,
            every: self.every,
            sessions: self.held_out_sessions,
        }
    }

    /// The jobs, seed by seed, then size by size (smallest first), then model by model:
    /// a study stopped early has whole curves of its first seeds.
    pub fn jobs(&self) -> Result<Vec<ScaleJob>> {
        let variants = self
            .models
            .iter()
            .map(|m| {
                Variant::parse(m).ok_or_else(|| {
                    Error::Invalid(format!("unknown model {m:?} ({})", Variant::names()))
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let mut jobs = Vec::new();
        for &seed in &self.seeds {
            for &minutes in &self.sizes {
                jobs.extend(variants.iter().map(|&variant| ScaleJob {
                    variant,
                    seed,
                    minutes,
                }));
            }
        }
        Ok(jobs)
    }

    /// Checks sizes, seeds, models, the run config and the held-out session.
    pub fn validate(&self) -> Result<()> {
        let longest = crate::data::MAX_RUN_SECONDS / 60.0;
        let max = self.recording_minutes;
        if !(max.is_finite() && max > 0.0 && max <= longest) {
            return Err(Error::Invalid(format!(
                "recording minutes: more than 0 and at most {longest} min, got {max}"
            )));
        }
        if self.sizes.is_empty() {
            return Err(Error::Invalid("sizes: give at least one size".into()));
        }
        for (i, &m) in self.sizes.iter().enumerate() {
            if !(m.is_finite() && m > 0.0 && m <= max) || (i > 0 && m <= self.sizes[i - 1]) {
                return Err(Error::Invalid(format!(
                    "sizes: each size is more than 0 and at most the recordings' {max} min, in \
                     ascending order and listed once; got {:?}",
                    self.sizes
                )));
            }
        }
        self.recipe.validate(max).map_err(sessions_setting)?;
        if self.closed_loop {
            check_closed_loop_sessions(self.recipe.sessions, " (or closed_loop = false)")?;
        }
        if !(1..=MAX_HELD_OUT_SESSIONS).contains(&self.held_out_sessions) {
            return Err(Error::Setting {
                setting: "held_out.sessions",
                message: format!(
                    "1 to {MAX_HELD_OUT_SESSIONS} held-out sessions, got {}",
                    self.held_out_sessions
                ),
            });
        }
        if let Some(path) = &self.graph {
            let graph = Graph::load(path)?;
            if graph.nodes.len() != self.run.model.nodes {
                return Err(Error::Invalid(format!(
                    "sources.graph {}: the graph has {} nodes, but the run config's [model] nodes \
                     is {}; a run config with nodes = {} reads it",
                    path.display(),
                    graph.nodes.len(),
                    self.run.model.nodes,
                    graph.nodes.len()
                )));
            }
        }
        check_seeds(&self.seeds)?;
        if self.models.is_empty() {
            return Err(Error::Invalid("the study needs at least one model".into()));
        }
        for (i, m) in self.models.iter().enumerate() {
            if self.models[..i].contains(m) {
                return Err(Error::Invalid(format!("models: {m} is listed twice")));
            }
        }
        self.jobs()?;
        self.run.validate().map_err(Error::Invalid)?;
        self.held_out().validate()
    }

    /// The study with what may change between runs of one folder cleared: its sizes,
    /// seeds and models, and where and on how many threads the steps run.
    pub(super) fn setup(&self) -> Study {
        let mut s = self.clone();
        s.sizes.clear();
        s.seeds.clear();
        s.models.clear();
        s.run.train.backend.clear();
        s.run.train.threads = 0;
        s.ensemble = false;
        s
    }
}

/// One model trained with one seed on `minutes` of training data per path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaleJob {
    /// The model.
    pub variant: Variant,
    /// Its `[train] seed`.
    pub seed: u64,
    /// Training data per path, minutes.
    pub minutes: f64,
}

impl ScaleJob {
    /// `<model>.min<m>.seed<k>`: grouped by `<model>.min<m>` over the seeds.
    pub fn name(&self) -> String {
        seeded_name(
            &format!("{}.min{}", self.variant.name(), self.minutes),
            self.seed,
        )
    }

    /// Its files in the one naming scheme (docs/usage.md "Checkpoint names"): the core
    /// stage's weights are `<name>.core.safetensors` (state, log and loss plot beside);
    /// only a study that refines writes the refined model, `<name>.safetensors`.
    pub fn files(&self, out: &Path) -> ModelFiles {
        ModelFiles::named(&out.join("models"), &self.name(), true)
    }

    /// The record written when the job has finished.
    pub fn record_path(&self, out: &Path) -> PathBuf {
        out.join("models").join(format!("{}.job.toml", self.name()))
    }
}
