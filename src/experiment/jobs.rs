//! What the experiments' resumable jobs share (`reproduce`, `scale`, `demo`): the shard a
//! process runs, the TOML files that pin a folder's setup and record each finished job,
//! the job record of a fitted model and its table over seeds, and the clock the progress
//! lines print.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::protocol::{epoch_seconds, Fitted};
use super::report::seeds::Spread;
use crate::error::{write_file, Error, Result};
use crate::train::{EpochRecord, TestMetrics};

/// One job of several processes: jobs `k − 1`, `k − 1 + n`, … of the list (1 ≤ k ≤ n).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shard {
    /// 1-based.
    pub index: usize,
    /// How many shards share the jobs.
    pub count: usize,
}

impl std::str::FromStr for Shard {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Shard, String> {
        let bad = || format!("a shard is k/n with 1 ≤ k ≤ n (e.g. 2/8), got {s:?}");
        let (k, n) = s.split_once('/').ok_or_else(bad)?;
        let (index, count): (usize, usize) = (
            k.trim().parse().map_err(|_| bad())?,
            n.trim().parse().map_err(|_| bad())?,
        );
        if index == 0 || index > count {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }
}

impl Shard {
    /// Whether job number `i` (0-based) belongs to this shard.
    pub fn owns(&self, i: usize) -> bool {
        i % self.count == self.index - 1
    }
}

/// What a finished job left: read back by the final run to build the report.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobRecord {
    /// `<model>.seed<k>`.
    pub name: String,
    /// The model.
    pub model: String,
    /// The training seed.
    pub seed: u64,
    /// Share of the training windows it trained on.
    pub fraction: f64,
    /// Training windows it trained on.
    pub train_windows: usize,
    /// Validation MAE of the core stage's best weights, position µm and attitude mdeg.
    pub val_mae: [f64; 2],
    /// Test MAE of the same weights.
    pub test_mae: [f64; 2],
    /// Best validation loss of the core stage (standardised).
    pub best_val: f64,
    /// Its epoch.
    pub best_epoch: usize,
    /// Core epochs run (over every resumption).
    pub epochs: usize,
    /// Mean core epoch time, s.
    pub epoch_seconds: f64,
    /// Where the core stage trained.
    pub trained_on: String,
    /// What refinement did (empty for the learning curve's jobs).
    pub refinement: String,
    /// Wall time of the job in the run that finished it, s.
    pub wall_seconds: f64,
}

impl JobRecord {
    /// A record read back; errors name the file.
    pub fn load(path: &Path) -> Result<JobRecord> {
        read_toml(path)
    }
}

impl JobRecord {
    /// The record of `name` (`model` with `seed` on `fraction` of the training windows,
    /// `train_windows` of them) from its core stage: the best validation loss and its
    /// epoch, the epochs, and the validation and test metrics of the best weights. No
    /// refinement and no wall time yet.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        name: &str,
        model: &str,
        seed: u64,
        fraction: f64,
        train_windows: usize,
        (best_val, best_epoch): (f64, usize),
        history: &[EpochRecord],
        (validation, test): (&[TestMetrics], &[TestMetrics]),
    ) -> JobRecord {
        JobRecord {
            name: name.into(),
            model: model.into(),
            seed,
            fraction,
            train_windows,
            val_mae: pooled(validation),
            test_mae: pooled(test),
            best_val,
            best_epoch,
            epochs: history.iter().filter(|r| r.stage == "core").count(),
            epoch_seconds: epoch_seconds(history),
            trained_on: crate::train::log::trained_on(
                history.iter().map(|r| r.trained_on.as_str()),
            ),
            refinement: String::new(),
            wall_seconds: 0.0,
        }
    }

    /// The record of a model [`fit_model`] trained and refined on the whole training set.
    pub fn of_fitted(
        name: &str,
        model: &str,
        seed: u64,
        train_windows: usize,
        f: &Fitted,
    ) -> JobRecord {
        JobRecord {
            refinement: f.verdict.clone(),
            ..JobRecord::new(
                name,
                model,
                seed,
                1.0,
                train_windows,
                (f.best_val, f.best_epoch),
                &f.core,
                (&f.validation, &f.test),
            )
        }
    }
}

/// Mean absolute errors (position µm, attitude mdeg) over every window of per-recording
/// metrics.
fn pooled(rows: &[TestMetrics]) -> [f64; 2] {
    let n: usize = rows.iter().map(|r| r.model.count).sum();
    let mean = |pick: fn(&TestMetrics) -> f64| {
        rows.iter()
            .map(|r| pick(r) * r.model.count as f64)
            .sum::<f64>()
            / n.max(1) as f64
    };
    [mean(|r| r.model.pos_mae), mean(|r| r.model.att_mae)]
}

/// Writes `value` to `path` as TOML, or, where an earlier run wrote one, checks that it
/// holds the same value as `same` compares them; otherwise the error is `refusal`.
pub fn pin_toml<T: Serialize + serde::de::DeserializeOwned>(
    value: &T,
    path: &Path,
    same: impl Fn(&T, &T) -> bool,
    refusal: &str,
) -> Result<()> {
    if path.exists() {
        let earlier: T = read_toml(path)?;
        if !same(&earlier, value) {
            return Err(Error::Invalid(format!("{}: {refusal}", path.display())));
        }
        return Ok(());
    }
    write_toml(value, path)
}

/// A TOML file (a pinned protocol or study, a job record) read back; errors name it.
pub fn read_toml<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    toml::from_str(&text).map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))
}

/// `value` written to `path` as TOML, atomically.
pub fn write_toml<T: Serialize>(value: &T, path: &Path) -> Result<()> {
    let text =
        toml::to_string(value).map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))?;
    write_file(path, text.as_bytes())
}

/// `h:mm:ss`.
pub fn clock(seconds: f64) -> String {
    let s = seconds.max(0.0).round() as u64;
    format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
}

/// Best validation loss, its epoch and the epochs run per model of `models`, over seeds.
pub fn training_table(models: &[String], records: &[JobRecord]) -> String {
    let mut out = String::from(
        "Core stage per model over its seeds (mean ± sample SD): the best validation loss \
         (standardised, eq. 39's data term), the epoch it was reached in, the epochs run \
         (early stopping), and the mean epoch time.\n\n\
         | Model | Seeds | Best validation loss | Best epoch | Epochs | s / epoch |\n\
         |---|---:|---:|---:|---:|---:|\n",
    );
    for model in models {
        let of: Vec<&JobRecord> = records
            .iter()
            .filter(|r| &r.model == model && r.fraction == 1.0)
            .collect();
        let spread = |pick: fn(&JobRecord) -> f64| {
            let s = Spread::of(&of.iter().map(|r| pick(r)).collect::<Vec<_>>());
            (s.mean, s.sd)
        };
        let (v, vs) = spread(|r| r.best_val);
        let (b, bs) = spread(|r| r.best_epoch as f64);
        let (e, es) = spread(|r| r.epochs as f64);
        let (t, _) = spread(|r| r.epoch_seconds);
        out.push_str(&format!(
            "| {model} | {} | {v:.4} ± {vs:.4} | {b:.1} ± {bs:.1} | {e:.1} ± {es:.1} | {t:.3} |\n",
            of.len()
        ));
    }
    out
}
