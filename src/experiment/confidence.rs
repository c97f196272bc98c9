//! How far to trust a prediction (docs/results.md "Confidence"): each model, a seed
//! ensemble, predicts along every held-out path's uncompensated run; each prediction's
//! miss against the true residual is set beside its members' spread. A 90 % interval is
//! calibrated on the validation session (the one after the scored ones) in two ways, a
//! radius proportional to the spread and a constant radius, and its coverage is measured
//! on the scored sessions, path by path: a calibrated interval covers 85–95 % of them.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::evaluate::{ensemble, session_start, HeldOutConfig, LoopModel};
use super::parallel;
use crate::compensate::held_out::IDLE_BETWEEN_RUNS;
use crate::compensate::online::{self, Feedback, Gate, Online, OpenLoopTick};
use crate::compensate::{EnsembleFile, IntervalCalibration, Radius};
use crate::data::DataSources;
use crate::error::{Error, Result};
use crate::gpu::Device;
use crate::model::Checkpoint;
use crate::progress::Reporter;
use crate::stats::Summary;
use crate::twin::{PathKind, SimConfig};

/// The open-loop predictions of one model on one held-out run.
#[derive(Clone, Debug)]
pub struct RunTicks {
    /// The model (an ensemble's name).
    pub model: String,
    /// The held-out session, from 0 (the validation session is the last).
    pub session: usize,
    /// The path.
    pub path: PathKind,
    /// Every prediction's miss and spread.
    pub ticks: Vec<OpenLoopTick>,
}

/// Records every model's open-loop predictions on the held-out sessions of `held` and
/// its validation session, on the machine and calibration of `sources`: each model is
/// the seeds `checkpoints` (as one ensemble, [`ensemble`]) named `name`; each session
/// warms up as Table V's does, then its paths run in turn uncompensated (the machine idle
/// between them), every model predicting along each from the same start. The sessions
/// run on every core when the models predict natively, each with predictors of its own;
/// the runs come back in the sessions' order.
pub fn record(
    device: &Device,
    models: &[(String, Vec<Checkpoint>)],
    sources: &DataSources,
    held: &HeldOutConfig,
    reporter: &mut dyn Reporter,
) -> Result<Vec<RunTicks>> {
    if models.is_empty() {
        return Err(Error::Invalid("no model to measure".into()));
    }
    let settings = Online { every: held.every };
    let build = || -> Result<Vec<LoopModel>> {
        models
            .iter()
            .map(|(name, checkpoints)| ensemble(device, name, checkpoints))
            .collect()
    };
    // Predictors run natively exactly where the device prefers it (`Predictor::on`).
    let native = device.prefers_native();
    let sessions: Vec<usize> = (0..=held.sessions).collect();
    // Every held-out run lasts as long (`held.minutes`).
    let steps = SimConfig::new(PathKind::Grid, held.minutes * 60.0, 0).steps();
    let ticks = sessions.len() * PathKind::ALL.len() * steps;
    reporter.begin("open-loop predictions", (ticks * models.len()) as u64);
    let mut done = 0u64;
    let per_session = parallel::run_all(
        sessions,
        parallel::workers(native),
        |k, tick| -> Result<Vec<RunTicks>> {
            let mut loop_models = build()?;
            let (machine, calibrated, mut state) = session_start(sources, held, k)?;
            let mut out = Vec::new();
            for (i, path) in PathKind::ALL.into_iter().enumerate() {
                let run = held.run(k, i, state.clone());
                let mut end = None;
                for m in loop_models.iter_mut() {
                    let result = run.run(
                        &machine,
                        &calibrated,
                        Feedback::OpenLoop(&mut m.members, &m.graph, settings),
                        |_| tick(),
                    )?;
                    out.push(RunTicks {
                        model: m.name.clone(),
                        session: k,
                        path,
                        ticks: result.open_loop_ticks,
                    });
                    end = Some(result.end);
                }
                // Uncompensated, every model's run ends in the same state.
                if let Some(mut end) = end {
                    end.idle(IDLE_BETWEEN_RUNS);
                    state = end;
                }
            }
            Ok(out)
        },
        || {
            done += 1;
            if done.is_multiple_of(500) {
                reporter.update(done, "");
            }
        },
    );
    reporter.end();
    Ok(per_session?.into_iter().flatten().collect())
}

