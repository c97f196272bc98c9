//! Checkpoints in safetensors (docs/model.md "Parameter names"): every parameter as an f32
//! tensor under its docs/model.md name, and as metadata (JSON strings) the format, the
//! variant, the config, the graph and the normalisation statistics. Written atomically;
//! loading checks names, shapes, dtypes, values and metadata and says what is wrong.

use std::collections::HashMap;
use std::path::Path;

use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use serde::{Deserialize, Serialize};

use super::config::ModelConfig;
use super::params::{check_parameter_count, param_specs, Parameters};
use crate::graph::Graph;

/// The value of the `format` metadata key.
pub const FORMAT: &str = "iastgcn-checkpoint/1";

/// Feature and label standardisation of the training split (docs/model.md "Features and
/// labels"): x' = (x − mean)/std per node and feature; ŷ is de-standardised as
/// ŷ·std + mean per output (µm, mdeg).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Normalization {
    /// Feature means, `[N][F]`.
    pub feature_mean: Vec<Vec<f64>>,
    /// Feature standard deviations, `[N][F]`.
    pub feature_std: Vec<Vec<f64>>,
    /// Label means, `[O]`: dx, dy, dz (µm), rx, ry, rz (mdeg).
    pub label_mean: Vec<f64>,
    /// Label standard deviations, `[O]`, µm and mdeg.
    pub label_std: Vec<f64>,
}

impl Normalization {
    /// No standardisation (mean 0, std 1), for freshly initialised models.
    pub fn identity(config: &ModelConfig) -> Normalization {
        Normalization {
            feature_mean: vec![vec![0.0; config.features]; config.nodes],
            feature_std: vec![vec![1.0; config.features]; config.nodes],
            label_mean: vec![0.0; config.outputs],
            label_std: vec![1.0; config.outputs],
        }
    }

    /// Checks the shapes against `config` and that every standard deviation is finite and
    /// positive; the message says which statistic is wrong.
    pub fn check(&self, config: &ModelConfig) -> Result<(), String> {
        let rows_ok = |v: &[Vec<f64>]| {
            v.len() == config.nodes && v.iter().all(|r| r.len() == config.features)
        };
        if !rows_ok(&self.feature_mean) || !rows_ok(&self.feature_std) {
            return Err(format!(
                "feature statistics must be [{}][{}]",
                config.nodes, config.features
            ));
        }
        if self.label_mean.len() != config.outputs || self.label_std.len() != config.outputs {
            return Err(format!(
                "label statistics must have {} values",
                config.outputs
            ));
        }
        let stds = self.feature_std.iter().flatten().chain(&self.label_std);
        if stds.clone().any(|s| !(s.is_finite() && *s > 0.0)) {
            return Err("standard deviations must be finite and positive".into());
        }
        Ok(())
    }
}

/// The graph as stored in the metadata.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct GraphMeta {
    nodes: Vec<String>,
    edges: Vec<(usize, usize)>,
}

/// A bad checkpoint: the file and what is wrong with it.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {message}")]
pub struct CheckpointError {
    /// The checkpoint's path (or the name given to [`Checkpoint::from_bytes`]).
    pub file: String,
    /// What is wrong, naming the tensor or metadata field.
    pub message: String,
}

impl crate::error::StageError for CheckpointError {}

/// Everything needed to run a trained network.
///
/// ```
/// use iastgcn::graph::Graph;
/// use iastgcn::model::{Checkpoint, ModelConfig, Normalization, Parameters, Variant};
///
/// let config = ModelConfig::gradient_check(Variant::Iastgcn);
/// let checkpoint = Checkpoint {
///     parameters: Parameters::init(&config, 1),
///     normalization: Normalization::identity(&config),
///     graph: Graph::default_asset(),
///     config,
/// };
/// let bytes = checkpoint.to_bytes()?;
/// assert_eq!(Checkpoint::from_bytes(&bytes, "in memory")?, checkpoint);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct Checkpoint {
    /// The network's shapes and variant.
    pub config: ModelConfig,
    /// The sensor graph it was trained on.
    pub graph: Graph,
    /// Its weights.
    pub parameters: Parameters,
    /// The statistics new inputs are standardised with and outputs de-standardised with.
    pub normalization: Normalization,
}

