//! The mirror study (`iastgcn polish`, docs/polishing.md): the same starting surfaces
//! polished for the same iterations under each controller (nominal, calibrated, each
//! model compensating online, the oracle, and a perfect machine), their PV and RMS per
//! iteration (Fig. 13), Table VI's decrease and convergence ratio as mean ± SD over
//! surface seeds, and the maps before and after (Fig. 14).

use std::fmt::Write as _;
use std::path::Path;
use std::sync::Mutex;

use crate::compensate::held_out::warm_up;
use crate::compensate::online::{Feedback, Online};
use crate::error::{Error, Result};
use crate::experiment::evaluate::LoopModel;
use crate::experiment::parallel;
use crate::plot::{self, HeatMap, Panel, Series};
use crate::polish::{draw_surface, Figure, HeightMap, Polisher, PoseSource, StartingPoint};
use crate::progress::Reporter;
use crate::robot::Robot;
use crate::stats::Summary;
use crate::twin::{Machine, MachineState};

/// What the study runs.
#[derive(Clone, Debug, PartialEq)]
pub struct PolishSpec {
    /// Polishing iterations (measure, plan, polish) per surface and controller.
    pub iterations: usize,
    /// Seeds of the starting surfaces.
    pub surface_seeds: Vec<u64>,
    /// Seed of the polishing runs (the same for every controller: the force, the
    /// sensors and the interferometer draw the same).
    pub seed: u64,
    /// Minutes of polishing that warm the machine up before each iteration.
    pub warm_up_minutes: f64,
    /// Predict every this many control ticks.
    pub every: usize,
    /// What the surfaces are scaled to.
    pub start: StartingPoint,
    /// Also run the nominal controller's position and attitude errors each alone.
    pub split_nominal: bool,
}

/// One controller's surface at one iteration.
#[derive(Clone, Debug, serde::Serialize)]
pub struct PolishRow {
    /// The starting surface's seed.
    pub surface_seed: u64,
    /// The controller: `nominal`, `calibrated`, `compensated (<model>)`, `oracle`,
    /// `perfect machine`.
    pub controller: String,
    /// Iterations done before this state (0: the starting surface).
    pub iteration: usize,
    /// The true surface over the clear aperture, piston and tilt removed.
    pub pv_nm: f64,
    /// Its RMS, nm.
    pub rms_nm: f64,
    /// What the interferometer reported (the plan's input), over the clear aperture.
    pub measured_rms_nm: f64,
    /// The RMS the dwell plan expected to leave, nm (NaN at the last state).
    pub planned_rms_nm: f64,
    /// Minutes the iteration that follows this state polished (NaN at the last state).
    pub minutes: f64,
    /// The pneumatic force that iteration was planned and run at, N (NaN at the last
    /// state).
    pub force_n: f64,
    /// Mean true pad position error of that iteration's run, µm (NaN at the last state).
    pub position_um: f64,
    /// Mean true tool-axis error of that run, mdeg (NaN at the last state).
    pub attitude_mdeg: f64,
}

/// The study's rows and the first surface's maps.
#[derive(Clone, Debug)]
pub struct PolishResult {
    /// Every controller's state at every iteration, every surface.
    pub rows: Vec<PolishRow>,
    /// The first surface seed's starting map and each controller's last map
    /// (controller, map), true surface, piston and tilt removed, NaN off the glass.
    pub maps: Vec<(String, HeightMap)>,
}

/// A controller of the study.
enum Controller<'m> {
    Plain(&'static str, &'m Robot, PoseSource),
    Model(&'m mut LoopModel),
    Oracle(usize),
}

/// The true surface as the figures judge it: piston and tilt removed over the clear
/// aperture.
pub(crate) fn judged(polisher: &Polisher, surface: &HeightMap) -> (HeightMap, Figure) {
    let mut m = surface.clone();
    m.remove_plane(&polisher.clear);
    let f = m.figure(&polisher.clear);
    (m, f)
}

