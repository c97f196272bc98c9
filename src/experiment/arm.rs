//! Residual models on a serial arm (docs/arms.md "Residual models"): each pose file is
//! cut into contiguous 70/20/10 % blocks in measurement order; the geometric calibration
//! is fitted on the training blocks only; IASTGCN and the comparison models learn the
//! calibrated residual from the training blocks (validation for early stopping); the
//! table scores the test blocks, which neither step saw: initial (nominal, registered),
//! calibrated, the training-mean residual, and the calibrated model plus each model's
//! predicted residual.

use std::path::Path;

use super::evaluate::predict_windows;
use super::protocol::{fit_model, ModelFiles};
use super::report::seeds::{split_name, Spread};
use crate::calibrate::arm::{
    arm_orientation_errors, arm_position_errors, calibrate_arm, ArmCalibration,
    ArmCalibrationConfig,
};
use crate::data::arm_dataset::{arm_dataset, prepare_arm};
use crate::data::arm_poses::{ArmPoses, ArmTargets};
use crate::data::{Dataset, SplitMode, WindowConfig};
use crate::error::{Error, Result};
use crate::gpu::Device;
use crate::model::{Checkpoint, Predictor, Variant};
use crate::progress::Reporter;
use crate::robot::arm::{next_approach, Arm, ArmPose};
use crate::stats::Summary;
use crate::train::fit::window_config;
use crate::train::RunConfig;
use nalgebra::{Point3, Vector3};

/// The embedded run config of the arm residual models (assets/arms/residual.toml).
pub const ARM_RUN_CONFIG: &str = include_str!("../../assets/arms/residual.toml");

/// The models an arm evaluation trains by default: IASTGCN, its Chebyshev ablation, the
/// instantaneous MLP and the three offline pose→error baselines (which read the arm's
/// joints, `ModelConfig::joint_inputs`).
pub const ARM_MODELS: [Variant; 6] = [
    Variant::Iastgcn,
    Variant::Chebyshev,
    Variant::Mlp,
    Variant::BklsAnn,
    Variant::AnnBfpa,
    Variant::Erc,
];

/// The default arm run config.
pub fn arm_run_config() -> RunConfig {
    // invariant: the embedded config is parsed in tests/arm.rs.
    RunConfig::parse(ARM_RUN_CONFIG, "assets/arms/residual.toml")
        .expect("the embedded arm run config is valid")
}

/// One row of the arm table: a model (or stage) and its position error at each test
/// pose, mm.
#[derive(Clone, Debug)]
pub struct ArmRow {
    /// `initial`, `calibrated`, `training mean` or a model's name.
    pub model: String,
    /// Position error at each test pose, mm.
    pub errors_mm: Vec<f64>,
    /// Orientation error at each test pose, mdeg; empty where the pose files have no
    /// orientation.
    pub orientation_mdeg: Vec<f64>,
}

/// What an arm evaluation found.
#[derive(Clone, Debug)]
pub struct ArmEvaluation {
    /// The geometric calibration (fitted on the training blocks).
    pub calibration: ArmCalibration,
    /// Poses of each split: train, validation, test (windows' last poses).
    pub split_poses: [usize; 3],
    /// The test poses: (file index, pose index), in table order.
    pub test_poses: Vec<(usize, usize)>,
    /// The table's rows.
    pub rows: Vec<ArmRow>,
    /// Each model's predicted residual (µm, mdeg) at each test pose.
    pub predictions: Vec<(String, Vec<[f64; 6]>)>,
    /// Each model's best validation loss and its epoch.
    pub validation: Vec<(String, f64, usize)>,
    /// Mean position error (µm) left on the validation windows: first `calibrated`
    /// (calibration alone, no residual), then each model's correction.
    pub validation_um: Vec<(String, f64)>,
    /// Each model's weights as evaluated.
    pub checkpoints: Vec<(String, Checkpoint)>,
}

