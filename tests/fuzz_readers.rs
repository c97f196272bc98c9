//! Property tests of every reader of user files (issue #23, "Never panic, never lose
//! work"): recording and calibration-set CSVs, measurement sets, the calibration TOML, run
//! configs, the robot and graph assets, a simulated recording's `.run.toml` sidecar,
//! checkpoints and training states.
//!
//! Each reader gets a valid input (an embedded asset, or a file written by the engine's own
//! writer) damaged in many ways: cut at a random byte, bytes flipped, random bytes, empty,
//! NaN/inf/1e300 in a number, a column or field missing, extra or twice, a tensor of the
//! wrong dtype, shape or length, NaN in a tensor, a huge safetensors header length. The
//! properties: the reader does not panic or hang, and it either returns Ok with finite
//! numbers or an error that names the file and, where the case aims at one, the line,
//! column, field or tensor.
//!
//! The seed is fixed so that CI sees the same cases every run (set `PROPTEST_RNG_SEED` to
//! explore others, `PROPTEST_CASES` for more cases per reader); no regression files are
//! written. The whole file runs in a few seconds in a debug build.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::OnceLock;

use iastgcn::calibrate::Measurement;
use iastgcn::data::recording::parse_calibration_set;
use iastgcn::data::{
    read_measurements, tracker_pose, write_calibration_set, CalibrationRow, Recording, Row,
};
use iastgcn::graph::Graph;
use iastgcn::model::{Checkpoint, ModelConfig, Normalization, Parameters, Variant};
use iastgcn::robot::{ErrorParams, Geometry};
use iastgcn::train::{EpochRecord, Progress, RunConfig, Snapshot, Stage, TrainState};
use iastgcn::twin::{PathKind, PathParams, RunInfo};
use proptest::prelude::*;
use proptest::sample::Index;
use proptest::test_runner::{RngSeed, TestCaseError};

// ---------------------------------------------------------------------------------------
// Shared: the config, damage to bytes, and the checks on a reader's answer.

fn config(cases: u32) -> ProptestConfig {
    let cases = std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|c| c.parse().ok())
        .unwrap_or(cases);
    let mut c = ProptestConfig {
        cases,
        failure_persistence: None,
        ..ProptestConfig::default()
    };
    if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
        c.rng_seed = RngSeed::Fixed(0x23);
    }
    c
}

/// A scratch file for one test (tests run in parallel threads: one name each).
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("iastgcn-fuzz-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// Characters CSV and TOML readers care about, for random text.
const ALPHABET: &[char] = &[
    '0', '1', '2', '5', '9', '.', ',', '-', '+', 'e', 'E', 'n', 'a', 'i', 'f', 't', 'x', 'q', '=',
    '[', ']', '{', '}', '"', '\'', '#', ' ', '\n', '\r', '\t', '\\', 'µ', '\u{0}',
];

#[derive(Clone, Debug)]
enum Damage {
    /// Cut at a byte (anywhere, the end included).
    Truncate(Index),
    /// XOR a few bytes with non-zero masks.
    Flip(Vec<(Index, u8)>),
    /// Random bytes instead of the file.
    Random(Vec<u8>),
    /// Random text from [`ALPHABET`] instead of the file.
    Text(Vec<char>),
    /// An empty file.
    Empty,
}

fn damage() -> impl Strategy<Value = Damage> {
    prop_oneof![
        3 => any::<Index>().prop_map(Damage::Truncate),
        3 => prop::collection::vec((any::<Index>(), 1u8..=255), 1..6).prop_map(Damage::Flip),
        1 => prop::collection::vec(any::<u8>(), 0..200).prop_map(Damage::Random),
        1 => prop::collection::vec(prop::sample::select(ALPHABET), 0..200).prop_map(Damage::Text),
        1 => Just(Damage::Empty),
    ]
}

fn damaged(bytes: &[u8], d: &Damage) -> Vec<u8> {
    match d {
        Damage::Truncate(i) => bytes[..i.index(bytes.len() + 1)].to_vec(),
        Damage::Flip(flips) => {
            let mut b = bytes.to_vec();
            for (i, mask) in flips {
                if !b.is_empty() {
                    let k = i.index(b.len());
                    b[k] ^= mask;
                }
            }
            b
        }
        Damage::Random(r) => r.clone(),
        Damage::Text(t) => t.iter().collect::<String>().into_bytes(),
        Damage::Empty => Vec::new(),
    }
}

/// What an error must say for one case.
#[derive(Debug, Default)]
struct Expect {
    /// The reader must refuse the input.
    must_fail: bool,
    /// The message starts with this (`file:line:column:`).
    prefix: Option<String>,
    /// The message contains each of these.
    all: Vec<String>,
    /// The message contains at least one of these (when not empty).
    any: Vec<String>,
}

impl Expect {
    fn fail() -> Expect {
        Expect {
            must_fail: true,
            ..Expect::default()
        }
    }

    fn naming(needle: impl Into<String>) -> Expect {
        Expect {
            must_fail: true,
            all: vec![needle.into()],
            ..Expect::default()
        }
    }
}

/// Checks a reader's answer: an error names `file` (and what `expect` asks for); a success
/// passes `finite`.
fn check<T, E: std::fmt::Display>(
    result: Result<T, E>,
    file: &str,
    expect: &Expect,
    finite: impl Fn(&T) -> bool,
) -> Result<(), TestCaseError> {
    match result {
        Ok(v) => {
            prop_assert!(!expect.must_fail, "accepted, but should fail: {expect:?}");
            prop_assert!(finite(&v), "accepted with a non-finite number");
        }
        Err(e) => {
            let msg = e.to_string();
            prop_assert!(
                msg.starts_with(&format!("{file}:")),
                "the error does not start with the file {file:?}: {msg}"
            );
            if let Some(p) = &expect.prefix {
                prop_assert!(
                    msg.starts_with(p.as_str()),
                    "expected {p:?} at the start: {msg}"
                );
            }
            for needle in &expect.all {
                prop_assert!(
                    msg.contains(needle.as_str()),
                    "expected {needle:?} in: {msg}"
                );
            }
            if !expect.any.is_empty() {
                prop_assert!(
                    expect.any.iter().any(|n| msg.contains(n.as_str())),
                    "expected one of {:?} in: {msg}",
                    expect.any
                );
            }
        }
    }
    Ok(())
}

fn pose_finite(p: &nalgebra::Isometry3<f64>) -> bool {
    p.translation.vector.iter().all(|v| v.is_finite())
        && p.rotation.coords.iter().all(|v| v.is_finite())
}

// ---------------------------------------------------------------------------------------
// CSV: recordings, calibration sets, measurement sets.

/// A CSV as header + rows of cells (the valid files have no quotes).
fn cells(text: &str) -> Vec<Vec<String>> {
    text.lines()
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect()
}

fn csv(table: &[Vec<String>]) -> String {
    table.iter().map(|r| r.join(",") + "\n").collect()
}

/// Values that are not finite numbers: the cell holding one must be named.
const BAD_NUMBERS: &[&str] = &[
    "NaN", "nan", "inf", "-inf", "+inf", "infinity", "1e400", "-1e400", "abc", "0x10", "1.2.3",
    "--1", "1e", "∞",
];
/// Odd but possibly acceptable cells: the reader may take them or refuse them by name.
const ODD_NUMBERS: &[&str] = &[
    "1e300", "-1e300", "1e-300", "1e-400", "-0", "", "+7", "1e308",
];

#[derive(Clone, Debug)]
enum CsvCase {
    Damage(Damage),
    /// One data cell replaced.
    Cell {
        row: Index,
        col: Index,
        value: &'static str,
    },
    /// A column removed from the header and every row.
    Missing(Index),
    /// A column inserted into the header and every row.
    Extra {
        at: Index,
        name: &'static str,
    },
    /// One row with a cell too many.
    RowLong(Index),
    /// One row with a cell too few.
    RowShort(Index),
}

fn csv_case(names: &'static [&'static str]) -> impl Strategy<Value = CsvCase> {
    let numbers: Vec<&'static str> = BAD_NUMBERS.iter().chain(ODD_NUMBERS).copied().collect();
    prop_oneof![
        3 => damage().prop_map(CsvCase::Damage),
        3 => (any::<Index>(), any::<Index>(), prop::sample::select(numbers))
            .prop_map(|(row, col, value)| CsvCase::Cell { row, col, value }),
        1 => any::<Index>().prop_map(CsvCase::Missing),
        2 => (any::<Index>(), prop::sample::select(names))
            .prop_map(|(at, name)| CsvCase::Extra { at, name }),
        1 => any::<Index>().prop_map(CsvCase::RowLong),
        1 => any::<Index>().prop_map(CsvCase::RowShort),
    ]
}

