//! When compensation matters on the glass (docs/polishing.md "When compensation pays"):
//! one polishing iteration on the raster, planned from a measured surface, walked
//! without a pose error and again with errors of each kind and size, for pads of
//! several footprints (the pass spacing with them) and two pneumatic floats; the cost
//! of an error is the final RMS over the clear aperture less the error-free walk's.

use std::fmt::Write as _;
use std::path::Path;

use crate::error::{ensure, Error, Result};
use crate::experiment::parallel;
use crate::experiment::polish::{csv_bytes, judged};
use crate::experiment::report::seeds::Spread;
use crate::plot::{self, CellAxes, CellMap};
use crate::polish::{
    draw_surface, walk, ErrorKind, Figure, Float, Pad, Polisher, PoseError, Setup, StartingPoint,
    SLOW_CORRELATION_S, SLOW_SMOOTHING_S, TICK_S,
};
use crate::progress::Reporter;
use crate::twin::{PathKind, PathParams};

/// The default pad's footprint, mm: twice its radius plus its orbit (15 + 6 mm).
pub const DEFAULT_FOOTPRINT: f64 = 42.0;

/// A cost that matters, nm RMS: the interferometer's noise per pixel (docs/polishing.md
/// "The loop"), below which one measurement does not resolve a change of the figure.
pub const MATTERS_NM: f64 = 0.5;

/// A pose error to mark on the map, mm.
#[derive(Clone, Debug, PartialEq)]
pub struct Mark {
    /// What it is.
    pub name: String,
    /// Its size, mm (a mean position error: within 8 % of the RMS the sweep's sizes are,
    /// for errors of the sweep's kinds).
    pub size: f64,
}

/// The paper's reported position errors (its Table V, mean over the compensated
/// trajectory): after calibration 0.1393 mm, with IASTGCN compensating 0.0591 mm.
pub fn paper_marks() -> Vec<Mark> {
    vec![
        Mark {
            name: "the paper, calibrated (139 µm)".into(),
            size: 0.1393,
        },
        Mark {
            name: "the paper, IASTGCN compensating (59 µm)".into(),
            size: 0.0591,
        },
    ]
}

/// The pose errors a `polish` run measured (its `polish.csv`): one mark per controller,
/// a model's seeds taken together, the mean of its rows' `position_um` (the pose error
/// the glass saw); the perfect machine, the oracle and the nominal controller's split
/// rows left out.
pub fn marks_from_polish_csv(path: &Path) -> Result<Vec<Mark>> {
    #[derive(serde::Deserialize)]
    struct Row {
        controller: String,
        position_um: f64,
    }
    let mut reader = csv::Reader::from_path(path)
        .map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))?;
    let mut rows = Vec::new();
    for (k, row) in reader.deserialize::<Row>().enumerate() {
        let row =
            row.map_err(|e| Error::Invalid(format!("{} line {}: {e}", path.display(), k + 2)))?;
        rows.push((row.controller, row.position_um));
    }
    Ok(marks_from_rows(
        rows.iter().map(|(c, um)| (c.as_str(), *um)),
    ))
}

/// The marks of a mirror study's rows, `(controller, position_um)`, as
/// [`marks_from_polish_csv`] makes them.
pub fn marks_from_rows<'a>(rows: impl IntoIterator<Item = (&'a str, f64)>) -> Vec<Mark> {
    let mut seen: Vec<(String, f64, usize)> = Vec::new();
    for (controller, um) in rows {
        let skip = ["perfect machine", "oracle"].contains(&controller)
            || controller.starts_with("nominal,");
        if skip || !um.is_finite() {
            continue;
        }
        let controller = without_seed(controller);
        match seen.iter_mut().find(|(c, _, _)| *c == controller) {
            Some((_, sum, n)) => {
                *sum += um;
                *n += 1;
            }
            None => seen.push((controller, um, 1)),
        }
    }
    seen.into_iter()
        .map(|(controller, sum, n)| {
            let um = sum / n as f64;
            Mark {
                name: format!("the twin, {controller} ({um:.0} µm)"),
                size: um / 1000.0,
            }
        })
        .collect()
}

