//! The open-loop diagnosis (docs/results.md "Where the error goes"): a model predicting
//! along a held-out run without its corrections being applied leaves the run exactly the
//! uncompensated one, and its miss is measured against the true residual the oracle
//! feeds back. An ensemble in the loop feeds back its members' mean.

use iastgcn::compensate::held_out::warm_up;
use iastgcn::compensate::online::{self, Feedback, Online};
use iastgcn::graph::Graph;
use iastgcn::model::{Checkpoint, ModelConfig, Normalization, Parameters, Predictor, Variant};
use iastgcn::robot::{Geometry, Robot};
use iastgcn::twin::{draw_machine, Machine, MachineState, PathKind, PathParams, SimConfig};

/// A small IASTGCN whose outputs are `label` (µm, mdeg) whatever it reads: its label
/// scale is zero, so the network's own output does not count.
fn constant(label: [f64; 6]) -> Checkpoint {
    constant_ahead(label, 0)
}

/// [`constant`] for the tick `look_ahead` ticks after its window (on the look-ahead
/// graph from 1 on).
fn constant_ahead(label: [f64; 6], look_ahead: usize) -> Checkpoint {
    let graph = Graph::default_for(look_ahead);
    let config = ModelConfig {
        nodes: graph.len(),
        look_ahead,
        ..ModelConfig::gradient_check(Variant::Iastgcn)
    };
    let mut normalization = Normalization::identity(&config);
    normalization.label_mean = label.to_vec();
    normalization.label_std = vec![0.0; 6];
    Checkpoint {
        parameters: Parameters::init(&config, 3),
        graph,
        normalization,
        config,
    }
}

/// 12 s of the held-out Hilbert curve on the default machine after 30 s of warm-up,
/// under a controller that knows the geometry (what is left is the non-geometric
/// residual): the machine, the controller, the start and the run's settings.
fn hilbert_run() -> (Machine, Robot, MachineState, SimConfig) {
    let machine = draw_machine(Geometry::default_asset(), 1);
    let controller = machine.robot.clone();
    let start = warm_up(&machine, &controller, 30.0, 5).unwrap();
    let mut config = SimConfig::new(PathKind::Hilbert, 12.0, 9);
    config.path_params = PathParams::held_out(PathKind::Hilbert);
    (machine, controller, start, config)
}

/// `ck` predicting along `run` (a [`hilbert_run`]) without its corrections applied.
fn open_loop(
    (machine, controller, start, config): &(Machine, Robot, MachineState, SimConfig),
    ck: &Checkpoint,
    settings: Online,
) -> online::RunResult {
    let mut predictor = Predictor::native(ck).unwrap();
    online::run(
        machine,
        controller,
        config.clone(),
        start.clone(),
        Feedback::OpenLoop(std::slice::from_mut(&mut predictor), &ck.graph, settings),
        |_| {},
    )
    .unwrap()
}

#[test]
fn a_look_ahead_prediction_is_scored_on_the_tick_it_is_for() {
    let run = hilbert_run();
    let settings = Online { every: 1 };
    let score =
        |look_ahead: usize| open_loop(&run, &constant_ahead([0.0; 6], look_ahead), settings);
    let (now, ahead) = (score(0), score(1));
    // Both predict on every tick from the 16th; the look-ahead one's prediction made on
    // tick t is for t + 1 (the last one's tick never comes), and a zero prediction misses
    // by that tick's true residual, as the other's made there does.
    assert_eq!(now.predictions, ahead.predictions);
    assert_eq!(now.open_loop_ticks[0].tick, 15);
    assert_eq!(ahead.open_loop_ticks.len(), now.open_loop_ticks.len() - 1);
    for (a, n) in ahead.open_loop_ticks.iter().zip(&now.open_loop_ticks[1..]) {
        assert_eq!((a.tick, a.miss), (n.tick, n.miss));
    }
    // Predicted (and replayable) on the tick it was made, as any correction.
    assert_eq!(ahead.predicted[0].0, 15);
}