/// The map as Fig. 14 shows it: [`judged`], NaN off the glass.
fn shown(polisher: &Polisher, surface: &HeightMap) -> HeightMap {
    let (mut m, _) = judged(polisher, surface);
    for (v, &g) in m.values.iter_mut().zip(&polisher.glass) {
        if !g {
            *v = f64::NAN;
        }
    }
    m
}

/// The controllers of `rows`, in the order first seen.
fn controllers(rows: &[PolishRow]) -> Vec<&str> {
    let mut names: Vec<&str> = Vec::new();
    for r in rows {
        if !names.contains(&r.controller.as_str()) {
            names.push(&r.controller);
        }
    }
    names
}

/// Runs the study: every surface seed under `nominal` (with `spec.split_nominal`, also
/// its position and attitude errors each alone, the other taken from the path's
/// target), `calibrated`, each of
/// `models` (compensating from the calibrated controller), the oracle (a `window`-tick
/// model's latency) and a perfect machine (the pad at the path's target pose).
///
/// No controller reads another's surface: where the polisher and every model run on
/// the native CPU path, the controllers go one per core (each worker plans with a
/// polisher of its own, [`Polisher::fork`]); the rows come in the same order, and the
/// same bits, whichever ran first.
#[allow(clippy::too_many_arguments)]
pub fn run(
    polisher: &mut Polisher,
    spec: &PolishSpec,
    machine: &Machine,
    nominal: &Robot,
    calibrated: &Robot,
    models: &mut [LoopModel],
    window: usize,
    progress: &mut dyn Reporter,
) -> Result<PolishResult> {
    if spec.iterations == 0 || spec.surface_seeds.is_empty() {
        return Err(Error::Invalid(
            "the mirror study needs at least one iteration and one surface seed".into(),
        ));
    }
    let initial: Vec<HeightMap> = spec
        .surface_seeds
        .iter()
        .map(|&seed| {
            draw_surface(
                polisher.grid,
                polisher.mirror.radius(),
                &polisher.clear,
                &spec.start,
                seed,
            )
        })
        .collect();
    let all_native = polisher.all_native() && models.iter().all(LoopModel::predicts_natively);
    let mut controllers: Vec<Controller> =
        vec![Controller::Plain("nominal", nominal, PoseSource::True)];
    if spec.split_nominal {
        controllers.push(Controller::Plain(
            "nominal, position error only",
            nominal,
            PoseSource::PositionOnly,
        ));
        controllers.push(Controller::Plain(
            "nominal, attitude error only",
            nominal,
            PoseSource::AttitudeOnly,
        ));
    }
    controllers.push(Controller::Plain(
        "calibrated",
        calibrated,
        PoseSource::True,
    ));
    controllers.extend(models.iter_mut().map(Controller::Model));
    controllers.push(Controller::Oracle(window));
    controllers.push(Controller::Plain(
        "perfect machine",
        calibrated,
        PoseSource::Target,
    ));
    let count = controllers.len();
    let workers = parallel::workers(all_native).min(count);
    // Every controller driving the same robot warms the machine up from the same state
    // for an iteration: each distinct warm-up is run once, here, before the walks.
    let mut robots: Vec<&Robot> = Vec::new();
    for c in &controllers {
        let robot = c.robot(calibrated);
        if !robots.iter().any(|r| std::ptr::eq(*r, robot)) {
            robots.push(robot);
        }
    }
    let warm_ups: Vec<(usize, u64)> = (0..robots.len())
        .flat_map(|r| {
            spec.surface_seeds.iter().flat_map(move |&surface_seed| {
                (0..spec.iterations).map(move |it| (r, run_seed(spec, it, surface_seed)))
            })
        })
        .collect();
    let states = parallel::run_all(
        warm_ups.clone(),
        parallel::workers(true).min(warm_ups.len()),
        |(r, seed), _| {
            warm_up(
                machine,
                robots[r],
                spec.warm_up_minutes * 60.0,
                seed ^ 0x5741,
            )
        },
        || {},
    )?;
    let walks = Walks {
        machine,
        calibrated,
        robots,
        runs: warm_ups.into_iter().zip(states).collect(),
    };
    // One polisher per worker: the dwell solver keeps its scratch between plans.
    let mut forks = (1..workers)
        .map(|_| polisher.fork())
        .collect::<Result<Vec<_>>>()?;
    let pool: Mutex<Vec<&mut Polisher>> = Mutex::new(
        std::iter::once(&mut *polisher)
            .chain(forks.iter_mut())
            .collect(),
    );
    let iterations = (spec.surface_seeds.len() * spec.iterations) as u64;
    progress.begin(
        &format!(
            "the mirror: {count} controllers × {} surface(s) × {} iterations ({workers} at a time)",
            spec.surface_seeds.len(),
            spec.iterations
        ),
        count as u64 * iterations * PER_ITERATION,
    );
    let mut done = 0;
    // The walks that predict at every tick first, so that the last to end is a short one.
    let per_controller = parallel::run_all_costliest_first(
        controllers,
        |c| match c {
            Controller::Model(_) => 2.0,
            Controller::Oracle(_) => 1.0,
            Controller::Plain(..) => 0.0,
        },
        workers,
        |_, controller, tick| {
            // invariant: no thread panics while holding the pool's lock, and each of the
            // `workers` threads holds at most one polisher at a time.
            let polisher = pool
                .lock()
                .expect("the polishers")
                .pop()
                .expect("a polisher per worker");
            let out = polish_with(&mut *polisher, controller, spec, &initial, &walks, tick);
            // invariant: as above, no thread panics while holding the pool's lock.
            pool.lock().expect("the polishers").push(polisher);
            out
        },
        || {
            done += 1;
            progress.update(done, "");
        },
    );
    progress.end();
    let per_controller = per_controller?;
    drop(pool);
    let polisher = &*polisher;
    let mut rows = Vec::new();
    let mut maps = Vec::new();
    for (k, (&surface_seed, initial)) in spec.surface_seeds.iter().zip(&initial).enumerate() {
        let start_rms = judged(polisher, initial).1.rms;
        if k == 0 {
            maps.push(("start".to_string(), shown(polisher, initial)));
        }
        for (name, runs) in &per_controller {
            let (surface_rows, surface) = &runs[k];
            rows.extend_from_slice(surface_rows);
            let last = surface_rows.last().map_or(f64::NAN, |r| r.rms_nm);
            progress.note(&format!(
                "surface {surface_seed}, {name}: RMS {start_rms:.2} → {last:.2} nm"
            ));
            if k == 0 {
                maps.push((name.clone(), shown(polisher, surface)));
            }
        }
    }
    Ok(PolishResult { rows, maps })
}

