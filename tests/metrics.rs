//! Table III's metrics: position as a vector, attitude as the tilt of the tool axis (the
//! roll about the axis is free), the same attitude measure as Table V.

use iastgcn::train::Metrics;

#[test]
fn attitude_errors_count_only_across_the_tool_axis() {
    let s = 0.5f64.sqrt();
    let axis = [0.0, s, s];
    let truth = [[1.0, 2.0, 3.0, 10.0, -4.0, 7.0]];
    // A prediction off only by a roll about the axis scores no attitude error...
    let roll = [[1.0, 2.0, 3.0, 10.0, -4.0 + 3.0 * s, 7.0 + 3.0 * s]];
    let m = Metrics::of(&roll, &truth, &[axis]);
    assert!(m.att_mae < 1e-12 && m.pos_mae == 0.0, "{m:?}");
    // ...one off across it scores the full difference, and position is the vector norm.
    let tilt = [[4.0, 6.0, 3.0, 12.0, -4.0 + 2.0 * s, 7.0 - 2.0 * s]];
    let m = Metrics::of(&tilt, &truth, &[axis]);
    assert!((m.att_mae - 8.0f64.sqrt()).abs() < 1e-12, "{m:?}");
    assert!((m.pos_mae - 5.0).abs() < 1e-12, "{m:?}");
    assert_eq!(m.count, 1);
}

/// MAE, RMSE and MAPE pinned by hand where they differ: position errors of 3, 4 and 12 µm
/// (vectors (3,0,0), (0,4,0), (0,0,12)) against labels of norm 10, 20 and 40 µm; attitude
/// tilts of 0, 1 and 2 mdeg across a vertical axis against labels of 1 mdeg tilt each. Pooling
/// two parts pools the squares for the RMSE, not the RMSEs.
#[test]
fn mae_rmse_and_mape_differ_as_computed_by_hand() {
    let axis = [0.0, 0.0, 1.0];
    let truth = [
        [10.0, 0.0, 0.0, 1.0, 0.0, 0.0],
        [0.0, 20.0, 0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 40.0, 1.0, 0.0, 0.0],
    ];
    let pred = [
        [13.0, 0.0, 0.0, 1.0, 0.0, 0.0],
        [0.0, 24.0, 0.0, 2.0, 0.0, 0.0],
        [0.0, 0.0, 52.0, 1.0, 2.0, 0.0],
    ];
    let m = Metrics::of(&pred, &truth, &[axis; 3]);
    let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
    assert!(close(m.pos_mae, 19.0 / 3.0), "{m:?}");
    assert!(close(m.pos_rmse, (169.0f64 / 3.0).sqrt()), "{m:?}");
    assert!(close(m.pos_mape, 100.0 * (0.3 + 0.2 + 0.3) / 3.0), "{m:?}");
    assert!(
        close(m.att_mae, 1.0) && close(m.att_rmse, (5.0f64 / 3.0).sqrt()),
        "{m:?}"
    );
    // Pooled with itself nothing changes; with a perfect part of the same count the RMSE
    // is sqrt(mean of squares), not the mean of the two RMSEs.
    let perfect = Metrics::of(&truth, &truth, &[axis; 3]);
    let pooled = Metrics::pooled([&m, &perfect]);
    assert!(close(pooled.pos_mae, 19.0 / 6.0), "{pooled:?}");
    assert!(
        close(pooled.pos_rmse, (169.0f64 / 6.0).sqrt()),
        "{pooled:?}"
    );
    assert_eq!(pooled.count, 6);
}
