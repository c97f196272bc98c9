//! Robot kinematics: asset checks, IK∘FK and FK∘IK round trips (nominal and with errors),
//! the MDH chain against an independent 4×4 product, and workspace errors.

use iastgcn::robot::{mdh, ErrorParams, Geometry, Joints, PlatformPose, Robot, RobotError};
use iastgcn::testing::rng;
use iastgcn::twin::{draw_errors, ErrorScales};
use nalgebra::{Matrix4, Vector3};
use rand::RngExt;

fn nominal() -> Robot {
    Robot::nominal(Geometry::default_asset())
}

fn twin() -> Robot {
    nominal().with_errors(draw_errors(1, &ErrorScales::default()))
}

/// Random platform poses over the workspace, kept where every limb is within its stroke
/// with a 5 mm margin (so that the error robot's lengths are too).
fn poses(n: usize, seed: u64) -> Vec<PlatformPose> {
    let robot = nominal();
    let [lo, hi] = robot.geometry.parallel.stroke;
    let mut r = rng(seed);
    let mut out = Vec::new();
    while out.len() < n {
        let p = PlatformPose {
            alpha: r.random_range(-0.3..0.3),
            beta: r.random_range(-0.3..0.3),
            w: r.random_range(560.0..890.0),
        };
        if robot
            .limb_lengths(&p)
            .iter()
            .all(|l| (lo + 5.0..hi - 5.0).contains(l))
        {
            out.push(p);
        }
    }
    out
}

#[test]
fn default_asset_is_plausible() {
    let g = Geometry::default_asset();
    for b in g.base_points() {
        assert!((b.norm() - 450.0).abs() < 1e-9 && b.z == 0.0);
    }
    let robot = nominal();
    let home = robot.home();
    let l = robot.limb_lengths(&home);
    // Symmetric limbs at home, inside the stroke.
    assert!(
        (l[0] - l[1]).abs() < 1e-9 && (l[1] - l[2]).abs() < 1e-9,
        "{l:?}"
    );
    robot.check_lengths(&l).unwrap();
    let expected = (270.0f64.powi(2) + home.w.powi(2)).sqrt() - g.parallel.shaft_length;
    assert!((l[0] - expected).abs() < 1e-9, "{} vs {expected}", l[0]);
    // The tool hangs straight down at home, d1 + tool length below the platform.
    let t = robot.tool_pose(&home, &[0.0, 0.0]);
    let axis = t.rotation * Vector3::z();
    assert!((axis - Vector3::z()).norm() < 1e-12, "{axis}");
    assert!((t.translation.vector - Vector3::new(0.0, 0.0, home.w + 120.0 + 250.0)).norm() < 1e-9);
}

#[test]
fn inverse_then_forward_recovers_the_platform_pose() {
    for robot in [nominal(), twin()] {
        for p in poses(200, 1) {
            let l = robot.limb_lengths(&p);
            let q = robot.platform_from_lengths(l, None).unwrap();
            assert!((q.alpha - p.alpha).abs() < 1e-9, "{p:?} -> {q:?}");
            assert!((q.beta - p.beta).abs() < 1e-9, "{p:?} -> {q:?}");
            assert!((q.w - p.w).abs() < 1e-9, "{p:?} -> {q:?}");
        }
    }
}

#[test]
fn forward_then_inverse_recovers_the_limb_lengths() {
    let robot = twin();
    let mut r = rng(2);
    let mut solved = 0;
    for _ in 0..200 {
        let l = [0; 3].map(|_| r.random_range(650.0..850.0));
        match robot.platform_from_lengths(l, None) {
            Ok(p) => {
                let back = robot.limb_lengths(&p);
                for i in 0..3 {
                    assert!((back[i] - l[i]).abs() < 1e-9, "{l:?} -> {back:?}");
                }
                solved += 1;
            }
            Err(RobotError::OutsideWorkspace { .. }) => {}
            Err(e) => panic!("{l:?}: {e}"),
        }
    }
    assert!(solved > 150, "only {solved} of 200 length triples solved");
}

/// `Rx(α) Tx(a) Rz(θ) Tz(d)` written out as 4×4 matrices, independently of `mdh`.
fn mdh_matrix(alpha: f64, a: f64, theta: f64, d: f64) -> Matrix4<f64> {
    let (sa, ca) = alpha.sin_cos();
    let (st, ct) = theta.sin_cos();
    let rx = Matrix4::new(
        1.0, 0.0, 0.0, 0.0, 0.0, ca, -sa, 0.0, 0.0, sa, ca, 0.0, 0.0, 0.0, 0.0, 1.0,
    );
    let tx = Matrix4::new(
        1.0, 0.0, 0.0, a, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
    );
    let rz = Matrix4::new(
        ct, -st, 0.0, 0.0, st, ct, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
    );
    let tz = Matrix4::new(
        1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, d, 0.0, 0.0, 0.0, 1.0,
    );
    rx * tx * rz * tz
}