impl Checkpoint {
    /// The safetensors bytes.
    pub fn to_bytes(&self) -> Result<Vec<u8>, String> {
        let bytes: Vec<&[u8]> = self
            .parameters
            .values
            .iter()
            .map(|v| bytemuck::cast_slice::<f32, u8>(v))
            .collect();
        let views = self
            .parameters
            .specs
            .iter()
            .zip(&bytes)
            .map(|(s, b)| {
                TensorView::new(Dtype::F32, s.shape.clone(), b)
                    .map(|v| (s.name.clone(), v))
                    .map_err(|e| format!("tensor {}: {e}", s.name))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let graph = GraphMeta {
            nodes: self.graph.nodes.clone(),
            edges: self.graph.edges.clone(),
        };
        let metadata = HashMap::from([
            ("format".to_string(), FORMAT.to_string()),
            (
                "variant".to_string(),
                self.config.variant.name().to_string(),
            ),
            ("config".to_string(), json(&self.config)?),
            ("graph".to_string(), json(&graph)?),
            ("normalization".to_string(), json(&self.normalization)?),
        ]);
        safetensors::serialize(views, Some(metadata))
            .map(sorted_header)
            .map_err(|e| e.to_string())
    }

    /// Writes the checkpoint atomically (temporary file, then rename).
    pub fn save(&self, path: &Path) -> Result<(), CheckpointError> {
        let mut batch = crate::atomic::Batch::new();
        self.stage(&mut batch, path)?;
        batch.commit().map_err(|e| CheckpointError {
            file: path.display().to_string(),
            message: e.to_string(),
        })
    }

    /// Stages the checkpoint for `path` in `batch`, to replace it together with the
    /// batch's other files.
    pub fn stage(
        &self,
        batch: &mut crate::atomic::Batch,
        path: &Path,
    ) -> Result<(), CheckpointError> {
        let err = |message: String| CheckpointError {
            file: path.display().to_string(),
            message,
        };
        let bytes = self.to_bytes().map_err(err)?;
        batch.add(path, &bytes).map_err(|e| err(e.to_string()))
    }

    /// Reads and validates the checkpoint at `path` (docs/model.md "Parameter names" lists
    /// the checks).
    pub fn load(path: &Path) -> Result<Checkpoint, CheckpointError> {
        let bytes = std::fs::read(path).map_err(|e| CheckpointError {
            file: path.display().to_string(),
            message: e.to_string(),
        })?;
        Checkpoint::from_bytes(&bytes, &path.display().to_string())
    }

    /// Parses and validates safetensors bytes; `file` names the source in errors.
    pub fn from_bytes(bytes: &[u8], file: &str) -> Result<Checkpoint, CheckpointError> {
        let err = |message: String| CheckpointError {
            file: file.to_string(),
            message,
        };
        let (st, meta) = open_safetensors(bytes, "is this an iastgcn checkpoint?").map_err(err)?;
        meta.expect_format(FORMAT, &format!("this engine reads {FORMAT:?}"))
            .map_err(err)?;
        let config: ModelConfig = meta.json("config").map_err(err)?;
        config
            .validate()
            .and_then(|()| check_parameter_count(&config))
            .map_err(|e| err(format!("metadata \"config\": {e}")))?;
        let variant = meta.field("variant").map_err(err)?;
        if variant != config.variant.name() {
            return Err(err(format!(
                "metadata variant {variant:?} disagrees with the config's {:?}",
                config.variant.name()
            )));
        }
        let graph: GraphMeta = meta.json("graph").map_err(err)?;
        if graph.nodes.len() != config.nodes
            || graph
                .edges
                .iter()
                .any(|&(a, b)| a >= config.nodes || b >= config.nodes)
        {
            return Err(err(format!(
                "metadata \"graph\": {} nodes (config says {}) or an edge to a missing node",
                graph.nodes.len(),
                config.nodes
            )));
        }
        let normalization: Normalization = meta.json("normalization").map_err(err)?;
        normalization
            .check(&config)
            .map_err(|e| err(format!("metadata \"normalization\": {e}")))?;

        let specs = param_specs(&config);
        let mut values = Vec::with_capacity(specs.len());
        for s in &specs {
            let t = st.tensor(&s.name).map_err(|_| {
                err(format!(
                    "tensor {} (shape {:?}) is missing for the {} config",
                    s.name, s.shape, config.variant
                ))
            })?;
            if t.dtype() != Dtype::F32 {
                return Err(err(format!(
                    "tensor {}: dtype {:?}, expected F32",
                    s.name,
                    t.dtype()
                )));
            }
            if t.shape() != s.shape.as_slice() {
                return Err(err(format!(
                    "tensor {}: shape {:?}, expected {:?}",
                    s.name,
                    t.shape(),
                    s.shape
                )));
            }
            let v = f32_values(&t);
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                return Err(err(format!("tensor {}: element {i} is {}", s.name, v[i])));
            }
            values.push(v);
        }
        if let Some(extra) = st
            .names()
            .into_iter()
            .find(|n| !specs.iter().any(|s| s.name == *n))
        {
            return Err(err(format!(
                "unexpected tensor {extra} for the {} config",
                config.variant
            )));
        }
        Ok(Checkpoint {
            config,
            graph: Graph {
                nodes: graph.nodes,
                edges: graph.edges,
            },
            parameters: Parameters { specs, values },
            normalization,
        })
    }
}

/// Safetensors bytes with their JSON header's keys in sorted order. The `safetensors`
/// crate writes the metadata map in a `HashMap`'s order, which changes from process to
/// process; sorting makes a file the same bit for bit for the same contents (readers
/// locate tensors by their offsets, not by the header's order). The bytes come back
/// unchanged if the header cannot be read, which a freshly serialised one always can.
pub fn sorted_header(bytes: Vec<u8>) -> Vec<u8> {
    let Some(n) = bytes
        .get(..8)
        .and_then(|b| b.try_into().ok())
        .map(u64::from_le_bytes)
        .and_then(|n| usize::try_from(n).ok())
    else {
        return bytes;
    };
    let Some(header) = bytes.get(8..8 + n) else {
        return bytes;
    };
    type Sorted = std::collections::BTreeMap<String, serde_json::Value>;
    let Ok(mut top) = serde_json::from_slice::<Sorted>(header) else {
        return bytes;
    };
    if let Some(meta) = top.remove("__metadata__") {
        let Ok(meta) = serde_json::from_value::<Sorted>(meta) else {
            return bytes;
        };
        let Ok(meta) = serde_json::to_value(meta) else {
            return bytes;
        };
        top.insert("__metadata__".into(), meta);
    }
    let Ok(text) = serde_json::to_string(&top) else {
        return bytes;
    };
    if text.len() > n {
        return bytes;
    }
    let mut out = bytes;
    out[8..8 + n].fill(b' ');
    out[8..8 + text.len()].copy_from_slice(text.as_bytes());
    out
}

/// Parses safetensors bytes into its tensors and its metadata map; the message of a
/// failure says what is wrong (`hint` is added when there is no metadata).
pub fn open_safetensors<'b>(
    bytes: &'b [u8],
    hint: &str,
) -> Result<(SafeTensors<'b>, Metadata), String> {
    let header = header_entries(bytes);
    if let Some((_, entries)) = &header {
        let mut seen = std::collections::HashSet::new();
        if let Some((twice, _)) = entries.iter().find(|(k, _)| !seen.insert(k.as_str())) {
            return Err(format!(
                "not a valid safetensors file: {} appears twice in the header",
                if twice == "__metadata__" {
                    "__metadata__".to_string()
                } else {
                    format!("tensor {twice}")
                }
            ));
        }
    }
    let st = SafeTensors::deserialize(bytes).map_err(|e| {
        let tensor = header
            .as_ref()
            .and_then(|(n, entries)| bad_tensor(entries, bytes.len() - 8 - n));
        format!(
            "not a valid safetensors file: {}",
            tensor.unwrap_or_else(|| e.to_string())
        )
    })?;
    let (_, header) = SafeTensors::read_metadata(bytes)
        .map_err(|e| format!("not a valid safetensors file: {e}"))?;
    let meta = header
        .metadata()
        .clone()
        .ok_or_else(|| format!("no metadata ({hint})"))?;
    Ok((st, Metadata(meta)))
}