impl ArmEvaluation {
    /// The model to use: the one leaving the least mean position error on the validation
    /// windows, if that is less than calibration alone leaves there; `None` when no model
    /// beats calibration alone on validation (then none should be used). Chosen on
    /// validation, never on test.
    pub fn recommended(&self) -> Option<&(String, Checkpoint)> {
        let (calibrated, _) = self.validation_um.split_first()?;
        let (model, um) = self
            .validation_by_model()
            .into_iter()
            .min_by(|a, b| a.1.total_cmp(&b.1))?;
        if um >= calibrated.1 {
            return None;
        }
        // The model's seed with the least error on validation.
        let best = self.validation_um[1..]
            .iter()
            .filter(|(label, _)| split_name(label).0 == model)
            .min_by(|a, b| a.1.total_cmp(&b.1))?;
        self.checkpoints.iter().find(|(n, _)| *n == best.0)
    }

    /// Each model's mean position error left on the validation windows (µm), averaged
    /// over its seeds, in training order.
    pub fn validation_by_model(&self) -> Vec<(String, f64)> {
        let mut out: Vec<(String, Vec<f64>)> = Vec::new();
        for (label, um) in self.validation_um.iter().skip(1) {
            let model = split_name(label).0;
            match out.iter_mut().find(|(m, _)| m == model) {
                Some((_, v)) => v.push(*um),
                None => out.push((model.to_string(), vec![*um])),
            }
        }
        out.into_iter()
            .map(|(m, v)| (m, v.iter().sum::<f64>() / v.len() as f64))
            .collect()
    }

    /// The report's sentence on which model to use, and why.
    pub fn recommendation(&self) -> String {
        let Some((calibrated, _)) = self.validation_um.split_first() else {
            return String::new();
        };
        let seeds = self.seeds();
        let each: Vec<String> = self
            .validation_by_model()
            .iter()
            .map(|(m, um)| format!("{m} {um:.1}"))
            .collect();
        let over = if seeds > 1 {
            format!(" (each model: mean over its {seeds} training seeds)")
        } else {
            String::new()
        };
        let head = format!(
            "Mean position error left on the validation windows (µm){over}: calibration \
             alone {:.1}; {}.",
            calibrated.1,
            each.join(", ")
        );
        match self.recommended() {
            Some((name, _)) => format!(
                "{head} Recommended: **{}**, the model that leaves the least error on \
                 validation and less than calibration alone (chosen on validation, not on \
                 the test poses){}.",
                split_name(name).0,
                if seeds > 1 {
                    format!("; its weights: `{name}`, its seed with the least error there")
                } else {
                    String::new()
                }
            ),
            None => format!(
                "{head} Recommended: **no residual model**: none leaves less error on \
                 validation than calibration alone, so use the calibrated description alone \
                 (the table still shows every model on the test poses)."
            ),
        }
    }

    /// Training seeds per learned model (1 when the labels carry none).
    pub fn seeds(&self) -> usize {
        let labels = || self.validation_um.iter().skip(1);
        let models = self.validation_by_model().len().max(1);
        labels().count().max(1) / models
    }

    /// Each row's name, number of test poses, summary in µm and, where the poses have
    /// orientation, in mdeg.
    fn summaries(&self) -> impl Iterator<Item = (&str, usize, Summary, Option<Summary>)> {
        self.rows.iter().filter_map(|r| {
            let um: Vec<f64> = r.errors_mm.iter().map(|e| e * 1e3).collect();
            let mdeg = Summary::of(&r.orientation_mdeg);
            Summary::of(&um).map(|s| (r.model.as_str(), um.len(), s, mdeg))
        })
    }

    /// Whether the table has orientation columns.
    fn oriented(&self) -> bool {
        self.rows.iter().any(|r| !r.orientation_mdeg.is_empty())
    }

