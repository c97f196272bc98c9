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
