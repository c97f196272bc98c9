//! Spread over twin machines (`experiment::machines`, `iastgcn reproduce --merge`):
//! reproduce folders of one protocol on different twin machines, merged by (machine,
//! seed) pair, with the share removed taken against each machine's own calibrated run.
//! Hand-made folders with known numbers; tests/reproduce.rs runs the real thing.

use std::path::{Path, PathBuf};

use iastgcn::experiment::machines::{merge_machines, summarize_machines};
use iastgcn::experiment::report::{TABLE_III_HEADER, TABLE_V_HEADER};
use iastgcn::experiment::reproduce::Protocol;

/// A finished reproduce folder of machine `machine`: Table V on the Hilbert path
/// (calibrated and compensated position / attitude means) and Table III on the grid.
fn folder(
    root: &Path,
    machine: u64,
    calibrated: (f64, f64),
    compensated: &[(&str, f64, f64)],
    mae: &[(&str, f64, f64)],
) -> PathBuf {
    let dir = root.join(format!("m{machine}"));
    std::fs::create_dir_all(&dir).unwrap();
    let protocol = Protocol {
        machine_seed: machine,
        ..Protocol::paper()
    };
    std::fs::write(
        dir.join("protocol.toml"),
        toml::to_string(&protocol).unwrap(),
    )
    .unwrap();
    let v_row = |stage: &str, model: &str, p: f64, a: f64| {
        format!("hilbert,0,{stage},{model},{p},1,2,{a},1,2,{p},1,2,{a},1,2\n")
    };
    let mut v = format!("{TABLE_V_HEADER}\n");
    v.push_str(&v_row("initial", "-", 900.0, 400.0));
    v.push_str(&v_row("calibrated", "-", calibrated.0, calibrated.1));
    for (model, p, a) in compensated {
        v.push_str(&v_row("compensated", model, *p, *a));
    }
    std::fs::write(dir.join("table_v.csv"), v).unwrap();
    let mut iii = format!("{TABLE_III_HEADER}\ngrid,training mean,99,99,9,99,99,9\n");
    for (model, p, a) in mae {
        iii.push_str(&format!("grid,{model},{p},1,1,{a},1,1\n"));
    }
    std::fs::write(dir.join("table_iii.csv"), iii).unwrap();
    dir
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9
}

#[test]
fn machines_merge_by_pair_against_each_machines_calibration() {
    let root = std::env::temp_dir().join(format!("iastgcn-machines-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let a = folder(
        &root,
        1,
        (100.0, 50.0),
        &[
            ("iastgcn.seed1", 60.0, 30.0),
            ("iastgcn.seed2", 70.0, 35.0),
            ("mlp.seed1", 80.0, 40.0),
            ("mlp.seed2", 65.0, 45.0),
        ],
        &[
            ("iastgcn.seed1", 10.0, 5.0),
            ("iastgcn.seed2", 12.0, 6.0),
            ("mlp.seed1", 11.0, 7.0),
            ("mlp.seed2", 13.0, 8.0),
        ],
    );
    let b = folder(
        &root,
        2,
        (200.0, 100.0),
        &[
            ("iastgcn.seed1", 100.0, 50.0),
            ("iastgcn.seed2", 120.0, 60.0),
            ("mlp.seed1", 150.0, 70.0),
            ("mlp.seed2", 110.0, 80.0),
        ],
        &[
            ("iastgcn.seed1", 14.0, 5.0),
            ("iastgcn.seed2", 16.0, 6.0),
            ("mlp.seed1", 20.0, 7.0),
            ("mlp.seed2", 18.0, 8.0),
        ],
    );
    let s = summarize_machines(&[a.clone(), b.clone()]).unwrap();
    assert_eq!(s.main, "iastgcn");
    assert_eq!(
        s.folders.iter().map(|f| f.1).collect::<Vec<_>>(),
        vec![1, 2]
    );
    let v = |model: &str| s.table_v.iter().find(|r| r.model == model).unwrap();
    let i = v("iastgcn");
    // Four (machine, seed) pairs: 60, 70, 100, 120 µm.
    assert_eq!(i.truth_pos.n, 4);
    assert!(close(i.truth_pos.mean, 87.5));
    // Removed against each machine's own calibrated run: 40, 30, 50, 40 %.
    assert!(close(i.pos_removed.mean, 40.0));
    assert!(close(i.pos_removed.sd, (200.0f64 / 3.0).sqrt()));
    // Machine means 35 % and 45 %.
    assert!(close(i.pos_removed_machine_sd, 50f64.sqrt()));
    // Attitude: 30/50, 35/50, 50/100, 60/100 → 40, 30, 50, 40 %.
    assert!(close(i.att_removed.mean, 40.0));
    // Paired with IASTGCN on the same (machine, seed): mlp − iastgcn = 20, −5, 50, −10.
    let p = s
        .paired
        .iter()
        .find(|p| p.measure == "V true pos" && p.model == "mlp")
        .unwrap();
    assert_eq!((p.wins, p.difference.n), (2, 4));
    assert!(close(p.difference.mean, 13.75));
    assert_eq!(p.verdict(), "within spread");
    // Table III: the seedless "training mean" row is not a model; mlp − iastgcn = 1, 1,
    // 6, 2 → better beyond the spread (mean 2.5, SD 2.38).
    let iii = s.table_iii.iter().find(|r| r.model == "iastgcn").unwrap();
    assert!(close(iii.pos_mae.mean, 13.0));
    assert!(s.table_iii.iter().all(|r| r.model != "training mean"));
    let p = s
        .paired
        .iter()
        .find(|p| p.measure == "III pos MAE")
        .unwrap();
    assert_eq!((p.wins, p.verdict()), (4, "better"));
    // The files.
    let out = root.join("merged");
    merge_machines(&[a.clone(), b.clone()], &out).unwrap();
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("| hilbert | 2 | 200.0 | 100.00 |"), "{md}");
    assert!(md.contains("removes 40.0 ± 8.2 %"), "{md}");
    let csv = std::fs::read_to_string(out.join("table_v_machines.csv")).unwrap();
    assert!(csv.contains("hilbert,iastgcn,4,87.5000,"), "{csv}");
    assert!(out.join("table_iii_machines.csv").exists());
    assert!(out.join("paired_machines.csv").exists());

    // Refused: one folder, the same machine twice, another protocol, no report yet.
    let err = |folders: &[PathBuf]| summarize_machines(folders).unwrap_err().to_string();
    assert!(err(std::slice::from_ref(&a)).contains("at least two"));
    assert!(err(&[a.clone(), a.clone()]).contains("twin machine 1 again"));
    let other = root.join("other");
    std::fs::create_dir_all(&other).unwrap();
    let protocol = Protocol {
        machine_seed: 3,
        seeds: vec![1, 2],
        ..Protocol::paper()
    };
    std::fs::write(
        other.join("protocol.toml"),
        toml::to_string(&protocol).unwrap(),
    )
    .unwrap();
    let e = err(&[a.clone(), other.clone()]);
    assert!(e.contains("other/protocol.toml: another protocol"), "{e}");
    let protocol = Protocol {
        machine_seed: 3,
        ..Protocol::paper()
    };
    std::fs::write(
        other.join("protocol.toml"),
        toml::to_string(&protocol).unwrap(),
    )
    .unwrap();
    let e = err(&[a, other]);
    assert!(e.contains("table_v.csv: missing"), "{e}");
    let _ = std::fs::remove_dir_all(&root);
}
