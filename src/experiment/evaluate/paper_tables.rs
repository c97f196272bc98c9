//! Table III (prediction accuracy on the held-out split per trajectory and model) and
//! Table V (pose error of held-out polishing runs: initial, calibrated, compensated per
//! model) into a report, with the graph-mixing table.

use super::held_out::{held_out_session, HeldOutConfig, SessionOptions};
use super::models::{predictors, NamedModel};
use crate::data::{DataSources, Dataset};
use crate::error::{Error, Result};
use crate::experiment::parallel;
use crate::experiment::recommend::{recommend, validation_session};
use crate::experiment::report::{table_iii_lines, Report, TableIIIRow, Timing};
use crate::gpu::Device;
use crate::graph::Graph;
use crate::model::{Checkpoint, Features, ModelError, Predictor};
use crate::progress::Reporter;
use crate::train::metrics::per_recording;
use crate::train::{
    build_dataset, by_path, data_normalization, recording_stem, RunConfig, TestMetrics,
};
use crate::twin::PathKind;

/// Predictions (µm, mdeg) of a checkpoint for the windows at `positions` of a dataset
/// standardised with the checkpoint's own statistics, through the batched
/// [`Predictor`] path.
pub fn predict_windows(
    device: &Device,
    ck: &Checkpoint,
    data: &Dataset,
    positions: &[usize],
) -> Result<Vec<[f64; 6]>, ModelError> {
    let mut predictor = Predictor::on(device, ck, 64.min(positions.len().max(1)))?;
    let (x, _) = data.gather(positions);
    let mut out = Vec::with_capacity(positions.len());
    predictor.predict_batch(&x, Features::Standardised, &mut out)?;
    Ok(out)
}

/// Table III rows of one model: test-split metrics per path (a recording's rows named
/// by its file stem; the sessions of one path pooled), plus the training-mean baseline
/// as the model `training mean` when `baseline` is set.
pub fn table_iii(
    device: &Device,
    model: &str,
    ck: &Checkpoint,
    data: &Dataset,
    baseline: bool,
) -> Result<Vec<TableIIIRow>, ModelError> {
    let [_, _, test] = data.split_ranges();
    let positions: Vec<usize> = test.collect();
    let pred = predict_windows(device, ck, data, &positions)?;
    let per: Vec<TestMetrics> = data
        .recordings
        .iter()
        .zip(per_recording(data, &positions, &pred))
        .map(|(name, (model, training_mean))| TestMetrics {
            recording: recording_stem(name),
            model,
            training_mean,
        })
        .collect();
    let mut rows = Vec::new();
    // The sessions of one path are one row (docs/twin.md "Sessions").
    for t in by_path(&per) {
        rows.push(TableIIIRow {
            trajectory: t.recording.clone(),
            model: model.to_string(),
            metrics: t.model,
        });
        if baseline {
            rows.push(TableIIIRow {
                trajectory: t.recording,
                model: "training mean".into(),
                metrics: t.training_mean,
            });
        }
    }
    Ok(rows)
}

