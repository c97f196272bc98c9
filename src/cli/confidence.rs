//! `iastgcn confidence`: how far to trust a prediction (docs/usage.md "Confidence"):
//! seed ensembles predicting along the twin's held-out runs, their spread set beside
//! their miss, 90 % intervals calibrated on the validation session and their coverage.

use std::path::PathBuf;

use anyhow::Context;

use super::adapt::name_and_seed;
use super::evaluate_args::HeldOutArgs;
use super::train::DataArgs;
use super::Console;
use iastgcn::experiment::confidence;
use iastgcn::experiment::demo::DEMO_HELD_OUT;
use iastgcn::experiment::evaluate::ensemble;
use iastgcn::gpu::Device;
use iastgcn::model::Checkpoint;
use iastgcn::progress::Reporter;

#[derive(clap::Args)]
pub struct ConfidenceArgs {
    /// The models' training data (their recordings and calibration): the held-out
    /// sessions run on the twin machine they were recorded on, under that calibration.
    #[command(flatten)]
    pub data: DataArgs,
    /// Trained checkpoints named `<model>.seed<k>.safetensors` (as `demo` writes them):
    /// the seeds of one model make one ensemble, whose spread is its uncertainty.
    #[arg(long, num_args = 1.., required = true)]
    pub models: Vec<PathBuf>,
    /// The interval's level: the share of the validation session's predictions it covers.
    #[arg(long, default_value_t = confidence::LEVEL)]
    pub level: f64,
    #[command(flatten)]
    pub held_out: HeldOutArgs,
    /// Measure the intervals only, not the gates that shrink wide corrections in the loop.
    #[arg(long)]
    pub no_gates: bool,
    /// Output folder: confidence.md, ticks.csv (every prediction's miss and spread) and
    /// `<model>.ensemble.toml` per model (its seeds and calibrated interval, for the
    /// predictor in Rust, Python and C: docs/embedding.md "Ensembles and intervals").
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(device: &Device, args: &ConfidenceArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.level > 0.5 && args.level < 1.0,
        "--level {}: an interval covers more than half and less than all (0.5 to 1)",
        args.level
    );
    // Each model's seeds, and beside them (same order) the files they came from.
    let mut seeds: Vec<(String, Vec<Checkpoint>)> = Vec::new();
    let mut files: Vec<Vec<PathBuf>> = Vec::new();
    for path in &args.models {
        let (name, _) = name_and_seed(path);
        let ck = Checkpoint::load(path).with_context(|| format!("--models {}", path.display()))?;
        match seeds.iter().position(|(n, _)| *n == name) {
            Some(k) => {
                seeds[k].1.push(ck);
                files[k].push(path.clone());
            }
            None => {
                seeds.push((name, vec![ck]));
                files.push(vec![path.clone()]);
            }
        }
    }
    if let Some((name, _)) = seeds.iter().find(|(_, m)| m.len() < 2) {
        anyhow::bail!(
            "--models: {name} has one seed; its uncertainty is the spread of its seeds, so \
             give two or more (<model>.seed<k>.safetensors)"
        );
    }
    let mut models = seeds
        .iter()
        .map(|(name, members)| ensemble(device, name, members))
        .collect::<Result<Vec<_>, _>>()?;
    let held = args.held_out.config_or(DEMO_HELD_OUT);
    held.validate()?;
    super::make_output_folder("--out", &args.out)?;
    let mut console = Console::default();
    let runs = confidence::record(device, &seeds, &args.data.sources(), &held, &mut console)?;
    console.end();
    let calibrated = confidence::calibrate(&runs, held.sessions, args.level)?;
    let mut md = confidence::markdown(&calibrated, &held, args.level);
    if !args.no_gates {
        let gated = confidence::gate_study(
            &mut models,
            &calibrated,
            &runs,
            &args.data.sources(),
            &held,
            &mut console,
        )?;
        console.end();
        md.push_str(&confidence::gate_markdown(&gated, held.sessions));
    }
    let ensembles: Vec<_> = calibrated
        .iter()
        .filter_map(|c| {
            let k = seeds.iter().position(|(n, _)| *n == c.model)?;
            let file = confidence::ensemble_file(c, &files[k], &args.out, &held, args.level);
            Some((c.model.clone(), file))
        })
        .collect();
    confidence::write(&args.out, &md, &runs, &ensembles)?;
    println!("{md}");
    println!("written to {}", args.out.display());
    Ok(())
}