#[test]
fn open_loop_predictions_are_scored_and_never_applied() {
    let run = hilbert_run();
    let (machine, controller, start, config) = &run;
    let settings = Online { every: 5 };
    let plain = online::run(
        machine,
        controller,
        config.clone(),
        start.clone(),
        Feedback::None,
        |_| {},
    )
    .unwrap();
    assert!(plain.open_loop.is_none());
    let score = |label: [f64; 6]| open_loop(&run, &constant(label), settings);
    let zero = score([0.0; 6]);
    // Not applied: the run is the uncompensated one, bit for bit.
    assert_eq!(zero.truth, plain.truth);
    assert_eq!(zero.tracker, plain.tracker);
    // Predictions every 5 ticks once the 16-tick window is full: 600 ticks → 117.
    assert_eq!(zero.predictions, (15..600).step_by(5).count());
    // A zero prediction misses by the whole true residual: about the run's true error
    // (the uncorrected controller expects the target itself), over the predicting ticks.
    let miss = zero.open_loop.unwrap();
    let ratio = miss.position.mean / plain.truth.position.mean;
    assert!(
        (0.9..1.1).contains(&ratio),
        "{ratio}: {miss:?} against {:?}",
        plain.truth
    );
    let ratio = miss.attitude.mean / plain.truth.attitude.mean;
    assert!((0.9..1.1).contains(&ratio), "{ratio}");
    // A prediction 1 mm off along x misses by about 1 mm whatever the residual; a roll
    // about the tool axis is free and not scored.
    let far = score([1000.0, 0.0, 0.0, 0.0, 0.0, 0.0]).open_loop.unwrap();
    assert!(
        (far.position.mean - 1000.0).abs() < 1.05 * plain.truth.position.max,
        "{far:?}"
    );
    assert_eq!(far.attitude, miss.attitude);

    // Fed forward, the open-loop corrections of a model that ignores its inputs are the
    // closed loop itself: the replay sets each at the tick the model would have, so the
    // runs agree bit for bit; a model that reads its inputs would differ by its feedback.
    let label = [40.0, -25.0, 10.0, 8.0, -6.0, 0.0];
    let open = score(label);
    assert_eq!(open.predicted.len(), open.predictions);
    let ck = constant(label);
    let mut predictor = Predictor::native(&ck).unwrap();
    let closed = online::run(
        machine,
        controller,
        config.clone(),
        start.clone(),
        Feedback::Model(std::slice::from_mut(&mut predictor), &ck.graph, settings),
        |_| {},
    )
    .unwrap();
    let replayed = online::run(
        machine,
        controller,
        config.clone(),
        start.clone(),
        Feedback::Replay(&open.predicted),
        |_| {},
    )
    .unwrap();
    assert_eq!(replayed.truth, closed.truth);
    assert_eq!(replayed.predictions, closed.predictions);
    assert_ne!(replayed.truth, plain.truth);
}

#[test]
fn an_ensemble_feeds_back_the_mean_of_its_members() {
    let machine = draw_machine(Geometry::default_asset(), 1);
    let controller = machine.robot.clone();
    let start = warm_up(&machine, &controller, 10.0, 5).unwrap();
    let mut config = SimConfig::new(PathKind::Grid, 6.0, 9);
    config.path_params = PathParams::held_out(PathKind::Grid);
    let graph = Graph::default_asset();
    let settings = Online { every: 5 };
    let closed = |members: &mut [Predictor]| {
        online::run(
            &machine,
            &controller,
            config.clone(),
            start.clone(),
            Feedback::Model(members, &graph, settings),
            |_| {},
        )
        .unwrap()
    };
    let native = |label: [f64; 6]| Predictor::native(&constant(label)).unwrap();
    let a = [40.0, -20.0, 10.0, 8.0, -6.0, 0.0];
    let b = [20.0, -10.0, 30.0, 4.0, -2.0, 0.0];
    let mean = [30.0, -15.0, 20.0, 6.0, -4.0, 0.0];
    let pair = closed(&mut [native(a), native(b)]);
    let one = closed(&mut [native(mean)]);
    // The same corrections at the same ticks: the same run, bit for bit.
    assert_eq!(pair.truth, one.truth);
    assert_eq!(pair.predictions, one.predictions);
    assert_ne!(pair.truth, closed(&mut [native(a)]).truth);
    // An ensemble of none is refused, not run uncompensated.
    let err = online::run(
        &machine,
        &controller,
        config.clone(),
        start.clone(),
        Feedback::Model(&mut [], &graph, settings),
        |_| {},
    )
    .unwrap_err();
    assert!(err.to_string().contains("at least one predictor"), "{err}");
}

