//! Look-ahead prediction (docs/model.md "Look-ahead"): the twin's planned-motion channels
//! are the controller's program (the target's motion to the next tick, the same whatever
//! was measured or corrected), a look-ahead window reads no row after its last step and
//! is labelled by the next row, the contiguous split keeps a window's label row in its
//! block, and the look-ahead graphs are Table II's (and the force node's) with the plan as
//! three more nodes.

use iastgcn::data::{
    prepare, split, tracker_columns, window_ends, Dataset, FeatureConfig, Recording, Row,
    SplitMode, Window, WindowConfig,
};
use iastgcn::graph::Graph;
use iastgcn::robot::Geometry;
use iastgcn::twin::{
    draw_machine, Correction, Mirror, PathKind, Sample, SimConfig, Simulation, CHANNELS,
    PLAN_CHANNELS, SENSOR_CHANNELS,
};

/// Every tick of `seconds` of the Hilbert curve on machine 1 under its own geometry, with
/// `correct` applied from tick 200 on.
fn hilbert(seconds: f64, correct: Option<Correction>) -> Vec<Sample> {
    let machine = draw_machine(Geometry::default_asset(), 1);
    let controller = machine.robot.clone();
    let mut sim = Simulation::new(
        &machine,
        &controller,
        Mirror::default(),
        SimConfig::new(PathKind::Hilbert, seconds, 11),
    )
    .unwrap();
    let mut samples = Vec::new();
    while let Some(s) = sim.step() {
        samples.push(s.unwrap());
        if let (Some(c), 200) = (correct, samples.len()) {
            sim.set_correction(c);
        }
    }
    samples
}

fn recording(samples: &[Sample]) -> Recording {
    Recording {
        channels: CHANNELS.iter().map(|c| c.to_string()).collect(),
        rows: samples
            .iter()
            .map(|s| Row {
                t: s.t,
                values: s.channels.to_vec(),
                tracker: s.tracker.map(|p| tracker_columns(&p)),
            })
            .collect(),
    }
}

#[test]
fn the_look_ahead_graph_is_table_ii_and_the_plan() {
    let (table_ii, g) = (Graph::default_asset(), Graph::look_ahead_asset());
    assert_eq!(g.nodes[..14], table_ii.nodes[..]);
    assert_eq!(g.nodes[14..], PLAN_CHANNELS.map(String::from));
    assert_eq!(Graph::default_for(0), table_ii);
    assert_eq!(Graph::default_for(1), g);
    // Table II's edges are all there; every plan node reaches a sensor node.
    let named = |g: &Graph, (i, j): (usize, usize)| {
        let mut e = [g.nodes[i].clone(), g.nodes[j].clone()];
        e.sort();
        e
    };
    let edges: Vec<[String; 2]> = g.edges.iter().map(|&e| named(&g, e)).collect();
    for &e in &table_ii.edges {
        assert!(
            edges.contains(&named(&table_ii, e)),
            "{:?}",
            named(&table_ii, e)
        );
    }
    let a = g.adjacency();
    for p in 14..17 {
        assert!(
            (0..14).any(|s| a[(p, s)] > 0.0),
            "{} is cut off",
            g.nodes[p]
        );
    }
    // Every node is a channel the twin records, so its loop can feed the model.
    assert!(g.nodes.iter().all(|n| CHANNELS.contains(&n.as_str())));
    assert_eq!(CHANNELS[SENSOR_CHANNELS..], PLAN_CHANNELS);
    // The force node's graph looking ahead: the force graph's nodes and edges, then the
    // plan's nodes with the look-ahead graph's edges.
    let root = env!("CARGO_MANIFEST_DIR");
    let force = Graph::load(format!("{root}/assets/graph-force.toml").as_ref()).unwrap();
    let both = Graph::load(format!("{root}/assets/graph-force-look-ahead.toml").as_ref()).unwrap();
    assert_eq!(both.nodes[..15], force.nodes[..]);
    assert_eq!(both.nodes[15..], g.nodes[14..]);
    let names = |g: &Graph| -> Vec<[String; 2]> { g.edges.iter().map(|&e| named(g, e)).collect() };
    let (in_both, in_force, in_ahead) = (names(&both), names(&force), names(&g));
    assert!(in_force
        .iter()
        .chain(&in_ahead)
        .all(|e| in_both.contains(e)));
    assert_eq!(
        in_both.len(),
        in_force.len() + in_ahead.len() - table_ii.edges.len()
    );
}

