//! `scale.md`: what ran, the tables per path, the recommended model, where the error
//! goes and the held-out sessions one by one.

use super::points::Point;
use super::records::{PathScore, ScaleRecord};
use super::study::{Study, PAPER_HILBERT_REMOVED};
use crate::experiment::evaluate::oracle_name;
use crate::experiment::recipe::NamedRecipe;
use crate::experiment::recommend::Recommendation;
use crate::twin::PathKind;

/// `scale.md`: what ran, then per path a table of error removed and test MAE per model
/// and size, and the held-out sessions one by one.
pub(super) fn markdown(
    study: &Study,
    (records, all): (&[ScaleRecord], &[ScaleRecord]),
    points: &[Point],
    recommended: &[(f64, Recommendation)],
) -> String {
    let minutes = study.recording_minutes;
    let ensembles = records
        .iter()
        .filter(|r| r.name.ends_with(".ensemble"))
        .count();
    let recipe = &study.recipe;
    let recorded = if recipe.sessions == 1 {
        format!("Recordings of {minutes} min per path in one session")
    } else {
        format!(
            "Recordings of {minutes} min per path in {} sessions of {} min (each a day of its \
             own starting cold, placements {}{}; docs/twin.md \"Sessions\")",
            recipe.sessions,
            minutes / recipe.sessions as f64,
            recipe.placement.name(),
            recipe.path_order.phrase()
        )
    };
    let held = study.held_out();
    let stage = if study.refine {
        "Core stage to early stopping, then refinement (Algorithm 2; the refined weights \
         kept where they lower the per-window validation loss); scored with the weights kept"
    } else {
        "Core stage to early stopping (no refinement)"
    };
    let sessions: Vec<String> = (0..study.scored_sessions())
        .map(|k| {
            let role = if Some(k) == study.validation_index() {
                " (**validation**: the model is chosen here; not in the tables)"
            } else {
                ""
            };
            format!(
                "  - session {}{role}: {}",
                k + 1,
                held.session(k).describe()
            )
        })
        .collect();
    let mut s = format!(
        "# Scaling study\n\n- {}\n- {recorded}; a size of m minutes \
         trains on the first m/{minutes} of each recording's training block and stops early \
         on the first m/{minutes} of its validation block; every size is scored on the same \
         test blocks, those of the {minutes}-minute recordings\n- {stage}\n- Held-out sessions: {}, \
         {} min runs each, a prediction every {} ticks, scored against hidden truth:\n{}\n- Jobs \
         finished in this folder: {} (the last call's study: sizes {:?}, seeds {:?}, models \
         {}){}\n\nMean ± SD over seeds and held-out sessions. Removed: share of the calibrated \
         controller's mean true error removed by compensation; Left: the mean true error it \
         leaves. Open-loop: the mean distance of the model's predictions from the true \
         residual along the same held-out runs played uncompensated (the oracle's \
         correction; docs/shift/README.md \"Where the error goes\"). Test MAE: the model's on \
         the path's test block (µm / mdeg), over seeds. The paper's Table V (Hilbert): {} % / \
         {} %.\n",
        NamedRecipe::line_for(&study.recipe, study.closed_loop, study.every),
        study.held_out_sessions,
        study.held_out_minutes,
        study.every,
        sessions.join("\n"),
        records.len() - ensembles,
        study.sizes,
        study.seeds,
        study.models.join(", "),
        if ensembles > 0 {
            format!(
                "\n- Seed ensembles scored: {ensembles} (`<model>-ensemble`: the controller \
                 averages the predictions of the model's seeds; mean ± SD over held-out \
                 sessions; its test block is not scored)"
            )
        } else {
            String::new()
        },
        PAPER_HILBERT_REMOVED[0],
        PAPER_HILBERT_REMOVED[1],
    );
    for path in PathKind::ALL.map(PathKind::name) {
        s.push_str(&format!(
            "\n## {path}\n\n| Model | Min/path | Train windows | Seeds × sessions | Pos. removed (%) | \
             Att. removed (%) | Test MAE pos (µm) | Test MAE att (mdeg) | Left pos (µm) | \
             Left att (mdeg) | Open-loop pos (µm) | Open-loop att (mdeg) |\n\
             |---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n"
        ));
        let mut oracle = None;
        for p in points.iter().filter(|p| p.path == path) {
            s.push_str(&format!(
                "| {} | {} | {} | {} × {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
                p.model,
                p.minutes,
                p.train_windows,
                p.seeds,
                p.sessions,
                p.pos_removed.text(1),
                p.att_removed.text(1),
                p.test_pos.text(2),
                p.test_att.text(2),
                p.compensated[0].text(1),
                p.compensated[1].text(1),
                p.open_loop[0].text(1),
                p.open_loop[1].text(1)
            ));
            oracle = Some(p.oracle_removed);
        }
        if let Some([pos, att]) = oracle {
            // The oracle stands in for the study's models: it looks ahead as they do.
            let name = oracle_name(study.run.model.look_ahead);
            s.push_str(&format!(
                "| oracle ({name}) | | | | {pos:.1} | {att:.1} | | | | | | |\n"
            ));
        }
    }
    s.push_str(&recommendation_section(recommended, points));
    s.push_str(&where_it_goes(points));
    s.push_str(&by_session(all, study.validation_index()));
    s
}