/// The `level` quantile of `values` (the smallest value at least that share of them
/// reaches), `None` when there are none.
pub fn quantile(values: &[f64], level: f64) -> Option<f64> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let at = ((level * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
    Some(v[at])
}

/// The share of `pairs` (miss, spread) whose miss is within `radius`.
pub fn coverage(radius: &Radius, pairs: &[(f64, f64)]) -> f64 {
    let inside = pairs
        .iter()
        .filter(|(miss, spread)| *miss <= radius.of(*spread))
        .count();
    inside as f64 / pairs.len().max(1) as f64
}

/// The radius proportional to the spread covering `level` of `pairs` (the `level`
/// quantile of miss / spread, over the pairs with a spread).
pub fn spread_scaled(pairs: &[(f64, f64)], level: f64) -> Option<Radius> {
    let ratios: Vec<f64> = pairs
        .iter()
        .filter(|(_, s)| *s > 0.0)
        .map(|(m, s)| m / s)
        .collect();
    Some(Radius {
        scale: quantile(&ratios, level)?,
        constant: 0.0,
    })
}

/// The constant radius covering `level` of `pairs` (the `level` quantile of the miss).
pub fn constant(pairs: &[(f64, f64)], level: f64) -> Option<Radius> {
    let misses: Vec<f64> = pairs.iter().map(|(m, _)| *m).collect();
    Some(Radius {
        scale: 0.0,
        constant: quantile(&misses, level)?,
    })
}

/// The mean radius over `pairs`.
fn mean_radius_over(radius: &Radius, pairs: &[(f64, f64)]) -> f64 {
    let radii: Vec<f64> = pairs.iter().map(|(_, s)| radius.of(*s)).collect();
    Summary::of(&radii).map_or(f64::NAN, |s| s.mean)
}

/// The (miss, spread) pairs of quantity `q` (0 position, 1 attitude) of `model`'s runs
/// that `keep` selects.
fn pairs(
    runs: &[RunTicks],
    model: &str,
    q: usize,
    keep: impl Fn(&RunTicks) -> bool,
) -> Vec<(f64, f64)> {
    runs.iter()
        .filter(|r| r.model == model && keep(r))
        .flat_map(|r| r.ticks.iter().map(move |t| (t.miss[q], t.spread[q])))
        .collect()
}

/// One model's calibrated intervals and their coverage.
#[derive(Clone, Debug)]
pub struct Calibrated {
    /// The model.
    pub model: String,
    /// Position, then attitude: the spread-scaled and the constant radius.
    pub intervals: [[Radius; 2]; 2],
    /// Per quantity and radius: the mean radius on the validation session (both cover
    /// the level there; the narrower is [`Calibrated::chosen`]).
    pub validation_radius: [[f64; 2]; 2],
    /// Per path (in [`PathKind::ALL`] order), per quantity and interval: the coverage on
    /// each scored session.
    pub coverage: Vec<[[Vec<f64>; 2]; 2]>,
    /// Per quantity and interval: the mean radius on the scored sessions.
    pub mean_radius: [[f64; 2]; 2],
    /// Per quantity: the mean miss of the predictions whose spread is in the widest tenth,
    /// and of the others, on the scored sessions.
    pub widest_tenth: [[f64; 2]; 2],
}

impl Calibrated {
    /// Per quantity, the radius the validation session favours: of the two, which both
    /// cover the level there, the narrower on average (0 spread-scaled, 1 constant; the
    /// constant on a tie: it needs no second member).
    pub fn chosen(&self) -> [usize; 2] {
        self.validation_radius
            .map(|[spread, constant]| if spread < constant { 0 } else { 1 })
    }

    /// The interval of the chosen radii ([`Calibrated::chosen`]) at `level`.
    pub fn calibration(&self, level: f64) -> IntervalCalibration {
        let [p, a] = self.chosen();
        IntervalCalibration {
            level,
            position: self.intervals[0][p],
            attitude: self.intervals[1][a],
        }
    }
}

/// Calibrates each model's intervals at `level` on the validation session (the last of
/// `runs`) and measures them on the scored sessions `0..scored`.
pub fn calibrate(runs: &[RunTicks], scored: usize, level: f64) -> Result<Vec<Calibrated>> {
    let mut names: Vec<String> = Vec::new();
    for r in runs {
        if !names.contains(&r.model) {
            names.push(r.model.clone());
        }
    }
    let mut out = Vec::new();
    for model in names {
        let mut intervals = [[Radius::default(); 2]; 2];
        let mut validation_radius = [[0.0; 2]; 2];
        let mut mean_radius = [[0.0; 2]; 2];
        let mut widest_tenth = [[0.0; 2]; 2];
        for q in 0..2 {
            let validation = pairs(runs, &model, q, |r| r.session == scored);
            let short = || {
                Error::Invalid(format!(
                    "{model}: no prediction with a spread on the validation session (an \
                     ensemble of at least two seeds is needed)"
                ))
            };
            intervals[q] = [
                spread_scaled(&validation, level).ok_or_else(short)?,
                constant(&validation, level).ok_or_else(short)?,
            ];
            let test = pairs(runs, &model, q, |r| r.session < scored);
            for (w, radius) in intervals[q].iter().enumerate() {
                validation_radius[q][w] = mean_radius_over(radius, &validation);
                mean_radius[q][w] = mean_radius_over(radius, &test);
            }
            let spreads: Vec<f64> = test.iter().map(|(_, s)| *s).collect();
            let cut = quantile(&spreads, 0.9).unwrap_or(f64::INFINITY);
            let mean_of = |wide: bool| {
                let m: Vec<f64> = test
                    .iter()
                    .filter(|(_, s)| (*s > cut) == wide)
                    .map(|(m, _)| *m)
                    .collect();
                Summary::of(&m).map_or(f64::NAN, |s| s.mean)
            };
            widest_tenth[q] = [mean_of(true), mean_of(false)];
        }
        let coverage = PathKind::ALL
            .iter()
            .map(|&path| {
                std::array::from_fn(|q| {
                    std::array::from_fn(|w| {
                        (0..scored)
                            .map(|k| {
                                let p =
                                    pairs(runs, &model, q, |r| r.session == k && r.path == path);
                                coverage(&intervals[q][w], &p)
                            })
                            .collect()
                    })
                })
            })
            .collect();
        out.push(Calibrated {
            model,
            intervals,
            validation_radius,
            coverage,
            mean_radius,
            widest_tenth,
        });
    }
    Ok(out)
}

/// The level of the intervals the demo calibrates and `iastgcn confidence` does by
/// default: 90 %.
pub const LEVEL: f64 = 0.9;

/// The radius quantiles on the validation session that the gate's candidate limits take.
pub const GATE_QUANTILES: [f64; 3] = [0.5, 0.75, 0.9];

/// One compensated run of the gate study.
#[derive(Clone, Debug)]
pub struct GatedRun {
    /// The model.
    pub model: String,
    /// `none` (every correction in full) or `q<NN>` (the gate at that radius quantile).
    pub gate: String,
    /// The session, from 0 (the validation session is the last).
    pub session: usize,
    /// The path.
    pub path: PathKind,
    /// Share of the calibrated error removed against truth: position, attitude, %.
    pub removed: [f64; 2],
    /// Share of the ticks whose true position error is larger than the calibrated run's
    /// at the same tick.
    pub worse_ticks: f64,
    /// The 99th percentile of the tick's true position error minus the calibrated run's,
    /// µm (how bad the worst ticks get).
    pub worst_excess_um: f64,
    /// Share of the predictions the gate shrank.
    pub shrunk: f64,
}

/// The gates a model's calibration gives: its spread-scaled interval, the limits at the
/// [`GATE_QUANTILES`] of its radii on the validation session, named `q50` …
pub fn gates(c: &Calibrated, runs: &[RunTicks], validation: usize) -> Vec<(String, Gate)> {
    let scale = [c.intervals[0][0].scale, c.intervals[1][0].scale];
    let radii: [Vec<f64>; 2] = std::array::from_fn(|q| {
        pairs(runs, &c.model, q, |r| r.session == validation)
            .iter()
            .map(|(_, s)| scale[q] * s)
            .collect()
    });
    GATE_QUANTILES
        .iter()
        .filter_map(|&level| {
            let limit = [quantile(&radii[0], level)?, quantile(&radii[1], level)?];
            Some((format!("q{:.0}", 100.0 * level), Gate { scale, limit }))
        })
        .collect()
}

/// Compensates every held-out session of `held` and its validation session with each
/// model in full and through each of its gates ([`gates`]), every run of a path from the
/// same start, and scores them against the calibrated run.
pub fn gate_study(
    models: &mut [LoopModel],
    calibrated: &[Calibrated],
    runs: &[RunTicks],
    sources: &DataSources,
    held: &HeldOutConfig,
    reporter: &mut dyn Reporter,
) -> Result<Vec<GatedRun>> {
    let settings = Online { every: held.every };
    let mut out = Vec::new();
    for k in 0..=held.sessions {
        let (machine, controller, mut state) = session_start(sources, held, k)?;
        for (i, path) in PathKind::ALL.into_iter().enumerate() {
            let run = held.run(k, i, state.clone());
            let plain = run.run(&machine, &controller, Feedback::None, |_| {})?;
            reporter.begin(
                &format!("gates: session {} {}", k + 1, path.name()),
                (models.len() * (1 + GATE_QUANTILES.len())) as u64,
            );
            let mut done = 0;
            for m in models.iter_mut() {
                let Some(c) = calibrated.iter().find(|c| c.model == m.name) else {
                    continue;
                };
                let mut ways: Vec<(String, Option<Gate>)> = vec![("none".into(), None)];
                ways.extend(
                    gates(c, runs, held.sessions)
                        .into_iter()
                        .map(|(n, g)| (n, Some(g))),
                );
                for (name, gate) in ways {
                    let feedback = match gate {
                        None => Feedback::Model(&mut m.members, &m.graph, settings),
                        Some(g) => Feedback::Gated(&mut m.members, &m.graph, settings, g),
                    };
                    let r = run.run(&machine, &controller, feedback, |_| {})?;
                    out.push(score(&m.name, &name, k, path, &plain, &r));
                    done += 1;
                    reporter.update(done, "");
                }
            }
            reporter.end();
            let mut end = plain.end;
            end.idle(IDLE_BETWEEN_RUNS);
            state = end;
        }
    }
    Ok(out)
}

/// A compensated run `r` against the calibrated run `plain` of the same path and start.
fn score(
    model: &str,
    gate: &str,
    session: usize,
    path: PathKind,
    plain: &online::RunResult,
    r: &online::RunResult,
) -> GatedRun {
    let share = |c: f64, b: f64| 100.0 * (c - b) / c;
    let excess: Vec<f64> = r.truth_per_tick[0]
        .iter()
        .zip(&plain.truth_per_tick[0])
        .map(|(b, c)| b - c)
        .collect();
    let worse = excess.iter().filter(|e| **e > 0.0).count();
    GatedRun {
        model: model.into(),
        gate: gate.into(),
        session,
        path,
        removed: [
            share(plain.truth.position.mean, r.truth.position.mean),
            share(plain.truth.attitude.mean, r.truth.attitude.mean),
        ],
        worse_ticks: worse as f64 / excess.len().max(1) as f64,
        worst_excess_um: quantile(&excess, 0.99).unwrap_or(f64::NAN),
        shrunk: r.shrunk as f64 / r.predictions.max(1) as f64,
    }
}

/// Per model and gate: the validation session's mean share removed (position, over the
/// paths), and over the scored sessions the share removed (position, attitude, mean over
/// paths), Hilbert's position share, the worse ticks, the worst excess and the shrunk
/// predictions, each a list over sessions.
#[allow(clippy::type_complexity)]
fn gate_table(gated: &[GatedRun], scored: usize) -> Vec<(String, String, f64, [Vec<f64>; 6])> {
    let mut keys: Vec<(String, String)> = Vec::new();
    for g in gated {
        let key = (g.model.clone(), g.gate.clone());
        if !keys.contains(&key) {
            keys.push(key);
        }
    }
    keys.into_iter()
        .map(|(model, gate)| {
            let of = |k: usize| -> Vec<&GatedRun> {
                gated
                    .iter()
                    .filter(|g| g.model == model && g.gate == gate && g.session == k)
                    .collect()
            };
            let mean = |v: &[&GatedRun], f: &dyn Fn(&GatedRun) -> f64| {
                v.iter().map(|g| f(g)).sum::<f64>() / v.len().max(1) as f64
            };
            let validation = mean(&of(scored), &|g| g.removed[0]);
            let mut cols: [Vec<f64>; 6] = Default::default();
            for k in 0..scored {
                let runs = of(k);
                cols[0].push(mean(&runs, &|g| g.removed[0]));
                cols[1].push(mean(&runs, &|g| g.removed[1]));
                let hilbert: Vec<&GatedRun> = runs
                    .iter()
                    .copied()
                    .filter(|g| g.path == PathKind::Hilbert)
                    .collect();
                cols[2].push(mean(&hilbert, &|g| g.removed[0]));
                cols[3].push(mean(&runs, &|g| 100.0 * g.worse_ticks));
                cols[4].push(mean(&runs, &|g| g.worst_excess_um));
                cols[5].push(mean(&runs, &|g| 100.0 * g.shrunk));
            }
            (model, gate, validation, cols)
        })
        .collect()
}

/// The gate study's Markdown section.
pub fn gate_markdown(gated: &[GatedRun], scored: usize) -> String {
    let mut md = String::new();
    let _ = writeln!(
        md,
        "## Shrinking the corrections where the interval is wide
"
    );
    let _ = writeln!(
        md,
        "Each model compensates in full (`none`) and through a gate that shrinks a \
         correction by limit / radius where its spread-scaled radius exceeds a limit, the \
         limit at the 50th, 75th or 90th percentile of the radii on the validation \
         session (`q50`, `q75`, `q90`). Over the scored sessions, mean ± SD over sessions \
         of the mean over paths: the share of the calibrated error removed against truth \
         (%), a worse tick is one whose true position error exceeds the calibrated run's \
         at the same tick, the worst excess the 99th percentile of that difference (µm).\n"
    );
    let _ = writeln!(
        md,
        "| model | gate | validation, position | position | attitude | Hilbert position | worse ticks % | worst excess µm | shrunk % |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|---|---|---|");
    let one =
        |v: &[f64]| Summary::of(v).map_or("-".into(), |s| format!("{:.1} ± {:.1}", s.mean, s.sd));
    for (model, gate, validation, cols) in gate_table(gated, scored) {
        let _ = write!(md, "| {model} | {gate} | {validation:.1} |");
        for c in &cols {
            let _ = write!(md, " {} |", one(c));
        }
        let _ = writeln!(md);
    }
    let _ = writeln!(md);
    md
}

/// `mean ± SD` of shares as percentages.
fn pct(values: &[f64]) -> String {
    Summary::of(values).map_or("-".into(), |s| {
        format!("{:.1} ± {:.1}", 100.0 * s.mean, 100.0 * s.sd)
    })
}

/// The study's Markdown.
pub fn markdown(calibrated: &[Calibrated], held: &HeldOutConfig, level: f64) -> String {
    let mut md = String::from("# Confidence\n\n");
    md.push_str(&method(
        "Each model (a seed ensemble, its members' mean in the loop) predicts",
        held,
        level,
    ));
    for c in calibrated {
        let _ = writeln!(md, "## {}\n", c.model);
        md.push_str(&model_markdown(c, level));
    }
    md
}

/// What the study does, in a paragraph that starts with `who` predicts.
fn method(who: &str, held: &HeldOutConfig, level: f64) -> String {
    format!(
        "{who} along every held-out path's uncompensated run, a prediction every {} tick(s); a prediction's \
         miss is its distance from the tick's true residual (position µm; attitude across \
         the tool axis, mdeg), its spread the members' root-mean-square distance from their \
         mean (position and attitude in 3-D, as a controller computes it). A {:.0} % \
         interval is calibrated on the validation session (session {}) two ways: a radius \
         proportional to the spread, and a constant radius. Its coverage is the share of \
         the scored sessions' predictions within it, per path, mean ± SD over {} \
         (docs/results.md \"Confidence\").\n\n",
        held.every,
        100.0 * level,
        held.sessions + 1,
        held.describe_sessions()
    )
}

/// One calibrated model's paragraphs and coverage table.
fn model_markdown(c: &Calibrated, level: f64) -> String {
    let mut md = String::new();
    let [pos, att] = c.intervals;
    let _ = writeln!(
        md,
        "Calibrated: position radius {:.2} × spread, or {:.1} µm; attitude {:.2} × \
         spread, or {:.1} mdeg. Mean radius on the scored sessions: position {:.1} µm \
         (spread-scaled) against {:.1}; attitude {:.1} mdeg against {:.1}.\n",
        pos[0].scale,
        pos[1].constant,
        att[0].scale,
        att[1].constant,
        c.mean_radius[0][0],
        c.mean_radius[0][1],
        c.mean_radius[1][0],
        c.mean_radius[1][1]
    );
    let kind = |w: usize| ["spread-scaled", "constant"][w];
    let [p, a] = c.chosen();
    let _ = writeln!(
        md,
        "Both cover about {:.0} % of the validation session; there the narrower is, for \
         position, the {} radius (mean {:.1} µm spread-scaled against {:.1} constant), for \
         attitude the {} ({:.1} against {:.1} mdeg). Those and the seeds are in `{}`, \
         which the predictor loads in Rust, Python and C (docs/embedding.md \"Ensembles \
         and intervals\").\n",
        100.0 * level,
        kind(p),
        c.validation_radius[0][0],
        c.validation_radius[0][1],
        kind(a),
        c.validation_radius[1][0],
        c.validation_radius[1][1],
        ensemble_file_name(&c.model)
    );
    let _ = writeln!(
        md,
        "| path | position, spread-scaled | position, constant | attitude, spread-scaled | attitude, constant |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|");
    for (path, cov) in PathKind::ALL.iter().zip(&c.coverage) {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} |",
            path.name(),
            pct(&cov[0][0]),
            pct(&cov[0][1]),
            pct(&cov[1][0]),
            pct(&cov[1][1])
        );
    }
    let _ = writeln!(
        md,
        "\nDoes the spread flag the bad predictions? Mean miss where the spread is in \
         its widest tenth against the rest: position {:.1} against {:.1} µm, attitude \
         {:.1} against {:.1} mdeg.\n",
        c.widest_tenth[0][0], c.widest_tenth[0][1], c.widest_tenth[1][0], c.widest_tenth[1][1]
    );
    md
}