    /// The table as Markdown: mean, SD and max position error (µm) on the test poses,
    /// and where the poses have orientation, mean and max orientation error (mdeg). A
    /// model trained with several seeds has one row: the mean over seeds of its mean
    /// error ± their SD, the mean of its SDs over the poses, and the largest error of any
    /// seed.
    pub fn markdown(&self) -> String {
        let seeds = self.seeds();
        let over = if seeds > 1 {
            format!(" (± SD over {seeds} seeds)")
        } else {
            String::new()
        };
        let oriented = self.oriented();
        let mut out = format!("| model | mean µm{over} | SD µm | max µm |");
        if oriented {
            out.push_str(&format!(" mean mdeg{over} | max mdeg |"));
        }
        out.push_str(if oriented {
            "\n|---|---|---|---|---|---|\n"
        } else {
            "\n|---|---|---|---|\n"
        });
        type Runs = Vec<(Summary, Option<Summary>)>;
        let mut groups: Vec<(&str, Runs)> = Vec::new();
        for (label, _, s, a) in self.summaries() {
            let model = split_name(label).0;
            match groups.iter_mut().find(|(m, _)| *m == model) {
                Some((_, v)) => v.push((s, a)),
                None => groups.push((model, vec![(s, a)])),
            }
        }
        let mean_cell = |means: &[f64]| {
            let spread = Spread::of(means);
            if means.len() > 1 {
                spread.text(1)
            } else {
                format!("{:.1}", spread.mean)
            }
        };
        for (model, runs) in groups {
            let means: Vec<f64> = runs.iter().map(|(s, _)| s.mean).collect();
            let sd = runs.iter().map(|(s, _)| s.sd).sum::<f64>() / runs.len() as f64;
            let max = runs.iter().map(|(s, _)| s.max).fold(f64::MIN, f64::max);
            out.push_str(&format!(
                "| {model} | {} | {sd:.1} | {max:.1} |",
                mean_cell(&means)
            ));
            if oriented {
                let angles: Vec<&Summary> = runs.iter().filter_map(|(_, a)| a.as_ref()).collect();
                if angles.is_empty() {
                    out.push_str(" – | – |");
                } else {
                    let means: Vec<f64> = angles.iter().map(|a| a.mean).collect();
                    let max = angles.iter().map(|a| a.max).fold(f64::MIN, f64::max);
                    out.push_str(&format!(" {} | {max:.1} |", mean_cell(&means)));
                }
            }
            out.push('\n');
        }
        out
    }

    /// The table as CSV (`model,seed,mean_um,sd_um,max_um,poses,mean_mdeg,max_mdeg`), one
    /// row per model and seed (`seed` empty for the stages without training, the
    /// orientation empty where the poses have none).
    pub fn csv(&self) -> String {
        let mut out = String::from("model,seed,mean_um,sd_um,max_um,poses,mean_mdeg,max_mdeg\n");
        for (label, n, s, a) in self.summaries() {
            let (model, seed) = split_name(label);
            let seed = seed.map_or(String::new(), |k| k.to_string());
            let angle = a.map_or(",".to_string(), |a| format!("{:.3},{:.3}", a.mean, a.max));
            out.push_str(&format!(
                "{model},{seed},{:.3},{:.3},{:.3},{n},{angle}\n",
                s.mean, s.sd, s.max
            ));
        }
        out
    }
}

/// Test poses below which `evaluate --robot` warns that its table rests on few poses.
pub const USEFUL_TEST_POSES: usize = 30;

/// The test windows (scored poses) of one pose file of `poses` poses under `window`:
/// windows ending at every pose, split into contiguous blocks as the dataset does.
pub fn test_windows(poses: usize, window: &crate::data::WindowConfig) -> usize {
    let ends: Vec<crate::data::Window> = crate::data::window_ends(poses, window, |_| true)
        .into_iter()
        .map(|end| crate::data::Window { recording: 0, end })
        .collect();
    crate::data::split(&ends, &[poses], window, SplitMode::Contiguous)
        .test
        .len()
}

