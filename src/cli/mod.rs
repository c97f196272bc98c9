//! Command line: clap commands that parse, call the library and print; progress bars;
//! every error turned into one readable message. No pipeline logic lives here.

mod adapt;
mod arm;
mod budget;
mod calibrate;
mod compensate;
mod confidence;
mod dataset;
mod demo;
mod evaluate_args;
mod floor;
mod import;
mod info;
mod model;
mod polish;
mod polish_sweep;
mod reference;
mod register;
mod reproduce;
mod scale;
mod simulate;
mod smoke;
mod train;

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};

use iastgcn::gpu::{Device, Gpu, GpuError};
use iastgcn::progress::Reporter;

#[derive(Parser)]
#[command(
    name = "iastgcn",
    version,
    about = "Pose residual prediction for a polishing robot (IASTGCN on wgpu)"
)]
struct Cli {
    /// Use the first adapter whose name contains this text (overrides IASTGCN_ADAPTER).
    #[arg(long, global = true)]
    adapter: Option<String>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the chosen adapter, its compute limits and features, and every adapter seen.
    Info,
    /// Run the kernels once on the device and check them against the CPU reference.
    Smoke(smoke::SmokeArgs),
    /// Run the digital twin and write a recording CSV (or a calibration measurement set).
    Simulate(simulate::SimulateArgs),
    /// Read a tracker export (any CSV, columns mapped by name) into a serial arm's pose file.
    Import(import::ImportArgs),
    /// Identify the geometric errors (graded EKF) from a calibration measurement set.
    Calibrate(calibrate::CalibrateArgs),
    /// Re-register a calibrated serial arm for a new campaign: tracker and tool fitted on a few poses.
    Register(register::RegisterArgs),
    /// Build the dataset (features, labels, splits) from recordings and print its summary.
    Dataset(dataset::DatasetArgs),
    /// Write a freshly initialised model checkpoint (safetensors).
    Init(model::InitArgs),
    /// Run a checkpoint on the tensor `x` [B,N,F,T] of a safetensors file; write `y` [B,6].
    Forward(model::ForwardArgs),
    /// Train a model (core stage: Adam, inverse-time decay, early stopping) on recordings.
    Train(train::TrainArgs),
    /// Refine a trained model on ensembles of consecutive windows (Algorithm 2).
    Refine(train::RefineArgs),
    /// Adapt a trained model to the day from a short morning recording (an output offset or
    /// a fine-tune, kept only when it lowers the loss on the recording's last part).
    Adapt(adapt::AdaptArgs),
    /// The morning minute measured: each held-out session starts with a short recording,
    /// the models adapted to it compensate the session's runs beside the trained ones.
    Morning(adapt::MorningArgs),
    /// How far to trust a prediction: seed ensembles' spread beside their miss on the
    /// twin's held-out runs, 90 % intervals calibrated on the validation session.
    Confidence(confidence::ConfidenceArgs),
    /// Predict residuals per window end of recordings; metrics where labels exist.
    Predict(train::PredictArgs),
    /// Run a held-out path in the twin: nominal, calibrated, and compensated online by each model.
    Compensate(compensate::CompensateArgs),
    /// The error budget of a run in the twin: the hidden tool-pose error split by source.
    Budget(budget::BudgetArgs),
    /// The look-ahead floor: what an oracle that knows the residual of the tick it acts on
    /// leaves on the twin's held-out runs, beside the oracle of the tick just measured.
    Floor(floor::FloorArgs),
    /// Tables III and V and the report folder for trained models.
    Evaluate(evaluate_args::EvaluateArgs),
    /// The main job end to end on the embedded twin: simulate, calibrate, train IASTGCN,
    /// its three ablations and the four dense baselines (--all-models: every baseline) for
    /// each training seed, refine, compensate, report.
    Demo(demo::DemoArgs),
    /// The paper's protocol at the paper's sizes (or any run config): every model over
    /// several training seeds, in resumable jobs that can be sharded over machines, then
    /// Tables III and V with mean ± SD over seeds and paired comparisons.
    Reproduce(reproduce::ReproduceArgs),
    /// The scaling study: error removed and test MAE against training data (sizes × models
    /// × seeds in resumable, shardable jobs), with a summary after every job.
    Scale(scale::ScaleArgs),
    /// The mirror (Table VI, Figs. 13–14): the same surfaces polished under the nominal and
    /// calibrated controllers, each model compensating online, the oracle and a perfect
    /// machine.
    Polish(polish::PolishArgs),
    /// When compensation matters on the glass: one polishing iteration walked with pose
    /// errors of each kind and size, for pads of several footprints and two pneumatic
    /// floats; a map of the cost in final RMS.
    PolishSweep(polish_sweep::PolishSweepArgs),
}

