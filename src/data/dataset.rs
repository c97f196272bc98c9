//! Model-ready tensors from recordings and a calibration: features per node and step,
//! labels at window ends (eq. 19 under the calibrated model), normalisation statistics
//! from the training split only.

use super::features::{hold, node_features, FeatureConfig};
use super::recording::{tracker_pose, Recording};
use super::windows::{split, window_ends, SplitMode, Splits, Window, WindowConfig};
use crate::calibrate::residual;
use crate::graph::Graph;
use crate::robot::{Joints, PlatformPose, Robot};

/// Features per node and step (docs/model.md F).
pub const FEATURES: usize = 3;
/// Label components: dx, dy, dz (µm), rx, ry, rz (mdeg).
pub const OUTPUTS: usize = 6;
/// A recording that cannot be turned into a dataset (uneven clock, missing channel, no
/// labelled window, ...).
#[derive(Debug, thiserror::Error)]
#[error("{file}: {message}")]
pub struct DatasetError {
    /// The recording's name, or `dataset` when the problem is not one recording's.
    pub file: String,
    /// What is wrong, naming the line where it can.
    pub message: String,
}

impl crate::error::StageError for DatasetError {}

/// Mean and standard deviation per (node, feature) and per label component.
#[derive(Clone, Debug, PartialEq)]
pub struct Normalization {
    /// Feature means, `[N][F]` (r and D in the channel's unit, H dimensionless).
    pub feature_mean: Vec<[f64; FEATURES]>,
    /// Feature standard deviations (population), `[N][F]`.
    pub feature_std: Vec<[f64; FEATURES]>,
    /// Label means: dx, dy, dz (µm), rx, ry, rz (mdeg).
    pub label_mean: [f64; OUTPUTS],
    /// Label standard deviations (population), µm and mdeg.
    pub label_std: [f64; OUTPUTS],
}

/// Windows, their tensors and splits.
#[derive(Clone, Debug)]
pub struct Dataset {
    /// The graph's node names, in node order.
    pub nodes: Vec<String>,
    /// The recordings' names, indexed by [`Window::recording`].
    pub recordings: Vec<String>,
    /// Window length, stride and split fractions.
    pub window: WindowConfig,
    /// How windows were assigned to splits.
    pub mode: SplitMode,
    /// Every window in `splits` order: train, then validation, then test.
    pub windows: Vec<Window>,
    /// The same windows by split.
    pub splits: Splits,
    /// `[W, N, F, T]`, z-scored with the training statistics.
    pub x: Vec<f32>,
    /// `[W, 6]`, z-scored labels.
    pub y: Vec<f32>,
    /// `[W]` raw labels (µm, mdeg): the residual at each window's end, or `look_ahead`
    /// rows after it ([`WindowConfig::look_ahead`]).
    pub labels: Vec<[f64; OUTPUTS]>,
    /// `[W]` the tool axis (unit, base frame) at each label's row under the calibrated
    /// model: attitude errors are scored as the tilt of this axis (docs/twin.md "Scoring").
    pub axes: Vec<[f64; 3]>,
    /// The statistics `x` and `y` were standardised with.
    pub normalization: Normalization,
}

/// One recording turned into raw (not yet standardised) features and labels.
#[derive(Clone, Debug)]
pub struct Prepared {
    /// `[N][F][rows]`, in the graph's node order.
    pub features: Vec<[Vec<f64>; FEATURES]>,
    /// Per row: the residual (µm, mdeg) where the tracker measured, else `None`.
    pub labels: Vec<Option<[f64; OUTPUTS]>>,
    /// Per row: the tool axis (unit, base frame) under the model where the tracker
    /// measured, else `None`.
    pub axes: Vec<Option<[f64; 3]>>,
}

impl Prepared {
    /// The raw window `[N, F, T]` (row-major, f32) ending at row `end`.
    pub fn window(&self, end: usize, length: usize, out: &mut Vec<f32>) {
        out.clear();
        for node in &self.features {
            for f in node {
                out.extend(f[end + 1 - length..=end].iter().map(|&v| v as f32));
            }
        }
    }
}

fn err(file: &str, message: impl Into<String>) -> DatasetError {
    DatasetError {
        file: file.to_string(),
        message: message.into(),
    }
}

