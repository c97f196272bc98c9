//! `report.md`: the report as Markdown, Table V with reductions against the calibrated
//! stage, Table III with the best model per trajectory marked, Fig. 10 timings, the
//! setup, sections and notes.

use std::fmt::Write as _;

use super::seeds::{split_name, Spread};
use super::{plan, Report, TableIIIRow, TableVRow, Timing};
use crate::train::log::distinct;
use crate::train::Metrics;

/// A Markdown table cell: pipes escaped, line breaks flattened.
fn md(s: &str) -> String {
    s.replace('|', "\\|").replace(['\n', '\r'], " ")
}

fn num(x: f64, decimals: usize) -> String {
    if x.is_finite() {
        format!("{x:.decimals$}")
    } else {
        "n/a".into()
    }
}

fn duration(seconds: f64) -> String {
    if !seconds.is_finite() || seconds < 60.0 {
        return format!("{} s", num(seconds, 1));
    }
    let total = seconds.round() as u64;
    let (h, m, s) = (total / 3600, total / 60 % 60, total % 60);
    if h > 0 {
        format!("{seconds:.1} s ({h} h {m:02} min {s:02} s)")
    } else {
        format!("{seconds:.1} s ({m} min {s:02} s)")
    }
}

/// Reduction of `after` relative to `before`, percent (positive: smaller after).
fn reduction(before: f64, after: f64) -> Option<f64> {
    let r = 100.0 * (before - after) / before;
    (before > 0.0 && r.is_finite()).then_some(r)
}

const STAGE_ORDER: [&str; 4] = ["initial", "calibrated", "oracle", "compensated"];

/// Table V rows of one trajectory in one held-out session: initial, calibrated, oracle,
/// compensated (input order), then any other stage.
fn table_v_group<'a>(
    rows: &'a [TableVRow],
    (session, trajectory): (usize, &str),
) -> Vec<&'a TableVRow> {
    let of = rows
        .iter()
        .filter(|r| r.trajectory == trajectory && r.session == session);
    let mut out: Vec<&TableVRow> = Vec::new();
    for stage in STAGE_ORDER {
        out.extend(of.clone().filter(|r| r.stage == stage));
    }
    out.extend(of.filter(|r| !STAGE_ORDER.contains(&r.stage.as_str())));
    out
}

fn markdown_table_v(out: &mut String, rows: &[TableVRow]) {
    out.push_str("## Table V analog: pose error along the trajectories\n\n");
    if rows.is_empty() {
        out.push_str("_No rows._\n\n");
        return;
    }
    out.push_str(
        "Each cell is hidden truth / tracker: the twin's true pad pose at every tick, and \
         the laser tracker's measurement at its samples, both against the path target \
         (attitude: the tool-axis angle). The oracle feeds back the true residual with a \
         model's latency and rate: the floor for any predictor.\n\n\
         | Trajectory | Stage | Model | Pos. mean (µm) | Pos. SD (µm) | Pos. max (µm) \
         | Att. mean (mdeg) | Att. SD (mdeg) | Att. max (mdeg) |\n\
         |---|---|---|---:|---:|---:|---:|---:|---:|\n",
    );
    // The runs, held-out session by session; a report of several names the session.
    let mut runs: Vec<(usize, &str)> = Vec::new();
    for r in rows {
        if !runs.contains(&(r.session, r.trajectory.as_str())) {
            runs.push((r.session, r.trajectory.as_str()));
        }
    }
    let several = runs.iter().any(|r| r.0 > 0);
    let name = |(session, t): (usize, &str)| {
        if several {
            format!("{t}, session {}", session + 1)
        } else {
            t.to_string()
        }
    };
    let pair = |t: f64, m: f64| format!("{} / {}", num(t, 1), num(m, 1));
    for &run in &runs {
        for r in table_v_group(rows, run) {
            let (tp, ta) = (&r.truth.position, &r.truth.attitude);
            let (mp, ma) = (&r.tracker.position, &r.tracker.attitude);
            let _ = writeln!(
                out,
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                md(&name(run)),
                md(&r.stage),
                md(&r.model),
                pair(tp.mean, mp.mean),
                pair(tp.sd, mp.sd),
                pair(tp.max, mp.max),
                pair(ta.mean, ma.mean),
                pair(ta.sd, ma.sd),
                pair(ta.max, ma.max),
            );
        }
    }
    out.push('\n');
    // Reduction of the mean error by each compensating model against calibration alone.
    let mut lines = String::new();
    for &run in &runs {
        let group = table_v_group(rows, run);
        let Some(cal) = group.iter().find(|r| r.stage == "calibrated") else {
            continue;
        };
        for c in group
            .iter()
            .filter(|r| r.stage == "compensated" || r.stage == "oracle")
        {
            let pct = |before: f64, after: f64| {
                reduction(before, after).map_or("n/a".into(), |x| format!("{x:.1} %"))
            };
            let (cp, ca) = (&cal.truth, &c.truth);
            let _ = writeln!(
                lines,
                "| {} | {} | {} | {} | {} | {} | {} | {} |",
                md(&name(run)),
                md(&c.model),
                num(cp.position.mean, 3),
                num(ca.position.mean, 3),
                pct(cp.position.mean, ca.position.mean),
                num(cp.attitude.mean, 3),
                num(ca.attitude.mean, 3),
                pct(cp.attitude.mean, ca.attitude.mean),
            );
        }
    }
    if !lines.is_empty() {
        out.push_str(
            "Reduction of the mean true error by compensation (and by the oracle), relative \
             to calibration alone (100 · (calibrated − compensated) / calibrated), scored \
             against the hidden truth:\n\n\
             | Trajectory | Model | Calibrated pos. mean (µm) | Compensated pos. mean (µm) \
             | Pos. reduction | Calibrated att. mean (mdeg) | Compensated att. mean (mdeg) \
             | Att. reduction |\n\
             |---|---|---:|---:|---:|---:|---:|---:|\n",
        );
        out.push_str(&lines);
        out.push('\n');
    }
}

