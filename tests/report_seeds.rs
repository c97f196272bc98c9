//! The report's spread over training seeds: models named `<model>.seed<k>` grouped,
//! mean ± sample SD per cell, the share of the calibrated error removed, the paired
//! comparison with IASTGCN (wins, difference, verdict), the bold rule and the CSV files.

use iastgcn::experiment::report::seeds::{self, split_name, Spread};
use iastgcn::experiment::report::{self, ErrorStats, Report, TableIIIRow, TableVRow};
use iastgcn::stats::Summary;
use iastgcn::train::Metrics;

fn summary(mean: f64) -> Summary {
    Summary {
        mean,
        sd: 1.0,
        max: 2.0 * mean,
        count: 100,
    }
}

fn v_row(trajectory: &str, stage: &str, model: &str, pos: f64, att: f64) -> TableVRow {
    let stats = |k: f64| ErrorStats {
        position: summary(k * pos),
        attitude: summary(k * att),
    };
    TableVRow {
        trajectory: trajectory.into(),
        session: 0,
        stage: stage.into(),
        model: model.into(),
        truth: stats(1.0),
        tracker: stats(1.1),
    }
}

fn iii_row(trajectory: &str, model: &str, pos_mae: f64, att_mae: f64) -> TableIIIRow {
    TableIIIRow {
        trajectory: trajectory.into(),
        model: model.into(),
        metrics: Metrics {
            count: 28,
            pos_mae,
            pos_rmse: 1.5 * pos_mae,
            pos_mape: 10.0,
            att_mae,
            att_rmse: 1.5 * att_mae,
            att_mape: 12.0,
        },
    }
}

/// IASTGCN (seeds 1–3) against an ablation that is worse in every seed on position and
/// mixed on attitude, and a baseline trained with seeds 1 and 2 only.
fn seeded_report() -> Report {
    let (main_pos, main_att) = ([40.0, 44.0, 42.0], [20.0, 26.0, 23.0]);
    let (abl_pos, abl_att) = ([50.0, 53.0, 49.0], [22.0, 24.0, 23.5]);
    let mut table_v = vec![v_row("hilbert", "calibrated", "-", 100.0, 50.0)];
    let mut table_iii = Vec::new();
    for s in 0..3 {
        let seed = s + 1;
        table_v.push(v_row(
            "hilbert",
            "compensated",
            &format!("iastgcn.seed{seed}"),
            main_pos[s],
            main_att[s],
        ));
        table_v.push(v_row(
            "hilbert",
            "compensated",
            &format!("iastgcn-s.seed{seed}"),
            abl_pos[s],
            abl_att[s],
        ));
        table_iii.push(iii_row(
            "grid",
            &format!("iastgcn.seed{seed}"),
            main_pos[s] / 2.0,
            main_att[s] / 2.0,
        ));
        table_iii.push(iii_row(
            "grid",
            &format!("iastgcn-s.seed{seed}"),
            abl_pos[s] / 2.0,
            abl_att[s] / 2.0,
        ));
    }
    for seed in [1, 2] {
        table_v.push(v_row(
            "hilbert",
            "compensated",
            &format!("mlp.seed{seed}"),
            90.0,
            60.0,
        ));
    }
    Report {
        table_v,
        table_iii,
        ..Report::default()
    }
}

fn close(a: f64, b: f64) {
    assert!((a - b).abs() < 1e-9, "{a} vs {b}");
}

#[test]
fn names_split_into_model_and_seed() {
    assert_eq!(split_name("iastgcn.seed2"), ("iastgcn", Some(2)));
    assert_eq!(split_name("iastgcn-s.seed13"), ("iastgcn-s", Some(13)));
    assert_eq!(split_name("iastgcn"), ("iastgcn", None));
    assert_eq!(split_name("a.seedx"), ("a.seedx", None));
    assert_eq!(split_name(".seed1"), (".seed1", None));
    assert_eq!(seeds::seeded_name("erc", 3), "erc.seed3");
    let s = Spread::of(&[1.0, 2.0, 6.0]);
    close(s.mean, 3.0);
    close(s.sd, 7.0f64.sqrt()); // sample SD: (4 + 1 + 9) / 2
    assert_eq!(Spread::of(&[5.0]).sd, 0.0);
}

