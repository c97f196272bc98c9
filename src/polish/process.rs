//! One polishing iteration on the twin: the interferometer measures the surface, the
//! dwell solver plans, the plan becomes the feed along the path, and the twin's
//! controller walks it while the pad removes glass at its pose every control tick
//! (docs/polishing.md "Polishing").

use std::sync::Arc;

use nalgebra::{Isometry3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::dwell::{gaussian_average, Dwell, DwellSolver, PathRaster};
use super::map::{Grid, HeightMap};
use super::tif::Pad;
use crate::compensate::online::{self, Feedback, RunResult};
use crate::error::{ensure, Error, Result};
use crate::gpu::{Device, Gpu};
use crate::ops::removal::{Accumulator, Tick};
use crate::robot::Robot;
use crate::twin::{
    gaussian, FeedPlan, Machine, MachineState, Mirror, Path, PathKind, PathParams, Sample,
    SimConfig, DEFAULT_FEED, DEFAULT_FORCE,
};

/// The polishing set-up: pad, map, path, machine limits and interferometer.
#[derive(Clone, Debug)]
pub struct Setup {
    /// The pad and its removal constants.
    pub pad: Pad,
    /// Map pixel side, mm.
    pub pitch: f64,
    /// The path the pad walks, and its placement on the part.
    pub path: PathKind,
    /// The placement.
    pub params: PathParams,
    /// The machine's feed limits, mm/s.
    pub feed_limits: [f64; 2],
    /// Diameter over which PV and RMS are judged, mm (within the glass).
    pub clear_aperture: f64,
    /// The interferometer's noise per pixel, nm RMS.
    pub interferometer_noise: f64,
}

impl Setup {
    /// The defaults of docs/polishing.md on `path` at its held-out placement (off every
    /// training lattice) but 5 mm from the rim: a 2 mm map, feeds 5–80 mm/s, a 480 mm
    /// clear aperture (the outer 15 mm left out), 0.5 nm interferometer noise.
    pub fn new(path: PathKind) -> Setup {
        Setup {
            pad: Pad::default(),
            pitch: 2.0,
            path,
            params: PathParams {
                margin: 5.0,
                ..PathParams::held_out(path)
            },
            feed_limits: [5.0, 80.0],
            clear_aperture: CLEAR_APERTURE,
            interferometer_noise: 0.5,
        }
    }
}

/// The default clear aperture's diameter, mm: the mirror's 510 less its outer 15 mm,
/// where the raster turns and the pad overhangs the rim (docs/polishing.md "The surface").
pub const CLEAR_APERTURE: f64 = 480.0;

/// The pneumatic forces a plan may choose, N.
pub const FORCE_RANGE: [f64; 2] = [30.0, 150.0];

/// How the pad's pose is taken during a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PoseSource {
    /// The machine's true pose: what the glass sees.
    True,
    /// The path's target pose: a perfect machine (the solver's and the force's floor).
    Target,
    /// The true position with the target's attitude: what the position error alone
    /// (across and along the path, so the feed's error too) does to the glass.
    PositionOnly,
    /// The target position with the true attitude: what the tilt alone does.
    AttitudeOnly,
}

/// The grid, masks, path and solver of one set-up on the twin's mirror.
pub struct Polisher {
    /// The set-up.
    pub setup: Setup,
    /// The mirror.
    pub mirror: Mirror,
    /// The map's grid.
    pub grid: Grid,
    /// Pixels of glass.
    pub glass: Vec<bool>,
    /// Pixels of the clear aperture.
    pub clear: Vec<bool>,
    path: Path,
    /// Arc length at the start of each segment of the path, mm.
    arc: Vec<f64>,
    /// The segments on the map.
    raster: PathRaster,
    /// Per segment: the least and most seconds on it (its length over the fastest and
    /// the slowest feed).
    bounds: Vec<[f64; 2]>,
    /// Per segment: the area it stands for, mm² (its length over the path's local length
    /// per unit area).
    area: Vec<f64>,
    solver: DwellSolver,
    /// The adapter whose WGSL kernel lays the removal (`None`: the native f64 path).
    removal_gpu: Option<Arc<Gpu>>,
}

