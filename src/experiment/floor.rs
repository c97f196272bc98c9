//! The look-ahead floor (docs/results.md "The look-ahead floor"): what an oracle leaves
//! when it feeds back the true residual of the tick it acts on (the next one) instead of
//! the tick just measured, on the held-out sessions. The gap between the two oracles is
//! the most a model that predicts ahead from the planned commands could add.

use std::fmt::Write as _;
use std::path::Path;

use super::evaluate::{session_start, HeldOutConfig};
use crate::compensate::held_out::IDLE_BETWEEN_RUNS;
use crate::compensate::online::{self, ErrorStats, Feedback, Online};
use crate::data::DataSources;
use crate::error::{Error, Result};
use crate::progress::Reporter;
use crate::stats::Summary;
use crate::twin::PathKind;

/// Passes of the look-ahead oracle's fixed point ([`online::look_ahead_oracle`]).
pub const PASSES: usize = online::LOOK_AHEAD_PASSES;

/// One held-out run under the calibrated controller alone and under both oracles.
#[derive(Clone, Debug)]
pub struct FloorRow {
    /// The held-out session, from 0.
    pub session: usize,
    /// The path.
    pub path: PathKind,
    /// Against truth, every tick: the calibrated run, the oracle of the tick just
    /// measured, and the look-ahead oracle.
    pub truth: [ErrorStats; 3],
}

impl FloorRow {
    /// The share of the calibrated error each oracle removed (`which` 1: the oracle, 2:
    /// the look-ahead one): position, attitude, %.
    pub fn removed(&self, which: usize) -> [f64; 2] {
        let (c, o) = (&self.truth[0], &self.truth[which]);
        [
            100.0 * (c.position.mean - o.position.mean) / c.position.mean,
            100.0 * (c.attitude.mean - o.attitude.mean) / c.attitude.mean,
        ]
    }
}

/// Runs every held-out session of `held` on the machine and calibration of `sources`:
/// each path uncompensated, with the oracle and with the look-ahead oracle of a
/// `window`-step model predicting every `held.every` ticks, all from the same start.
pub fn run(
    sources: &DataSources,
    held: &HeldOutConfig,
    window: usize,
    reporter: &mut dyn Reporter,
) -> Result<Vec<FloorRow>> {
    if window == 0 {
        return Err(Error::Setting {
            setting: "floor.window",
            message: "a model's window is at least one tick".into(),
        });
    }
    let settings = Online { every: held.every };
    let mut rows = Vec::new();
    for k in 0..held.sessions {
        let (machine, controller, mut state) = session_start(sources, held, k)?;
        reporter.begin(&format!("session {}", k + 1), PathKind::ALL.len() as u64);
        for (i, path) in PathKind::ALL.into_iter().enumerate() {
            let run = held.run(k, i, state.clone());
            let go = |feedback| run.run(&machine, &controller, feedback, |_| {});
            let plain = go(Feedback::None)?;
            let oracle = go(Feedback::Oracle { window, settings })?;
            let (ahead, passes) = online::look_ahead_oracle(
                &machine,
                &controller,
                &run.config(),
                &run.start,
                window,
                held.every,
                1,
                PASSES,
            )?;
            reporter.note(&format!(
                "session {} {}: the look-ahead oracle's passes leave {} µm",
                k + 1,
                path.name(),
                passes
                    .iter()
                    .map(|p| format!("{p:.2}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
            rows.push(FloorRow {
                session: k,
                path,
                truth: [plain.truth, oracle.truth, ahead.truth],
            });
            let mut end = plain.end;
            end.idle(IDLE_BETWEEN_RUNS);
            state = end;
            reporter.update(i as u64 + 1, path.name());
        }
        reporter.end();
    }
    Ok(rows)
}

/// `mean ± SD` with one decimal.
fn pm(values: &[f64]) -> String {
    Summary::of(values).map_or("-".into(), |s| format!("{:.1} ± {:.1}", s.mean, s.sd))
}

/// The floor's Markdown: per path, the calibrated error and what each oracle removes and
/// leaves, mean ± SD over the sessions.
pub fn markdown(rows: &[FloorRow], held: &HeldOutConfig, window: usize) -> String {
    let mut md = String::new();
    let _ = writeln!(md, "# The look-ahead floor\n");
    let _ = writeln!(
        md,
        "Each held-out path under the calibrated controller alone, with the oracle (the \
         true residual of the tick just measured, applied from the next tick, as Table V's \
         oracle row) and with the look-ahead oracle (the true residual of the next tick, \
         the one the correction acts on), both as a {window}-step model predicting every \
         {} tick(s); against truth every tick, mean ± population SD over {} \
         (docs/results.md \"The look-ahead floor\").\n",
        held.every,
        held.describe_sessions()
    );
    let _ = writeln!(
        md,
        "| path | calibrated µm / mdeg | oracle removes % | oracle leaves µm / mdeg | look-ahead removes % | look-ahead leaves µm / mdeg |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|");
    for path in PathKind::ALL {
        let mine: Vec<&FloorRow> = rows.iter().filter(|r| r.path == path).collect();
        let col =
            |f: &dyn Fn(&FloorRow) -> f64| -> Vec<f64> { mine.iter().map(|r| f(r)).collect() };
        let pair = |which: usize| {
            format!(
                "{} / {}",
                pm(&col(&|r| r.truth[which].position.mean)),
                pm(&col(&|r| r.truth[which].attitude.mean))
            )
        };
        let share = |which: usize| {
            format!(
                "{} / {}",
                pm(&col(&|r| r.removed(which)[0])),
                pm(&col(&|r| r.removed(which)[1]))
            )
        };
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} |",
            path.name(),
            pair(0),
            share(1),
            pair(1),
            share(2),
            pair(2)
        );
    }
    md
}

/// One row per session and path: the three runs' mean true errors.
pub fn csv(rows: &[FloorRow]) -> String {
    let mut out = String::from(
        "session,path,calibrated_um,calibrated_mdeg,oracle_um,oracle_mdeg,look_ahead_um,look_ahead_mdeg\n",
    );
    for r in rows {
        let _ = write!(out, "{},{}", r.session + 1, r.path.name());
        for t in &r.truth {
            let _ = write!(out, ",{:.4},{:.4}", t.position.mean, t.attitude.mean);
        }
        out.push('\n');
    }
    out
}

/// Writes `floor.md` and `floor.csv` into `dir`, together or not at all.
pub fn write(dir: &Path, rows: &[FloorRow], held: &HeldOutConfig, window: usize) -> Result<()> {
    crate::error::write_files(
        dir,
        &[
            ("floor.md", &markdown(rows, held, window)),
            ("floor.csv", &csv(rows)),
        ],
    )
}