/// One model's seeds as an ensemble for a report (the demo's "Confidence"): `members`
/// (each checkpoint with its file) named `name` predict open loop along `held`'s
/// sessions ([`record`]), a `level` interval is calibrated on the validation session
/// ([`calibrate`]), its ensemble file is written into `dir` (members relative to it),
/// and the section's Markdown comes back.
#[allow(clippy::too_many_arguments)]
pub fn ensemble_section(
    device: &Device,
    name: &str,
    members: &[(PathBuf, Checkpoint)],
    sources: &DataSources,
    held: &HeldOutConfig,
    level: f64,
    dir: &Path,
    reporter: &mut dyn Reporter,
) -> Result<String> {
    let checkpoints = members.iter().map(|(_, c)| c.clone()).collect();
    let runs = record(
        device,
        &[(name.to_string(), checkpoints)],
        sources,
        held,
        reporter,
    )?;
    let calibrated = calibrate(&runs, held.sessions, level)?;
    let Some(c) = calibrated.first() else {
        return Err(Error::Invalid(format!("{name}: nothing calibrated")));
    };
    let paths: Vec<PathBuf> = members.iter().map(|(p, _)| p.clone()).collect();
    ensemble_file(c, &paths, dir, held, level).write(&dir.join(ensemble_file_name(name)))?;
    let who = format!(
        "The recommended model's {} seeds, as one ensemble (their mean in the loop), predict",
        members.len()
    );
    Ok(format!(
        "{}{}",
        method(&who, held, level),
        model_markdown(c, level)
    ))
}