/// One naming scheme for checkpoints: the refined model is `<name>.safetensors`, its core
/// stage `<name>.core.safetensors`; an older demo's `<model>.seed<k>-refined` is read as
/// the seeded model, and nothing else loses a `-refined`.
#[test]
fn checkpoint_names_follow_one_scheme() {
    use iastgcn::experiment::protocol::ModelFiles;
    use iastgcn::experiment::report::seeds::model_name;
    let f = ModelFiles::named(std::path::Path::new("m"), "iastgcn.seed2", true);
    assert_eq!(
        f.refined,
        std::path::Path::new("m/iastgcn.seed2.safetensors")
    );
    assert_eq!(
        f.core,
        std::path::Path::new("m/iastgcn.seed2.core.safetensors")
    );
    assert_eq!(model_name("iastgcn.seed2-refined"), "iastgcn.seed2");
    assert_eq!(
        split_name(model_name("iastgcn-s.seed3-refined")),
        ("iastgcn-s", Some(3))
    );
    assert_eq!(model_name("iastgcn.seed2"), "iastgcn.seed2");
    assert_eq!(model_name("iastgcn.seed2.core"), "iastgcn.seed2.core");
    assert_eq!(model_name("my-refined"), "my-refined");
    assert_eq!(model_name("iastgcn-refined"), "iastgcn-refined");
}

#[test]
fn one_seed_per_model_has_no_summary() {
    let r = Report {
        table_v: vec![
            v_row("hilbert", "calibrated", "-", 100.0, 50.0),
            v_row("hilbert", "compensated", "iastgcn", 40.0, 20.0),
            v_row("hilbert", "compensated", "mlp.seed1", 45.0, 25.0),
        ],
        ..Report::default()
    };
    assert!(seeds::summarize(&r).is_none());
    let tmp = std::env::temp_dir().join(format!("iastgcn-seeds-none-{}", std::process::id()));
    let written = report::write(&tmp, &r).unwrap();
    assert!(written.iter().all(|p| !p.ends_with("paired.csv")));
    let text = std::fs::read_to_string(tmp.join("report.md")).unwrap();
    assert!(!text.contains("Spread over training seeds"));
    let _ = std::fs::remove_dir_all(&tmp);
}

#[test]
fn seeds_summarise_into_spread_and_paired_comparisons() {
    let r = seeded_report();
    let s = seeds::summarize(&r).unwrap();
    assert_eq!(s.main, "iastgcn");
    assert_eq!(
        s.groups,
        vec![
            ("iastgcn".to_string(), vec![1, 2, 3]),
            ("iastgcn-s".to_string(), vec![1, 2, 3]),
            ("mlp".to_string(), vec![1, 2]),
        ]
    );
    let row = |model: &str| {
        s.table_v
            .iter()
            .find(|r| r.trajectory == "hilbert" && r.model == model)
            .unwrap()
    };
    let main = row("iastgcn");
    close(main.truth_pos.mean, 42.0);
    close(main.truth_pos.sd, 2.0);
    close(main.tracker_pos.mean, 1.1 * 42.0);
    // 100 → 40, 44, 42 µm: 60, 56, 58 % removed.
    close(main.pos_removed.mean, 58.0);
    close(main.pos_removed.sd, 2.0);
    // 50 → 20, 26, 23 mdeg: 60, 48, 54 %.
    close(main.att_removed.mean, 54.0);
    assert_eq!(row("mlp").truth_pos.n, 2);
    let grid = s.table_iii.iter().find(|r| r.model == "iastgcn-s").unwrap();
    close(grid.pos_mae.mean, 152.0 / 6.0);
    close(grid.pos_rmse.mean, 1.5 * 152.0 / 6.0);

    let paired = |measure: &str, model: &str| {
        s.paired
            .iter()
            .find(|p| p.measure == measure && p.model == model)
            .unwrap_or_else(|| panic!("{measure} {model}"))
    };
    // Position: the ablation is worse by 10, 9, 7 µm: 3 wins, better beyond the spread.
    let p = paired("V true pos", "iastgcn-s");
    assert_eq!((p.wins, p.difference.n), (3, 3));
    close(p.difference.mean, 26.0 / 3.0);
    assert_eq!(p.verdict(), "better");
    // Attitude: +2, −2, +0.5 mdeg: 2 wins, within the spread.
    let a = paired("V true att", "iastgcn-s");
    assert_eq!(a.wins, 2);
    close(a.difference.mean, 0.5 / 3.0);
    assert_eq!(a.verdict(), "within spread");
    // Table III at half the scale: the same verdicts.
    assert_eq!(paired("III pos MAE", "iastgcn-s").verdict(), "better");
    // The baseline shares seeds 1 and 2 only.
    let m = paired("V true pos", "mlp");
    assert_eq!((m.wins, m.difference.n), (2, 2));
    close(m.difference.mean, 90.0 - 42.0);
    // No comparison of IASTGCN with itself, none for a path a model never ran.
    assert!(s.paired.iter().all(|p| p.model != "iastgcn"));
    assert!(!s
        .paired
        .iter()
        .any(|p| p.model == "mlp" && p.measure.starts_with("III")));
}

