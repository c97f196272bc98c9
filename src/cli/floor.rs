//! `iastgcn floor`: the look-ahead floor (docs/usage.md "The look-ahead floor"): what
//! an oracle that knows the residual of the tick it acts on leaves on the twin's held-out
//! runs, beside Table V's oracle.

use std::path::PathBuf;

use super::evaluate_args::HeldOutArgs;
use super::train::DataArgs;
use super::Console;
use iastgcn::experiment::demo::DEMO_HELD_OUT;
use iastgcn::experiment::floor;
use iastgcn::progress::Reporter;

#[derive(clap::Args)]
pub struct FloorArgs {
    /// The training data whose machine and calibration the held-out sessions run on.
    #[command(flatten)]
    pub data: DataArgs,
    /// The window T of the model the oracles stand in for (the demo's: 48): they act
    /// from its T-th tick on.
    #[arg(long, default_value_t = 48, value_parser = super::count(1..))]
    pub window: usize,
    #[command(flatten)]
    pub held_out: HeldOutArgs,
    /// Output folder: floor.md and floor.csv.
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(args: &FloorArgs) -> anyhow::Result<()> {
    let held = args.held_out.config_or(DEMO_HELD_OUT);
    held.validate()?;
    super::make_output_folder("--out", &args.out)?;
    let mut console = Console::default();
    let rows = floor::run(&args.data.sources(), &held, args.window, &mut console)?;
    console.end();
    floor::write(&args.out, &rows, &held, args.window)?;
    println!("{}", floor::markdown(&rows, &held, args.window));
    println!("written to {}", args.out.display());
    Ok(())
}
