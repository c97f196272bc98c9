//! `iastgcn demo` (the main job end to end on the embedded twin) and `iastgcn evaluate`
//! (Tables III and V and the report folder for models you trained; its flags are in
//! `evaluate_args`): arguments, then the library's `experiment::demo`.

use std::path::{Path, PathBuf};

use clap::Args;

use super::evaluate_args::{EvaluateArgs, HeldOutArgs};
use super::train::read_run_config;
use super::Console;
use iastgcn::data::DataSources;
use iastgcn::experiment::demo::{self, DemoConfig};
use iastgcn::gpu::Device;
use iastgcn::robot::Description;

#[derive(Args)]
pub struct DemoArgs {
    /// Report folder. A demo interrupted in it continues where it stopped when run again
    /// with the same settings; a finished one starts afresh (docs/usage.md "Run the demo").
    #[arg(long, default_value = "report")]
    pub out: PathBuf,
    /// Run config; the embedded assets/demo.toml when absent (assets/paper.toml runs the
    /// paper's sizes, for a real GPU).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Length of each training recording, minutes.
    #[arg(long, default_value_t = iastgcn::experiment::demo::DEMO_MINUTES)]
    pub minutes: f64,
    /// Training seeds, comma-separated: every model is trained with each, and the tables
    /// report mean ± SD over them with paired comparisons (one seed: a single run; 1,2,3
    /// adds a third seed, about two minutes more on 2 cores).
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    pub seeds: Vec<u64>,
    /// Also train and evaluate the spatio-temporal baselines of Table III (ConvLSTM, T-GCN,
    /// EAT-GCN, ST-GAT) at the same budget (beyond the demo's 10 minutes on 2 CPU cores).
    #[arg(long)]
    pub all_models: bool,
    #[command(flatten)]
    pub recipe: super::RecipeArgs,
    #[command(flatten)]
    pub held_out: HeldOutArgs,
    /// Polishing iterations of the mirror section (the recommended model polishing one
    /// surface against the other controllers, docs/polishing.md); 0 leaves it out.
    #[arg(long, default_value_t = 2, value_parser = super::count(0..=20))]
    pub mirror_iterations: usize,
}

pub fn evaluate(device: Device, args: &EvaluateArgs) -> anyhow::Result<()> {
    super::make_output_folder("--out", &args.out)?;
    if let Description::Serial(arm) = Description::load_or_default(args.robot.as_deref())? {
        // The arm's models are trained here and its calibration fitted here: flags of
        // the hybrid machine's evaluation would be ignored, so they are refused.
        let robot = args.robot.as_deref().unwrap_or(Path::new("")).display();
        let unused = [
            (
                !args.models.is_empty(),
                "--models",
                "its residual models are trained here (--train-models picks them)",
            ),
            (
                args.calibration.is_some(),
                "--calibration",
                "it is calibrated here on the training blocks of its pose files",
            ),
            (
                args.graph.is_some(),
                "--graph",
                "its sensor graph comes from its description",
            ),
        ];
        if let Some((_, flag, why)) = unused.iter().find(|u| u.0) {
            anyhow::bail!("{flag} does not apply to a serial arm (--robot {robot}): {why}");
        }
        return super::arm::evaluate(device, &arm, args);
    }
    anyhow::ensure!(
        args.targets.is_none(),
        "--targets is for a serial arm's corrected joint targets: give its description in --robot"
    );
    anyhow::ensure!(
        args.seeds.is_none(),
        "--seeds is for a serial arm's residual models, trained here: give its description in --robot (the hybrid machine's evaluation scores the checkpoints of --models; `demo` and `reproduce` train over seeds)"
    );
    anyhow::ensure!(
        !args.without_channel_time,
        "--without-channel-time is for a serial arm's sensor channels: give its description in --robot"
    );
    anyhow::ensure!(
        args.test.is_empty(),
        "--test is for a serial arm's separate test poses: give its description in --robot (the hybrid machine's Table V scores held-out runs in the twin)"
    );
    let calibration = args.calibration.clone().ok_or_else(|| {
        anyhow::anyhow!("--calibration is required (or give a serial arm's description in --robot)")
    })?;
    anyhow::ensure!(
        !args.models.is_empty(),
        "--models is required: the checkpoints to compare (or give a serial arm's description in --robot)"
    );
    let config = read_run_config(args.config.as_deref(), None)?;
    let sources = DataSources {
        recordings: args.data.clone(),
        calibration,
        graph: args.graph.clone(),
        robot: args.robot.clone(),
    };
    let report = iastgcn::experiment::evaluate::evaluation_report(
        device,
        &args.models,
        &sources,
        &config,
        &args.held_out.config(),
        &args.out,
        &mut Console::default(),
    )?;
    if let Some(headline) = &report.headline {
        println!("{headline}");
    }
    Ok(())
}

pub fn demo(device: Device, args: &DemoArgs) -> anyhow::Result<()> {
    let held_out = args.recipe.held_out(&args.held_out, demo::DEMO_HELD_OUT);
    let mut config = DemoConfig {
        minutes: args.minutes,
        held_out,
        all_models: args.all_models,
        seeds: args.seeds.clone(),
        recipe: args.recipe.sessions()?,
        mirror: (args.mirror_iterations > 0).then(|| demo::PolishSpec {
            iterations: args.mirror_iterations,
            every: held_out.every,
            ..demo::demo_mirror()
        }),
        closed_loop: args.recipe.closed_loop(),
        ..DemoConfig::default()
    };
    if let Some(p) = &args.config {
        config.run = read_run_config(Some(p), None)?;
        config.run_source = p.display().to_string();
    }
    let report = demo::demo(device, &config, &args.out, &mut Console::default())?;
    if let Some(headline) = &report.headline {
        println!("{headline}");
    }
    println!("demo finished in {:.0} s", report.wall_seconds);
    Ok(())
}
