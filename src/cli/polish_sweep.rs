//! `iastgcn polish-sweep`: when compensation matters on the glass (docs/polishing.md
//! "When compensation pays"): one polishing iteration walked with pose errors of each
//! kind and size, for pads of several footprints and two pneumatic floats, drawn as a
//! map of the cost in final RMS.

use std::path::PathBuf;

use anyhow::Context;

use super::Console;
use iastgcn::experiment::polish_sweep::{self, Mark, SweepSpec};
use iastgcn::polish::{ErrorKind, Float};
use iastgcn::progress::Reporter;

#[derive(clap::Args)]
pub struct PolishSweepArgs {
    /// Pad footprints, mm, comma-separated (2 × (radius + orbit); the default pad's is 42):
    /// each pad is the default one scaled, the raster's pass spacing with it.
    #[arg(long, value_delimiter = ',', default_value = "14,21,28,42,63,84")]
    pub footprints: Vec<f64>,
    /// Pose error sizes, mm, comma-separated: the RMS of the position error's length.
    #[arg(long, value_delimiter = ',', default_value = "0.01,0.03,0.1,0.3,1,3")]
    pub sizes: Vec<f64>,
    /// Kinds of pose error, comma-separated: slow (a drift), pass-to-pass (backlash that
    /// jumps at the raster's turns), white (jitter).
    #[arg(long, value_delimiter = ',', default_value = "slow,pass-to-pass,white")]
    pub kinds: Vec<String>,
    /// Pneumatic floats, comma-separated: `ideal` (the force whatever the height) and
    /// `stiff` (a 4 N/mm air column and 3 N of seal friction: a height error becomes a
    /// force error).
    #[arg(long, value_delimiter = ',', default_value = "ideal,stiff")]
    pub floats: Vec<String>,
    /// Map pixels across a footprint (the pitch is the footprint over this).
    #[arg(long, default_value_t = 21.0)]
    pub pixels_across: f64,
    /// The coarsest map pitch, mm.
    #[arg(long, default_value_t = 2.0)]
    pub max_pixel_mm: f64,
    /// Seed of the starting surface.
    #[arg(long, default_value_t = 1)]
    pub surface_seed: u64,
    /// Seeds of the errors' draws, comma-separated: every cell is walked with each, and
    /// the tables give mean ± SD over them.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
    pub seeds: Vec<u64>,
    /// Mark the pose errors a `polish` run measured (its polish.csv) on the map, beside
    /// the paper's.
    #[arg(long)]
    pub marks_from: Option<PathBuf>,
    /// Output folder: sweep.md, sweep.csv, map.png.
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(args: &PolishSweepArgs) -> anyhow::Result<()> {
    let kinds = args
        .kinds
        .iter()
        .map(|k| ErrorKind::parse(k))
        .collect::<Result<Vec<_>, _>>()
        .context("--kinds")?;
    let floats = args
        .floats
        .iter()
        .map(|f| match f.as_str() {
            "ideal" => Ok(Float::IDEAL),
            "stiff" => Ok(Float::STIFF),
            other => Err(anyhow::anyhow!(
                "--floats: unknown float {other:?}: expected ideal or stiff"
            )),
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let mut marks: Vec<Mark> = polish_sweep::paper_marks();
    if let Some(path) = &args.marks_from {
        marks.extend(polish_sweep::marks_from_polish_csv(path).context("--marks-from")?);
    }
    let spec = SweepSpec {
        footprints: args.footprints.clone(),
        sizes: args.sizes.clone(),
        kinds,
        floats,
        pixels_across: args.pixels_across,
        max_pitch: args.max_pixel_mm,
        surface_seed: args.surface_seed,
        seeds: args.seeds.clone(),
        marks,
    };
    spec.validate()?;
    super::make_output_folder("--out", &args.out)?;
    let mut console = Console::default();
    let result = polish_sweep::run(&spec, &mut console).context("the sweep")?;
    console.end();
    polish_sweep::write(&args.out, &spec, &result)?;
    println!("{}", polish_sweep::report(&spec, &result));
    println!("written to {}", args.out.display());
    Ok(())
}
