//! What the demo will do, said before it starts: its stages and, for the default
//! settings on the native CPU path, how long it will take on this machine.

use super::DemoConfig;
use crate::error::Result;
use crate::experiment::forecast;
use crate::experiment::protocol::TRAINING_SEED;
use crate::gpu::Device;
use crate::model::Variant;

/// What the demo will do, stage by stage, and about how long it will take here
/// ([`forecast`]: on the native CPU path only, where training takes most of the time).
pub(super) fn plan(
    demo: &DemoConfig,
    device: &Device,
    out: &std::path::Path,
) -> Result<Vec<String>> {
    let models = Variant::IASTGCN.len()
        + Variant::DENSE.len()
        + if demo.all_models {
            Variant::SPATIO_TEMPORAL.len()
        } else {
            0
        };
    let seeds = demo.seeds.len();
    let mut lines = vec![
        "== the plan".to_string(),
        format!(
            "1. the twin: a calibration set on a cold machine and its EKF calibration; training recordings, {}",
            demo.recipe.describe(demo.minutes, TRAINING_SEED)
        ),
        if demo.closed_loop {
            "2. closed-loop recordings: a round-0 IASTGCN compensates the second half of the sessions as they are recorded again".into()
        } else {
            "2. (no closed-loop recordings: open-loop data only)".into()
        },
        format!(
            "3. the dataset (T = {}, stride {}, contiguous 70/20/10 blocks per recording)",
            demo.run.model.window, demo.run.data.stride
        ),
        format!(
            "4. for each of {seeds} training seed(s): {models} models trained and refined, then evaluated (Table III, Table V on {} held-out session(s), a validation session that picks the model to use){}",
            demo.held_out.sessions,
            if seeds > 1 {
                "; the first seed's result is on screen and in report.md as soon as it is ready"
            } else {
                ""
            }
        ),
        format!("5. the report: {}", out.join("report.md").display()),
    ];
    if seeds > 1 {
        lines.push(
            "   with it, the recommended model's seeds as one ensemble: a 90 % interval calibrated on the validation session, its coverage per path, and models/<model>.ensemble.toml for the predictors"
                .into(),
        );
    }
    if let Some(mirror) = &demo.mirror {
        lines.push(format!(
            "6. the mirror: the recommended model polishing against the other controllers, {} iteration(s) on {} surface(s)",
            mirror.iterations,
            mirror.surface_seeds.len()
        ));
    }
    // The reference ran the default demo: the forecast holds for its settings (any
    // seeds) on the native CPU path.
    let defaults = DemoConfig {
        seeds: demo.seeds.clone(),
        run_source: demo.run_source.clone(),
        ..DemoConfig::default()
    };
    lines.push(if !device.prefers_native() {
        format!(
            "time: no forecast on {} (it is scaled from the native CPU path)",
            device.name()
        )
    } else if *demo != defaults {
        "time: no forecast for these settings (it is scaled from a run of the default demo)"
            .into()
    } else {
        let step_ms = forecast::probe(&demo.run)?;
        let (first, all) = forecast::forecast(step_ms);
        // The rest scales with the seeds over the reference's.
        let all = first + (all - first) * seeds as f64 / forecast::REFERENCE.seeds as f64;
        format!(
            "time: {} here{}, if nothing else runs beside it (an IASTGCN training step takes {step_ms:.1} ms here, {:.1} ms on the reference machine, where the demo took {:.0} s: {})",
            forecast::minutes(all),
            if seeds > 1 {
                format!(", the first result in {}", forecast::minutes(first))
            } else {
                String::new()
            },
            forecast::REFERENCE.step_ms,
            forecast::REFERENCE.demo_s,
            forecast::REFERENCE.measured
        )
    });
    Ok(lines)
}