/// The header length and the header's entries (`name` → JSON value) in file order,
/// duplicates kept; `None` when the header cannot be read as a JSON object.
type HeaderEntries = (usize, Vec<(String, serde_json::Value)>);

fn header_entries(bytes: &[u8]) -> Option<HeaderEntries> {
    struct Entries;
    impl<'de> serde::de::Visitor<'de> for Entries {
        type Value = Vec<(String, serde_json::Value)>;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("a JSON object")
        }
        fn visit_map<A: serde::de::MapAccess<'de>>(
            self,
            mut map: A,
        ) -> Result<Self::Value, A::Error> {
            let mut out = Vec::new();
            while let Some(entry) = map.next_entry()? {
                out.push(entry);
            }
            Ok(out)
        }
    }
    let n = usize::try_from(u64::from_le_bytes(bytes.get(..8)?.try_into().ok()?)).ok()?;
    let header = bytes.get(8..8usize.checked_add(n)?)?;
    let mut de = serde_json::Deserializer::from_slice(header);
    let entries = serde::Deserializer::deserialize_map(&mut de, Entries).ok()?;
    Some((n, entries))
}

/// What is wrong with the first tensor (in data order) whose entry cannot be read, whose
/// shape and dtype disagree with its byte range, or whose range leaves a gap, overlaps or
/// runs past the `data_len` bytes after the header; `None` when every tensor is fine.
fn bad_tensor(entries: &[(String, serde_json::Value)], data_len: usize) -> Option<String> {
    let mut infos = Vec::new();
    for (name, value) in entries.iter().filter(|(k, _)| k != "__metadata__") {
        match serde_json::from_value::<safetensors::tensor::TensorInfo>(value.clone()) {
            Ok(info) => infos.push((name, info)),
            Err(e) => return Some(format!("tensor {name}: {e}")),
        }
    }
    infos.sort_by_key(|(_, info)| info.data_offsets);
    let mut start = 0;
    for (name, info) in &infos {
        let (s, e) = info.data_offsets;
        let bits = info
            .shape
            .iter()
            .try_fold(1usize, |a, &d| a.checked_mul(d))
            .and_then(|n| n.checked_mul(info.dtype.bitsize()));
        let Some(bits) = bits else {
            return Some(format!(
                "tensor {name}: shape {:?} overflows the size of a buffer",
                info.shape
            ));
        };
        if e < s || e - s != bits.div_ceil(8) {
            return Some(format!(
                "tensor {name}: shape {:?} of {:?} needs {} bytes, but its data_offsets \
                 [{s}, {e}] hold {}",
                info.shape,
                info.dtype,
                bits.div_ceil(8),
                e.saturating_sub(s)
            ));
        }
        if s != start {
            return Some(format!(
                "tensor {name}: data_offsets [{s}, {e}] {} the previous tensor's end {start}",
                if s > start {
                    "leave a gap after"
                } else {
                    "overlap"
                }
            ));
        }
        if e > data_len {
            return Some(format!(
                "tensor {name}: data_offsets [{s}, {e}] run past the end of the data \
                 ({data_len} bytes): the file looks truncated"
            ));
        }
        start = e;
    }
    None
}

/// A safetensors file's metadata, read with errors that name the field.
pub struct Metadata(HashMap<String, String>);

impl Metadata {
    /// The string value of `key`.
    pub fn field(&self, key: &str) -> Result<&str, String> {
        self.0
            .get(key)
            .map(String::as_str)
            .ok_or_else(|| format!("metadata has no \"{key}\""))
    }

    /// Field `key` parsed as JSON.
    pub fn json<T: serde::de::DeserializeOwned>(&self, key: &str) -> Result<T, String> {
        serde_json::from_str(self.field(key)?).map_err(|e| format!("metadata \"{key}\": {e}"))
    }

    /// Checks the `format` field; `otherwise` ends the message when it differs.
    pub fn expect_format(&self, expected: &str, otherwise: &str) -> Result<(), String> {
        let format = self.field("format")?;
        if format == expected {
            Ok(())
        } else {
            Err(format!("metadata format is {format:?}, {otherwise}"))
        }
    }
}

/// The values of an F32 safetensors tensor (stored little-endian).
pub fn f32_values(view: &TensorView) -> Vec<f32> {
    view.data()
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

fn json<T: Serialize>(value: &T) -> Result<String, String> {
    serde_json::to_string(value).map_err(|e| e.to_string())
}
