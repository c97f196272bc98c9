//! `iastgcn simulate`: run the digital twin and write a recording (or a calibration
//! measurement set), with a progress bar and a PNG of the path and the error traces.

use std::path::PathBuf;

use anyhow::Context;
use indicatif::ProgressBar;

use crate::data::{tracker_columns, write_calibration_set, CalibrationRow, Recording, Row};
use crate::plot::{self, Panel, Series};
use crate::robot::{Geometry, Robot};
use crate::twin::{
    calibration_configurations, draw_machine, measure_calibration, Mirror, PathKind, SensorNoise,
    SimConfig, Simulation, CHANNELS,
};

#[derive(clap::Args)]
pub struct SimulateArgs {
    /// Path to polish (grid, fermat, hilbert) or `calibration` for static measurement poses.
    #[arg(long, value_parser = ["grid", "fermat", "hilbert", "calibration"])]
    pub trajectory: String,
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
    // The controller drives with the nominal model: what an uncalibrated machine does.
    let controller = Robot::nominal(geometry);
    if args.trajectory == "calibration" {
        return calibration(args, &machine, &controller);
    }
    let kind: PathKind = args.trajectory.parse().map_err(anyhow::Error::msg)?;
    if !args.minutes.is_finite() || args.minutes <= 0.0 {
        anyhow::bail!("--minutes must be positive, got {}", args.minutes);
    }
    let config = SimConfig::new(kind, args.minutes * 60.0, args.seed);
    let steps = config.steps();
    let mut sim = Simulation::new(&machine, &controller, Mirror::default(), config)?;
    let bar = progress(steps as u64, &format!("simulating {}", kind.name()));
    let mut rows = Vec::with_capacity(steps);
    let mut truth = Vec::with_capacity(steps);
    while let Some(sample) = sim.step() {
        let s = sample.with_context(|| format!("at t = {:.2} s", rows.len() as f64 * 0.02))?;
        let tracker = s.tracker.as_ref().map(tracker_columns);
        let h = s.hidden;
        truth.push((
            s.t,
            (h.actual.pose.translation.vector - h.commanded.translation.vector).norm(),
            (h.actual.pose.rotation * h.commanded.rotation.inverse())
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
    let recording = Recording {
        channels: CHANNELS.iter().map(|c| c.to_string()).collect(),
        rows,
    };
    recording.write(&args.out)?;
    let n = truth.len() as f64;
    let mean_pos = truth.iter().map(|t| t.1).sum::<f64>() / n;
    let mean_att = truth.iter().map(|t| t.2).sum::<f64>() / n;
    let tracked = recording
        .rows
        .iter()
        .filter(|r| r.tracker.is_some())
        .count();
    println!(
        "wrote {} ({} rows, {:.0} s, {} tracker samples)",
        args.out.display(),
        recording.rows.len(),
        args.minutes * 60.0,
        tracked
    );
    println!(
        "twin truth (not in the file): machine {} is off by {:.3} mm and {:.4} deg on average",
        args.machine_seed, mean_pos, mean_att
    );
    let plot_path = args
        .plot
        .clone()
        .unwrap_or_else(|| args.out.with_extension("png"));
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
    Ok(())
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
        &SensorNoise::default(),
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
    println!(
        "wrote {} ({} measurement poses, tracker averaged over 10 readings each)",
        args.out.display(),
        rows.len()
    );
    Ok(())
}
