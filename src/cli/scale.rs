//! `iastgcn scale`: arguments, then the library's `experiment::scale`.

use std::path::PathBuf;

use clap::Args;

use super::evaluate_args::HeldOutArgs;
use super::train::read_run_config;
use super::Console;
use iastgcn::experiment::evaluate::HeldOutConfig;
use iastgcn::experiment::jobs::Shard;
use iastgcn::experiment::scale::{self, Study};
use iastgcn::gpu::Device;

#[derive(Args)]
pub struct ScaleArgs {
    /// Output folder: study.toml, data/, models/ and the summary (scale.md, scale.csv,
    /// scale_summary.csv, scale.png), rewritten after every job.
    #[arg(long, default_value = "scale")]
    pub out: PathBuf,
    /// Run config of every model; the demo's (assets/demo.toml) when absent.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Training data per path, minutes of recording, ascending, comma-separated, each at
    /// most --recording-minutes.
    #[arg(long, value_delimiter = ',', default_value = "2,8,32,128")]
    pub sizes: Vec<f64>,
    /// Length of each training recording, minutes (default: the largest size); its
    /// validation and test blocks score every size. A folder keeps its length: give the
    /// largest size a study will reach, then grow sizes, seeds and models call by call.
    #[arg(long)]
    pub recording_minutes: Option<f64>,
    /// Training seeds, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
    pub seeds: Vec<u64>,
    /// Models, comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "iastgcn,iastgcn-s,tgcn,mlp"
    )]
    pub models: Vec<String>,
    /// Run only this shard's jobs, k/n (jobs k−1, k−1+n, …), then stop.
    #[arg(long)]
    pub shard: Option<Shard>,
    /// Record (or check) the data and stop: run this once before the shards.
    #[arg(long)]
    pub data_only: bool,
    /// The twin machine (seed of its geometric and non-geometric errors) of the data and
    /// the held-out session.
    #[arg(long, default_value_t = iastgcn::experiment::protocol::MACHINE_SEED)]
    pub machine_seed: u64,
    #[command(flatten)]
    pub recipe: super::RecipeArgs,
    /// Sensor graph of every model (default: the embedded assets/graph.toml, or
    /// assets/graph-look-ahead.toml for a run config with `[model] look_ahead`); the run
    /// config's `[model] nodes` must match it (assets/graph-force.toml: 15). A folder
    /// keeps it.
    #[arg(long)]
    pub graph: Option<PathBuf>,
    /// Refine every job after its core stage (Algorithm 2, as `demo` does) and score the
    /// weights it keeps. A folder keeps this choice.
    #[arg(long)]
    pub refine: bool,
    /// Also score each model and size whose seeds have all finished as a seed ensemble:
    /// the controller averages the seeds' predictions (`<model>-ensemble` in the summary;
    /// not in a --shard call).
    #[arg(long)]
    pub ensemble: bool,
    /// Also score every job on a validation session (the one after the held-out
    /// sessions, never in the tables) and name the model recommended at each size there,
    /// as `evaluate` does (scale.md "Recommended model", scale_validation.csv). A folder
    /// keeps this choice.
    #[arg(long)]
    pub validation_session: bool,
    #[command(flatten)]
    pub held_out: HeldOutArgs,
}

pub fn run(device: Device, args: &ScaleArgs) -> anyhow::Result<()> {
    let mut study = Study::demo_shape();
    if let Some(p) = &args.config {
        study.run = read_run_config(Some(p), None)?;
    }
    study.sizes = args.sizes.clone();
    study.recording_minutes = args
        .recording_minutes
        .unwrap_or_else(|| args.sizes.iter().copied().fold(0.0, f64::max));
    study.seeds = args.seeds.clone();
    study.models = args.models.clone();
    study.machine_seed = args.machine_seed;
    study.recipe = args.recipe.sessions()?;
    study.held_out_sessions = args.held_out.held_out_sessions;
    study.refine = args.refine;
    study.ensemble = args.ensemble;
    study.closed_loop = args.recipe.closed_loop();
    study.validation = args.validation_session;
    study.graph = args.graph.clone();
    let held = args.recipe.held_out(
        &args.held_out,
        HeldOutConfig {
            minutes: study.held_out_minutes,
            ..HeldOutConfig::default()
        },
    );
    study.held_out_minutes = held.minutes;
    study.held_out_seed = held.seed;
    study.warm_up_minutes = held.warm_up_minutes;
    study.every = held.every;
    let progress = scale::scale(
        device,
        &study,
        args.shard,
        args.data_only,
        &args.out,
        &mut Console::default(),
    )?;
    println!(
        "scale: {} of {} jobs done; summary in {}",
        progress.done,
        progress.total,
        args.out.join("scale.md").display()
    );
    Ok(())
}
