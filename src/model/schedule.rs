//! A schedule: prepared dispatches and buffer copies, recorded in order into one
//! command buffer. Built once per network and batch size; recording allocates nothing.

use std::collections::HashMap;

use crate::gpu::{DType, Dispatch, Gpu, GpuError, Recorder, Tensor};

/// One entry of a schedule.
#[derive(Debug)]
pub enum Step {
    Run(Dispatch),
    Copy { src: Tensor, dst: Tensor },
}

/// An ordered list of steps.
#[derive(Debug, Default)]
pub struct Steps(pub Vec<Step>);

impl Steps {
    pub fn run(&mut self, d: Result<Dispatch, GpuError>) -> Result<usize, GpuError> {
        self.0.push(Step::Run(d?));
        Ok(self.0.len() - 1)
    }

    pub fn copy(&mut self, src: &Tensor, dst: &Tensor) {
        self.0.push(Step::Copy {
            src: src.clone(),
            dst: dst.clone(),
        });
    }

    pub fn dispatch(&self, index: usize) -> Option<&Dispatch> {
        match self.0.get(index) {
            Some(Step::Run(d)) => Some(d),
            _ => None,
        }
    }

    pub fn len(&self) -> usize {
        self.0.len()
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    pub fn record(&self, rec: &mut Recorder) -> Result<(), GpuError> {
        for step in &self.0 {
            match step {
                Step::Run(d) => rec.dispatch(d),
                Step::Copy { src, dst } => rec.copy(src, dst)?,
            }
        }
        Ok(())
    }
}

/// Scratch buffers shared by the backward passes of all blocks (only one block's
/// backward runs at a time): one buffer per role, sized by its largest user.
pub struct Scratch<'g> {
    gpu: &'g Gpu,
    buffers: HashMap<&'static str, Tensor>,
}

impl<'g> Scratch<'g> {
    pub fn new(gpu: &'g Gpu) -> Scratch<'g> {
        Scratch {
            gpu,
            buffers: HashMap::new(),
        }
    }

    pub fn get(&mut self, role: &'static str, shape: &[usize]) -> Result<Tensor, GpuError> {
        if let Some(t) = self.buffers.get(role) {
            if let Ok(view) = t.prefix(role, shape) {
                return Ok(view);
            }
        }
        let t = self.gpu.zeros(role, shape, DType::F32);
        self.buffers.insert(role, t.clone());
        Ok(t)
    }
}