/// `scale.md`'s recommended model at each size: every model's score on the validation
/// session, the choice, and what the chosen model does on the test sessions' Hilbert runs.
pub(super) fn recommendation_section(
    recommended: &[(f64, Recommendation)],
    points: &[Point],
) -> String {
    if recommended.is_empty() {
        return String::new();
    }
    let mut s = String::from(
        "\n## Recommended model\n\nAt each size, every model scored on the validation \
         session (never in the tables above): the share of the calibrated controller's mean \
         true error removed, position and attitude, each the mean over the four paths and \
         the model's seeds; the highest mean of the two is recommended \
         (`experiment::recommend`, as `evaluate` chooses).\n",
    );
    for (minutes, r) in recommended {
        s.push_str(&format!(
            "\n### {minutes} min per path\n\n{}\n{}",
            r.table(),
            r.sentence()
        ));
        let hilbert = r.model().and_then(|v| {
            points
                .iter()
                .find(|p| p.model == v.model && p.minutes == *minutes && p.path == "hilbert")
        });
        if let Some(p) = hilbert {
            s.push_str(&format!(
                " On the test sessions' Hilbert runs it removes {} % of the position and {} % \
                 of the attitude error (mean ± SD over {} seed(s) × {} session(s)).",
                p.pos_removed.text(1),
                p.att_removed.text(1),
                p.seeds,
                p.sessions
            ));
        }
        s.push('\n');
    }
    s
}

/// `scale.md`'s diagnosis: what compensation leaves on each held-out path, split into
/// the loop's own floor (the oracle's residual: the true residual fed back at a model's
/// rate and latency), the model's part (its open-loop predictions fed forward, less the
/// floor) and the feedback (the closed loop less the fed-forward run: the model's
/// corrections acting on its own inputs), mean over seeds and held-out sessions.
pub(super) fn where_it_goes(points: &[Point]) -> String {
    let measured: Vec<&Point> = points
        .iter()
        .filter(|p| p.replayed[0].mean.is_finite())
        .collect();
    if measured.is_empty() {
        return String::new();
    }
    let mut s = String::from(
        "\n## Where the error goes\n\nMean true error (position µm / attitude mdeg) of the \
         held-out runs: calibrated; compensated in closed loop (what is left); and that left \
         error split into the loop's floor (the oracle's), the model's part (its open-loop \
         predictions fed forward as corrections, less the floor) and the feedback (closed \
         loop less fed forward). Open-loop miss: the mean distance of the predictions from \
         the true residual along the uncompensated run. Mean over seeds and held-out \
         sessions.\n\n| Path | Model | Min/path | Calibrated | Left (closed loop) | Floor \
         (oracle) | Model part | Feedback part | Open-loop miss | Left / miss |\n\
         |---|---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    let pair = |v: [f64; 2]| format!("{:.1} / {:.1}", v[0], v[1]);
    for p in measured {
        let left = [p.compensated[0].mean, p.compensated[1].mean];
        let replayed = [p.replayed[0].mean, p.replayed[1].mean];
        let miss = [p.open_loop[0].mean, p.open_loop[1].mean];
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.2} / {:.2} |\n",
            p.path,
            p.model,
            p.minutes,
            pair(p.calibrated),
            pair(left),
            pair(p.oracle),
            pair([0, 1].map(|i| replayed[i] - p.oracle[i])),
            pair([0, 1].map(|i| left[i] - replayed[i])),
            pair(miss),
            left[0] / miss[0],
            left[1] / miss[1],
        ));
    }
    s
}

