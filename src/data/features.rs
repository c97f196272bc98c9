//! Per-node features of docs/model.md: the filtered signal r(n), its difference D(n) and the
//! differential entropy H(n) of eq. 20–22 — all causal, so the same code runs online.

/// Preprocessing settings.
#[derive(Clone, Copy, Debug)]
pub struct FeatureConfig {
    /// Cut-off of the causal first-order low-pass filter, Hz.
    pub cutoff_hz: f64,
    /// Trailing differences in the entropy of eq. 21–22 (w).
    pub entropy_window: usize,
}

impl Default for FeatureConfig {
    fn default() -> FeatureConfig {
        FeatureConfig {
            cutoff_hz: 5.0,
            entropy_window: 20,
        }
    }
}

/// Zero-order hold onto the control clock: an empty cell repeats the sensor's last sample
/// (causal). Cells before the sensor's first sample take that first sample (start-up
/// only: the one look ahead; [`Stream`] cannot do it and gives 0 there). `None` when the
/// sensor never reported.
pub fn hold(values: &[Option<f64>]) -> Option<Vec<f64>> {
    let first = values.iter().find_map(|v| *v)?;
    let mut last = first;
    Some(
        values
            .iter()
            .map(|v| {
                if let Some(v) = v {
                    last = *v;
                }
                last
            })
            .collect(),
    )
}

/// The smoothing gain a = dt / (τ + dt), τ = 1/(2π f_c), of [`low_pass`] and [`Stream`].
fn low_pass_gain(dt: f64, cutoff_hz: f64) -> f64 {
    let tau = 1.0 / (std::f64::consts::TAU * cutoff_hz);
    dt / (tau + dt)
}

/// Causal first-order low-pass (exponential smoothing) with cut-off `cutoff_hz` at sample
/// period `dt`: y(n) = y(n−1) + a (x(n) − y(n−1)), a = dt / (τ + dt), τ = 1/(2π f_c);
/// y(0) = x(0).
pub fn low_pass(x: &[f64], dt: f64, cutoff_hz: f64) -> Vec<f64> {
    let a = low_pass_gain(dt, cutoff_hz);
    let mut y = Vec::with_capacity(x.len());
    for (n, &v) in x.iter().enumerate() {
        let prev = if n == 0 { v } else { y[n - 1] };
        y.push(prev + a * (v - prev));
    }
    y
}

/// D(n) = r(n) − r(n−1), D(0) = 0 (causal form of eq. 20).
pub fn differences(r: &[f64]) -> Vec<f64> {
    (0..r.len())
        .map(|n| if n == 0 { 0.0 } else { r[n] - r[n - 1] })
        .collect()
}

/// H(n) of eq. 21–22 over the trailing `w` differences D(n−w+1..=n) (fewer at the
/// start), divided by log2(w) so a full window lies in [0, 1]; 0 when all |D| are 0.
pub fn entropy(d: &[f64], w: usize) -> Vec<f64> {
    let norm = (w as f64).log2();
    (0..d.len())
        .map(|n| window_entropy(&d[(n + 1).saturating_sub(w)..=n], norm))
        .collect()
}

/// The normalised entropy of one window of differences (shared by [`entropy`] and
/// [`Stream`], so both give the same bits).
fn window_entropy(window: &[f64], norm: f64) -> f64 {
    let total: f64 = window.iter().map(|v| v.abs()).sum();
    if total == 0.0 {
        return 0.0;
    }
    let h: f64 = window
        .iter()
        .map(|v| v.abs() / total)
        .filter(|&p| p > 0.0)
        .map(|p| -p * p.log2())
        .sum();
    h / norm
}

/// The three raw (not yet z-scored) feature series of one node: r, D, H.
pub fn node_features(samples: &[f64], dt: f64, config: &FeatureConfig) -> [Vec<f64>; 3] {
    let r = low_pass(samples, dt, config.cutoff_hz);
    let d = differences(&r);
    let h = entropy(&d, config.entropy_window);
    [r, d, h]
}

/// Features per node of [`Stream`]: r, D, H.
const STREAM_FEATURES: usize = 3;

