//! The mirror stage on the twin (docs/polishing.md): a polishing run removes glass at the
//! pose the controller really reaches, the same seed gives the same glass bit for bit, and
//! Table VI is computed from the rows as the paper defines it.

use iastgcn::compensate::online::Feedback;
use iastgcn::experiment::polish::{self, paired_against, table_vi, PolishRow, PolishSpec};
use iastgcn::polish::{draw_surface, HeightMap, Polisher, PoseSource, Setup, StartingPoint};
use iastgcn::progress::Notes;
use iastgcn::robot::{Geometry, Robot};
use iastgcn::twin::{draw_machine, PathKind};

/// A coarse, quick set-up: 6 mm pixels.
fn quick() -> Polisher {
    let mut setup = Setup::new(PathKind::Grid);
    setup.pitch = 6.0;
    Polisher::new(setup).unwrap()
}

#[test]
fn polishing_removes_glass_at_the_true_pose_deterministically() {
    let geometry = Geometry::load_or_default(None).unwrap();
    let machine = draw_machine(geometry.clone(), 1);
    let nominal = Robot::nominal(geometry);
    let mut polisher = quick();
    let start = draw_surface(
        polisher.grid,
        polisher.mirror.radius(),
        &polisher.clear,
        &StartingPoint::default(),
        3,
    );
    let measured = polisher.measure(&start, 11);
    let dwell = polisher.plan(&measured).unwrap();
    let polish = |pose: PoseSource| -> HeightMap {
        let mut surface = start.clone();
        let plan = polisher.feed(&dwell).unwrap();
        let run = polisher
            .polish(
                &machine,
                &nominal,
                machine.cold(),
                Feedback::None,
                plan,
                21,
                pose,
                &mut surface,
                |_| {},
            )
            .unwrap();
        assert!(run.truth.position.count > 1000);
        surface
    };
    let perfect = polish(PoseSource::Target);
    let real = polish(PoseSource::True);
    assert_eq!(perfect, polish(PoseSource::Target), "same seed, same glass");
    // The nominal controller misses the path by a millimetre or more: the glass differs,
    // by much less than what was removed (the volume is the force's, not the pose's).
    let removed = |m: &HeightMap| {
        let (mut sum, mut n) = (0.0, 0.0);
        for ((a, b), &c) in start.values.iter().zip(&m.values).zip(&polisher.clear) {
            if c {
                sum += a - b;
                n += 1.0;
            }
        }
        sum / n
    };
    let (depth, depth_real) = (removed(&perfect), removed(&real));
    assert!(depth > 50.0, "mean removal {depth} nm");
    assert!(
        (depth_real - depth).abs() < 0.1 * depth,
        "{depth_real} against {depth} nm"
    );
    let differs = perfect
        .values
        .iter()
        .zip(&real.values)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f64, f64::max);
    assert!(differs > 0.1, "the pose error left no mark: {differs} nm");
}

/// A fork plans the same dwell bit for bit as the polisher it came from, after that one
/// has planned another surface (the scratch a solver keeps does not leak into its next
/// plan): the study's controllers plan on threads of their own.
#[test]
fn a_fork_plans_what_its_original_plans() {
    let mut polisher = quick();
    let surface = |seed| {
        draw_surface(
            polisher.grid,
            polisher.mirror.radius(),
            &polisher.clear,
            &StartingPoint::default(),
            seed,
        )
    };
    let (a, b) = (surface(3), surface(4));
    let (a, b) = (polisher.measure(&a, 11), polisher.measure(&b, 12));
    polisher.plan(&a).unwrap();
    let mut fork = polisher.fork().unwrap();
    let by_fork = fork.plan(&b).unwrap();
    let by_original = polisher.plan(&b).unwrap();
    let by_fresh = quick().plan(&b).unwrap();
    for other in [&by_original, &by_fresh] {
        assert_eq!(by_fork.seconds, other.seconds);
        assert_eq!(by_fork.removal, other.removal);
        assert_eq!(by_fork.force, other.force);
    }
}