/// What [`Polisher::removal_device`] and [`Polisher::solve_device`] say: the adapter
/// `gpu` names, or the CPU path.
fn described(gpu: Option<&str>) -> String {
    gpu.map_or_else(
        || "native CPU (f64)".to_string(),
        |name| format!("{name} (WGSL, f32)"),
    )
}

/// Control ticks laid per dispatch of the removal kernel.
const REMOVAL_BATCH: usize = 4096;

impl Polisher {
    /// Prepares `setup` on the twin's mirror.
    pub fn new(setup: Setup) -> Result<Polisher> {
        let mirror = Mirror::default();
        let [lo, hi] = setup.feed_limits;
        ensure(lo > 0.0 && hi > lo && hi.is_finite(), || {
            format!("feed limits must satisfy 0 < least < most, got {lo}–{hi} mm/s")
        })?;
        ensure(
            setup.clear_aperture > 0.0 && setup.clear_aperture <= mirror.diameter,
            || {
                format!(
                    "the clear aperture must be within the mirror's {} mm, got {} mm",
                    mirror.diameter, setup.clear_aperture
                )
            },
        )?;
        ensure(setup.interferometer_noise >= 0.0, || {
            format!(
                "interferometer noise must be ≥ 0 nm, got {}",
                setup.interferometer_noise
            )
        })?;
        let pad = setup.pad;
        for (field, value) in [
            ("radius", pad.radius),
            ("orbit_radius", pad.orbit_radius),
            ("orbit_rpm", pad.orbit_rpm),
            ("preston", pad.preston),
        ] {
            ensure(value.is_finite() && value > 0.0, || {
                format!("the pad's {field} must be a positive number, got {value}")
            })?;
        }
        ensure(pad.stiffness.is_finite() && pad.stiffness >= 0.0, || {
            format!(
                "the pad's stiffness must be ≥ 0 N/mm³, got {}",
                pad.stiffness
            )
        })?;
        ensure(pad.orbit_radius < pad.radius, || {
            format!(
                "the pad's orbit_radius ({} mm) must be less than its radius ({} mm): the pad covers its orbit's centre",
                pad.orbit_radius, pad.radius
            )
        })?;
        ensure(4.0 * pad.reach() < mirror.diameter, || {
            format!(
                "the pad reaches {} mm from its orbit's centre (radius + orbit_radius): more than a quarter of the mirror's {} mm",
                pad.reach(),
                mirror.diameter
            )
        })?;
        let grid = Grid::covering(mirror.radius() + pad.reach(), setup.pitch)?;
        let glass = grid.disc(mirror.radius());
        let clear = grid.disc(0.5 * setup.clear_aperture);
        let path = Path::generate(setup.path, &mirror, &setup.params);
        let usable = mirror.radius() - setup.params.margin;
        let (covered, region) = match setup.path {
            // The Hilbert curve fills the square inscribed in the usable disc.
            PathKind::Hilbert => {
                let half = usable * std::f64::consts::FRAC_1_SQRT_2;
                let mut region = Vec::with_capacity(grid.len());
                let (s, c) = setup.params.rotation_deg.to_radians().sin_cos();
                for r in 0..grid.n {
                    for col in 0..grid.n {
                        let [x, y] = grid.centre(r, col);
                        let (u, v) = (c * x + s * y, -s * x + c * y);
                        region.push(u.abs() <= half && v.abs() <= half);
                    }
                }
                (4.0 * half * half, region)
            }
            _ => (
                std::f64::consts::PI * usable * usable,
                grid.disc(usable + 0.5 * grid.pitch),
            ),
        };
        let spacing = covered / path.length();
        // The path's vertices, repeats dropped.
        let (mut arc, mut points) = (Vec::new(), Vec::new());
        for (p, &s) in path.points().iter().zip(path.arc()) {
            if arc.last().is_none_or(|&last| s > last) {
                arc.push(s);
                points.push(*p);
            }
        }
        ensure(points.len() >= 2, || {
            format!(
                "the {} path has no length on this mirror",
                setup.path.name()
            )
        })?;
        let raster = PathRaster::new(grid, &points);
        arc.pop();
        // The path's length per unit area around each pixel: a Gaussian average over
        // 0.75 of the spacing, wide enough that the passes leave no ripple in it.
        let laid = raster.dwell_map(&raster.lengths);
        let rho = gaussian_average(grid.n, &laid, &region, 0.75 * spacing / grid.pitch);
        let rho_along = raster.sample(&rho);
        let area = raster
            .lengths
            .iter()
            .zip(&rho_along)
            .map(|(l, r)| if *r > 0.0 { l / r } else { l * spacing })
            .collect();
        let bounds = raster.lengths.iter().map(|l| [l / hi, l / lo]).collect();
        let (kernel, reach) = pad.kernel(grid, DEFAULT_FORCE);
        // A dwell point's gain at the rim: the orbit's mean pressure at the pad's centre
        // over what it would be clear of the rim.
        let footprint = pad.footprint(mirror.radius());
        let gain = (0..grid.len())
            .map(|i| {
                let tick = Tick {
                    centre: grid.centre(i / grid.n, i % grid.n),
                    force: 1.0,
                    ..Tick::default()
                };
                footprint.orbit_pressure(&tick) * pad.area()
            })
            .collect();
        let solver = DwellSolver::new(
            grid.n,
            &kernel,
            reach,
            glass.clone(),
            clear.clone(),
            gain,
            spacing / grid.pitch,
            DEFAULT_FORCE,
        )?;
        Ok(Polisher {
            setup,
            mirror,
            grid,
            glass,
            clear,
            path,
            arc,
            raster,
            bounds,
            area,
            solver,
            removal_gpu: None,
        })
    }

