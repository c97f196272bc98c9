//! The rule that keeps held-out runs unseen (docs/twin.md "Sessions"): no held-out
//! placement may follow a training placement of its own pattern for a window's length
//! (20 mm within 1 mm), nor another pattern's for three windows. `tests/twin_honest.rs`
//! checks every training placement against every held-out one with it, and
//! [`spread_placements`] chooses the spread placements by it.

use super::mirror::Mirror;
use super::trajectory::{Path, PathKind, PathParams};

/// Points every `step` mm along the whole path.
pub fn samples(path: &Path, step: f64) -> Vec<[f64; 2]> {
    let n = (path.length() / step).ceil() as usize;
    (0..=n).map(|i| path.at(i as f64 * step)).collect()
}

/// The longest stretch (in samples of `held`) along which `held` follows `trained` in
/// order: consecutive held-out samples within `tol` of training samples that are
/// themselves consecutive along the training path (either way), up to `reach` indices.
pub fn longest_retrace(held: &[[f64; 2]], trained: &[[f64; 2]], tol: f64, reach: usize) -> usize {
    let mut cells = std::collections::HashMap::<(i64, i64), Vec<usize>>::new();
    let key = |p: [f64; 2]| ((p[0] / tol).floor() as i64, (p[1] / tol).floor() as i64);
    for (j, p) in trained.iter().enumerate() {
        cells.entry(key(*p)).or_default().push(j);
    }
    let near = |p: [f64; 2]| -> Vec<usize> {
        let (cx, cy) = key(p);
        let mut out = Vec::new();
        for dx in -1..=1 {
            for dy in -1..=1 {
                for &j in cells.get(&(cx + dx, cy + dy)).map_or(&[][..], |v| &v[..]) {
                    let q = trained[j];
                    if (p[0] - q[0]).hypot(p[1] - q[1]) <= tol {
                        out.push(j);
                    }
                }
            }
        }
        out
    };
    let (mut longest, mut prev): (usize, Vec<(usize, usize)>) = (0, Vec::new());
    for p in held {
        let now: Vec<(usize, usize)> = near(*p)
            .into_iter()
            .map(|j| {
                let run = prev
                    .iter()
                    .filter(|(k, _)| j.abs_diff(*k) <= reach)
                    .map(|(_, r)| r + 1)
                    .max()
                    .unwrap_or(1);
                (j, run)
            })
            .collect();
        longest = longest.max(now.iter().map(|(_, r)| *r).max().unwrap_or(0));
        prev = now;
    }
    longest
}

/// The longest a held-out path may follow a training path, mm: a window (48 ticks at up
/// to 26 mm/s, under 25 mm; 20 taken) along its own pattern, three along another (where
/// a straight pass runs tangent to a curved one).
pub fn retrace_limit(trained: PathKind, held: PathKind) -> usize {
    let window_mm = 20;
    if trained == held {
        window_mm
    } else {
        3 * window_mm
    }
}

/// Every held-out placement of every pattern, sampled every 1 mm: what a training
/// placement is checked against.
pub struct HeldOutPlacements {
    placements: Vec<(PathKind, usize, Vec<[f64; 2]>)>,
}

impl HeldOutPlacements {
    /// The held-out placements of every pattern in every held-out session
    /// ([`PathParams::HELD_OUT_PLACEMENTS`] distinct ones) on `mirror`.
    pub fn new(mirror: &Mirror) -> HeldOutPlacements {
        let placements = PathKind::ALL
            .into_iter()
            .flat_map(|kind| (0..PathParams::HELD_OUT_PLACEMENTS).map(move |s| (kind, s)))
            .map(|(kind, s)| {
                let p = PathParams::held_out_in(kind, s);
                (kind, s, samples(&Path::generate(kind, mirror, &p), 1.0))
            })
            .collect();
        HeldOutPlacements { placements }
    }

    /// The held-out placements that a training run of `kind` at `params` retraces beyond
    /// the rule's limit, as `(held-out pattern, session, mm)`; empty when it keeps them
    /// unseen.
    pub fn retraced_by(
        &self,
        mirror: &Mirror,
        kind: PathKind,
        params: &PathParams,
    ) -> Vec<(PathKind, usize, usize)> {
        let trained = samples(&Path::generate(kind, mirror, params), 0.5);
        self.placements
            .iter()
            .filter_map(|(held_kind, session, held)| {
                let mm = longest_retrace(held, &trained, 1.0, 6);
                (mm >= retrace_limit(kind, *held_kind)).then_some((*held_kind, *session, mm))
            })
            .collect()
    }
}

/// The golden section, 1/φ: successive multiples of it, taken modulo 1, spread over
/// the interval with no two close together (each new one falls into the largest gap).
pub const GOLDEN_SECTION: f64 = 0.618_033_988_749_894_9;

/// Degrees after which the stroke directions of a pattern repeat: the Hilbert curve's
/// strokes run along its lattice (a quarter turn), the raster's passes along one line (a
/// half turn), the spirals' every way (a whole turn).
pub fn direction_period_deg(kind: PathKind) -> f64 {
    match kind {
        PathKind::Hilbert => 90.0,
        PathKind::Grid => 180.0,
        PathKind::Fermat | PathKind::Rosette => 360.0,
    }
}

/// The i-th candidate turn of `kind` for [`spread_placements`], whole degrees: i golden
/// sections of the pattern's direction period P (so the strokes' directions spread
/// evenly over P), plus i mod (360/P) periods (so the pattern also turns round the part).
pub fn spread_candidate_deg(kind: PathKind, i: usize) -> f64 {
    let period = direction_period_deg(kind);
    let copies = (360.0 / period).round() as usize;
    let within = (i as f64 * GOLDEN_SECTION).fract() * period;
    ((within + period * (i % copies) as f64).round()).rem_euclid(360.0)
}

/// The first `n` spread placements of `kind` by their rule (docs/twin.md "Sessions"):
/// candidate i is turned by [`spread_candidate_deg`], and every candidate that retraces a
/// held-out placement of any session is skipped; the k-th kept one is walked from its
/// other end when k is odd. The table behind [`PathParams::spread`] is this list;
/// `tests/twin_honest.rs` checks that they agree. Fewer than `n` only if 4096 candidates
/// leave fewer.
pub fn spread_placements(mirror: &Mirror, kind: PathKind, n: usize) -> Vec<PathParams> {
    let held = HeldOutPlacements::new(mirror);
    let mut kept = Vec::with_capacity(n);
    for i in 0..4096 {
        if kept.len() == n {
            break;
        }
        let params = PathParams {
            rotation_deg: spread_candidate_deg(kind, i),
            reverse: kept.len() % 2 == 1,
            ..PathParams::default()
        };
        if held.retraced_by(mirror, kind, &params).is_empty() {
            kept.push(params);
        }
    }
    kept
}
