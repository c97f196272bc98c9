//! A schedule: prepared dispatches and buffer copies, recorded in order into one
//! command buffer. Built once per network and batch size; recording allocates nothing.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use crate::gpu::{DType, Dispatch, Gpu, GpuError, Recorder, Tensor, Timestamps};

/// One entry of a schedule.
#[derive(Debug)]
pub enum Step {
    /// A kernel launch.
    Run(Dispatch),
    /// `count` f32 elements from `src[src_at..]` to `dst[dst_at..]`.
    CopyRange {
        /// The tensor copied from.
        src: Tensor,
        /// The first element copied, in elements.
        src_at: usize,
        /// The tensor copied into.
        dst: Tensor,
        /// Where the copy lands in `dst`, in elements.
        dst_at: usize,
        /// Elements copied.
        count: usize,
    },
}

/// An ordered list of steps.
#[derive(Debug, Default)]
pub struct Steps(pub Vec<Step>);

impl Steps {
    /// Appends the dispatch (passing on its error) and returns its index, for
    /// [`Steps::dispatch`].
    pub fn run(&mut self, d: Result<Dispatch, GpuError>) -> Result<usize, GpuError> {
        self.0.push(Step::Run(d?));
        Ok(self.0.len() - 1)
    }

    /// Copies `count` elements of `src` from `src_at` into `dst` at `dst_at`.
    pub fn copy_range(
        &mut self,
        (src, src_at): (&Tensor, usize),
        (dst, dst_at): (&Tensor, usize),
        count: usize,
    ) {
        self.0.push(Step::CopyRange {
            src: src.clone(),
            src_at,
            dst: dst.clone(),
            dst_at,
            count,
        });
    }

    /// The dispatch at `index`; `None` for a copy or past the end.
    pub fn dispatch(&self, index: usize) -> Option<&Dispatch> {
        match self.0.get(index) {
            Some(Step::Run(d)) => Some(d),
            _ => None,
        }
    }

    /// Number of steps.
    pub fn len(&self) -> usize {
        self.0.len()
    }

    /// True without steps.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// Records every step, in order, into `rec`.
    pub fn record(&self, rec: &mut Recorder) -> Result<(), GpuError> {
        for step in &self.0 {
            Self::record_step(step, rec)?;
        }
        Ok(())
    }

    fn record_step(step: &Step, rec: &mut Recorder) -> Result<(), GpuError> {
        match step {
            Step::Run(d) => rec.dispatch(d),
            Step::CopyRange {
                src,
                src_at,
                dst,
                dst_at,
                count,
            } => rec.copy_f32(src, *src_at, dst, *dst_at, *count)?,
        }
        Ok(())
    }
}

/// One step's time in a [`Profile`].
#[derive(Clone, Debug)]
pub struct StepTime {
    /// `shader::entry`, or `copy`.
    pub kernel: String,
    /// The tensor the step writes.
    pub target: String,
    /// Kernel launches of the step: 1, 2 for a split reduction (its partial sums, then
    /// their sum), 0 for a copy.
    pub launches: usize,
    /// FLOPs of a contraction, 0 otherwise.
    pub flops: f64,
    /// The fastest of the repeats: with [`Timing::Timestamps`] the device's time of the
    /// step's launches (a copy reads 0: it falls between launches), with
    /// [`Timing::Alone`] its submit and wait included.
    pub time: Duration,
}

impl StepTime {
    /// GFLOP/s of a contraction, 0 for other steps.
    pub fn gflops(&self) -> f64 {
        self.flops / self.time.as_secs_f64() / 1e9
    }
}

/// How a profile timed its steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Timing {
    /// The whole pass in one submit, as training runs it, each launch timed by the
    /// device's timestamps at its start and end (needs [`Gpu::has_timestamps`]).
    Timestamps,
    /// Each step submitted alone and waited for: the submit's cost is in every figure
    /// (~0.25 ms on an H200, ~0.5 ms on lavapipe), so small steps read as upper bounds.
    Alone,
}

impl Timing {
    /// Timestamps where the device has them, else each step alone.
    pub fn best(gpu: &Gpu) -> Timing {
        if gpu.has_timestamps() {
            Timing::Timestamps
        } else {
            Timing::Alone
        }
    }
}

/// Where a pass's time goes, step by step ([`profile`]).
#[derive(Clone, Debug)]
pub struct Profile {
    /// Every step of the pass, in schedule order.
    pub steps: Vec<StepTime>,
    /// How they were timed.
    pub timing: Timing,
    /// With timestamps, the fastest repeat's time from the first launch's start to the
    /// last one's end; each step alone, the sum of the steps.
    pub span: Duration,
}

impl Profile {
    /// The steps' times summed.
    pub fn launches(&self) -> Duration {
        self.steps.iter().map(|s| s.time).sum()
    }