/// Calibrates `nominal` on the training blocks of `files`, trains `variants` on the
/// calibrated residuals with `config`, once per training seed of `seeds` (checkpoints,
/// logs and plots into `out/models`, named `<model>.seed<k>` when there are several
/// seeds),
/// and scores the test blocks. With `tests` (separate pose files), `files` are cut into
/// 80/20 % training and validation blocks only, and every window of the test files is
/// scored instead: they serve nothing else (not the calibration, its registration, early
/// stopping or the choice of model), and are standardised with the training statistics.
/// `targets`, the points that [`corrected_targets`] will be asked for, are checked to be
/// reachable by the calibrated arm before any training.
#[allow(clippy::too_many_arguments)]
pub fn evaluate_arm(
    device: &Device,
    nominal: &Arm,
    files: &[(String, ArmPoses)],
    tests: &[(String, ArmPoses)],
    config: &RunConfig,
    variants: &[Variant],
    seeds: &[u64],
    targets: Option<&ArmTargets>,
    out: &Path,
    reporter: &mut dyn Reporter,
) -> Result<ArmEvaluation> {
    config.validate().map_err(Error::Invalid)?;
    super::protocol::check_seeds(seeds)?;
    if targets.is_some() && variants.is_empty() {
        return Err(Error::Invalid(
            "corrected targets need a model: the list of models to train is empty".into(),
        ));
    }
    if config.model.look_ahead > 0 {
        return Err(Error::Invalid(format!(
            "model.look_ahead = {}: a serial arm's poses are measured one at a time, with no \
             planned motion between them to look ahead along; look-ahead is for polishing runs",
            config.model.look_ahead
        )));
    }
    if config.data.split != "contiguous" {
        return Err(Error::Invalid(format!(
            "data.split = {:?}: arm evaluations split each pose file into contiguous blocks (a random split would put neighbours of test poses in training)",
            config.data.split
        )));
    }
    let mut window = window_config(config);
    // With test files, every window of theirs is a test window and the pose files have
    // no test block.
    let scored_window = WindowConfig {
        train: 0.0,
        validation: 0.0,
        ..window
    };
    if !tests.is_empty() {
        (window.train, window.validation) = (0.8, 0.2);
    }
    let (scored_files, scored_split) = if tests.is_empty() {
        (files, &window)
    } else {
        (tests, &scored_window)
    };
    // Too few poses for a test window fail here, before the calibration; a thin test
    // block is said before anything trains.
    let counts: Vec<usize> = scored_files
        .iter()
        .map(|(_, f)| test_windows(f.poses.len(), scored_split))
        .collect();
    let total: usize = counts.iter().sum();
    let needed = (1..1_000_000)
        .find(|&n| test_windows(n, scored_split) >= 1)
        .unwrap_or(usize::MAX);
    let useful = (1..1_000_000)
        .find(|&n| test_windows(n, scored_split) >= USEFUL_TEST_POSES)
        .unwrap_or(usize::MAX);
    if total == 0 {
        let sizes: Vec<String> = scored_files
            .iter()
            .map(|(name, f)| format!("{name}: {} poses", f.poses.len()))
            .collect();
        let block = if tests.is_empty() {
            "each pose file's last 10 % is its test block, where"
        } else {
            "in each test file"
        };
        return Err(Error::Invalid(format!(
            "no test window: {block} a window of T = {} poses must fit; a file needs at \
             least {needed} poses for one test pose ({useful} for {USEFUL_TEST_POSES}), and \
             the files have {} (docs/arms.md \"How many poses\")",
            window.length,
            sizes.join(", ")
        )));
    }
    if total < USEFUL_TEST_POSES {
        reporter.note(&format!(
            "warning: only {total} test poses: the table's means rest on few poses; a pose \
             file of {useful} poses gives {USEFUL_TEST_POSES} (docs/arms.md \"How many poses\")"
        ));
    }
    // The calibration sees the training blocks only, as the models do.
    let train_poses: Vec<ArmPose> = files
        .iter()
        .flat_map(|(_, f)| {
            let n = (window.train * f.poses.len() as f64).round() as usize;
            f.poses[..n.min(f.poses.len())].iter().cloned()
        })
        .collect();
    reporter.note(&format!(
        "== calibrating {} on the {} poses of the training blocks",
        nominal.spec.name,
        train_poses.len()
    ));
    let calibration = calibrate_arm(nominal, &train_poses, &ArmCalibrationConfig::default())?;
    reporter.note(&format!(
        "identified {} parameters; RMS {:.1} → {:.1} µm on the training poses",
        calibration.identified.len(),
        calibration.rms_before_mm * 1e3,
        calibration.rms_after_mm * 1e3
    ));
    if let Some(t) = targets {
        target_poses(&calibration.arm, t)?;
    }
    let (graph, data) = arm_dataset(
        &calibration.arm,
        files,
        &window,
        SplitMode::Contiguous,
        None,
        config.data.channel_time,
    )?;
    for line in data.summary().lines() {
        reporter.note(line);
    }
    // The scored windows: the test blocks, or every window of the test files under the
    // training statistics.
    let separate = if tests.is_empty() {
        None
    } else {
        let (_, t) = arm_dataset(
            &calibration.arm,
            tests,
            &scored_window,
            SplitMode::Contiguous,
            Some(&data.normalization),
            config.data.channel_time,
        )?;
        Some(t)
    };
    let scored = separate.as_ref().unwrap_or(&data);
    let [_, _, test] = scored.split_ranges();
    let positions: Vec<usize> = test.collect();
    if positions.is_empty() {
        return Err(Error::Invalid(
            "no test window: the pose files are too short for their test blocks".into(),
        ));
    }
    let test_poses: Vec<(usize, usize)> = positions
        .iter()
        .map(|&i| (scored.windows[i].recording, scored.windows[i].end))
        .collect();
    let measured: Vec<ArmPose> = test_poses
        .iter()
        .map(|&(f, p)| scored_files[f].1.poses[p].clone())
        .collect();
    // Position error left after subtracting a predicted residual (µm) from the label.
    let left = |predicted: &dyn Fn(usize) -> [f64; 6]| -> Vec<f64> {
        left_at(scored, &positions, predicted, position_left_um)
            .iter()
            .map(|um| um * 1e-3)
            .collect()
    };
    // Orientation error left (mdeg), where every test pose has an orientation.
    let oriented = measured.iter().all(|p| p.orientation.is_some());
    let angle_left = |predicted: &dyn Fn(usize) -> [f64; 6]| -> Vec<f64> {
        if oriented {
            left_at(scored, &positions, predicted, rotation_left_mdeg)
        } else {
            Vec::new()
        }
    };
    let mdeg = |v: Vec<f64>| v.iter().map(|e| e * 1e3).collect::<Vec<_>>();
    let mean = data.normalization.label_mean;
    let mut rows = vec![
        ArmRow {
            model: "initial".into(),
            errors_mm: arm_position_errors(&calibration.registered, &measured),
            orientation_mdeg: mdeg(arm_orientation_errors(&calibration.registered, &measured)),
        },
        ArmRow {
            model: "calibrated".into(),
            errors_mm: arm_position_errors(&calibration.arm, &measured),
            orientation_mdeg: mdeg(arm_orientation_errors(&calibration.arm, &measured)),
        },
        ArmRow {
            model: "training mean".into(),
            errors_mm: left(&|_| mean),
            orientation_mdeg: angle_left(&|_| mean),
        },
    ];
    let model_dir = out.join("models");
    std::fs::create_dir_all(&model_dir).map_err(|e| Error::io(&model_dir, e))?;
    let mut predictions = Vec::new();
    let mut validation = Vec::new();
    // Position error left on the validation windows, µm: calibration alone leaves the
    // label itself.
    let [_, val_range, _] = data.split_ranges();
    let val_positions: Vec<usize> = val_range.collect();
    let left_on_validation = |predicted: &dyn Fn(usize) -> [f64; 6]| -> f64 {
        let left = left_at(&data, &val_positions, predicted, position_left_um);
        left.iter().sum::<f64>() / left.len().max(1) as f64
    };
    let mut validation_um = vec![("calibrated".to_string(), left_on_validation(&|_| [0.0; 6]))];
    let mut checkpoints = Vec::new();
    for &variant in variants {
        for &seed in seeds {
            let mut c = config.clone();
            c.model.variant = variant;
            c.model.nodes = graph.len();
            c.train.seed = seed;
            // The offline baselines read the arm's joints (the graph's first nodes).
            c.model.joint_inputs = nominal.spec.joint.iter().map(|j| j.name.clone()).collect();
            let name = if seeds.len() > 1 {
                format!("{}.seed{seed}", variant.name())
            } else {
                variant.name().to_string()
            };
            reporter.note(&format!(
                "== {name} on the calibrated residuals (seed {seed})"
            ));
            let files = ModelFiles::named(&model_dir, &name, false);
            let fitted = fit_model(device, &data, &graph, &c, &name, &files, reporter)?;
            let predicted = predict_windows(device, &fitted.model.checkpoint, scored, &positions)?;
            rows.push(ArmRow {
                model: name.clone(),
                errors_mm: left(&|k| predicted[k]),
                orientation_mdeg: angle_left(&|k| predicted[k]),
            });
            validation.push((name.clone(), fitted.best_val, fitted.best_epoch));
            let on_validation =
                predict_windows(device, &fitted.model.checkpoint, &data, &val_positions)?;
            let um = left_on_validation(&|k| on_validation[k]);
            validation_um.push((name.clone(), um));
            predictions.push((name.clone(), predicted));
            checkpoints.push((name, fitted.model.checkpoint));
        }
    }
    let split_poses = [
        data.splits.train.len(),
        data.splits.validation.len(),
        positions.len(),
    ];
    Ok(ArmEvaluation {
        calibration,
        split_poses,
        test_poses,
        rows,
        predictions,
        validation,
        validation_um,
        checkpoints,
    })
}

