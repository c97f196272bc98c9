//! The flags of `iastgcn evaluate` and the held-out session's flags that `demo`,
//! `evaluate`, `reproduce`, `scale`, `morning` and `confidence` share (arguments only: `demo` runs `evaluate`,
//! `arm` the serial arm's evaluation).

use std::path::PathBuf;

use clap::Args;

use iastgcn::experiment::evaluate::HeldOutConfig;

#[derive(Args, Clone)]
pub struct HeldOutArgs {
    /// Length of each held-out compensation run, minutes (default 0.5; 2 for `scale`,
    /// whose held-out runs score every training size).
    #[arg(long)]
    pub held_out_minutes: Option<f64>,
    /// Seed of the first held-out run; the next paths take the following seeds (the
    /// demo's training recordings use 201–203, its calibration set 101).
    #[arg(long, default_value_t = 301)]
    pub held_out_seed: u64,
    /// Minutes of polishing that warm the machine before the held-out session's first
    /// scored run (0: it starts cold).
    #[arg(long, default_value_t = 2.0)]
    pub warm_up_minutes: f64,
    /// Predict every this many control ticks during compensation (default: the recipe's,
    /// 1 for `use-like`, whose models train on closed-loop data recorded at that rate, 5
    /// for `paper`; 1, the default recipe's, for `evaluate`, `morning`, `confidence` and
    /// `floor`).
    #[arg(long, value_parser = super::count(1..=10_000))]
    pub every: Option<usize>,
    /// Held-out sessions scored (Table V; in `scale` every job): the first as
    /// --warm-up-minutes and --held-out-seed say, the others on days of their own, cold
    /// or warmed longer (docs/usage.md "Held-out sessions"). The recommended model is
    /// chosen on the session after them. A `scale` folder keeps its number.
    #[arg(long, default_value_t = 3, value_parser = super::count(1..=16))]
    pub held_out_sessions: usize,
}

impl HeldOutArgs {
    /// The session, with 0.5-minute runs and a prediction every tick (the default
    /// recipe's) unless `--held-out-minutes` or `--every` is given.
    pub fn config(&self) -> HeldOutConfig {
        self.config_or(HeldOutConfig::default())
    }

    /// The session, with `default`'s run length and prediction rate where
    /// `--held-out-minutes` or `--every` is absent.
    pub fn config_or(&self, default: HeldOutConfig) -> HeldOutConfig {
        HeldOutConfig {
            minutes: self.held_out_minutes.unwrap_or(default.minutes),
            seed: self.held_out_seed,
            warm_up_minutes: self.warm_up_minutes,
            every: self.every.unwrap_or(default.every),
            sessions: self.held_out_sessions,
        }
    }
}

#[derive(Args)]
pub struct EvaluateArgs {
    /// Recordings (CSV, docs/twin.md "File formats"), or with a serial arm's description
    /// in `--robot`, its pose files (docs/arms.md).
    #[arg(long, num_args = 1.., required = true)]
    pub data: Vec<PathBuf>,
    /// Calibration file from `iastgcn calibrate` (the hybrid machine; labels are
    /// residuals under it). A serial arm is calibrated on the training blocks instead.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Sensor graph asset (default: the embedded assets/graph.toml; the hybrid machine).
    #[arg(long)]
    pub graph: Option<PathBuf>,
    /// Robot description (default: the embedded hybrid machine, assets/robot.toml); a
    /// serial arm's (`kind = "serial"`) is calibrated, its residual models trained and
    /// scored on held-out poses.
    #[arg(long, visible_alias = "arm")]
    pub robot: Option<PathBuf>,
    /// Checkpoints to compare (the hybrid machine; named by file stem; a `<stem>.log.csv`
    /// beside one gives its training time per epoch).
    #[arg(long, num_args = 1..)]
    pub models: Vec<PathBuf>,
    /// A serial arm's desired tool points (CSV: pose,x,y,z and the pose files' channels):
    /// corrected joint targets into `targets.csv`, from the model with the lowest
    /// validation loss.
    #[arg(long)]
    pub targets: Option<PathBuf>,
    /// A serial arm's separate test pose files: --data is cut into 80/20 % training and
    /// validation blocks only, and every pose of these files with a full window is scored
    /// (they serve nothing else: not the calibration, early stopping or model choice).
    #[arg(long, num_args = 1..)]
    pub test: Vec<PathBuf>,
    /// A serial arm's training seeds, comma-separated: every model is trained with each
    /// and the table gives mean ± SD over them (default: the config's `[train] seed`
    /// alone).
    #[arg(long, value_delimiter = ',')]
    pub seeds: Option<Vec<u64>>,
    /// A serial arm's sensor channels without the time since the file's first pose
    /// (`[data] channel_time = false`): for a file longer than its warm-up, whose test
    /// poses lie at times the training never saw (docs/arms.md "The residual models on
    /// the time block").
    #[arg(long)]
    pub without_channel_time: bool,
    /// The models to train on a serial arm's residuals, comma-separated.
    #[arg(long, default_value_t = iastgcn::experiment::arm::ARM_MODELS.map(iastgcn::model::Variant::name).join(","))]
    pub train_models: String,
    /// Run config (its [data] table windows the recordings for Table III); for a serial
    /// arm, the residual models' config (default: the embedded assets/arms/residual.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Report folder.
    #[arg(long, default_value = "report")]
    pub out: PathBuf,
    #[command(flatten)]
    pub held_out: HeldOutArgs,
}
