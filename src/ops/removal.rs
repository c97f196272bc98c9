//! The glass an orbital polishing pad removes at each control tick (docs/polishing.md
//! "Tool influence function", "Compute"): the closed-form removal rate and one tick's
//! removal in f64, which are both the reference and the native path
//! (`polish::Pad::rate` and `Pad::remove` call them), and the WGSL kernel
//! (`shaders/removal.wgsl`) that lays a batch of ticks over the map on a GPU,
//! [`Accumulator`].
//!
//! The map is square, `n` pixels of side `pitch` mm a side, centred on the mirror's
//! axis: pixel `(row, col)` has its centre at `((col + ½ − n/2)·pitch,
//! (row + ½ − n/2)·pitch)` (`polish::Grid`).

use crate::gpu::{
    Binding, DType, Dispatch, Gpu, GpuError, Kernel, Readback, Recorder, Shader, Tensor,
};

/// The WGSL module of this family (`shaders/removal.wgsl`: `removal_accumulate`).
pub static SHADER: Shader = Shader {
    name: "removal",
    source: include_str!("../../shaders/removal.wgsl"),
    base: None,
};

static ACCUMULATE: Kernel = Kernel {
    shader: &SHADER,
    entry: "removal_accumulate",
    bindings: &[
        Binding::read(1),
        Binding::read(2),
        Binding::read(3),
        Binding::read(4),
        Binding::read_write(5),
    ],
};

/// Pixels per side of the kernel's tiles (its workgroup is one tile).
pub const TILE: usize = 16;

/// The pad as the removal sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Footprint {
    /// Pad radius R, mm.
    pub radius: f64,
    /// Orbit radius e, mm.
    pub orbit: f64,
    /// Preston's coefficient K, mm²/N.
    pub preston: f64,
    /// The sliding speed of every point of the pad, mm/s.
    pub speed: f64,
    /// Radius of the glass, mm: a disc centred on the map's axis, larger than the pad
    /// (`f64::INFINITY`: no rim).
    pub glass: f64,
}

/// One control tick: where the orbit's centre is, how hard the pad is pressed, how its
/// pressure leans, and how long it stays.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Tick {
    /// The orbit's centre, mm (the map's plane).
    pub centre: [f64; 2],
    /// The contact force, N.
    pub force: f64,
    /// The pressure's gradient across the pad in the map's plane, N/mm³ (`p(u) = p₀ −
    /// gradient·u` at offset `u` from the pad's centre).
    pub gradient: [f64; 2],
    /// Seconds.
    pub seconds: f64,
}

/// Phases of the orbit over which the pressure at the pad's centre is averaged when the
/// pad overhangs the rim somewhere on its orbit (the trapezoidal rule, exact for a
/// periodic function up to its 63rd harmonic).
pub const ORBIT_PHASES: usize = 64;

/// Gauss–Legendre's 16-point rule on [−1, 1], its positive half: nodes and weights (the
/// arc of the orbit over which a pixel near the rim is under the pad).
pub const ARC_NODES: [[f64; 2]; 8] = [
    [0.095_012_509_837_637_44, 0.189_450_610_455_068_5],
    [0.281_603_550_779_258_9, 0.182_603_415_044_923_6],
    [0.458_016_777_657_227_4, 0.169_156_519_395_002_5],
    [0.617_876_244_402_643_7, 0.149_595_988_816_576_7],
    [0.755_404_408_355_003, 0.124_628_971_255_533_9],
    [0.865_631_202_387_831_7, 0.095_158_511_682_492_78],
    [0.944_575_023_073_232_6, 0.062_253_523_938_647_89],
    [0.989_400_934_991_649_9, 0.027_152_459_411_754_09],
];

