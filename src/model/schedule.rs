//! A schedule: prepared dispatches and buffer copies, recorded in order into one
//! command buffer. Built once per network and batch size; recording allocates nothing.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use crate::gpu::{DType, Dispatch, Gpu, GpuError, Recorder, Tensor};

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

    /// Times every step on its own: each is submitted alone and waited for, `repeats`
    /// times, keeping the fastest. The steps run in schedule order, so each reads what
    /// the steps before it wrote. A submit + wait costs ~0.5 ms on lavapipe, which is
    /// in every figure: read the small steps as upper bounds.
    pub fn profile(&self, gpu: &Gpu, repeats: usize) -> Result<Vec<StepTime>, GpuError> {
        let mut times = Vec::with_capacity(self.0.len());
        for step in &self.0 {
            let mut best = Duration::MAX;
            for _ in 0..repeats.max(1) {
                let mut rec = Recorder::new(gpu);
                Self::record_step(step, &mut rec)?;
                let t0 = Instant::now();
                rec.submit()?;
                gpu.wait()?;
                best = best.min(t0.elapsed());
            }
            times.push(match step {
                Step::Run(d) => StepTime {
                    kernel: d.label().to_string(),
                    target: d.target().to_string(),
                    flops: d.flops(),
                    time: best,
                },
                Step::CopyRange { src, dst, .. } => StepTime {
                    kernel: "copy".into(),
                    target: format!("{} <- {}", dst.name(), src.name()),
                    flops: 0.0,
                    time: best,
                },
            });
        }
        Ok(times)
    }
}

/// One step's time from [`Steps::profile`].
#[derive(Clone, Debug)]
pub struct StepTime {
    /// `shader::entry`, or `copy`.
    pub kernel: String,
    /// The tensor the step writes.
    pub target: String,
    /// FLOPs of a contraction, 0 otherwise.
    pub flops: f64,
    /// The fastest of the repeats, submit and wait included.
    pub time: Duration,
}

impl StepTime {
    /// GFLOP/s of a contraction, 0 for other steps.
    pub fn gflops(&self) -> f64 {
        self.flops / self.time.as_secs_f64() / 1e9
    }
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
