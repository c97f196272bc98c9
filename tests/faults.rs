//! Fault injection over the commands that write files (docs/robustness.md "Nothing
//! lost"): each runs under file-size limits that make some or all of its writes fail as
//! a full disk would. Whatever the limit, the command either succeeds and replaces every
//! output, or fails naming a file and replaces none; no temporary file is left behind.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::{cli, twin_session};

const TINY: &str =
    "[model]\nwindow = 16\nchannels = 4\nblocks = 2\nhidden = 8\n\n[data]\nstride = 5\n\n\
[train]\nbatch = 32\nlr = 3e-3\nmax_epochs = 1\n\n[refine]\nmagnifications = [5]\nmax_epochs = 1\n";

/// Limits in 512-byte blocks: the first write fails; small files (sidecars, short
/// CSVs) pass and larger ones fail; most pass and the largest fail.
const LIMITS: [u32; 3] = [1, 16, 256];

/// What one run under a limit did to the outputs.
#[derive(Debug, PartialEq)]
enum Outcome {
    /// Succeeded: every output was replaced.
    Replaced,
    /// Failed with this error; no output was replaced.
    Refused(String),
}

/// Runs `iastgcn args` with `outputs` holding the text "old" beforehand, under a limit
/// of `blocks` × 512 bytes per file, and checks the all-or-nothing promise.
fn run_limited(dir: &Path, args: &[String], outputs: &[PathBuf], blocks: u32) -> Outcome {
    for o in outputs {
        std::fs::write(o, "old").unwrap();
    }
    let quoted: Vec<String> = args.iter().map(|a| format!("'{a}'")).collect();
    let o = Command::new("bash")
        .arg("-c")
        .arg(format!(
            "trap '' XFSZ; ulimit -f {blocks}; exec '{}' {}",
            env!("CARGO_BIN_EXE_iastgcn"),
            quoted.join(" ")
        ))
        .output()
        .unwrap();
    let leftovers: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".tmp"))
        .collect();
    assert!(
        leftovers.is_empty(),
        "{} under {blocks} blocks left {leftovers:?}",
        args[0]
    );
    let old: Vec<bool> = outputs
        .iter()
        .map(|p| std::fs::read(p).is_ok_and(|b| b == b"old"))
        .collect();
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    if o.status.success() {
        assert!(
            old.iter().all(|o| !o),
            "{} succeeded under {blocks} blocks but left some outputs old: {outputs:?} {old:?}",
            args[0]
        );
        Outcome::Replaced
    } else {
        assert!(
            old.iter().all(|o| *o),
            "{} failed under {blocks} blocks ({err}) and replaced some outputs: {outputs:?} {old:?}",
            args[0]
        );
        assert!(
            err.contains(&*dir.to_string_lossy()),
            "{} failed without naming a file: {err}",
            args[0]
        );
        Outcome::Refused(err)
    }
}

#[test]
fn every_writing_command_replaces_all_of_its_outputs_or_none() {
    let dir = std::env::temp_dir().join(format!("iastgcn-faults-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (cal, recs) = twin_session(&dir, &["grid", "hilbert"], 40.0);
    let f = |name: &str| dir.join(name);
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let config = f("tiny.toml");
    std::fs::write(&config, TINY).unwrap();
    let data: Vec<String> = recs.iter().map(|p| s(p)).collect();
    // A trained model for predict and refine, written without any limit.
    let model = f("m.safetensors");
    let mut train: Vec<String> = ["train", "--config", &s(&config), "--calibration", &s(&cal)]
        .map(String::from)
        .to_vec();
    train.extend(["--out".into(), s(&model), "--data".into()]);
    train.extend(data.iter().cloned());
    let args: Vec<&str> = train.iter().map(String::as_str).collect();
    cli(&args);

    let strings = |a: &[&str]| a.iter().map(|x| x.to_string()).collect::<Vec<_>>();
    let stems = |stem: &str, suffixes: &[&str]| -> Vec<PathBuf> {
        suffixes.iter().map(|x| f(&format!("{stem}{x}"))).collect()
    };
    let mut cases: Vec<(Vec<String>, Vec<PathBuf>)> = Vec::new();
    let run = f("run.csv");
    cases.push((
        strings(&[
            "simulate",
            "--trajectory",
            "fermat",
            "--minutes",
            "0.1",
            "--out",
            &s(&run),
        ]),
        stems("run", &[".csv", ".run.toml", ".png"]),
    ));
    cases.push((
        strings(&[
            "simulate",
            "--trajectory",
            "calibration",
            "--poses",
            "30",
            "--out",
            &s(&f("poses.csv")),
        ]),
        stems("poses", &[".csv", ".run.toml"]),
    ));
    cases.push((
        strings(&[
            "calibrate",
            "--measurements",
            &s(&f("set.csv")),
            "--out",
            &s(&f("cal2.toml")),
        ]),
        vec![f("cal2.toml")],
    ));
    cases.push((
        strings(&[
            "init",
            "--config",
            &s(&config),
            "--out",
            &s(&f("init.safetensors")),
        ]),
        vec![f("init.safetensors")],
    ));
    let mut t = train.clone();
    t[6] = s(&f("t.safetensors"));
    cases.push((
        t,
        stems(
            "t",
            &[
                ".safetensors",
                ".state.safetensors",
                ".log.csv",
                ".loss.png",
            ],
        ),
    ));
    let mut p = strings(&[
        "predict",
        "--model",
        &s(&model),
        "--calibration",
        &s(&cal),
        "--out",
        &s(&f("pred.csv")),
        "--data",
    ]);
    p.extend(data.iter().cloned());
    cases.push((p, stems("pred", &[".csv", ".png"])));
    let mut r = strings(&[
        "refine",
        "--model",
        &s(&model),
        "--config",
        &s(&config),
        "--calibration",
        &s(&cal),
        "--out",
        &s(&f("r.safetensors")),
        "--data",
    ]);
    r.extend(data.iter().cloned());
    cases.push((
        r,
        stems(
            "r",
            &[
                ".safetensors",
                ".log.csv",
                ".loss.png",
                ".accumulated.csv",
                ".accumulated.png",
            ],
        ),
    ));

    let mut refused = 0;
    for (args, outputs) in &cases {
        let outcomes: Vec<Outcome> = LIMITS
            .iter()
            .map(|&blocks| run_limited(&dir, args, outputs, blocks))
            .collect();
        // The smallest limit always fails: every command writes more than 512 bytes.
        assert!(
            matches!(outcomes[0], Outcome::Refused(_)),
            "{} wrote its outputs under 512 bytes per file",
            args[0]
        );
        refused += outcomes
            .iter()
            .filter(|o| matches!(o, Outcome::Refused(_)))
            .count();
    }
    eprintln!(
        "{} commands × {} limits: {refused} refused with no output replaced, the rest replaced all",
        cases.len(),
        LIMITS.len()
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
