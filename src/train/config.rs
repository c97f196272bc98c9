//! Run configuration (`assets/demo.toml`, `assets/paper.toml`): the model shape, the
//! windowing of the data, the core training schedule (docs/model.md "Optimiser and schedule")
//! and the refinement stages (docs/model.md "Refinement"). Every field has a default (the
//! paper's values) and a check whose message names the field.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::model::ModelConfig;

/// Windowing of the recordings (the window length is the model's `window`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DataConfig {
    /// Steps between consecutive window ends.
    pub stride: usize,
    /// `contiguous` (leakage-free blocks, the default) or `random` (the paper's protocol,
    /// labelled as such in every report).
    pub split: String,
    /// Seed of the `random` split.
    pub split_seed: u64,
    /// Share of the training windows used, in (0, 1]: with contiguous blocks, the first
    /// share of each recording's training block (as if it had been recorded for less
    /// time); validation and test stay the same. The learning curve of
    /// `iastgcn reproduce` trains with 0.25 and 0.5.
    pub train_fraction: f64,
    /// Share of the validation windows used, in (0, 1]: with contiguous blocks, the first
    /// share of each recording's validation block; the test blocks stay the same. The
    /// scaling study (`iastgcn scale`) sets both shares to what a shorter session would
    /// have had, so that early stopping sees what it would have seen.
    pub validation_fraction: f64,
    /// Serial arms (docs/arms.md "Residual models"): a sensor channel's node carries the
    /// time since the pose file's first pose as its third feature (`true`, what a warm-up
    /// depends on), or 0 (`false`: for a file longer than its warm-up, whose later poses
    /// lie at times the training never saw).
    pub channel_time: bool,
}

impl Default for DataConfig {
    fn default() -> DataConfig {
        DataConfig {
            stride: 20,
            split: "contiguous".into(),
            split_seed: 7,
            train_fraction: 1.0,
            validation_fraction: 1.0,
            channel_time: true,
        }
    }
}

/// The core stage (docs/model.md "Loss", "Optimiser and schedule").
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    /// Windows per mini-batch.
    pub batch: usize,
    /// lr0 of the inverse-time decay.
    pub lr: f64,
    /// r of lr(step) = lr0 / (1 + r · step / steps_per_epoch).
    pub lr_decay: f64,
    /// Adam's β1.
    pub beta1: f64,
    /// Adam's β2.
    pub beta2: f64,
    /// Adam's ε.
    pub adam_eps: f64,
    /// λ of eq. 39 (on weights only).
    pub weight_decay: f64,
    /// P of eq. 39.
    pub attitude_penalty: f64,
    /// Epochs at most.
    pub max_epochs: usize,
    /// Epochs without a better validation loss before stopping.
    pub patience: usize,
    /// Seed of the initial weights, the shuffling and the dropout masks.
    pub seed: u64,
    /// Where the steps run: `auto` (the native CPU path on a CPU adapter for the IASTGCN
    /// variants, the device otherwise), `device` (WGSL on the adapter) or `native`.
    pub backend: String,
    /// Threads of the native path; 0 = every core. The gradient sums in a fixed order
    /// for a given count: a run repeats bit for bit with the same count.
    pub threads: usize,
}

impl TrainConfig {
    /// The native path's threads: `threads`, or every core for 0.
    pub fn native_threads(&self) -> usize {
        match self.threads {
            0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
            n => n,
        }
    }
}

impl Default for TrainConfig {
    fn default() -> TrainConfig {
        TrainConfig {
            batch: 64,
            lr: 1e-3,
            lr_decay: 0.1,
            beta1: 0.9,
            beta2: 0.999,
            adam_eps: 1e-8,
            weight_decay: 1e-4,
            attitude_penalty: 1.0,
            max_epochs: 150,
            patience: 10,
            seed: 1,
            backend: "auto".into(),
            threads: 0,
        }
    }
}