    /// The part of the span outside every launch (barriers, copies, gaps in the
    /// device's front end); 0 when each step ran alone.
    pub fn between_launches(&self) -> Duration {
        self.span.saturating_sub(self.launches())
    }
}

/// Times the steps of `passes`, recorded one after the other as a training step records
/// them, `repeats` times, keeping each step's fastest. They run in schedule order, so
/// each reads what the steps before it wrote.
pub fn profile(
    gpu: &Gpu,
    passes: &[&Steps],
    timing: Timing,
    repeats: usize,
) -> Result<Profile, GpuError> {
    let steps = || passes.iter().flat_map(|p| p.0.iter());
    let mut times: Vec<StepTime> = steps()
        .map(|step| match step {
            Step::Run(d) => StepTime {
                kernel: d.label().to_string(),
                target: d.target().to_string(),
                launches: d.launches(),
                flops: d.flops(),
                time: Duration::MAX,
            },
            Step::CopyRange { src, dst, .. } => StepTime {
                kernel: "copy".into(),
                target: format!("{} <- {}", dst.name(), src.name()),
                launches: 0,
                flops: 0.0,
                time: Duration::MAX,
            },
        })
        .collect();
    let mut span = Duration::MAX;
    match timing {
        Timing::Alone => {
            for _ in 0..repeats.max(1) {
                for (step, time) in steps().zip(times.iter_mut()) {
                    let mut rec = Recorder::new(gpu);
                    Steps::record_step(step, &mut rec)?;
                    let t0 = Instant::now();
                    rec.submit()?;
                    gpu.wait()?;
                    time.time = time.time.min(t0.elapsed());
                }
            }
            span = times.iter().map(|t| t.time).sum();
        }
        Timing::Timestamps => {
            let launches: usize = steps()
                .map(|step| match step {
                    Step::Run(d) => d.launches(),
                    Step::CopyRange { .. } => 0,
                })
                .sum();
            let stamps = Timestamps::new(gpu, launches)?;
            for _ in 0..repeats.max(1) {
                let mut rec = Recorder::timed(gpu, &stamps);
                for pass in passes {
                    pass.record(&mut rec)?;
                }
                let timed = rec.timed_launches();
                rec.submit()?;
                let intervals = stamps.read(gpu, timed)?;
                let mut next = intervals.iter();
                for (step, time) in steps().zip(times.iter_mut()) {
                    let ns: f64 = match step {
                        Step::Run(d) => next
                            .by_ref()
                            .take(d.launches())
                            .map(|i| i.duration_ns())
                            .sum(),
                        Step::CopyRange { .. } => 0.0,
                    };
                    time.time = time.time.min(Duration::from_secs_f64(ns * 1e-9));
                }
                let start = intervals
                    .iter()
                    .map(|i| i.start_ns)
                    .fold(f64::INFINITY, f64::min);
                let end = intervals
                    .iter()
                    .map(|i| i.end_ns)
                    .fold(f64::NEG_INFINITY, f64::max);
                if end > start {
                    span = span.min(Duration::from_secs_f64((end - start) * 1e-9));
                } else {
                    span = Duration::ZERO;
                }
            }
        }
    }
    Ok(Profile {
        steps: times,
        timing,
        span,
    })
}

/// Scratch buffers shared by the backward passes of all blocks (only one block's
/// backward runs at a time): one buffer per role, sized by its largest user.
pub struct Scratch<'g> {
    gpu: &'g Gpu,
    buffers: HashMap<&'static str, Tensor>,
}

impl<'g> Scratch<'g> {
    /// No buffers yet; they are made on `gpu` as roles ask for them.
    pub fn new(gpu: &'g Gpu) -> Scratch<'g> {
        Scratch {
            gpu,
            buffers: HashMap::new(),
        }
    }

    /// A tensor of `shape` for `role`: a view of the role's buffer when that is large
    /// enough, else a new zeroed buffer that becomes the role's.
    pub fn get(&mut self, role: &'static str, shape: &[usize]) -> Result<Tensor, GpuError> {
        if let Some(t) = self.buffers.get(role) {
            if let Ok(view) = t.prefix(role, shape) {
                return Ok(view);
            }
        }
        let t = self.gpu.zeros(role, shape, DType::F32)?;
        self.buffers.insert(role, t.clone());
        Ok(t)
    }
}

/// A pass through the network: which schedules a network is built with
/// ([`Network::built_for`](crate::model::Network::built_for)), and which one
/// [`Network::profile`](crate::model::Network::profile) times.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pass {
    /// The inference forward.
    Inference,
    /// The training forward, the loss and the backward.
    Train,
}

/// Device parameters and their gradients, looked up by docs/model.md name.
pub trait ParamTable {
    /// The parameter `name` (or `graph.basis`, the graph's basis).
    fn param(&self, name: &str) -> &Tensor;
    /// The gradient of parameter `name`.
    fn grad(&self, name: &str) -> &Tensor;
}