impl<'m> Controller<'m> {
    /// The robot model the controller drives.
    fn robot<'r>(&self, calibrated: &'r Robot) -> &'r Robot
    where
        'm: 'r,
    {
        match self {
            Controller::Plain(_, robot, _) => robot,
            _ => calibrated,
        }
    }
}

/// The seed of iteration `it`'s walk on surface `surface_seed`.
fn run_seed(spec: &PolishSpec, it: usize, surface_seed: u64) -> u64 {
    spec.seed.wrapping_add(1000 * it as u64 + surface_seed)
}

/// The machine, the calibrated robot, and the states the walks start from: per robot a
/// controller drives and walk seed, the state after the spec's warm-up.
struct Walks<'r> {
    machine: &'r Machine,
    calibrated: &'r Robot,
    robots: Vec<&'r Robot>,
    runs: Vec<((usize, u64), MachineState)>,
}

impl Walks<'_> {
    /// The warmed-up state for `robot`'s walk of seed `run_seed`.
    fn start(&self, robot: &Robot, run_seed: u64) -> Result<MachineState> {
        let r = self.robots.iter().position(|r| std::ptr::eq(*r, robot));
        self.runs
            .iter()
            .find(|((i, seed), _)| Some(*i) == r && *seed == run_seed)
            .map(|(_, state)| state.clone())
            .ok_or_else(|| Error::Invalid(format!("no warm-up for the walk of seed {run_seed}")))
    }
}