/// `scale.md`'s last section: per path and held-out session, the calibrated error, what
/// the oracle removes, and each model and size's share removed (mean over seeds).
pub(super) fn by_session(records: &[ScaleRecord], validation: Option<usize>) -> String {
    let sessions = records
        .iter()
        .flat_map(|r| r.paths.iter().map(|p| p.session))
        .max()
        .map_or(0, |k| k + 1);
    if sessions < 2 {
        return String::new();
    }
    let mut groups: Vec<(String, f64)> = Vec::new();
    for r in records {
        if !groups.iter().any(|g| g.0 == r.model && g.1 == r.minutes) {
            groups.push((r.model.clone(), r.minutes));
        }
    }
    let mut s = String::from(
        "\n## By held-out session\n\nPosition / attitude: the calibrated controller's mean \
         true error (µm / mdeg), then the share removed (%), mean over seeds.\n",
    );
    for path in PathKind::ALL.map(PathKind::name) {
        s.push_str(&format!("\n### {path}\n\n| | "));
        s.push_str(
            &(0..sessions)
                .map(|k| match Some(k) == validation {
                    true => format!("session {} (validation)", k + 1),
                    false => format!("session {}", k + 1),
                })
                .collect::<Vec<_>>()
                .join(" | "),
        );
        s.push_str(" |\n|---|");
        s.push_str(&"---:|".repeat(sessions));
        s.push('\n');
        let scores = |model: Option<&(String, f64)>, k: usize| -> Vec<&PathScore> {
            records
                .iter()
                .filter(|r| model.is_none_or(|g| r.model == g.0 && r.minutes == g.1))
                .flat_map(|r| r.paths.iter())
                .filter(|p| p.path == path && p.session == k)
                .collect()
        };
        let mean = |v: &[&PathScore], f: &dyn Fn(&PathScore) -> [f64; 2]| -> [f64; 2] {
            let n = v.len().max(1) as f64;
            [0, 1].map(|i| v.iter().map(|p| f(p)[i]).sum::<f64>() / n)
        };
        let cells = |f: &dyn Fn(&[&PathScore]) -> String, model: Option<&(String, f64)>| {
            (0..sessions)
                .map(|k| f(&scores(model, k)))
                .collect::<Vec<_>>()
                .join(" | ")
        };
        let pair = |v: [f64; 2], digits: usize| format!("{:.digits$} / {:.digits$}", v[0], v[1]);
        s.push_str(&format!(
            "| calibrated (µm / mdeg) | {} |\n",
            cells(&|v| pair(mean(v, &|p| p.calibrated), 1), None)
        ));
        s.push_str(&format!(
            "| oracle removed (%) | {} |\n",
            cells(&|v| pair(mean(v, &|p| p.removed(p.oracle)), 1), None)
        ));
        for g in &groups {
            s.push_str(&format!(
                "| {} at {} min (%) | {} |\n",
                g.0,
                g.1,
                cells(
                    &|v| pair(mean(v, &|p| p.removed(p.compensated)), 1),
                    Some(g)
                )
            ));
        }
    }
    s
}
