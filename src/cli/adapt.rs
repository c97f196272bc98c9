//! `iastgcn adapt` (a trained model adapted to the day from a short morning recording)
//! and `iastgcn morning` (the adaptation measured on the twin's held-out sessions);
//! docs/usage.md "The morning minute".

use std::path::{Path, PathBuf};

use anyhow::Context;

use super::evaluate_args::HeldOutArgs;
use super::train::{read_run_config, DataArgs};
use super::Console;
use iastgcn::experiment::demo::DEMO_HELD_OUT;
use iastgcn::experiment::morning::{self, MorningSpec, Trained};
use iastgcn::gpu::Device;
use iastgcn::model::Checkpoint;
use iastgcn::progress::Reporter;
use iastgcn::train::{self, AdaptConfig, Adaptation};

#[derive(clap::Args)]
pub struct AdaptArgs {
    /// The morning recording(s) (CSV with tracker samples; a minute or two of one path)
    /// and the calibration the controller ran under.
    #[command(flatten)]
    pub data: DataArgs,
    /// Trained checkpoint to adapt.
    #[arg(long)]
    pub model: PathBuf,
    /// How: `offset` (the mean miss on the recording added to the output bias, closed
    /// form), `fine-tune` (every weight, 2 epochs of Adam at 3e-4) or
    /// `fine-tune:EPOCHS:LR`.
    #[arg(long, default_value = "offset")]
    pub method: String,
    /// Run config: its [train] table gives the fine-tune's batch, Adam constants, seed and
    /// backend (the paper's values when absent).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Ticks between window ends (5: every tracker sample of the twin ends a window).
    #[arg(long, default_value_t = 5, value_parser = super::count(1..))]
    pub stride: usize,
    /// The last share of the recording's windows that judges: the adapted weights are
    /// kept only when they lower the loss there.
    #[arg(long, default_value_t = 0.2)]
    pub judge: f64,
    /// The adapted checkpoint (the trained weights when adapting did not help).
    #[arg(long)]
    pub out: PathBuf,
}

pub fn adapt(device: &Device, args: &AdaptArgs) -> anyhow::Result<()> {
    super::output_folder_exists("--out", &args.out)?;
    let method: Adaptation = args.method.parse().map_err(anyhow::Error::msg)?;
    let trained = Checkpoint::load(&args.model)?;
    let config = read_run_config(args.config.as_deref(), None)?;
    let mut how = AdaptConfig::new(method, &config);
    how.stride = args.stride;
    how.judge = args.judge;
    let mut console = Console::default();
    let adapted = train::adapt(device, &args.data.sources(), &trained, &how, &mut console)?;
    console.end();
    adapted.checkpoint(&trained).save(&args.out)?;
    println!("{}", adapted.verdict());
    println!("saved {}", args.out.display());
    Ok(())
}

#[derive(clap::Args)]
pub struct MorningArgs {
    /// The models' training data (their recordings and calibration): the held-out
    /// sessions run on the twin machine they were recorded on, under that calibration.
    #[command(flatten)]
    pub data: DataArgs,
    /// Trained checkpoints, named `<model>.seed<k>.safetensors` as `demo` and
    /// `reproduce` write them (`models/iastgcn-a.seed1.safetensors`).
    #[arg(long, num_args = 1.., required = true)]
    pub models: Vec<PathBuf>,
    /// Run config: its [train] table gives the fine-tune's batch, Adam constants and
    /// backend (the demo's: `demo.toml` in its folder).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The morning recording's path (grid, fermat, hilbert, rosette), turned 45° on the
    /// part.
    #[arg(long, default_value = "fermat")]
    pub path: String,
    /// Length of each session's morning recording, minutes (2: long enough for the
    /// judge to refuse an offset that the rest of the day would not bear out).
    #[arg(long, default_value_t = 2.0)]
    pub minutes: f64,
    /// Ways of adapting to compare with none, comma-separated: offset, fine-tune,
    /// fine-tune:EPOCHS:LR.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "offset,fine-tune,fine-tune:8:1e-3"
    )]
    pub methods: Vec<String>,
    #[command(flatten)]
    pub held_out: HeldOutArgs,
    /// Output folder: morning.md, morning_table_v.csv, adaptations.csv and the morning
    /// recordings.
    #[arg(long)]
    pub out: PathBuf,
}

/// `models/iastgcn-a.seed2.safetensors` is `iastgcn-a` seed 2; a name without `.seed<k>`
/// is seed 0.
pub(super) fn name_and_seed(path: &Path) -> (String, u64) {
    let stem = path
        .file_stem()
        .map_or("model".into(), |s| s.to_string_lossy().into_owned());
    match stem.rsplit_once(".seed") {
        Some((name, seed)) => match seed.parse() {
            Ok(seed) => (name.to_string(), seed),
            Err(_) => (stem.clone(), 0),
        },
        None => (stem, 0),
    }
}

pub fn morning(device: &Device, args: &MorningArgs) -> anyhow::Result<()> {
    let methods = args
        .methods
        .iter()
        .map(|m| m.parse::<Adaptation>())
        .collect::<Result<Vec<_>, _>>()
        .map_err(anyhow::Error::msg)
        .context("--methods")?;
    let trained = args
        .models
        .iter()
        .map(|path| {
            let (name, seed) = name_and_seed(path);
            Ok(Trained {
                name,
                seed,
                checkpoint: Checkpoint::load(path)
                    .with_context(|| format!("--models {}", path.display()))?,
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let config = read_run_config(args.config.as_deref(), None)?;
    let spec = MorningSpec {
        path: args
            .path
            .parse()
            .map_err(anyhow::Error::msg)
            .context("--path")?,
        minutes: args.minutes,
        methods,
        held: args.held_out.config_or(DEMO_HELD_OUT),
    };
    super::make_output_folder("--out", &args.out)?;
    let mut console = Console::default();
    let study = morning::run(
        device,
        &args.data.sources(),
        &trained,
        &spec,
        &config,
        &args.out,
        &mut console,
    )?;
    console.end();
    study.write(&args.out)?;
    println!("{}", study.markdown());
    println!("written to {}", args.out.display());
    Ok(())
}
