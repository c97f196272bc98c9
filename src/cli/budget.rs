//! `iastgcn budget`: the error budget of one held-out polishing run in the twin (the
//! hidden tool-pose error split by source, docs/twin.md "Error budget").

use super::compensate::RunArgs;
use iastgcn::compensate::budget::{error_budget, markdown};
use iastgcn::compensate::held_out::Prepared;

#[derive(clap::Args)]
pub struct BudgetArgs {
    #[command(flatten)]
    pub run: RunArgs,
}

pub fn run(args: &BudgetArgs) -> anyhow::Result<()> {
    args.run.warn_other_machine()?;
    let Prepared {
        machine,
        calibrated,
        run,
        ..
    } = args.run.spec()?.prepare()?;
    let rows = error_budget(&machine, &calibrated, &run.config(), &run.start)?;
    let a = &args.run;
    println!(
        "error budget of {} ({} min, seed {}, machine {}, {} min warm-up): true tool-pose error by source",
        run.path.name(),
        a.minutes,
        a.seed,
        a.machine_seed,
        a.warm_up_minutes
    );
    print!("{}", markdown(&rows));
    Ok(())
}