/// One controller on one starting surface: its rows, then its last surface.
type SurfaceRun = (Vec<PolishRow>, HeightMap);

/// Progress units per polishing iteration.
const PER_ITERATION: u64 = 100;

/// One controller's name and, per starting surface of `initial` (the seeds of
/// `spec.surface_seeds`), its rows and its last surface; `tick` is called
/// [`PER_ITERATION`] times per iteration, as the walk goes.
fn polish_with(
    polisher: &mut Polisher,
    mut controller: Controller,
    spec: &PolishSpec,
    initial: &[HeightMap],
    walks: &Walks,
    tick: &dyn Fn(),
) -> Result<(String, Vec<SurfaceRun>)> {
    let settings = Online { every: spec.every };
    let name = match &controller {
        Controller::Plain(name, ..) => name.to_string(),
        Controller::Model(m) => format!("compensated ({})", m.name),
        Controller::Oracle(_) => "oracle".to_string(),
    };
    let robot = controller.robot(walks.calibrated);
    let mut out = Vec::with_capacity(initial.len());
    for (&surface_seed, initial) in spec.surface_seeds.iter().zip(initial) {
        let mut rows = Vec::with_capacity(spec.iterations + 1);
        let mut surface = initial.clone();
        for it in 0..=spec.iterations {
            let (_, figure) = judged(polisher, &surface);
            let measured = polisher.measure(&surface, spec.seed ^ (surface_seed << 20) ^ it as u64);
            let mut row = PolishRow {
                surface_seed,
                controller: name.clone(),
                iteration: it,
                pv_nm: figure.pv,
                rms_nm: figure.rms,
                measured_rms_nm: measured.figure(&polisher.clear).rms,
                planned_rms_nm: f64::NAN,
                minutes: f64::NAN,
                force_n: f64::NAN,
                position_um: f64::NAN,
                attitude_mdeg: f64::NAN,
            };
            if it == spec.iterations {
                rows.push(row);
                break;
            }
            let dwell = polisher.plan(&measured)?;
            let plan = polisher.feed(&dwell)?;
            let seconds = plan.duration(polisher.path_length());
            let run_seed = run_seed(spec, it, surface_seed);
            let start = walks.start(robot, run_seed)?;
            // The walk's share of its planned ticks, in progress units.
            let planned = ((seconds / 0.02).round() as u64).max(1);
            let mut reported = 0;
            let mut on_tick = |t: usize| {
                let due = (t as u64 * PER_ITERATION / planned).min(PER_ITERATION - 1);
                while reported < due {
                    tick();
                    reported += 1;
                }
            };
            let (pose, feedback) = match &mut controller {
                Controller::Plain(_, _, pose) => (*pose, Feedback::None),
                Controller::Model(m) => (
                    PoseSource::True,
                    Feedback::Model(&mut m.members, &m.graph, settings),
                ),
                Controller::Oracle(window) => (
                    PoseSource::True,
                    Feedback::Oracle {
                        window: *window,
                        settings,
                    },
                ),
            };
            let r = polisher.polish(
                walks.machine,
                robot,
                start,
                feedback,
                plan,
                run_seed,
                pose,
                &mut surface,
                &mut on_tick,
            )?;
            for _ in reported..PER_ITERATION {
                tick();
            }
            row.planned_rms_nm = dwell.planned.rms;
            row.force_n = dwell.force;
            // The walk's own time: the feed follows the force.
            row.minutes = r.truth.position.count as f64 * 0.02 / 60.0;
            // The pose error the glass sees: the perfect machine's pad is at its
            // target, the split rows keep one part of the error.
            let (position, attitude) = (r.truth.position.mean, r.truth.attitude.mean);
            (row.position_um, row.attitude_mdeg) = match pose {
                PoseSource::True => (position, attitude),
                PoseSource::Target => (0.0, 0.0),
                PoseSource::PositionOnly => (position, 0.0),
                PoseSource::AttitudeOnly => (0.0, attitude),
            };
            rows.push(row);
        }
        out.push((rows, surface));
    }
    Ok((name, out))
}