/// A controller's name with its model's `.seed<k>` taken out: `compensated (m.seed2)`
/// is `compensated (m)`.
fn without_seed(controller: &str) -> String {
    match controller.find(".seed") {
        Some(at) => {
            let rest = &controller[at + 5..];
            let digits = rest.chars().take_while(char::is_ascii_digit).count();
            if digits == 0 {
                return controller.to_string();
            }
            format!("{}{}", &controller[..at], &rest[digits..])
        }
        None => controller.to_string(),
    }
}

/// What the sweep runs.
#[derive(Clone, Debug, PartialEq)]
pub struct SweepSpec {
    /// The pads' footprints (2 × (radius + orbit)), mm: each pad is the default one
    /// scaled, and the raster's pass spacing with it.
    pub footprints: Vec<f64>,
    /// The errors' sizes: the RMS of the position error's length, mm.
    pub sizes: Vec<f64>,
    /// The errors' kinds.
    pub kinds: Vec<ErrorKind>,
    /// The floats.
    pub floats: Vec<Float>,
    /// Pixels across a footprint (the map's pitch: the footprint over this, at most
    /// `max_pitch`).
    pub pixels_across: f64,
    /// The coarsest pitch, mm.
    pub max_pitch: f64,
    /// Seed of the starting surface.
    pub surface_seed: u64,
    /// Seeds of the errors' draws: every cell is walked with each, and the tables give
    /// mean ± SD over them.
    pub seeds: Vec<u64>,
    /// Pose errors marked on the map.
    pub marks: Vec<Mark>,
}

impl Default for SweepSpec {
    /// Footprints 14–84 mm, sizes 10 µm to 3 mm, every kind, the ideal and the stiff
    /// float, 21 pixels across a footprint (2 mm at the default pad), surface 1, error
    /// seeds 1–3, the paper's errors marked.
    fn default() -> SweepSpec {
        SweepSpec {
            footprints: vec![14.0, 21.0, 28.0, 42.0, 63.0, 84.0],
            sizes: vec![0.01, 0.03, 0.1, 0.3, 1.0, 3.0],
            kinds: ErrorKind::ALL.to_vec(),
            floats: vec![Float::IDEAL, Float::STIFF],
            pixels_across: 21.0,
            max_pitch: 2.0,
            surface_seed: 1,
            seeds: vec![1, 2, 3],
            marks: paper_marks(),
        }
    }
}

impl SweepSpec {
    /// Checks the spec, naming the field at fault.
    pub fn validate(&self) -> Result<()> {
        let positive = |name: &str, v: &[f64]| {
            ensure(
                !v.is_empty() && v.iter().all(|x| x.is_finite() && *x > 0.0),
                || format!("{name}: give at least one, each a positive number (got {v:?})"),
            )
        };
        positive("footprints", &self.footprints)?;
        positive("sizes", &self.sizes)?;
        positive("pixels across a footprint", &[self.pixels_across])?;
        positive("the coarsest pitch", &[self.max_pitch])?;
        ensure(!self.kinds.is_empty(), || "kinds: give at least one".into())?;
        ensure(!self.seeds.is_empty(), || "seeds: give at least one".into())?;
        ensure(!self.floats.is_empty(), || {
            "floats: give at least one".into()
        })?;
        for f in &self.floats {
            ensure(
                f.stiffness.is_finite()
                    && f.stiffness >= 0.0
                    && f.friction.is_finite()
                    && f.friction >= 0.0,
                || format!("a float's stiffness and friction must be ≥ 0, got {f:?}"),
            )?;
        }
        Ok(())
    }