/// The refinement stages (Algorithm 2): warm start at `lr_scale · lr0` on ensembles of
/// `magnifications[i]` consecutive windows, one stage per entry.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RefineConfig {
    /// Windows per ensemble, m, one stage per entry in order (each at least 2).
    pub magnifications: Vec<usize>,
    /// Each stage's lr0 as a multiple of `[train] lr`.
    pub lr_scale: f64,
    /// Epochs at most per stage.
    pub max_epochs: usize,
    /// Epochs without a better validation loss before a stage stops.
    pub patience: usize,
    /// Longest run of consecutive held-out windows in the accumulated-error check.
    pub horizon: usize,
}

impl Default for RefineConfig {
    fn default() -> RefineConfig {
        RefineConfig {
            magnifications: vec![10, 5],
            lr_scale: 0.1,
            max_epochs: 30,
            patience: 5,
            horizon: 10,
        }
    }
}

/// One run: `[model]`, `[data]`, `[train]`, `[refine]` tables.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunConfig {
    /// `[model]`: the network's shape and variant.
    pub model: ModelConfig,
    /// `[data]`: windowing and split.
    pub data: DataConfig,
    /// `[train]`: the core stage.
    pub train: TrainConfig,
    /// `[refine]`: the refinement stages.
    pub refine: RefineConfig,
}

/// A config file that cannot be used; the message names the file and the field.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {message}")]
pub struct ConfigError {
    /// The config file's name.
    pub file: String,
    /// What is wrong, naming the field.
    pub message: String,
}

impl crate::error::StageError for ConfigError {}

fn check(ok: bool, field: &str, value: impl std::fmt::Display, rule: &str) -> Result<(), String> {
    if ok {
        Ok(())
    } else {
        Err(format!("{field} = {value}: {rule}"))
    }
}

impl RunConfig {
    /// The embedded `assets/demo.toml`: the paper's config with a smaller network (T 48,
    /// C 16, L 2) and a shorter schedule.
    ///
    /// ```
    /// use iastgcn::train::RunConfig;
    ///
    /// let config = RunConfig::demo();
    /// assert_eq!(
    ///     (config.model.window, config.model.channels, config.model.blocks),
    ///     (48, 16, 2)
    /// );
    /// assert_eq!(config.train.max_epochs, 80);
    /// assert_eq!(config.refine.magnifications, vec![10, 5]);
    /// ```
    pub fn demo() -> RunConfig {
        // invariant: the embedded config is parsed in tests/train_cli.rs.
        RunConfig::parse(include_str!("../../assets/demo.toml"), "assets/demo.toml")
            .expect("the embedded demo config is valid")
    }

    /// The config at `path` (the defaults, the paper's shape, without one), with its
    /// model's variant replaced by `variant` when one is given (`--variant`).
    pub fn read(path: Option<&Path>, variant: Option<&str>) -> Result<RunConfig, ConfigError> {
        let mut config = match path {
            Some(p) => RunConfig::load(p)?,
            None => RunConfig::default(),
        };
        if let Some(v) = variant {
            config.model.variant = crate::model::Variant::parse(v).ok_or_else(|| ConfigError {
                file: "variant".into(),
                message: format!("unknown variant {v:?} ({})", crate::model::Variant::names()),
            })?;
        }
        Ok(config)
    }

