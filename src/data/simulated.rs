//! Recordings made on the twin: a polishing run or a calibration measurement set
//! simulated and written in the formats of docs/twin.md "File formats", each with its
//! `.run.toml` sidecar, and a PNG of the run (path, driving errors, hidden true error).

use std::path::{Path, PathBuf};

use super::{calibration_set_csv, tracker_columns, CalibrationRow, Recording, Row};
use crate::atomic::Batch;
use crate::error::{Error, Result};
use crate::plot::{self, Panel, Series};
use crate::progress::Reporter;
use crate::robot::Robot;
use crate::twin::{
    calibration_configurations, located, measure_calibration, pose_error, Correction, Machine,
    MachineState, Mirror, PathKind, RunInfo, SensorSpecs, SimConfig, Simulation, CHANNELS,
};

/// What a recorded run left: the machine's state at its end (to carry the session on),
/// and a summary of the file.
#[derive(Clone, Debug)]
pub struct RecordedRun {
    /// The machine's state at the end of the run.
    pub end: MachineState,
    /// The run's provenance, as written to its `.run.toml` sidecar.
    pub info: RunInfo,
    /// Rows written (control ticks).
    pub rows: usize,
    /// Rows with a tracker measurement.
    pub tracker_samples: usize,
    /// The hidden truth, not in the file: mean distance of the true pad (in the frame the
    /// part was located in) from the pose the controller expected for its command, mm.
    pub mean_position_error_mm: f64,
    /// The hidden truth: mean angle between the true pad attitude and the expected one,
    /// deg.
    pub mean_attitude_error_deg: f64,
    /// The hidden truth against the path target, as Table V scores a run: the true pad's
    /// mean position error, µm, and tool-axis angle, mdeg (with a [`Corrector`], what the
    /// corrections left; without, about the expected-pose error above).
    pub mean_target_error: [f64; 2],
    /// The run's PNG.
    pub plot: PathBuf,
}

/// The longest run the twin records: one day (4.32 million control ticks, about a
/// gigabyte of rows in memory before they are written).
pub const MAX_RUN_SECONDS: f64 = 86_400.0;
/// The most poses of a calibration set.
pub const MAX_CALIBRATION_POSES: usize = 100_000;

/// Records the polishing run `info` describes on `machine` under `controller` from
/// `start` (the machine's state from earlier runs of the session; `info.start`, the
/// session clock and temperatures are filled in from it), and writes the CSV `out`, its
/// `.run.toml` sidecar and a PNG (`plot`, or `out` with `.png`).
pub fn record_run(
    machine: &Machine,
    controller: &Robot,
    info: RunInfo,
    start: MachineState,
    out: &Path,
    plot: Option<PathBuf>,
    reporter: &mut dyn Reporter,
) -> Result<RecordedRun> {
    record_corrected_run(machine, controller, info, start, out, plot, None, reporter)
}

/// What corrects a recorded run's commands: called every control tick with the tick's
/// index and the twin's channels, it returns a correction to apply from the next tick
/// (docs/usage.md "scale", `--closed-loop`: a model compensating while the data are taken).
pub type Corrector<'a> = &'a mut dyn FnMut(usize, &[Option<f64>]) -> Result<Option<Correction>>;