/// Per-node causal feature state for online use: push one control tick of raw channel
/// values (`None` = no sample this tick) and get the F = 3 raw features [r, D, H] per node
/// — the same numbers, bit for bit, that [`node_features`] of [`hold`] gives on the whole
/// recording, from the tick of each node's first sample on.
///
/// Before a node's first sample the stream cannot know its value (batch [`hold`] back-fills
/// it from the future): its features are then 0 and its difference history holds zeros,
/// exactly the D = 0 that batch mode has there, so nothing of the start-up leaks into
/// later ticks. At the first sample the filter starts at that value (batch: y(0) = x(0)
/// on the back-filled series) and D = 0. Ticks count from the first [`Stream::push`], which
/// must be the recording's first row for the comparison with batch mode to hold (the
/// entropy window of the first w − 1 ticks is shorter, as in [`entropy`]).
#[derive(Clone, Debug)]
pub struct Stream {
    nodes: usize,
    /// Low-pass gain a.
    gain: f64,
    /// Entropy window w and its normaliser log2(w).
    window: usize,
    norm: f64,
    /// Per node: the last filtered value r(n−1).
    filtered: Vec<f64>,
    /// Per node: the last held raw sample, `None` before the first.
    held: Vec<Option<f64>>,
    /// Per node a run of `capacity` slots holding the last `len` differences, oldest
    /// first, so the entropy window is one contiguous slice; when full, the last w − 1
    /// move to the front (once every w + 1 ticks).
    differences: Vec<f64>,
    capacity: usize,
    len: usize,
}

impl Stream {
    /// A stream of `nodes` channels at control period `dt` (s). Use the `dt` that the batch
    /// path uses (`prepare` takes it from the first two rows' times) for bit-equal features.
    pub fn new(nodes: usize, dt: f64, config: &FeatureConfig) -> Stream {
        let window = config.entropy_window;
        let capacity = 2 * window.max(1);
        Stream {
            nodes,
            gain: low_pass_gain(dt, config.cutoff_hz),
            window,
            norm: (window as f64).log2(),
            filtered: vec![0.0; nodes],
            held: vec![None; nodes],
            differences: vec![0.0; nodes * capacity],
            capacity,
            len: 0,
        }
    }

    /// Pushes one tick: `values[n]` is node n's raw sample (`None`: no sample, the last
    /// one is held). Writes `out[n * 3 + f]` for f = r, D, H. Returns false while some node
    /// has never had a sample (its features are then 0). Allocation-free.
    ///
    /// # Panics
    /// If `values` does not have one entry per node or `out` is shorter than 3 per node.
    pub fn push(&mut self, values: &[Option<f64>], out: &mut [f64]) -> bool {
        assert_eq!(values.len(), self.nodes, "one value per node");
        assert!(
            out.len() >= self.nodes * STREAM_FEATURES,
            "3 features per node"
        );
        if self.len == self.capacity {
            let keep = self.window.saturating_sub(1);
            for n in 0..self.nodes {
                let run = &mut self.differences[n * self.capacity..(n + 1) * self.capacity];
                run.copy_within(self.capacity - keep.., 0);
            }
            self.len = keep;
        }
        let mut ready = true;
        for (n, value) in values.iter().enumerate() {
            if let Some(v) = value {
                if self.held[n].is_none() {
                    // The batch filter's y(0) = x(0), by the same operations.
                    self.filtered[n] = *v;
                }
                self.held[n] = Some(*v);
            }
            let (r, d) = match self.held[n] {
                Some(x) => {
                    let prev = self.filtered[n];
                    let r = prev + self.gain * (x - prev);
                    self.filtered[n] = r;
                    (r, r - prev)
                }
                None => {
                    ready = false;
                    (0.0, 0.0)
                }
            };
            let run = &mut self.differences[n * self.capacity..(n + 1) * self.capacity];
            run[self.len] = d;
            let h = if self.held[n].is_some() {
                window_entropy(
                    &run[(self.len + 1).saturating_sub(self.window)..=self.len],
                    self.norm,
                )
            } else {
                0.0
            };
            out[n * STREAM_FEATURES..(n + 1) * STREAM_FEATURES].copy_from_slice(&[r, d, h]);
        }
        self.len += 1;
        ready
    }
}
