//! The identification Jacobian: closed-form serial/tool/tracker columns against central
//! differences of the full error kinematics, and the parallel columns against the
//! kinematics' own first-order response.

use iastgcn::calibrate::jacobian::{analytic_serial, measured_pose, numeric, twist};
use iastgcn::robot::{ErrorParams, Geometry, Joints, Robot, N_PARAMS};
use iastgcn::testing::{compare, rng, Tolerance};
use iastgcn::twin::{calibration_configurations, draw_errors, ErrorScales};
use rand::RngExt;

fn robots() -> [Robot; 2] {
    let nominal = Robot::nominal(Geometry::default_asset());
    let twin = nominal.with_errors(draw_errors(1, &ErrorScales::default()));
    [nominal, twin]
}

#[test]
fn closed_form_serial_columns_match_central_differences() {
    for robot in robots() {
        for c in calibration_configurations(&robot, 5, 3) {
            let joints = Joints {
                limbs: robot.limb_lengths(&c.platform),
                head: c.head,
            };
            let jn = numeric(&robot, &joints, c.platform).unwrap();
            let ja = analytic_serial(&robot, &joints, &c.platform);
            let cols: Vec<usize> = ErrorParams::serial_indices()
                .chain(ErrorParams::tracker_indices())
                .collect();
            let pick = |j: &nalgebra::DMatrix<f64>| {
                cols.iter()
                    .flat_map(|&k| j.column(k).iter().copied().collect::<Vec<_>>())
                    .collect::<Vec<f64>>()
            };
            // Entries are O(1) mm/mm and O(1000) mm/rad; central differences with a 1e-6
            // step are good to ~1e-7 of that.
            compare(
                "serial/tool/tracker columns",
                &pick(&ja),
                &pick(&jn),
                Tolerance::new(1e-5, 1e-6),
            )
            .unwrap();
        }
    }
}

#[test]
fn parallel_columns_predict_the_first_order_response() {
    let [_, robot] = robots();
    let mut r = rng(4);
    let names = ErrorParams::names();
    for c in calibration_configurations(&robot, 4, 8) {
        let joints = Joints {
            limbs: robot.limb_lengths(&c.platform),
            head: c.head,
        };
        let j = numeric(&robot, &joints, c.platform).unwrap();
        let p0 = measured_pose(&robot, &joints, c.platform).unwrap();
        // A small random change of every parallel parameter (1e-3 mm / 1e-5 rad).
        let mut e = robot.errors.clone();
        let mut delta = nalgebra::DVector::zeros(N_PARAMS);
        for k in ErrorParams::parallel_indices() {
            let s = if names[k].contains("theta") {
                1e-5
            } else {
                1e-3
            };
            delta[k] = r.random_range(-s..s);
            e.values[k] += delta[k];
        }
        let p1 = measured_pose(&robot.with_errors(e), &joints, c.platform).unwrap();
        let actual = twist(&p0, &p1);
        let predicted = &j * &delta;
        // Second-order terms are ~1e-3 of the first-order ones at this size.
        compare(
            "first-order response",
            &predicted.iter().copied().collect::<Vec<_>>(),
            &actual,
            Tolerance::new(1e-8, 2e-3),
        )
        .unwrap();
    }
}

#[test]
fn stacked_jacobian_reveals_unidentifiable_parameters() {
    // Over many poses the stacked Jacobian has a null space: parameters whose effect the
    // tracker cannot see (e.g. θ_N, absorbed by the free Hooke angles) or cannot tell
    // apart (a shaft-length error and a drive zero offset along the same limb).
    let [_, robot] = robots();
    let poses = calibration_configurations(&robot, 30, 2);
    let mut stacked = nalgebra::DMatrix::zeros(6 * poses.len(), N_PARAMS);
    for (i, c) in poses.iter().enumerate() {
        let joints = Joints {
            limbs: robot.limb_lengths(&c.platform),
            head: c.head,
        };
        stacked
            .view_mut((6 * i, 0), (6, N_PARAMS))
            .copy_from(&numeric(&robot, &joints, c.platform).unwrap());
    }
    let sv = stacked.clone().svd(false, false).singular_values;
    let rank = sv.iter().filter(|&&s| s > 1e-6 * sv[0]).count();
    println!(
        "identification Jacobian over {} poses: rank {rank} of {N_PARAMS}",
        poses.len()
    );
    assert!(rank > 30 && rank < N_PARAMS, "rank {rank}");
    let names = ErrorParams::names();
    let col = |n: &str| {
        stacked
            .column(names.iter().position(|x| x == n).unwrap())
            .norm()
    };
    println!(
        "column norms: theta_n {:.3e}, theta_b {:.3e}, theta_a {:.3e}, db {:.3e}",
        col("limb1.theta_n.x"),
        col("limb1.theta_b.x"),
        col("limb1.theta_a.x"),
        col("limb1.db.x")
    );
    // The joints are ideal spherical centres with the composite joint's shaft on the limb
    // axis, so a joint frame's attitude error moves the pad only through the sub-millimetre
    // offsets it turns: far weaker than a joint-centre position error.
    for theta in [
        "limb1.theta_b.x",
        "limb1.theta_n.x",
        "limb1.theta_m.y",
        "limb1.theta_a.z",
    ] {
        assert!(col(theta) < 0.2 * col("limb1.db.x"), "{theta}");
    }
}