/// [`record_run`] with the controller's commands corrected by `correct` as the run goes
/// (the file, the labels and the sidecar as for any run: the labels are the tracker's
/// pose against the pose the corrected joint commands give).
#[allow(clippy::too_many_arguments)]
pub fn record_corrected_run(
    machine: &Machine,
    controller: &Robot,
    mut info: RunInfo,
    start: MachineState,
    out: &Path,
    plot: Option<PathBuf>,
    mut correct: Option<Corrector<'_>>,
    reporter: &mut dyn Reporter,
) -> Result<RecordedRun> {
    let kind: PathKind = info.path.parse().map_err(Error::Invalid)?;
    crate::error::ensure(info.seconds.is_finite() && info.seconds > 0.0, || {
        format!("a run must last a positive time, got {} s", info.seconds)
    })?;
    let tick = SimConfig::new(kind, 1.0, info.seed).dt;
    crate::error::ensure(
        info.seconds >= tick && info.seconds <= MAX_RUN_SECONDS,
        || {
            format!(
                "a run lasts from one control tick ({tick} s) to {} h, got {} s ({} min)",
                MAX_RUN_SECONDS / 3600.0,
                info.seconds,
                info.seconds / 60.0
            )
        },
    )?;
    crate::error::ensure(
        info.rotation_deg.is_finite() && info.rotation_deg.abs() <= 360.0,
        || {
            format!(
                "the path's rotation is -360 to 360 degrees, got {}",
                info.rotation_deg
            )
        },
    )?;
    for (name, value, range) in [
        ("feed", info.feed_mm_s, (1.0, 200.0)),
        ("polishing force", info.force_n, (0.0, 1000.0)),
    ] {
        crate::error::ensure(
            value.is_finite() && value > range.0 && value <= range.1,
            || {
                format!(
                    "the {name} is more than {} and at most {}, got {value}",
                    range.0, range.1
                )
            },
        )?;
    }
    let mut config = SimConfig::new(kind, info.seconds, info.seed);
    config.path_params = info.placement();
    config.feed = info.feed_mm_s;
    config.force_mean = info.force_n;
    info.start = if start.clock > 0.0 { "warm" } else { "cold" }.into();
    info.session_clock_s = start.clock;
    info.screw_rise_k = start.screw_rise();
    let steps = config.steps();
    let dt = config.dt;
    let mut sim = Simulation::resume(machine, controller, Mirror::default(), config, start)?;
    reporter.begin(&format!("simulating {}", kind.name()), steps as u64);
    let mut rows = Vec::with_capacity(steps);
    let mut truth = Vec::with_capacity(steps);
    let mut target_error = [0.0; 2];
    while let Some(sample) = sim.step() {
        let s = sample.map_err(|e| {
            Error::from(e).context(format!("at t = {:.2} s", rows.len() as f64 * dt))
        })?;
        let tracker = s.tracker.as_ref().map(tracker_columns);
        let h = s.hidden;
        // In the frame the part was located in (docs/twin.md "Scoring").
        let actual = located(machine, controller, &h.actual.pose);
        let (p, a) = pose_error(&h.target, &actual);
        target_error[0] += p;
        target_error[1] += a;
        truth.push((
            s.t,
            (actual.translation.vector - h.commanded.translation.vector).norm(),
            (actual.rotation * h.commanded.rotation.inverse())
                .angle()
                .to_degrees(),
            [h.target.position.x, h.target.position.y],
        ));
        if let Some(correct) = correct.as_mut() {
            if let Some(c) = correct(rows.len(), &s.channels)? {
                sim.set_correction(c);
            }
        }
        rows.push(Row {
            t: s.t,
            values: s.channels.to_vec(),
            tracker,
        });
        if rows.len().is_multiple_of(50) {
            reporter.update(rows.len() as u64, "");
        }
    }
    reporter.end();
    let end = sim.machine_state();
    let recording = Recording {
        channels: CHANNELS.iter().map(|c| c.to_string()).collect(),
        rows,
    };
    let plot_path = plot.unwrap_or_else(|| out.with_extension("png"));
    // The plot, the CSV and its sidecar replace older files together or not at all.
    let mut batch = Batch::new();
    batch.add_with(&plot_path, |tmp| plot_run(tmp, kind, &recording, &truth))?;
    batch
        .add(out, recording.to_csv().as_bytes())
        .map_err(|e| Error::io(out, e))?;
    stage_sidecar(&mut batch, &info, out)?;
    batch.commit().map_err(|e| Error::io(out, e))?;
    let n = truth.len().max(1) as f64;
    Ok(RecordedRun {
        end,
        tracker_samples: recording
            .rows
            .iter()
            .filter(|r| r.tracker.is_some())
            .count(),
        rows: recording.rows.len(),
        info,
        mean_position_error_mm: truth.iter().map(|t| t.1).sum::<f64>() / n,
        mean_attitude_error_deg: truth.iter().map(|t| t.2).sum::<f64>() / n,
        mean_target_error: target_error.map(|e| e / n),
        plot: plot_path,
    })
}