/// The part of a disc of radius `a` centred at `p` that lies on a disc of glass of
/// radius `big` > `a` centred at the origin: its area (mm²) and its first moment about
/// the small disc's centre (mm³, a vector in the plane). In closed form: the part is a
/// segment of the small disc beyond the common chord plus a segment of the glass inside
/// it, and the two segments' moments about the chord cancel, leaving `d·A_glass` towards
/// the origin (`d = |p|`, `A_glass` the glass's segment).
pub fn on_glass(a: f64, p: [f64; 2], big: f64) -> (f64, [f64; 2]) {
    use std::f64::consts::PI;
    let d = p[0].hypot(p[1]);
    if d + a <= big {
        (PI * a * a, [0.0, 0.0])
    } else if d >= a + big {
        (0.0, [0.0, 0.0])
    } else {
        // The chord's distance from the small disc's centre, towards the origin, and
        // from the origin, outwards; its half-length.
        let h = ((d - big) * (d + big) + a * a) / (2.0 * d);
        let hg = d - h;
        let w = (a * a - h * h).max(0.0).sqrt();
        let small = a * a * (h / a).clamp(-1.0, 1.0).acos() - h * w;
        // The glass's segment, `big²·(x − sin x)/2` with `x` the angle the chord
        // subtends at the origin: in a form that keeps its digits when the segment is a
        // sliver of a large disc (the WGSL kernel's, in f32).
        let glass = 0.5 * big * big * chord_segment(2.0 * w.atan2(hg));
        // The moment d·A_glass along −p/d.
        (small + glass, [-p[0] * glass, -p[1] * glass])
    }
}

/// `x − sin x` for `x` in [0, 2π], by its series where the difference would lose its
/// digits (`x < 1`).
pub fn chord_segment(x: f64) -> f64 {
    if x < 1.0 {
        let x2 = x * x;
        // x³/3! − x⁵/5! + x⁷/7! − x⁹/9! + x¹¹/11!: the next term is under 2e-10 of it.
        x * x2 / 6.0
            * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0 * (1.0 - x2 / 72.0 * (1.0 - x2 / 110.0))))
    } else {
        x - x.sin()
    }
}

impl Footprint {
    /// How far from the orbit's centre the pad reaches, mm.
    pub fn reach(&self) -> f64 {
        self.radius + self.orbit
    }

    /// Whether the pad hangs over the rim somewhere on the orbit centred at `centre`.
    pub fn touches_rim(&self, centre: [f64; 2]) -> bool {
        centre[0].hypot(centre[1]) + self.reach() > self.glass
    }

    /// The pressure at the pad's centre, N/mm², when that centre is at `p`: the force
    /// balanced over the part of the pad on the glass, `p₀ = (F + g·S)/A` (A its area, S
    /// its first moment about the pad's centre; a pad square to the glass and clear of
    /// the rim: F/(πR²)). The area is taken as at least a quarter of the pad's (the paths
    /// keep a margin).
    #[inline]
    pub fn centre_pressure(&self, tick: &Tick, p: [f64; 2]) -> f64 {
        let (area, s) = on_glass(self.radius, p, self.glass);
        let floor = 0.25 * std::f64::consts::PI * self.radius * self.radius;
        let g = tick.gradient;
        (tick.force.max(0.0) + g[0] * s[0] + g[1] * s[1]) / area.max(floor)
    }

    /// The pressure at the pad's centre at phase `phi` of `tick`'s orbit.
    #[inline]
    fn phase_pressure(&self, tick: &Tick, phi: f64) -> f64 {
        let (s, c) = phi.sin_cos();
        let [x, y] = tick.centre;
        self.centre_pressure(tick, [x + self.orbit * c, y + self.orbit * s])
    }

    /// The pressure at the pad's centre averaged over `tick`'s orbit, N/mm² (what a point
    /// under the pad for the whole orbit sees, with the gradient's part, which averages
    /// out): F/(πR²) clear of the rim, the mean over [`ORBIT_PHASES`] phases where the
    /// pad overhangs it.
    pub fn orbit_pressure(&self, tick: &Tick) -> f64 {
        if !self.touches_rim(tick.centre) {
            return tick.force.max(0.0) / (std::f64::consts::PI * self.radius * self.radius);
        }
        let sum: f64 = (0..ORBIT_PHASES)
            .map(|j| {
                let phi = std::f64::consts::TAU * j as f64 / ORBIT_PHASES as f64;
                self.phase_pressure(tick, phi)
            })
            .sum();
        sum / ORBIT_PHASES as f64
    }

