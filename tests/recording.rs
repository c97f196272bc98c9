//! The recording and calibration-set CSV formats: round trips, and a clear error naming
//! file, line and column for every kind of bad input.

use iastgcn::data::{recording::parse_calibration_set, CalibrationRow, Recording, Row};

const CH: [&str; 3] = ["E1", "Q1", "F"];

fn sample() -> Recording {
    Recording {
        channels: CH.iter().map(|s| s.to_string()).collect(),
        rows: (0..5)
            .map(|k| Row {
                t: k as f64 * 0.02,
                values: vec![
                    Some(0.1 * k as f64 + 1e-17),
                    if k % 2 == 0 {
                        Some(700.0 + k as f64)
                    } else {
                        None
                    },
                    Some(-3.25),
                ],
                tracker: (k % 2 == 0).then_some([
                    1500.5,
                    -800.25,
                    1100.0,
                    0.1,
                    -0.2,
                    std::f64::consts::PI,
                ]),
            })
            .collect(),
    }
}

#[test]
fn round_trip_is_bit_exact() {
    let r = sample();
    let text = r.to_csv();
    assert!(text.starts_with("t,E1,Q1,F,x,y,z,rx,ry,rz\n"));
    let back = Recording::parse(&text, "mem.csv", &CH, 1).unwrap();
    assert_eq!(back, r);
    // Columns may come in another order in the file; they are read by name.
    let back = Recording::parse(&text, "mem.csv", &["F", "E1", "Q1"], 1).unwrap();
    assert_eq!(back.channels, ["E1", "Q1", "F"]);
}

#[test]
fn writing_is_atomic_and_reads_back() {
    let dir = std::env::temp_dir().join(format!("iastgcn-rec-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("r.csv");
    sample().write(&path).unwrap();
    assert_eq!(Recording::read(&path, &CH, 5).unwrap(), sample());
    let leftovers: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter(|e| e.as_ref().unwrap().file_name() != "r.csv")
        .collect();
    assert!(leftovers.is_empty(), "temporary files left behind");
    std::fs::remove_dir_all(&dir).unwrap();
}

fn error_of(text: &str, min_rows: usize) -> String {
    Recording::parse(text, "bad.csv", &CH, min_rows)
        .unwrap_err()
        .to_string()
}

#[test]
fn bad_recordings_name_file_line_and_column() {
    let header = "t,E1,Q1,F,x,y,z,rx,ry,rz\n";
    let ok_row = |t: f64| format!("{t},1,700,3,1,2,3,0,0,0\n");
    let cases: Vec<(String, &str)> = vec![
        (
            "t,E1,F,x,y,z,rx,ry,rz\n0,1,3,,,,,,\n".to_string(),
            "bad.csv: missing column \"Q1\"",
        ),
        (
            "t,E1,Q1,F,E9,x,y,z,rx,ry,rz\n".to_string(),
            "bad.csv:1:E9: unexpected column \"E9\"",
        ),
        (
            "t,E1,Q1,Q1,x,y,z,rx,ry,rz\n".to_string(),
            "bad.csv:1:Q1: column \"Q1\" appears twice",
        ),
        (
            "time,E1,Q1,F,x,y,z,rx,ry,rz\n".to_string(),
            "bad.csv:1:time: the first column must be `t`",
        ),
        (
            "t,E1,Q1,F,x,y,z,rx,ry\n".to_string(),
            "the last six columns must be the tracker pose",
        ),
        (
            format!("{header}{}0.02,1,abc,3,,,,,,\n", ok_row(0.0)),
            "bad.csv:3:Q1: not a number: \"abc\"",
        ),
        (
            format!("{header}{}0.02,NaN,700,3,,,,,,\n", ok_row(0.0)),
            "bad.csv:3:E1: not a finite number",
        ),
        (
            format!("{header}{}0.02,1,700,inf,,,,,,\n", ok_row(0.0)),
            "bad.csv:3:F: not a finite number",
        ),
        (
            format!("{header}{}{}", ok_row(0.04), ok_row(0.02)),
            "bad.csv:3:t: time goes backwards",
        ),
        (
            format!("{header}{}{}", ok_row(0.02), ok_row(0.02)),
            "bad.csv:3:t: time goes backwards or repeats",
        ),
        (
            format!("{header}0,1,700,3,1,2,,0,0,0\n"),
            "bad.csv:2:z: the tracker pose is incomplete",
        ),
        (
            format!("{header}0,1,700,3,1,2\n"),
            "bad.csv:2:z: 6 fields, but the header has 10: the cells from column 7 on are missing",
        ),
        (
            format!("{header},1,700,3,,,,,,\n"),
            "bad.csv:2:t: time is empty",
        ),
        (String::new(), "bad.csv: empty file"),
    ];
    for (text, want) in cases {
        let got = error_of(&text, 0);
        assert!(
            got.starts_with(want) || got.contains(want),
            "expected {want:?}, got {got:?}"
        );
    }
    let got = error_of(&format!("{header}{}", ok_row(0.0)), 100);
    assert!(got.contains("1 rows, but at least 100"), "{got}");
}

#[test]
fn calibration_sets_round_trip_and_reject_gaps() {
    let dir = std::env::temp_dir().join(format!("iastgcn-cal-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("c.csv");
    let rows = vec![
        CalibrationRow {
            joints: [700.0, 710.5, 690.25, 12.5, -3.0],
            pose: [1.0, 2.0, 3.0, 0.1, 0.2, 0.3],
        },
        CalibrationRow {
            joints: [720.0, 700.0, 705.0, -100.0, 20.0],
            pose: [4.0, 5.0, 6.0, -0.1, 0.0, 1e-9],
        },
    ];
    iastgcn::data::write_calibration_set(&path, &rows).unwrap();
    assert_eq!(iastgcn::data::read_calibration_set(&path).unwrap(), rows);
    std::fs::remove_dir_all(&dir).unwrap();
    let err = parse_calibration_set(
        "q1,q2,q3,q4,q5,x,y,z,rx,ry,rz\n1,2,3,4,,1,2,3,4,5,6\n",
        "cal.csv",
    )
    .unwrap_err();
    assert_eq!(err.to_string(), "cal.csv:2:q5: empty cell");
    let err = parse_calibration_set("q1,q2,q3,x,y,z\n", "cal.csv").unwrap_err();
    assert!(err
        .to_string()
        .starts_with("cal.csv: the header must be q1,q2,q3,q4,q5,x,y,z,rx,ry,rz"));
}
