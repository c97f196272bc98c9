//! The morning minute measured (docs/results.md "The morning minute"): at the start of
//! each held-out session the twin records one short tracker run (the raster turned 45°,
//! which no scored run retraces, open loop under the calibration), each trained model is
//! adapted to it ([`crate::train::adapt`]) in every way asked for, and the session's runs
//! are then compensated by the trained and the adapted models from the same state. The
//! validation session (the one after the scored ones) chooses the way; the scored
//! sessions measure it, paired with the trained model on the same seed and session.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::evaluate::{
    held_out_session_from, predictors, session_start, HeldOutConfig, LoopModel, SessionOptions,
};
use super::report::{table_v_csv, TableVRow};
use crate::compensate::held_out::IDLE_BETWEEN_RUNS;
use crate::data::{record_run, DataSources};
use crate::error::{Error, Result};
use crate::gpu::Device;
use crate::model::Checkpoint;
use crate::progress::Reporter;
use crate::stats::Summary;
use crate::train::{adapt, AdaptConfig, Adaptation, Adapted, RunConfig};
use crate::twin::{PathKind, PathParams, RunInfo};

/// A trained model of the study: its name in the tables, its training seed and weights.
#[derive(Clone, Debug)]
pub struct Trained {
    /// The model (`iastgcn-a`).
    pub name: String,
    /// Its training seed.
    pub seed: u64,
    /// Its checkpoint.
    pub checkpoint: Checkpoint,
}

/// What the study runs.
#[derive(Clone, Debug)]
pub struct MorningSpec {
    /// The morning recording's path, turned [`MORNING_ROTATION_DEG`] on the part.
    pub path: PathKind,
    /// Length of the morning recording, minutes (0.25 to 10).
    pub minutes: f64,
    /// The ways of adapting compared with none.
    pub methods: Vec<Adaptation>,
    /// The held-out sessions (the validation session is the one after them).
    pub held: HeldOutConfig,
}

/// The rotation of the morning raster on the part, deg (the warm-up's is 90°, the scored
/// runs' [`PathParams::held_out_in`] others).
pub const MORNING_ROTATION_DEG: f64 = 45.0;

/// The seed of session `plan_seed`'s morning recording.
fn morning_seed(plan_seed: u64) -> u64 {
    plan_seed.wrapping_add(700)
}

/// One adaptation of the study.
#[derive(Clone, Debug)]
pub struct AdaptRecord {
    /// The held-out session, from 0 (the validation session is the last).
    pub session: usize,
    /// The model and its seed.
    pub model: String,
    /// Its seed.
    pub seed: u64,
    /// What the adaptation did.
    pub adapted: Adapted,
}

/// What the study measured.
pub struct Morning {
    /// Table V rows of every session, the validation session's last; a model's row is
    /// named `<model>.seed<k>` (trained) or `<model>.seed<k> +<method>`.
    pub rows: Vec<TableVRow>,
    /// Every adaptation.
    pub adaptations: Vec<AdaptRecord>,
    /// The morning recordings, one per session.
    pub recordings: Vec<PathBuf>,
    /// What ran.
    pub spec: MorningSpec,
    /// The models' names, in order.
    pub models: Vec<String>,
    /// Their seeds, in order.
    pub seeds: Vec<u64>,
}

/// The row name of `model` seed `seed` adapted by `method` (`None`: as trained).
pub fn row_name(model: &str, seed: u64, method: Option<&Adaptation>) -> String {
    match method {
        None => format!("{model}.seed{seed}"),
        Some(m) => format!("{model}.seed{seed} +{m}"),
    }
}

impl MorningSpec {
    fn validate(&self) -> Result<()> {
        self.held.validate()?;
        if !(self.minutes.is_finite() && (0.25..=10.0).contains(&self.minutes)) {
            return Err(Error::Setting {
                setting: "morning.minutes",
                message: format!(
                    "a morning recording of 0.25 to 10 minutes, got {}",
                    self.minutes
                ),
            });
        }
        if self.methods.is_empty() {
            return Err(Error::Setting {
                setting: "morning.methods",
                message: "at least one way of adapting to compare".into(),
            });
        }
        Ok(())
    }
}