/// The study's rows come surface by surface, each in the controllers' order, whichever
/// thread polished which controller; a surface's rows are the same when it is polished
/// alone.
#[test]
fn the_study_keeps_its_order_and_its_bits_on_every_core() {
    let geometry = Geometry::load_or_default(None).unwrap();
    let machine = draw_machine(geometry.clone(), 1);
    let nominal = Robot::nominal(geometry);
    let spec = |seeds: Vec<u64>| PolishSpec {
        iterations: 1,
        surface_seeds: seeds,
        seed: 5,
        warm_up_minutes: 0.0,
        every: 5,
        start: StartingPoint::default(),
        split_nominal: false,
    };
    let study = |seeds: Vec<u64>| {
        let mut notes = Notes::default();
        let result = polish::run(
            &mut quick(),
            &spec(seeds),
            &machine,
            &nominal,
            &nominal,
            &mut [],
            48,
            &mut notes,
        )
        .unwrap();
        (result, notes.0)
    };
    let (both, notes) = study(vec![3, 4]);
    let controllers = ["nominal", "calibrated", "oracle", "perfect machine"];
    let expected: Vec<(u64, &str, usize)> = [3, 4]
        .into_iter()
        .flat_map(|s| {
            controllers
                .iter()
                .flat_map(move |&c| [(s, c, 0), (s, c, 1)])
        })
        .collect();
    let order: Vec<(u64, &str, usize)> = both
        .rows
        .iter()
        .map(|r| (r.surface_seed, r.controller.as_str(), r.iteration))
        .collect();
    assert_eq!(order, expected);
    let names: Vec<&str> = both.maps.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        [
            "start",
            "nominal",
            "calibrated",
            "oracle",
            "perfect machine"
        ]
    );
    assert_eq!(notes.len(), 8, "{notes:?}");
    assert!(notes[4].starts_with("surface 4, nominal: RMS"), "{notes:?}");
    let (alone, _) = study(vec![4]);
    let key = |r: &PolishRow| format!("{r:?}");
    assert_eq!(
        alone.rows.iter().map(key).collect::<Vec<_>>(),
        both.rows[8..].iter().map(key).collect::<Vec<_>>()
    );
}

/// A set-up the removal's model does not hold for is refused before any work, naming the
/// field: a pad as large as the mirror, an orbit wider than the pad, NaN or negative
/// constants.
#[test]
fn impossible_pads_are_refused_naming_the_field() {
    type Spoil = fn(&mut Setup);
    let cases: [(&str, Spoil); 5] = [
        ("quarter of the mirror", |s| s.pad.radius = 200.0),
        ("orbit_radius", |s| s.pad.orbit_radius = 20.0),
        ("preston", |s| s.pad.preston = f64::NAN),
        ("radius", |s| s.pad.radius = -1.0),
        ("stiffness", |s| s.pad.stiffness = -0.1),
    ];
    for (field, spoil) in cases {
        let mut setup = Setup::new(PathKind::Grid);
        spoil(&mut setup);
        let message = match Polisher::new(setup) {
            Ok(_) => panic!("a pad with a bad {field} was accepted"),
            Err(e) => e.to_string(),
        };
        assert!(message.contains(field), "{field}: {message}");
    }
}

fn row(seed: u64, controller: &str, iteration: usize, pv: f64, rms: f64) -> PolishRow {
    PolishRow {
        surface_seed: seed,
        controller: controller.into(),
        iteration,
        pv_nm: pv,
        rms_nm: rms,
        measured_rms_nm: rms,
        planned_rms_nm: f64::NAN,
        minutes: if iteration < 2 { 10.0 } else { f64::NAN },
        force_n: 100.0,
        position_um: 100.0,
        attitude_mdeg: 50.0,
    }
}