#[test]
fn mdh_chain_matches_homogeneous_matrices() {
    let robot = twin();
    let g = &robot.geometry;
    let mut r = rng(3);
    for _ in 0..50 {
        let head = [r.random_range(-3.0..3.0), r.random_range(-0.7..0.7)];
        let mut m = Matrix4::identity();
        for (j, joint) in g.serial.joints.iter().enumerate() {
            let e = robot.errors.mdh(j);
            m *= mdh_matrix(
                joint.alpha_deg.to_radians() + e.alpha,
                joint.a + e.a,
                head[j] + joint.theta_offset_deg.to_radians() + e.theta,
                joint.d + e.d,
            );
        }
        m *= mdh_matrix(
            g.tool.alpha_deg.to_radians(),
            g.tool.a,
            g.tool.theta_deg.to_radians(),
            g.tool.d,
        );
        let dt = robot.errors.tool();
        m *= Matrix4::new(
            1.0, 0.0, 0.0, dt.x, 0.0, 1.0, 0.0, dt.y, 0.0, 0.0, 1.0, dt.z, 0.0, 0.0, 0.0, 1.0,
        );
        let got = robot.head_transform(&head).to_homogeneous();
        assert!((got - m).amax() < 1e-12, "{head:?}\n{got}\n{m}");
        let one = mdh(0.3, 12.0, -1.1, 7.0).to_homogeneous();
        assert!((one - mdh_matrix(0.3, 12.0, -1.1, 7.0)).amax() < 1e-12);
    }
}

#[test]
fn geometric_errors_move_the_tool_by_a_realistic_amount() {
    let (n, t) = (nominal(), twin());
    let (mut pos, mut att) = (Vec::new(), Vec::new());
    let mut r = rng(5);
    for p in poses(100, 4) {
        let head = [r.random_range(-3.0..3.0), r.random_range(-0.3..0.3)];
        // The same joint inputs on both robots: what an uncalibrated controller gets.
        let joints = Joints {
            limbs: n.limb_lengths(&p),
            head,
        };
        let (_, pn) = n.forward(&joints, Some(p)).unwrap();
        let (_, pt) = t.forward(&joints, Some(p)).unwrap();
        pos.push((pn.translation.vector - pt.translation.vector).norm());
        att.push((pt.rotation * pn.rotation.inverse()).angle().to_degrees());
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    println!(
        "geometric errors only: mean position error {:.3} mm, mean attitude error {:.4} deg",
        mean(&pos),
        mean(&att)
    );
    // The twin's machine (seed 1) over the whole workspace, geometric errors alone: most
    // of a millimetre and a few tenths of a degree (polishing paths use less of the
    // workspace; the twin's magnitude test checks those against docs/twin.md).
    assert!(
        (0.4..1.5).contains(&mean(&pos)),
        "mean position error {} mm",
        mean(&pos)
    );
    assert!(
        (0.08..0.4).contains(&mean(&att)),
        "mean attitude error {} deg",
        mean(&att)
    );
}

#[test]
fn leaving_the_workspace_is_an_error_that_names_the_limit() {
    let robot = nominal();
    let err = robot
        .platform_from_lengths([300.0, 700.0, 700.0], None)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("limb 1 length") && err.contains("300"),
        "{err}"
    );
    let err = robot
        .check_platform(&PlatformPose {
            alpha: 0.6,
            beta: 0.0,
            w: 700.0,
        })
        .unwrap_err()
        .to_string();
    assert!(err.contains("tilt alpha"), "{err}");
    let joints = Joints {
        limbs: robot.limb_lengths(&robot.home()),
        head: [0.0, 1.2],
    };
    let err = robot.forward(&joints, None).unwrap_err().to_string();
    assert!(err.contains("serial joint 2 (tilt)"), "{err}");
}

#[test]
fn bad_assets_name_the_file_and_the_field() {
    let good = iastgcn::robot::DEFAULT_ASSET;
    let err = Geometry::parse(
        &good.replace("stroke = [520.0, 1000.0]", "stroke = [1000.0, 520.0]"),
        "my.toml",
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.starts_with("my.toml:") && err.contains("parallel.stroke"),
        "{err}"
    );
    let err = Geometry::parse(&good.replace("shaft_length", "shaft_lenght"), "my.toml")
        .unwrap_err()
        .to_string();
    assert!(
        err.starts_with("my.toml:") && err.contains("shaft_lenght"),
        "{err}"
    );
    let err = Geometry::parse(
        &good.replace("base_radius = 450.0", "base_radius = \"wide\""),
        "my.toml",
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("base_radius") && err.contains("line"), "{err}");
}

#[test]
fn error_draws_are_seeded_and_named() {
    let s = ErrorScales::default();
    assert_eq!(draw_errors(5, &s), draw_errors(5, &s));
    assert_ne!(draw_errors(5, &s), draw_errors(6, &s));
    let names = ErrorParams::names();
    assert_eq!(names.len(), iastgcn::robot::N_PARAMS);
    let unique: std::collections::HashSet<_> = names.iter().collect();
    assert_eq!(unique.len(), names.len());
    assert_eq!(names[27], "limb1.d_shaft");
    let e = draw_errors(5, &s);
    assert_eq!(e.limb(1).d_length, e.values[2 * 29 - 1]);
}