/// A count in `range` (e.g. `1..`); clap names the argument and the range when the
/// value is not in it.
fn count(range: impl std::ops::RangeBounds<u64>) -> clap::builder::RangedU64ValueParser<usize> {
    clap::builder::RangedU64ValueParser::<usize>::new().range(range)
}

/// How a training set is recorded (docs/twin.md "Sessions") and how often the models
/// predict in the loop, for `demo`, `reproduce`, `scale` and `simulate --trajectory
/// training`: a named recipe (`experiment::recipe`), each of whose settings a flag may
/// change.
#[derive(clap::Args, Clone)]
pub struct RecipeArgs {
    /// The recipe the other flags start from: `use-like` (the default, the best measured:
    /// 4 cold sessions at spread placements, the second half recorded again with a round-0
    /// model compensating, a prediction every tick) or `paper` (the paper's single session
    /// at the training placement, open loop, a prediction every 5 ticks); docs/usage.md
    /// "Recipes".
    #[arg(long, value_parser = ["use-like", "paper"])]
    pub recipe: Option<String>,
    /// Split each path's minutes over this many sessions, each a day of its own that
    /// starts cold (its ambient, feed and force drawn; docs/twin.md "Days"); 1 is a
    /// single session on the calibration day. Each run lasts at least 0.25 minutes.
    /// Default: the recipe's (4; 1 for `paper`).
    #[arg(long, value_parser = count(1..=64))]
    pub sessions: Option<usize>,
    /// Where the sessions' runs lie on the part: `fixed` (the default placement),
    /// `varied` (quarter turns and reversals) or `spread` (turns spread over every angle,
    /// so the strokes run every way, and reversals); none retraces a held-out placement.
    /// Default: the recipe's (`spread`; `fixed` for `paper`).
    #[arg(long, value_parser = ["fixed", "varied", "spread"])]
    pub placement: Option<String>,
    /// In which order each session runs its paths: `fixed` (grid, fermat, hilbert) or
    /// `rotated` (session s starts with the s-th path and goes round, so that every path
    /// starts a day cold in one session of three). Default: `fixed`.
    #[arg(long, value_parser = ["fixed", "rotated"])]
    pub path_order: Option<String>,
    /// Record every training session open loop, under the calibrated controller alone
    /// (the `paper` recipe's way).
    #[arg(long, conflicts_with = "closed_loop")]
    pub open_loop: bool,
    /// Closed-loop data (the `use-like` recipe's way): a round-0 IASTGCN trained on the
    /// first half of the sessions records the others again with it compensating (every
    /// --every ticks), and the models train on both (the same minutes; needs --sessions 2
    /// or more). A `reproduce` or `scale` folder keeps this choice. Not for `simulate`,
    /// which records open loop.
    #[arg(long)]
    pub closed_loop: bool,
}

impl RecipeArgs {
    /// The named recipe the flags start from.
    pub fn named(&self) -> iastgcn::experiment::recipe::NamedRecipe {
        use iastgcn::experiment::recipe::{NamedRecipe, DEFAULT};
        // clap has checked the name against the recipes' names.
        self.recipe
            .as_deref()
            .and_then(NamedRecipe::parse)
            .unwrap_or(DEFAULT)
    }

    /// The sessions these flags ask for: the recipe's sessions, placement and path order
    /// where a flag is absent.
    pub fn sessions(&self) -> anyhow::Result<iastgcn::twin::Recipe> {
        let default = self.named().sessions;
        Ok(iastgcn::twin::Recipe {
            sessions: self.sessions.unwrap_or(default.sessions),
            placement: match &self.placement {
                Some(p) => p.parse().map_err(anyhow::Error::msg)?,
                None => default.placement,
            },
            path_order: match &self.path_order {
                Some(o) => o.parse().map_err(anyhow::Error::msg)?,
                None => default.path_order,
            },
        })
    }

