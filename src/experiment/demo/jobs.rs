//! The demo's jobs (one model trained and refined with one seed, each leaving a job
//! record) and its folder's setup: a demo interrupted before its end continues where it
//! stopped when run again into the same folder with the same settings; a finished demo,
//! or one with other settings, starts afresh.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::DemoConfig;
use crate::error::{Error, Result};
use crate::experiment::evaluate::NamedModel;
use crate::experiment::jobs::{read_toml, write_toml, JobRecord};
use crate::experiment::protocol::{ModelFiles, CORE_SUFFIX};
use crate::experiment::report::seeds::seeded_name;
use crate::model::{Checkpoint, Variant};
use crate::train::refine::AccumulatedCurve;
use crate::train::{log, sibling, EpochRecord, RunConfig};
use crate::twin::Recipe;

/// One of the demo's models: a variant trained with a seed, named as the report names it.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct DemoJob {
    /// The model.
    pub variant: Variant,
    /// Its `[train] seed`.
    pub seed: u64,
    /// `<model>.seed<k>`, or the variant's name in a demo of one seed.
    pub name: String,
}

impl DemoJob {
    /// Every model with every seed, seed by seed.
    pub fn all(variants: &[Variant], seeds: &[u64]) -> Vec<DemoJob> {
        let seeded = seeds.len() > 1;
        seeds
            .iter()
            .flat_map(|&seed| {
                variants.iter().map(move |&variant| DemoJob {
                    variant,
                    seed,
                    name: if seeded {
                        seeded_name(variant.name(), seed)
                    } else {
                        variant.name().to_string()
                    },
                })
            })
            .collect()
    }

    /// Its files in the models' folder `dir`; the core stage resumes from its state file.
    pub fn files(&self, dir: &Path) -> ModelFiles {
        ModelFiles::named(dir, &self.name, true)
    }

    /// The model as its finished job left it in `dir`: the evaluated checkpoint and the
    /// record's epoch time and device.
    pub fn model(&self, dir: &Path, record: &JobRecord) -> Result<NamedModel> {
        Ok(NamedModel {
            name: self.name.clone(),
            checkpoint: Checkpoint::load(&self.files(dir).refined)?,
            epoch_seconds: record.epoch_seconds,
            trained_on: record.trained_on.clone(),
        })
    }

    /// The epochs of its core stage and of its refinement, from their logs in `dir`.
    pub fn histories(&self, dir: &Path) -> Result<(Vec<EpochRecord>, Vec<EpochRecord>)> {
        let files = self.files(dir);
        Ok((
            log::read_csv(&sibling(&files.core, ".log.csv"))?,
            log::read_csv(&sibling(&files.refined, ".log.csv"))?,
        ))
    }

    /// Fig. 9b's curves before and after its refinement, from their file in `dir`.
    pub fn accumulated(&self, dir: &Path) -> Result<(AccumulatedCurve, AccumulatedCurve)> {
        log::read_accumulated(&sibling(&self.files(dir).refined, ".accumulated.csv"))
    }
}

impl crate::experiment::runner::Job for DemoJob {
    type Record = JobRecord;

    fn record_path(&self, out: &Path) -> PathBuf {
        out.join("models").join(format!("{}.job.toml", self.name))
    }

    fn describe(&self) -> String {
        format!("{} seed {}", self.variant, self.seed)
    }

    fn set_wall_seconds(record: &mut JobRecord, seconds: f64) {
        record.wall_seconds = seconds;
    }
}

/// What the demo's trained models depend on, kept in `demo.toml` in its folder: a later
/// run with the same continues the folder's unfinished run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub(super) struct Setup {
    /// Whether the run got to its report.
    pub finished: bool,
    /// Minutes per path of the training recordings.
    pub minutes: f64,
    /// How they were recorded.
    pub recipe: Recipe,
    /// Whether the second half of the sessions was recorded again in closed loop.
    pub closed_loop: bool,
    /// The closed-loop round's prediction rate (ticks; 0 without it).
    pub closed_loop_every: usize,
    /// The seed of its round-0 model (0 without it).
    pub round0_seed: u64,
    /// Every model's run config (where and on how many threads it runs left out).
    pub run: RunConfig,
}

impl Setup {
    /// The setup of `demo`, unfinished.
    pub fn of(demo: &DemoConfig) -> Setup {
        let mut run = demo.run.clone();
        run.train.backend.clear();
        run.train.threads = 0;
        Setup {
            finished: false,
            minutes: demo.minutes,
            recipe: demo.recipe,
            closed_loop: demo.closed_loop,
            closed_loop_every: if demo.closed_loop {
                demo.held_out.every
            } else {
                0
            },
            round0_seed: if demo.closed_loop { demo.seeds[0] } else { 0 },
            run,
        }
    }

    /// Its file in the demo's folder `out`.
    pub fn path(out: &Path) -> PathBuf {
        out.join("demo.toml")
    }