/// Checks the clock: rows must be evenly spaced (one control period); returns it.
fn control_period(name: &str, rec: &Recording) -> Result<f64, DatasetError> {
    if rec.rows.len() < 2 {
        return Err(err(name, "fewer than two rows"));
    }
    let dt = rec.rows[1].t - rec.rows[0].t;
    for (i, w) in rec.rows.windows(2).enumerate() {
        let step = w[1].t - w[0].t;
        if (step - dt).abs() > 0.25 * dt {
            // +2: the header is line 1 and rows count from 0.
            return Err(err(
                name,
                format!("line {}: a gap in time ({:.4} s after {:.4} s; the control period is {dt:.4} s)", i + 3, step, w[0].t),
            ));
        }
    }
    Ok(dt)
}

/// Features and labels of one recording (`name` labels errors): the hold, filter,
/// difference and entropy steps per graph node, and eq. 19 under `model` where the
/// tracker measured.
pub fn prepare(
    name: &str,
    rec: &Recording,
    graph: &Graph,
    model: &Robot,
    config: &FeatureConfig,
) -> Result<Prepared, DatasetError> {
    let dt = control_period(name, rec)?;
    let column = |c: &str| {
        rec.channels.iter().position(|x| x == c).ok_or_else(|| {
            err(
                name,
                format!("no column for {c:?} (needed by the graph asset or the labels)"),
            )
        })
    };
    let mut features = Vec::with_capacity(graph.len());
    for node in &graph.nodes {
        let c = column(node)?;
        let values: Vec<Option<f64>> = rec.rows.iter().map(|r| r.values[c]).collect();
        let held = hold(&values)
            .ok_or_else(|| err(name, format!("sensor {node:?} has no sample at all")))?;
        features.push(node_features(&held, dt, config));
    }
    let q: Vec<Vec<f64>> = crate::graph::HYBRID_JOINT_INPUTS
        .iter()
        .map(|c| {
            let col = column(c)?;
            hold(&rec.rows.iter().map(|r| r.values[col]).collect::<Vec<_>>())
                .ok_or_else(|| err(name, format!("sensor {c:?} has no sample at all")))
        })
        .collect::<Result<_, _>>()?;
    let mut guess: Option<PlatformPose> = None;
    let mut labels = Vec::with_capacity(rec.rows.len());
    let mut axes = Vec::with_capacity(rec.rows.len());
    for (i, row) in rec.rows.iter().enumerate() {
        let Some(p) = row.tracker else {
            labels.push(None);
            axes.push(None);
            continue;
        };
        let joints = Joints {
            limbs: [q[0][i], q[1][i], q[2][i]],
            head: [q[3][i].to_radians(), q[4][i].to_radians()],
        };
        let measured = tracker_pose(&p);
        let (label, platform) = residual(model, &joints, &measured, guess)
            .map_err(|e| err(name, format!("line {}: {e}", i + 2)))?;
        guess = Some(platform);
        labels.push(Some(label));
        let axis = model.tool_pose(&platform, &joints.head).rotation * nalgebra::Vector3::z();
        axes.push(Some([axis.x, axis.y, axis.z]));
    }
    Ok(Prepared {
        features,
        labels,
        axes,
    })
}

fn mean_std(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut n, mut s, mut s2) = (0.0, 0.0, 0.0);
    for v in values {
        n += 1.0;
        s += v;
        s2 += v * v;
    }
    if n == 0.0 {
        return (0.0, 1.0);
    }
    let mean = s / n;
    let sd = (s2 / n - mean * mean).max(0.0).sqrt();
    (mean, if sd > 1e-12 { sd } else { 1.0 })
}

impl Dataset {
    /// Builds the dataset from named recordings, the sensor graph and the calibrated model.
    pub fn build(
        recordings: &[(String, Recording)],
        graph: &Graph,
        model: &Robot,
        features: &FeatureConfig,
        window: &WindowConfig,
        mode: SplitMode,
    ) -> Result<Dataset, DatasetError> {
        Dataset::build_normalized(recordings, graph, model, features, window, mode, None)
    }

    /// [`Dataset::build`], standardising with `fixed` statistics (a trained model's) instead
    /// of the training split's when given.
    pub fn build_normalized(
        recordings: &[(String, Recording)],
        graph: &Graph,
        model: &Robot,
        features: &FeatureConfig,
        window: &WindowConfig,
        mode: SplitMode,
        fixed: Option<&Normalization>,
    ) -> Result<Dataset, DatasetError> {
        let prepared: Vec<(String, Prepared)> = recordings
            .iter()
            .map(|(name, rec)| Ok((name.clone(), prepare(name, rec, graph, model, features)?)))
            .collect::<Result<_, DatasetError>>()?;
        Dataset::from_prepared(&prepared, &graph.nodes, window, mode, fixed)
    }