    /// Reads and checks a TOML file.
    pub fn load(path: &Path) -> Result<RunConfig, ConfigError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError {
            file: file.clone(),
            message: e.to_string(),
        })?;
        RunConfig::parse(&text, &file)
    }

    /// Parses and checks TOML text (`file` names it in errors); fields left out take the
    /// paper's values.
    ///
    /// ```
    /// use iastgcn::train::RunConfig;
    ///
    /// let config = RunConfig::parse("[train]\nbatch = 32", "run.toml")?;
    /// assert_eq!((config.train.batch, config.model.window), (32, 100));
    ///
    /// let err = RunConfig::parse("[train]\nbatch = 0", "run.toml").unwrap_err();
    /// assert_eq!(err.to_string(), "run.toml: train.batch = 0: must be positive");
    /// # Ok::<(), iastgcn::train::ConfigError>(())
    /// ```
    pub fn parse(text: &str, file: &str) -> Result<RunConfig, ConfigError> {
        let err = |message: String| ConfigError {
            file: file.to_string(),
            message,
        };
        let config: RunConfig = toml::from_str(text).map_err(|e| err(e.to_string()))?;
        config.validate().map_err(err)?;
        Ok(config)
    }

    /// Checks every field; the message names the first bad one.
    pub fn validate(&self) -> Result<(), String> {
        self.model.validate()?;
        crate::model::check_parameter_count(&self.model)?;
        let d = &self.data;
        check(d.stride > 0, "data.stride", d.stride, "must be positive")?;
        check(
            d.train_fraction > 0.0 && d.train_fraction <= 1.0,
            "data.train_fraction",
            d.train_fraction,
            "must be in (0, 1]",
        )?;
        check(
            d.validation_fraction > 0.0 && d.validation_fraction <= 1.0,
            "data.validation_fraction",
            d.validation_fraction,
            "must be in (0, 1]",
        )?;
        check(
            d.split == "contiguous" || d.split == "random",
            "data.split",
            &d.split,
            "must be \"contiguous\" or \"random\"",
        )?;
        let t = &self.train;
        check(t.batch > 0, "train.batch", t.batch, "must be positive")?;
        check(
            ["auto", "device", "native"].contains(&t.backend.as_str()),
            "train.backend",
            format!("{:?}", t.backend),
            "must be \"auto\", \"device\" or \"native\"",
        )?;
        check(
            t.threads <= 1024,
            "train.threads",
            t.threads,
            "must be at most 1024 (0 = every core)",
        )?;
        check(
            t.lr > 0.0 && t.lr.is_finite(),
            "train.lr",
            t.lr,
            "must be positive",
        )?;
        check(
            t.lr_decay >= 0.0 && t.lr_decay.is_finite(),
            "train.lr_decay",
            t.lr_decay,
            "must be ≥ 0",
        )?;
        for (name, b) in [("train.beta1", t.beta1), ("train.beta2", t.beta2)] {
            check((0.0..1.0).contains(&b), name, b, "must be in [0, 1)")?;
        }
        check(
            t.adam_eps > 0.0 && t.adam_eps.is_finite(),
            "train.adam_eps",
            t.adam_eps,
            "must be positive and finite",
        )?;
        check(
            t.weight_decay >= 0.0 && t.weight_decay.is_finite(),
            "train.weight_decay",
            t.weight_decay,
            "must be ≥ 0",
        )?;
        check(
            t.attitude_penalty >= 0.0 && t.attitude_penalty.is_finite(),
            "train.attitude_penalty",
            t.attitude_penalty,
            "must be ≥ 0",
        )?;
        check(
            t.max_epochs > 0,
            "train.max_epochs",
            t.max_epochs,
            "must be positive",
        )?;
        check(
            t.patience > 0,
            "train.patience",
            t.patience,
            "must be positive",
        )?;
        let r = &self.refine;
        check(
            r.magnifications.iter().all(|&m| m >= 2),
            "refine.magnifications",
            format!("{:?}", r.magnifications),
            "each must be ≥ 2 windows",
        )?;
        check(
            r.lr_scale > 0.0 && r.lr_scale.is_finite(),
            "refine.lr_scale",
            r.lr_scale,
            "must be positive",
        )?;
        check(
            r.max_epochs > 0,
            "refine.max_epochs",
            r.max_epochs,
            "must be positive",
        )?;
        check(
            r.patience > 0,
            "refine.patience",
            r.patience,
            "must be positive",
        )?;
        check(
            r.horizon >= 1,
            "refine.horizon",
            r.horizon,
            "must be positive",
        )?;
        Ok(())
    }
}