    /// The set-up for a pad of footprint `footprint` mm: the default pad and pass
    /// spacing scaled by `footprint / 42`, on the raster at its held-out placement. The
    /// Preston constant, the force and the feeds stay: the sliding speed and the
    /// spacing scale together, so a pass removes the same depth at every footprint.
    pub fn setup(&self, footprint: f64) -> Setup {
        let scale = footprint / DEFAULT_FOOTPRINT;
        let mut setup = Setup::new(PathKind::Grid);
        let pad = Pad::default();
        setup.pad = Pad {
            radius: pad.radius * scale,
            orbit_radius: pad.orbit_radius * scale,
            ..pad
        };
        setup.params = PathParams {
            spacing: PathParams::default().spacing * scale,
            ..setup.params
        };
        setup.pitch = (footprint / self.pixels_across).min(self.max_pitch);
        setup
    }
}

/// One cell of the sweep.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SweepRow {
    /// The pad's footprint, mm.
    pub footprint_mm: f64,
    /// The raster's pass spacing, mm.
    pub spacing_mm: f64,
    /// The map's pitch, mm.
    pub pitch_mm: f64,
    /// The error's kind.
    pub kind: String,
    /// The float.
    pub float: String,
    /// The error's size, mm.
    pub size_mm: f64,
    /// The seed of its draws.
    pub seed: u64,
    /// The realised RMS of the error's length, mm.
    pub realised_mm: f64,
    /// The realised SD of the contact force about the plan's, N.
    pub force_sd_n: f64,
    /// The error-free walk's final RMS over the clear aperture, nm.
    pub reference_rms_nm: f64,
    /// This walk's final RMS, nm.
    pub rms_nm: f64,
    /// The cost: `rms_nm − reference_rms_nm`, nm.
    pub cost_rms_nm: f64,
    /// The RMS of the difference between this walk's glass and the error-free one's
    /// (piston and tilt removed), nm: the error's imprint.
    pub imprint_rms_nm: f64,
    /// The error-free walk's final PV, nm.
    pub reference_pv_nm: f64,
    /// This walk's final PV, nm.
    pub pv_nm: f64,
}

/// Per footprint: the starting figure, the plan and the error-free walk.
#[derive(Clone, Debug, PartialEq)]
pub struct FootprintRow {
    /// The pad's footprint, mm.
    pub footprint_mm: f64,
    /// The map's pitch, mm.
    pub pitch_mm: f64,
    /// The starting surface over the clear aperture.
    pub start: Figure,
    /// What the plan expected.
    pub planned: Figure,
    /// The error-free walk's result.
    pub reference: Figure,
    /// The plan's force, N.
    pub force_n: f64,
    /// Minutes of polishing.
    pub minutes: f64,
}

/// What the sweep measured.
#[derive(Clone, Debug, PartialEq)]
pub struct SweepResult {
    /// One per footprint.
    pub footprints: Vec<FootprintRow>,
    /// One per footprint × kind × float × size × seed, in that order.
    pub rows: Vec<SweepRow>,
}