/// True when `msg` names column position `p` (1-based) the way the readers write it.
fn position_texts(p: usize) -> Vec<String> {
    vec![
        format!("(column {p})"),
        format!("(columns {p} and"),
        format!(" and {p})"),
        format!("column {p} is"),
    ]
}

/// The damaged text and what its error must say. `recording`: the first column is `t`
/// and cells may be empty.
fn csv_input(valid: &str, file: &str, case: &CsvCase, recording: bool) -> (Vec<u8>, Expect) {
    let table = cells(valid);
    let (header, n_rows) = (&table[0], table.len() - 1);
    let n = header.len();
    match case {
        CsvCase::Damage(d) => {
            let bytes = damaged(valid.as_bytes(), d);
            (bytes, Expect::default())
        }
        CsvCase::Cell { row, col, value } => {
            let (r, c) = (row.index(n_rows) + 1, col.index(n));
            let mut t = table.clone();
            t[r][c] = value.to_string();
            let mut expect = Expect::default();
            if BAD_NUMBERS.contains(value) || (value.is_empty() && !recording) {
                expect = Expect {
                    must_fail: true,
                    prefix: Some(format!("{file}:{}:{}:", r + 1, header[c])),
                    ..Expect::default()
                };
            }
            (csv(&t).into_bytes(), expect)
        }
        CsvCase::Missing(col) => {
            let c = col.index(n);
            let mut t = table.clone();
            let name = t[0][c].clone();
            for r in &mut t {
                r.remove(c);
            }
            let needle = if recording && c == 0 {
                "`t`".to_string()
            } else {
                format!("{name:?}")
            };
            (csv(&t).into_bytes(), Expect::naming(needle))
        }
        CsvCase::Extra { at, name } => {
            let k = at.index(n + 1);
            let mut t = table.clone();
            t[0].insert(k, name.to_string());
            for r in &mut t[1..] {
                r.insert(k, "1".to_string());
            }
            let mut expect = Expect::naming(format!("{name:?}"));
            if !(recording && k == 0) {
                expect.any = position_texts(k + 1);
                // A copy of an existing column may be reported at the original's place.
                if let Some(o) = header.iter().position(|h| h == name) {
                    let o = if o < k { o } else { o + 1 };
                    expect.any.extend(position_texts(o + 1));
                }
            }
            if recording && k == 0 && *name == "t" {
                expect.all = vec!["\"t\"".into()];
            }
            (csv(&t).into_bytes(), expect)
        }
        CsvCase::RowLong(row) => {
            let r = row.index(n_rows) + 1;
            let mut t = table.clone();
            t[r].push("1".into());
            let prefix = format!("{file}:{}:#{}: ", r + 1, n + 1);
            let mut expect = Expect::naming("an extra cell");
            expect.prefix = Some(prefix);
            (csv(&t).into_bytes(), expect)
        }
        CsvCase::RowShort(row) => {
            let r = row.index(n_rows) + 1;
            let mut t = table.clone();
            t[r].pop();
            let mut expect = Expect::fail();
            expect.prefix = Some(format!("{file}:{}:{}: ", r + 1, header[n - 1]));
            (csv(&t).into_bytes(), expect)
        }
    }
}

/// The rule every CSV reader keeps: a non-empty text whose last line has no newline is
/// refused at that line.
fn truncation_rule(text: &str, file: &str, expect: &mut Expect) {
    if !text.is_empty() && !text.ends_with('\n') {
        expect.must_fail = true;
        expect.prefix = Some(format!(
            "{file}:{}: the file ends inside this line",
            text.matches('\n').count() + 1
        ));
        expect.all.clear();
        expect.any.clear();
    }
}

const CH: [&str; 3] = ["E1", "Q1", "F"];

fn recording() -> Recording {
    Recording {
        channels: CH.iter().map(|s| s.to_string()).collect(),
        rows: (0..6)
            .map(|k| Row {
                t: k as f64 * 0.02,
                values: vec![
                    Some(0.1 * k as f64 - 0.25),
                    (k % 2 == 0).then_some(700.0 + k as f64),
                    Some(-3.25),
                ],
                tracker: (k % 3 == 0).then_some([1500.5, -800.25, 1100.0, 0.1, -0.2, 3.0]),
            })
            .collect(),
    }
}

fn recording_finite(r: &Recording) -> bool {
    r.rows.iter().all(|row| {
        row.t.is_finite()
            && row.values.iter().flatten().all(|v| v.is_finite())
            && row
                .tracker
                .iter()
                .all(|p| p.iter().all(|v| v.is_finite()) && pose_finite(&tracker_pose(p)))
    })
}

fn calibration_rows() -> Vec<CalibrationRow> {
    (0..5)
        .map(|k| CalibrationRow {
            joints: [700.0 + k as f64, 710.5, 690.25, 12.5 * k as f64, -3.0],
            pose: [1500.0, -800.0 + k as f64, 1100.0, 3.0, 0.1, -0.2 * k as f64],
        })
        .collect()
}

/// The calibration set as our writer writes it (written once: tests run in parallel).
fn calibration_text() -> String {
    static TEXT: OnceLock<String> = OnceLock::new();
    TEXT.get_or_init(|| {
        let path = scratch("written-poses.csv");
        write_calibration_set(&path, &calibration_rows()).unwrap();
        std::fs::read_to_string(&path).unwrap()
    })
    .clone()
}