    /// A polisher of its own for the same set-up on the same adapters (the dwell solver's
    /// scratch is its own), so that another thread can plan while this one does.
    pub fn fork(&self) -> Result<Polisher> {
        Ok(Polisher {
            setup: self.setup.clone(),
            mirror: self.mirror,
            grid: self.grid,
            glass: self.glass.clone(),
            clear: self.clear.clone(),
            path: self.path.clone(),
            arc: self.arc.clone(),
            raster: self.raster.clone(),
            bounds: self.bounds.clone(),
            area: self.area.clone(),
            solver: self.solver.fork()?,
            removal_gpu: self.removal_gpu.clone(),
        })
    }

    /// Whether every heavy part runs on the native CPU path (none on an adapter).
    pub fn all_native(&self) -> bool {
        self.removal_gpu.is_none() && self.solver.gpu().is_none()
    }

    /// Runs the heavy parts where `device` does them best: the removal of every tick
    /// (`ops::removal`) and the dwell solve's FFTs (`ops::fft`) as WGSL kernels, in f32,
    /// on a GPU; on the native f64 path on a CPU adapter or without one (the default, bit
    /// for bit the reference).
    pub fn run_on(&mut self, device: &Device) -> Result<()> {
        let gpu = match device {
            Device::Adapter(gpu) if !device.prefers_native() => Some(gpu.clone()),
            _ => None,
        };
        self.remove_with_kernel(gpu.clone());
        self.solve_with_kernels(gpu)
    }

    /// Solves the dwell with the FFTs of `ops::fft` on `gpu` (any adapter, a CPU one too),
    /// or on the CPU (rustfft, f64) with `None`.
    pub fn solve_with_kernels(&mut self, gpu: Option<Arc<Gpu>>) -> Result<()> {
        self.solver.run_on(gpu)
    }

    /// Where the dwell is solved: the adapter's name, or `native CPU (f64)`.
    pub fn solve_device(&self) -> String {
        described(self.solver.gpu().map(|g| g.info().name.as_str()))
    }

    /// Lays the removal with the WGSL kernel on `gpu` (any adapter, a CPU one too), or
    /// on the native path with `None`.
    pub fn remove_with_kernel(&mut self, gpu: Option<Arc<Gpu>>) {
        self.removal_gpu = gpu;
    }