/// The indices of the smallest finite values (ties all count); none for fewer than two.
fn best(values: &[f64]) -> Vec<usize> {
    if values.len() < 2 {
        return Vec::new();
    }
    let min = values
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(f64::INFINITY, f64::min);
    if !min.is_finite() {
        return Vec::new();
    }
    (0..values.len()).filter(|&i| values[i] == min).collect()
}

fn markdown_table_iii(out: &mut String, rows: &[TableIIIRow]) {
    out.push_str("## Table III analog: prediction accuracy on the test split\n\n");
    if rows.is_empty() {
        out.push_str("_No rows._\n\n");
        return;
    }
    out.push_str(
        "Cells are position / attitude; position in µm, attitude in mdeg, MAPE in %. \
         The best model of each row is in bold.\n\n",
    );
    type Pick = fn(&Metrics) -> f64;
    let metric_rows: [(&str, Pick, Pick, usize); 3] = [
        ("MAE (µm / mdeg)", |m| m.pos_mae, |m| m.att_mae, 3),
        ("RMSE (µm / mdeg)", |m| m.pos_rmse, |m| m.att_rmse, 3),
        ("MAPE (% / %)", |m| m.pos_mape, |m| m.att_mape, 2),
    ];
    for t in distinct(rows.iter().map(|r| r.trajectory.as_str())) {
        let of: Vec<&TableIIIRow> = rows.iter().filter(|r| r.trajectory == t).collect();
        let _ = writeln!(out, "### {t}\n");
        out.push_str("| Metric |");
        for r in &of {
            let _ = write!(out, " {} |", md(&r.model));
        }
        out.push_str("\n|---|");
        out.push_str(&"---:|".repeat(of.len()));
        out.push('\n');
        for (label, pos, att, decimals) in metric_rows {
            let p: Vec<f64> = of.iter().map(|r| pos(&r.metrics)).collect();
            let a: Vec<f64> = of.iter().map(|r| att(&r.metrics)).collect();
            let (bp, ba) = (best(&p), best(&a));
            let _ = write!(out, "| {label} |");
            for i in 0..of.len() {
                let cell = |v: f64, bold: bool| {
                    let s = num(v, decimals);
                    if bold {
                        format!("**{s}**")
                    } else {
                        s
                    }
                };
                let _ = write!(
                    out,
                    " {} / {} |",
                    cell(p[i], bp.contains(&i)),
                    cell(a[i], ba.contains(&i))
                );
            }
            out.push('\n');
        }
        out.push_str("| Test windows |");
        for r in &of {
            let _ = write!(out, " {} |", r.metrics.count);
        }
        out.push_str("\n\n");
    }
}

fn markdown_timings(out: &mut String, timings: &[Timing]) {
    out.push_str("## Fig. 10 analog: training and inference time\n\n");
    if timings.is_empty() {
        out.push_str("_No timings._\n\n");
        return;
    }
    out.push_str(
        "| Model | Training (s/epoch) | Inference (ms/window) | Trained on | Inference on |\n\
         |---|---:|---:|---|---|\n",
    );
    for t in timings {
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {} |",
            md(&t.model),
            num(t.epoch_seconds, 3),
            num(t.infer_ms, 3),
            md(&t.trained_on),
            md(&t.inference_on)
        );
    }
    out.push('\n');
}

