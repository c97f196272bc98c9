//! The morning minute (docs/model.md "The morning minute"): a trained model adapted to
//! the day from a short tracker recording taken at its start. The recording's windows
//! are split in time: the first share adapts, the last share judges, and the adapted
//! weights are kept only when they lower the model's loss on that last share (as
//! refinement keeps the incoming weights unless validation improves).
//!
//! Two ways, the evidence chooses between them (docs/results.md "The morning minute"):
//! an **offset**, the mean of what the model missed on the adapting windows added to
//! its output bias (closed form, one forward pass), and a **fine-tune** of every weight
//! for a few epochs of Adam from the trained weights, seeded.

use std::fmt;
use std::ops::Range;
use std::str::FromStr;

use super::{core_stage, data_normalization, RunConfig, Stage, Trainer};
use crate::data::{DataSources, Dataset, SplitMode, WindowConfig, OUTPUTS};
use crate::error::{Error, Result};
use crate::gpu::Device;
use crate::model::{Checkpoint, Parameters};
use crate::progress::Reporter;

/// How a model is adapted to the day.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Method {
    /// The mean miss on the adapting windows, added to the output bias.
    Offset,
    /// Every weight, `epochs` epochs of Adam at learning rate `lr` (no decay).
    FineTune {
        /// Epochs over the adapting windows.
        epochs: usize,
        /// Adam's learning rate.
        lr: f64,
    },
}

impl Method {
    /// `fine-tune` without numbers: 2 epochs at 3e-4, the least harmful of those the
    /// morning study measured (docs/results.md "The morning minute").
    pub const FINE_TUNE: Method = Method::FineTune {
        epochs: 2,
        lr: 3e-4,
    };
}

impl fmt::Display for Method {
    /// `offset`, or `fine-tune:EPOCHS:LR` (what [`Method::from_str`] reads).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Method::Offset => write!(f, "offset"),
            Method::FineTune { epochs, lr } => write!(f, "fine-tune:{epochs}:{lr:e}"),
        }
    }
}

impl FromStr for Method {
    type Err = String;

    /// `offset`, `fine-tune` ([`Method::FINE_TUNE`]) or `fine-tune:EPOCHS:LR`.
    fn from_str(s: &str) -> std::result::Result<Method, String> {
        let bad = || {
            format!(
                "adaptation {s:?}: expected offset, fine-tune or fine-tune:EPOCHS:LR \
                 (1 to 1000 epochs, a learning rate in (0, 1])"
            )
        };
        match s {
            "offset" => return Ok(Method::Offset),
            "fine-tune" => return Ok(Method::FINE_TUNE),
            _ => {}
        }
        let rest = s.strip_prefix("fine-tune:").ok_or_else(bad)?;
        let (epochs, lr) = rest.split_once(':').ok_or_else(bad)?;
        let epochs: usize = epochs.parse().map_err(|_| bad())?;
        let lr: f64 = lr.parse().map_err(|_| bad())?;
        if !((1..=1000).contains(&epochs) && lr.is_finite() && lr > 0.0 && lr <= 1.0) {
            return Err(bad());
        }
        Ok(Method::FineTune { epochs, lr })
    }
}

/// What the adaptation reads from its recording and how it runs.
#[derive(Clone, Debug, PartialEq)]
pub struct AdaptConfig {
    /// How.
    pub method: Method,
    /// Ticks between window ends (the tracker measures every 5 ticks on the twin: 5
    /// makes every measurement a window's label).
    pub stride: usize,
    /// The last share of the recording's windows that judges (0.05 to 0.5).
    pub judge: f64,
    /// The fine-tune's batch, Adam constants, seed and backend (`[train]` of a run
    /// config; its learning rate and epochs are the method's).
    pub train: super::TrainConfig,
}

impl AdaptConfig {
    /// `method` with the stride of every tracker sample, a fifth of the windows judging,
    /// and `config`'s `[train]` table.
    pub fn new(method: Method, config: &RunConfig) -> AdaptConfig {
        AdaptConfig {
            method,
            stride: 5,
            judge: 0.2,
            train: config.train.clone(),
        }
    }

