//! Resumable training state: the current and best parameters, the Adam moments, the
//! stage and its progress (epoch, step, early-stopping counters, history), and the run
//! config and normalisation it belongs to. One safetensors file, written atomically at
//! the end of every epoch.

use std::collections::HashMap;
use std::path::Path;

use safetensors::tensor::{Dtype, TensorView};

use super::config::RunConfig;
use super::trainer::{Progress, Snapshot, Stage};
use crate::model::checkpoint::{f32_values, open_safetensors};
use crate::model::{param_specs, Normalization, Parameters};

/// The value of the `format` metadata key.
pub const FORMAT: &str = "iastgcn-train-state/1";

/// A state file that cannot be used; the message names the file and what is wrong.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {message}")]
pub struct StateError {
    /// The state file's path.
    pub file: String,
    /// What is wrong, naming the tensor or metadata field.
    pub message: String,
}

impl crate::error::StageError for StateError {}

/// A snapshot with the run it belongs to.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainState {
    /// The whole run config (a resumed run must match it).
    pub run: RunConfig,
    /// The dataset's standardisation statistics.
    pub normalization: Normalization,
    /// The trainer's state at the end of the last finished epoch.
    pub snapshot: Snapshot,
}

const GROUPS: [&str; 4] = ["param", "best", "adam.m", "adam.v"];

impl TrainState {
    /// Writes the state atomically as safetensors (docs/twin.md "Checkpoints and training
    /// states" has the layout).
    pub fn save(&self, path: &Path) -> Result<(), StateError> {
        let bytes = self.to_bytes(path)?;
        crate::atomic::write(path, &bytes).map_err(|e| StateError {
            file: path.display().to_string(),
            message: e.to_string(),
        })
    }

    /// The state as safetensors bytes (what [`TrainState::save`] writes); errors name
    /// `path`.
    pub fn to_bytes(&self, path: &Path) -> Result<Vec<u8>, StateError> {
        let err = |message: String| StateError {
            file: path.display().to_string(),
            message,
        };
        let s = &self.snapshot;
        let specs = &s.params.specs;
        let sets: [&Vec<Vec<f32>>; 4] = [&s.params.values, &s.best.values, &s.adam_m, &s.adam_v];
        let mut views = Vec::new();
        for (group, values) in GROUPS.iter().zip(sets) {
            for (spec, v) in specs.iter().zip(values) {
                let view = TensorView::new(Dtype::F32, spec.shape.clone(), bytemuck::cast_slice(v))
                    .map_err(|e| err(format!("tensor {group}.{}: {e}", spec.name)))?;
                views.push((format!("{group}.{}", spec.name), view));
            }
        }
        let json = |v: &dyn erased::Json| v.json().map_err(|e| err(e.to_string()));
        let metadata = HashMap::from([
            ("format".to_string(), FORMAT.to_string()),
            ("run".to_string(), json(&self.run)?),
            ("normalization".to_string(), json(&self.normalization)?),
            ("stage".to_string(), json(&s.stage)?),
            ("progress".to_string(), json(&s.progress)?),
        ]);
        safetensors::serialize(views, Some(metadata))
            .map(crate::model::checkpoint::sorted_header)
            .map_err(|e| err(e.to_string()))
    }

    /// Reads and checks a state written by [`TrainState::save`].
    pub fn load(path: &Path) -> Result<TrainState, StateError> {
        let file = path.display().to_string();
        let err = |message: String| StateError {
            file: file.clone(),
            message,
        };
        let bytes = std::fs::read(path).map_err(|e| err(e.to_string()))?;
        let (st, meta) = open_safetensors(&bytes, "is this a training state?").map_err(&err)?;
        let otherwise = format!("expected {FORMAT:?} (a model checkpoint is not a training state)");
        meta.expect_format(FORMAT, &otherwise).map_err(&err)?;
        let run: RunConfig = meta.json("run").map_err(&err)?;
        run.validate()
            .map_err(|e| err(format!("metadata \"run\": {e}")))?;
        let normalization: Normalization = meta.json("normalization").map_err(&err)?;
        normalization
            .check(&run.model)
            .map_err(|e| err(format!("metadata \"normalization\": {e}")))?;
        let stage: Stage = meta.json("stage").map_err(&err)?;
        if stage.group == 0 || !(stage.lr0.is_finite() && stage.lr0 > 0.0) {
            return Err(err(format!(
                "metadata \"stage\": group = {}, lr0 = {}: the group must be positive and \
                 lr0 a finite positive number",
                stage.group, stage.lr0
            )));
        }
        let progress: Progress = meta.json("progress").map_err(&err)?;
        let specs = param_specs(&run.model);
        let mut sets: Vec<Vec<Vec<f32>>> = Vec::new();
        for group in GROUPS {
            let mut values = Vec::new();
            for spec in &specs {
                let name = format!("{group}.{}", spec.name);
                let t = st
                    .tensor(&name)
                    .map_err(|_| err(format!("tensor {name} is missing")))?;
                if t.dtype() != Dtype::F32 || t.shape() != spec.shape.as_slice() {
                    return Err(err(format!(
                        "tensor {name}: {:?} {:?}, expected F32 {:?}",
                        t.dtype(),
                        t.shape(),
                        spec.shape
                    )));
                }
                let v = f32_values(&t);
                if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                    return Err(err(format!("tensor {name}: element {i} is {}", v[i])));
                }
                values.push(v);
            }
            sets.push(values);
        }
        let expected = GROUPS.len() * specs.len();
        let known = |n: &str| {
            GROUPS.iter().any(|g| {
                n.strip_prefix(g)
                    .and_then(|rest| rest.strip_prefix('.'))
                    .is_some_and(|rest| specs.iter().any(|s| s.name == rest))
            })
        };
        if let Some(extra) = st.names().into_iter().find(|n| !known(n)) {
            return Err(err(format!(
                "unexpected tensor {extra} for the {} config",
                run.model.variant
            )));
        }
        if st.len() != expected {
            return Err(err(format!(
                "{} tensors, expected {expected} for the {} config",
                st.len(),
                run.model.variant
            )));
        }
        let [params, best, adam_m, adam_v]: [Vec<Vec<f32>>; 4] =
            // invariant: the loop above pushes one set per entry of GROUPS (4).
            sets.try_into().expect("one set per group");
        Ok(TrainState {
            snapshot: Snapshot {
                stage,
                progress,
                params: Parameters {
                    specs: specs.clone(),
                    values: params,
                },
                best: Parameters {
                    specs,
                    values: best,
                },
                adam_m,
                adam_v,
            },
            run,
            normalization,
        })
    }
}

mod erased {
    /// JSON text of any serialisable value (for the metadata map).
    pub trait Json {
        fn json(&self) -> serde_json::Result<String>;
    }

    impl<T: serde::Serialize> Json for T {
        fn json(&self) -> serde_json::Result<String> {
            serde_json::to_string(self)
        }
    }
}
