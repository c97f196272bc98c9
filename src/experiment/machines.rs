//! Spread over twin machines: several `iastgcn reproduce` folders of one protocol, each
//! run on its own twin machine (`--machine-seed`: its own geometric and non-geometric
//! errors, calibration, training data and held-out session), merged by `iastgcn
//! reproduce --merge`. One sample is one (machine, training seed) pair; Tables V and III
//! become mean ± SD over every pair, the share of the calibrated error removed is taken
//! against each machine's own calibrated run, and every model is compared with IASTGCN
//! pair by pair (same machine, same seed, same split and held-out runs).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::report::seeds::{beyond_spread_cells, pair_up, paired_rows, split_name, Paired, Spread};
use super::reproduce::Protocol;
use crate::atomic::Batch;
use crate::error::{Error, Result};
use crate::train::log::{csv_text, distinct, read_rows};

/// One line of a folder's `table_v.csv` (the columns the merge reads).
#[derive(Deserialize)]
struct VLine {
    trajectory: String,
    /// Absent in folders written before there were several held-out sessions: 0.
    #[serde(default)]
    held_out_session: usize,
    stage: String,
    model: String,
    true_pos_mean_um: f64,
    true_att_mean_mdeg: f64,
}

/// One line of a folder's `table_iii.csv` (the columns the merge reads).
#[derive(Deserialize)]
struct IIILine {
    trajectory: String,
    model: String,
    pos_mae_um: f64,
    att_mae_mdeg: f64,
}

/// A value of one model on one path, keyed by (machine, seed, held-out session; Table III: session 0).
type BySample = Vec<((u64, u64, usize), f64)>;

/// Table V of one model on one held-out path over every (machine, seed) pair.
#[derive(Clone, Debug, PartialEq)]
pub struct MachineRowV {
    /// The held-out path.
    pub trajectory: String,
    /// The model (group) name.
    pub model: String,
    /// Mean true position error of the run, µm.
    pub truth_pos: Spread,
    /// Mean true attitude error of the run, mdeg.
    pub truth_att: Spread,
    /// Share of the same machine's calibrated mean true position error removed, %.
    pub pos_removed: Spread,
    /// The same for attitude, %.
    pub att_removed: Spread,
    /// SD over machines of each machine's mean share removed (position, %): how much of
    /// the spread is the machine's rather than the seed's.
    pub pos_removed_machine_sd: f64,
}

/// Table III of one model on one path over every (machine, seed) pair.
#[derive(Clone, Debug, PartialEq)]
pub struct MachineRowIII {
    /// The training recording whose test block was scored.
    pub trajectory: String,
    /// The model (group) name.
    pub model: String,
    /// Position MAE, µm.
    pub pos_mae: Spread,
    /// Attitude MAE, mdeg.
    pub att_mae: Spread,
}

/// Tables V and III over machines and seeds, and the paired comparisons.
#[derive(Clone, Debug, PartialEq)]
pub struct MachineSummary {
    /// Each folder and its machine, in the order given.
    pub folders: Vec<(PathBuf, u64)>,
    /// The model the others are compared with (`iastgcn`, or the first).
    pub main: String,
    /// Each machine's calibrated run per held-out path: (path, machine, position µm,
    /// attitude mdeg).
    pub calibrated: Vec<(String, u64, f64, f64)>,
    /// Table V over (machine, seed) pairs.
    pub table_v: Vec<MachineRowV>,
    /// Table III over (machine, seed) pairs.
    pub table_iii: Vec<MachineRowIII>,
    /// Every other model against the main one, pair by pair.
    pub paired: Vec<Paired>,
}

fn read_csv<T: serde::de::DeserializeOwned>(path: &Path) -> Result<Vec<T>> {
    if !path.exists() {
        return Err(Error::Invalid(format!(
            "{}: missing: the folder's reproduce run has not written its report yet",
            path.display()
        )));
    }
    read_rows(path)
}

fn read_protocol(folder: &Path) -> Result<Protocol> {
    let path = folder.join("protocol.toml");
    let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
    toml::from_str(&text).map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))
}

