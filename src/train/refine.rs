//! Refinement (docs/model.md "Refinement", the paper's Algorithm 2): warm-started stages
//! on ensembles of consecutive windows, a final per-window judge that keeps the incoming
//! weights unless refinement lowers the per-window validation loss, and the accumulated
//! error over consecutive held-out windows (Fig. 9b) before and after.

use std::path::Path;

use super::fit::{run_stage, sibling, test_metrics, TestMetrics};
use super::{
    accumulated_error, consecutive_runs, core_stage, log, refine_stages, to_physical, EpochRecord,
    RunConfig, Trainer,
};
use crate::data::Dataset;
use crate::error::{Error, Result};
use crate::gpu::Device;
use crate::graph::Graph;
use crate::model::{Checkpoint, Parameters};
use crate::progress::Reporter;

/// Accumulated error over consecutive windows `k`: (k, position µm, attitude mdeg).
pub type AccumulatedCurve = Vec<(usize, f64, f64)>;

/// Accumulated error curve (Fig. 9b) of the test split's runs with the trainer's weights.
fn accumulated(trainer: &Trainer, data: &Dataset, horizon: usize) -> Result<AccumulatedCurve> {
    let [_, _, test] = data.split_ranges();
    let runs = consecutive_runs(data, test);
    let positions: Vec<usize> = runs.iter().flatten().copied().collect();
    let pred = to_physical(&trainer.predict(&positions)?, &data.normalization);
    let mut pred = pred.into_iter();
    let pairs: Vec<Vec<([f64; 6], [f64; 6])>> = runs
        .iter()
        .map(|run| {
            run.iter()
                .zip(pred.by_ref())
                .map(|(&p, y)| (y, data.labels[p]))
                .collect()
        })
        .collect();
    Ok(accumulated_error(&pairs, horizon))
}

/// What a refinement produced.
pub struct Refined {
    /// The weights to keep: the refined ones, or the incoming ones when `kept_core`.
    pub params: Parameters,
    /// One record per epoch of every refinement stage.
    pub history: Vec<EpochRecord>,
    /// Fig. 9b before refinement.
    pub before: AccumulatedCurve,
    /// Fig. 9b after, for `params`.
    pub after: AccumulatedCurve,
    /// Test-split metrics of the incoming weights, per recording.
    pub metrics_before: Vec<TestMetrics>,
    /// Test-split metrics of `params`, per recording.
    pub metrics_after: Vec<TestMetrics>,
    /// Per-window validation loss (the core stage's) of the incoming parameters.
    pub core_val: f64,
    /// The same loss of the returned parameters (the incoming ones when refinement did
    /// not lower it).
    pub refined_val: f64,
    /// True when refinement did not lower the loss and the incoming weights are kept.
    pub kept_core: bool,
}

