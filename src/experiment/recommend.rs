//! Which model to use, chosen the way it will be used: every model compensates a
//! validation session of held-out runs in the twin (a session of its own, never scored
//! in Table V), and the model that removes the most of the calibrated error there, over
//! its training seeds, is recommended (docs/usage.md "evaluate", "Recommended model").
//! The tables stay complete; this only names one model and says why.

use super::report::seeds::{split_name, Spread};
use super::report::TableVRow;

/// The held-out session index the recommendation is chosen on
/// (`evaluate::HeldOutConfig::session`) when Table V scores sessions 0 to
/// `test_sessions − 1`: the next one, on a day of its own, with its own seeds and
/// placements, never scored in Table V.
pub fn validation_session(test_sessions: usize) -> usize {
    test_sessions
}

/// One model's score on the validation session: the share of the calibrated controller's
/// mean true error its compensation removed, position and attitude, %, each the mean
/// over the session's paths; averaged over its training seeds.
#[derive(Clone, Debug, PartialEq)]
pub struct ValidationScore {
    /// The model (its seeds grouped: `iastgcn` for `iastgcn.seed1` …).
    pub model: String,
    /// Training seeds averaged.
    pub seeds: usize,
    /// Position error removed, %, mean over paths and seeds.
    pub position: f64,
    /// Attitude error removed, %, mean over paths and seeds.
    pub attitude: f64,
    /// Its seed with the highest score (its full name), for the weights to deploy.
    pub best_seed: String,
}

impl ValidationScore {
    /// The criterion: the mean of the position and attitude shares removed.
    pub fn score(&self) -> f64 {
        0.5 * (self.position + self.attitude)
    }
}

/// The recommendation from a validation session's Table V rows.
#[derive(Clone, Debug, PartialEq)]
pub struct Recommendation {
    /// Every model's score, in the order the rows name them.
    pub scores: Vec<ValidationScore>,
    /// The index into `scores` of the model to use; `None` when no model removes any
    /// error on validation (then none should be used).
    pub best: Option<usize>,
}

/// One trained run on the validation session: the model it is a seed of (its seeds are
/// grouped under this name), its own name, and the share of the calibrated error its
/// compensation removed on each path, position and attitude, %.
#[derive(Clone, Debug, PartialEq)]
pub struct ValidationRun {
    /// The model (`iastgcn` for `iastgcn.seed1` …; a seed ensemble is a model of its own).
    pub model: String,
    /// The run's own name (a seed's, for the weights to deploy).
    pub run: String,
    /// Per path: position and attitude error removed, %.
    pub shares: Vec<[f64; 2]>,
}

/// Scores every compensating model of `rows` (one validation session's Table V rows)
/// and picks the one with the highest mean share removed, over its seeds.
pub fn recommend(rows: &[TableVRow]) -> Recommendation {
    let mut runs: Vec<ValidationRun> = Vec::new();
    for r in rows.iter().filter(|r| r.stage == "compensated") {
        let Some(share) = r.removed_in(rows) else {
            continue;
        };
        match runs.iter_mut().find(|v| v.run == r.model) {
            Some(v) => v.shares.push(share),
            None => runs.push(ValidationRun {
                model: split_name(&r.model).0.to_string(),
                run: r.model.clone(),
                shares: vec![share],
            }),
        }
    }
    recommend_runs(&runs)
}

/// The rule over trained runs: each model's score is the mean over its runs (seeds) of
/// the mean over paths of the share removed; the highest mean of position and attitude
/// is recommended, if it removes anything.
pub fn recommend_runs(runs: &[ValidationRun]) -> Recommendation {
    let mean = |v: &[[f64; 2]], i: usize| v.iter().map(|s| s[i]).sum::<f64>() / v.len() as f64;
    let per_run: Vec<(&ValidationRun, [f64; 2])> = runs
        .iter()
        .filter(|r| !r.shares.is_empty())
        .map(|r| (r, [mean(&r.shares, 0), mean(&r.shares, 1)]))
        .collect();
    let mut scores: Vec<ValidationScore> = Vec::new();
    for (run, _) in &per_run {
        if scores.iter().any(|v| v.model == run.model) {
            continue;
        }
        let of: Vec<&(&ValidationRun, [f64; 2])> = per_run
            .iter()
            .filter(|(r, _)| r.model == run.model)
            .collect();
        let n = of.len() as f64;
        let best = of
            .iter()
            .max_by(|a, b| (a.1[0] + a.1[1]).total_cmp(&(b.1[0] + b.1[1])))
            .map_or(run.run.clone(), |b| b.0.run.clone());
        scores.push(ValidationScore {
            model: run.model.clone(),
            seeds: of.len(),
            position: of.iter().map(|r| r.1[0]).sum::<f64>() / n,
            attitude: of.iter().map(|r| r.1[1]).sum::<f64>() / n,
            best_seed: best,
        });
    }
    let best = scores
        .iter()
        .enumerate()
        .filter(|(_, s)| s.score() > 0.0)
        .max_by(|a, b| a.1.score().total_cmp(&b.1.score()))
        .map(|(i, _)| i);
    Recommendation { scores, best }
}

