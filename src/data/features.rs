//! Per-node features of MODEL.md: the filtered signal r(n), its difference D(n) and the
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
/// only). `None` when the sensor never reported.
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

/// Causal first-order low-pass (exponential smoothing) with cut-off `cutoff_hz` at sample
/// period `dt`: y(n) = y(n−1) + a (x(n) − y(n−1)), a = dt / (τ + dt), τ = 1/(2π f_c);
/// y(0) = x(0).
pub fn low_pass(x: &[f64], dt: f64, cutoff_hz: f64) -> Vec<f64> {
    let tau = 1.0 / (std::f64::consts::TAU * cutoff_hz);
    let a = dt / (tau + dt);
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
        .map(|n| {
            let window = &d[(n + 1).saturating_sub(w)..=n];
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
        })
        .collect()
}

/// The three raw (not yet z-scored) feature series of one node: r, D, H.
pub fn node_features(samples: &[f64], dt: f64, config: &FeatureConfig) -> [Vec<f64>; 3] {
    let r = low_pass(samples, dt, config.cutoff_hz);
    let d = differences(&r);
    let h = entropy(&d, config.entropy_window);
    [r, d, h]
}
