//! The demo's own parts of its report: the setup lines, the sensor table, the first
//! seed's partial result and the mirror's section (Table VI).

use std::time::Instant;

use super::{demo_sweep, DemoConfig};
use crate::calibrate::file;
use crate::compensate::held_out::IDLE_BETWEEN_RUNS;
use crate::data::DataSources;
use crate::error::{Error, Result};
use crate::experiment::evaluate::{predictors, Evaluated, NamedModel};
use crate::experiment::polish::{self, PolishSpec};
use crate::experiment::polish_sweep;
use crate::experiment::protocol::{CALIBRATION_SEED, MACHINE_SEED, OPEN_LOOP_DATA, TRAINING_SEED};
use crate::experiment::recipe::NamedRecipe;
use crate::experiment::recommend::recommend;
use crate::experiment::report::TableVRow;
use crate::gpu::Device;
use crate::polish::{Polisher, Setup};
use crate::progress::Reporter;
use crate::robot::{Geometry, Robot};
use crate::twin::{draw_machine, PathKind};

/// The report's table of what each channel's instrument is (docs/twin.md "Sensors" has
/// the figures and their sources).
pub(super) fn sensor_table() -> String {
    let s = crate::twin::SensorSpecs::default();
    let mut out = String::from(
        "Every channel is the instrument a real machine would carry, with its own span, \
         resolution, lag and drift; none is a term of the truth model plus white noise \
         (docs/twin.md \"Sensors\").\n\n| Channel | Instrument |\n|---|---|\n",
    );
    for (name, what) in crate::twin::CHANNEL_UNITS {
        out.push_str(&format!("| {name} | {what} |\n"));
    }
    out.push_str(&format!(
        "\nScales: pitch error ±{} µm over {} mm, glass {} ppm/K, noise {} µm. Load encoders: \
         {:.3} mdeg quantum, ±{} mdeg eccentricity. Inclinometer: {} s lag, {} mdeg noise, \
         {} mdeg/K, bias walk {} mdeg/√s, mounting offset σ {} mdeg. Gyro: angle random walk \
         {:.3} °/√h, bias σ {:.3} °/h. Force from pressure: seal friction σ {} N, lag {} s. \
         Tracker: {} µm, {:.1} mdeg per axis.\n",
        s.scale_pitch_error,
        s.scale_pitch_wavelength,
        s.scale_expansion * 1e6,
        s.scale_noise,
        s.load_encoder_quantum,
        s.load_encoder_eccentricity,
        s.tilt_lag,
        s.tilt_noise,
        s.tilt_tempco,
        s.tilt_bias_walk,
        s.tilt_mounting,
        s.gyro_angle_walk * 60.0,
        s.gyro_bias * 3600.0,
        s.force_seal_friction,
        s.force_lag,
        s.tracker_position * 1e3,
        s.tracker_attitude.to_degrees() * 1e3,
    ));
    out
}

/// The first seed's result, while the other seeds train: its recommendation and
/// headline on screen, and `out/report.md` saying so, marked as partial (the full report
/// replaces it).
pub(super) fn first_result(
    e: &Evaluated,
    seed: u64,
    seeds: usize,
    began: Instant,
    out: &std::path::Path,
    reporter: &mut dyn Reporter,
) -> Result<()> {
    let rows: Vec<TableVRow> = e.sessions.iter().flat_map(|s| s.rows.clone()).collect();
    let recommendation = recommend(&e.validation.rows);
    let headline = recommendation.headline(&rows).unwrap_or_else(|| {
        "No model removed error on the validation session: none is recommended.".into()
    });
    let minutes = began.elapsed().as_secs_f64() / 60.0;
    reporter.note(&format!(
        "first result, after {minutes:.1} min (training seed {seed} only; {} more seed(s) to come): {headline}",
        seeds - 1
    ));
    let text = format!(
        "# IASTGCN on the digital twin — demo report (partial)\n\n\
         **Partial: only training seed {seed}'s models are trained and evaluated so far \
         ({minutes:.1} min into the demo). The demo is still running; this file is replaced \
         by the full report, over all {seeds} seeds, when it ends.**\n\n\
         {headline}\n\n{}\n",
        recommendation.sentence()
    );
    crate::error::write_file(&out.join("report.md"), text.as_bytes())
}

