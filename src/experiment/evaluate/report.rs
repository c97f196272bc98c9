//! The report of `iastgcn evaluate`: Tables III and V for checkpoints on recordings.

use std::path::PathBuf;
use std::time::Instant;

use super::models::NamedModel;
use super::paper_tables::tables;
use super::HeldOutConfig;
use crate::data::DataSources;
use crate::error::{Error, Result};
use crate::experiment::report::{self, Report};
use crate::gpu::Device;
use crate::progress::Reporter;
use crate::train::RunConfig;

/// The report of `iastgcn evaluate`: Tables III and V for `models` on `sources`, written
/// into the folder `out`.
pub fn evaluation_report(
    device: Device,
    models: &[PathBuf],
    sources: &DataSources,
    config: &RunConfig,
    held_out: &HeldOutConfig,
    out: &std::path::Path,
    reporter: &mut dyn Reporter,
) -> Result<Report> {
    let began = Instant::now();
    let named = models
        .iter()
        .map(|p| NamedModel::load(p))
        .collect::<Result<Vec<_>>>()?;
    for (i, m) in named.iter().enumerate() {
        if let Some(j) = named[..i].iter().position(|o| o.name == m.name) {
            return Err(Error::Invalid(format!(
                "evaluate.models: {} and {} are both the model {}; give each model once (in a demo \
                 folder written before the naming of docs/usage.md \"Checkpoint names\", \
                 <model>.seed<k>.safetensors is the core stage of \
                 <model>.seed<k>-refined.safetensors)",
                models[j].display(),
                models[i].display(),
                m.name
            )));
        }
    }
    let list = |paths: &[PathBuf]| {
        paths
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut report = Report {
        title: "IASTGCN evaluation".into(),
        headline: None,
        adapter: device.name(),
        setup: vec![
            format!("models: {}", list(models)),
            format!("recordings: {}", list(&sources.recordings)),
            format!(
                "split: {}",
                if config.data.split == "random" {
                    "random (the paper's protocol: windows leak between splits)"
                } else {
                    "contiguous blocks per recording (leakage-free)"
                }
            ),
            format!(
                "held-out runs: {} min each, seed {}, prediction every {} ticks",
                held_out.minutes, held_out.seed, held_out.every
            ),
        ],
        ..Report::default()
    };
    tables(
        &device,
        &mut report,
        &named,
        sources,
        config,
        held_out,
        reporter,
    )?;
    report::finish(report, began, out, reporter)
}
