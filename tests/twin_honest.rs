//! The twin is honest (docs/twin.md): its channels are instruments, not the truth model
//! plus noise; held-out paths never retrace a training recording; the machine's state
//! carries over from one run of a session to the next.

use iastgcn::robot::{Geometry, Robot};
use iastgcn::twin::retrace::{
    longest_retrace, retrace_limit, samples, spread_candidate_deg, spread_placements,
    HeldOutPlacements,
};
use iastgcn::twin::{
    draw_machine, Mirror, Path, PathKind, PathParams, Sample, SimConfig, Simulation, CHANNELS,
};

fn correlation(a: &[f64], b: &[f64]) -> Option<f64> {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    // A term that never moves (or moves below rounding) has no correlation to speak of.
    (saa > 1e-18 * n && sbb > 1e-18 * n).then(|| sab / (saa * sbb).sqrt())
}

/// Every term of the truth model, and each limb's and joint's total error, per tick.
fn truth_terms(s: &Sample) -> Vec<(String, f64)> {
    let h = &s.hidden;
    let t = &h.actual.terms;
    let mut v = Vec::new();
    for i in 0..3 {
        v.push((format!("lost motion {i}"), t.lost_motion[i]));
        v.push((format!("screw growth {i}"), t.thermal.screw[i]));
        v.push((format!("tube growth {i}"), t.thermal.tube[i]));
        v.push((format!("screw stretch {i}"), t.give.screw[i]));
        v.push((format!("strut stretch {i}"), t.give.strut[i]));
        v.push((format!("clearance {i}"), t.give.clearance[i]));
    }
    for j in 0..2 {
        v.push((format!("backlash {j}"), t.backlash[j]));
        v.push((format!("transmission error {j}"), t.transmission[j]));
        v.push((format!("wind-up {j}"), t.windup[j]));
    }
    let tip = t.tip.translation.vector;
    let bend = t.tip.rotation.scaled_axis();
    for k in 0..3 {
        v.push((format!("tip shift {k}"), tip[k]));
        v.push((format!("tip bend {k}"), bend[k]));
    }
    let dp = h.actual.pose.translation.vector - h.commanded.translation.vector;
    let dr = (h.actual.pose.rotation * h.commanded.rotation.inverse()).scaled_axis();
    for k in 0..3 {
        v.push((format!("pose residual p{k}"), dp[k]));
        v.push((format!("pose residual r{k}"), dr[k]));
    }
    v
}

#[test]
fn no_channel_is_a_truth_term_plus_noise() {
    let g = Geometry::default_asset();
    let machine = draw_machine(g.clone(), 1);
    let controller = Robot::nominal(g);
    let mut sim = Simulation::new(
        &machine,
        &controller,
        Mirror::default(),
        SimConfig::new(PathKind::Hilbert, 90.0, 17),
    )
    .unwrap();
    let mut channels: Vec<Vec<f64>> = vec![Vec::new(); CHANNELS.len()];
    let mut terms: Vec<(String, Vec<f64>)> = Vec::new();
    while let Some(s) = sim.step() {
        let s = s.unwrap();
        // The 10 Hz ticks: every channel has a sample there.
        if s.channels.iter().any(Option::is_none) {
            continue;
        }
        for (c, v) in channels.iter_mut().zip(&s.channels) {
            c.push(v.unwrap());
        }
        for (k, (name, value)) in truth_terms(&s).into_iter().enumerate() {
            if terms.len() <= k {
                terms.push((name, Vec::new()));
            }
            terms[k].1.push(value);
        }
    }
    assert!(channels[0].len() > 400);
    let mut worst = (0.0f64, String::new());
    let mut failures = Vec::new();
    for (c, values) in CHANNELS.iter().zip(&channels) {
        for (name, term) in &terms {
            if let Some(r) = correlation(values, term) {
                if r.abs() > worst.0 {
                    worst = (r.abs(), format!("{c} ~ {name}"));
                }
                if r.abs() >= 0.99 {
                    failures.push(format!("{c} reads {name}: correlation {r:.4}"));
                }
            }
        }
    }
    println!("highest |correlation| of a channel with a truth term: {worst:?}");
    assert!(failures.is_empty(), "{failures:#?}");
}