/// Table VI's figures for one controller over the surface seeds.
#[derive(Clone, Debug)]
pub struct TableViRow {
    /// The controller.
    pub controller: String,
    /// PV before and after, nm.
    pub pv: [Summary; 2],
    /// RMS before and after, nm.
    pub rms: [Summary; 2],
    /// PV decrease, %.
    pub pv_decrease: Summary,
    /// RMS decrease (the convergence ratio (RMS₀ − RMS₁)/RMS₀), %.
    pub rms_decrease: Summary,
    /// Minutes polished over all iterations.
    pub minutes: Summary,
    /// Mean true position and attitude error of its runs, µm / mdeg.
    pub pose: [Summary; 2],
}

/// Table VI over the rows: per controller, in the order first seen.
pub fn table_vi(rows: &[PolishRow]) -> Vec<TableViRow> {
    let names = controllers(rows);
    let last = rows.iter().map(|r| r.iteration).max().unwrap_or(0);
    let summary = |v: &[f64]| {
        Summary::of(v).unwrap_or(Summary {
            mean: f64::NAN,
            sd: f64::NAN,
            max: f64::NAN,
            count: 0,
        })
    };
    names
        .into_iter()
        .map(|name| {
            let mine: Vec<&PolishRow> = rows.iter().filter(|r| r.controller == name).collect();
            let seeds: Vec<u64> = {
                let mut s: Vec<u64> = mine.iter().map(|r| r.surface_seed).collect();
                s.dedup();
                s
            };
            let (mut pv, mut rms, mut dpv, mut drms, mut minutes) =
                ([vec![], vec![]], [vec![], vec![]], vec![], vec![], vec![]);
            let (mut pos, mut att) = (vec![], vec![]);
            for seed in seeds {
                let of = |it: usize| {
                    mine.iter()
                        .find(|r| r.surface_seed == seed && r.iteration == it)
                };
                let (Some(a), Some(b)) = (of(0), of(last)) else {
                    continue;
                };
                pv[0].push(a.pv_nm);
                pv[1].push(b.pv_nm);
                rms[0].push(a.rms_nm);
                rms[1].push(b.rms_nm);
                dpv.push(100.0 * (a.pv_nm - b.pv_nm) / a.pv_nm);
                drms.push(100.0 * (a.rms_nm - b.rms_nm) / a.rms_nm);
                let runs: Vec<&&PolishRow> = mine
                    .iter()
                    .filter(|r| r.surface_seed == seed && r.iteration < last)
                    .collect();
                minutes.push(runs.iter().map(|r| r.minutes).sum());
                pos.extend(runs.iter().map(|r| r.position_um));
                att.extend(runs.iter().map(|r| r.attitude_mdeg));
            }
            TableViRow {
                controller: name.to_string(),
                pv: [summary(&pv[0]), summary(&pv[1])],
                rms: [summary(&rms[0]), summary(&rms[1])],
                pv_decrease: summary(&dpv),
                rms_decrease: summary(&drms),
                minutes: summary(&minutes),
                pose: [summary(&pos), summary(&att)],
            }
        })
        .collect()
}

