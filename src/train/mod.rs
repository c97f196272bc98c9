//! Training (docs/model.md "Loss", "Optimiser and schedule", "Refinement"): the run config,
//! Adam on the device, the stage loop with early stopping and the divergence guard,
//! resumable states, metrics, logs and plots; the morning minute's adaptation to a day.

pub mod adapt;
pub mod config;
pub mod engine;
pub mod error;
pub mod fit;
pub mod log;
pub mod metrics;
pub mod optimizer;
pub mod pollination;
pub mod predict;
pub mod refine;
pub mod state;
pub mod trainer;

pub use adapt::{adapt, AdaptConfig, Adapted, Method as Adaptation};
pub use config::{ConfigError, DataConfig, RefineConfig, RunConfig, TrainConfig};
pub use fit::{
    build_dataset, by_path, initial_parameters, recording_path, recording_stem, run_stage, sibling,
    test_metrics, train, TestMetrics, Trained,
};
pub use metrics::{accumulated_error, Metrics};
pub use optimizer::{learning_rate, Optimizer};
pub use pollination::{pollinate, Pollination, Searched};
pub use predict::{batch_error, predict_recordings, PredictOptions, RecordingPrediction, Subset};
pub use refine::{refine, refine_checkpoint, Refined};
pub use state::{StateError, TrainState};
pub use trainer::{
    consecutive_runs, ensembles, EpochRecord, Progress, Snapshot, Stage, TrainError, Trainer,
    EXPLOSION_FACTOR,
};

use crate::data;
use crate::graph::Graph;
use crate::model::{Checkpoint, ModelConfig, Normalization, Parameters};

/// The core stage of a run.
pub fn core_stage(config: &RunConfig) -> Stage {
    Stage {
        name: "core".into(),
        group: 1,
        lr0: config.train.lr,
        max_epochs: config.train.max_epochs,
        patience: config.train.patience,
    }
}

/// The refinement stages of a run, one per magnification, warm-started at lr0 · scale.
pub fn refine_stages(config: &RunConfig) -> Vec<Stage> {
    let r = &config.refine;
    r.magnifications
        .iter()
        .map(|&m| Stage {
            name: format!("refine-m{m}"),
            group: m,
            lr0: config.train.lr * r.lr_scale,
            max_epochs: r.max_epochs,
            patience: r.patience,
        })
        .collect()
}

/// The dataset's statistics in the checkpoint's form.
pub fn normalization(n: &data::Normalization) -> Normalization {
    Normalization {
        feature_mean: n.feature_mean.iter().map(|r| r.to_vec()).collect(),
        feature_std: n.feature_std.iter().map(|r| r.to_vec()).collect(),
        label_mean: n.label_mean.to_vec(),
        label_std: n.label_std.to_vec(),
    }
}

/// A checkpoint's statistics in the dataset's form (to standardise new recordings the
/// way the model was trained); refused unless the shapes are N×3 and 6.
pub fn data_normalization(n: &Normalization) -> crate::error::Result<data::Normalization> {
    let rows = |v: &[Vec<f64>]| -> Option<Vec<[f64; data::FEATURES]>> {
        v.iter().map(|r| r.as_slice().try_into().ok()).collect()
    };
    let fixed = || {
        Some(data::Normalization {
            feature_mean: rows(&n.feature_mean)?,
            feature_std: rows(&n.feature_std)?,
            label_mean: n.label_mean.as_slice().try_into().ok()?,
            label_std: n.label_std.as_slice().try_into().ok()?,
        })
    };
    fixed().ok_or_else(|| {
        crate::error::Error::Invalid(
            "the checkpoint's normalisation is not N×3 features and 6 labels".into(),
        )
    })
}

/// A checkpoint of `params` trained on a dataset with statistics `n`.
pub fn checkpoint(
    config: &ModelConfig,
    graph: &Graph,
    params: &Parameters,
    n: &data::Normalization,
) -> Checkpoint {
    Checkpoint {
        config: config.clone(),
        graph: graph.clone(),
        parameters: params.clone(),
        normalization: normalization(n),
    }
}

/// De-standardises ŷ rows (`[len, 6]`) into µm / mdeg.
pub fn to_physical(pred: &[f32], n: &data::Normalization) -> Vec<[f64; 6]> {
    pred.chunks(6)
        .map(|r| std::array::from_fn(|k| r[k] as f64 * n.label_std[k] + n.label_mean[k]))
        .collect()
}