/// The run's PNG: the path over the mirror, the driving errors E1–E4, and the hidden true
/// pad position and attitude error. `truth` holds (t, position mm, attitude deg, target
/// x/y mm) per tick.
fn plot_run(
    path: &Path,
    kind: PathKind,
    recording: &Recording,
    truth: &[(f64, f64, f64, [f64; 2])],
) -> Result<()> {
    let channel = |i: usize| -> Vec<(f64, f64)> {
        recording
            .rows
            .iter()
            .filter_map(|r| r.values[i].map(|v| (r.t, v)))
            .collect()
    };
    let panels = [
        Panel {
            title: format!("{} path over the mirror", kind.name()),
            x_label: "x (mm)".into(),
            y_label: "y (mm)".into(),
            series: vec![Series::new(
                "target",
                truth.iter().map(|t| (t.3[0], t.3[1])).collect(),
            )],
            equal_aspect: true,
            log_x: false,
            integer_x: false,
        },
        Panel {
            title: "driving errors E1-E4".into(),
            x_label: "t (s)".into(),
            y_label: "µm".into(),
            series: (0..4)
                .map(|i| Series::new(CHANNELS[i], channel(i)))
                .collect(),
            equal_aspect: false,
            log_x: false,
            integer_x: false,
        },
        Panel {
            title: "true pad position error (hidden)".into(),
            x_label: "t (s)".into(),
            y_label: "µm".into(),
            series: vec![Series::new(
                "|Δp|",
                truth.iter().map(|t| (t.0, t.1 * 1e3)).collect(),
            )],
            equal_aspect: false,
            log_x: false,
            integer_x: false,
        },
        Panel {
            title: "true pad attitude error (hidden)".into(),
            x_label: "t (s)".into(),
            y_label: "mdeg".into(),
            series: vec![Series::new(
                "|Δθ|",
                truth.iter().map(|t| (t.0, t.2 * 1e3)).collect(),
            )],
            equal_aspect: false,
            log_x: false,
            integer_x: false,
        },
    ];
    Ok(plot::draw(path, &panels, 2, 2, (1400, 1000))?)
}

/// Measures `poses` static calibration poses (seeded by `info.seed`, the tracker
/// averaged over 10 readings each) on a cold `machine` under `controller`, and writes
/// the calibration set `out` with its sidecar. Returns the number of poses.
pub fn record_calibration_set(
    machine: &Machine,
    controller: &Robot,
    poses: usize,
    info: &RunInfo,
    out: &Path,
    reporter: &mut dyn Reporter,
) -> Result<usize> {
    crate::error::ensure(poses > 0 && poses <= MAX_CALIBRATION_POSES, || {
        format!("a calibration set has from 1 to {MAX_CALIBRATION_POSES} poses, got {poses}")
    })?;
    let configs = calibration_configurations(controller, poses, info.seed);
    reporter.begin("measuring", configs.len() as u64);
    let measured = measure_calibration(
        machine,
        controller,
        &configs,
        &SensorSpecs::default(),
        10,
        info.seed,
    )?;
    let rows: Vec<CalibrationRow> = measured
        .iter()
        .map(|m| {
            let j = &m.joints;
            CalibrationRow {
                joints: [
                    j.limbs[0],
                    j.limbs[1],
                    j.limbs[2],
                    j.head[0].to_degrees(),
                    j.head[1].to_degrees(),
                ],
                pose: tracker_columns(&m.measured),
            }
        })
        .collect();
    reporter.update(rows.len() as u64, "");
    reporter.end();
    let mut batch = Batch::new();
    batch
        .add(out, calibration_set_csv(&rows).as_bytes())
        .map_err(|e| Error::io(out, e))?;
    stage_sidecar(&mut batch, info, out)?;
    batch.commit().map_err(|e| Error::io(out, e))?;
    Ok(rows.len())
}

/// Stages the `.run.toml` sidecar of the recording `csv` in `batch`.
fn stage_sidecar(batch: &mut Batch, info: &RunInfo, csv: &Path) -> Result<()> {
    let sidecar = RunInfo::sidecar(csv);
    let text = info.to_toml().map_err(|e| Error::io(&sidecar, e))?;
    batch
        .add(&sidecar, text.as_bytes())
        .map_err(|e| Error::io(&sidecar, e))
}