/// Runs the study on the machine and calibration of `sources` (the models' training
/// data), writing the morning recordings into `dir`.
pub fn run(
    device: &Device,
    sources: &DataSources,
    trained: &[Trained],
    spec: &MorningSpec,
    config: &RunConfig,
    dir: &Path,
    reporter: &mut dyn Reporter,
) -> Result<Morning> {
    spec.validate()?;
    if trained.is_empty() {
        return Err(Error::Invalid(
            "the morning study needs a trained model".into(),
        ));
    }
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let mut rows = Vec::new();
    let mut adaptations = Vec::new();
    let mut recordings = Vec::new();
    // The scored sessions, then the validation session.
    for k in 0..=spec.held.sessions {
        let plan = spec.held.session(k);
        let (machine, calibrated, start) = session_start(sources, &spec.held, k)?;
        let params = PathParams {
            rotation_deg: MORNING_ROTATION_DEG,
            ..PathParams::default()
        };
        let mut info = RunInfo::polishing(
            spec.path,
            &params,
            spec.minutes * 60.0,
            morning_seed(plan.seed),
        );
        info.machine_seed = sources.machine_seed()?;
        info.controller = sources.calibration.display().to_string();
        info.session = k + 1;
        plan.conditions.stamp(&mut info);
        let csv = dir.join(format!("morning.s{}.csv", k + 1));
        let recorded = record_run(&machine, &calibrated, info, start, &csv, None, reporter)?;
        let mut state = recorded.end;
        state.idle(IDLE_BETWEEN_RUNS);
        recordings.push(csv.clone());
        let minute = DataSources {
            recordings: vec![csv],
            ..sources.clone()
        };
        let mut models: Vec<LoopModel> = Vec::new();
        for t in trained {
            let named = vec![(row_name(&t.name, t.seed, None), t.checkpoint.clone())];
            models.extend(predictors(device, &named)?);
            for method in &spec.methods {
                // Seeded by the model's training seed: the same study gives the same bits.
                let mut how = AdaptConfig::new(*method, config);
                how.train.seed = t.seed;
                let adapted = adapt(device, &minute, &t.checkpoint, &how, reporter)?;
                reporter.note(&format!(
                    "session {} {}: {}",
                    k + 1,
                    row_name(&t.name, t.seed, None),
                    adapted.verdict()
                ));
                let named = vec![(
                    row_name(&t.name, t.seed, Some(method)),
                    adapted.checkpoint(&t.checkpoint),
                )];
                models.extend(predictors(device, &named)?);
                adaptations.push(AdaptRecord {
                    session: k,
                    model: t.name.clone(),
                    seed: t.seed,
                    adapted,
                });
            }
        }
        let session = held_out_session_from(
            device,
            &mut models,
            sources,
            &spec.held,
            SessionOptions::rows(k),
            state,
            reporter,
        )?;
        rows.extend(session.rows);
    }
    let mut names: Vec<String> = Vec::new();
    let mut seeds: Vec<u64> = Vec::new();
    for t in trained {
        if !names.contains(&t.name) {
            names.push(t.name.clone());
        }
        if !seeds.contains(&t.seed) {
            seeds.push(t.seed);
        }
    }
    Ok(Morning {
        rows,
        adaptations,
        recordings,
        spec: spec.clone(),
        models: names,
        seeds,
    })
}

/// An adaptation's cells: session (from 1), model, seed, method, windows adapting and
/// judging, the judging loss before and adapted, the weights kept, seconds.
fn fields(a: &AdaptRecord) -> [String; 10] {
    let d = &a.adapted;
    [
        (a.session + 1).to_string(),
        a.model.clone(),
        a.seed.to_string(),
        d.method.to_string(),
        d.windows[0].to_string(),
        d.windows[1].to_string(),
        format!("{:.4}", d.loss_before),
        format!("{:.4}", d.loss_after),
        (if d.kept_trained { "trained" } else { "adapted" }).to_string(),
        format!("{:.2}", d.seconds),
    ]
}

/// The share of the calibrated position and attitude error a model's row removed on one
/// session, mean over the paths, and on Hilbert; `None` when the session lacks the row.
fn shares(rows: &[TableVRow], session: usize, row: &str) -> Option<([f64; 2], [f64; 2])> {
    let mine: Vec<&TableVRow> = rows
        .iter()
        .filter(|r| r.session == session && r.model == row && r.stage == "compensated")
        .collect();
    if mine.is_empty() {
        return None;
    }
    let mut mean = [0.0; 2];
    let mut hilbert = None;
    for r in &mine {
        let s = r.removed_in(rows)?;
        mean[0] += s[0] / mine.len() as f64;
        mean[1] += s[1] / mine.len() as f64;
        if r.trajectory == PathKind::Hilbert.name() {
            hilbert = Some(s);
        }
    }
    Some((mean, hilbert?))
}

/// `mean ± SD` of `values` with one decimal.
fn pm(values: &[f64]) -> String {
    Summary::of(values).map_or("-".into(), |s| format!("{:.1} ± {:.1}", s.mean, s.sd))
}

impl Morning {
    /// The ways compared: none (`None`), then each method.
    fn ways(&self) -> Vec<Option<Adaptation>> {
        std::iter::once(None)
            .chain(self.spec.methods.iter().copied().map(Some))
            .collect()
    }

    /// Per model and way, over its seeds and `sessions`: the mean-over-paths share
    /// removed (position, attitude), Hilbert's, and the gain over the trained model on
    /// the same seed and session, each as a list of values.
    fn table(&self, sessions: &[usize]) -> Vec<(String, String, [Vec<f64>; 6])> {
        let mut out = Vec::new();
        for model in &self.models {
            for way in self.ways() {
                let mut cols: [Vec<f64>; 6] = Default::default();
                for &seed in &self.seeds {
                    for &k in sessions {
                        let name = row_name(model, seed, way.as_ref());
                        let base = row_name(model, seed, None);
                        let (Some((mean, hilbert)), Some((base_mean, base_hilbert))) =
                            (shares(&self.rows, k, &name), shares(&self.rows, k, &base))
                        else {
                            continue;
                        };
                        cols[0].push(mean[0]);
                        cols[1].push(mean[1]);
                        cols[2].push(hilbert[0]);
                        cols[3].push(hilbert[1]);
                        cols[4].push(mean[0] - base_mean[0]);
                        cols[5].push(hilbert[0] - base_hilbert[0]);
                    }
                }
                let way = way.map_or("none (as trained)".to_string(), |m| m.to_string());
                out.push((model.clone(), way, cols));
            }
        }
        out
    }