/// The report at a glance, under its headline: per held-out path, the calibrated
/// controller's mean true error, and the share of it the recommended model (over its
/// seeds) and the oracle remove, mean ± SD over the held-out sessions (and seeds). None
/// without a recommended model or its Table V rows.
pub(super) fn at_a_glance(r: &Report) -> Option<String> {
    let (model, _) = split_name(r.recommended.as_deref()?);
    let rows = &r.table_v;
    let shares = |path: &str, of: &dyn Fn(&TableVRow) -> bool| -> String {
        let s: Vec<[f64; 2]> = rows
            .iter()
            .filter(|row| row.trajectory == path && of(row))
            .filter_map(|row| row.removed_in(rows))
            .collect();
        let spread = |i: usize| Spread::of(&s.iter().map(|v| v[i]).collect::<Vec<_>>());
        format!("{} / {}", spread(0).text(1), spread(1).text(1))
    };
    let mut out = format!(
        "| Held-out path | Calibrated: position (µm) / attitude (mdeg) | {model} removes (%) | the oracle removes (%) |\n|---|---:|---:|---:|\n"
    );
    let mut any = false;
    for path in distinct(rows.iter().map(|row| row.trajectory.as_str())) {
        let cal: Vec<&TableVRow> = rows
            .iter()
            .filter(|row| row.trajectory == path && row.stage == "calibrated")
            .collect();
        if cal.is_empty() {
            continue;
        }
        let mean = |f: &dyn Fn(&TableVRow) -> f64| {
            Spread::of(&cal.iter().map(|row| f(row)).collect::<Vec<_>>()).mean
        };
        let by_model =
            |row: &TableVRow| row.stage == "compensated" && split_name(&row.model).0 == model;
        any |= rows
            .iter()
            .any(|row| row.trajectory == path && by_model(row));
        let _ = writeln!(
            out,
            "| {} | {} / {} | {} | {} |",
            md(path),
            num(mean(&|row| row.truth.position.mean), 1),
            num(mean(&|row| row.truth.attitude.mean), 2),
            shares(path, &by_model),
            shares(path, &|row| row.stage == "oracle"),
        );
    }
    any.then(|| {
        format!(
            "{out}\nAgainst the twin's hidden truth; each share is the mean ± SD over the \
             held-out sessions (and the model's seeds) of the calibrated error removed, \
             position / attitude. The oracle feeds the true residual back at a model's \
             latency, of the tick the correction acts on when the models look ahead: about \
             what online compensation can remove at all.\n"
        )
    })
}

/// The figure shown under the headline.
const KEY_FIGURE: &str = "compensated.png";

/// The Markdown text of the report.
pub fn markdown(r: &Report) -> String {
    let mut out = String::new();
    let title = if r.title.trim().is_empty() {
        "IASTGCN evaluation report"
    } else {
        r.title.trim()
    };
    let _ = writeln!(out, "# {title}\n");
    if let Some(headline) = &r.headline {
        let _ = writeln!(out, "**{headline}**\n");
    }
    if let Some(glance) = at_a_glance(r) {
        let _ = writeln!(out, "{glance}");
    }
    // The key figure under the headline, before the setup and the tables (the file list
    // at the end names it without showing it again).
    let files = plan(r);
    let key = files.iter().find(|e| e.name == KEY_FIGURE);
    if let Some(e) = key {
        let _ = writeln!(out, "![{}]({})\n", e.name, e.name);
    }
    for line in &r.setup {
        let _ = writeln!(out, "- {line}");
    }
    let adapter = if r.adapter.is_empty() {
        "unknown"
    } else {
        &r.adapter
    };
    let _ = writeln!(out, "- Adapter: {adapter}");
    let _ = writeln!(out, "- Wall time: {}\n", duration(r.wall_seconds));
    // Over several seeds the summary (means, SDs, paired comparisons) answers the
    // question, so it comes before the sections and the per-seed tables.
    if let Some(summary) = super::seeds::summarize(r) {
        out.push_str(&super::seeds::markdown(&summary));
    }
    for (heading, body) in &r.sections {
        let _ = writeln!(out, "## {heading}\n\n{}\n", body.trim_end());
    }
    markdown_table_v(&mut out, &r.table_v);
    markdown_table_iii(&mut out, &r.table_iii);
    if !r.curve.is_empty() {
        out.push_str(&super::curve::markdown(&r.curve));
    }
    markdown_timings(&mut out, &r.timings);
    if !r.notes.is_empty() {
        // The run's log: each model's refinement verdict, the corrections the controller
        // refused, findings.
        out.push_str("## Notes\n\n");
        for n in &r.notes {
            let _ = writeln!(out, "- {n}");
        }
        out.push('\n');
    }
    out.push_str("## Files\n\n");
    for e in &files {
        let _ = writeln!(out, "- `{}`: {}", e.name, e.what);
        if e.name.ends_with(".png") && e.name != KEY_FIGURE {
            let _ = writeln!(out, "\n  ![{}]({})\n", e.name, e.name);
        }
    }
    out
}