#[test]
fn the_plan_is_the_next_ticks_target_motion_and_nothing_measured() {
    let plain = hilbert(8.0, None);
    let dt = plain[1].t - plain[0].t;
    // The planned velocity of tick k is the path target's motion to tick k + 1, as the
    // next tick computes it: the same bits.
    for w in plain.windows(2) {
        let motion = (w[1].hidden.target.position - w[0].hidden.target.position) / dt;
        let plan: Vec<f64> = w[0].channels[SENSOR_CHANNELS..]
            .iter()
            .map(|v| v.unwrap())
            .collect();
        assert_eq!(plan, motion.as_slice(), "tick at t = {}", w[0].t);
    }
    // The path turns: the plan changes direction, which is what a look-ahead model reads.
    let turns = plain
        .windows(2)
        .filter(|w| {
            let v = |s: &Sample| [0, 1].map(|k| s.channels[SENSOR_CHANNELS + k].unwrap());
            let (a, b) = (v(&w[0]), v(&w[1]));
            let dot = a[0] * b[0] + a[1] * b[1];
            // More than 30° from one tick to the next.
            dot < 0.866 * a[0].hypot(a[1]) * b[0].hypot(b[1])
        })
        .count();
    println!("{turns} ticks turn the plan by more than 30°");
    assert!(turns > 0, "no turn in the Hilbert curve's plan");
    // A correction moves the machine and every sensor that sees it, never the plan: the
    // program does not depend on what was measured.
    let corrected = hilbert(
        8.0,
        Some(Correction {
            dp: nalgebra::Vector3::new(0.05, -0.03, 0.01),
            dr: nalgebra::Vector3::zeros(),
        }),
    );
    assert_eq!(plain.len(), corrected.len());
    let mut sensors_moved = false;
    for (a, b) in plain.iter().zip(&corrected) {
        assert_eq!(a.channels[SENSOR_CHANNELS..], b.channels[SENSOR_CHANNELS..]);
        sensors_moved |= a.channels[..SENSOR_CHANNELS] != b.channels[..SENSOR_CHANNELS];
    }
    assert!(sensors_moved, "the correction changed no sensor");
}

#[test]
fn a_look_ahead_window_ends_a_row_before_its_label_and_reads_nothing_after() {
    let samples = hilbert(6.0, None);
    let rec = recording(&samples);
    let graph = Graph::look_ahead_asset();
    let robot = draw_machine(Geometry::default_asset(), 1).robot;
    let features = FeatureConfig::default();
    let prepared = prepare("hilbert", &rec, &graph, &robot, &features).unwrap();
    let window = WindowConfig {
        length: 16,
        stride: 5,
        look_ahead: 1,
        ..WindowConfig::default()
    };
    let data = Dataset::build(
        &[("hilbert".into(), rec.clone())],
        &graph,
        &robot,
        &features,
        &window,
        SplitMode::Contiguous,
    )
    .unwrap();
    assert!(data.windows.len() > 20);
    let norm = &data.normalization;
    let len = data.window_len();
    for (i, w) in data.windows.iter().enumerate() {
        // Labelled by the next row: the tracker measured there, not at the window's end.
        let label = prepared.labels[w.end + 1].unwrap();
        assert!(prepared.labels[w.end].is_none());
        assert_eq!(data.labels[i], label);
        assert_eq!(data.axes[i], prepared.axes[w.end + 1].unwrap());
        // The inputs are the window's own rows, standardised.
        for (k, &x) in data.x[i * len..(i + 1) * len].iter().enumerate() {
            let (n, f, t) = (k / (3 * 16), k / 16 % 3, k % 16);
            let r = prepared.features[n][f][w.end + 1 - 16 + t];
            let z = ((r - norm.feature_mean[n][f]) / norm.feature_std[n][f]) as f32;
            assert_eq!(x, z, "window {i} value {k}");
        }
    }
    // Nothing after a window's last row reaches it: every column of every later row,
    // sensors, plan and tracker, replaced, and the window reads the same.
    let w = data.windows[data.windows.len() / 2];
    let mut changed = rec.clone();
    for row in &mut changed.rows[w.end + 1..] {
        for v in row.values.iter_mut().flatten() {
            *v = *v * 1.001 + 0.01;
        }
        row.tracker = row.tracker.map(|p| p.map(|v| v * 1.001));
    }
    let again = prepare("hilbert", &changed, &graph, &robot, &features).unwrap();
    let (mut before, mut after) = (Vec::new(), Vec::new());
    prepared.window(w.end, 16, &mut before);
    again.window(w.end, 16, &mut after);
    assert_eq!(before, after);
}

#[test]
fn the_contiguous_split_keeps_a_label_row_in_its_windows_block() {
    let config = |look_ahead| WindowConfig {
        length: 10,
        stride: 1,
        look_ahead,
        ..WindowConfig::default()
    };
    let windows = |c: &WindowConfig| -> Vec<Window> {
        window_ends(200, c, |_| true)
            .into_iter()
            .map(|end| Window { recording: 0, end })
            .collect()
    };
    let (now, ahead) = (config(0), config(1));
    let s0 = split(&windows(&now), &[200], &now, SplitMode::Contiguous);
    let s1 = split(&windows(&ahead), &[200], &ahead, SplitMode::Contiguous);
    // Rows 0-139 train, 140-179 validate, 180-199 test: the window ending at row 139
    // trains when its label is row 139's, and belongs to no split when it is row 140's.
    assert_eq!(s0.train.last().unwrap().end, 139);
    assert_eq!(s1.train.last().unwrap().end, 138);
    assert_eq!(s0.validation.last().unwrap().end, 179);
    assert_eq!(s1.validation.last().unwrap().end, 178);
    assert_eq!(s1.test.first().unwrap().end, 189);
    assert_eq!(s1.test.last().unwrap().end, 198);
    assert_eq!(window_ends(200, &ahead, |_| true).last(), Some(&198));
    for (block, ws) in [(140, &s1.train), (180, &s1.validation), (200, &s1.test)] {
        assert!(ws.iter().all(|w| w.end + 1 < block));
    }
}