    /// The way the validation session favours for `model`: the largest mean-over-paths
    /// position share removed, mean over seeds (none when nothing beats it).
    pub fn chosen(&self, model: &str) -> String {
        let k = self.spec.held.sessions;
        self.table(&[k])
            .into_iter()
            .filter(|(m, _, _)| m == model)
            .map(|(_, way, cols)| {
                let mean = Summary::of(&cols[0]).map_or(f64::NEG_INFINITY, |s| s.mean);
                (way, mean)
            })
            .fold((String::new(), f64::NEG_INFINITY), |best, (way, mean)| {
                if mean > best.1 {
                    (way, mean)
                } else {
                    best
                }
            })
            .0
    }

    /// The study's Markdown: what ran, the table over the scored sessions (mean ± SD
    /// over seeds × sessions, and the paired gain), the validation session's choice, and
    /// every adaptation's verdict.
    pub fn markdown(&self) -> String {
        let mut md = String::new();
        let held = &self.spec.held;
        let _ = writeln!(md, "# The morning minute\n");
        let _ = writeln!(
            md,
            "At the start of each held-out session the twin records {} min of the {} path \
             turned {MORNING_ROTATION_DEG}° (open loop, under the calibration; no scored run \
             retraces it); each trained model is adapted to it and the session's runs are \
             compensated from the same state by the trained and the adapted models. \
             Seeds {}; {}; the validation session is session {} (docs/results.md \"The \
             morning minute\").\n",
            self.spec.minutes,
            self.spec.path.name(),
            self.seeds
                .iter()
                .map(|s| s.to_string())
                .collect::<Vec<_>>()
                .join(", "),
            held.describe_sessions(),
            held.sessions + 1
        );
        let scored: Vec<usize> = (0..held.sessions).collect();
        let _ = writeln!(
            md,
            "Share of the calibrated error removed against the twin's truth, %, mean ± SD \
             over seeds × held-out sessions; the gain is paired with the trained model on \
             the same seed and session (points of position share).\n"
        );
        let _ = writeln!(
            md,
            "| model | adaptation | position (4 paths) | attitude (4 paths) | Hilbert position | Hilbert attitude | gain (4 paths) | gain (Hilbert) |"
        );
        let _ = writeln!(md, "|---|---|---|---|---|---|---|---|");
        for (model, way, cols) in self.table(&scored) {
            let _ = write!(md, "| {model} | {way} |");
            for c in &cols {
                let _ = write!(md, " {} |", pm(c));
            }
            let _ = writeln!(md);
        }
        let _ = writeln!(md, "\nOn the validation session:\n");
        let _ = writeln!(
            md,
            "| model | adaptation | position (4 paths) | gain (4 paths) |"
        );
        let _ = writeln!(md, "|---|---|---|---|");
        for (model, way, cols) in self.table(&[held.sessions]) {
            let _ = writeln!(
                md,
                "| {model} | {way} | {} | {} |",
                pm(&cols[0]),
                pm(&cols[4])
            );
        }
        let _ = writeln!(md);
        for model in &self.models {
            let _ = writeln!(
                md,
                "The validation session favours **{}** for {model}.",
                self.chosen(model)
            );
        }
        let _ = writeln!(md, "\n## Each adaptation\n");
        let _ = writeln!(
            md,
            "| session | model | seed | adaptation | windows adapting | windows judging | loss before | loss adapted | kept | seconds |"
        );
        let _ = writeln!(md, "|---|---|---|---|---|---|---|---|---|---|");
        for a in &self.adaptations {
            let _ = writeln!(md, "| {} |", fields(a).join(" | "));
        }
        md
    }

    /// Writes `morning.md`, `morning_table_v.csv` (every row) and `adaptations.csv` into
    /// `dir`, together or not at all.
    pub fn write(&self, dir: &Path) -> Result<()> {
        let mut csv = String::from(
            "session,model,seed,adaptation,adapt_windows,judge_windows,loss_before,loss_adapted,kept,seconds,dx_um,dy_um,dz_um,rx_mdeg,ry_mdeg,rz_mdeg\n",
        );
        for a in &self.adaptations {
            let d = &a.adapted;
            csv.push_str(&fields(a).join(","));
            for o in d.offset {
                let _ = write!(csv, ",{o}");
            }
            csv.push('\n');
        }
        crate::error::write_files(
            dir,
            &[
                ("morning.md", &self.markdown()),
                ("morning_table_v.csv", &table_v_csv(&self.rows)),
                ("adaptations.csv", &csv),
            ],
        )
    }
}