    /// Whether `out` holds an unfinished run of this setup, so that this run continues
    /// it. Otherwise the folder is made ready for a fresh run: the earlier run's records,
    /// state files (`jobs`' and `round0`'s) and closed-loop recordings, which a fresh run
    /// must not take for its own, are removed, and this setup is written, unfinished.
    pub fn continue_or_start(&self, out: &Path, jobs: &[DemoJob], round0: &str) -> Result<bool> {
        let path = Setup::path(out);
        if path.exists() {
            // An unreadable file (an older build's, or damaged) is another setup.
            if let Ok(earlier) = read_toml::<Setup>(&path) {
                if !earlier.finished && earlier == *self {
                    return Ok(true);
                }
            }
        }
        let models = out.join("models");
        let mut stale: Vec<PathBuf> = jobs
            .iter()
            .flat_map(|j| {
                [
                    crate::experiment::runner::Job::record_path(j, out),
                    sibling(&j.files(&models).core, ".state.safetensors"),
                ]
            })
            .collect();
        stale.push(models.join(format!("{round0}{CORE_SUFFIX}.state.safetensors")));
        for file in stale.iter().filter(|f| f.exists()) {
            std::fs::remove_file(file).map_err(|e| Error::io(file, e))?;
        }
        let closed = out.join("data").join("closed-loop");
        if closed.exists() {
            std::fs::remove_dir_all(&closed).map_err(|e| Error::io(&closed, e))?;
        }
        write_toml(self, &path)?;
        Ok(false)
    }

    /// Marks the run in `out` finished: a later run starts afresh.
    pub fn finish(mut self, out: &Path) -> Result<()> {
        self.finished = true;
        write_toml(&self, &Setup::path(out))
    }
}

#[cfg(test)]
mod tests {
    use super::{DemoJob, Setup};
    use crate::experiment::demo::DemoConfig;
    use crate::experiment::runner::Job;
    use crate::model::Variant;

    #[test]
    fn only_an_unfinished_run_of_the_same_setup_continues() {
        let out = std::env::temp_dir().join(format!("iastgcn-demo-setup-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        let models = out.join("models");
        std::fs::create_dir_all(&models).unwrap();
        // Three seeds, whatever the default's count.
        let demo = DemoConfig {
            seeds: vec![1, 2, 3],
            ..DemoConfig::default()
        };
        let jobs = DemoJob::all(&[Variant::Iastgcn, Variant::Mlp], &demo.seeds);
        assert_eq!(jobs.len(), 6);
        assert_eq!(jobs[3].name, "mlp.seed2");
        let setup = Setup::of(&demo);
        // What an earlier run left: a record, a state file, a closed-loop recording.
        let leave = || {
            std::fs::write(jobs[3].record_path(&out), "").unwrap();
            std::fs::write(models.join("mlp.seed2.core.state.safetensors"), "").unwrap();
            std::fs::write(
                models.join("iastgcn.seed1.round0.core.state.safetensors"),
                "",
            )
            .unwrap();
            std::fs::create_dir_all(out.join("data/closed-loop")).unwrap();
        };
        let left = || {
            [
                jobs[3].record_path(&out),
                models.join("mlp.seed2.core.state.safetensors"),
                models.join("iastgcn.seed1.round0.core.state.safetensors"),
                out.join("data/closed-loop"),
            ]
            .map(|p| p.exists())
        };
        let round0 = "iastgcn.seed1.round0";
        // No setup file: a fresh run, which clears what it would otherwise take as its own.
        leave();
        assert!(!setup.continue_or_start(&out, &jobs, round0).unwrap());
        assert_eq!(left(), [false; 4]);
        // Its own unfinished run: continued, nothing removed.
        leave();
        assert!(setup.continue_or_start(&out, &jobs, round0).unwrap());
        assert_eq!(left(), [true; 4]);
        // Another setup (where and on how many threads aside): fresh.
        let mut threads = demo.clone();
        threads.run.train.threads = 1;
        assert!(Setup::of(&threads)
            .continue_or_start(&out, &jobs, round0)
            .unwrap());
        let mut other = demo.clone();
        other.run.train.lr *= 2.0;
        assert!(!Setup::of(&other)
            .continue_or_start(&out, &jobs, round0)
            .unwrap());
        assert_eq!(left(), [false; 4]);
        // A finished run: fresh.
        leave();
        setup.clone().finish(&out).unwrap();
        assert!(!setup.continue_or_start(&out, &jobs, round0).unwrap());
        assert_eq!(left(), [false; 4]);
        // A damaged setup file: fresh.
        leave();
        std::fs::write(Setup::path(&out), "finished = [").unwrap();
        assert!(!setup.continue_or_start(&out, &jobs, round0).unwrap());
        assert_eq!(left(), [false; 4]);
        std::fs::remove_dir_all(&out).unwrap();
    }
}