/// Runs the sweep: per footprint, the surface drawn, measured and planned once, walked
/// without error and with each kind, float, size and seed (the walks one per core; the
/// rows in the same order and bits whichever core ran them).
pub fn run(spec: &SweepSpec, reporter: &mut dyn Reporter) -> Result<SweepResult> {
    spec.validate()?;
    let per_footprint = spec.kinds.len() * spec.floats.len() * spec.sizes.len() * spec.seeds.len();
    let (mut footprints, mut rows) = (Vec::new(), Vec::new());
    let total = (spec.footprints.len() * (per_footprint + 1)) as u64;
    reporter.begin("polishing walks", total);
    let mut done = 0u64;
    for &footprint in &spec.footprints {
        let setup = spec.setup(footprint);
        let spacing = setup.params.spacing;
        let mut polisher = Polisher::new(setup)
            .map_err(|e| Error::Invalid(format!("a pad of footprint {footprint} mm: {e}")))?;
        let surface = draw_surface(
            polisher.grid,
            polisher.mirror.radius(),
            &polisher.clear,
            &StartingPoint::default(),
            spec.surface_seed,
        );
        let measured = polisher.measure(&surface, spec.surface_seed);
        let dwell = polisher.plan(&measured)?;
        let reference = walk(&polisher, &surface, &dwell, &PoseError::NONE)?;
        done += 1;
        reporter.update(done, &format!("{footprint} mm: error-free"));
        let (reference_map, reference_fig) = judged(&polisher, &reference.surface);
        footprints.push(FootprintRow {
            footprint_mm: footprint,
            pitch_mm: polisher.grid.pitch,
            start: judged(&polisher, &surface).1,
            planned: dwell.planned,
            reference: reference_fig,
            force_n: dwell.force,
            minutes: reference.ticks as f64 * TICK_S / 60.0,
        });
        let mut jobs = Vec::with_capacity(per_footprint);
        for &kind in &spec.kinds {
            for float in &spec.floats {
                for &size in &spec.sizes {
                    for &seed in &spec.seeds {
                        jobs.push(PoseError {
                            kind,
                            size,
                            float: *float,
                            seed,
                        });
                    }
                }
            }
        }
        let (polisher, surface, dwell, reference_map) =
            (&polisher, &surface, &dwell, &reference_map);
        let walked = parallel::run_all(
            jobs,
            parallel::workers(true),
            |error, tick| -> Result<SweepRow> {
                let w = walk(polisher, surface, dwell, &error)?;
                let (map, fig) = judged(polisher, &w.surface);
                let mut imprint = map;
                for (v, r) in imprint.values.iter_mut().zip(&reference_map.values) {
                    *v -= r;
                }
                let (_, imprint) = judged(polisher, &imprint);
                tick();
                Ok(SweepRow {
                    footprint_mm: footprint,
                    spacing_mm: spacing,
                    pitch_mm: polisher.grid.pitch,
                    kind: error.kind.name().into(),
                    float: error.float.name(),
                    size_mm: error.size,
                    seed: error.seed,
                    realised_mm: w.error_rms,
                    force_sd_n: w.force_sd,
                    reference_rms_nm: reference_fig.rms,
                    rms_nm: fig.rms,
                    cost_rms_nm: fig.rms - reference_fig.rms,
                    imprint_rms_nm: imprint.rms,
                    reference_pv_nm: reference_fig.pv,
                    pv_nm: fig.pv,
                })
            },
            || {
                done += 1;
                reporter.update(done, &format!("{footprint} mm"));
            },
        )?;
        let worst = walked
            .iter()
            .map(|r| r.cost_rms_nm)
            .fold(f64::NEG_INFINITY, f64::max);
        reporter.note(&format!(
            "{footprint} mm footprint ({:.2} mm pixels): the error-free walk leaves {:.2} nm RMS; the costliest error adds {worst:+.2} nm",
            polisher.grid.pitch, reference_fig.rms
        ));
        rows.extend(walked);
    }
    reporter.end();
    Ok(SweepResult { footprints, rows })
}

/// A cell's cost over its seeds (`None` where the sweep has no such cell).
pub fn cost(
    result: &SweepResult,
    footprint: f64,
    kind: &str,
    float: &str,
    size: f64,
) -> Option<Spread> {
    let costs: Vec<f64> = result
        .rows
        .iter()
        .filter(|r| {
            r.footprint_mm == footprint && r.kind == kind && r.float == float && r.size_mm == size
        })
        .map(|r| r.cost_rms_nm)
        .collect();
    (!costs.is_empty()).then(|| Spread::of(&costs))
}

/// The smallest of `sizes` at which `kind` under `float` costs at least [`MATTERS_NM`]
/// on a pad of `footprint` mm (the mean over seeds), if any does.
pub fn matters_from(
    result: &SweepResult,
    sizes: &[f64],
    footprint: f64,
    kind: &str,
    float: &str,
) -> Option<f64> {
    sizes
        .iter()
        .copied()
        .filter(|&size| {
            cost(result, footprint, kind, float, size).is_some_and(|c| c.mean >= MATTERS_NM)
        })
        .min_by(f64::total_cmp)
}

