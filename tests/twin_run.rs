//! The running twin end to end: error magnitudes on the three polishing paths against
//! docs/twin.md, and bit-for-bit reproducible recordings from the CLI.

use std::path::PathBuf;
use std::process::Command;

use iastgcn::robot::{Geometry, Robot};
use iastgcn::twin::{draw_machine, Mirror, PathKind, SimConfig, Simulation};

/// Mean true pad error (mm, deg) of a run of `seconds` with `controller`.
fn mean_error(kind: PathKind, seconds: f64, controller_knows_geometry: bool) -> (f64, f64) {
    let g = Geometry::default_asset();
    let machine = draw_machine(g.clone(), 1);
    let nominal = Robot::nominal(g);
    let controller = if controller_knows_geometry {
        &machine.robot
    } else {
        &nominal
    };
    let mut sim = Simulation::new(
        &machine,
        controller,
        Mirror::default(),
        SimConfig::new(kind, seconds, 3),
    )
    .unwrap();
    let (mut pos, mut att, mut n) = (0.0, 0.0, 0.0);
    while let Some(s) = sim.step() {
        let h = s.unwrap().hidden;
        pos += (h.actual.pose.translation.vector - h.commanded.translation.vector).norm();
        att += (h.actual.pose.rotation * h.commanded.rotation.inverse())
            .angle()
            .to_degrees();
        n += 1.0;
    }
    (pos / n, att / n)
}

#[test]
fn error_magnitudes_match_twin_md() {
    // docs/twin.md: uncalibrated ~0.5–0.7 mm / 0.15–0.2°; with the geometry known exactly
    // (a perfect calibration) ~0.10–0.15 mm / 0.05–0.08°, the non-geometric remainder.
    // Four minutes lets the screws warm up (180 s time constant).
    // The six runs are independent: spread them over the cores.
    let results: Vec<_> = std::thread::scope(|s| {
        let runs: Vec<_> = PathKind::TRAINING
            .into_iter()
            .flat_map(|kind| {
                [false, true].map(|known| (kind, s.spawn(move || mean_error(kind, 240.0, known))))
            })
            .collect();
        runs.into_iter()
            .map(|(kind, h)| (kind, h.join().unwrap()))
            .collect()
    });
    for pair in results.chunks(2) {
        let (kind, (p0, a0)) = pair[0];
        let (p1, a1) = pair[1].1;
        println!(
            "{:8} uncalibrated {p0:.3} mm {a0:.4} deg | geometry corrected {p1:.3} mm {a1:.4} deg",
            kind.name()
        );
        assert!(
            (0.5..0.8).contains(&p0),
            "{kind:?} uncalibrated position {p0}"
        );
        assert!(
            (0.12..0.22).contains(&a0),
            "{kind:?} uncalibrated attitude {a0}"
        );
        assert!(
            (0.08..0.17).contains(&p1),
            "{kind:?} corrected position {p1}"
        );
        assert!(
            (0.045..0.085).contains(&a1),
            "{kind:?} corrected attitude {a1}"
        );
    }
}

fn simulate(args: &[&str], out: &PathBuf) -> std::process::Output {
    let o = Command::new(env!("CARGO_BIN_EXE_iastgcn"))
        .arg("simulate")
        .args(args)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    o
}

#[test]
fn same_seed_gives_the_same_bytes_and_another_seed_does_not() {
    let dir = std::env::temp_dir().join(format!("iastgcn-sim-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let f = |n: &str| dir.join(n);
    let run = ["--trajectory", "hilbert", "--minutes", "0.1", "--seed", "5"];
    simulate(&run, &f("a.csv"));
    simulate(&run, &f("b.csv"));
    simulate(
        &["--trajectory", "hilbert", "--minutes", "0.1", "--seed", "6"],
        &f("c.csv"),
    );
    simulate(
        &[
            "--trajectory",
            "hilbert",
            "--minutes",
            "0.1",
            "--seed",
            "5",
            "--machine-seed",
            "2",
        ],
        &f("d.csv"),
    );
    let read = |n: &str| std::fs::read(f(n)).unwrap();
    assert_eq!(read("a.csv"), read("b.csv"));
    assert_ne!(read("a.csv"), read("c.csv"));
    assert_ne!(read("a.csv"), read("d.csv"));
    // 0.1 min at 50 Hz, with its plot.
    let text = String::from_utf8(read("a.csv")).unwrap();
    assert_eq!(text.lines().count(), 1 + 300);
    assert!(std::fs::metadata(f("a.png")).unwrap().len() > 10_000);
    // Calibration sets are reproducible too.
    let calibration = [
        "--trajectory",
        "calibration",
        "--poses",
        "12",
        "--seed",
        "5",
    ];
    simulate(&calibration, &f("k1.csv"));
    simulate(&calibration, &f("k2.csv"));
    assert_eq!(read("k1.csv"), read("k2.csv"));
    let cal = iastgcn::data::read_calibration_set(&f("k1.csv")).unwrap();
    assert_eq!(cal.len(), 12);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn recordings_read_back_with_the_graph_channels() {
    let dir = std::env::temp_dir().join(format!("iastgcn-rb-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("r.csv");
    simulate(&["--trajectory", "grid", "--minutes", "0.05"], &out);
    let graph = iastgcn::graph::Graph::default_asset();
    let mut channels: Vec<&str> = graph.nodes.iter().map(String::as_str).collect();
    channels.push("F");
    let rec = iastgcn::data::Recording::read(&out, &channels, 100).unwrap();
    assert_eq!(rec.rows.len(), 150);
    // Tilt sensor at 10 Hz, tracker at 10 Hz: every fifth row.
    let phi = rec.channels.iter().position(|c| c == "phiX").unwrap();
    assert_eq!(
        rec.rows.iter().filter(|r| r.values[phi].is_some()).count(),
        30
    );
    assert_eq!(rec.rows.iter().filter(|r| r.tracker.is_some()).count(), 30);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_arguments_are_clear() {
    let stderr = |args: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_iastgcn"))
            .args(args)
            .output()
            .unwrap();
        assert!(!o.status.success());
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let out = "/tmp/iastgcn-never-written.csv";
    assert!(stderr(&["simulate", "--trajectory", "zigzag", "--out", out]).contains("zigzag"));
    let e = stderr(&[
        "simulate",
        "--trajectory",
        "grid",
        "--minutes",
        "0",
        "--out",
        out,
    ]);
    assert!(e.contains("--minutes must be positive"), "{e}");
    // Too short to hold one control tick, too long to hold in memory, too many poses:
    // refused before anything is simulated or allocated.
    let simulate = |extra: &[&str]| {
        let mut args = vec!["simulate", "--out", out];
        args.extend(extra);
        stderr(&args)
    };
    for minutes in ["1e-6", "1e9"] {
        let e = simulate(&["--trajectory", "grid", "--minutes", minutes]);
        assert!(e.contains("a run lasts from one control tick"), "{e}");
        assert!(!e.contains("panicked"), "{e}");
    }
    let e = simulate(&["--trajectory", "calibration", "--poses", "1000000000"]);
    assert!(e.contains("from 1 to 100000 poses, got 1000000000"), "{e}");
    assert!(!std::path::Path::new(out).exists());
}