/// The look-ahead oracle (docs/results.md "The look-ahead floor"): on each tick it acts
/// (from the window's last tick, every `every`) it sets the true residual of the next
/// tick; replayed, the first pass reproduces the uncompensated run's residuals it was
/// built from up to the corrections' own effect, and its fixed point converges and
/// leaves less than the oracle of the tick just measured on the Hilbert curve; Table V's
/// oracle is the one or the other as the models look ahead or not.
#[test]
fn the_look_ahead_oracle_sets_the_next_ticks_residual_and_converges() {
    let (machine, controller, start, config) = hilbert_run();
    let (plain, residuals) = online::with_true_residuals(
        &machine,
        &controller,
        config.clone(),
        start.clone(),
        Feedback::None,
    )
    .unwrap();
    assert_eq!(residuals.len(), config.steps());
    let ahead = online::look_ahead(&residuals, 48, 5, 1);
    assert_eq!(
        ahead.first().map(|a| a.0),
        Some(50),
        "from tick 47 on, every 5th"
    );
    for (t, c) in &ahead {
        assert!(t % 5 == 0 && *t + 1 >= 48);
        assert_eq!(
            c.dp,
            residuals[t + 1].dp,
            "tick {t} sets tick {}'s residual",
            t + 1
        );
    }
    let last = residuals.len() - 1;
    assert!(
        ahead.iter().all(|(t, _)| *t < last),
        "no tick past the run's end"
    );
    let oracle = online::run(
        &machine,
        &controller,
        config.clone(),
        start.clone(),
        Feedback::Oracle {
            window: 48,
            settings: Online { every: 1 },
        },
        |_| {},
    )
    .unwrap();
    let (run, passes) =
        online::look_ahead_oracle(&machine, &controller, &config, &start, 48, 1, 1, 4).unwrap();
    eprintln!(
        "calibrated {:.2} µm, oracle {:.2}, look-ahead passes {passes:?}",
        plain.truth.position.mean, oracle.truth.position.mean
    );
    assert_eq!(passes.len(), 4);
    let step = |i: usize| (passes[i] - passes[i + 1]).abs();
    assert!(
        step(2) < 0.2 * step(0).max(1e-9) + 0.05,
        "the passes converge: {passes:?}"
    );
    assert!(run.truth.position.mean < oracle.truth.position.mean);
    assert!(run.truth.position.mean < 0.2 * plain.truth.position.mean);
    // Table V's oracle stands in for a model: the oracle of the tick just measured for
    // one that does not look ahead, this fixed point for one that looks a tick ahead; two
    // ticks ahead set the residual of the tick after next.
    let settings = Online { every: 1 };
    let table_v = |ahead| {
        online::oracle(&machine, &controller, &config, &start, 48, settings, ahead).unwrap()
    };
    assert_eq!(table_v(0).truth, oracle.truth);
    assert_eq!(table_v(1).truth, run.truth);
    let two = online::look_ahead(&residuals, 48, 1, 2);
    assert!(two.iter().all(|(t, c)| c.dp == residuals[t + 2].dp));
    assert_eq!(two.last().map(|a| a.0), Some(last - 2));
}