#[test]
fn held_out_paths_never_retrace_a_training_recording() {
    let m = Mirror::default();
    // Training paths every 0.5 mm, held-out ones every 1 mm: following a training path
    // advances its index by about 2 per held-out sample.
    let trained: Vec<Vec<[f64; 2]>> = PathKind::TRAINING
        .iter()
        .map(|&k| samples(&Path::generate(k, &m, &PathParams::default()), 0.5))
        .collect();
    // A window is 48 ticks at up to 26 mm/s (the feed's peak): under 25 mm of path. No
    // 20 mm of a held-out path may follow the training recording of its own pattern
    // within 1 mm. Another pattern can only touch it where a pass runs tangent to a
    // curved one (a straight pass stays within 1 mm of a 245 mm arc for ~44 mm): such
    // brushes stay under three windows (retrace_limit).
    let mut retraced = Vec::new();
    for kind in PathKind::ALL {
        let held = samples(&Path::generate(kind, &m, &PathParams::held_out(kind)), 1.0);
        let per: Vec<usize> = trained
            .iter()
            .map(|t| longest_retrace(&held, t, 1.0, 6))
            .collect();
        println!("{kind:?} along grid, fermat, hilbert: {per:?} mm");
        for (trained_kind, &mm) in PathKind::TRAINING.iter().zip(&per) {
            if mm >= retrace_limit(*trained_kind, kind) {
                retraced.push(format!(
                    "{kind:?} follows the {trained_kind:?} recording for {mm} mm"
                ));
            }
        }
    }
    assert!(retraced.is_empty(), "{retraced:?}");
    // The check has teeth: the training placement itself, and the raster shifted by
    // half a millimetre, retrace all the way.
    let grid = |params: PathParams| samples(&Path::generate(PathKind::Grid, &m, &params), 1.0);
    assert!(longest_retrace(&grid(PathParams::default())[..200], &trained[0], 1.0, 6) >= 199);
    let turned = PathParams {
        rotation_deg: 0.1,
        ..PathParams::default()
    };
    assert!(longest_retrace(&grid(turned)[..200], &trained[0], 1.0, 6) >= 100);
}

#[test]
fn no_held_out_session_retraces_any_training_placement() {
    // Multi-session training sets with varied placements (docs/twin.md "Sessions") put
    // each pattern at PathParams::training(kind, k); held-out session j puts it at
    // PathParams::held_out_in(kind, j). No held-out placement of any session may follow a
    // training placement of its own pattern for 20 mm (1 mm tolerance), nor another
    // pattern's for three windows: the rule of the test above, over every pair.
    let m = Mirror::default();
    let held = HeldOutPlacements::new(&m);
    let mut retraced = Vec::new();
    for trained_kind in PathKind::TRAINING {
        for k in 0..PathParams::TRAINING_PLACEMENTS {
            let p = PathParams::training(trained_kind, k);
            for (kind, session, mm) in held.retraced_by(&m, trained_kind, &p) {
                retraced.push(format!(
                    "{kind:?} of held-out session {session} follows {trained_kind:?} at \
                     training placement {k} for {mm} mm"
                ));
            }
        }
    }
    assert!(retraced.is_empty(), "{retraced:#?}");
    // Session 0 is the single-session protocol's placement, and placement 0 the default.
    for kind in PathKind::ALL {
        assert_eq!(PathParams::held_out_in(kind, 0), PathParams::held_out(kind));
    }
    for kind in PathKind::TRAINING {
        assert_eq!(PathParams::training(kind, 0), PathParams::default());
    }
    // The check has teeth here too: the spiral at the held-out half turn, as a training
    // placement, retraces the held-out spiral all the way.
    let half = PathParams {
        rotation_deg: 180.0,
        ..PathParams::default()
    };
    let spiral = samples(&Path::generate(PathKind::Fermat, &m, &half), 0.5);
    let held = samples(
        &Path::generate(
            PathKind::Fermat,
            &m,
            &PathParams::held_out_in(PathKind::Fermat, 1),
        ),
        1.0,
    );
    assert!(longest_retrace(&held[..200], &spiral, 1.0, 6) >= 199);
}

