//! Summary statistics of error magnitudes, as the paper's tables report them.

/// Mean, standard deviation and maximum of a set of values.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Summary {
    /// Arithmetic mean.
    pub mean: f64,
    /// Population standard deviation (divided by the count).
    pub sd: f64,
    /// Largest value.
    pub max: f64,
    /// Number of values.
    pub count: usize,
}

impl Summary {
    /// The summary of `values`, in their unit; `None` for an empty set.
    ///
    /// ```
    /// use iastgcn::stats::Summary;
    ///
    /// let s = Summary::of(&[1.0, 2.0, 3.0, 6.0]).unwrap();
    /// assert_eq!((s.mean, s.max, s.count), (3.0, 6.0, 4));
    /// assert!((s.sd - 3.5f64.sqrt()).abs() < 1e-12);
    /// assert!(Summary::of(&[]).is_none());
    /// ```
    pub fn of(values: &[f64]) -> Option<Summary> {
        if values.is_empty() {
            return None;
        }
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
        Some(Summary {
            mean,
            sd: var.sqrt(),
            max: values.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            count: values.len(),
        })
    }

    /// The root mean square of the values summarised: √(mean² + SD²).
    ///
    /// ```
    /// use iastgcn::stats::Summary;
    ///
    /// let s = Summary::of(&[3.0, 4.0]).unwrap();
    /// assert!((s.rms() - 12.5f64.sqrt()).abs() < 1e-12);
    /// ```
    pub fn rms(&self) -> f64 {
        self.mean.hypot(self.sd)
    }
}