    /// Windows, splits and standardised tensors of recordings already turned into
    /// features and labels (`prepared`, each with its name; rows are steps in time, or
    /// measured poses in their order), for a graph of `nodes`.
    pub fn from_prepared(
        prepared: &[(String, Prepared)],
        nodes: &[String],
        window: &WindowConfig,
        mode: SplitMode,
        fixed: Option<&Normalization>,
    ) -> Result<Dataset, DatasetError> {
        let mut all = Vec::new();
        for (r, (name, p)) in prepared.iter().enumerate() {
            let rows = p.labels.len();
            let ends = window_ends(rows, window, |e| p.labels[e].is_some());
            if ends.is_empty() {
                return Err(err(
                    name,
                    format!(
                        "{rows} rows give no labelled window of {} steps",
                        window.length
                    ),
                ));
            }
            all.extend(ends.into_iter().map(|end| Window { recording: r, end }));
        }
        let rows: Vec<usize> = prepared.iter().map(|(_, p)| p.labels.len()).collect();
        let splits = split(&all, &rows, window, mode);
        // Without given statistics the training windows provide them; with them, a
        // dataset of test windows only is fine (a separate test file).
        if splits.train.is_empty() && fixed.is_none() {
            return Err(err(
                "dataset",
                "no training window: the recordings are too short",
            ));
        }
        // Statistics over the steps of training windows only (each step once).
        let n_nodes = nodes.len();
        let mut in_train: Vec<Vec<bool>> = rows.iter().map(|&n| vec![false; n]).collect();
        for w in &splits.train {
            in_train[w.recording][w.end + 1 - window.length..=w.end].fill(true);
        }
        let mut feature_mean = vec![[0.0; FEATURES]; n_nodes];
        let mut feature_std = vec![[1.0; FEATURES]; n_nodes];
        for n in 0..n_nodes {
            for f in 0..FEATURES {
                let values = prepared.iter().enumerate().flat_map(|(r, (_, p))| {
                    let mask = &in_train[r];
                    p.features[n][f]
                        .iter()
                        .enumerate()
                        .filter(move |(t, _)| mask[*t])
                        .map(|(_, v)| *v)
                });
                (feature_mean[n][f], feature_std[n][f]) = mean_std(values);
            }
        }
        // invariant: windows are only made where their label row is labelled (windows.rs).
        let label_of = |w: &Window| {
            prepared[w.recording].1.labels[window.label_row(w.end)]
                .expect("windows have labelled rows")
        };
        let mut label_mean = [0.0; OUTPUTS];
        let mut label_std = [1.0; OUTPUTS];
        for k in 0..OUTPUTS {
            (label_mean[k], label_std[k]) = mean_std(splits.train.iter().map(|w| label_of(w)[k]));
        }
        if let Some(n) = fixed {
            if n.feature_mean.len() != n_nodes {
                return Err(err(
                    "dataset",
                    format!(
                        "the given statistics cover {} nodes, the graph has {n_nodes}",
                        n.feature_mean.len()
                    ),
                ));
            }
            feature_mean.clone_from(&n.feature_mean);
            feature_std.clone_from(&n.feature_std);
            label_mean = n.label_mean;
            label_std = n.label_std;
        }
        let windows: Vec<Window> = splits
            .train
            .iter()
            .chain(&splits.validation)
            .chain(&splits.test)
            .copied()
            .collect();
        let t_len = window.length;
        let mut x = Vec::with_capacity(windows.len() * n_nodes * FEATURES * t_len);
        let mut y = Vec::with_capacity(windows.len() * OUTPUTS);
        let mut labels = Vec::with_capacity(windows.len());
        let mut axes = Vec::with_capacity(windows.len());
        for w in &windows {
            let p = &prepared[w.recording].1;
            let start = w.end + 1 - t_len;
            for n in 0..n_nodes {
                for f in 0..FEATURES {
                    let (m, s) = (feature_mean[n][f], feature_std[n][f]);
                    x.extend(
                        p.features[n][f][start..=w.end]
                            .iter()
                            .map(|v| ((v - m) / s) as f32),
                    );
                }
            }
            let l = label_of(w);
            y.extend((0..OUTPUTS).map(|k| ((l[k] - label_mean[k]) / label_std[k]) as f32));
            labels.push(l);
            // invariant: windows are only made where their label row is labelled (windows.rs).
            axes.push(p.axes[window.label_row(w.end)].expect("windows have labelled rows"));
        }
        Ok(Dataset {
            nodes: nodes.to_vec(),
            recordings: prepared.iter().map(|(n, _)| n.clone()).collect(),
            window: *window,
            mode,
            windows,
            splits,
            x,
            y,
            labels,
            axes,
            normalization: Normalization {
                feature_mean,
                feature_std,
                label_mean,
                label_std,
            },
        })
    }