/// Reads the report folders of `iastgcn reproduce` runs in `folders` (at least two, one
/// protocol, each on another twin machine) and summarises them.
pub fn summarize_machines(folders: &[PathBuf]) -> Result<MachineSummary> {
    if folders.len() < 2 {
        return Err(Error::Invalid(
            "a merge takes at least two reproduce folders, one per twin machine".into(),
        ));
    }
    let first = read_protocol(&folders[0])?;
    let mut machines: Vec<(PathBuf, u64)> = Vec::new();
    let (mut v_lines, mut iii_lines) = (Vec::new(), Vec::new());
    for folder in folders {
        let p = read_protocol(folder)?;
        if !p.same_but_machine(&first) {
            return Err(Error::Invalid(format!(
                "{}: another protocol than {} (minutes, seeds, models or run config differ): \
                 only runs of one protocol on different machines merge",
                folder.join("protocol.toml").display(),
                folders[0].join("protocol.toml").display()
            )));
        }
        if let Some((other, _)) = machines.iter().find(|(_, m)| *m == p.machine_seed) {
            return Err(Error::Invalid(format!(
                "{}: twin machine {} again (also {}); each folder must be another machine",
                folder.display(),
                p.machine_seed,
                other.display()
            )));
        }
        machines.push((folder.clone(), p.machine_seed));
        v_lines.push(read_csv::<VLine>(&folder.join("table_v.csv"))?);
        iii_lines.push(read_csv::<IIILine>(&folder.join("table_iii.csv"))?);
    }
    let sample = |m: u64, model: &str, session: usize| {
        let (group, seed) = split_name(model);
        (group.to_string(), (m, seed.unwrap_or(0), session))
    };
    // Every value keyed by (path, group), then (machine, seed).
    let mut calibrated = Vec::new();
    let mut v: Vec<(String, String, BySample, BySample, BySample, BySample)> = Vec::new();
    for ((_, m), lines) in machines.iter().zip(&v_lines) {
        for c in lines.iter().filter(|l| l.stage == "calibrated") {
            calibrated.push((
                c.trajectory.clone(),
                (*m, c.held_out_session),
                c.true_pos_mean_um,
                c.true_att_mean_mdeg,
            ));
        }
        for l in lines.iter().filter(|l| l.stage == "compensated") {
            let (group, key) = sample(*m, &l.model, l.held_out_session);
            let before = calibrated
                .iter()
                .find(|c| c.0 == l.trajectory && c.1 == (*m, l.held_out_session))
                .ok_or_else(|| {
                    Error::Invalid(format!(
                        "machine {m}: table_v.csv has no calibrated row for {}",
                        l.trajectory
                    ))
                })?;
            // A calibrated run without error has no share to remove (NaN, shown as n/a).
            let removed = |b: f64, a: f64| {
                if b > 0.0 {
                    100.0 * (b - a) / b
                } else {
                    f64::NAN
                }
            };
            let at = match v.iter().position(|r| r.0 == l.trajectory && r.1 == group) {
                Some(i) => i,
                None => {
                    v.push((l.trajectory.clone(), group, vec![], vec![], vec![], vec![]));
                    v.len() - 1
                }
            };
            let row = &mut v[at];
            row.2.push((key, l.true_pos_mean_um));
            row.3.push((key, l.true_att_mean_mdeg));
            row.4.push((key, removed(before.2, l.true_pos_mean_um)));
            row.5.push((key, removed(before.3, l.true_att_mean_mdeg)));
        }
    }
    let mut iii: Vec<(String, String, BySample, BySample)> = Vec::new();
    for ((_, m), lines) in machines.iter().zip(&iii_lines) {
        for l in lines.iter().filter(|l| split_name(&l.model).1.is_some()) {
            let (group, key) = sample(*m, &l.model, 0);
            let at = match iii.iter().position(|r| r.0 == l.trajectory && r.1 == group) {
                Some(i) => i,
                None => {
                    iii.push((l.trajectory.clone(), group, vec![], vec![]));
                    iii.len() - 1
                }
            };
            iii[at].2.push((key, l.pos_mae_um));
            iii[at].3.push((key, l.att_mae_mdeg));
        }
    }
    let spread = |values: &BySample| Spread::of(&values.iter().map(|v| v.1).collect::<Vec<_>>());
    let machine_sd = |values: &BySample| {
        let means: Vec<f64> = machines
            .iter()
            .filter_map(|(_, m)| {
                let of: Vec<f64> = values
                    .iter()
                    .filter(|v| v.0 .0 == *m)
                    .map(|v| v.1)
                    .collect();
                (!of.is_empty()).then(|| Spread::of(&of).mean)
            })
            .collect();
        Spread::of(&means).sd
    };
    let groups: Vec<String> = distinct(v.iter().map(|r| r.1.as_str()))
        .into_iter()
        .map(String::from)
        .collect();
    let main = groups
        .iter()
        .find(|g| *g == "iastgcn")
        .or(groups.first())
        .cloned()
        .unwrap_or_default();
    let mut paired = Vec::new();
    for g in groups.iter().filter(|g| **g != main) {
        for r in iii.iter().filter(|r| &r.1 == g) {
            if let Some(m) = iii.iter().find(|x| x.0 == r.0 && x.1 == main) {
                paired.extend(pair_up("III pos MAE", &r.0, g, &m.2, &r.2));
                paired.extend(pair_up("III att MAE", &r.0, g, &m.3, &r.3));
            }
        }
        for r in v.iter().filter(|r| &r.1 == g) {
            if let Some(m) = v.iter().find(|x| x.0 == r.0 && x.1 == main) {
                paired.extend(pair_up("V true pos", &r.0, g, &m.2, &r.2));
                paired.extend(pair_up("V true att", &r.0, g, &m.3, &r.3));
            }
        }
    }
    let table_v = v
        .iter()
        .map(|r| MachineRowV {
            trajectory: r.0.clone(),
            model: r.1.clone(),
            truth_pos: spread(&r.2),
            truth_att: spread(&r.3),
            pos_removed: spread(&r.4),
            att_removed: spread(&r.5),
            pos_removed_machine_sd: machine_sd(&r.4),
        })
        .collect();
    Ok(MachineSummary {
        folders: machines,
        main,
        // The first held-out session's calibrated runs.
        calibrated: calibrated
            .into_iter()
            .filter(|c| c.1 .1 == 0)
            .map(|(t, (m, _), p, a)| (t, m, p, a))
            .collect(),
        table_v,
        table_iii: iii
            .iter()
            .map(|r| MachineRowIII {
                trajectory: r.0.clone(),
                model: r.1.clone(),
                pos_mae: spread(&r.2),
                att_mae: spread(&r.3),
            })
            .collect(),
        paired,
    })
}