    /// The removal rate, nm/s, at offset `(dx, dy)` mm from `tick`'s orbit centre, with
    /// `orbit_pressure` its [`Footprint::orbit_pressure`]: Preston's law averaged over the
    /// orbit. A point at offset `d` is under the pad over the arc of phases within β of
    /// its own direction, `cos β = (|d|² + e² − R²)/(2·|d|·e)` (docs/polishing.md); the
    /// pressure at the pad's centre `p₀(φ)` is constant clear of the rim, giving the
    /// closed form `K·V·[p₀·β − (g·d)·(β − e·sin β / |d|)]/π`, and near the rim
    /// `p₀·β` becomes `½∫ p₀(φ) dφ` over the arc (Gauss–Legendre, [`ARC_NODES`]).
    #[inline]
    pub fn rate(&self, tick: &Tick, orbit_pressure: f64, dx: f64, dy: f64) -> f64 {
        use std::f64::consts::PI;
        let (big, e) = (self.radius, self.orbit);
        let r = dx.hypot(dy);
        let beta = if r <= big - e {
            PI
        } else if r >= big + e {
            return 0.0;
        } else {
            ((r * r + e * e - big * big) / (2.0 * r * e))
                .clamp(-1.0, 1.0)
                .acos()
        };
        let arc = if beta == PI || !self.touches_rim(tick.centre) {
            orbit_pressure * beta
        } else {
            let theta = dy.atan2(dx);
            let sum: f64 = ARC_NODES
                .iter()
                .map(|[x, w]| {
                    w * (self.phase_pressure(tick, theta + beta * x)
                        + self.phase_pressure(tick, theta - beta * x))
                })
                .sum();
            0.5 * beta * sum
        };
        // ∫ u dφ over the arc in contact is 2·d·(β − e·sin β / |d|); at |d| = 0 the arc
        // is the whole orbit and the integral vanishes.
        let lever = if r > 0.0 {
            beta - e * beta.sin() / r
        } else {
            0.0
        };
        let g = tick.gradient;
        let g_dot_d = g[0] * dx + g[1] * dy;
        let pressure = (arc - g_dot_d * lever) / PI;
        // mm/s → nm/s.
        self.preston * self.speed * pressure.max(0.0) * 1e6
    }

    /// The pixels a tick centred at `[x, y]` mm can reach on an `n`-pixel map of side
    /// `pitch`: inclusive row and column ranges, or `None` off the map.
    fn pixel_box(&self, n: usize, pitch: f64, [x, y]: [f64; 2]) -> Option<[usize; 4]> {
        // The centre's fractional column and row (pixel centres at whole numbers).
        let half = 0.5 * n as f64;
        let (fc, fr) = (x / pitch + half - 0.5, y / pitch + half - 0.5);
        let span = self.reach() / pitch;
        let lo = |f: f64| ((f - span).floor().max(0.0)) as usize;
        let hi = |f: f64| (((f + span).ceil()).max(-1.0) as isize).min(n as isize - 1);
        let (r1, c1) = (hi(fr), hi(fc));
        if r1 < 0 || c1 < 0 {
            return None;
        }
        Some([lo(fr), r1 as usize, lo(fc), c1 as usize])
    }

    /// Removes `tick`'s glass from `map` (`n × n` heights, nm, pixel side `pitch` mm) on
    /// the pixels `glass` marks: the reference, and the native path.
    pub fn remove_tick(&self, n: usize, pitch: f64, glass: &[bool], tick: &Tick, map: &mut [f64]) {
        let half = 0.5 * n as f64;
        let [x, y] = tick.centre;
        let Some([r0, r1, c0, c1]) = self.pixel_box(n, pitch, tick.centre) else {
            return;
        };
        let mean = self.orbit_pressure(tick);
        for r in r0..=r1 {
            for c in c0..=c1 {
                let i = r * n + c;
                if !glass[i] {
                    continue;
                }
                let px = (c as f64 + 0.5 - half) * pitch;
                let py = (r as f64 + 0.5 - half) * pitch;
                map[i] -= tick.seconds * self.rate(tick, mean, px - x, py - y);
            }
        }
    }
}