/// Table III (each model on the test split of `sources`, windowed as `config` says and
/// standardised with the model's own statistics) and Table V (every path of one held-out
/// session in the twin, compensated by each model), with the Hilbert run's error budget,
/// Fig. 11 traces and Fig. 10 timings, added to `report`. Each model reads the sensors of
/// its own checkpoint's graph online; the oracle runs at the first model's window; Fig.
/// 11 shows the first model named `iastgcn` or `iastgcn.seed<k>` (or the first).
pub fn evaluate(
    device: &Device,
    report: &mut Report,
    models: &[NamedModel],
    sources: &DataSources,
    config: &RunConfig,
    held: &HeldOutConfig,
    reporter: &mut dyn Reporter,
) -> Result<()> {
    let Some(first) = models.first() else {
        return Err(Error::Invalid("no model to evaluate".into()));
    };
    held.validate()?;
    reporter.note("== Table III: prediction accuracy on the held-out split");
    let windowed = Graph::load_or_default(sources.graph.as_deref())?;
    // Each model windows the recordings with its own statistics and predicts alone: on
    // every core where the predictions run on the native CPU path.
    let native = match device {
        Device::Native => true,
        Device::Adapter(gpu) => gpu.is_software(),
    };
    let per_model = parallel::run_all(
        models.iter().enumerate().collect(),
        parallel::workers(native),
        |(i, m), _| -> Result<Vec<TableIIIRow>> {
            let mut c = config.clone();
            c.model = m.checkpoint.config.clone();
            let fixed =
                data_normalization(&m.checkpoint.normalization).map_err(|e| e.context(&m.name))?;
            // The test windows are read with the sources' graph: a model that reads other
            // sensors would be scored on the wrong channels.
            if windowed.nodes != m.checkpoint.graph.nodes {
                return Err(Error::Invalid(format!(
                    "{}: the model reads the sensors [{}], but the recordings are windowed \
                     with the graph [{}]; a model is scored on recordings windowed with its \
                     own graph",
                    m.name,
                    m.checkpoint.graph.nodes.join(", "),
                    windowed.nodes.join(", ")
                )));
            }
            let (_, data) = build_dataset(sources, &c, Some(&fixed))?;
            Ok(table_iii(device, &m.name, &m.checkpoint, &data, i == 0)?)
        },
        || {},
    )?;
    let rows: Vec<TableIIIRow> = per_model.into_iter().flatten().collect();
    for line in table_iii_lines(&rows) {
        reporter.note(&line);
    }
    report.table_iii = rows;

    reporter.note("== Table V: compensation of held-out runs in the twin");
    let checkpoints: Vec<(String, Checkpoint)> = models
        .iter()
        .map(|m| (m.name.clone(), m.checkpoint.clone()))
        .collect();
    let mut in_loop = predictors(device, &checkpoints)?;
    let table_v_session = SessionOptions {
        budget: true,
        ..SessionOptions::rows(0)
    };
    let session = held_out_session(
        device,
        &mut in_loop,
        sources,
        held,
        table_v_session,
        reporter,
    )?;
    if let Some(budget) = session.budget {
        report.sections.push((
            format!("Error budget: {} (held-out run)", PathKind::Hilbert.name()),
            format!(
                "The hidden tool-pose error of this run split by source (RMS over every tick, \
                 against the path target; `iastgcn budget` gives it for any run):\n\n{budget}"
            ),
        ));
    }
    report.table_v.extend(session.rows);
    // The other held-out sessions: Table V's rows only (its traces, budget and timings
    // are the first session's).
    for k in 1..held.sessions {
        reporter.note(&format!(
            "== Table V, held-out session {} of {}: {}",
            k + 1,
            held.sessions,
            held.session(k).describe()
        ));
        let other = held_out_session(
            device,
            &mut in_loop,
            sources,
            held,
            SessionOptions::rows(k),
            reporter,
        )?;
        report.table_v.extend(other.rows);
        report.notes.extend(other.refusals);
    }

    reporter.note(
        "== recommended model: every model in the loop on a validation session (not in Table V)",
    );
    let validation_index = validation_session(held.sessions);
    let validation = held_out_session(
        device,
        &mut in_loop,
        sources,
        held,
        SessionOptions::rows(validation_index),
        reporter,
    )?;
    let recommendation = recommend(&validation.rows);
    reporter.note(&recommendation.sentence());
    report.headline = recommendation.headline(&report.table_v);
    report.recommended = recommendation
        .best
        .map(|i| recommendation.scores[i].best_seed.clone());
    report.setup.push(recommendation.sentence());
    report.sections.push((
        "Recommended model".into(),
        recommendation.markdown(
            (
                validation_index + 1,
                &held.session(validation_index).describe(),
            ),
            held.minutes,
        ),
    ));
    report.setup.push(format!(
        "held-out session (Table V): twin machine {}, the machine the recordings were taken \
         on (their `.run.toml` sidecars; machine 1 when none has one)",
        session.machine_seed
    ));
    report.setup.extend(session.calibration_warning);
    report.notes.extend(session.refusals);
    // Fig. 11 shows before/after: calibration only, and the main model.
    let main = models
        .iter()
        .find(|m| crate::experiment::report::seeds::split_name(&m.name).0 == "iastgcn")
        .unwrap_or(first)
        .name
        .clone();
    let keep = format!("compensated ({main})");
    report.traces.extend(
        session
            .traces
            .into_iter()
            .filter(|t| t.label == "calibrated" || t.label == keep),
    );
    report.timings = models
        .iter()
        .zip(session.latency_ms)
        .zip(session.ran_on)
        .map(|((m, infer_ms), inference_on)| Timing {
            model: m.name.clone(),
            epoch_seconds: m.epoch_seconds,
            infer_ms,
            trained_on: m.trained_on.clone(),
            inference_on,
        })
        .collect();
    Ok(())
}

/// Tables III and V of `models` into `report`, with the table of how much each model's
/// graph convolution mixes the sensors.
pub(crate) fn tables(
    device: &Device,
    report: &mut Report,
    models: &[NamedModel],
    sources: &DataSources,
    config: &RunConfig,
    held_out: &HeldOutConfig,
    reporter: &mut dyn Reporter,
) -> Result<()> {
    evaluate(device, report, models, sources, config, held_out, reporter)?;
    if let Some(table) = graph_mixing_table(models) {
        report
            .sections
            .push(("Graph convolution after training".into(), table));
    }
    Ok(())
}

/// The report's table of how much each model's graph convolution mixes the sensors
/// (`model::graph_mixing`, per block); None when no model has one.
pub(super) fn graph_mixing_table(models: &[NamedModel]) -> Option<String> {
    let rows: Vec<(&str, Vec<f64>)> = models
        .iter()
        .map(|m| {
            let c = &m.checkpoint;
            (
                m.name.as_str(),
                crate::model::graph_mixing(&c.config, &c.graph, &c.parameters),
            )
        })
        .filter(|(_, v)| !v.is_empty())
        .collect();
    let blocks = rows.iter().map(|(_, v)| v.len()).max()?;
    let mut out = String::from(
        "How much each block's graph convolution mixes the sensors after training: \
         ‖Ψ − diag Ψ‖ / ‖diag Ψ‖ (Frobenius) with Ψ = Σ_k θ_k basis_k (docs/model.md \
         step 3). 0 is the identity, no mixing: the wavelet convolution starts there with \
         every θ = 1, and stays near it unless its θ move apart; the Chebyshev convolution \
         of `iastgcn-s` starts near 0.95 on the embedded graph.\n\n| Model |",
    );
    for l in 1..=blocks {
        out.push_str(&format!(" Block {l} |"));
    }
    out.push_str("\n|---|");
    out.push_str(&"---:|".repeat(blocks));
    out.push('\n');
    for (name, v) in rows {
        out.push_str(&format!("| {name} |"));
        for l in 0..blocks {
            match v.get(l) {
                Some(x) => out.push_str(&format!(" {x:.3} |")),
                None => out.push_str(" |"),
            }
        }
        out.push('\n');
    }
    Some(out)
}