    fn validate(&self) -> Result<()> {
        if !(0.05..=0.5).contains(&self.judge) {
            return Err(Error::Setting {
                setting: "adapt.judge",
                message: format!("0.05 to 0.5 of the windows judge, got {}", self.judge),
            });
        }
        if self.stride == 0 {
            return Err(Error::Setting {
                setting: "adapt.stride",
                message: "windows at least one tick apart".into(),
            });
        }
        Ok(())
    }
}

/// What an adaptation produced.
#[derive(Clone, Debug)]
pub struct Adapted {
    /// The weights to use: the adapted ones, or the trained ones when `kept_trained`.
    pub params: Parameters,
    /// The adapted weights, whether kept or not.
    pub candidate: Parameters,
    /// The method.
    pub method: Method,
    /// Windows that adapted and that judged.
    pub windows: [usize; 2],
    /// The loss (eq. 39, standardised) on the judging windows with the trained weights.
    pub loss_before: f64,
    /// The same with the adapted weights (before the judge keeps either).
    pub loss_after: f64,
    /// True when the adapted weights did not lower the judging loss.
    pub kept_trained: bool,
    /// The offset's shift of the output, µm and mdeg (zero for a fine-tune).
    pub offset: [f64; OUTPUTS],
    /// Wall time of the adaptation, s.
    pub seconds: f64,
}

impl Adapted {
    /// The checkpoint with the kept weights.
    pub fn checkpoint(&self, trained: &Checkpoint) -> Checkpoint {
        Checkpoint {
            parameters: self.params.clone(),
            ..trained.clone()
        }
    }

    /// One line: the method, the windows, the losses and what was kept.
    pub fn verdict(&self) -> String {
        let shift = match self.method {
            Method::Offset => format!(
                " (shift {:+.1} {:+.1} {:+.1} µm, {:+.2} {:+.2} {:+.2} mdeg)",
                self.offset[0],
                self.offset[1],
                self.offset[2],
                self.offset[3],
                self.offset[4],
                self.offset[5]
            ),
            Method::FineTune { .. } => String::new(),
        };
        format!(
            "{}{shift} on {} windows, judged on the last {}: loss {:.4} before, {:.4} adapted; {} ({:.1} s)",
            self.method,
            self.windows[0],
            self.windows[1],
            self.loss_before,
            self.loss_after,
            if self.kept_trained {
                "kept the trained weights"
            } else {
                "kept the adapted weights"
            },
            self.seconds
        )
    }
}

/// The morning recording's windows, standardised with the checkpoint's statistics and
/// split in time into the adapting and the judging windows.
struct Minute {
    data: Dataset,
    label_std: [f64; OUTPUTS],
    fit: Range<usize>,
}

impl Minute {
    fn new(sources: &DataSources, trained: &Checkpoint, config: &AdaptConfig) -> Result<Minute> {
        config.validate()?;
        let model = &trained.config;
        let fixed = data_normalization(&trained.normalization)?;
        let window = WindowConfig {
            length: model.window,
            stride: config.stride,
            train: 1.0 - config.judge,
            validation: config.judge,
            look_ahead: model.look_ahead,
            ..WindowConfig::default()
        };
        let (graph, data) = sources.dataset(&window, SplitMode::Contiguous, Some(&fixed))?;
        if graph.nodes != trained.graph.nodes {
            return Err(Error::Invalid(format!(
                "the morning recording's sensor graph [{}] is not the model's [{}]",
                graph.nodes.join(", "),
                trained.graph.nodes.join(", ")
            )));
        }
        let [fit, judge, _] = data.split_ranges();
        if fit.len() < 2 || judge.len() < 2 {
            return Err(Error::Invalid(format!(
                "the morning recording gives {} windows to adapt on and {} to judge of {} \
                 ticks every {}: record longer",
                fit.len(),
                judge.len(),
                model.window,
                config.stride
            )));
        }
        Ok(Minute {
            data,
            label_std: fixed.label_std,
            fit,
        })
    }

    /// Windows that adapt and that judge.
    fn windows(&self) -> [usize; 2] {
        let [fit, judge, _] = self.data.split_ranges();
        [fit.len(), judge.len()]
    }