crate::gpu::uniform! {
    pub(crate) struct Params = RemovalParams in SHADER {
        n: u32,
        tiles: u32,
        pitch: f32,
        radius: f32,
        orbit: f32,
        scale: f32,
        glass: f32,
        pad0: u32,
    }
}

/// Lays control ticks' removal over a map on a GPU: ticks are gathered on the host,
/// binned to the kernel's tiles in tick order and laid down a batch at a time (no
/// readback until [`Accumulator::finish`]); the removed depth stays on the device in f32.
pub struct Accumulator<'g> {
    gpu: &'g Gpu,
    n: usize,
    pitch: f64,
    footprint: Footprint,
    tiles: usize,
    /// Ticks per batch.
    capacity: usize,
    /// The batch so far: two vec4 per tick.
    batch: Vec<[f32; 4]>,
    starts: Vec<u32>,
    lists: Vec<u32>,
    ticks: Tensor,
    tile_start: Tensor,
    tile_ticks: Tensor,
    removed: Tensor,
    dispatch: Dispatch,
    readback: Readback,
    host: Vec<f32>,
    /// Ticks laid since the last [`Accumulator::finish`].
    laid: usize,
}

impl<'g> Accumulator<'g> {
    /// An accumulator for an `n × n` map of pixel side `pitch` mm whose pixels of glass
    /// `glass` marks, for `footprint`, `capacity` ticks per batch.
    pub fn new(
        gpu: &'g Gpu,
        n: usize,
        pitch: f64,
        glass: &[bool],
        footprint: Footprint,
        capacity: usize,
    ) -> Result<Accumulator<'g>, GpuError> {
        if glass.len() != n * n || n == 0 || capacity == 0 {
            return Err(GpuError::Shape {
                tensor: "removal glass mask".into(),
                expected: format!(
                    "{} pixels (n = {n}) and a batch of at least one tick",
                    n * n
                ),
                got: format!("{} pixels, batch {capacity}", glass.len()),
            });
        }
        let tiles = n.div_ceil(TILE);
        // A tick's pixels span at most 2·span + 3 columns, so at most that over 16 tiles,
        // plus one where the span straddles a tile's edge.
        let span = (footprint.reach() / pitch).ceil() as usize;
        let per_side = ((2 * span + 3).div_ceil(TILE) + 1).min(tiles);
        let list_capacity = capacity * per_side * per_side;
        let mut words = vec![0u32; (n * n).div_ceil(32)];
        for (i, _) in glass.iter().enumerate().filter(|(_, g)| **g) {
            words[i >> 5] |= 1 << (i & 31);
        }
        let mask = gpu.zeros("removal glass", &[words.len()], DType::U32)?;
        gpu.write(&mask, &words)?;
        let ticks = gpu.zeros("removal ticks", &[2 * capacity, 4], DType::F32)?;
        let tile_start = gpu.zeros("removal tile starts", &[tiles * tiles + 1], DType::U32)?;
        let tile_ticks = gpu.zeros("removal tile ticks", &[list_capacity], DType::U32)?;
        let removed = gpu.zeros("removed", &[n * n], DType::F32)?;
        let params = Params {
            n: n as u32,
            tiles: tiles as u32,
            pitch: pitch as f32,
            radius: footprint.radius as f32,
            orbit: footprint.orbit as f32,
            scale: (footprint.preston * footprint.speed * 1e6) as f32,
            glass: footprint.glass.min(f64::from(f32::MAX)) as f32,
            pad0: 0,
        };
        let dispatch = gpu.dispatch(
            &ACCUMULATE,
            &[],
            &params,
            &[&ticks, &tile_start, &tile_ticks, &mask, &removed],
            [tiles as u32, tiles as u32, 1],
        )?;
        let readback = Readback::new(gpu, "removed", removed.byte_len())?;
        Ok(Accumulator {
            gpu,
            n,
            pitch,
            footprint,
            tiles,
            capacity,
            batch: Vec::with_capacity(2 * capacity),
            starts: vec![0; tiles * tiles + 1],
            lists: vec![0; list_capacity],
            ticks,
            tile_start,
            tile_ticks,
            removed,
            dispatch,
            readback,
            host: vec![0.0; n * n],
            laid: 0,
        })
    }

    /// Adds one tick; a full batch goes to the device.
    pub fn push(&mut self, tick: &Tick) -> Result<(), GpuError> {
        let t = tick;
        // The orbit's mean pressure is the host's (in f64, over the orbit's phases); the
        // kernel evaluates the pressure along an arc itself only where the pad overhangs
        // the rim.
        let rim = if self.footprint.touches_rim(t.centre) {
            1.0
        } else {
            0.0
        };
        self.batch.push([
            t.centre[0] as f32,
            t.centre[1] as f32,
            self.footprint.orbit_pressure(t) as f32,
            t.seconds as f32,
        ]);
        self.batch.push([
            t.gradient[0] as f32,
            t.gradient[1] as f32,
            t.force as f32,
            rim,
        ]);
        if self.batch.len() == 2 * self.capacity {
            self.flush()?;
        }
        Ok(())
    }

    /// The tiles each tick of the batch reaches, as one list per tile in tick order.
    fn bin(&mut self) -> usize {
        let (n, pitch, tiles) = (self.n, self.pitch, self.tiles);
        let boxes: Vec<Option<[usize; 4]>> = self
            .batch
            .chunks(2)
            .map(|t| {
                // The centre as the kernel sees it (f32).
                let centre = [f64::from(t[0][0]), f64::from(t[0][1])];
                self.footprint
                    .pixel_box(n, pitch, centre)
                    .map(|[r0, r1, c0, c1]| [r0 / TILE, r1 / TILE, c0 / TILE, c1 / TILE])
            })
            .collect();
        self.starts.iter_mut().for_each(|s| *s = 0);
        for [r0, r1, c0, c1] in boxes.iter().flatten() {
            for tr in *r0..=*r1 {
                for tc in *c0..=*c1 {
                    self.starts[tr * tiles + tc + 1] += 1;
                }
            }
        }
        for k in 1..self.starts.len() {
            self.starts[k] += self.starts[k - 1];
        }
        let mut next = self.starts.clone();
        for (t, b) in boxes.iter().enumerate() {
            if let Some([r0, r1, c0, c1]) = b {
                for tr in *r0..=*r1 {
                    for tc in *c0..=*c1 {
                        let slot = &mut next[tr * tiles + tc];
                        self.lists[*slot as usize] = t as u32;
                        *slot += 1;
                    }
                }
            }
        }
        self.starts[tiles * tiles] as usize
    }

    /// Sends the ticks gathered so far to the device and lays them (no wait).
    pub fn flush(&mut self) -> Result<(), GpuError> {
        if self.batch.is_empty() {
            return Ok(());
        }
        let used = self.bin();
        debug_assert!(used <= self.lists.len());
        let count = self.batch.len() / 2;
        self.batch.resize(2 * self.capacity, [0.0; 4]);
        self.gpu.write(&self.ticks, &self.batch)?;
        self.gpu.write(&self.tile_start, &self.starts)?;
        self.gpu.write(&self.tile_ticks, &self.lists)?;
        let mut rec = Recorder::new(self.gpu);
        rec.dispatch(&self.dispatch);
        rec.submit()?;
        self.batch.clear();
        self.laid += count;
        Ok(())
    }

    /// Lays what is left, subtracts everything laid since the last call from `map`
    /// (`n × n` heights, nm) and starts again from zero. Returns the ticks laid.
    pub fn finish(&mut self, map: &mut [f64]) -> Result<usize, GpuError> {
        if map.len() != self.n * self.n {
            return Err(GpuError::Shape {
                tensor: "removal map".into(),
                expected: format!("{} heights", self.n * self.n),
                got: format!("{}", map.len()),
            });
        }
        self.flush()?;
        let mut rec = Recorder::new(self.gpu);
        rec.read_into(&self.removed, &self.readback)?;
        rec.zero(&self.removed);
        rec.submit()?;
        self.readback.read_into(self.gpu, &mut self.host)?;
        for (m, r) in map.iter_mut().zip(&self.host) {
            *m -= f64::from(*r);
        }
        Ok(std::mem::take(&mut self.laid))
    }
}
