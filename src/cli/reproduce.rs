//! `iastgcn reproduce`: arguments, then the library's `experiment::reproduce`.

use std::path::PathBuf;

use clap::Args;

use super::evaluate_args::HeldOutArgs;
use super::train::read_run_config;
use super::Console;
use iastgcn::experiment::evaluate::HeldOutConfig;
use iastgcn::experiment::jobs::Shard;
use iastgcn::experiment::reproduce::{self, Outcome, Protocol};
use iastgcn::gpu::Device;

#[derive(Args)]
pub struct ReproduceArgs {
    /// Output folder: protocol.toml, data/, models/ and, once every job is done, the report.
    #[arg(long, default_value = "paper")]
    pub out: PathBuf,
    /// Run config of every model; the paper's sizes when absent (assets/paper.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Length of each training recording, minutes (135: about 42k windows at the paper's
    /// window and stride).
    #[arg(long, default_value_t = 135.0)]
    pub minutes: f64,
    /// Training seeds, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
    pub seeds: Vec<u64>,
    /// Models, comma-separated (default: IASTGCN, its ablations and every baseline).
    #[arg(long, value_delimiter = ',')]
    pub models: Vec<String>,
    /// Shares of the training windows for the learning curve, comma-separated, each in
    /// (0, 1) (default 0.25,0.5).
    #[arg(long, value_delimiter = ',')]
    pub fractions: Vec<f64>,
    /// Models of the learning curve, comma-separated (default iastgcn,tgcn).
    #[arg(long, value_delimiter = ',')]
    pub curve_models: Vec<String>,
    /// No learning curve: only the tables' models.
    #[arg(long, conflicts_with_all = ["fractions", "curve_models"])]
    pub no_curve: bool,
    /// Run only this shard's jobs, k/n (jobs k−1, k−1+n, …), then stop; a final call
    /// without --shard writes the report.
    #[arg(long)]
    pub shard: Option<Shard>,
    /// Record (or check) the data and stop: run this once before the shards.
    #[arg(long)]
    pub data_only: bool,
    /// The twin machine (seed of its geometric and non-geometric errors) the data and
    /// the held-out session come from; one folder holds one machine.
    #[arg(long, default_value_t = iastgcn::experiment::protocol::MACHINE_SEED)]
    pub machine_seed: u64,
    /// Merge finished reproduce folders of one protocol, one per twin machine, into
    /// --out: Tables V and III over machines and seeds, as a report; nothing trains.
    #[arg(long, num_args = 2.., conflicts_with_all = ["shard", "data_only"])]
    pub merge: Vec<PathBuf>,
    #[command(flatten)]
    pub recipe: super::RecipeArgs,
    #[command(flatten)]
    pub held_out: HeldOutArgs,
}

pub fn run(device: Device, args: &ReproduceArgs) -> anyhow::Result<()> {
    if !args.merge.is_empty() {
        let summary = iastgcn::experiment::machines::merge_machines(&args.merge, &args.out)?;
        println!(
            "merged {} twin machines ({}): {}",
            summary.folders.len(),
            summary
                .folders
                .iter()
                .map(|(_, m)| m.to_string())
                .collect::<Vec<_>>()
                .join(", "),
            args.out.join("report.md").display()
        );
        return Ok(());
    }
    let mut protocol = Protocol::paper();
    protocol.machine_seed = args.machine_seed;
    if let Some(p) = &args.config {
        protocol.run = read_run_config(Some(p), None)?;
    }
    protocol.minutes = args.minutes;
    protocol.recipe = args.recipe.sessions()?;
    protocol.closed_loop = args.recipe.closed_loop();
    protocol.seeds = args.seeds.clone();
    if !args.models.is_empty() {
        protocol.models = args.models.clone();
    }
    if !args.fractions.is_empty() {
        protocol.fractions = args.fractions.clone();
    }
    if !args.curve_models.is_empty() {
        protocol.curve_models = args.curve_models.clone();
    }
    if args.no_curve {
        protocol.fractions.clear();
        protocol.curve_models.clear();
    }
    let outcome = reproduce::reproduce(
        device,
        &protocol,
        &args
            .recipe
            .held_out(&args.held_out, HeldOutConfig::default()),
        args.shard,
        args.data_only,
        &args.out,
        &mut Console::default(),
    )?;
    match outcome {
        Outcome::Report(r) => println!(
            "reproduce finished: report in {} ({:.0} s)",
            args.out.join("report.md").display(),
            r.wall_seconds
        ),
        Outcome::Partial { done, total } => {
            println!("reproduce stopped: {done} of {total} jobs done")
        }
    }
    Ok(())
}