/// One row per run and prediction: `model,session,path,tick,miss_um,miss_mdeg,spread_um,
/// spread_mdeg,size_um,size_mdeg` (the size: the correction's length).
pub fn ticks_csv(runs: &[RunTicks]) -> String {
    let mut csv = String::from(
        "model,session,path,tick,miss_um,miss_mdeg,spread_um,spread_mdeg,size_um,size_mdeg\n",
    );
    for r in runs {
        for t in &r.ticks {
            let _ = writeln!(
                csv,
                "{},{},{},{},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3}",
                r.model,
                r.session + 1,
                r.path.name(),
                t.tick,
                t.miss[0],
                t.miss[1],
                t.spread[0],
                t.spread[1],
                t.size[0],
                t.size[1]
            );
        }
    }
    csv
}

/// The ensemble file of a calibrated model (docs/embedding.md "Ensembles and
/// intervals"): its `members`' checkpoints, relative to `dir` where the file goes when
/// they can be, and the interval the validation session favours
/// ([`Calibrated::calibration`]).
pub fn ensemble_file(
    c: &Calibrated,
    members: &[PathBuf],
    dir: &Path,
    held: &HeldOutConfig,
    level: f64,
) -> EnsembleFile {
    let absolute = |p: &Path| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    let folder = absolute(dir);
    let members = members
        .iter()
        .map(|m| {
            let m = absolute(m);
            pathdiff::diff_paths(&m, &folder).unwrap_or(m)
        })
        .collect();
    EnsembleFile {
        members,
        calibrated_on: format!(
            "the validation session (session {}) of {}, a prediction every {} tick(s)",
            held.sessions + 1,
            held.describe_sessions(),
            held.every
        ),
        interval: Some(c.calibration(level)),
    }
}