/// Runs the refinement stages of `config` from `init`.
pub fn refine(
    device: &Device,
    data: &Dataset,
    graph: &Graph,
    config: &RunConfig,
    init: &Parameters,
    reporter: &mut dyn Reporter,
) -> Result<Refined> {
    let horizon = config.refine.horizon;
    let mut params = init.clone();
    let mut history = Vec::new();
    let mut before = None;
    let mut last: Option<Trainer> = None;
    for stage in refine_stages(config) {
        let mut trainer = Trainer::new(
            device,
            data,
            graph,
            &config.model,
            &config.train,
            stage.clone(),
            &params,
        )?;
        if before.is_none() {
            before = Some((
                accumulated(&trainer, data, horizon)?,
                test_metrics(&trainer, data)?,
            ));
        }
        // A stage keeps what it was given unless its validation loss improves.
        trainer.keep_start_unless_improved()?;
        reporter.note(&format!(
            "{}: ensembles of {} windows, {} per step, {} steps per epoch, lr0 {:.1e}",
            stage.name,
            stage.group,
            trainer.batch(),
            trainer.steps_per_epoch(),
            stage.lr0
        ));
        run_stage(&mut trainer, &stage.name, reporter, |_, _| Ok(()))?;
        history.extend(trainer.progress.history.iter().cloned());
        params = trainer.best.clone();
        last = Some(trainer);
    }
    let (Some(mut trainer), Some((before, metrics_before))) = (last, before) else {
        return Err(Error::Invalid(
            "refine.magnifications is empty: nothing to refine".into(),
        ));
    };
    // The stages score ensembles; the model is used window by window, so it is kept only
    // if the per-window validation loss improves too.
    let mut judge = Trainer::new(
        device,
        data,
        graph,
        &config.model,
        &config.train,
        core_stage(config),
        init,
    )?;
    let core_val = judge.validation_loss_of(init)?;
    let refined_val = judge.validation_loss_of(&params)?;
    let kept_core = refined_val >= core_val;
    if kept_core {
        params = init.clone();
        trainer.load_parameters(init)?;
    }
    drop(judge);
    Ok(Refined {
        after: accumulated(&trainer, data, horizon)?,
        metrics_after: test_metrics(&trainer, data)?,
        params,
        history,
        before,
        metrics_before,
        core_val,
        refined_val: refined_val.min(core_val),
        kept_core,
    })
}

/// Refines `checkpoint` on the recordings of `sources` with `config`'s refinement stages
/// (`config`'s model is replaced by the checkpoint's): the recordings are windowed as
/// `config` says and standardised with the checkpoint's own statistics, as it was
/// trained. `iastgcn refine` and the Python `refine` run this.
pub fn refine_checkpoint(
    device: &Device,
    sources: &crate::data::DataSources,
    config: &RunConfig,
    checkpoint: &Checkpoint,
    reporter: &mut dyn Reporter,
) -> Result<Refined> {
    let mut config = config.clone();
    config.model = checkpoint.config.clone();
    let fixed = super::data_normalization(&checkpoint.normalization)?;
    let (graph, data) = super::build_dataset(sources, &config, Some(&fixed))?;
    refine(
        device,
        &data,
        &graph,
        &config,
        &checkpoint.parameters,
        reporter,
    )
}

impl Refined {
    /// One line that says whether refinement kept the incoming or the refined weights.
    pub fn verdict(&self) -> String {
        format!(
            "per-window validation loss {:.4} before refinement, {:.4} after; {}",
            self.core_val,
            self.refined_val,
            if self.kept_core {
                "kept the core model"
            } else {
                "kept the refined model"
            }
        )
    }

    /// Writes the refined checkpoint (`base` with the refined weights) to `out`, and
    /// beside it `<stem>.log.csv`, `<stem>.loss.png`, `<stem>.accumulated.csv` and
    /// `<stem>.accumulated.png` (Fig. 9b). Returns the checkpoint.
    pub fn save(&self, base: &Checkpoint, out: &Path) -> Result<Checkpoint> {
        let ck = Checkpoint {
            parameters: self.params.clone(),
            ..base.clone()
        };
        // All five replace older files together or not at all.
        let mut batch = crate::atomic::Batch::new();
        ck.stage(&mut batch, out)?;
        let mut text =
            |path: &Path, bytes: &[u8]| batch.add(path, bytes).map_err(|e| Error::io(path, e));
        let log_csv = sibling(out, ".log.csv");
        text(&log_csv, log::history_csv(&self.history).as_bytes())?;
        let accumulated = sibling(out, ".accumulated.csv");
        let csv = log::accumulated_csv(&self.before, &self.after);
        text(&accumulated, csv.as_bytes())?;
        batch.add_with(&sibling(out, ".loss.png"), |tmp| {
            log::plot_losses(tmp, &[("refine".to_string(), self.history.clone())])
        })?;
        batch.add_with(&sibling(out, ".accumulated.png"), |tmp| {
            log::plot_accumulated(tmp, &self.before, &self.after)
        })?;
        batch.commit().map_err(|e| Error::io(out, e))?;
        Ok(ck)
    }
}
