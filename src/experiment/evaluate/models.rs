//! The models a table scores: checkpoints by name ([`NamedModel`]), their predictors,
//! and what the control loop runs ([`LoopModel`]: one model, or a seed ensemble).

use crate::error::{Error, Result};
use crate::gpu::Device;
use crate::graph::Graph;
use crate::model::Backend;
use crate::model::{Checkpoint, ModelError, Predictor};
use crate::train::sibling;

/// Predictors for checkpoints on one device (B = 1, the online path).
pub fn predictors(
    device: &Device,
    models: &[(String, Checkpoint)],
) -> Result<Vec<LoopModel>, ModelError> {
    models
        .iter()
        .map(|(name, ck)| {
            Ok(LoopModel {
                name: name.clone(),
                members: vec![Predictor::on(device, ck, 1)?],
                graph: ck.graph.clone(),
            })
        })
        .collect()
}

/// An ensemble in the control loop, named `name`: the mean of the predictions of
/// `checkpoints` (the seeds of one model), which must read the same sensor graph.
pub fn ensemble(device: &Device, name: &str, checkpoints: &[Checkpoint]) -> Result<LoopModel> {
    let Some(first) = checkpoints.first() else {
        return Err(Error::Invalid(format!("ensemble {name}: no member")));
    };
    if let Some(other) = checkpoints
        .iter()
        .find(|c| c.graph.nodes != first.graph.nodes)
    {
        return Err(Error::Invalid(format!(
            "ensemble {name}: its members read different sensor graphs ([{}] and [{}])",
            first.graph.nodes.join(", "),
            other.graph.nodes.join(", ")
        )));
    }
    Ok(LoopModel {
        name: name.into(),
        members: checkpoints
            .iter()
            .map(|ck| Predictor::on(device, ck, 1))
            .collect::<Result<_, ModelError>>()?,
        graph: first.graph.clone(),
    })
}

/// A model in the control loop: its name, its forward pass (one predictor, or an
/// ensemble's members, whose predictions the controller averages), and the sensor graph
/// its checkpoints read (each model's own: two models may read different sensors).
pub struct LoopModel {
    /// The model's name in the tables.
    pub name: String,
    /// Its forward pass: one predictor, or an ensemble's members.
    pub members: Vec<Predictor>,
    /// The sensor channels it reads, in its node order.
    pub graph: Graph,
}

impl LoopModel {
    /// Whether every member predicts on the native CPU path (none on an adapter's queue,
    /// so that its runs may go on several threads).
    pub fn predicts_natively(&self) -> bool {
        self.members.iter().all(|p| p.backend() == Backend::Native)
    }

    /// Where it predicts: the native CPU forward on a CPU adapter, else the adapter.
    pub fn runs_on(&self, device: &Device) -> String {
        self.members
            .first()
            .map_or_else(|| "nowhere".into(), |p| runs_on(device, p))
    }

    /// The window length, ticks, of its first member (the oracle stands in for it).
    pub fn window(&self) -> usize {
        self.members.first().map_or(0, |p| p.config().window)
    }

    /// Ticks ahead its first member predicts (the oracle stands in for it).
    pub fn look_ahead(&self) -> usize {
        self.members.first().map_or(0, |p| p.config().look_ahead)
    }
}

/// A checkpoint with the name the tables give it, and its mean training time per epoch
/// (NaN when unknown).
#[derive(Clone, Debug)]
pub struct NamedModel {
    /// The model's name in the tables.
    pub name: String,
    /// Its weights, config, graph and normalisation.
    pub checkpoint: Checkpoint,
    /// Mean wall time of a training epoch, s (NaN when unknown).
    pub epoch_seconds: f64,
    /// Where it trained (`unknown` without a training log).
    pub trained_on: String,
}

impl NamedModel {
    /// The checkpoint at `path`, named by its file stem (an older demo's
    /// `<model>.seed<k>-refined` is `<model>.seed<k>`: [`crate::experiment::report::seeds::model_name`]); a
    /// `<stem>.log.csv` beside it gives its training time per epoch and where it trained.
    pub fn load(path: &std::path::Path) -> Result<NamedModel> {
        let name = path.file_stem().map_or("model".into(), |s| {
            crate::experiment::report::seeds::model_name(&s.to_string_lossy()).to_string()
        });
        let (epoch_seconds, trained_on) =
            read_training_log(&sibling(path, ".log.csv")).unwrap_or((f64::NAN, "unknown".into()));
        Ok(NamedModel {
            name,
            checkpoint: Checkpoint::load(path)?,
            epoch_seconds,
            trained_on,
        })
    }
}

/// The mean `seconds` of the core epochs in a training log (of every epoch when it has
/// no core stage, as a refined model's log) and where they ran (`train::log::trained_on`
/// of those epochs; `unknown` in logs written before that column), if the log exists
/// and has epochs.
pub(super) fn read_training_log(log: &std::path::Path) -> Option<(f64, String)> {
    let mut reader = csv::Reader::from_path(log).ok()?;
    let header = reader.headers().ok()?.clone();
    let column = |name: &str| header.iter().position(|h| h == name);
    let (stage, seconds, on) = (column("stage")?, column("seconds")?, column("trained_on"));
    let rows: Vec<csv::StringRecord> = reader.records().filter_map(|r| r.ok()).collect();
    let core: Vec<&csv::StringRecord> = rows
        .iter()
        .filter(|r| r.get(stage) == Some("core"))
        .collect();
    let picked = if core.is_empty() {
        rows.iter().collect()
    } else {
        core
    };
    let values: Vec<f64> = picked
        .iter()
        .filter_map(|r| r.get(seconds)?.parse().ok())
        .collect();
    if values.is_empty() {
        return None;
    }
    let trained_on = crate::train::log::trained_on(
        on.into_iter()
            .flat_map(|c| picked.iter().filter_map(move |r| r.get(c))),
    );
    Some((values.iter().sum::<f64>() / values.len() as f64, trained_on))
}

/// Where `predictor`'s predictions run: "native CPU forward", or the adapter's name.
pub fn runs_on(device: &Device, predictor: &Predictor) -> String {
    match predictor.backend() {
        Backend::Native => "native CPU forward".to_string(),
        Backend::Device => device.name(),
    }
}