    /// Positions (in `windows`) of the training, validation and test windows.
    pub fn split_ranges(&self) -> [std::ops::Range<usize>; 3] {
        let a = self.splits.train.len();
        let b = a + self.splits.validation.len();
        [0..a, a..b, b..self.windows.len()]
    }

    /// Mini-batches of `batch` window positions from `range`, shuffled with `seed` (the
    /// same seed gives the same batches; the last batch may be short).
    pub fn batches(
        &self,
        range: std::ops::Range<usize>,
        batch: usize,
        seed: u64,
    ) -> Vec<Vec<usize>> {
        use rand::seq::SliceRandom;
        use rand::SeedableRng;
        let mut order: Vec<usize> = range.collect();
        order.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(seed));
        order.chunks(batch.max(1)).map(<[usize]>::to_vec).collect()
    }

    /// The windows at `positions` as contiguous buffers ready for upload:
    /// `x` `[B, N, F, T]` and `y` `[B, 6]`.
    pub fn gather(&self, positions: &[usize]) -> (Vec<f32>, Vec<f32>) {
        let (mut x, mut y) = (Vec::new(), Vec::new());
        self.gather_into(positions, &mut x, &mut y);
        (x, y)
    }

    /// [`Dataset::gather`] into buffers that are cleared first (no allocation once they
    /// have grown to a batch).
    pub fn gather_into(&self, positions: &[usize], x: &mut Vec<f32>, y: &mut Vec<f32>) {
        let len = self.window_len();
        x.clear();
        y.clear();
        for &p in positions {
            x.extend_from_slice(&self.x[p * len..(p + 1) * len]);
            y.extend_from_slice(&self.y[p * OUTPUTS..(p + 1) * OUTPUTS]);
        }
    }

    /// Elements of one window in `x`: N·F·T.
    pub fn window_len(&self) -> usize {
        self.nodes.len() * FEATURES * self.window.length
    }

    /// A printable summary: windows per split and recording, label statistics.
    pub fn summary(&self) -> String {
        let mut s = format!(
            "{} windows of {} steps (stride {}), split: {}\n",
            self.windows.len(),
            self.window.length,
            self.window.stride,
            self.mode.describe()
        );
        s += &format!(
            "  train {}, validation {}, test {}\n",
            self.splits.train.len(),
            self.splits.validation.len(),
            self.splits.test.len()
        );
        for (r, name) in self.recordings.iter().enumerate() {
            let count = |ws: &[Window]| ws.iter().filter(|w| w.recording == r).count();
            s += &format!(
                "  {name}: train {}, validation {}, test {}\n",
                count(&self.splits.train),
                count(&self.splits.validation),
                count(&self.splits.test)
            );
        }
        let n = &self.normalization;
        let names = ["dx µm", "dy µm", "dz µm", "rx mdeg", "ry mdeg", "rz mdeg"];
        // Position-only data (a serial arm without a 6-DoF probe) has no attitude label:
        // every one is exactly 0, and its statistics would be made up.
        let attitude = !self.labels.iter().all(|l| l[3..].iter().all(|&v| v == 0.0));
        let shown = if attitude { OUTPUTS } else { 3 };
        s += "  labels (training mean ± SD):";
        for ((name, mean), sd) in names.iter().zip(n.label_mean).zip(n.label_std).take(shown) {
            s += &format!(" {name} {mean:.1}±{sd:.1};");
        }
        if !attitude {
            s += " no attitude labels (position-only data);";
        }
        s.push('\n');
        s
    }
}
