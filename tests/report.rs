//! The report folder: every file present and well-formed, the CSV tables exact, the
//! Markdown showing both tables, the best model in bold and the reductions computed right.

use std::path::{Path, PathBuf};

use iastgcn::experiment::report::curve::{CurvePoint, CURVE_HEADER};
use iastgcn::experiment::report::seeds::Spread;
use iastgcn::experiment::report::{
    self, ErrorStats, Report, TableIIIRow, TableVRow, Timing, Trace,
};
use iastgcn::stats::Summary;
use iastgcn::train::{EpochRecord, Metrics};

const TABLE_V_HEADER: &str = "trajectory,held_out_session,stage,model,\
true_pos_mean_um,true_pos_sd_um,true_pos_max_um,true_att_mean_mdeg,true_att_sd_mdeg,true_att_max_mdeg,\
trk_pos_mean_um,trk_pos_sd_um,trk_pos_max_um,trk_att_mean_mdeg,trk_att_sd_mdeg,trk_att_max_mdeg";
const TABLE_III_HEADER: &str =
    "trajectory,model,pos_mae_um,pos_rmse_um,pos_mape_pct,att_mae_mdeg,att_rmse_mdeg,att_mape_pct";
const PNG_SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a];

/// A fresh, empty directory under the system temp dir, removed on drop (kept when
/// `IASTGCN_KEEP_REPORT` is set, to look at the pictures).
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> TempDir {
        let dir =
            std::env::temp_dir().join(format!("iastgcn-report-test-{}-{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        TempDir(dir)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        if std::env::var_os("IASTGCN_KEEP_REPORT").is_some() {
            eprintln!("kept {}", self.0.display());
            return;
        }
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn summary(mean: f64, sd: f64, max: f64) -> Summary {
    Summary {
        mean,
        sd,
        max,
        count: 500,
    }
}

fn stats(pos: (f64, f64, f64), att: (f64, f64, f64)) -> ErrorStats {
    ErrorStats {
        position: summary(pos.0, pos.1, pos.2),
        attitude: summary(att.0, att.1, att.2),
    }
}

/// A row whose tracker statistics are the truth's × 1.25 (so the two are told apart).
fn v_row(trajectory: &str, stage: &str, model: &str, truth: ErrorStats) -> TableVRow {
    let scale = |s: &Summary| summary(1.25 * s.mean, 1.25 * s.sd, 1.25 * s.max);
    TableVRow {
        trajectory: trajectory.into(),
        session: 0,
        stage: stage.into(),
        model: model.into(),
        truth,
        tracker: ErrorStats {
            position: scale(&truth.position),
            attitude: scale(&truth.attitude),
        },
    }
}

fn iii_row(trajectory: &str, model: &str, m: [f64; 6]) -> TableIIIRow {
    TableIIIRow {
        trajectory: trajectory.into(),
        model: model.into(),
        metrics: Metrics {
            count: 321,
            pos_mae: m[0],
            pos_rmse: m[1],
            pos_mape: m[2],
            att_mae: m[3],
            att_rmse: m[4],
            att_mape: m[5],
        },
    }
}

/// A residual cloud around the origin whose radius is `scale` µm.
fn trace(trajectory: &str, label: &str, scale: f64, n: usize) -> Trace {
    Trace {
        trajectory: trajectory.into(),
        label: label.into(),
        points: (0..n)
            .map(|i| {
                let t = i as f64 * 0.01;
                let a = i as f64 * 0.37;
                let r = scale * (0.3 + 0.7 * ((i * 7919) % 101) as f64 / 100.0);
                (t, r * a.cos() + 0.2 * scale, r * a.sin(), 0.5 * r)
            })
            .collect(),
    }
}

fn history(stages: &[(&str, usize)]) -> Vec<EpochRecord> {
    let mut out = Vec::new();
    let mut step = 0;
    for &(stage, epochs) in stages {
        for e in 1..=epochs {
            step += 40;
            out.push(EpochRecord {
                stage: stage.into(),
                epoch: e,
                step,
                train_loss: 1.0 / e as f64 + 0.05,
                val_loss: 1.1 / e as f64 + 0.08,
                lr: 1e-3,
                seconds: 2.5,
                windows_per_s: 800.0,
                validation_seconds: 0.2,
                readback_seconds: 0.01,
                trained_on: "Test GPU (Vulkan)".into(),
            });
        }
    }
    out
}

fn synthetic() -> Report {
    let table_v = vec![
        // Deliberately out of stage order: the Markdown groups them.
        v_row(
            "hilbert",
            "calibrated",
            "-",
            stats((8.0, 3.25, 20.5), (4.0, 1.5, 9.0)),
        ),
        v_row(
            "hilbert",
            "initial",
            "-",
            stats((812.345678, 210.5, 1604.25), (95.4321, 20.0, 170.0)),
        ),
        v_row(
            "hilbert",
            "compensated",
            "iastgcn",
            stats((2.0, 0.75, 5.5), (1.0, 0.5, 2.5)),
        ),
        v_row(
            "hilbert",
            "compensated",
            "lstm",
            stats((6.0, 2.123456, 15.0), (3.0, 1.0, 7.0)),
        ),
        v_row(
            "raster",
            "initial",
            "-",
            stats((640.12344, 150.0, 1200.0), (80.0, 15.0, 140.0)),
        ),
        v_row(
            "raster",
            "calibrated",
            "-",
            stats((10.0, 4.0, 25.0), (5.0, 2.0, 11.0)),
        ),
        v_row(
            "raster",
            "compensated",
            "iastgcn",
            stats((3.333333, 1.0, 7.0), (1.5, 0.6, 3.2)),
        ),
        v_row(
            "raster",
            "compensated",
            "lstm",
            stats((7.5, 3.0, 18.0), (3.5, 1.2, 8.0)),
        ),
    ];
    let table_iii = vec![
        iii_row(
            "hilbert",
            "iastgcn",
            [1.5, 2.25, 12.3456, 0.2, 0.3, 9.87654],
        ),
        iii_row("hilbert", "lstm", [3.0, 4.5, 25.0, 0.4, 0.6, 20.0]),
        iii_row(
            "raster",
            "iastgcn",
            [1.23456789, 1.9, 10.0, 0.25, 0.35, 8.0],
        ),
        iii_row("raster", "lstm", [2.5, 3.75, 22.0, 0.2, 0.5, 18.5]),
    ];
    let timings = vec![
        Timing {
            model: "iastgcn".into(),
            epoch_seconds: 12.5,
            infer_ms: 1.75,
            trained_on: "native CPU (2 threads)".into(),
            inference_on: "native CPU forward".into(),
        },
        Timing {
            model: "lstm".into(),
            epoch_seconds: 4.25,
            infer_ms: 0.5,
            trained_on: "Test GPU (Vulkan)".into(),
            inference_on: "Test GPU (Vulkan)".into(),
        },
    ];
    let traces = vec![
        trace("hilbert", "calibrated", 8.0, 400),
        trace("hilbert", "compensated (iastgcn)", 2.0, 400),
        trace("raster", "calibrated", 10.0, 300),
        trace("raster", "compensated (iastgcn)", 3.0, 300),
    ];
    let before: Vec<(usize, f64, f64)> = (1..=20)
        .map(|k| (k, 0.8 * k as f64, 0.3 * k as f64))
        .collect();
    let after: Vec<(usize, f64, f64)> = (1..=20)
        .map(|k| (k, 0.3 * k as f64, 0.1 * k as f64))
        .collect();
    Report {
        title: "Synthetic evaluation".into(),
        headline: Some("a, the recommended model, removes 50.0 ± 1.0 % of it".into()),
        recommended: Some("a".into()),
        adapter: "Test GPU (Vulkan)".into(),
        setup: vec![
            "config: runs/test.toml".into(),
            "recordings: 2 trajectories, split by trajectory".into(),
        ],
        wall_seconds: 3725.0,
        table_v,
        table_iii,
        timings,
        histories: vec![
            ("iastgcn".into(), history(&[("core", 8), ("refine×4", 3)])),
            ("lstm".into(), history(&[("core", 6)])),
        ],
        traces,
        accumulated: Some((before, after)),
        notes: vec!["The compensated cloud shrinks toward the origin.".into()],
        sections: vec![("Sensor models".into(), "| E1 | a scale |".into())],
        curve: [("iastgcn", 30.0), ("lstm", 36.0)]
            .into_iter()
            .flat_map(|(model, mae)| {
                [(0.25, 1.6), (0.5, 1.2), (1.0, 1.0)].map(|(fraction, k)| CurvePoint {
                    model: model.into(),
                    fraction,
                    windows: (624.0 * fraction) as usize,
                    val_pos: Spread::of(&[k * mae, k * mae + 2.0, k * mae - 2.0]),
                    val_att: Spread::of(&[k * mae / 2.0, k * mae / 2.0 + 1.0]),
                    test_pos: Spread::of(&[k * mae * 1.1]),
                    test_att: Spread::of(&[k * mae * 0.6]),
                })
            })
            .collect(),
    }
}

fn lines(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(str::to_string)
        .collect()
}

fn close(text: &str, value: f64, decimals: i32) {
    let parsed: f64 = text
        .parse()
        .unwrap_or_else(|_| panic!("{text:?} is a number"));
    let tol = 0.5 * 10f64.powi(-decimals) + 1e-9 * value.abs().max(1.0);
    assert!(
        (parsed - value).abs() <= tol,
        "{text} ≠ {value} to {decimals} decimals"
    );
}

#[test]
fn writes_every_file_of_the_report_folder() {
    let tmp = TempDir::new("full");
    let dir = tmp.0.join("nested/report");
    let r = synthetic();
    let written = report::write(&dir, &r).unwrap();

    let expected = [
        "compensated.png",
        "report.md",
        "table_v.csv",
        "table_iii.csv",
        "timings.csv",
        "fig10_timings.png",
        "fig11_hilbert.png",
        "fig11_raster.png",
        "losses.png",
        "losses.csv",
        "learning_curve.png",
        "learning_curve.csv",
        "accumulated.png",
        "accumulated.csv",
    ];
    for name in expected {
        let path = dir.join(name);
        assert!(written.contains(&path), "{name} reported as written");
        let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(!bytes.is_empty(), "{name} is empty");
        if name.ends_with(".png") {
            assert!(bytes.len() > 1000, "{name} is a real picture");
            assert_eq!(bytes[..8], PNG_SIGNATURE, "{name} is a PNG");
        }
    }
    assert_eq!(written.len(), expected.len(), "{written:?}");
    // Every epoch of every history, then the learning curve's points in order.
    let losses = lines(&dir.join("losses.csv"));
    assert_eq!(losses[0], "model,stage,epoch,train_loss,val_loss");
    assert_eq!(losses.len(), 1 + 8 + 3 + 6);
    assert!(losses[9].starts_with("iastgcn,refine×4,1,"), "{losses:?}");
    let curve = lines(&dir.join("learning_curve.csv"));
    assert_eq!(curve[0], CURVE_HEADER);
    assert_eq!(curve.len(), 1 + 6);
    assert!(
        curve[1].starts_with("iastgcn,0.25,156,3,48.0000,2.0000,24.5000,0.7071,52.8000,0.0000,"),
        "{curve:?}"
    );
    // No temporary files left behind.
    for entry in std::fs::read_dir(&dir).unwrap() {
        let name = entry.unwrap().file_name().to_string_lossy().into_owned();
        assert!(!name.starts_with('.'), "leftover {name}");
    }

    // table_v.csv: the header, then one line per row, in order, numbers to 4 decimals.
    let v = lines(&dir.join("table_v.csv"));
    assert_eq!(v[0], TABLE_V_HEADER);
    assert_eq!(v.len(), 1 + r.table_v.len());
    for (line, row) in v[1..].iter().zip(&r.table_v) {
        let cells: Vec<&str> = line.split(',').collect();
        assert_eq!(cells.len(), 16, "{line}");
        let session = row.session.to_string();
        assert_eq!(
            cells[..4],
            [&row.trajectory, &session, &row.stage, &row.model]
        );
        let values = [&row.truth, &row.tracker].into_iter().flat_map(|e| {
            let (p, a) = (&e.position, &e.attitude);
            [p.mean, p.sd, p.max, a.mean, a.sd, a.max]
        });
        for (cell, value) in cells[4..].iter().zip(values) {
            close(cell, value, 4);
            assert_eq!(cell.split('.').nth(1).map(str::len), Some(4), "{cell}");
        }
    }
    assert!(
        v[2].starts_with("hilbert,0,initial,-,812.3457,"),
        "{}",
        v[2]
    );

    // table_iii.csv: 4 decimals for µm/mdeg, 3 for percentages.
    let iii = lines(&dir.join("table_iii.csv"));
    assert_eq!(iii[0], TABLE_III_HEADER);
    assert_eq!(iii.len(), 1 + r.table_iii.len());
    for (line, row) in iii[1..].iter().zip(&r.table_iii) {
        let cells: Vec<&str> = line.split(',').collect();
        assert_eq!(cells.len(), 8, "{line}");
        assert_eq!(cells[..2], [&row.trajectory, &row.model]);
        let m = &row.metrics;
        let values = [
            m.pos_mae, m.pos_rmse, m.pos_mape, m.att_mae, m.att_rmse, m.att_mape,
        ];
        let decimals = [4, 4, 3, 4, 4, 3];
        for ((cell, value), d) in cells[2..].iter().zip(values).zip(decimals) {
            close(cell, value, d);
        }
    }
    assert_eq!(
        iii[1],
        "hilbert,iastgcn,1.5000,2.2500,12.346,0.2000,0.3000,9.877"
    );
    assert_eq!(report::table_v_csv(&r.table_v), v.join("\n") + "\n");
    assert_eq!(report::table_iii_csv(&r.table_iii), iii.join("\n") + "\n");

    let t = lines(&dir.join("timings.csv"));
    assert_eq!(t.len(), 3);
    assert_eq!(
        t[1],
        "iastgcn,12.5000,1.7500,native CPU (2 threads),native CPU forward"
    );

    // The Markdown report.
    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert_eq!(md, report::markdown(&r));
    assert!(md.starts_with(
        "# Synthetic evaluation\n\n**a, the recommended model, removes 50.0 ± 1.0 % of it**\n"
    ));
    // The key figure right under the headline, before the setup; the run's notes at the
    // end, after the tables.
    let figure = md.find("](compensated.png)\n").expect("the key figure");
    let setup = md.find("- config: runs/test.toml").expect("the setup");
    assert!(figure < setup, "the figure comes before the setup");
    let notes = md.find("## Notes").expect("the notes");
    assert!(
        notes > md.find("## Table V analog").unwrap(),
        "the notes after the tables"
    );
    assert!(md.contains("- config: runs/test.toml"));
    assert!(md.contains("Adapter: Test GPU (Vulkan)"));
    assert!(md.contains("1 h 02 min 05 s"), "wall time");
    assert!(md.contains("## Table V analog"));
    assert!(md.contains("## Table III analog"));
    assert!(md.contains("## Fig. 10 analog"));
    assert!(md.contains("The compensated cloud shrinks toward the origin."));
    // Table V rows grouped per trajectory: initial, calibrated, compensated per model;
    // each cell truth / tracker.
    let order: Vec<usize> = [
        "| hilbert | initial | - | 812.3 / 1015.4 |",
        "| hilbert | calibrated | - | 8.0 / 10.0 |",
        "| hilbert | compensated | iastgcn | 2.0 / 2.5 |",
        "| hilbert | compensated | lstm | 6.0 / 7.5 |",
        "| raster | initial | - | 640.1 / 800.2 |",
    ]
    .iter()
    .map(|row| {
        md.find(row)
            .unwrap_or_else(|| panic!("{row} missing:\n{md}"))
    })
    .collect();
    assert!(order.windows(2).all(|w| w[0] < w[1]), "{order:?}");
    // Reduction of the mean position error vs calibrated: (8 − 2) / 8 = 75 %,
    // (8 − 6) / 8 = 25 %; attitude (4 − 1) / 4 = 75 %.
    assert!(
        md.contains("| hilbert | iastgcn | 8.000 | 2.000 | 75.0 % | 4.000 | 1.000 | 75.0 % |"),
        "{md}"
    );
    assert!(md.contains("| hilbert | lstm | 8.000 | 6.000 | 25.0 % |"));
    // (10 − 3.333333) / 10 = 66.67 %.
    assert!(md.contains("| raster | iastgcn | 10.000 | 3.333 | 66.7 % |"));
    // Table III: models as columns, best in bold per row and component.
    assert!(
        md.contains("### hilbert\n\n| Metric | iastgcn | lstm |\n"),
        "{md}"
    );
    assert!(md.contains("| MAE (µm / mdeg) | **1.500** / **0.200** | 3.000 / 0.400 |"));
    assert!(md.contains("| MAPE (% / %) | **12.35** / **9.88** | 25.00 / 20.00 |"));
    // raster: iastgcn best in position, lstm in attitude MAE.
    assert!(md.contains("| MAE (µm / mdeg) | **1.235** / 0.250 | 2.500 / **0.200** |"));
    // Fig. 10 table.
    assert!(md.contains("| iastgcn | 12.500 | 1.750 | native CPU (2 threads) |"));
    // Every file listed, the PNGs linked as images.
    for name in expected {
        assert!(md.contains(&format!("- `{name}`: ")), "{name} listed");
        if name.ends_with(".png") {
            assert!(md.contains(&format!("![{name}]({name})")), "{name} linked");
        }
    }
}

#[test]
fn an_empty_report_still_writes_the_tables() {
    let tmp = TempDir::new("empty");
    let r = Report::default();
    let written = report::write(&tmp.0, &r).unwrap();
    for name in ["report.md", "table_v.csv", "table_iii.csv", "timings.csv"] {
        let path = tmp.0.join(name);
        assert!(written.contains(&path), "{name}");
        assert!(std::fs::metadata(&path).unwrap().len() > 0, "{name}");
    }
    assert_eq!(
        std::fs::read_to_string(tmp.0.join("table_v.csv")).unwrap(),
        format!("{TABLE_V_HEADER}\n")
    );
    assert_eq!(
        std::fs::read_to_string(tmp.0.join("table_iii.csv")).unwrap(),
        format!("{TABLE_III_HEADER}\n")
    );
    for path in &written {
        assert!(path.exists(), "{}", path.display());
        assert_ne!(path.extension().unwrap(), "png", "nothing to plot");
    }
    let md = std::fs::read_to_string(tmp.0.join("report.md")).unwrap();
    assert!(md.contains("## Table V analog"));
    assert!(md.contains("## Table III analog"));
    // Writing again over the same folder works (atomic replacement).
    report::write(&tmp.0, &r).unwrap();
}

#[test]
fn one_model_gets_no_bold_and_odd_names_get_safe_file_names() {
    let tmp = TempDir::new("odd");
    let r = Report {
        table_iii: vec![iii_row(
            "hilbert",
            "iastgcn",
            [1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
        )],
        traces: vec![trace("a/b c", "calibrated", 5.0, 50)],
        timings: vec![Timing {
            model: "iastgcn".into(),
            epoch_seconds: 1.0,
            infer_ms: 0.25,
            trained_on: "cpu".into(),
            inference_on: "native CPU forward".into(),
        }],
        ..Report::default()
    };
    let written = report::write(&tmp.0, &r).unwrap();
    assert!(
        written.contains(&tmp.0.join("fig11_a_b_c.png")),
        "{written:?}"
    );
    assert!(written.contains(&tmp.0.join("fig10_timings.png")));
    let md = report::markdown(&r);
    assert!(!md.contains("**"), "{md}");
}

/// The terminal tables keep their columns with model names longer than the default
/// width (a seed suffix, a file stem): every line of Table V's ends at one column, and
/// the units line puts "(µm)" over the position numbers.
#[test]
fn terminal_tables_stay_aligned_with_long_model_names() {
    let e = stats((68.1, 30.2, 150.7), (20.5, 9.1, 48.3));
    let rows = vec![
        v_row("hilbert", "calibrated", "-", e),
        v_row("hilbert", "compensated", "iastgcn", e),
        v_row(
            "hilbert",
            "compensated",
            "iastgcn-s.seed3-refined.train25",
            e,
        ),
    ];
    let lines = report::table_v_lines(&rows);
    let width = |l: &str| l.chars().count();
    let data: Vec<&String> = lines.iter().skip(2).collect();
    assert_eq!(data.len(), 6);
    for l in &data {
        assert_eq!(width(l), width(&lines[0]), "{lines:#?}");
    }
    // "(µm)" ends where the position max column ends.
    let max_end = |l: &str| l.find("150.7").map(|b| l[..b].chars().count()).unwrap() + 5;
    let units_end = lines[1]
        .find("(µm)")
        .map(|b| lines[1][..b].chars().count())
        .unwrap()
        + 4;
    assert_eq!(units_end, max_end(data[0]), "{lines:#?}");

    let iii = [
        iii_row("hilbert", "iastgcn", [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]),
        iii_row(
            "hilbert",
            "iastgcn-s.seed3-refined.train25",
            [1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
        ),
    ];
    let lines = report::table_iii_lines(&iii);
    assert_eq!(width(&lines[0]), width(&lines[1]), "{lines:#?}");
}

/// Under the headline, the report at a glance: per held-out path the calibrated error and
/// the share of it the recommended model (grouped over its seeds) and the oracle remove,
/// before the key figure and the setup.
#[test]
fn the_report_opens_with_the_recommended_model_beside_the_oracle() {
    let mut r = synthetic();
    r.recommended = Some("iastgcn.seed2".into());
    r.table_v.push(v_row(
        "hilbert",
        "oracle",
        "true residual",
        stats((1.0, 0.5, 2.0), (0.5, 0.2, 1.0)),
    ));
    r.table_v.push(v_row(
        "hilbert",
        "compensated",
        "iastgcn.seed2",
        stats((4.0, 1.0, 6.0), (2.0, 0.5, 3.0)),
    ));
    let md = report::markdown(&r);
    let glance = md.find("| Held-out path |").expect("the table at a glance");
    assert!(glance < md.find("](compensated.png)").unwrap(), "{md}");
    assert!(
        md.contains("| Held-out path | Calibrated: position (µm) / attitude (mdeg) | iastgcn removes (%) | the oracle removes (%) |"),
        "{md}"
    );
    // Hilbert: 8 µm / 4 mdeg calibrated; iastgcn (its two rows, seeds grouped) leaves 2
    // and 4 µm, 1 and 2 mdeg: 75 and 50 %; the oracle leaves 1 µm / 0.5 mdeg.
    assert!(
        md.contains(
            "| hilbert | 8.0 / 4.00 | 62.5 ± 17.7 / 62.5 ± 17.7 | 87.5 ± 0.0 / 87.5 ± 0.0 |"
        ),
        "{md}"
    );
    // The raster has no oracle row: said, not invented.
    assert!(
        md.contains("| raster | 10.0 / 5.00 | 66.7 ± 0.0 / 70.0 ± 0.0 | n/a / n/a |"),
        "{md}"
    );
    // Without a recommended model there is no such table.
    r.recommended = None;
    assert!(!report::markdown(&r).contains("| Held-out path |"));
}
