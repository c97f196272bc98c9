//! The twin's non-geometric sources: each behaves as its physics says, and together they
//! make the pose error depend on the machine's history, not only on its pose.

use iastgcn::robot::{Configuration, Geometry, Robot};
use iastgcn::twin::sources::{
    Backlash, BacklashParams, LostMotion, LostMotionParams, NonGeometric, Play, Thermal,
    ThermalParams,
};
use iastgcn::twin::{draw_machine, measure_calibration, Machine, SensorSpecs};

#[test]
fn play_lags_by_half_the_slack_and_holds_on_reversal() {
    let mut p = Play::new();
    assert_eq!(p.step(0.0, 0.02), 0.0);
    // Moving up: the driven side trails by half the slack.
    assert!((p.step(1.0, 0.02) - 0.99).abs() < 1e-12);
    // Reversing by less than the slack: the driven side does not move.
    assert!((p.step(0.995, 0.02) - 0.99).abs() < 1e-12);
    // Past the slack it follows, now leading from the other side.
    assert!((p.step(0.5, 0.02) - 0.51).abs() < 1e-12);
}

#[test]
fn lost_motion_grows_with_travel() {
    let mut lm = LostMotion::new(LostMotionParams {
        width: [0.02; 3],
        wear_per_m: 0.1,
    });
    let w0 = lm.width();
    for k in 0..=2000 {
        // 2000 strokes of ±0.5 m... in 1 mm steps: 2 m of travel per limb.
        let x = if (k / 1000) % 2 == 0 {
            (k % 1000) as f64
        } else {
            1000.0 - (k % 1000) as f64
        };
        lm.step([x; 3]);
    }
    let w1 = lm.width();
    assert!((w1[0] / w0[0] - 1.2).abs() < 0.01, "{w0:?} -> {w1:?}");
}

#[test]
fn backlash_error_flips_sign_with_direction() {
    let w = 0.02f64.to_radians();
    let mut b = Backlash::new(BacklashParams {
        width: [w, w],
        transmission_error: [0.0; 2],
        transmission_phase: [0.0; 2],
        ratio: 100.0,
    });
    b.step([0.0, 0.0]);
    let up = b.step([0.01, 0.01]);
    let mut b2 = Backlash::new(BacklashParams {
        width: [w, w],
        transmission_error: [0.0; 2],
        transmission_phase: [0.0; 2],
        ratio: 100.0,
    });
    b2.step([0.02, 0.02]);
    let down = b2.step([0.01, 0.01]);
    assert!(
        (up[0] + 0.5 * w).abs() < 1e-15 && (down[0] - 0.5 * w).abs() < 1e-15,
        "{up:?} {down:?}"
    );
}

#[test]
fn thermal_elongation_settles_to_gain_times_speed() {
    let p = ThermalParams {
        gain_per_speed: [2.0, 1.0, 0.0],
        time_constant: 60.0,
        expansion: 11.5e-6,
        tube_length: 300.0,
        tube_share: 0.5,
        tube_time_constant: 120.0,
        ambient_amplitude: 0.0,
        ambient_period: 3600.0,
        ambient_phase: 0.0,
    };
    let mut th = Thermal::new(p);
    let dt = 0.1;
    // The nut 400 mm from its bearing: the screw grows over that span only.
    let travel = [400.0; 3];
    let mut e = th.step(0.0, dt, [0.0; 3], travel);
    let mut x = 0.0;
    for k in 1..30_000 {
        x = 5.0 * k as f64 * dt; // 5 mm/s for 3000 s, ≫ both time constants
        e = th.step(k as f64 * dt, dt, [x; 3], travel);
    }
    // Equilibrium rise 10 K and 5 K in the screws, half of that in the tubes.
    let screw = |rise: f64| 11.5e-6 * 400.0 * rise;
    let tube = |rise: f64| 11.5e-6 * 300.0 * 0.5 * rise;
    assert!((e.screw[0] - screw(10.0)).abs() < 1e-9, "{e:?}");
    assert!((e.screw[1] - screw(5.0)).abs() < 1e-9, "{e:?}");
    assert!((e.tube[0] - tube(10.0)).abs() < 1e-9, "{e:?}");
    assert_eq!(e.total()[2], 0.0);
    // After one screw time constant at rest, 1/e of the screw's growth is left; the
    // slower tube has lost less than half of its own.
    th.idle(60.0);
    let e = th.step(3060.0, dt, [x; 3], travel);
    assert!(
        (e.screw[0] / screw(10.0) - (-1.0f64).exp()).abs() < 0.01,
        "{e:?}"
    );
    let kept = e.tube[0] / tube(10.0);
    assert!((0.5..0.9).contains(&kept), "tube kept {kept}");
}

/// Drives the machine to one configuration through a short approach from `from`, and
/// returns the true pad position.
fn approach(
    machine: &Machine,
    controller: &Robot,
    from: &Configuration,
    to: &Configuration,
) -> nalgebra::Vector3<f64> {
    let noise = SensorSpecs::default();
    let m = measure_calibration(machine, controller, &[*from, *to], &noise, 1, 0).unwrap();
    m[1].actual.translation.vector
}

#[test]
fn the_same_pose_reached_from_opposite_sides_differs() {
    let g = Geometry::default_asset();
    let full = draw_machine(g.clone(), 1);
    let controller = Robot::nominal(g);
    let home = controller.home();
    let at = |dw: f64| Configuration {
        platform: iastgcn::robot::PlatformPose {
            w: home.w + dw,
            ..home
        },
        head: [0.3, 0.1],
    };
    let target = at(0.0);
    let from_above = approach(&full, &controller, &at(-20.0), &target);
    let from_below = approach(&full, &controller, &at(20.0), &target);
    let gap = (from_above - from_below).norm();
    // Lost motion of 10–30 µm per limb, amplified by the platform's lever: tens of µm.
    assert!(
        (0.01..0.2).contains(&gap),
        "approach-direction difference {gap} mm"
    );
    // Without lost motion, backlash and the heat of the approach, the two agree.
    let rigid = Machine {
        nongeometric: NonGeometric {
            lost_motion: None,
            backlash: None,
            thermal: None,
            ..full.nongeometric
        },
        ..full.clone()
    };
    let gap = (approach(&rigid, &controller, &at(-20.0), &target)
        - approach(&rigid, &controller, &at(20.0), &target))
    .norm();
    assert!(gap < 1e-6, "{gap}");
}
