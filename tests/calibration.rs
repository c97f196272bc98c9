//! EKF calibration on twin data: recovery of injected errors within their posterior σ,
//! held-out pose error down to the non-geometric floor, order independence, bad input.

use iastgcn::calibrate::jacobian::twist;
use iastgcn::calibrate::{calibrate, Calibration, CalibrationError, EkfConfig, Measurement};
use iastgcn::robot::{Configuration, ErrorParams, Geometry, Robot};
use iastgcn::twin::sources::NonGeometric;
use iastgcn::twin::{
    calibration_configurations, draw_errors, draw_machine, measure_calibration, ErrorScales,
    Installation, Machine, SensorSpecs,
};

fn measure(
    machine: &Machine,
    nominal: &Robot,
    configs: &[Configuration],
    seed: u64,
) -> Vec<Measurement> {
    measure_calibration(machine, nominal, configs, &SensorSpecs::default(), 10, seed)
        .unwrap()
        .into_iter()
        .map(|m| Measurement {
            joints: m.joints,
            pose: m.measured,
        })
        .collect()
}

/// Mean position (µm) and attitude (mdeg) error of `model`'s prediction of measurements.
fn model_error(model: &Robot, ms: &[Measurement]) -> (f64, f64) {
    let (mut p, mut a) = (0.0, 0.0);
    for m in ms {
        let (_, pose) = model.forward(&m.joints, None).unwrap();
        let d = twist(&(model.tracker_from_base() * pose), &m.pose);
        p += (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() * 1e3;
        a += (d[3] * d[3] + d[4] * d[4] + d[5] * d[5])
            .sqrt()
            .to_degrees()
            * 1e3;
    }
    (p / ms.len() as f64, a / ms.len() as f64)
}

fn geometric_machine(errors: ErrorParams) -> Machine {
    Machine {
        robot: Robot::new(Geometry::default_asset(), errors),
        nongeometric: NonGeometric::none(),
        sensors: Installation::default(),
    }
}

#[test]
fn identifiable_parameters_are_recovered_within_three_sigma() {
    let nominal = Robot::nominal(Geometry::default_asset());
    let configs = calibration_configurations(&nominal, 60, 21);
    let config = EkfConfig::default();
    // First find which parameters this pose set identifies, then inject errors into
    // exactly those (so the truth is representable) and check each estimate.
    let full = draw_errors(1, &ErrorScales::default());
    let probe = calibrate(
        &nominal,
        &measure(&geometric_machine(full.clone()), &nominal, &configs, 5),
        &config,
    )
    .unwrap();
    let mut truth = ErrorParams::zero();
    for &k in &probe.identified {
        truth.values[k] = full.values[k];
    }
    let cal: Calibration = calibrate(
        &nominal,
        &measure(&geometric_machine(truth.clone()), &nominal, &configs, 6),
        &config,
    )
    .unwrap();
    assert_eq!(cal.identified, probe.identified);
    let names = ErrorParams::names();
    let mut worst = (0.0, String::new());
    for (i, &k) in cal.identified.iter().enumerate() {
        let sigma = cal.covariance[(i, i)].sqrt();
        let z = (cal.errors.values[k] - truth.values[k]) / sigma;
        if z.abs() > worst.0 {
            worst = (z.abs(), names[k].clone());
        }
        assert!(
            z.abs() <= 3.0,
            "{}: estimate {:.3e}, truth {:.3e}, σ {:.3e} ({z:.1}σ)",
            names[k],
            cal.errors.values[k],
            truth.values[k],
            sigma
        );
    }
    println!(
        "{} parameters identified; worst {} at {:.2}σ; stages {:?}",
        cal.identified.len(),
        worst.1,
        worst.0,
        cal.stages
    );
}

#[test]
fn held_out_error_falls_to_the_non_geometric_floor() {
    let g = Geometry::default_asset();
    let nominal = Robot::nominal(g.clone());
    let machine = draw_machine(g, 1);
    let fit = measure(
        &machine,
        &nominal,
        &calibration_configurations(&nominal, 60, 31),
        7,
    );
    let held = measure(
        &machine,
        &nominal,
        &calibration_configurations(&nominal, 20, 32),
        8,
    );
    let cal = calibrate(&nominal, &fit, &EkfConfig::default()).unwrap();
    let calibrated = nominal.with_errors(cal.errors.clone());
    let before = model_error(&nominal, &held);
    let after = model_error(&calibrated, &held);
    let floor = model_error(&machine.robot, &held);
    println!(
        "held-out poses: nominal {:.0} µm / {:.1} mdeg, calibrated {:.0} µm / {:.1} mdeg, true geometry (floor) {:.0} µm / {:.1} mdeg",
        before.0, before.1, after.0, after.1, floor.0, floor.1
    );
    assert!(after.0 < 0.15 * before.0 && after.1 < 0.3 * before.1);
    // At rest the floor is lost motion, backlash, gravity sag and tracker noise.
    assert!(
        after.0 < floor.0 * 1.5 + 10.0,
        "calibrated {after:?} vs floor {floor:?}"
    );
    assert!(
        after.1 < floor.1 * 1.5 + 2.0,
        "calibrated {after:?} vs floor {floor:?}"
    );
}

#[test]
fn measurement_order_does_not_matter() {
    let nominal = Robot::nominal(Geometry::default_asset());
    let machine = geometric_machine(draw_errors(1, &ErrorScales::default()));
    let ms = measure(
        &machine,
        &nominal,
        &calibration_configurations(&nominal, 50, 41),
        9,
    );
    let mut shuffled = ms.clone();
    shuffled.reverse();
    shuffled.swap(3, 17);
    let config = EkfConfig::default();
    let a = calibrate(&nominal, &ms, &config).unwrap();
    let b = calibrate(&nominal, &shuffled, &config).unwrap();
    for (i, &k) in a.identified.iter().enumerate() {
        let sigma = a.covariance[(i, i)].sqrt();
        let d = (a.errors.values[k] - b.errors.values[k]).abs();
        assert!(
            d < 0.01 * sigma,
            "parameter {k}: moved {d:.3e} = {:.4}σ",
            d / sigma
        );
    }
}

#[test]
fn too_few_poses_are_refused() {
    let nominal = Robot::nominal(Geometry::default_asset());
    let machine = geometric_machine(draw_errors(1, &ErrorScales::default()));
    let ms = measure(
        &machine,
        &nominal,
        &calibration_configurations(&nominal, 3, 1),
        1,
    );
    let err = calibrate(&nominal, &ms, &EkfConfig::default()).unwrap_err();
    assert!(matches!(err, CalibrationError::TooFew { .. }), "{err}");
    assert!(err.to_string().contains("too few"), "{err}");
}

#[test]
fn one_pose_measured_forty_times_is_refused() {
    // 40 measurements "identified 6 of 110 parameters" from a single pose, silently.
    let nominal = Robot::nominal(Geometry::default_asset());
    let machine = geometric_machine(draw_errors(1, &ErrorScales::default()));
    let one = calibration_configurations(&nominal, 1, 1);
    let repeated = vec![one[0]; 40];
    let ms = measure(&machine, &nominal, &repeated, 1);
    assert_eq!(ms.len(), 40);
    assert_eq!(iastgcn::calibrate::identify::distinct_poses(&ms), 1);
    let err = calibrate(&nominal, &ms, &EkfConfig::default()).unwrap_err();
    let text = err.to_string();
    assert!(
        matches!(err, CalibrationError::TooFew { distinct: 1, .. }),
        "{text}"
    );
    assert!(
        text.contains("40 measurements (distinct poses: 1)"),
        "{text}"
    );
}

#[test]
fn calibration_file_round_trips_and_residuals_are_the_label() {
    let nominal = Robot::nominal(Geometry::default_asset());
    let truth = draw_errors(1, &ErrorScales::default());
    let machine = geometric_machine(truth);
    let ms = measure(
        &machine,
        &nominal,
        &calibration_configurations(&nominal, 40, 51),
        2,
    );
    let cal = calibrate(&nominal, &ms, &EkfConfig::default()).unwrap();
    let dir = std::env::temp_dir().join(format!("iastgcn-calfile-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("calibration.toml");
    iastgcn::calibrate::file::save(&path, &cal, ms.len()).unwrap();
    let back = iastgcn::calibrate::file::load(&path).unwrap();
    assert_eq!(back.errors, cal.errors);
    assert_eq!(back.identified.len(), cal.identified.len());
    // A damaged file says what is wrong.
    let text = std::fs::read_to_string(&path).unwrap();
    std::fs::write(&path, text.replace("\"limb1.db.x\"", "\"limb9.db.x\"")).unwrap();
    let err = iastgcn::calibrate::file::load(&path)
        .unwrap_err()
        .to_string();
    assert!(err.contains("unknown parameter \"limb9.db.x\""), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
    // Eq. 19 under the calibrated model: small (tracker noise, µm and mdeg) for these
    // purely geometric measurements, and exactly the pose gap it is defined as.
    let model = nominal.with_errors(back.errors);
    for m in &ms[..5] {
        let (r, _) = iastgcn::calibrate::residual(&model, &m.joints, &m.pose, None).unwrap();
        assert!(
            r[..3].iter().all(|v| v.abs() < 30.0) && r[3..].iter().all(|v| v.abs() < 5.0),
            "{r:?}"
        );
        let (_, cg) = model.forward(&m.joints, None).unwrap();
        let in_base = model.tracker_from_base().inverse() * m.pose;
        let dp = (in_base.translation.vector - cg.translation.vector) * 1e3;
        assert!((dp.x - r[0]).abs() < 1e-9 && (dp.z - r[2]).abs() < 1e-9);
    }
}

#[test]
fn calibrate_cli_reports_before_and_after() {
    let dir = std::env::temp_dir().join(format!("iastgcn-calcli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bin = env!("CARGO_BIN_EXE_iastgcn");
    let run = |args: &[&str]| {
        let o = std::process::Command::new(bin)
            .args(args)
            .current_dir(&dir)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8(o.stdout).unwrap()
    };
    run(&[
        "simulate",
        "--trajectory",
        "calibration",
        "--poses",
        "50",
        "--out",
        "cal.csv",
    ]);
    run(&[
        "simulate",
        "--trajectory",
        "grid",
        "--minutes",
        "0.2",
        "--out",
        "grid.csv",
    ]);
    let out = run(&[
        "calibrate",
        "--measurements",
        "cal.csv",
        "--out",
        "calibration.toml",
        "--recordings",
        "grid.csv",
    ]);
    assert!(
        out.contains("identified")
            && out.contains("held-out poses (10)")
            && out.contains("grid.csv"),
        "{out}"
    );
    assert!(dir.join("calibration.toml").exists());
    let bad = std::process::Command::new(bin)
        .args(["calibrate", "--measurements", "grid.csv", "--out", "x.toml"])
        .current_dir(&dir)
        .output()
        .unwrap();
    // A recording is not a calibration set: its first column is named with the rule.
    let stderr = String::from_utf8_lossy(&bad.stderr);
    assert!(
        stderr.contains(
            "grid.csv:1:t: unexpected column \"t\" (column 1); the header must be q1,q2,q3,q4,q5"
        ),
        "{stderr}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