    /// Whether the second half of the sessions is recorded again closed loop: as
    /// `--open-loop` or `--closed-loop` says, else as the recipe does.
    pub fn closed_loop(&self) -> bool {
        !self.open_loop && (self.closed_loop || self.named().closed_loop)
    }

    /// The held-out sessions of `held_out`'s flags, `default`'s where a flag is absent
    /// and the recipe's prediction rate where `--every` is.
    pub fn held_out(
        &self,
        held_out: &evaluate_args::HeldOutArgs,
        default: iastgcn::experiment::evaluate::HeldOutConfig,
    ) -> iastgcn::experiment::evaluate::HeldOutConfig {
        held_out.config_or(iastgcn::experiment::evaluate::HeldOutConfig {
            every: self.named().every,
            ..default
        })
    }

    /// Whether any of the training set's flags was given.
    pub fn given(&self) -> bool {
        self.recipe.is_some()
            || self.sessions.is_some()
            || self.placement.is_some()
            || self.path_order.is_some()
            || self.open_loop
            || self.closed_loop
    }
}

/// Refuses an output file whose folder does not exist, naming the flag, before any long
/// work (a run that fails only when it writes its result has lost that work).
fn output_folder_exists(flag: &str, path: &std::path::Path) -> anyhow::Result<()> {
    match path.parent().filter(|p| !p.as_os_str().is_empty()) {
        Some(dir) if !dir.is_dir() => anyhow::bail!(
            "{flag} {}: the folder {} does not exist (nothing was run)",
            path.display(),
            dir.display()
        ),
        _ => Ok(()),
    }
}

/// Creates an output folder (and its parents) before any long work, naming the flag when
/// it cannot be made.
fn make_output_folder(flag: &str, dir: &std::path::Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| {
        anyhow::anyhow!(
            "{flag} {}: cannot make the folder: {e} (nothing was run)",
            dir.display()
        )
    })
}

/// The adapter, for the commands that exist only as WGSL (`smoke`, `forward`; `what`
/// names the command); without one they fail and say so.
fn open_gpu(adapter: Option<&str>, what: &str) -> anyhow::Result<Gpu> {
    let opened = match adapter {
        Some(name) => Gpu::with_adapter(Some(name)),
        None => Gpu::new(),
    };
    Ok(opened.map_err(|e| match e {
        GpuError::NoAdapter { hint } => GpuError::NeedsAdapter {
            what: what.to_string(),
            hint,
        },
        other => other,
    })?)
}

/// The device of a command with a native path: the adapter, or with none at all the
/// native CPU, said once on stderr.
fn open_device(adapter: Option<&str>) -> anyhow::Result<Device> {
    let device = Device::open(adapter)?;
    if let Device::Native = device {
        eprintln!(
            "no GPU adapter found (Vulkan, Metal or DX12): running on the native CPU path \
             (`iastgcn info` says more)"
        );
    }
    Ok(device)
}