/// Formats a size in mm as µm below a millimetre.
fn size_label(mm: f64) -> String {
    if mm < 1.0 {
        format!("{:.0} µm", mm * 1000.0)
    } else {
        format!("{mm} mm")
    }
}

/// The float names of `spec`, in its order.
fn float_names(spec: &SweepSpec) -> Vec<String> {
    spec.floats.iter().map(Float::name).collect()
}

/// `sweep.md`: what ran, the cost tables per float and kind, and where the cost starts
/// to matter.
pub fn report(spec: &SweepSpec, result: &SweepResult) -> String {
    let mut s = String::from("# When compensation matters on the glass\n\n");
    let _ = writeln!(
        s,
        "One polishing iteration on the raster (docs/polishing.md \"When compensation pays\"): surface {} drawn, measured and planned once per pad; the plan walked at its feed without a pose error and again with one of each kind, size and float (error seeds {}); the cost is the final RMS over the clear aperture less the error-free walk's, in nm (negative: the error happened to help). Pads: the default one (30 mm, 6 mm orbit: a 42 mm footprint) scaled, the pass spacing with it (15 mm at 42 mm); the force, the feeds and Preston's constant as at 42 mm, so a pass removes the same depth at every footprint. Kinds: slow (a drift, correlation time {SLOW_CORRELATION_S} s, smoothed over {SLOW_SMOOTHING_S} s), pass-to-pass (backlash: each axis off with the sign of its travel, jumping at the raster's turns) and white (per tick). A size is the RMS of the position error's length (each axis a third of its square); the pad stays square to the glass. A cost of {MATTERS_NM} nm or more (the interferometer's noise per pixel) is taken to matter.\n",
        spec.surface_seed,
        spec.seeds
            .iter()
            .map(u64::to_string)
            .collect::<Vec<_>>()
            .join(", ")
    );
    let _ = writeln!(s, "| footprint (mm) | pitch (mm) | start RMS (nm) | planned (nm) | error-free walk RMS / PV (nm) | force (N) | polishing (min) |\n|---:|---:|---:|---:|---|---:|---:|");
    for f in &result.footprints {
        let _ = writeln!(
            s,
            "| {} | {:.2} | {:.2} | {:.2} | {:.2} / {:.1} | {:.0} | {:.1} |",
            f.footprint_mm,
            f.pitch_mm,
            f.start.rms,
            f.planned.rms,
            f.reference.rms,
            f.reference.pv,
            f.force_n,
            f.minutes
        );
    }
    for float in float_names(spec) {
        for kind in &spec.kinds {
            let _ = writeln!(
                s,
                "\n## {}, {float}: cost in final RMS (nm), mean ± SD over {} error seed(s)\n",
                kind.name(),
                spec.seeds.len()
            );
            let header: Vec<String> = spec.sizes.iter().map(|&m| size_label(m)).collect();
            let _ = writeln!(
                s,
                "| footprint | {} | matters from |\n|---:|{}---|",
                header.join(" | "),
                "---:|".repeat(header.len())
            );
            for &footprint in &spec.footprints {
                let cells: Vec<String> = spec
                    .sizes
                    .iter()
                    .map(|&size| {
                        cost(result, footprint, kind.name(), &float, size)
                            .map_or("–".into(), |c| format!("{:+.3} ± {:.3}", c.mean, c.sd))
                    })
                    .collect();
                let from = matters_from(result, &spec.sizes, footprint, kind.name(), &float)
                    .map_or("beyond the sweep".into(), size_label);
                let _ = writeln!(s, "| {footprint} mm | {} | {from} |", cells.join(" | "));
            }
        }
    }
    if !spec.marks.is_empty() {
        let _ = writeln!(s, "\nMarked on `map.png`:");
        for m in &spec.marks {
            let _ = writeln!(s, "- {}", m.name);
        }
    }
    s
}