/// The mirror with the model `name` of `models` compensating (none: only the other
/// controllers; docs/polishing.md), into `out/polish/`; returns the report's section.
pub(super) fn mirror_section(
    device: &Device,
    models: &[NamedModel],
    name: Option<&str>,
    sources: &DataSources,
    spec: &PolishSpec,
    out: &std::path::Path,
    reporter: &mut dyn Reporter,
) -> Result<String> {
    let model = match name {
        Some(name) => Some(models.iter().find(|m| m.name == name).ok_or_else(|| {
            Error::Invalid(format!(
                "the recommended model {name} is not among the demo's"
            ))
        })?),
        None => None,
    };
    let checkpoints: Vec<(String, _)> = model
        .iter()
        .map(|m| (m.name.clone(), m.checkpoint.clone()))
        .collect();
    let mut loop_models = predictors(device, &checkpoints)?;
    // The oracle stands in for a model of the demo's window.
    let window = models.first().map_or(48, |m| m.checkpoint.config.window);
    let geometry = Geometry::load_or_default(None)?;
    let machine = draw_machine(geometry.clone(), MACHINE_SEED);
    let nominal = Robot::nominal(geometry.clone());
    let calibrated = file::calibrated_robot(geometry, &sources.calibration)?;
    let mut polisher = Polisher::new(Setup::new(PathKind::Grid))?;
    polisher.run_on(device)?;
    let result = polish::run(
        &mut polisher,
        spec,
        &machine,
        &nominal,
        &calibrated,
        &mut loop_models,
        window,
        reporter,
    )?;
    let dir = out.join("polish");
    polish::write(&dir, spec, &polisher, &result)?;
    let pays = pays_section(&result, &dir, reporter)?;
    let table = polish::report(spec, &polisher, &result);
    // The study's own heading goes; the rest is the section.
    let body: String = table.lines().skip(2).collect::<Vec<_>>().join("\n");
    let who = match name {
        Some(name) => format!("The recommended model ({name}) in the loop"),
        None => "No model was recommended (none removed error on the validation session), so none is in the loop: the other controllers".into(),
    };
    Ok(format!(
        "{who} while the twin polishes a mirror, against the other controllers, from the same starting surface with the same seeds (docs/polishing.md; `iastgcn polish` runs more surfaces and iterations). Files: `polish/polish.md`, `polish/polish.csv`, `polish/convergence.png` (Fig. 13), `polish/maps.png` (Fig. 14).\n\n{body}\n{pays}"
    ))
}

/// When compensation pays on the demo's pad: its mirror's first iteration walked with
/// pose errors of each kind and size ([`demo_sweep`]), this run's controllers' errors
/// marked; written to `dir/sweep/`, and the report's sub-section.
fn pays_section(
    result: &polish::PolishResult,
    dir: &std::path::Path,
    reporter: &mut dyn Reporter,
) -> Result<String> {
    let marks = polish_sweep::marks_from_rows(
        result
            .rows
            .iter()
            .map(|r| (r.controller.as_str(), r.position_um)),
    );
    let shown: Vec<String> = marks
        .iter()
        .map(|m| m.name.replace("the twin, ", ""))
        .collect();
    let spec = demo_sweep(marks);
    reporter.note("== when compensation pays on this pad: its first iteration walked with pose errors of each kind and size (docs/polishing.md)");
    let swept = polish_sweep::run(&spec, reporter)?;
    polish_sweep::write(&dir.join("sweep"), &spec, &swept)?;
    Ok(format!(
        "\n### When compensation pays on this pad\n\nThe mirror's starting surface on this pad ({} mm footprint), measured and planned once and walked at the plan's feed with a pose error of each kind and size instead of a controller, the force at the plan's (error seed {}; `iastgcn polish-sweep`): the cost in final RMS over the clear aperture, nm, against the same walk without error. A stiff float (4 N/mm, 3 N of seal friction) turns a height error into a force error; the ideal one does not. docs/polishing.md \"When compensation pays\" has the map over pads of 14–84 mm and three seeds.\n\n{}\nThis run's controllers showed the glass: {}. Files: `polish/sweep/` (`map.png`, `sweep.md`, `sweep.csv`).\n",
        polish_sweep::DEFAULT_FOOTPRINT,
        spec.seeds.iter().map(u64::to_string).collect::<Vec<_>>().join(", "),
        polish_sweep::pad_table(&spec, &swept, polish_sweep::DEFAULT_FOOTPRINT),
        shown.join(", ")
    ))
}

/// The report's setup lines: the config and seeds, the protocol, the training data
/// (`closed_loop`: what the closed-loop round did, in words), the split and the models.
pub(super) fn setup_lines(demo: &DemoConfig, closed_loop: Option<String>) -> Vec<String> {
    vec![
        format!(
            "config: {} (T = {}, C = {}, L = {}, {}, at most {} epochs, patience {}); \
             training seeds {}",
            demo.run_source,
            demo.run.model.window,
            demo.run.model.channels,
            demo.run.model.blocks,
            demo.run.model.look_ahead_words(),
            demo.run.train.max_epochs,
            demo.run.train.patience,
            demo.seeds
                .iter()
                .map(u64::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
        NamedRecipe::line_for(&demo.recipe, demo.closed_loop, demo.held_out.every),
        format!(
            "protocol: machine 1; calibration set at rest on a cold machine (seed \
             {CALIBRATION_SEED}); training recordings under the calibrated controller: {}, \
             {IDLE_BETWEEN_RUNS} s idle between runs; held-out runs under the same \
             controller, every path turned or reversed on the part so that no window \
             retraces a training recording, plus the rosette that training never saw, {} min \
             each, every stage of a path starting from the same machine state, in {}; \
             prediction every {} ticks. Table V scores against the hidden truth and as the \
             tracker measures; Table III scores the test split of the training recordings \
             against the tracker-derived labels",
            demo.recipe.describe(demo.minutes, TRAINING_SEED),
            demo.held_out.minutes,
            demo.held_out.describe_sessions(),
            demo.held_out.every
        ),
        closed_loop.unwrap_or_else(|| OPEN_LOOP_DATA.into()),
        "split: contiguous 70/20/10 blocks per recording (leakage-free)".into(),
        if demo.all_models {
            "models: IASTGCN, its ablations and every baseline, all at the same budget".into()
        } else {
            "models: IASTGCN, its ablations and the dense baselines; the spatio-temporal baselines of Table III (ConvLSTM, T-GCN, EAT-GCN, ST-GAT) are left out to keep the demo within its time (demo.all_models trains them too)".into()
        },
        "every model is refined the same way and keeps its core weights unless refinement lowers its per-window validation loss".into(),
    ]
}
