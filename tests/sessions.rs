//! Training sets recorded as several sessions (docs/twin.md "Sessions" and "Days"): the
//! plan (placements, seeds, conditions, file names), its determinism, the day's ambient
//! in the twin, the recorder behind `simulate --trajectory training`, and the refusals.

mod common;

use std::path::{Path, PathBuf};

use common::{cli, cli_fails};
use iastgcn::experiment::evaluate::HeldOutConfig;
use iastgcn::robot::Geometry;
use iastgcn::twin::{
    draw_machine, Conditions, Day, PathKind, PathOrder, PathParams, Placement, PlannedSession,
    Recipe, RunInfo,
};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn a_single_session_is_the_protocol_of_before() {
    let plan = Recipe::SINGLE.plan(8.0, 201, 1);
    assert_eq!(plan.len(), 1);
    assert_eq!(plan[0].conditions, Conditions::NOMINAL);
    let runs = &plan[0].runs;
    assert_eq!(
        runs.iter()
            .map(|r| (r.path.as_str(), r.seed))
            .collect::<Vec<_>>(),
        [("grid", 201), ("fermat", 202), ("hilbert", 203)]
    );
    for (r, kind) in runs.iter().zip(PathKind::TRAINING) {
        assert_eq!(r.placement(), PathParams::default());
        assert_eq!(
            (r.seconds, r.session, r.feed_mm_s, r.force_n),
            (480.0, 1, 20.0, 100.0)
        );
        assert_eq!(r.day(), Day::CALIBRATION);
        assert_eq!(
            Recipe::SINGLE.file_name(kind, 1),
            format!("{}.csv", kind.name())
        );
    }
}

#[test]
fn several_sessions_split_the_minutes_each_on_its_own_day_and_placement() {
    let recipe = Recipe {
        sessions: 4,
        placement: Placement::Varied,
        path_order: PathOrder::Fixed,
    };
    let plan = recipe.plan(8.0, 201, 3);
    assert_eq!(plan, recipe.plan(8.0, 201, 3), "the plan is deterministic");
    assert_eq!(plan.len(), 4);
    let mut seeds = Vec::new();
    for (s, session) in plan.iter().enumerate() {
        assert_eq!(session.runs.len(), 3);
        for (r, kind) in session.runs.iter().zip(PathKind::TRAINING) {
            assert_eq!(r.path, kind.name());
            assert_eq!((r.seconds, r.session, r.machine_seed), (120.0, s + 1, 3));
            assert_eq!(r.placement(), PathParams::training(kind, s));
            // Every run of a session shares its conditions.
            assert_eq!(r.day(), session.conditions.day);
            assert_eq!(r.feed_mm_s, session.conditions.feed_mm_s);
            seeds.push(r.seed);
        }
        assert_eq!(
            recipe.file_name(PathKind::Hilbert, s + 1),
            format!("hilbert.s{:02}.csv", s + 1)
        );
    }
    assert_eq!(seeds, (20100..20112).collect::<Vec<_>>());
    // Four different days, none the calibration day.
    for (i, a) in plan.iter().enumerate() {
        assert_ne!(a.conditions.day, Day::CALIBRATION);
        for b in &plan[i + 1..] {
            assert_ne!(a.conditions, b.conditions);
        }
    }
    // Fixed placement: the same days and seeds, every run at the default placement.
    let fixed = Recipe {
        placement: Placement::Fixed,
        ..recipe
    }
    .plan(8.0, 201, 3);
    for (a, b) in fixed.iter().zip(&plan) {
        assert_eq!(a.conditions, b.conditions);
        assert!(a
            .runs
            .iter()
            .all(|r| r.placement() == PathParams::default()));
    }
    // Spread placement: the same days and seeds, session s's runs at the s-th spread
    // turn of each pattern (docs/twin.md "Sessions"), recorded in their sidecars.
    let spread = Recipe {
        placement: Placement::Spread,
        ..recipe
    }
    .plan(8.0, 201, 3);
    for (s, (a, b)) in spread.iter().zip(&plan).enumerate() {
        assert_eq!(a.conditions, b.conditions);
        for ((r, q), kind) in a.runs.iter().zip(&b.runs).zip(PathKind::TRAINING) {
            assert_eq!(r.seed, q.seed);
            assert_eq!(r.placement(), PathParams::spread(kind, s));
        }
    }
    assert_eq!("spread".parse::<Placement>(), Ok(Placement::Spread));
    // Rotated order: session s starts with path (s − 1) mod 3 and goes round; each run
    // keeps the seed, day and placement its path has in the fixed order.
    let rotated = Recipe {
        path_order: PathOrder::Rotated,
        ..recipe
    }
    .plan(8.0, 201, 3);
    let order = |session: &PlannedSession| -> Vec<String> {
        session.runs.iter().map(|r| r.path.clone()).collect()
    };
    for (s, first) in [(0, "grid"), (1, "fermat"), (2, "hilbert"), (3, "grid")] {
        assert_eq!(order(&rotated[s])[0], first, "session {}", s + 1);
        for r in &rotated[s].runs {
            let same = plan[s].runs.iter().find(|q| q.path == r.path).unwrap();
            assert_eq!(r, same);
        }
    }
    assert_eq!(order(&rotated[1]), ["fermat", "hilbert", "grid"]);
    assert_eq!(PathOrder::Rotated.paths(0), PathOrder::Rotated.paths(1));
    assert_eq!(PathOrder::Rotated.paths(4), PathOrder::Fixed.paths(2));
    assert_eq!("rotated".parse::<PathOrder>(), Ok(PathOrder::Rotated));
    assert!("sideways".parse::<PathOrder>().is_err());
    assert_eq!(Placement::Spread.name(), "spread");
}