impl Recommendation {
    /// The model to use, if any.
    pub fn model(&self) -> Option<&ValidationScore> {
        self.best.map(|i| &self.scores[i])
    }

    /// The headline of a report: what the recommended model does on the held-out Hilbert
    /// runs of `table_v` (Table V, every test session): the share of each session's
    /// calibrated mean true error its compensation removed, position and attitude, mean
    /// ± SD over its seeds and the sessions. `None` without a recommended model or its
    /// Hilbert rows.
    pub fn headline(&self, table_v: &[TableVRow]) -> Option<String> {
        let model = self.model()?;
        let shares: Vec<[f64; 2]> = table_v
            .iter()
            .filter(|r| {
                r.trajectory == "hilbert"
                    && r.stage == "compensated"
                    && split_name(&r.model).0 == model.model
            })
            .filter_map(|r| r.removed_in(table_v))
            .collect();
        if shares.is_empty() {
            return None;
        }
        let mut sessions: Vec<usize> = table_v.iter().map(|r| r.session).collect();
        sessions.sort_unstable();
        sessions.dedup();
        let spread = |i: usize| Spread::of(&shares.iter().map(|s| s[i]).collect::<Vec<_>>());
        Some(format!(
            "{}, the recommended model, removes {} % of the position and {} % of the \
             attitude error left by calibration on the held-out Hilbert runs (Table V, \
             against hidden truth; mean ± SD over {} seed(s) × {} held-out session(s)).",
            model.model,
            spread(0).text(1),
            spread(1).text(1),
            model.seeds,
            sessions.len()
        ))
    }

    /// The report's section: the validation session (`session`: its number from 1 and
    /// how it ran, `HeldOutSession::describe`), each model's score, the choice and why.
    pub fn markdown(&self, session: (usize, &str), minutes: f64) -> String {
        format!(
            "Every model compensated a **validation session** of its own, not scored in \
             Table V: {minutes} min runs of the four paths, {}, the raster, the Hilbert curve \
             and the rosette placed where no training or test run lies, the spiral at its \
             one held-out placement (`PathParams::held_out_in`, session {}). Score: the \
             share of the calibrated controller's mean true error removed, position and \
             attitude, each the mean over the four paths and over the model's training \
             seeds; the recommended model has the highest mean of the two.\n\n{}\n{}\n",
            session.1,
            session.0,
            self.table(),
            self.sentence()
        )
    }

    /// Every model's score as a Markdown table, the recommended model in bold.
    pub fn table(&self) -> String {
        let mut s = String::from(
            "| Model | Seeds | Position removed (%) | Attitude removed (%) | Score |\n\
             |---|---:|---:|---:|---:|\n",
        );
        for (i, v) in self.scores.iter().enumerate() {
            let mark = if Some(i) == self.best { "**" } else { "" };
            s.push_str(&format!(
                "| {mark}{}{mark} | {} | {:.1} | {:.1} | {:.1} |\n",
                v.model,
                v.seeds,
                v.position,
                v.attitude,
                v.score()
            ));
        }
        s
    }

    /// One sentence: which model, and why (or why none).
    pub fn sentence(&self) -> String {
        match self.model() {
            Some(v) => format!(
                "Recommended: **{}**, which removes the most of the calibrated error on the \
                 validation session ({:.1} % of the position and {:.1} % of the attitude \
                 error, mean over its {} seed(s); chosen there, not on the test runs){}.",
                v.model,
                v.position,
                v.attitude,
                v.seeds,
                if v.seeds > 1 {
                    format!("; its weights: `{}`, its best seed there", v.best_seed)
                } else {
                    String::new()
                }
            ),
            None => "Recommended: **no residual model**: none removes any of the calibrated \
                     error on the validation session, so use the calibration alone (the \
                     tables still show every model)."
                .to_string(),
        }
    }
}