/// The Markdown report of the study.
pub fn report(spec: &PolishSpec, polisher: &Polisher, result: &PolishResult) -> String {
    let s = &polisher.setup;
    let mut out = String::new();
    let _ = writeln!(out, "# The mirror: polishing under each controller\n");
    let _ = writeln!(
        out,
        "- {} iterations per surface, surface seeds {:?}, run seed {}, {} min warm-up before each iteration, a prediction every {} ticks",
        spec.iterations, spec.surface_seeds, spec.seed, spec.warm_up_minutes, spec.every
    );
    let _ = writeln!(
        out,
        "- {} path at its held-out placement (rotation {}°, margin {} mm), feeds {}–{} mm/s; a {} × {} map of {} mm pixels, the removal laid on {} and the dwell solved on {}; PV and RMS over the {} mm clear aperture, piston and tilt removed; interferometer noise {} nm per pixel",
        s.path.name(),
        s.params.rotation_deg,
        s.params.margin,
        s.feed_limits[0],
        s.feed_limits[1],
        polisher.grid.n,
        polisher.grid.n,
        s.pitch,
        polisher.removal_device(),
        polisher.solve_device(),
        s.clear_aperture,
        s.interferometer_noise
    );
    let p = &s.pad;
    let _ = writeln!(
        out,
        "- Pad: {} mm radius orbiting {} mm at {} rpm ({:.0} mm/s), backing {} N/mm³, Preston K = {:e} mm²/N\n",
        p.radius,
        p.orbit_radius,
        p.orbit_rpm,
        p.speed(),
        p.stiffness,
        p.preston
    );
    let _ = writeln!(
        out,
        "Mean ± SD over surface seeds. Decrease: (before − after) / before; the RMS decrease is the convergence ratio. Pose: the mean true pad error the glass sees in the polishing runs (none for the perfect machine; one part of the nominal's for the split rows). The paper (Table VI, section V): compensated PV 277 → 72 nm (−73.9 %), RMS 13.4 → 7.4 nm (−45.1 %); uncompensated PV 246 → 143 nm (−41.6 %), RMS 15.7 → 13.9 nm (−11.2 %).\n"
    );
    let _ = writeln!(
        out,
        "| Controller | PV before (nm) | PV after (nm) | PV decrease (%) | RMS before (nm) | RMS after (nm) | RMS decrease (%) | Minutes polished | Pose error (µm / mdeg) |"
    );
    let _ = writeln!(out, "|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    let ms = |s: &Summary, d: usize| format!("{:.*} ± {:.*}", d, s.mean, d, s.sd);
    for r in table_vi(&result.rows) {
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {} | {} | {} | {:.0} | {:.1} / {:.1} |",
            r.controller,
            ms(&r.pv[0], 1),
            ms(&r.pv[1], 1),
            ms(&r.pv_decrease, 1),
            ms(&r.rms[0], 2),
            ms(&r.rms[1], 2),
            ms(&r.rms_decrease, 1),
            r.minutes.mean,
            r.pose[0].mean,
            r.pose[1].mean
        );
    }
    let paired = paired_against(&result.rows, "calibrated");
    if !paired.is_empty() {
        let _ = writeln!(
            out,
            "\nPaired against the calibrated controller, surface by surface: the final RMS and PV less the calibrated controller's on the same surface (negative: better), mean ± SD over surfaces.\n"
        );
        let _ = writeln!(
            out,
            "| Controller | Surfaces | RMS after − calibrated (nm) | PV after − calibrated (nm) |"
        );
        let _ = writeln!(out, "|---|---:|---:|---:|");
        for (name, rms, pv) in paired {
            let _ = writeln!(
                out,
                "| {name} | {} | {} | {} |",
                rms.count,
                ms(&rms, 2),
                ms(&pv, 1)
            );
        }
    }
    out
}

/// Per controller other than `base`: the final RMS and PV less `base`'s on the same
/// surface, over the surfaces both finished.
pub fn paired_against(rows: &[PolishRow], base: &str) -> Vec<(String, Summary, Summary)> {
    let last = rows.iter().map(|r| r.iteration).max().unwrap_or(0);
    let finals: Vec<&PolishRow> = rows.iter().filter(|r| r.iteration == last).collect();
    controllers(rows)
        .into_iter()
        .filter(|&name| name != base)
        .filter_map(|name| {
            let (mut rms, mut pv) = (Vec::new(), Vec::new());
            for r in finals.iter().filter(|r| r.controller == name) {
                if let Some(b) = finals
                    .iter()
                    .find(|b| b.controller == base && b.surface_seed == r.surface_seed)
                {
                    rms.push(r.rms_nm - b.rms_nm);
                    pv.push(r.pv_nm - b.pv_nm);
                }
            }
            Some((name.to_string(), Summary::of(&rms)?, Summary::of(&pv)?))
        })
        .collect()
}

