//! `iastgcn simulate`: run the digital twin and write a recording (or a calibration
//! measurement set), with a progress bar and a PNG of the path and the error traces.

use std::path::PathBuf;

use anyhow::Context;
use indicatif::ProgressBar;

use crate::compensate::online::located;
use crate::data::{tracker_columns, write_calibration_set, CalibrationRow, Recording, Row};
use crate::plot::{self, Panel, Series};
use crate::robot::{Geometry, Robot};
use crate::twin::{
    calibration_configurations, draw_machine, measure_calibration, Machine, MachineState, Mirror,
    PathKind, PathParams, RunInfo, SensorSpecs, SimConfig, Simulation, CHANNELS,
};

#[derive(clap::Args)]
pub struct SimulateArgs {
    /// Path to polish (grid, fermat, hilbert, rosette) or `calibration` for static
    /// measurement poses.
    #[arg(long, value_parser = ["grid", "fermat", "hilbert", "rosette", "calibration"])]
    pub trajectory: String,
    /// Rotation of the pattern on the part, degrees.
    #[arg(long, default_value_t = 0.0)]
    pub rotation: f64,
    /// Walk the pattern from its other end.
    #[arg(long)]
    pub reverse: bool,
    /// Drive with this calibration's model (default: the nominal model, as an
    /// uncalibrated machine does).
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Length of a polishing run, minutes.
    #[arg(long, default_value_t = 5.0)]
    pub minutes: f64,
    /// Seed of the run (sensor noise, force, feed modulation, calibration poses).
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// Seed of the machine: its geometric errors and non-geometric sources (the twin's
    /// default machine is 1).
    #[arg(long, default_value_t = 1)]
    pub machine_seed: u64,
    /// Robot geometry asset (default: the embedded assets/robot.toml).
    #[arg(long)]
    pub robot: Option<PathBuf>,
    /// Number of measurement poses for `--trajectory calibration`.
    #[arg(long, default_value_t = 80)]
    pub poses: usize,
    /// Output CSV.
    #[arg(long)]
    pub out: PathBuf,
    /// PNG of the path and error traces (default: the output path with `.png`).
    #[arg(long)]
    pub plot: Option<PathBuf>,
}

fn progress(len: u64, what: &str) -> ProgressBar {
    super::progress_bar(
        len,
        &format!("{what} {{bar:40}} {{pos}}/{{len}} {{per_sec}} eta {{eta}}"),
    )
}

pub fn run(args: &SimulateArgs) -> anyhow::Result<()> {
    let geometry = match &args.robot {
        Some(p) => Geometry::load(p)?,
        None => Geometry::default_asset(),
    };
    let machine = draw_machine(geometry.clone(), args.machine_seed);
    let (controller, controller_name) = match &args.calibration {
        Some(p) => (
            Robot::new(geometry, crate::calibrate::file::load(p)?.errors),
            p.display().to_string(),
        ),
        None => (Robot::nominal(geometry), "nominal".to_string()),
    };
    if args.trajectory == "calibration" {
        return calibration(args, &machine, &controller);
    }
    let kind: PathKind = args.trajectory.parse().map_err(anyhow::Error::msg)?;
    if !args.minutes.is_finite() || args.minutes <= 0.0 {
        anyhow::bail!("--minutes must be positive, got {}", args.minutes);
    }
    let params = PathParams {
        rotation_deg: args.rotation,
        reverse: args.reverse,
        ..PathParams::default()
    };
    let mut info = RunInfo::polishing(kind, &params, args.minutes * 60.0, args.seed);
    info.machine_seed = args.machine_seed;
    info.controller = controller_name;
    record_run(
        &machine,
        &controller,
        info,
        machine.cold(),
        &args.out,
        args.plot.clone(),
    )?;
    Ok(())
}

