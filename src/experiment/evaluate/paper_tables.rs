//! Table III (prediction accuracy on the held-out split per trajectory and model) and
//! Table V (pose error of held-out polishing runs: initial, calibrated, compensated per
//! model) into a report, with the graph-mixing table.

use super::held_out::{held_out_session, more_models, HeldOutConfig, Session, SessionOptions};
use super::models::{predictors, NamedModel};
use crate::data::{DataSources, Dataset};
use crate::error::{Error, Result};
use crate::experiment::parallel;
use crate::experiment::recommend::{recommend, validation_session};
use crate::experiment::report::{table_iii_lines, Report, TableIIIRow, Timing};
use crate::gpu::Device;
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

/// What [`evaluate_models`] measured of a group of models: their Table III rows, every
/// held-out session of Table V, and the validation session the recommendation is chosen
/// on.
pub struct Evaluated {
    /// Table III rows, model by model.
    pub table_iii: Vec<TableIIIRow>,
    /// Table V's held-out sessions, in order.
    pub sessions: Vec<Session>,
    /// The validation session ([`validation_session`]), not scored in Table V.
    pub validation: Session,
}

impl Evaluated {
    /// The evaluation of every model of `groups` (the first from [`evaluate_models`]
    /// alone, the others after it), as one evaluation of all of them in the groups'
    /// order would give it.
    pub fn merge(groups: Vec<Evaluated>) -> Result<Evaluated> {
        let sessions = groups.first().map_or(0, |g| g.sessions.len());
        let mut table_iii = Vec::new();
        let mut per_session: Vec<Vec<Session>> = (0..sessions).map(|_| Vec::new()).collect();
        let mut validation = Vec::new();
        for g in groups {
            if g.sessions.len() != sessions {
                return Err(Error::Invalid(
                    "evaluations of different held-out sessions cannot be merged".into(),
                ));
            }
            table_iii.extend(g.table_iii);
            for (all, s) in per_session.iter_mut().zip(g.sessions) {
                all.push(s);
            }
            validation.push(g.validation);
        }
        Ok(Evaluated {
            table_iii,
            sessions: per_session
                .into_iter()
                .map(Session::merge)
                .collect::<Result<_>>()?,
            validation: Session::merge(validation)?,
        })
    }
}

/// Table III (each model on the test split of `sources`, windowed as `config` says and
/// standardised with the model's own statistics), Table V (every path of each held-out
/// session in the twin, compensated by each model, with the first session's Hilbert
/// error budget) and the validation session. Each model reads the sensors of its own
/// checkpoint's graph online; the oracle runs at the first model's window. With `after`
/// (an evaluation of other models), only these models run: Table III without the
/// training mean's rows, and each held-out run from the state `after`'s started from
/// ([`more_models`]), for [`Evaluated::merge`].
pub fn evaluate_models(
    device: &Device,
    models: &[NamedModel],
    sources: &DataSources,
    config: &RunConfig,
    held: &HeldOutConfig,
    after: Option<&Evaluated>,
    reporter: &mut dyn Reporter,
) -> Result<Evaluated> {
    if models.is_empty() {
        return Err(Error::Invalid("no model to evaluate".into()));
    }
    held.validate()?;
    reporter.note("== Table III: prediction accuracy on the held-out split");
    // Each model windows the recordings with its own statistics and predicts alone: on
    // every core where the predictions run on the native CPU path.
    let native = match device {
        Device::Native => true,
        Device::Adapter(gpu) => gpu.is_software(),
    };
    let baseline = after.is_none();
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
            let windowed = sources.graph(c.model.look_ahead)?;
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
            Ok(table_iii(
                device,
                &m.name,
                &m.checkpoint,
                &data,
                baseline && i == 0,
            )?)
        },
        || {},
    )?;
    let table_iii_rows: Vec<TableIIIRow> = per_model.into_iter().flatten().collect();
    for line in table_iii_lines(&table_iii_rows) {
        reporter.note(&line);
    }

    reporter.note("== Table V: compensation of held-out runs in the twin");
    let checkpoints: Vec<(String, Checkpoint)> = models
        .iter()
        .map(|m| (m.name.clone(), m.checkpoint.clone()))
        .collect();
    let mut in_loop = predictors(device, &checkpoints)?;
    let mut session =
        |index: usize, options: SessionOptions, reporter: &mut dyn Reporter| -> Result<Session> {
            match after {
                None => held_out_session(device, &mut in_loop, sources, held, options, reporter),
                Some(after) => {
                    let earlier = if index == validation_session(held.sessions) {
                        &after.validation
                    } else {
                        after.sessions.get(index).ok_or_else(|| {
                            Error::Invalid(format!("no held-out session {} to follow", index + 1))
                        })?
                    };
                    more_models(device, &mut in_loop, sources, held, earlier, reporter)
                }
            }
        };
    let mut sessions = vec![session(
        0,
        SessionOptions {
            budget: true,
            ..SessionOptions::rows(0)
        },
        reporter,
    )?];
    // The other held-out sessions: Table V's rows only (its traces, budget and timings
    // are the first session's).
    for k in 1..held.sessions {
        reporter.note(&format!(
            "== Table V, held-out session {} of {}: {}",
            k + 1,
            held.sessions,
            held.session(k).describe()
        ));
        sessions.push(session(k, SessionOptions::rows(k), reporter)?);
    }
    reporter.note(
        "== recommended model: every model in the loop on a validation session (not in Table V)",
    );
    let validation_index = validation_session(held.sessions);
    let validation = session(
        validation_index,
        SessionOptions::rows(validation_index),
        reporter,
    )?;
    Ok(Evaluated {
        table_iii: table_iii_rows,
        sessions,
        validation,
    })
}