fn calibration_finite(rows: &[CalibrationRow]) -> bool {
    rows.iter().all(|r| {
        r.joints.iter().chain(&r.pose).all(|v| v.is_finite()) && pose_finite(&tracker_pose(&r.pose))
    })
}

fn measurements_finite(m: &[Measurement]) -> bool {
    m.iter().all(|m| {
        m.joints
            .limbs
            .iter()
            .chain(&m.joints.head)
            .all(|v| v.is_finite())
            && pose_finite(&m.pose)
    })
}

const RECORDING_NAMES: &[&str] = &["E9", "foo", "", "E1", "F", "t", "x", "rz", "q1"];
const CALIBRATION_NAMES: &[&str] = &["foo", "", "q1", "q5", "x", "rz", "Q1", "t"];

proptest! {
    #![proptest_config(config(1000))]

    #[test]
    fn recording_csv(case in csv_case(RECORDING_NAMES)) {
        let file = "run.csv";
        let (bytes, mut expect) = csv_input(&recording().to_csv(), file, &case, true);
        let text = String::from_utf8_lossy(&bytes);
        truncation_rule(&text, file, &mut expect);
        check(Recording::parse(&text, file, &CH, 1), file, &expect, recording_finite)?;
    }

    #[test]
    fn calibration_set_csv(case in csv_case(CALIBRATION_NAMES)) {
        let file = "poses.csv";
        let (bytes, mut expect) = csv_input(&calibration_text(), file, &case, false);
        let text = String::from_utf8_lossy(&bytes);
        truncation_rule(&text, file, &mut expect);
        check(parse_calibration_set(&text, file), file, &expect, |r: &Vec<_>| calibration_finite(r))?;
    }
}

proptest! {
    #![proptest_config(config(300))]

    #[test]
    fn measurement_set_file(case in csv_case(CALIBRATION_NAMES)) {
        let path = scratch("measurements.csv");
        let file = path.display().to_string();
        let (bytes, mut expect) = csv_input(&calibration_text(), &file, &case, false);
        if let Ok(text) = std::str::from_utf8(&bytes) {
            truncation_rule(text, &file, &mut expect);
        }
        std::fs::write(&path, &bytes).unwrap();
        check(read_measurements(&path), &file, &expect, |m: &Vec<_>| measurements_finite(m))?;
    }
}

// ---------------------------------------------------------------------------------------
// TOML: the calibration file, run configs, the robot and graph assets.

#[derive(Clone, Debug, PartialEq)]
enum Seg {
    Key(String),
    Idx(usize),
}

/// Every value under `v` with its path (tables and arrays included).
fn entries(v: &toml::Value) -> Vec<(Vec<Seg>, toml::Value)> {
    fn walk(v: &toml::Value, path: &mut Vec<Seg>, out: &mut Vec<(Vec<Seg>, toml::Value)>) {
        let children: Vec<(Seg, &toml::Value)> = match v {
            toml::Value::Table(t) => t.iter().map(|(k, x)| (Seg::Key(k.clone()), x)).collect(),
            toml::Value::Array(a) => a
                .iter()
                .enumerate()
                .map(|(i, x)| (Seg::Idx(i), x))
                .collect(),
            _ => Vec::new(),
        };
        for (seg, x) in children {
            path.push(seg);
            out.push((path.clone(), x.clone()));
            walk(x, path, out);
            path.pop();
        }
    }
    let mut out = Vec::new();
    walk(v, &mut Vec::new(), &mut out);
    out
}

fn at_path<'a>(v: &'a mut toml::Value, path: &[Seg]) -> &'a mut toml::Value {
    path.iter().fold(v, |v, seg| match seg {
        Seg::Key(k) => &mut v[k.as_str()],
        Seg::Idx(i) => &mut v[*i],
    })
}

/// The last key of a path: what an error about it must name.
fn leaf_key(path: &[Seg]) -> String {
    path.iter()
        .rev()
        .find_map(|s| match s {
            Seg::Key(k) => Some(k.clone()),
            Seg::Idx(_) => None,
        })
        .unwrap_or_default()
}

#[derive(Clone, Copy, Debug)]
enum Num {
    Nan,
    Inf,
    NegInf,
    Big,
    NegBig,
    Tiny,
    Zero,
    NegOne,
    IntMax,
    IntNeg,
    IntBig,
}

impl Num {
    fn value(self) -> toml::Value {
        use toml::Value::{Float, Integer};
        match self {
            Num::Nan => Float(f64::NAN),
            Num::Inf => Float(f64::INFINITY),
            Num::NegInf => Float(f64::NEG_INFINITY),
            Num::Big => Float(1e300),
            Num::NegBig => Float(-1e300),
            Num::Tiny => Float(1e-300),
            Num::Zero => Float(0.0),
            Num::NegOne => Integer(-1),
            Num::IntMax => Integer(i64::MAX),
            Num::IntNeg => Integer(i64::MIN),
            Num::IntBig => Integer(1 << 40),
        }
    }
}

fn num() -> impl Strategy<Value = Num> {
    prop::sample::select(vec![
        Num::Nan,
        Num::Inf,
        Num::NegInf,
        Num::Big,
        Num::NegBig,
        Num::Tiny,
        Num::Zero,
        Num::NegOne,
        Num::IntMax,
        Num::IntNeg,
        Num::IntBig,
    ])
}

const STRINGS: &[&str] = &["", "a,b", " E1", "E1", "E2", "zz", "core", "iastgcn", "mlp"];