/// Table VI's decrease is (before − after)/before per surface, then mean ± SD over the
/// surfaces; minutes add up over the iterations.
#[test]
fn table_vi_follows_the_paper() {
    let rows = vec![
        row(1, "calibrated", 0, 250.0, 14.0),
        row(1, "calibrated", 1, 150.0, 10.0),
        row(1, "calibrated", 2, 125.0, 7.0),
        row(2, "calibrated", 0, 200.0, 16.0),
        row(2, "calibrated", 1, 150.0, 12.0),
        row(2, "calibrated", 2, 150.0, 12.0),
        row(1, "perfect machine", 0, 250.0, 14.0),
        row(1, "perfect machine", 2, 50.0, 7.0),
    ];
    let table = table_vi(&rows);
    assert_eq!(table.len(), 2);
    let cal = &table[0];
    assert_eq!(cal.controller, "calibrated");
    assert_eq!(cal.rms_decrease.count, 2);
    assert!((cal.rms_decrease.mean - 37.5).abs() < 1e-9); // 50 % and 25 %
    assert!((cal.rms_decrease.sd - 12.5).abs() < 1e-9);
    assert!((cal.pv_decrease.mean - 37.5).abs() < 1e-9); // 50 % and 25 %
    assert!((cal.minutes.mean - 20.0).abs() < 1e-9);
    assert!((table[1].rms_decrease.mean - 50.0).abs() < 1e-9);
    // Paired on surface 1 only (the perfect machine ran no other): 7 − 7 and 50 − 125.
    let paired = paired_against(&rows, "calibrated");
    assert_eq!(paired.len(), 1);
    assert_eq!(paired[0].0, "perfect machine");
    assert_eq!((paired[0].1.count, paired[0].1.mean), (1, 0.0));
    assert_eq!(paired[0].2.mean, -75.0);
}

/// `iastgcn polish-sweep` on a coarse grid: every cell of the sweep in the CSV, the cost
/// tables and the map written, a `polish` run's pose errors marked; bad kinds, floats and
/// mark files refused by name.
#[test]
fn the_sweep_writes_its_map_and_refuses_bad_input() {
    let dir = std::env::temp_dir().join(format!("iastgcn-sweep-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let marks = dir.join("polish.csv");
    std::fs::write(
        &marks,
        "surface_seed,controller,iteration,pv_nm,rms_nm,measured_rms_nm,planned_rms_nm,minutes,force_n,position_um,attitude_mdeg\n\
         1,calibrated,0,250,13,13,7,12,150,120,60\n\
         1,calibrated,1,120,9,9,8,9,44,140,62\n\
         1,perfect machine,0,250,13,13,7,12,150,0,0\n",
    )
    .unwrap();
    let out = dir.join("sweep");
    let bin = env!("CARGO_BIN_EXE_iastgcn");
    let common = [
        "polish-sweep",
        "--footprints",
        "42,84",
        "--sizes",
        "0.1,1",
        "--pixels-across",
        "7",
        "--max-pixel-mm",
        "12",
        "--seeds",
        "1",
    ];
    let run = |extra: &[&str]| {
        std::process::Command::new(bin)
            .args(common)
            .args(extra)
            .output()
            .unwrap()
    };
    let o = run(&[
        "--kinds",
        "slow,white",
        "--marks-from",
        marks.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = std::fs::read_to_string(out.join("sweep.csv")).unwrap();
    // 2 footprints × 2 kinds × 2 floats × 2 sizes.
    assert_eq!(csv.lines().count(), 1 + 16, "{csv}");
    let md = std::fs::read_to_string(out.join("sweep.md")).unwrap();
    assert!(md.contains("## slow, ideal float"), "{md}");
    assert!(md.contains("## white, float 4 N/mm, seal 3 N"), "{md}");
    assert!(md.contains("the twin, calibrated (130 µm)"), "{md}");
    assert!(!md.contains("perfect machine"), "{md}");
    assert!(std::fs::metadata(out.join("map.png")).unwrap().len() > 1000);
    for (extra, says) in [
        (
            vec!["--kinds", "sideways"],
            "unknown pose error kind \"sideways\"",
        ),
        (vec!["--floats", "rigid"], "unknown float \"rigid\""),
        (
            vec!["--marks-from", "/nonexistent/polish.csv"],
            "--marks-from",
        ),
        (vec!["--sizes", "0.1,-1"], "sizes"),
    ] {
        let mut args = extra.clone();
        args.extend(["--out", out.to_str().unwrap()]);
        let o = run(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            !o.status.success() && err.contains(says),
            "{extra:?}: {err}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