/// What [`evaluate_models`] measured of `models` (in their order), into `report`: Table
/// III, Table V with the first session's Hilbert error budget, Fig. 11 traces (the first
/// model named `iastgcn` or `iastgcn.seed<k>`, or the first), Fig. 10 timings, the
/// recommendation and its headline.
pub fn report_evaluation(
    report: &mut Report,
    models: &[NamedModel],
    evaluated: Evaluated,
    held: &HeldOutConfig,
    reporter: &mut dyn Reporter,
) -> Result<()> {
    let Some(first) = models.first() else {
        return Err(Error::Invalid("no model to evaluate".into()));
    };
    let Evaluated {
        table_iii,
        sessions,
        validation,
    } = evaluated;
    report.table_iii = table_iii;
    let mut sessions = sessions.into_iter();
    let Some(mut session) = sessions.next() else {
        return Err(Error::Invalid("no held-out session was run".into()));
    };
    if let Some(budget) = &session.budget {
        report.sections.push((
            format!("Error budget: {} (held-out run)", PathKind::Hilbert.name()),
            format!(
                "The hidden tool-pose error of this run split by source (RMS over every tick, \
                 against the path target; `iastgcn budget` gives it for any run):\n\n{budget}"
            ),
        ));
    }
    report.table_v.append(&mut session.rows);
    for other in sessions {
        report.table_v.extend(other.rows);
        report.notes.extend(other.refusals);
    }
    let recommendation = recommend(&validation.rows);
    reporter.note(&recommendation.sentence());
    report.headline = recommendation.headline(&report.table_v);
    report.recommended = recommendation
        .best
        .map(|i| recommendation.scores[i].best_seed.clone());
    report.setup.push(recommendation.sentence());
    let validation_index = validation.index;
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
    if session.latency_ms.len() != models.len() {
        return Err(Error::Invalid(format!(
            "{} models, but the held-out session timed {}",
            models.len(),
            session.latency_ms.len()
        )));
    }
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

/// Table III and Table V of `models` on `sources` into `report` ([`evaluate_models`]
/// then [`report_evaluation`]).
pub fn evaluate(
    device: &Device,
    report: &mut Report,
    models: &[NamedModel],
    sources: &DataSources,
    config: &RunConfig,
    held: &HeldOutConfig,
    reporter: &mut dyn Reporter,
) -> Result<()> {
    let evaluated = evaluate_models(device, models, sources, config, held, None, reporter)?;
    report_evaluation(report, models, evaluated, held, reporter)
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
    add_graph_mixing(report, models);
    Ok(())
}

/// The table of how much each model's graph convolution mixes the sensors, as a section
/// of `report` (none when no model has one).
pub(crate) fn add_graph_mixing(report: &mut Report, models: &[NamedModel]) {
    if let Some(table) = graph_mixing_table(models) {
        report
            .sections
            .push(("Graph convolution after training".into(), table));
    }
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