/// What is left at each window of `data` at `positions` when the residual
/// `predicted(k)` (µm, mdeg) of the k-th is applied to its label, as `error` measures it
/// ([`position_left_um`], [`rotation_left_mdeg`]).
fn left_at(
    data: &Dataset,
    positions: &[usize],
    predicted: &dyn Fn(usize) -> [f64; 6],
    error: fn(&[f64; 6], &[f64; 6]) -> f64,
) -> Vec<f64> {
    positions
        .iter()
        .enumerate()
        .map(|(k, &i)| error(&data.labels[i], &predicted(k)))
        .collect()
}

/// The position error (µm) left when the predicted residual is subtracted from the
/// label.
fn position_left_um(label: &[f64; 6], predicted: &[f64; 6]) -> f64 {
    (0..3)
        .map(|a| (label[a] - predicted[a]).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// The orientation error (mdeg) left when a predicted residual's rotation is applied to
/// the calibrated model's: `label` and `predicted` carry rotation vectors (mdeg) in
/// their last three entries, as the labels do (`arm_residual`), and what is left is the
/// angle of exp(label)·exp(predicted)⁻¹.
pub fn rotation_left_mdeg(label: &[f64; 6], predicted: &[f64; 6]) -> f64 {
    let rotation = |v: &[f64]| {
        let rad = Vector3::new(v[0], v[1], v[2]).map(|a| (a * 1e-3).to_radians());
        nalgebra::UnitQuaternion::from_scaled_axis(rad)
    };
    let left = rotation(&label[3..6]) * rotation(&predicted[3..6]).inverse();
    left.angle().to_degrees() * 1e3
}

/// One desired tool point and the joint targets that reach it.
#[derive(Clone, Debug, PartialEq)]
pub struct CorrectedTarget {
    /// The target's stamp (pose number or time).
    pub stamp: f64,
    /// The desired tool point, mm (tracker frame).
    pub point: Point3<f64>,
    /// Joint values that reach it under the calibrated model alone.
    pub calibrated: Vec<f64>,
    /// The residual the model predicts there (µm, mdeg).
    pub residual: [f64; 6],
    /// Joint values that reach the point minus the predicted residual under the
    /// calibrated model: the compensated command.
    pub corrected: Vec<f64>,
}

/// The poses that put `calibrated`'s tool on each point of `targets`, in order: inverse
/// kinematics from the previous target's solution, the first from the middle of every
/// joint's range. An unreachable point is an error naming the file, the target and its
/// line.
fn target_poses(calibrated: &Arm, targets: &ArmTargets) -> Result<Vec<ArmPose>> {
    let mut seed = calibrated.at_shares(|_| 0.5);
    let mut poses: Vec<ArmPose> = Vec::with_capacity(targets.targets.len());
    for (k, (stamp, point, channels)) in targets.targets.iter().enumerate() {
        let unreachable = |e: String| {
            Error::Invalid(format!(
                "{}: target {} (line {}): {e}",
                targets.file,
                k + 1,
                k + 2
            ))
        };
        let mut q = calibrated
            .inverse_position(point, &seed)
            .map_err(unreachable)?;
        // Each joint comes from the previous target's value, as a pose file's order says
        // (the first target's approach is unknown: the middle of the play); with lost
        // motion, solve again for joints reached from that side.
        let approach = match poses.last() {
            Some(before) => next_approach(before, &q),
            None => vec![0.0; q.len()],
        };
        if calibrated.spec.lost_motion {
            q = calibrated
                .inverse_position_from(point, &q, &approach)
                .map_err(unreachable)?;
        }
        seed.clone_from(&q);
        poses.push(ArmPose {
            stamp: *stamp,
            joints: q,
            position: *point,
            orientation: None,
            channels: channels.clone(),
            reading_sd: None,
            approach,
        });
    }
    Ok(poses)
}

/// Corrected joint targets for `targets` in order: inverse kinematics of each point under
/// the calibrated model (from the previous target's solution, the first from the middle
/// of every joint's range), the residual `checkpoint` predicts over the window of the
/// targets so far (the first target's features stand in for the poses before it), and
/// inverse kinematics of the point minus that residual. `channel_time`: the
/// `data.channel_time` the checkpoint was trained with.
pub fn corrected_targets(
    device: &Device,
    checkpoint: &Checkpoint,
    calibrated: &Arm,
    targets: &ArmTargets,
    channel_time: bool,
) -> Result<Vec<CorrectedTarget>> {
    let poses = target_poses(calibrated, targets)?;
    let channels = poses.first().map_or(0, |p| p.channels.len());
    let file = ArmPoses {
        stamp: targets.stamp.clone(),
        oriented: false,
        channels: (0..channels).map(|c| format!("c{c}")).collect(),
        poses,
    };
    let features = prepare_arm(calibrated, &file, channel_time).features;
    let mut predictor = Predictor::on(device, checkpoint, 1)?;
    let step = |k: usize| -> Vec<f32> {
        features
            .iter()
            .flat_map(|node| node.iter().map(move |f| f[k] as f32))
            .collect()
    };
    for _ in 1..checkpoint.config.window {
        predictor.push_step(&step(0))?;
    }
    let mut out = Vec::with_capacity(file.poses.len());
    for (k, pose) in file.poses.iter().enumerate() {
        let residual = predictor
            .push(&step(k))?
            .ok_or_else(|| Error::Invalid("the predictor's window did not fill".into()))?;
        let shifted = pose.position - Vector3::new(residual[0], residual[1], residual[2]) * 1e-3;
        let corrected = calibrated
            .inverse_position_from(&shifted, &pose.joints, &pose.approach)
            .map_err(|e| {
                Error::Invalid(format!(
                    "{}: target {} (line {}), compensated: {e}",
                    targets.file,
                    k + 1,
                    k + 2
                ))
            })?;
        out.push(CorrectedTarget {
            stamp: pose.stamp,
            point: pose.position,
            calibrated: pose.joints.clone(),
            residual,
            corrected,
        });
    }
    Ok(out)
}

/// Joint targets for `targets` under the calibrated model alone (no residual model: what
/// [`ArmEvaluation::recommended`] advises when none beats calibration on validation), in
/// the shape of [`corrected_targets`]' with a zero residual.
pub fn calibrated_targets(calibrated: &Arm, targets: &ArmTargets) -> Result<Vec<CorrectedTarget>> {
    Ok(target_poses(calibrated, targets)?
        .into_iter()
        .map(|pose| CorrectedTarget {
            stamp: pose.stamp,
            point: pose.position,
            calibrated: pose.joints.clone(),
            residual: [0.0; 6],
            corrected: pose.joints,
        })
        .collect())
}

/// Corrected targets as CSV: `pose,x,y,z,q1…qn` (the corrected command),
/// `dx_um,dy_um,dz_um` (the predicted residual), `calibrated_q1…` (calibration only).
pub fn targets_csv(stamp: &str, targets: &[CorrectedTarget]) -> String {
    let n = targets.first().map_or(0, |t| t.corrected.len());
    let mut header = vec![stamp.to_string(), "x".into(), "y".into(), "z".into()];
    header.extend((1..=n).map(|i| format!("q{i}")));
    header.extend(["dx_um", "dy_um", "dz_um"].map(String::from));
    header.extend((1..=n).map(|i| format!("calibrated_q{i}")));
    let mut out = header.join(",") + "\n";
    for t in targets {
        let mut cells = vec![t.stamp.to_string()];
        cells.extend(t.point.coords.iter().map(f64::to_string));
        cells.extend(t.corrected.iter().map(f64::to_string));
        cells.extend(t.residual[..3].iter().map(f64::to_string));
        cells.extend(t.calibrated.iter().map(f64::to_string));
        out.push_str(&cells.join(","));
        out.push('\n');
    }
    out
}
