//! A reader that closes its end of the pipe early (`iastgcn info | head -1`) ends the
//! program quietly: no panic, no "Broken pipe" message, for every kind of command.

#[cfg(unix)]
mod unix {
    use std::os::unix::process::ExitStatusExt;
    use std::path::Path;
    use std::process::{Command, Stdio};

    /// SIGPIPE's number on Linux and the BSDs.
    const SIGPIPE: i32 = 13;

    fn iastgcn(args: &[&str], dir: &Path) -> Command {
        let mut c = Command::new(env!("CARGO_BIN_EXE_iastgcn"));
        c.args(args).current_dir(dir);
        c
    }

    /// Runs `args` once normally (it must succeed and print to stdout, so the second run
    /// does write into the closed pipe), then with stdout a pipe whose reader is already
    /// closed: it must end without a panic or an error message, either successfully or
    /// by SIGPIPE's default action, as `cat` and `ls` do.
    fn quiet_on_closed_pipe(args: &[&str], dir: &Path) {
        let o = iastgcn(args, dir).output().unwrap();
        assert!(
            o.status.success(),
            "iastgcn {args:?} failed:\n{}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(!o.stdout.is_empty(), "iastgcn {args:?} printed nothing");

        let (reader, writer) = std::io::pipe().unwrap();
        drop(reader);
        let o = iastgcn(args, dir)
            .stdout(writer)
            .stderr(Stdio::piped())
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(
            o.status.success() || o.status.signal() == Some(SIGPIPE),
            "iastgcn {args:?} into a closed pipe ended with {:?}:\n{stderr}",
            o.status
        );
        assert!(
            !stderr.contains("panicked") && !stderr.contains("Broken pipe"),
            "iastgcn {args:?} into a closed pipe:\n{stderr}"
        );
    }

    #[test]
    fn a_closed_pipe_ends_every_command_quietly() {
        let dir = std::env::temp_dir().join(format!("iastgcn-pipe-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // Help and version (clap's own printing), the adapter report, and commands that
        // write files and then print their summaries.
        for args in [
            &["--help"][..],
            &["train", "--help"],
            &["--version"],
            &["info"],
            &[
                "simulate",
                "--trajectory",
                "calibration",
                "--poses",
                "20",
                "--out",
                "set.csv",
            ],
            &[
                "calibrate",
                "--measurements",
                "set.csv",
                "--out",
                "cal.toml",
            ],
        ] {
            quiet_on_closed_pipe(args, &dir);
        }
        std::fs::remove_dir_all(&dir).ok();
    }
}