/// Entry point of the `iastgcn` binary.
pub fn main() -> ExitCode {
    restore_sigpipe();
    // Mesa's device-select layer complains on stderr at every enumeration when there is
    // no XDG_RUNTIME_DIR (headless CI); it has nothing to select among here anyway.
    // Safe: no other thread exists yet.
    if std::env::var_os("XDG_RUNTIME_DIR").is_none()
        && std::env::var_os("NODEVICE_SELECT").is_none()
    {
        std::env::set_var("NODEVICE_SELECT", "1");
    }
    let cli = Cli::parse();
    let result =
        match cli.command {
            Command::Info => info::run(cli.adapter.as_deref()),
            Command::Smoke(args) => {
                open_gpu(cli.adapter.as_deref(), "`iastgcn smoke` (the WGSL kernels)")
                    .and_then(|gpu| smoke::run(&gpu, &args))
            }
            Command::Simulate(args) => simulate::run(&args),
            Command::Calibrate(args) => calibrate::run(&args),
            Command::Import(args) => import::run(&args),
            Command::Register(args) => register::run(&args),
            Command::Dataset(args) => dataset::run(&args),
            Command::Init(args) => model::init(&args),
            Command::Forward(args) => open_gpu(
                cli.adapter.as_deref(),
                "`iastgcn forward` (the WGSL forward)",
            )
            .and_then(|gpu| model::forward(&gpu, &args)),
            Command::Train(args) => {
                open_device(cli.adapter.as_deref()).and_then(|device| train::train(&device, &args))
            }
            Command::Refine(args) => {
                open_device(cli.adapter.as_deref()).and_then(|device| train::refine(&device, &args))
            }
            Command::Adapt(args) => {
                open_device(cli.adapter.as_deref()).and_then(|device| adapt::adapt(&device, &args))
            }
            Command::Morning(args) => open_device(cli.adapter.as_deref())
                .and_then(|device| adapt::morning(&device, &args)),
            Command::Confidence(args) => open_device(cli.adapter.as_deref())
                .and_then(|device| confidence::run(&device, &args)),
            Command::Predict(args) => open_device(cli.adapter.as_deref())
                .and_then(|device| train::predict(&device, &args)),
            Command::Compensate(args) => open_device(cli.adapter.as_deref())
                .and_then(|device| compensate::run(device, &args)),
            Command::Budget(args) => budget::run(&args),
            Command::Floor(args) => floor::run(&args),
            Command::Evaluate(args) => {
                open_device(cli.adapter.as_deref()).and_then(|device| demo::evaluate(device, &args))
            }
            Command::Demo(args) => {
                open_device(cli.adapter.as_deref()).and_then(|device| demo::demo(device, &args))
            }
            Command::Reproduce(args) => {
                open_device(cli.adapter.as_deref()).and_then(|device| reproduce::run(device, &args))
            }
            Command::Polish(args) => polish::run(cli.adapter.as_deref(), &args),
            Command::PolishSweep(args) => polish_sweep::run(&args),
            Command::Scale(args) => {
                open_device(cli.adapter.as_deref()).and_then(|device| scale::run(device, &args))
            }
        };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", message(&e));
            ExitCode::FAILURE
        }
    }
}

/// The error as `{:#}` prints it (each cause after the last, joined by ": "), with the
/// library's settings named by their flags ([`with_flags`]).
fn message(e: &anyhow::Error) -> String {
    with_flags(&format!("{e:#}"))
}

/// The settings the library names in its errors (`Error::Setting`) and notes, with the
/// flag that sets each.
const SETTING_FLAGS: [(&str, &str); 12] = [
    ("closed_loop = false", "--open-loop"),
    ("demo.all_models", "--all-models"),
    ("evaluate.models", "--models"),
    ("held_out.sessions", "--held-out-sessions"),
    ("predict.batch", "--batch"),
    ("protocol.machine_seed", "--machine-seed"),
    ("protocol.minutes", "--minutes"),
    ("recipe.sessions", "--sessions"),
    ("sources.graph", "--graph"),
    ("sources.robot", "--robot"),
    ("train.max_epochs", "--max-epochs"),
    ("train.patience", "--patience"),
];

/// A library note with every setting it names written as its flag.
fn with_flags(line: &str) -> String {
    SETTING_FLAGS
        .iter()
        .fold(line.to_string(), |text, (name, flag)| {
            text.replace(name, flag)
        })
}

#[cfg(test)]
mod error_messages {
    use super::message;
    use anyhow::Context;
    use iastgcn::error::Error;

    #[test]
    fn a_setting_is_named_by_its_flag_under_every_context() {
        let lib = Error::Setting {
            setting: "held_out.sessions",
            message: "1 to 16 held-out sessions, got 0".into(),
        }
        .context("evaluation");
        let e = Err::<(), _>(lib).context("iastgcn evaluate").unwrap_err();
        assert_eq!(
            message(&e),
            "iastgcn evaluate: evaluation: --held-out-sessions: 1 to 16 held-out sessions, got 0"
        );
        // A setting with no flag keeps the library's name.
        let other = anyhow::Error::from(Error::Setting {
            setting: "model.heads",
            message: "must divide channels".into(),
        });
        assert_eq!(message(&other), "model.heads: must divide channels");
    }

    #[test]
    fn notes_name_settings_by_their_flags() {
        assert_eq!(
            super::with_flags(
                "to continue, set train.max_epochs above 72 and train.patience above 1"
            ),
            "to continue, set --max-epochs above 72 and --patience above 1"
        );
    }
}