#[test]
fn days_draw_within_their_documented_ranges_and_move_the_ambient() {
    let (mut offsets, mut feeds) = (Vec::new(), Vec::new());
    for seed in 0..2000 {
        let c = Conditions::draw(seed);
        let d = c.day;
        assert!(d.ambient_offset_k.abs() <= Conditions::AMBIENT_LIMIT_K);
        assert!((0.0..std::f64::consts::TAU).contains(&d.ambient_phase_shift));
        assert!((16.0..24.0).contains(&c.feed_mm_s));
        assert!(
            (90.0 - 1e-9..=110.0 + 1e-9).contains(&c.force_n),
            "{}",
            c.force_n
        );
        offsets.push(d.ambient_offset_k);
        feeds.push(c.feed_mm_s);
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let sd = |v: &[f64]| {
        let m = mean(v);
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
    };
    // N(0, 0.5 K) clamped at 1.5 K (3 SD): mean 0 and SD 0.5 within sampling error.
    assert!(mean(&offsets).abs() < 0.05, "{}", mean(&offsets));
    assert!((sd(&offsets) - 0.5).abs() < 0.04, "{}", sd(&offsets));
    assert!((mean(&feeds) - 20.0).abs() < 0.2, "{}", mean(&feeds));
    // The machine switched on on a day sits at that day's ambient: offset plus the
    // machine's slow cycle at the shifted phase.
    let machine = draw_machine(Geometry::default_asset(), 1);
    let thermal = machine.nongeometric.thermal.unwrap();
    let day = Day {
        ambient_offset_k: 0.8,
        ambient_phase_shift: 1.0,
    };
    let want = |d: &Day, t: f64| {
        d.ambient_offset_k
            + thermal.ambient_amplitude
                * (std::f64::consts::TAU * t / thermal.ambient_period
                    + thermal.ambient_phase
                    + d.ambient_phase_shift)
                    .sin()
    };
    for t in [0.0, 600.0, 1800.0] {
        assert!((machine.cold_on(day).ambient(t) - want(&day, t)).abs() < 1e-12);
        assert_eq!(
            machine.cold().ambient(t),
            machine.cold_on(Day::CALIBRATION).ambient(t)
        );
        assert!((machine.cold().ambient(t) - want(&Day::CALIBRATION, t)).abs() < 1e-12);
    }
}

#[test]
fn held_out_sessions_start_cold_or_warm_on_days_of_their_own() {
    let held = HeldOutConfig::default();
    let first = held.session(0);
    assert_eq!((first.warm_up_minutes, first.seed), (2.0, 301));
    assert_eq!(first.conditions, Conditions::NOMINAL);
    let (one, two) = (held.session(1), held.session(2));
    assert_eq!((one.warm_up_minutes, one.seed), (0.0, 311));
    assert_eq!((two.warm_up_minutes, two.seed), (6.0, 321));
    assert_ne!(one.conditions, two.conditions);
    assert_eq!(one, held.session(1));
    assert!(
        one.describe().starts_with("cold, ambient"),
        "{}",
        one.describe()
    );
}

fn training_set(out: &Path, extra: &[&str]) -> String {
    let mut args = vec!["simulate", "--trajectory", "training", "--minutes", "0.5"];
    args.extend(extra);
    args.extend(["--out", s(out)]);
    cli(&args)
}

#[test]
fn simulate_records_a_training_set_in_sessions_deterministically() {
    let dir: PathBuf =
        std::env::temp_dir().join(format!("iastgcn-sessions-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let (a, b) = (dir.join("a"), dir.join("b"));
    let flags = ["--sessions", "2", "--placement", "varied"];
    let text = training_set(&a, &flags);
    assert!(text.contains("6 recordings"), "{text}");
    let mut days = Vec::new();
    for session in 1..=2 {
        for (i, kind) in PathKind::TRAINING.into_iter().enumerate() {
            let csv = a.join(format!("{}.s{session:02}.csv", kind.name()));
            let info = RunInfo::read(&csv).unwrap();
            assert_eq!((info.session, info.seconds), (session, 15.0));
            assert_eq!(info.placement(), PathParams::training(kind, session - 1));
            // Each session starts cold; its later runs start warm.
            assert_eq!(info.start, if i == 0 { "cold" } else { "warm" }, "{csv:?}");
            assert!(info.controller.ends_with("calibration.toml"));
            days.push(info.day());
        }
    }
    assert!(days[..3].iter().all(|d| *d == days[0]) && days[3..].iter().all(|d| *d == days[3]));
    assert_ne!(days[0], days[3]);
    // The same flags record the same bytes.
    training_set(&b, &flags);
    for name in ["grid.s01.csv", "hilbert.s02.csv", "calibration.toml"] {
        assert_eq!(
            std::fs::read(a.join(name)).unwrap(),
            std::fs::read(b.join(name)).unwrap(),
            "{name}"
        );
    }
    // Spread placements with the paths' order rotated: session 2 runs fermat, hilbert,
    // grid, so fermat starts it cold and grid runs last; each run keeps its path's seed
    // and day, at its spread placement.
    let c = dir.join("c");
    let text = training_set(
        &c,
        &[
            "--sessions",
            "2",
            "--placement",
            "spread",
            "--path-order",
            "rotated",
        ],
    );
    assert!(text.contains("path order rotated"), "{text}");
    for session in 1..=2 {
        for kind in PathKind::TRAINING {
            let name = format!("{}.s{session:02}.csv", kind.name());
            let (info, varied) = (
                RunInfo::read(&c.join(&name)).unwrap(),
                RunInfo::read(&a.join(&name)).unwrap(),
            );
            assert_eq!(info.placement(), PathParams::spread(kind, session - 1));
            assert_eq!((info.seed, info.day()), (varied.seed, varied.day()));
            let first = if session == 1 {
                PathKind::Grid
            } else {
                PathKind::Fermat
            };
            let start = if kind == first { "cold" } else { "warm" };
            assert_eq!(info.start, start, "{name}");
        }
    }
    // Session 2's grid runs after the other two (two 15 s runs and their idles): later on
    // the session's clock and with warmer screws than session 1's grid, which starts the
    // day cold.
    let info = |name: &str| RunInfo::read(&c.join(name)).unwrap();
    let (late, first) = (info("grid.s02.csv"), info("grid.s01.csv"));
    assert!(
        late.session_clock_s > 30.0 && first.session_clock_s == 0.0,
        "{late:?}"
    );
    assert!(late.screw_rise_k.iter().all(|t| *t > 0.0) && first.screw_rise_k == [0.0; 3]);
    // Refused before any work, the flag named (and every needle in the message), with
    // nothing written where the output would have gone.
    let graph = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/graph-force.toml");
    let training = ["simulate", "--trajectory", "training"];
    let cases: [(&[&str], &[&str]); 9] = [
        (
            &["--minutes", "0.5", "--sessions", "3"],
            &["--sessions", "at most 2 sessions"],
        ),
        (&["--sessions", "0"], &["--sessions"]),
        (&["--sessions", "65"], &["--sessions"]),
        (&["--placement", "diagonal"], &["--placement"]),
        (&["--path-order", "backwards"], &["--path-order"]),
        (
            &[
                "simulate",
                "--trajectory",
                "grid",
                "--path-order",
                "rotated",
            ],
            &["--path-order", "--trajectory training"],
        ),
        (
            &["simulate", "--trajectory", "grid", "--sessions", "2"],
            &["--trajectory training"],
        ),
        (
            &["scale", "--sessions", "40", "--sizes", "8"],
            &["--sessions"],
        ),
        (
            &["scale", "--graph", graph, "--sizes", "8"],
            &["--graph", "nodes = 15"],
        ),
    ];
    for (i, (flags, needles)) in cases.into_iter().enumerate() {
        let out = dir.join(format!("refused{i}"));
        let mut args: Vec<&str> = if matches!(flags[0], "simulate" | "scale") {
            Vec::new()
        } else {
            training.to_vec()
        };
        args.extend(flags);
        args.extend(["--out", s(&out)]);
        let err = cli_fails(&args);
        assert!(needles.iter().all(|n| err.contains(n)), "{args:?}: {err}");
        assert!(!out.exists(), "{args:?}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_held_out_count_out_of_range_names_the_setting() {
    let config = HeldOutConfig {
        sessions: 0,
        ..HeldOutConfig::default()
    };
    let err = config.validate().unwrap_err();
    assert!(
        matches!(
            err.root(),
            iastgcn::error::Error::Setting {
                setting: "held_out.sessions",
                ..
            }
        ),
        "{err}"
    );
    assert_eq!(
        err.to_string(),
        "held_out.sessions: 1 to 16 held-out sessions, got 0"
    );
}
