//! The report of a protocol whose jobs are all done: Tables III and V over seeds, the
//! core training table and the learning curve.

use std::path::Path;
use std::time::Instant;

use super::protocol::{Job, Protocol};
use crate::data::DataSources;
use crate::error::Result;
use crate::experiment::evaluate::{tables, HeldOutConfig, NamedModel};
use crate::experiment::jobs::{clock, training_table, JobRecord};
use crate::experiment::protocol::{CALIBRATION_SEED, OPEN_LOOP_DATA, TRAINING_SEED};
use crate::experiment::recipe::NamedRecipe;
use crate::experiment::report::curve::CurvePoint;
use crate::experiment::report::seeds::Spread;
use crate::experiment::report::{self, Report};
use crate::gpu::Device;
use crate::model::Checkpoint;
use crate::progress::Reporter;

/// The report of a protocol whose jobs are all done.
#[allow(clippy::too_many_arguments)]
pub(super) fn report(
    device: Device,
    protocol: &Protocol,
    jobs: &[Job],
    held_out: &HeldOutConfig,
    (sources, closed_loop): (&DataSources, Option<String>),
    began: Instant,
    out: &Path,
    reporter: &mut dyn Reporter,
) -> Result<Report> {
    reporter.note("== every job done: Tables III and V, report");
    let mut records = Vec::new();
    let mut models = Vec::new();
    let mut histories = Vec::new();
    for job in jobs {
        let record = JobRecord::load(&job.record_path(out))?;
        if job.is_curve() {
            records.push(record);
            continue;
        }
        let files = job.files(out);
        models.push(NamedModel {
            name: record.name.clone(),
            checkpoint: Checkpoint::load(&files.refined)?,
            epoch_seconds: record.epoch_seconds,
            trained_on: record.trained_on.clone(),
        });
        // The learning curves of the first seed (one panel per model).
        if job.seed == protocol.seeds[0] {
            let log = crate::train::sibling(&files.core, ".log.csv");
            histories.push((record.name.clone(), crate::train::log::read_csv(&log)?));
        }
        records.push(record);
    }
    let run = &protocol.run;
    let seeds: Vec<String> = protocol.seeds.iter().map(u64::to_string).collect();
    let setup = vec![
        format!(
            "protocol: {} (T = {}, C = {}, L = {}, {}, batch {}, at most {} epochs, \
             patience {}); models {}; training seeds {}",
            out.join("protocol.toml").display(),
            run.model.window,
            run.model.channels,
            run.model.blocks,
            run.model.look_ahead_words(),
            run.train.batch,
            run.train.max_epochs,
            run.train.patience,
            protocol.models.join(", "),
            seeds.join(", ")
        ),
        NamedRecipe::line_for(&protocol.recipe, protocol.closed_loop, held_out.every),
        format!(
            "data: twin machine {}; calibration set at rest on a cold machine (seed \
             {CALIBRATION_SEED}); training recordings under the calibrated controller: {}; \
             held-out runs: every path turned or reversed on the part, plus the rosette, {} \
             min each, in {}; prediction every {} ticks",
            protocol.machine_seed,
            protocol.recipe.describe(protocol.minutes, TRAINING_SEED),
            held_out.minutes,
            held_out.describe_sessions(),
            held_out.every
        ),
        closed_loop.unwrap_or_else(|| OPEN_LOOP_DATA.into()),
        "split: contiguous 70/20/10 blocks per recording (leakage-free); every seed sees the same split".into(),
        format!(
            "wall time of the jobs (summed over the runs that finished them): {}",
            clock(records.iter().map(|r| r.wall_seconds).sum())
        ),
    ];
    let mut report = Report {
        title: "IASTGCN on the digital twin — reproduction of the paper's protocol".into(),
        headline: None,
        adapter: device.name(),
        setup,
        histories,
        sections: vec![(
            "Core training over seeds".into(),
            training_table(&protocol.models, &records),
        )],
        curve: learning_curve(protocol, &records),
        ..Report::default()
    };
    tables(
        &device,
        &mut report,
        &models,
        sources,
        run,
        held_out,
        reporter,
    )?;
    report::finish(report, began, out, reporter)
}

/// The learning curve's points: each curve model at each share (and at the full set when
/// it is one of the tables' models too), over its seeds.
fn learning_curve(protocol: &Protocol, records: &[JobRecord]) -> Vec<CurvePoint> {
    let mut points = Vec::new();
    for model in &protocol.curve_models {
        let mut shares = protocol.fractions.clone();
        if protocol.models.contains(model) {
            shares.push(1.0);
        }
        shares.sort_by(f64::total_cmp);
        for fraction in shares {
            let of: Vec<&JobRecord> = records
                .iter()
                .filter(|r| &r.model == model && r.fraction == fraction)
                .collect();
            let Some(first) = of.first() else {
                continue;
            };
            let spread = |pick: fn(&JobRecord) -> f64| {
                Spread::of(&of.iter().map(|r| pick(r)).collect::<Vec<_>>())
            };
            points.push(CurvePoint {
                model: model.clone(),
                fraction,
                windows: first.train_windows,
                val_pos: spread(|r| r.val_mae[0]),
                val_att: spread(|r| r.val_mae[1]),
                test_pos: spread(|r| r.test_mae[0]),
                test_att: spread(|r| r.test_mae[1]),
            });
        }
    }
    points
}