/// One pad's costs as a table: a row per kind and float, a column per size, and from
/// which size the cost matters (the demo's report).
pub fn pad_table(spec: &SweepSpec, result: &SweepResult, footprint: f64) -> String {
    let header: Vec<String> = spec.sizes.iter().map(|&m| size_label(m)).collect();
    let mut s = format!(
        "| kind, float | {} | matters (≥ {MATTERS_NM} nm) from |\n|---|{}---|\n",
        header.join(" | "),
        "---:|".repeat(header.len())
    );
    for float in float_names(spec) {
        for kind in &spec.kinds {
            let cells: Vec<String> = spec
                .sizes
                .iter()
                .map(|&size| {
                    cost(result, footprint, kind.name(), &float, size)
                        .map_or("–".into(), |c| format!("{:+.3}", c.mean))
                })
                .collect();
            let from = matters_from(result, &spec.sizes, footprint, kind.name(), &float)
                .map_or("beyond the sweep".into(), size_label);
            let _ = writeln!(
                s,
                "| {}, {float} | {} | {from} |",
                kind.name(),
                cells.join(" | ")
            );
        }
    }
    s
}

/// Where `size` falls between the sweep's sizes, in columns (log interpolation; 0 is
/// the first size's column).
fn column_of(sizes: &[f64], size: f64) -> f64 {
    let logs: Vec<f64> = sizes.iter().map(|s| s.log10()).collect();
    let x = size.log10();
    match logs.len() {
        0 => 0.0,
        1 => 0.0,
        n => {
            let k = logs.windows(2).position(|w| x <= w[1]).unwrap_or(n - 2);
            k as f64 + (x - logs[k]) / (logs[k + 1] - logs[k])
        }
    }
}