    /// Where the removal is laid: the adapter's name, or `native CPU (f64)`.
    pub fn removal_device(&self) -> String {
        described(self.removal_gpu.as_ref().map(|g| g.info().name.as_str()))
    }

    /// What the interferometer reports of `surface`: the heights plus its noise (seeded
    /// by `seed`), piston and tilt removed over the clear aperture, zero off the glass.
    pub fn measure(&self, surface: &HeightMap, seed: u64) -> HeightMap {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5a59_474f);
        let mut out = surface.clone();
        for (v, &g) in out.values.iter_mut().zip(&self.glass) {
            *v = if g {
                *v + gaussian(&mut rng, self.setup.interferometer_noise)
            } else {
                0.0
            };
        }
        out.remove_plane(&self.clear);
        for (v, &g) in out.values.iter_mut().zip(&self.glass) {
            if !g {
                *v = 0.0;
            }
        }
        out
    }

    /// The dwell along the path for a measured surface.
    ///
    /// The pneumatic force is chosen with it, as an optician lightens the pressure for
    /// fine iterations: planned at the nominal 100 N first, then at the force that puts
    /// the median feed at the twin's mean feed (20 mm/s), within 30–150 N. The removal
    /// per pass then shrinks with the error, and with it the least layer the fastest feed
    /// still removes, whose own unevenness (the passes' ripple, the force's error) would
    /// otherwise stop the convergence; and the machine runs at the feeds it was trained
    /// at.
    pub fn plan(&mut self, measured: &HeightMap) -> Result<Dwell> {
        let first = self.plan_at(measured, DEFAULT_FORCE)?;
        let mut feeds = self.segment_feeds(&first.seconds);
        feeds.sort_by(f64::total_cmp);
        let median = feeds.get(feeds.len() / 2).copied().unwrap_or(DEFAULT_FEED);
        let force = (DEFAULT_FORCE * DEFAULT_FEED / median).clamp(FORCE_RANGE[0], FORCE_RANGE[1]);
        self.plan_at(measured, force)
    }

    /// The dwell for `measured` with the pad pressed by `force` N: the removal scales
    /// with the force, so the solver's seconds at the nominal force are `force / 100 N`
    /// times the seconds at `force`, within bounds scaled alike.
    pub fn plan_at(&mut self, measured: &HeightMap, force: f64) -> Result<Dwell> {
        let scale = force / DEFAULT_FORCE;
        let bounds: Vec<[f64; 2]> = self
            .bounds
            .iter()
            .map(|b| [b[0] * scale, b[1] * scale])
            .collect();
        let mut dwell = self
            .solver
            .solve(measured, &self.raster, &bounds, &self.area)?;
        for t in dwell.seconds.iter_mut() {
            *t /= scale;
        }
        dwell.force = force;
        Ok(dwell)
    }

    /// The dwell for `measured` at the nominal force (as [`Polisher::plan_at`] with 100 N),
    /// with the problem and the solution written to the safetensors file `out` for an
    /// implementation outside the engine to check against ([`DwellSolver::write_problem`]).
    pub fn write_dwell_problem(
        &mut self,
        measured: &HeightMap,
        out: &std::path::Path,
    ) -> Result<Dwell> {
        let dwell = self
            .solver
            .solve(measured, &self.raster, &self.bounds, &self.area)?;
        let problem = (&self.bounds[..], &self.area[..]);
        self.solver
            .write_problem(out, measured, &self.raster, problem, &dwell)?;
        Ok(dwell)
    }

    /// Each raster segment's feed, mm/s: its length over its `seconds`.
    fn segment_feeds(&self, seconds: &[f64]) -> Vec<f64> {
        self.raster
            .lengths
            .iter()
            .zip(seconds)
            .map(|(l, t)| l / t)
            .collect()
    }

    /// The feed that realises `dwell`: each segment's length over its seconds, scaled
    /// during the run by the force reading over the planned force (force × dwell is the
    /// removal).
    pub fn feed(&self, dwell: &Dwell) -> Result<FeedPlan> {
        let feed = self.segment_feeds(&dwell.seconds);
        let mut plan = FeedPlan::new(self.arc.clone(), feed).map_err(Error::Invalid)?;
        plan.force_reference = Some(dwell.force);
        plan.walk_once = true;
        Ok(plan)
    }

    /// The length of the path, mm.
    pub fn path_length(&self) -> f64 {
        self.path.length()
    }

    /// The path the pad walks.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Walks the path once along `plan` on `machine` from `start`, driven by `controller`
    /// corrected by `feedback`, with the run's seed `seed`; removes glass from `surface`
    /// at every tick at the pad's pose (`pose`) with the tick's contact force. `on_tick`
    /// sees the progress.
    #[allow(clippy::too_many_arguments)]
    pub fn polish(
        &self,
        machine: &Machine,
        controller: &Robot,
        start: MachineState,
        feedback: Feedback<'_>,
        plan: FeedPlan,
        seed: u64,
        pose: PoseSource,
        surface: &mut HeightMap,
        mut on_tick: impl FnMut(usize),
    ) -> Result<RunResult> {
        // The feed follows the force within a factor of two: the walk ends with the path,
        // within twice its planned time.
        let seconds = 2.0 * plan.duration(self.path.length());
        let mut config = SimConfig::new(self.setup.path, seconds, seed);
        config.path_params = self.setup.params;
        // The pneumatic set-point of the plan; its wander scales with it (a regulator's
        // error is a share of its pressure).
        if let Some(force) = plan.force_reference {
            config.force_sd *= force / config.force_mean;
            config.force_mean = force;
        }
        config.feed_plan = Some(Arc::new(plan));
        let dt = config.dt;
        let mut ticks = 0;
        let mut kernel = match &self.removal_gpu {
            Some(gpu) => Some(Accumulator::new(
                gpu,
                self.grid.n,
                self.grid.pitch,
                &self.glass,
                self.setup.pad.footprint(self.mirror.radius()),
                REMOVAL_BATCH,
            )?),
            None => None,
        };
        let (footprint, mut failed) = (self.setup.pad.footprint(self.mirror.radius()), None);
        let run = online::run_observed(
            machine,
            controller,
            config,
            start,
            feedback,
            |s: &Sample, actual: &Isometry3<f64>| {
                let tick = self.tick(s, actual, pose, dt);
                match &mut kernel {
                    None => footprint.remove_tick(
                        self.grid.n,
                        self.grid.pitch,
                        &self.glass,
                        &tick,
                        &mut surface.values,
                    ),
                    Some(k) if failed.is_none() => failed = k.push(&tick).err(),
                    Some(_) => {}
                }
                ticks += 1;
                on_tick(ticks);
            },
        )?;
        if let Some(e) = failed {
            return Err(e.into());
        }
        if let Some(k) = &mut kernel {
            k.finish(&mut surface.values)?;
        }
        Ok(run)
    }

    /// One tick's removal: the pad's centre and contact at the pose `pose` takes.
    fn tick(&self, s: &Sample, actual: &Isometry3<f64>, pose: PoseSource, dt: f64) -> Tick {
        let target = &s.hidden.target;
        let (true_centre, true_axis) = (actual.translation.vector, actual.rotation * Vector3::z());
        let (centre, axis) = match pose {
            PoseSource::True => (true_centre, true_axis),
            PoseSource::Target => (target.position, target.axis.normalize()),
            PoseSource::PositionOnly => (true_centre, target.axis.normalize()),
            PoseSource::AttitudeOnly => (target.position, true_axis),
        };
        // The glass's normal where the pad really is; the face's tilt against it.
        let normal = self.mirror.target(centre.x, centre.y).axis;
        let across = axis - normal * axis.dot(&normal);
        let contact = self.setup.pad.contact([across.x, across.y], s.hidden.force);
        self.setup.pad.tick([centre.x, centre.y], &contact, dt)
    }
}