impl MachineSummary {
    /// The Markdown report, the merged folder's entry point.
    pub fn markdown(&self) -> String {
        let mut out = String::from("# Spread over twin machines\n\n");
        for (folder, m) in &self.folders {
            let _ = writeln!(out, "- twin machine {m}: `{}`", folder.display());
        }
        out.push_str(
            "\nEvery folder ran the same protocol on its own twin machine (geometric and \
             non-geometric errors, calibration, training data, held-out session). A cell is \
             the mean ± sample SD over every (machine, training seed) pair; the share removed \
             is against the same machine's calibrated run. A mean is bold only where it is \
             the column's smallest and its gap to the next exceeds the larger of their SDs. \
             \"Machine SD\" is the SD over machines of each machine's mean share removed.\n\n",
        );
        out.push_str(
            "## Calibrated runs per machine (mean true error, µm / mdeg)\n\n\
             | Trajectory | Machine | Position | Attitude |\n|---|---:|---:|---:|\n",
        );
        for (t, m, p, a) in &self.calibrated {
            let _ = writeln!(out, "| {t} | {m} | {p:.1} | {a:.2} |");
        }
        if let Some(goal) = self
            .table_v
            .iter()
            .find(|r| r.trajectory == "hilbert" && r.model == self.main)
        {
            let _ = writeln!(
                out,
                "\nOn the held-out Hilbert run, {} removes {} % of the calibrated mean true \
                 position error (goal: 65 %) and {} % of the attitude error (goal: 80 %), over \
                 machines and seeds.",
                self.main,
                goal.pos_removed.text(1),
                goal.att_removed.text(1)
            );
        }
        out.push_str(
            "\n## Table V over machines and seeds: compensated error against the hidden truth\n\n\
             | Trajectory | Model | n | Pos. mean (µm) | Att. mean (mdeg) | Pos. removed (%) | Machine SD (%) | Att. removed (%) |\n\
             |---|---|---:|---:|---:|---:|---:|---:|\n",
        );
        for t in distinct(self.table_v.iter().map(|r| r.trajectory.as_str())) {
            let rows: Vec<&MachineRowV> =
                self.table_v.iter().filter(|r| r.trajectory == t).collect();
            let p = beyond_spread_cells(&rows.iter().map(|r| r.truth_pos).collect::<Vec<_>>(), 1);
            let a = beyond_spread_cells(&rows.iter().map(|r| r.truth_att).collect::<Vec<_>>(), 2);
            for (i, r) in rows.iter().enumerate() {
                let _ = writeln!(
                    out,
                    "| {t} | {} | {} | {} | {} | {} | {:.1} | {} |",
                    r.model,
                    r.truth_pos.n,
                    p[i],
                    a[i],
                    r.pos_removed.text(1),
                    r.pos_removed_machine_sd,
                    r.att_removed.text(1)
                );
            }
        }
        out.push_str(
            "\n## Table III over machines and seeds: prediction error on the test split\n\n\
             | Trajectory | Model | n | Pos. MAE (µm) | Att. MAE (mdeg) |\n|---|---|---:|---:|---:|\n",
        );
        for t in distinct(self.table_iii.iter().map(|r| r.trajectory.as_str())) {
            let rows: Vec<&MachineRowIII> = self
                .table_iii
                .iter()
                .filter(|r| r.trajectory == t)
                .collect();
            let p = beyond_spread_cells(&rows.iter().map(|r| r.pos_mae).collect::<Vec<_>>(), 2);
            let a = beyond_spread_cells(&rows.iter().map(|r| r.att_mae).collect::<Vec<_>>(), 2);
            for (i, r) in rows.iter().enumerate() {
                let _ = writeln!(
                    out,
                    "| {t} | {} | {} | {} | {} |",
                    r.model, r.pos_mae.n, p[i], a[i]
                );
            }
        }
        let _ = writeln!(
            out,
            "\n## Paired comparison with {main}\n\n\
             Pair by pair (same machine, same seed): in how many pairs {main}'s error is \
             smaller, and the other model's error minus {main}'s as mean ± SD (positive: \
             {main} is better). `better` / `worse` where the mean difference exceeds its SD.\n\n\
             | Measure | Trajectory | Model | {main} wins | Difference | Verdict |\n\
             |---|---|---|---:|---:|---|",
            main = self.main
        );
        out.push_str(&paired_rows(&self.main, &self.paired));
        out
    }