/// Writes `sweep.csv`, `sweep.md` and `map.png` (a panel per kind and float: footprint
/// against size, each cell its cost) into `dir`, atomically.
pub fn write(dir: &Path, spec: &SweepSpec, result: &SweepResult) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let bytes = csv_bytes(&result.rows, "sweep.csv")?;
    let mut batch = crate::atomic::Batch::new();
    for (name, b) in [
        ("sweep.csv", bytes),
        ("sweep.md", report(spec, result).into_bytes()),
    ] {
        let path = dir.join(name);
        batch.add(&path, &b).map_err(|e| Error::io(&path, e))?;
    }
    batch.commit().map_err(|e| Error::io(dir, e))?;
    let mut maps = Vec::new();
    for float in float_names(spec) {
        for kind in &spec.kinds {
            let mut values = Vec::new();
            for &footprint in &spec.footprints {
                for &size in &spec.sizes {
                    values.push(
                        cost(result, footprint, kind.name(), &float, size)
                            .map_or(f64::NAN, |c| c.mean),
                    );
                }
            }
            maps.push(CellMap {
                title: format!("{}, {float}", kind.name()),
                values,
            });
        }
    }
    let axes = CellAxes {
        columns: spec.sizes.iter().map(|&m| size_label(m)).collect(),
        rows: spec.footprints.iter().map(|f| format!("{f}")).collect(),
        x_title: "pose error (RMS of the position error's length)".into(),
        y_title: "pad footprint (mm)".into(),
        marks: spec
            .marks
            .iter()
            .map(|m| (column_of(&spec.sizes, m.size), m.name.clone()))
            .collect(),
    };
    // The colour's top: the costliest single walk, at least ten times what matters.
    let top = result
        .rows
        .iter()
        .map(|r| r.cost_rms_nm)
        .fold(MATTERS_NM * 10.0, f64::max);
    plot::cell_maps(
        &dir.join("map.png"),
        &maps,
        spec.kinds.len(),
        &axes,
        (0.01, top),
        MATTERS_NM,
        "the cost in final RMS over the clear aperture, nm (mean over the error seeds)",
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A mark between two sizes falls between their columns, at its log position.
    #[test]
    fn marks_fall_at_their_log_position() {
        let sizes = [0.01, 0.1, 1.0];
        assert!((column_of(&sizes, 0.01) - 0.0).abs() < 1e-12);
        assert!((column_of(&sizes, 0.1393) - (1.0 + 0.1393f64.log10() + 1.0)).abs() < 1e-12);
        assert!((column_of(&sizes, 1.0) - 2.0).abs() < 1e-12);
    }

    /// A cell is the mean ± SD over its seeds, and the cost matters from the smallest
    /// size whose mean reaches [`MATTERS_NM`].
    #[test]
    fn cells_average_their_seeds() {
        let row = |size: f64, seed: u64, cost: f64| SweepRow {
            footprint_mm: 42.0,
            spacing_mm: 15.0,
            pitch_mm: 2.0,
            kind: "slow".into(),
            float: "ideal float".into(),
            size_mm: size,
            seed,
            realised_mm: size,
            force_sd_n: 0.0,
            reference_rms_nm: 8.0,
            rms_nm: 8.0 + cost,
            cost_rms_nm: cost,
            imprint_rms_nm: cost.abs(),
            reference_pv_nm: 100.0,
            pv_nm: 100.0,
        };
        let result = SweepResult {
            footprints: vec![],
            rows: vec![
                row(0.1, 1, 0.2),
                row(0.1, 2, 0.9),
                row(1.0, 1, 0.6),
                row(1.0, 2, 0.8),
            ],
        };
        let c = cost(&result, 42.0, "slow", "ideal float", 0.1).unwrap();
        assert!((c.mean - 0.55).abs() < 1e-12 && c.n == 2);
        assert!(cost(&result, 42.0, "white", "ideal float", 0.1).is_none());
        // 0.1 mm: one seed above, the mean (0.55) too; with 0.2 and 0.7 it would not be.
        let sizes = [0.1, 1.0];
        assert_eq!(
            matters_from(&result, &sizes, 42.0, "slow", "ideal float"),
            Some(0.1)
        );
        let mut lower = result.clone();
        lower.rows[1].cost_rms_nm = 0.7;
        assert_eq!(
            matters_from(&lower, &sizes, 42.0, "slow", "ideal float"),
            Some(1.0)
        );
        assert_eq!(
            matters_from(&lower, &sizes, 84.0, "slow", "ideal float"),
            None
        );
    }

    /// A model's seeds make one mark.
    #[test]
    fn seeds_are_taken_out_of_a_controller_name() {
        assert_eq!(
            without_seed("compensated (iastgcn-a.seed12)"),
            "compensated (iastgcn-a)"
        );
        assert_eq!(without_seed("calibrated"), "calibrated");
        assert_eq!(
            without_seed("compensated (m.seedling)"),
            "compensated (m.seedling)"
        );
    }

    /// Bad specs name their field.
    #[test]
    fn bad_specs_are_refused() {
        let bad = SweepSpec {
            footprints: vec![],
            ..SweepSpec::default()
        };
        let e = bad.validate().unwrap_err().to_string();
        assert!(e.contains("footprints"), "{e}");
        let bad = SweepSpec {
            sizes: vec![0.1, -1.0],
            ..SweepSpec::default()
        };
        assert!(bad.validate().unwrap_err().to_string().contains("sizes"));
    }

    /// The pad and the spacing scale with the footprint; the pitch resolves it.
    #[test]
    fn pads_scale_with_the_footprint() {
        let spec = SweepSpec::default();
        let s = spec.setup(14.0);
        assert!((2.0 * (s.pad.radius + s.pad.orbit_radius) - 14.0).abs() < 1e-12);
        assert!((s.params.spacing - 5.0).abs() < 1e-12);
        assert!((s.pitch - 14.0 / 21.0).abs() < 1e-12);
        let d = spec.setup(DEFAULT_FOOTPRINT);
        assert_eq!(d.pad, Pad::default());
        assert_eq!(d.pitch, 2.0);
    }
}