/// The name of model `model`'s ensemble file.
pub fn ensemble_file_name(model: &str) -> String {
    format!("{model}.ensemble.toml")
}

/// Writes `confidence.md`, `ticks.csv` and each model's ensemble file
/// ([`ensemble_file_name`]) into `dir`, together or not at all.
pub fn write(
    dir: &Path,
    markdown: &str,
    runs: &[RunTicks],
    ensembles: &[(String, EnsembleFile)],
) -> Result<()> {
    let mut files = vec![
        ("confidence.md".to_string(), markdown.to_string()),
        ("ticks.csv".to_string(), ticks_csv(runs)),
    ];
    for (model, file) in ensembles {
        let name = ensemble_file_name(model);
        let text = file.to_toml(&name)?;
        files.push((name, text));
    }
    let refs: Vec<(&str, &str)> = files
        .iter()
        .map(|(n, t)| (n.as_str(), t.as_str()))
        .collect();
    crate::error::write_files(dir, &refs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_quantile_is_the_smallest_value_that_share_reaches() {
        let v: Vec<f64> = (1..=10).map(f64::from).collect();
        assert_eq!(quantile(&v, 0.9), Some(9.0));
        assert_eq!(quantile(&v, 0.91), Some(10.0));
        assert_eq!(quantile(&v, 0.0), Some(1.0));
        assert_eq!(quantile(&[f64::NAN, 2.0], 0.5), Some(2.0));
        assert_eq!(quantile(&[], 0.5), None);
    }

    #[test]
    fn intervals_cover_their_level_where_they_were_calibrated() {
        // miss = 2 · spread on most ticks, 10 · spread on a tenth: the spread-scaled
        // interval needs a scale of 2 for 90 %, the constant one the 90 % miss.
        let pairs: Vec<(f64, f64)> = (1..=100)
            .map(|i| {
                let s = f64::from(i);
                (if i % 10 == 0 { 10.0 * s } else { 2.0 * s }, s)
            })
            .collect();
        let scaled = spread_scaled(&pairs, 0.9).unwrap();
        assert_eq!(scaled.scale, 2.0);
        assert!((coverage(&scaled, &pairs) - 0.9).abs() < 1e-12);
        let fixed = constant(&pairs, 0.9).unwrap();
        assert_eq!(fixed.scale, 0.0);
        assert!(coverage(&fixed, &pairs) >= 0.9);
        assert!(spread_scaled(&[(1.0, 0.0)], 0.9).is_none());
    }

    #[test]
    fn a_gate_shrinks_by_the_tighter_of_its_limits() {
        let g = Gate {
            scale: [2.0, 4.0],
            limit: [10.0, 8.0],
        };
        assert_eq!(g.factor([1.0, 1.0]), 1.0, "radii 2 and 4 are within");
        assert_eq!(g.factor([10.0, 1.0]), 0.5, "position radius 20 against 10");
        assert_eq!(g.factor([10.0, 4.0]), 0.5, "attitude 16 against 8 ties it");
        assert_eq!(
            g.factor([10.0, 8.0]),
            0.25,
            "attitude 32 against 8 is tighter"
        );
        assert_eq!(g.factor([0.0, 0.0]), 1.0);
    }

    #[test]
    fn calibration_uses_the_validation_session_and_scores_the_others() {
        let run = |session, path, miss: f64, spread: f64| RunTicks {
            model: "m".into(),
            session,
            path,
            ticks: (0..10)
                .map(|tick| OpenLoopTick {
                    tick,
                    miss: [miss * (1 + tick) as f64, miss],
                    spread: [spread * (1 + tick) as f64, spread],
                    size: [100.0, 50.0],
                })
                .collect(),
        };
        let mut runs = Vec::new();
        for path in PathKind::ALL {
            runs.push(run(0, path, 4.0, 1.0)); // scored: misses twice the validation's
            runs.push(run(1, path, 2.0, 1.0)); // validation
        }
        let c = calibrate(&runs, 1, 0.9).unwrap();
        assert_eq!(c.len(), 1);
        assert_eq!(c[0].intervals[0][0].scale, 2.0);
        // On the scored session every miss is 4 × spread: a 2 × spread radius covers none.
        for cov in &c[0].coverage {
            assert_eq!(cov[0][0], vec![0.0]);
        }
        // Position: the miss grows with the spread, so the spread-scaled radius (mean 11
        // on validation) is narrower than the constant one (18); attitude: both are 2,
        // and the tie goes to the constant.
        assert_eq!(c[0].chosen(), [0, 1]);
        let chosen = c[0].calibration(0.9);
        assert_eq!(
            chosen.position,
            Radius {
                scale: 2.0,
                constant: 0.0
            }
        );
        assert_eq!(
            chosen.attitude,
            Radius {
                scale: 0.0,
                constant: 2.0
            }
        );
    }
}