#[test]
fn the_report_shows_the_spread_and_bolds_only_beyond_it() {
    let r = seeded_report();
    let tmp = std::env::temp_dir().join(format!("iastgcn-seeds-{}", std::process::id()));
    let written = report::write(&tmp, &r).unwrap();
    for name in ["table_v_seeds.csv", "table_iii_seeds.csv", "paired.csv"] {
        assert!(written.contains(&tmp.join(name)), "{name}");
    }
    let text = std::fs::read_to_string(tmp.join("report.md")).unwrap();
    assert!(text.contains("## Spread over training seeds"), "{text}");
    // The answer first: the summary over seeds comes before the per-seed tables.
    let at = |heading: &str| text.find(heading).unwrap_or_else(|| panic!("{heading}"));
    assert!(at("## Spread over training seeds") < at("## Table V analog"));
    // Position: 42 ± 2 against 50.7 ± 2.1 and 90 ± 0: the gap exceeds both SDs.
    assert!(
        text.contains("| hilbert | iastgcn | **42.0 ± 2.0** |"),
        "{text}"
    );
    // Attitude: 23.00 ± 3.00 against 23.17 ± 1.04: no bold.
    assert!(text.contains("| 23.00 ± 3.00 |"), "{text}");
    assert!(!text.contains("**23.00"), "{text}");
    assert!(text.contains("removes 58.0 ± 2.0 % of the calibrated mean true position error"));
    assert!(text.contains("| V true pos | hilbert | iastgcn-s | 3/3 | 8.67 ± 1.53 | better |"));

    let paired = std::fs::read_to_string(tmp.join("paired.csv")).unwrap();
    let mut lines = paired.lines();
    assert_eq!(lines.next().unwrap(), seeds::PAIRED_HEADER);
    assert!(paired.contains("V true pos,hilbert,iastgcn-s,iastgcn,3,3,8.6667,1.5275,better"));
    let v = std::fs::read_to_string(tmp.join("table_v_seeds.csv")).unwrap();
    assert_eq!(v.lines().next().unwrap(), seeds::TABLE_V_SEEDS_HEADER);
    assert!(v.contains(
        "hilbert,iastgcn,3,42.0000,2.0000,23.0000,3.0000,58.0000,2.0000,54.0000,6.0000,"
    ));
    let iii = std::fs::read_to_string(tmp.join("table_iii_seeds.csv")).unwrap();
    assert_eq!(iii.lines().next().unwrap(), seeds::TABLE_III_SEEDS_HEADER);
    assert_eq!(iii.lines().count(), 1 + 2);
    let _ = std::fs::remove_dir_all(&tmp);
}

#[test]
fn several_held_out_sessions_pool_against_their_own_calibrated_runs() {
    // Two seeds of two models on two held-out sessions; session 1 (index 1) is another
    // day, its calibrated error twice session 0's.
    let at = |session: usize, row: TableVRow| TableVRow { session, ..row };
    let mut table_v = Vec::new();
    for (session, k) in [(0, 1.0), (1, 2.0)] {
        table_v.push(at(
            session,
            v_row("hilbert", "calibrated", "-", 100.0 * k, 50.0 * k),
        ));
        for seed in [1, 2] {
            let (m, o) = (format!("iastgcn.seed{seed}"), format!("tgcn.seed{seed}"));
            table_v.push(at(
                session,
                v_row("hilbert", "compensated", &m, 40.0 * k, 20.0 * k),
            ));
            table_v.push(at(
                session,
                v_row("hilbert", "compensated", &o, 50.0 * k, 20.0 * k),
            ));
        }
    }
    let r = Report {
        table_v,
        ..Report::default()
    };
    let s = seeds::summarize(&r).unwrap();
    let main = s.table_v.iter().find(|r| r.model == "iastgcn").unwrap();
    // 60 % removed in every session against its own calibrated run: no spread; against
    // session 0's calibrated run, session 1 would have removed 20 %.
    assert_eq!(main.pos_removed.n, 4);
    close(main.pos_removed.mean, 60.0);
    close(main.pos_removed.sd, 0.0);
    close(main.truth_pos.mean, 60.0);
    // Paired seed by seed and session by session: 4 pairs, IASTGCN better in each.
    let p = s
        .paired
        .iter()
        .find(|p| p.measure == "V true pos" && p.model == "tgcn")
        .unwrap();
    assert_eq!((p.difference.n, p.wins), (4, 4));
    close(p.difference.mean, 15.0);
    // The per-run tables name each session.
    let md = report::markdown(&r);
    assert!(
        md.contains("| hilbert, session 1 | calibrated |")
            && md.contains("| hilbert, session 2 | calibrated |"),
        "{md}"
    );
}