#[derive(Clone, Debug)]
enum TomlCase {
    Damage(Damage),
    /// A number replaced.
    Number(Index, Num),
    /// A string replaced.
    Text(Index, &'static str),
    /// A key removed.
    Remove(Index),
    /// An unknown key `surplus` added to a table.
    Extra(Index),
    /// A `key = value` line written twice.
    Twice(Index),
}

fn toml_case() -> impl Strategy<Value = TomlCase> {
    prop_oneof![
        3 => damage().prop_map(TomlCase::Damage),
        4 => (any::<Index>(), num()).prop_map(|(i, n)| TomlCase::Number(i, n)),
        1 => (any::<Index>(), prop::sample::select(STRINGS)).prop_map(|(i, s)| TomlCase::Text(i, s)),
        1 => any::<Index>().prop_map(TomlCase::Remove),
        1 => any::<Index>().prop_map(TomlCase::Extra),
        1 => any::<Index>().prop_map(TomlCase::Twice),
    ]
}

/// A TOML reader's input for `case`, from the file's text, and what an error must name.
/// Keys in `inf_ok` may hold an infinity (a condition number).
fn toml_input(text: &str, case: &TomlCase, inf_ok: &[&str]) -> (Vec<u8>, Expect) {
    let value: toml::Value = toml::from_str(text).unwrap();
    let all = entries(&value);
    let pick = |i: &Index, keep: &dyn Fn(&toml::Value, &[Seg]) -> bool| {
        let found: Vec<_> = all.iter().filter(|(p, v)| keep(v, p)).collect();
        (!found.is_empty()).then(|| found[i.index(found.len())].0.clone())
    };
    let render = |v: &toml::Value| toml::to_string(v).unwrap().into_bytes();
    match case {
        TomlCase::Damage(d) => (damaged(text.as_bytes(), d), Expect::default()),
        TomlCase::Number(i, n) => {
            let numeric = |v: &toml::Value, _: &[Seg]| v.is_float() || v.is_integer();
            let Some(path) = pick(i, &numeric) else {
                return (text.as_bytes().to_vec(), Expect::default());
            };
            let mut v = value.clone();
            *at_path(&mut v, &path) = n.value();
            let key = leaf_key(&path);
            // NaN and ±inf must be refused naming the key (an infinity is fine where allowed).
            let must_name = match n {
                Num::Nan => true,
                Num::Inf | Num::NegInf => !inf_ok.contains(&key.as_str()),
                _ => false,
            };
            let expect = if must_name {
                Expect::naming(key)
            } else {
                Expect::default()
            };
            (render(&v), expect)
        }
        TomlCase::Text(i, s) => {
            let Some(path) = pick(i, &|v, _| v.is_str()) else {
                return (text.as_bytes().to_vec(), Expect::default());
            };
            let mut v = value.clone();
            *at_path(&mut v, &path) = toml::Value::String(s.to_string());
            (render(&v), Expect::default())
        }
        TomlCase::Remove(i) => {
            let Some(path) = pick(i, &|_, p| matches!(p.last(), Some(Seg::Key(_)))) else {
                return (text.as_bytes().to_vec(), Expect::default());
            };
            let mut v = value.clone();
            let key = leaf_key(&path);
            let parent = at_path(&mut v, &path[..path.len() - 1]);
            parent.as_table_mut().unwrap().remove(&key);
            let expect = Expect {
                all: vec![key],
                ..Expect::default()
            };
            (render(&v), expect)
        }
        TomlCase::Extra(i) => {
            let mut v = value.clone();
            let path = pick(i, &|v, _| v.is_table()).unwrap_or_default();
            let table = at_path(&mut v, &path).as_table_mut().unwrap();
            table.insert("surplus".into(), toml::Value::Integer(1));
            (render(&v), Expect::naming("surplus"))
        }
        TomlCase::Twice(i) => {
            let lines: Vec<&str> = text.lines().collect();
            let assignments: Vec<usize> = (0..lines.len())
                .filter(|&k| {
                    let l = lines[k].trim_start();
                    !l.starts_with('#') && !l.starts_with('[') && l.contains(" = ")
                })
                .collect();
            let k = assignments[i.index(assignments.len())];
            let key = lines[k]
                .split(" = ")
                .next()
                .unwrap()
                .trim()
                .trim_matches('"');
            let mut out: Vec<&str> = lines.clone();
            out.insert(k + 1, lines[k]);
            let text = out.join("\n") + "\n";
            (text.into_bytes(), Expect::naming(key))
        }
    }
}

fn run_config_finite(c: &RunConfig) -> bool {
    let m = &c.model;
    let (t, d, r) = (&c.train, &c.data, &c.refine);
    [
        m.scale,
        m.eps,
        m.dropout,
        d.train_fraction,
        d.validation_fraction,
        t.lr,
        t.lr_decay,
        t.beta1,
        t.beta2,
        t.adam_eps,
        t.weight_decay,
        t.attitude_penalty,
        r.lr_scale,
    ]
    .iter()
    .all(|v| v.is_finite())
        && c.validate().is_ok()
}

fn geometry_finite(g: &Geometry) -> bool {
    let p = &g.parallel;
    let mut all = vec![
        p.base_radius,
        p.platform_radius,
        p.shaft_length,
        p.tilt_limit_deg,
        g.tool.alpha_deg,
        g.tool.a,
        g.tool.theta_deg,
        g.tool.d,
    ];
    all.extend(p.base_angles_deg.iter().chain(&p.platform_angles_deg));
    all.extend(p.stroke.iter().chain(&p.extension));
    all.extend(g.tracker.position.iter().chain(&g.tracker.rpy_deg));
    for j in &g.serial.joints {
        all.extend([j.alpha_deg, j.a, j.theta_offset_deg, j.d]);
        all.extend(j.limits_deg.iter().flatten());
    }
    all.iter().all(|v| v.is_finite())
        && g.base_points()
            .iter()
            .chain(&g.platform_points())
            .all(|v| v.iter().all(|x| x.is_finite()))
        && pose_finite(&g.tracker_from_base())
}

fn graph_sound(g: &Graph) -> bool {
    let n = g.len();
    n > 0
        && g.nodes.iter().all(|s| !s.is_empty() && !s.contains(','))
        && g.edges.iter().all(|&(i, j)| i < j && j < n)
}

/// A calibration file as `calibrate::file::save` writes it: every parameter, three
/// identified with their σ and covariance.
fn calibration_toml() -> String {
    let names = ErrorParams::names();
    let mut errors = String::new();
    for (k, n) in names.iter().enumerate() {
        errors.push_str(&format!("\"{n}\" = {}\n", (k as f64 - 10.0) * 1e-3));
    }
    format!(
        "# iastgcn geometric calibration\nversion = 1\nmeasurements = 80\n\
         identified = [\"{}\", \"{}\", \"{}\"]\nsigma = [0.01, 0.002, 1e-5]\n\
         covariance = [[1e-4, 0.0, 1e-7], [0.0, 4e-6, 0.0], [1e-7, 0.0, 1e-10]]\n\
         condition = [12.5, 340.0, 1200.0]\n\n[errors]\n{errors}\n\
         [[stages]]\nname = \"serial\"\nround = 1\nparameters = 8\nsweeps = 3\ngamma = 0.0001\n\n\
         [[stages]]\nname = \"parallel\"\nround = 1\nparameters = 20\nsweeps = 4\ngamma = 2e-5\n",
        names[0], names[20], names[30]
    )
}

proptest! {
    #![proptest_config(config(1000))]

    #[test]
    fn calibration_file(case in toml_case()) {
        let path = scratch("calibration.toml");
        let file = path.display().to_string();
        let (bytes, expect) = toml_input(&calibration_toml(), &case, &["condition"]);
        std::fs::write(&path, &bytes).unwrap();
        let finite = |c: &iastgcn::calibrate::file::LoadedCalibration| {
            c.errors.values.iter().chain(&c.sigma).all(|v| v.is_finite())
        };
        check(iastgcn::calibrate::file::load(&path), &file, &expect, finite)?;
    }

    #[test]
    fn run_config(case in toml_case(), demo in any::<bool>()) {
        let file = "run.toml";
        // The demo file as shipped (comments, fields left out), or every field written out.
        let text = if demo {
            include_str!("../assets/demo.toml").to_string()
        } else {
            toml::to_string(&RunConfig::demo()).unwrap()
        };
        let (bytes, mut expect) = toml_input(&text, &case, &[]);
        // Every field has a default: a missing one is fine.
        if matches!(case, TomlCase::Remove(_)) {
            expect = Expect::default();
        }
        let text = String::from_utf8_lossy(&bytes);
        check(RunConfig::parse(&text, file), file, &expect, run_config_finite)?;
    }

    #[test]
    fn robot_asset(case in toml_case()) {
        let file = "robot.toml";
        let (bytes, mut expect) = toml_input(iastgcn::robot::DEFAULT_ASSET, &case, &[]);
        // `limits_deg` and `kind` are optional.
        if matches!(case, TomlCase::Remove(_))
            && (expect.all == ["limits_deg"] || expect.all == ["kind"])
        {
            expect = Expect::default();
        }
        let text = String::from_utf8_lossy(&bytes);
        // Through the reader every `--robot` goes through: `kind` picks the hybrid.
        let hybrid = |d: &iastgcn::robot::Description| {
            matches!(d, iastgcn::robot::Description::Hybrid(g) if geometry_finite(g))
        };
        check(iastgcn::robot::Description::parse(&text, file), file, &expect, hybrid)?;
    }

    #[test]
    fn graph_asset(case in toml_case()) {
        let file = "graph.toml";
        let (bytes, expect) = toml_input(iastgcn::graph::DEFAULT_ASSET, &case, &[]);
        let text = String::from_utf8_lossy(&bytes);
        check(Graph::parse(&text, file), file, &expect, graph_sound)?;
    }

    #[test]
    fn run_sidecar(case in toml_case()) {
        // The sidecar a simulated recording carries (read back by `evaluate`, `reproduce`
        // and `calibrate` for its machine and length), as the engine writes it.
        let csv = scratch("run.csv");
        let sidecar = RunInfo::sidecar(&csv);
        let file = sidecar.display().to_string();
        let mut info = RunInfo::polishing(PathKind::Hilbert, &PathParams::default(), 90.0, 7);
        info.session_clock_s = 1800.0;
        info.screw_rise_k = [0.4, 0.5, 0.3];
        let (bytes, expect) = toml_input(&info.to_toml().unwrap(), &case, &[]);
        std::fs::write(&sidecar, &bytes).unwrap();
        let sound = |i: &RunInfo| {
            let [a, b, c] = i.screw_rise_k;
            [i.rotation_deg, i.seconds, i.session_clock_s, a, b, c, i.feed_mm_s, i.force_n,
                i.ambient_offset_k, i.ambient_phase_shift]
                .iter()
                .all(|v| v.is_finite())
                && i.seconds >= 0.0
                && i.session_clock_s >= 0.0
        };
        check(RunInfo::read(&csv), &file, &expect, sound)?;
    }
}

// ---------------------------------------------------------------------------------------
// Safetensors: checkpoints and training states.

/// One tensor of a safetensors file, dtype as its header spells it.
#[derive(Clone, Debug)]
struct Tensor {
    name: String,
    dtype: String,
    shape: Vec<usize>,
    data: Vec<u8>,
}

/// A safetensors file taken apart, to be put back together with any inconsistency.
#[derive(Clone, Debug)]
struct St {
    meta: BTreeMap<String, String>,
    tensors: Vec<Tensor>,
}

fn decode(bytes: &[u8]) -> St {
    let st = safetensors::SafeTensors::deserialize(bytes).unwrap();
    let (_, header) = safetensors::SafeTensors::read_metadata(bytes).unwrap();
    let meta = header.metadata().clone().unwrap().into_iter().collect();
    let mut tensors: Vec<Tensor> = st
        .tensors()
        .into_iter()
        .map(|(name, v)| Tensor {
            name,
            dtype: format!("{:?}", v.dtype()),
            shape: v.shape().to_vec(),
            data: v.data().to_vec(),
        })
        .collect();
    tensors.sort_by(|a, b| a.name.cmp(&b.name));
    St { meta, tensors }
}

/// The bytes of `st`, each tensor's offsets its data's place, whatever its shape says.
fn encode(st: &St) -> Vec<u8> {
    let mut header = format!(
        "{{\"__metadata__\":{}",
        serde_json::to_string(&st.meta).unwrap()
    );
    let (mut offset, mut data) = (0, Vec::new());
    for t in &st.tensors {
        let end = offset + t.data.len();
        header.push_str(&format!(
            ",{}:{{\"dtype\":\"{}\",\"shape\":{:?},\"data_offsets\":[{offset},{end}]}}",
            serde_json::to_string(&t.name).unwrap(),
            t.dtype,
            t.shape
        ));
        offset = end;
        data.extend_from_slice(&t.data);
    }
    header.push('}');
    while header.len() % 8 != 0 {
        header.push(' ');
    }
    let mut out = (header.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(header.as_bytes());
    out.extend(data);
    out
}

/// Tokens for a number in the JSON metadata; the first three are not JSON numbers of f64.
const JSON_NUMBERS: &[&str] = &[
    "1e999",
    "-1e999",
    "NaN",
    "0",
    "-1",
    "1e300",
    "-1e300",
    "1e-300",
    "18446744073709551616",
    "0.5",
    "1e20",
];

#[derive(Clone, Debug)]
enum StCase {
    Damage(Damage),
    /// Bytes flipped inside the header.
    HeaderFlip(Vec<(Index, u8)>),
    /// The header length (first 8 bytes) set.
    HeaderLen(u64),
    /// A tensor's dtype changed (its data kept).
    Dtype(Index, &'static str),
    /// A tensor's last dimension grown by one (its data kept).
    ShapeGrow(Index),
    /// A tensor reshaped to the same element count.
    Reshape(Index),
    /// A shape whose size overflows.
    ShapeHuge(Index),
    /// A tensor's data 4 bytes short (its shape kept).
    DataShort(Index),
    /// A tensor left out.
    Missing(Index),
    /// An unknown tensor added.
    Extra,
    /// A tensor written twice.
    Twice(Index),
    /// One element set to NaN or ±inf.
    NonFinite(Index, Index, f32),
    /// A number in a metadata JSON value replaced by a token.
    MetaNumber(Index, Index, &'static str),
    /// A metadata key left out.
    MetaMissing(Index),
    /// A field `surplus` added to a metadata JSON object.
    MetaExtra(Index),
}

fn st_case() -> impl Strategy<Value = StCase> {
    let idx = any::<Index>;
    prop_oneof![
        3 => damage().prop_map(StCase::Damage),
        2 => prop::collection::vec((idx(), 1u8..=255), 1..4).prop_map(StCase::HeaderFlip),
        1 => prop::sample::select(vec![1u64 << 62, u64::MAX, 0, 7, 1 << 27, 99_999_999])
            .prop_map(StCase::HeaderLen),
        2 => (idx(), prop::sample::select(vec!["F64", "F16", "BF16", "I32", "U32", "U8", "BOOL", "F99"]))
            .prop_map(|(i, d)| StCase::Dtype(i, d)),
        1 => idx().prop_map(StCase::ShapeGrow),
        1 => idx().prop_map(StCase::Reshape),
        1 => idx().prop_map(StCase::ShapeHuge),
        1 => idx().prop_map(StCase::DataShort),
        1 => idx().prop_map(StCase::Missing),
        1 => Just(StCase::Extra),
        1 => idx().prop_map(StCase::Twice),
        2 => (idx(), idx(), prop::sample::select(vec![f32::NAN, f32::INFINITY, f32::NEG_INFINITY]))
            .prop_map(|(t, e, v)| StCase::NonFinite(t, e, v)),
        3 => (idx(), idx(), prop::sample::select(JSON_NUMBERS))
            .prop_map(|(k, l, v)| StCase::MetaNumber(k, l, v)),
        1 => idx().prop_map(StCase::MetaMissing),
        1 => idx().prop_map(StCase::MetaExtra),
    ]
}

/// Paths (object keys and array indices) of every number in a JSON value.
fn json_numbers(v: &serde_json::Value, path: &mut Vec<Seg>, out: &mut Vec<Vec<Seg>>) {
    match v {
        serde_json::Value::Number(_) => out.push(path.clone()),
        serde_json::Value::Object(m) => {
            for (k, x) in m {
                path.push(Seg::Key(k.clone()));
                json_numbers(x, path, out);
                path.pop();
            }
        }
        serde_json::Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                path.push(Seg::Idx(i));
                json_numbers(x, path, out);
                path.pop();
            }
        }
        _ => {}
    }
}

/// The damaged bytes for `case` and what an error must name. `strict`: the metadata keys
/// whose JSON objects refuse unknown fields.
fn st_input(valid: &[u8], case: &StCase, strict: &[&str]) -> (Vec<u8>, Expect) {
    let st = decode(valid);
    let n = st.tensors.len();
    let tensor = |i: &Index| i.index(n);
    let mut s = st.clone();
    let expect = match case {
        StCase::Damage(d) => return (damaged(valid, d), Expect::default()),
        StCase::HeaderFlip(flips) => {
            let len = u64::from_le_bytes(valid[..8].try_into().unwrap()) as usize;
            let mut b = valid.to_vec();
            for (i, mask) in flips {
                b[8 + i.index(len)] ^= mask;
            }
            return (b, Expect::default());
        }
        StCase::HeaderLen(len) => {
            let mut b = valid.to_vec();
            b[..8].copy_from_slice(&len.to_le_bytes());
            return (b, Expect::fail());
        }
        StCase::Dtype(i, d) => {
            let t = tensor(i);
            s.tensors[t].dtype = d.to_string();
            Expect::naming(&st.tensors[t].name)
        }
        StCase::ShapeGrow(i) => {
            let t = tensor(i);
            match s.tensors[t].shape.last_mut() {
                Some(d) => *d += 1,
                None => s.tensors[t].shape.push(2),
            }
            Expect::naming(&st.tensors[t].name)
        }
        StCase::Reshape(i) => {
            let t = tensor(i);
            let shape = &mut s.tensors[t].shape;
            let count: usize = shape.iter().product();
            *shape = if shape.len() > 1 {
                vec![count]
            } else {
                vec![1, count]
            };
            Expect::naming(&st.tensors[t].name)
        }
        StCase::ShapeHuge(i) => {
            let t = tensor(i);
            s.tensors[t].shape = vec![1 << 40, 1 << 40, 1 << 40];
            Expect::naming(&st.tensors[t].name)
        }
        StCase::DataShort(i) => {
            let t = tensor(i);
            let len = s.tensors[t].data.len();
            s.tensors[t].data.truncate(len.saturating_sub(4));
            Expect::naming(&st.tensors[t].name)
        }
        StCase::Missing(i) => {
            let t = tensor(i);
            s.tensors.remove(t);
            Expect::naming(&st.tensors[t].name)
        }
        StCase::Extra => {
            s.tensors.push(Tensor {
                name: "extra.w".into(),
                dtype: "F32".into(),
                shape: vec![2],
                data: vec![0; 8],
            });
            Expect::naming("extra.w")
        }
        StCase::Twice(i) => {
            let t = tensor(i);
            s.tensors.push(st.tensors[t].clone());
            Expect::naming(&st.tensors[t].name)
        }
        StCase::NonFinite(i, e, v) => {
            let t = tensor(i);
            let count = s.tensors[t].data.len() / 4;
            let e = e.index(count);
            s.tensors[t].data[4 * e..4 * e + 4].copy_from_slice(&v.to_le_bytes());
            Expect {
                must_fail: true,
                all: vec![
                    format!("tensor {}", st.tensors[t].name),
                    format!("element {e}"),
                ],
                ..Expect::default()
            }
        }
        StCase::MetaNumber(k, l, token) => {
            let keys: Vec<String> = st.meta.keys().cloned().collect();
            let key = &keys[k.index(keys.len())];
            let mut v: serde_json::Value = match serde_json::from_str(&st.meta[key]) {
                Ok(v) => v,
                Err(_) => return (valid.to_vec(), Expect::default()),
            };
            let mut paths = Vec::new();
            json_numbers(&v, &mut Vec::new(), &mut paths);
            if paths.is_empty() {
                return (valid.to_vec(), Expect::default());
            }
            let path = &paths[l.index(paths.len())];
            let slot = path.iter().fold(&mut v, |v, seg| match seg {
                Seg::Key(k) => &mut v[k.as_str()],
                Seg::Idx(i) => &mut v[*i],
            });
            *slot = serde_json::Value::String("@@".into());
            let text = serde_json::to_string(&v).unwrap().replace("\"@@\"", token);
            s.meta.insert(key.clone(), text);
            if JSON_NUMBERS[..3].contains(token) {
                Expect::naming(format!("metadata \"{key}\""))
            } else {
                Expect::default()
            }
        }
        StCase::MetaMissing(k) => {
            let keys: Vec<String> = st.meta.keys().cloned().collect();
            let key = keys[k.index(keys.len())].clone();
            s.meta.remove(&key);
            Expect::naming(format!("\"{key}\""))
        }
        StCase::MetaExtra(k) => {
            let keys: Vec<String> = st.meta.keys().cloned().collect();
            let key = keys[k.index(keys.len())].clone();
            let Ok(serde_json::Value::Object(mut o)) = serde_json::from_str(&st.meta[&key]) else {
                return (valid.to_vec(), Expect::default());
            };
            o.insert("surplus".into(), serde_json::Value::from(1));
            s.meta
                .insert(key.clone(), serde_json::Value::Object(o).to_string());
            if strict.contains(&key.as_str()) {
                Expect::naming("surplus")
            } else {
                Expect::default()
            }
        }
    };
    (encode(&s), expect)
}

fn small_model() -> ModelConfig {
    ModelConfig {
        window: 8,
        channels: 2,
        blocks: 1,
        ..ModelConfig::gradient_check(Variant::Iastgcn)
    }
}

fn checkpoint_bytes() -> Vec<u8> {
    let config = small_model();
    Checkpoint {
        parameters: Parameters::init(&config, 1),
        normalization: Normalization::identity(&config),
        graph: Graph::default_asset(),
        config,
    }
    .to_bytes()
    .unwrap()
}

fn normalization_finite(n: &Normalization) -> bool {
    n.feature_mean
        .iter()
        .chain(&n.feature_std)
        .flatten()
        .chain(&n.label_mean)
        .chain(&n.label_std)
        .all(|v| v.is_finite())
}

fn params_finite(p: &Parameters) -> bool {
    p.values.iter().flatten().all(|v| v.is_finite())
}

fn checkpoint_finite(c: &Checkpoint) -> bool {
    params_finite(&c.parameters)
        && normalization_finite(&c.normalization)
        && [c.config.scale, c.config.eps, c.config.dropout]
            .iter()
            .all(|v| v.is_finite())
        && c.config.validate().is_ok()
}

fn train_state() -> TrainState {
    let model = small_model();
    let params = Parameters::init(&model, 1);
    let zeros: Vec<Vec<f32>> = params.values.iter().map(|v| vec![0.0; v.len()]).collect();
    TrainState {
        run: RunConfig {
            model: model.clone(),
            ..RunConfig::default()
        },
        normalization: Normalization::identity(&model),
        snapshot: Snapshot {
            stage: Stage {
                name: "core".into(),
                group: 1,
                lr0: 1e-3,
                max_epochs: 10,
                patience: 3,
            },
            progress: Progress {
                epoch: 1,
                step: 20,
                best_val: 0.75,
                best_epoch: 1,
                bad_epochs: 0,
                first_loss: Some(1.2),
                history: vec![EpochRecord {
                    stage: "core".into(),
                    epoch: 1,
                    step: 20,
                    train_loss: 0.9,
                    val_loss: 0.75,
                    lr: 1e-3,
                    seconds: 0.5,
                    windows_per_s: 2000.0,
                    validation_seconds: 0.1,
                    readback_seconds: 0.01,
                    trained_on: "native CPU (1 threads)".into(),
                }],
            },
            best: Parameters::init(&model, 2),
            params,
            adam_m: zeros.clone(),
            adam_v: zeros,
        },
    }
}

/// The state as `TrainState::save` writes it (written once: tests run in parallel).
fn state_bytes() -> Vec<u8> {
    static BYTES: OnceLock<Vec<u8>> = OnceLock::new();
    BYTES
        .get_or_init(|| {
            let path = scratch("written.state.safetensors");
            train_state().save(&path).unwrap();
            std::fs::read(&path).unwrap()
        })
        .clone()
}

fn state_finite(s: &TrainState) -> bool {
    let snap = &s.snapshot;
    let p = &snap.progress;
    params_finite(&snap.params)
        && params_finite(&snap.best)
        && snap
            .adam_m
            .iter()
            .chain(&snap.adam_v)
            .flatten()
            .all(|v| v.is_finite())
        && normalization_finite(&s.normalization)
        && run_config_finite(&s.run)
        && snap.stage.lr0.is_finite()
        && p.best_val.is_finite()
        && p.history.iter().all(|r| {
            [r.train_loss, r.val_loss, r.lr, r.seconds, r.windows_per_s]
                .iter()
                .all(|v| v.is_finite())
        })
}

proptest! {
    #![proptest_config(config(500))]

    #[test]
    fn checkpoint(case in st_case()) {
        let file = "model.safetensors";
        let (bytes, expect) =
            st_input(&checkpoint_bytes(), &case, &["config", "graph", "normalization"]);
        check(Checkpoint::from_bytes(&bytes, file), file, &expect, checkpoint_finite)?;
    }
}

proptest! {
    #![proptest_config(config(300))]

    #[test]
    fn training_state(case in st_case()) {
        let path = scratch("state.safetensors");
        let file = path.display().to_string();
        let (bytes, expect) = st_input(&state_bytes(), &case, &["run", "normalization"]);
        std::fs::write(&path, &bytes).unwrap();
        check(TrainState::load(&path), &file, &expect, state_finite)?;
    }
}

// ---------------------------------------------------------------------------------------
// The defects these tests found, one plain test each.

#[test]
fn a_csv_cut_inside_its_last_line_is_refused() {
    let text = calibration_text();
    let lines = text.lines().count();
    // Cut inside the last cell: the number reads as another, smaller one.
    let cut = &text[..text.len() - 3];
    let err = parse_calibration_set(cut, "poses.csv")
        .unwrap_err()
        .to_string();
    assert_eq!(
        err,
        format!(
            "poses.csv:{lines}: the file ends inside this line (no newline at the end): it \
             looks truncated; if it is complete, end it with a newline"
        )
    );
    // Only the final newline missing: refused as well (a writer always ends with one).
    let err = parse_calibration_set(text.trim_end(), "poses.csv").unwrap_err();
    assert!(err
        .to_string()
        .starts_with(&format!("poses.csv:{lines}: the file ends")));
    // The recording reader keeps the same rule.
    let text = recording().to_csv();
    let lines = text.lines().count();
    let err = Recording::parse(&text[..text.len() - 2], "run.csv", &CH, 1).unwrap_err();
    assert!(
        err.to_string()
            .starts_with(&format!("run.csv:{lines}: the file ends inside this line")),
        "{err}"
    );
    // And so does the measurement set read from a file.
    let path = scratch("cut-measurements.csv");
    let text = calibration_text();
    std::fs::write(&path, &text[..text.len() - 1]).unwrap();
    let err = read_measurements(&path).unwrap_err().to_string();
    assert!(err.starts_with(&format!(
        "{}:{}: the file ends",
        path.display(),
        text.lines().count()
    )));
}

#[test]
fn an_extra_csv_column_is_named_with_its_position() {
    let mut t = cells(&calibration_text());
    t[0].insert(5, "temperature".into());
    for r in &mut t[1..] {
        r.insert(5, "21.5".into());
    }
    let err = parse_calibration_set(&csv(&t), "poses.csv")
        .unwrap_err()
        .to_string();
    assert!(
        err.starts_with("poses.csv:1:temperature: unexpected column \"temperature\" (column 6)"),
        "{err}"
    );
    // After the tracker's columns of a recording.
    let mut t = cells(&recording().to_csv());
    t[0].push("note".into());
    for r in &mut t[1..] {
        r.push(String::new());
    }
    let err = Recording::parse(&csv(&t), "run.csv", &CH, 1)
        .unwrap_err()
        .to_string();
    assert!(
        err.starts_with(
            "run.csv:1:note: unexpected column \"note\" (column 11) after the tracker's rz"
        ),
        "{err}"
    );
    // One row with a cell too many names the row and the position.
    let mut t = cells(&calibration_text());
    t[3].push("7".into());
    let err = parse_calibration_set(&csv(&t), "poses.csv")
        .unwrap_err()
        .to_string();
    assert!(
        err.starts_with("poses.csv:4:#12: 12 fields, but the header has 11"),
        "{err}"
    );
}

#[test]
fn a_tensor_whose_shape_disagrees_with_its_bytes_is_named() {
    let mut st = decode(&checkpoint_bytes());
    let t = st.tensors.len() / 2;
    let name = st.tensors[t].name.clone();
    *st.tensors[t].shape.last_mut().unwrap() += 1;
    let err = Checkpoint::from_bytes(&encode(&st), "model.safetensors")
        .unwrap_err()
        .to_string();
    assert!(
        err.starts_with(&format!(
            "model.safetensors: not a valid safetensors file: tensor {name}: shape"
        )),
        "{err}"
    );
    assert!(err.contains("needs"), "{err}");
    // The same in a training state, and for a dtype the crate does not know.
    let mut st = decode(&state_bytes());
    st.tensors[0].dtype = "F99".into();
    let path = scratch("bad-dtype.state.safetensors");
    std::fs::write(&path, encode(&st)).unwrap();
    let err = TrainState::load(&path).unwrap_err().to_string();
    assert!(
        err.contains(&format!("tensor {}", st.tensors[0].name)),
        "{err}"
    );
}

#[test]
fn the_test_encoder_round_trips() {
    let bytes = encode(&decode(&checkpoint_bytes()));
    Checkpoint::from_bytes(&bytes, "model.safetensors").unwrap();
    let path = scratch("round-trip.state.safetensors");
    std::fs::write(&path, encode(&decode(&state_bytes()))).unwrap();
    assert_eq!(TrainState::load(&path).unwrap(), train_state());
    parse_calibration_set(&calibration_text(), "poses.csv").unwrap();
    std::fs::write(scratch("cal-ok.toml"), calibration_toml()).unwrap();
    iastgcn::calibrate::file::load(&scratch("cal-ok.toml")).unwrap();
}

#[test]
fn a_training_state_with_nan_is_refused_by_tensor_and_element() {
    let mut st = decode(&state_bytes());
    let t = st
        .tensors
        .iter()
        .position(|t| t.name.starts_with("adam.v."))
        .unwrap();
    st.tensors[t].data[4..8].copy_from_slice(&f32::NAN.to_le_bytes());
    let path = scratch("nan.state.safetensors");
    std::fs::write(&path, encode(&st)).unwrap();
    let err = TrainState::load(&path).unwrap_err().to_string();
    assert!(
        err.ends_with(&format!("tensor {}: element 1 is NaN", st.tensors[t].name)),
        "{err}"
    );
}

#[test]
fn an_extra_tensor_in_a_training_state_is_named() {
    let mut st = decode(&state_bytes());
    st.tensors.push(Tensor {
        name: "extra.w".into(),
        dtype: "F32".into(),
        shape: vec![1],
        data: vec![0; 4],
    });
    let path = scratch("extra.state.safetensors");
    std::fs::write(&path, encode(&st)).unwrap();
    let err = TrainState::load(&path).unwrap_err().to_string();
    assert!(err.contains("unexpected tensor extra.w"), "{err}");
}

#[test]
fn infinite_epsilons_are_refused_by_field() {
    let err = RunConfig::parse("[train]\nadam_eps = inf\n", "run.toml").unwrap_err();
    assert_eq!(
        err.to_string(),
        "run.toml: train.adam_eps = inf: must be positive and finite"
    );
    let err = RunConfig::parse("[model]\neps = inf\n", "run.toml").unwrap_err();
    assert!(err.to_string().contains("eps = inf"), "{err}");
}

#[test]
fn a_non_finite_robot_number_is_named() {
    let text = iastgcn::robot::DEFAULT_ASSET.replace("d = 250.0", "d = nan");
    let err = Geometry::parse(&text, "robot.toml")
        .unwrap_err()
        .to_string();
    assert_eq!(err, "robot.toml: tool.d must be a finite number, got NaN");
}

#[test]
fn a_calibration_file_with_nan_sigma_is_refused() {
    let path = scratch("nan-sigma.toml");
    let text = calibration_toml().replace("sigma = [0.01,", "sigma = [nan,");
    std::fs::write(&path, text).unwrap();
    let err = iastgcn::calibrate::file::load(&path)
        .unwrap_err()
        .to_string();
    assert!(err.contains("sigma[0]"), "{err}");
}

#[test]
fn an_implausible_calibration_value_is_blamed_on_the_parameter() {
    // 1e300 used to load, and then "forward kinematics did not converge" blamed the
    // recording the robot could not follow.
    let path = scratch("huge-error.toml");
    let text = calibration_toml();
    let line = text
        .lines()
        .find(|l| l.starts_with("\"limb1.db.x\" = "))
        .expect("the file lists limb1.db.x");
    std::fs::write(&path, text.replace(line, "\"limb1.db.x\" = 1e300")).unwrap();
    let err = iastgcn::calibrate::file::load(&path)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("huge-error.toml") && err.contains("errors.\"limb1.db.x\" = 1e300"),
        "{err}"
    );
}

#[test]
fn a_rotation_vector_too_long_to_rotate_is_named() {
    let mut t = cells(&calibration_text());
    t[2][9] = "1e300".into();
    let err = parse_calibration_set(&csv(&t), "poses.csv")
        .unwrap_err()
        .to_string();
    assert!(
        err.starts_with("poses.csv:3:rx: the rotation vector"),
        "{err}"
    );
}

// ---------------------------------------------------------------------------------------
// A serial arm's description and pose CSV (docs/arms.md).

const ARM_NAMES: &[&str] = &["foo", "", "q1", "q4", "q5", "x", "rx", "temp_c", "time"];

/// A WAM pose file with its temperature channel: time,q1..q4,x,y,z,temp_c.
fn arm_pose_text() -> String {
    let arm =
        iastgcn::robot::arm::Arm::parse(include_str!("../assets/arms/wam4.toml"), "wam4.toml")
            .unwrap();
    let twin = iastgcn::twin::arm::ArmTwin::draw(&arm, 1, Default::default());
    iastgcn::data::arm_poses::ArmPoses {
        stamp: "time".into(),
        oriented: false,
        channels: vec!["temp_c".into()],
        poses: twin.measure(6, 1).poses,
    }
    .to_csv()
}

proptest! {
    #![proptest_config(config(500))]

    #[test]
    fn arm_description(case in toml_case()) {
        let file = "arm.toml";
        let (bytes, expect) = toml_input(include_str!("../assets/arms/wam4.toml"), &case, &[]);
        let text = String::from_utf8_lossy(&bytes);
        let finite = |a: &iastgcn::robot::arm::Arm| a.values.iter().all(|v| v.is_finite());
        check(iastgcn::robot::arm::Arm::parse(&text, file), file, &expect, finite)?;
    }

    #[test]
    fn arm_pose_csv(case in csv_case(ARM_NAMES)) {
        let file = "poses.csv";
        let valid = arm_pose_text();
        let (bytes, mut expect) = csv_input(&valid, file, &case, false);
        // Columns after z are free sensor channels: one more or one fewer there may be
        // taken (or refused naming the file, as a repeated name is).
        let columns = valid.lines().next().unwrap().split(',').count();
        match &case {
            CsvCase::Missing(c) if c.index(columns) == columns - 1 => expect = Expect::default(),
            CsvCase::Extra { at, .. } if at.index(columns + 1) >= columns - 1 => {
                expect = Expect::default()
            }
            _ => {}
        }
        let text = String::from_utf8_lossy(&bytes);
        truncation_rule(&text, file, &mut expect);
        let finite = |f: &iastgcn::data::arm_poses::ArmPoses| {
            f.poses.iter().all(|p| {
                p.stamp.is_finite()
                    && p.joints.iter().chain(&p.channels).all(|v| v.is_finite())
                    && p.position.coords.iter().all(|v| v.is_finite())
            })
        };
        check(
            iastgcn::data::arm_poses::parse_arm_poses(&text, file, 4),
            file,
            &expect,
            finite,
        )?;
    }
}