/// Records the polishing run `info` describes on `machine` from `start` (the machine's
/// state from earlier runs of the session; `info.start` and the temperatures are filled
/// in from it), writes the CSV, its `.run.toml` sidecar and a PNG (`plot`, or the CSV's
/// path with `.png`), and returns the machine's state at the end.
pub fn record_run(
    machine: &Machine,
    controller: &Robot,
    mut info: RunInfo,
    start: MachineState,
    out: &std::path::Path,
    plot: Option<PathBuf>,
) -> anyhow::Result<MachineState> {
    let kind: PathKind = info.path.parse().map_err(anyhow::Error::msg)?;
    let params = PathParams {
        rotation_deg: info.rotation_deg,
        reverse: info.reverse,
        ..PathParams::default()
    };
    let mut config = SimConfig::new(kind, info.seconds, info.seed);
    config.path_params = params;
    info.start = if start.clock > 0.0 { "warm" } else { "cold" }.into();
    info.session_clock_s = start.clock;
    info.screw_rise_k = start.screw_rise();
    let steps = config.steps();
    let mut sim = Simulation::resume(machine, controller, Mirror::default(), config, start)?;
    let bar = progress(steps as u64, &format!("simulating {}", kind.name()));
    let mut rows = Vec::with_capacity(steps);
    let mut truth = Vec::with_capacity(steps);
    while let Some(sample) = sim.step() {
        let s = sample.with_context(|| format!("at t = {:.2} s", rows.len() as f64 * 0.02))?;
        let tracker = s.tracker.as_ref().map(tracker_columns);
        let h = s.hidden;
        // In the frame the part was located in (docs/twin.md "Scoring").
        let actual = located(machine, controller, &h.actual.pose);
        truth.push((
            s.t,
            (actual.translation.vector - h.commanded.translation.vector).norm(),
            (actual.rotation * h.commanded.rotation.inverse())
                .angle()
                .to_degrees(),
            [h.target.position.x, h.target.position.y],
        ));
        rows.push(Row {
            t: s.t,
            values: s.channels.to_vec(),
            tracker,
        });
        if rows.len() % 50 == 0 {
            bar.set_position(rows.len() as u64);
        }
    }
    bar.finish_and_clear();
    let end = sim.machine_state();
    let recording = Recording {
        channels: CHANNELS.iter().map(|c| c.to_string()).collect(),
        rows,
    };
    recording.write(out)?;
    info.write(out)
        .with_context(|| RunInfo::sidecar(out).display().to_string())?;
    let n = truth.len() as f64;
    let mean_pos = truth.iter().map(|t| t.1).sum::<f64>() / n;
    let mean_att = truth.iter().map(|t| t.2).sum::<f64>() / n;
    let tracked = recording
        .rows
        .iter()
        .filter(|r| r.tracker.is_some())
        .count();
    println!(
        "wrote {} ({} rows, {:.0} s, {} tracker samples; seed {}, {} start, controller {})",
        out.display(),
        recording.rows.len(),
        info.seconds,
        tracked,
        info.seed,
        info.start,
        info.controller
    );
    println!(
        "twin truth (not in the file): machine {} is off by {:.3} mm and {:.4} deg on average",
        info.machine_seed, mean_pos, mean_att
    );
    let plot_path = plot.unwrap_or_else(|| out.with_extension("png"));
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
        },
        Panel {
            title: "driving errors E1-E4".into(),
            x_label: "t (s)".into(),
            y_label: "µm".into(),
            series: (0..4)
                .map(|i| Series::new(CHANNELS[i], channel(i)))
                .collect(),
            equal_aspect: false,
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
        },
    ];
    plot::draw(&plot_path, &panels, 2, 2, (1400, 1000))?;
    println!("plot {}", plot_path.display());
    Ok(end)
}

fn calibration(
    args: &SimulateArgs,
    machine: &crate::twin::Machine,
    controller: &Robot,
) -> anyhow::Result<()> {
    let configs = calibration_configurations(controller, args.poses, args.seed);
    let bar = progress(configs.len() as u64, "measuring");
    let mut rows = Vec::with_capacity(configs.len());
    // One pose at a time so the bar moves; the machine state carries over between them.
    let measured = measure_calibration(
        machine,
        controller,
        &configs,
        &SensorSpecs::default(),
        10,
        args.seed,
    )?;
    for m in &measured {
        let j = &m.joints;
        rows.push(CalibrationRow {
            joints: [
                j.limbs[0],
                j.limbs[1],
                j.limbs[2],
                j.head[0].to_degrees(),
                j.head[1].to_degrees(),
            ],
            pose: tracker_columns(&m.measured),
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    write_calibration_set(&args.out, &rows)?;
    RunInfo {
        path: "calibration".into(),
        rotation_deg: 0.0,
        reverse: false,
        seconds: 0.0,
        seed: args.seed,
        machine_seed: args.machine_seed,
        controller: args
            .calibration
            .as_ref()
            .map_or("nominal".into(), |p| p.display().to_string()),
        start: "cold".into(),
        session_clock_s: 0.0,
        screw_rise_k: [0.0; 3],
    }
    .write(&args.out)
    .with_context(|| RunInfo::sidecar(&args.out).display().to_string())?;
    println!(
        "wrote {} ({} measurement poses, tracker averaged over 10 readings each)",
        args.out.display(),
        rows.len()
    );
    Ok(())
}