    /// `table_v_machines.csv`: one line per path and model.
    pub fn table_v_csv(&self) -> String {
        let f = |x: f64| format!("{x:.4}");
        csv_text(
            "trajectory,model,samples,true_pos_mean_um,true_pos_sd_um,true_att_mean_mdeg,\
             true_att_sd_mdeg,pos_removed_mean_pct,pos_removed_sd_pct,pos_removed_machine_sd_pct,\
             att_removed_mean_pct,att_removed_sd_pct",
            self.table_v
                .iter()
                .map(|r| {
                    vec![
                        r.trajectory.clone(),
                        r.model.clone(),
                        r.truth_pos.n.to_string(),
                        f(r.truth_pos.mean),
                        f(r.truth_pos.sd),
                        f(r.truth_att.mean),
                        f(r.truth_att.sd),
                        f(r.pos_removed.mean),
                        f(r.pos_removed.sd),
                        f(r.pos_removed_machine_sd),
                        f(r.att_removed.mean),
                        f(r.att_removed.sd),
                    ]
                })
                .collect(),
        )
    }

    /// `table_iii_machines.csv`: one line per path and model.
    pub fn table_iii_csv(&self) -> String {
        let f = |x: f64| format!("{x:.4}");
        csv_text(
            "trajectory,model,samples,pos_mae_mean_um,pos_mae_sd_um,att_mae_mean_mdeg,att_mae_sd_mdeg",
            self.table_iii
                .iter()
                .map(|r| {
                    vec![
                        r.trajectory.clone(),
                        r.model.clone(),
                        r.pos_mae.n.to_string(),
                        f(r.pos_mae.mean),
                        f(r.pos_mae.sd),
                        f(r.att_mae.mean),
                        f(r.att_mae.sd),
                    ]
                })
                .collect(),
        )
    }

    /// `paired_machines.csv`: one line per comparison.
    pub fn paired_csv(&self) -> String {
        csv_text(
            "measure,trajectory,model,main,samples,main_wins,difference_mean,difference_sd,verdict",
            self.paired
                .iter()
                .map(|p| {
                    vec![
                        p.measure.clone(),
                        p.trajectory.clone(),
                        p.model.clone(),
                        self.main.clone(),
                        p.difference.n.to_string(),
                        p.wins.to_string(),
                        format!("{:.4}", p.difference.mean),
                        format!("{:.4}", p.difference.sd),
                        p.verdict().into(),
                    ]
                })
                .collect(),
        )
    }
}

/// Merges the reproduce folders `folders` into `out` (created if missing):
/// the Markdown report, `table_v_machines.csv`, `table_iii_machines.csv` and
/// `paired_machines.csv`, replaced together.
pub fn merge_machines(folders: &[PathBuf], out: &Path) -> Result<MachineSummary> {
    let summary = summarize_machines(folders)?;
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let mut batch = Batch::new();
    for (name, text) in [
        ("report.md", summary.markdown()),
        ("table_v_machines.csv", summary.table_v_csv()),
        ("table_iii_machines.csv", summary.table_iii_csv()),
        ("paired_machines.csv", summary.paired_csv()),
    ] {
        let path = out.join(name);
        batch
            .add(&path, text.as_bytes())
            .map_err(|e| Error::io(&path, e))?;
    }
    batch.commit().map_err(|e| Error::io(out, e))?;
    Ok(summary)
}
