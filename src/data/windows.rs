//! Sliding windows and leakage-free splits.
//!
//! Contiguous mode (the default): each recording is cut into three blocks in time,
//! 70/20/10 %, and a window belongs to a split only when all its steps lie inside that
//! split's block — windows straddling a boundary are dropped, so no step of a test window
//! is ever seen in training. Random mode shuffles windows into the splits, as the paper's
//! protocol does; overlapping windows then leak between splits, and reports say so.

use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// How windows are assigned to train / validation / test.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SplitMode {
    /// Each recording cut into 70/20/10 % blocks in time; windows straddling a boundary
    /// are dropped (leakage-free).
    Contiguous,
    /// The paper's protocol; leaks through overlapping windows.
    Random {
        /// Seed of the shuffle (`[data] split_seed`).
        seed: u64,
    },
}

impl SplitMode {
    /// A label for reports.
    pub fn describe(&self) -> &'static str {
        match self {
            SplitMode::Contiguous => "contiguous blocks per recording (leakage-free)",
            SplitMode::Random { .. } => {
                "random (paper protocol; overlapping windows leak between splits)"
            }
        }
    }
}

/// Window geometry: length T and stride S in control ticks.
#[derive(Clone, Copy, Debug)]
pub struct WindowConfig {
    /// Window length T, ticks.
    pub length: usize,
    /// Least distance S between window ends, ticks.
    pub stride: usize,
    /// Fraction of train (test takes what train and validation leave).
    pub train: f64,
    /// Fraction of validation.
    pub validation: f64,
    /// Share of the training windows kept (1: all). With contiguous blocks, each
    /// recording's training block is cut to its first share, as if the recording's
    /// training part had been shorter; the validation and test blocks do not change. With
    /// the random split, the first share of the shuffled training windows.
    pub train_kept: f64,
    /// Share of the validation windows kept (1: all), as `train_kept` does for training:
    /// the first share of each recording's validation block; the test blocks do not
    /// change.
    pub validation_kept: f64,
    /// Ticks from a window's last step to its labelled row (the model's `look_ahead`):
    /// the label of the window ending at `end` is the residual at `end + look_ahead`, and
    /// that row must lie in the window's split block too.
    pub look_ahead: usize,
}

impl WindowConfig {
    /// The row whose label a window ending at row `end` carries: `end + look_ahead`.
    pub fn label_row(&self, end: usize) -> usize {
        end + self.look_ahead
    }
}

impl Default for WindowConfig {
    fn default() -> WindowConfig {
        WindowConfig {
            length: 100,
            stride: 20,
            train: 0.7,
            validation: 0.2,
            train_kept: 1.0,
            validation_kept: 1.0,
            look_ahead: 0,
        }
    }
}

/// A window of recording `recording` ending at row `end` (inclusive), covering
/// `end + 1 − T ..= end`; its label is row `end + look_ahead`'s ([`WindowConfig`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Window {
    /// Index of the recording, from 0.
    pub recording: usize,
    /// Its last row, from 0.
    pub end: usize,
}

/// Window ends of a recording of `rows` rows: the first row that completes a window
/// and whose label row (`look_ahead` rows on) is labelled (the tracker measured there),
/// then each such row at least `stride` rows after the previous end. With the tracker
/// every 5 ticks and S = 20 that is exactly every 20 rows.
///
/// ```
/// use iastgcn::data::{window_ends, WindowConfig};
///
/// let config = WindowConfig { length: 10, stride: 4, ..WindowConfig::default() };
/// // The tracker measured at every second row.
/// assert_eq!(window_ends(20, &config, |row| row % 2 == 0), vec![10, 14, 18]);
/// // Predicting one tick ahead: windows end one row before a measured row.
/// let ahead = WindowConfig { look_ahead: 1, ..config };
/// assert_eq!(window_ends(20, &ahead, |row| row % 2 == 0), vec![9, 13, 17]);
/// ```
pub fn window_ends(
    rows: usize,
    config: &WindowConfig,
    labelled: impl Fn(usize) -> bool,
) -> Vec<usize> {
    let mut ends: Vec<usize> = Vec::new();
    for e in config.length.saturating_sub(1)..rows.saturating_sub(config.look_ahead) {
        let due = ends
            .last()
            .is_none_or(|&last| e >= last + config.stride.max(1));
        if due && labelled(config.label_row(e)) {
            ends.push(e);
        }
    }
    ends
}

/// Train / validation / test windows.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Splits {
    /// Training windows.
    pub train: Vec<Window>,
    /// Validation windows (early stopping).
    pub validation: Vec<Window>,
    /// Test windows (Table III).
    pub test: Vec<Window>,
}

/// Assigns `windows` (of recordings with `rows[r]` rows) to splits.
///
/// ```
/// use iastgcn::data::{split, window_ends, SplitMode, Window, WindowConfig};
///
/// let config = WindowConfig { length: 10, stride: 5, ..WindowConfig::default() };
/// let windows: Vec<Window> = window_ends(100, &config, |_| true)
///     .into_iter()
///     .map(|end| Window { recording: 0, end })
///     .collect();
/// let s = split(&windows, &[100], &config, SplitMode::Contiguous);
/// // 19 windows: the two that straddle the cuts at rows 70 and 90 are dropped.
/// assert_eq!((s.train.len(), s.validation.len(), s.test.len()), (13, 3, 1));
/// ```
pub fn split(windows: &[Window], rows: &[usize], config: &WindowConfig, mode: SplitMode) -> Splits {
    let mut s = Splits::default();
    match mode {
        SplitMode::Contiguous => {
            for &w in windows {
                let n = rows[w.recording] as f64;
                let b1 = (config.train * n).round() as usize;
                let b2 = ((config.train + config.validation) * n).round() as usize;
                let kept = (config.train * config.train_kept * n).round() as usize;
                let kept_validation =
                    b1 + (config.validation * config.validation_kept * n).round() as usize;
                let start = w.end + 1 - config.length;
                // The last row a window touches: its label's.
                let last = config.label_row(w.end);
                if last < b1 {
                    if last < kept {
                        s.train.push(w);
                    }
                } else if start >= b1 && last < b2 {
                    if last < kept_validation {
                        s.validation.push(w);
                    }
                } else if start >= b2 {
                    s.test.push(w);
                }
            }
        }
        SplitMode::Random { seed } => {
            let mut all = windows.to_vec();
            all.shuffle(&mut ChaCha8Rng::seed_from_u64(seed));
            let n = all.len() as f64;
            let a = (config.train * n).round() as usize;
            let b = ((config.train + config.validation) * n).round() as usize;
            s.test = all.split_off(b.min(all.len()));
            s.validation = all.split_off(a.min(all.len()));
            s.validation
                .truncate((config.validation_kept * s.validation.len() as f64).round() as usize);
            all.truncate((config.train_kept * all.len() as f64).round() as usize);
            s.train = all;
        }
    }
    s
}