    /// A stage of `epochs` at a constant `lr` from the trained weights, judged on the
    /// judging windows.
    fn trainer<'a>(
        &'a self,
        device: &Device,
        trained: &Checkpoint,
        config: &AdaptConfig,
        lr: f64,
        epochs: usize,
    ) -> Result<Trainer<'a>> {
        let mut train = config.train.clone();
        train.lr = lr;
        train.lr_decay = 0.0;
        let stage = Stage {
            name: "adapt".into(),
            lr0: lr,
            max_epochs: epochs,
            patience: epochs,
            ..core_stage(&RunConfig::default())
        };
        Ok(Trainer::new(
            device,
            &self.data,
            &trained.graph,
            &trained.config,
            &train,
            stage,
            &trained.parameters,
        )?)
    }

    /// The mean of y − ŷ over the adapting windows with the trainer's weights,
    /// standardised.
    fn mean_miss(&self, trainer: &Trainer) -> Result<[f64; OUTPUTS]> {
        let positions: Vec<usize> = self.fit.clone().collect();
        let pred = trainer.predict(&positions)?;
        let mut sum = [0.0; OUTPUTS];
        for (row, &p) in positions.iter().enumerate() {
            for (k, s) in sum.iter_mut().enumerate() {
                *s += (self.data.y[p * OUTPUTS + k] - pred[row * OUTPUTS + k]) as f64;
            }
        }
        Ok(sum.map(|s| s / positions.len() as f64))
    }

    /// A standardised shift in µm and mdeg.
    fn physical(&self, shift: &[f64; OUTPUTS]) -> [f64; OUTPUTS] {
        std::array::from_fn(|k| shift[k] * self.label_std[k])
    }
}

/// How far `trained` misses on the adapting windows of the morning recording of
/// `sources`, on average: the mean of the true minus the predicted residual, µm and mdeg
/// (what [`Method::Offset`] adds).
pub fn mean_miss(
    device: &Device,
    sources: &DataSources,
    trained: &Checkpoint,
    config: &AdaptConfig,
) -> Result<[f64; OUTPUTS]> {
    let minute = Minute::new(sources, trained, config)?;
    let trainer = minute.trainer(device, trained, config, config.train.lr, 1)?;
    Ok(minute.physical(&minute.mean_miss(&trainer)?))
}

/// Adapts `trained` to the day of the recordings of `sources` (the morning minute, under
/// the calibration `sources` names), standardised with the checkpoint's own statistics.
pub fn adapt(
    device: &Device,
    sources: &DataSources,
    trained: &Checkpoint,
    config: &AdaptConfig,
    reporter: &mut dyn Reporter,
) -> Result<Adapted> {
    let clock = std::time::Instant::now();
    let minute = Minute::new(sources, trained, config)?;
    let (lr, epochs) = match config.method {
        Method::Offset => (config.train.lr, 1),
        Method::FineTune { epochs, lr } => (lr, epochs),
    };
    let mut trainer = minute.trainer(device, trained, config, lr, epochs)?;
    let loss_before = trainer.keep_start_unless_improved()?;
    let mut offset = [0.0; OUTPUTS];
    let candidate = match config.method {
        Method::Offset => {
            let shift = minute.mean_miss(&trainer)?;
            offset = minute.physical(&shift);
            shifted(&trained.parameters, &shift)?
        }
        Method::FineTune { .. } => {
            super::run_stage(&mut trainer, "adapt", reporter, |_, _| Ok(()))?;
            trainer.best.clone()
        }
    };
    let loss_after = trainer.validation_loss_of(&candidate)?;
    // NaN or no lower: the trained weights stay.
    let improved = loss_after < loss_before;
    let kept_trained = !improved;
    Ok(Adapted {
        params: if kept_trained {
            trained.parameters.clone()
        } else {
            candidate.clone()
        },
        candidate,
        method: config.method,
        windows: minute.windows(),
        loss_before,
        loss_after,
        kept_trained,
        offset,
        seconds: clock.elapsed().as_secs_f64(),
    })
}

/// `params` with `shift` (standardised) added to the output bias `head.bias`.
fn shifted(params: &Parameters, shift: &[f64; OUTPUTS]) -> Result<Parameters> {
    let mut out = params.clone();
    let index = out
        .index("head.bias")
        .ok_or_else(|| Error::Invalid("the model has no output bias head.bias to shift".into()))?;
    let bias = &mut out.values[index];
    if bias.len() != OUTPUTS {
        return Err(Error::Invalid(format!(
            "head.bias has {} values, the offset {OUTPUTS}",
            bias.len()
        )));
    }
    for (b, s) in bias.iter_mut().zip(shift) {
        *b += *s as f32;
    }
    Ok(out)
}