/// `rows` as the bytes of a CSV file with a header (`file` names it in an error).
pub(crate) fn csv_bytes<T: serde::Serialize>(rows: &[T], file: &str) -> Result<Vec<u8>> {
    let mut csv = csv::Writer::from_writer(Vec::new());
    for r in rows {
        csv.serialize(r)
            .map_err(|e| Error::Invalid(format!("{file}: {e}")))?;
    }
    csv.into_inner()
        .map_err(|e| Error::Invalid(format!("{file}: {e}")))
}

/// Writes `polish.csv`, `polish.md`, `convergence.png` (Fig. 13) and `maps.png` (Fig. 14)
/// into `dir`.
pub fn write(
    dir: &Path,
    spec: &PolishSpec,
    polisher: &Polisher,
    result: &PolishResult,
) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let bytes = csv_bytes(&result.rows, "polish.csv")?;
    let mut batch = crate::atomic::Batch::new();
    let add = |batch: &mut crate::atomic::Batch, name: &str, b: &[u8]| {
        let path = dir.join(name);
        batch.add(&path, b).map_err(|e| Error::io(&path, e))
    };
    add(&mut batch, "polish.csv", &bytes)?;
    add(
        &mut batch,
        "polish.md",
        report(spec, polisher, result).as_bytes(),
    )?;
    batch.commit().map_err(|e| Error::io(dir, e))?;
    // Fig. 13: mean over surface seeds per iteration.
    let names = controllers(&result.rows);
    let curve = |name: &str, f: &dyn Fn(&PolishRow) -> f64| {
        let mut pts = Vec::new();
        for it in 0..=spec.iterations {
            let v: Vec<f64> = result
                .rows
                .iter()
                .filter(|r| r.controller == name && r.iteration == it)
                .map(f)
                .collect();
            if let Some(s) = Summary::of(&v) {
                pts.push((it as f64, s.mean));
            }
        }
        Series::new(name, pts)
    };
    let panels = [
        Panel {
            title: "RMS over the clear aperture (mean over surfaces)".into(),
            x_label: "iteration".into(),
            y_label: "RMS (nm)".into(),
            series: names.iter().map(|n| curve(n, &|r| r.rms_nm)).collect(),
            integer_x: true,
            ..Panel::default()
        },
        Panel {
            title: "PV over the clear aperture (mean over surfaces)".into(),
            x_label: "iteration".into(),
            y_label: "PV (nm)".into(),
            series: names.iter().map(|n| curve(n, &|r| r.pv_nm)).collect(),
            integer_x: true,
            ..Panel::default()
        },
    ];
    plot::draw(&dir.join("convergence.png"), &panels, 1, 2, (1400, 560))?;
    // Fig. 14: one colour scale for every map, from the starting map's spread.
    if let Some((_, first)) = result.maps.first() {
        let finite: Vec<f64> = first
            .values
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .collect();
        let sd = Summary::of(&finite).map_or(1.0, |s| s.sd);
        let heat: Vec<HeatMap> = result
            .maps
            .iter()
            .map(|(name, m)| {
                let f = m.figure(&polisher.clear);
                HeatMap {
                    title: format!("{name}\nPV {:.0} nm, RMS {:.1} nm", f.pv, f.rms),
                    n: m.grid.n,
                    values: m.values.clone(),
                }
            })
            .collect();
        plot::heat_maps(&dir.join("maps.png"), &heat, 3, (-3.0 * sd, 3.0 * sd), "nm")?;
    }
    Ok(())
}