#[test]
fn spread_placements_follow_their_rule_and_keep_held_out_unseen() {
    // `--placement spread` (docs/twin.md "Sessions"): the table behind PathParams::spread
    // is what the rule chooses (turns by golden sections of the pattern's direction
    // period, skipping any that retraces a held-out placement of any session, with the
    // pairs and limits of the test above).
    let m = Mirror::default();
    let held = HeldOutPlacements::new(&m);
    for kind in PathKind::TRAINING {
        let table: Vec<PathParams> = (0..PathParams::SPREAD_PLACEMENTS)
            .map(|k| PathParams::spread(kind, k))
            .collect();
        assert_eq!(
            spread_placements(&m, kind, PathParams::SPREAD_PLACEMENTS),
            table,
            "{kind:?}: the table and the rule disagree"
        );
        for (k, p) in table.iter().enumerate() {
            assert_eq!(p.reverse, k % 2 == 1, "{kind:?} spread placement {k}");
        }
        assert_eq!(table[0], PathParams::default());
        // Placements repeat after the table's length, as the quarter turns do after 4.
        assert_eq!(
            PathParams::spread(kind, PathParams::SPREAD_PLACEMENTS + 3),
            table[3]
        );
        // The strokes run every way: over the first four sessions the turns, taken
        // modulo the pattern's direction period, are at least 8° apart.
        let period = iastgcn::twin::retrace::direction_period_deg(kind);
        for i in 0..4 {
            for j in 0..i {
                let d = (table[i].rotation_deg - table[j].rotation_deg).rem_euclid(period);
                assert!(d.min(period - d) >= 8.0, "{kind:?}: {i} and {j} too close");
            }
        }
    }
    // The rule has teeth: a candidate the rule skipped (the Hilbert curve a few degrees
    // off its held-out turn) retraces a held-out placement, and is not in the table.
    let skipped = (0..64)
        .map(|i| spread_candidate_deg(PathKind::Hilbert, i))
        .find(|deg| {
            !(0..PathParams::SPREAD_PLACEMENTS)
                .any(|k| PathParams::spread(PathKind::Hilbert, k).rotation_deg == *deg)
        })
        .expect("the rule skips some candidate");
    let at = PathParams {
        rotation_deg: skipped,
        ..PathParams::default()
    };
    assert!(
        !held.retraced_by(&m, PathKind::Hilbert, &at).is_empty(),
        "{skipped}°"
    );
    // The rosette is never trained on: its spread placement is the default.
    assert_eq!(
        PathParams::spread(PathKind::Rosette, 5),
        PathParams::default()
    );
}

#[test]
fn a_warm_machine_carries_its_temperatures_into_the_next_run() {
    let g = Geometry::default_asset();
    let machine = draw_machine(g.clone(), 1);
    let controller = Robot::nominal(g);
    let config = SimConfig::new(PathKind::Grid, 60.0, 3);
    let mut sim =
        Simulation::new(&machine, &controller, Mirror::default(), config.clone()).unwrap();
    while sim.step().is_some() {}
    let mut warm = sim.machine_state();
    assert!((warm.clock - 60.0).abs() < 1e-9);
    let hot = warm.screw_rise();
    assert!(hot.iter().all(|&r| r > 0.1), "{hot:?}");
    warm.idle(30.0);
    let cooled = warm.screw_rise();
    assert!((0..3).all(|i| cooled[i] < hot[i] && cooled[i] > 0.5 * hot[i]));
    // The same run from the warm state differs from the cold one at its first tick.
    let first = |state| {
        let mut s = Simulation::resume(
            &machine,
            &controller,
            Mirror::default(),
            config.clone(),
            state,
        )
        .unwrap();
        s.step().unwrap().unwrap().hidden.actual.joints.limbs
    };
    let (cold, resumed) = (first(machine.cold()), first(warm));
    assert!(
        (0..3).any(|i| (cold[i] - resumed[i]).abs() > 1e-3),
        "{cold:?} {resumed:?}"
    );
}

#[test]
fn the_error_budget_splits_the_true_error_by_source() {
    use iastgcn::compensate::budget::error_budget;
    let g = Geometry::default_asset();
    let machine = draw_machine(g, 1);
    // A perfect calibration: the controller knows the machine's geometry.
    let config = SimConfig::new(PathKind::Fermat, 60.0, 23);
    let rows = error_budget(&machine, &machine.robot, &config, &machine.cold()).unwrap();
    for r in &rows {
        println!(
            "{:<60} {:>8.2} µm {:>8.2} mdeg",
            r.source, r.position_rms, r.attitude_rms
        );
    }
    assert_eq!(rows.len(), 5);
    // Nothing is left of the geometry in position, and every non-geometric group
    // matters. (In attitude a few mdeg stay: a head whose axes are not quite
    // perpendicular cannot point exactly along its revolution axis, near the centre.)
    assert!(rows[1].position_rms < 1e-3, "{:?}", rows[1]);
    for r in &rows[2..] {
        assert!(r.position_rms > 1.0, "{r:?}");
    }
    // The whole is about the root-sum-square of independent parts: never below the
    // largest one by much, never above their sum.
    let all = rows[0].position_rms;
    let parts: Vec<f64> = rows[2..].iter().map(|r| r.position_rms).collect();
    let largest = parts.iter().cloned().fold(0.0, f64::max);
    assert!(
        all > 0.8 * largest && all < 1.1 * parts.iter().sum::<f64>(),
        "{all} vs {parts:?}"
    );
}