/// Gives SIGPIPE back its default action, which Rust's runtime sets to "ignore": a
/// reader that closes the pipe early (`iastgcn info | head -1`) then ends the program
/// quietly, as it ends `cat`, instead of every `println!` panicking on the broken pipe.
fn restore_sigpipe() {
    #[cfg(unix)]
    // Safe: called first in main, before any other thread exists; SIG_DFL is a valid
    // disposition for SIGPIPE.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// The terminal's [`Reporter`]: a progress bar per task, notes printed as lines.
#[derive(Default)]
pub struct Console {
    bar: Option<ProgressBar>,
}

impl Reporter for Console {
    fn begin(&mut self, what: &str, len: u64) {
        self.end();
        let bar = ProgressBar::new(len);
        let template = format!("{what} {{pos}}/{{len}} {{bar:30}} {{elapsed}} eta {{eta}} {{msg}}");
        if let Ok(style) = ProgressStyle::with_template(&template) {
            bar.set_style(style);
        }
        self.bar = Some(bar);
    }
    fn update(&mut self, pos: u64, message: &str) {
        if let Some(bar) = &self.bar {
            bar.set_position(pos);
            bar.set_message(message.to_string());
        }
    }
    fn end(&mut self) {
        if let Some(bar) = self.bar.take() {
            bar.finish();
        }
    }
    fn note(&mut self, line: &str) {
        let line = with_flags(line);
        // A hidden bar (output not to a terminal) drops what it is asked to print.
        match &self.bar {
            Some(bar) if !bar.is_hidden() => bar.println(line),
            _ => println!("{line}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use clap::{CommandFactory, Parser};

    /// The flags of `command` and of every subcommand below it that have no help text.
    fn without_help(command: &clap::Command, path: &str, missing: &mut Vec<String>) {
        for arg in command.get_arguments() {
            let help = arg.get_help().map(|h| h.to_string()).unwrap_or_default();
            if help.trim().is_empty() {
                missing.push(format!("{path} --{}", arg.get_id()));
            }
        }
        for sub in command.get_subcommands() {
            let path = format!("{path} {}", sub.get_name());
            if sub.get_about().is_none() {
                missing.push(format!("{path} (the command)"));
            }
            without_help(sub, &path, missing);
        }
    }

    /// Every command and every flag of it says what it is for in `--help`.
    #[test]
    fn every_flag_has_a_help_text() {
        let mut missing = Vec::new();
        without_help(&super::Cli::command(), "iastgcn", &mut missing);
        assert!(missing.is_empty(), "without a help text: {missing:?}");
    }

    /// `--arm` is another name of `--robot` wherever a command takes a robot description
    /// (docs/arms.md), not only in `simulate`.
    #[test]
    fn every_robot_flag_is_also_arm() {
        fn walk(command: &clap::Command, path: &str, wrong: &mut Vec<String>, seen: &mut usize) {
            for arg in command.get_arguments() {
                if arg.get_id() == "robot" {
                    *seen += 1;
                    let aliases = arg.get_visible_aliases().unwrap_or_default();
                    if !aliases.contains(&"arm") {
                        wrong.push(path.to_string());
                    }
                }
            }
            for sub in command.get_subcommands() {
                walk(sub, &format!("{path} {}", sub.get_name()), wrong, seen);
            }
        }
        let (mut wrong, mut seen) = (Vec::new(), 0);
        walk(&super::Cli::command(), "iastgcn", &mut wrong, &mut seen);
        assert!(seen >= 5, "only {seen} commands take --robot");
        assert!(wrong.is_empty(), "--robot without --arm: {wrong:?}");
    }

    /// A count out of range is refused naming the flag, not a config field.
    #[test]
    fn dataset_counts_are_refused_by_their_flag() {
        for (flag, value) in [
            ("--window", "0"),
            ("--window", "2000000"),
            ("--stride", "0"),
        ] {
            let args = [
                "iastgcn",
                "dataset",
                "--recordings",
                "a.csv",
                "--calibration",
                "c.toml",
            ];
            let err = super::Cli::try_parse_from(args.iter().chain(&[flag, value]))
                .err()
                .map(|e| e.to_string())
                .unwrap_or_default();
            assert!(err.contains(flag), "{flag} {value}: {err:?}");
        }
    }
}
