//! Prepared dispatches and the recorder that batches them into one submit.

use std::sync::Arc;

use super::pipeline::Pipeline;
use super::timestamps::Timestamps;
use super::{Gpu, GpuError, Readback, Tensor, Uniform};

/// One kernel launch with its buffers bound: built once, recorded any number of times.
///
/// Owns its uniform parameter block, so recording allocates nothing.
#[derive(Debug)]
pub struct Dispatch {
    pub(crate) pipeline: Arc<Pipeline>,
    pub(crate) bind_group: wgpu::BindGroup,
    pub(crate) params: wgpu::Buffer,
    /// The WGSL struct of the uniform block (what [`Dispatch::write_params`] accepts).
    pub(crate) uniform: &'static str,
    pub(crate) workgroups: [u32; 3],
    pub(crate) label: String,
    /// Name of the tensor bound last (by convention the one the kernel writes).
    pub(crate) target: String,
    /// Multiply-adds × 2 of a contraction (set by the matmul op), 0 for other kernels.
    pub(crate) flops: f64,
    /// A launch that must follow this one and belongs to the same operation (the sum of
    /// a split product's partial results): recorded, profiled and counted with it.
    pub(crate) next: Option<Box<Dispatch>>,
}

impl Dispatch {
    /// `shader::entry` of the kernel, as profiles and errors name it.
    pub fn label(&self) -> &str {
        &self.label
    }

    /// The workgroup counts along x, y, z.
    pub fn workgroups(&self) -> [u32; 3] {
        self.workgroups
    }

    /// Name of the tensor this dispatch writes (its last binding).
    pub fn target(&self) -> &str {
        &self.target
    }

    /// FLOPs of a contraction (2 per multiply-add), 0 for elementwise kernels: what a
    /// profile divides by the time to get GFLOP/s.
    pub fn flops(&self) -> f64 {
        self.flops
    }

    pub(crate) fn with_flops(mut self, flops: f64) -> Dispatch {
        self.flops = flops;
        self
    }

    /// This launch followed by `next`, as one operation that writes what `next` writes.
    pub(crate) fn then(mut self, next: Dispatch) -> Dispatch {
        self.target = next.target.clone();
        match self.next.take() {
            Some(first) => self.next = Some(Box::new(first.then(next))),
            None => self.next = Some(Box::new(next)),
        }
        self
    }

    /// Launches recorded for this operation (1, or more when it is split).
    pub fn launches(&self) -> usize {
        1 + self.next.as_ref().map_or(0, |n| n.launches())
    }

    /// Replaces the uniform parameters (same type as at creation), e.g. a learning rate.
    pub fn write_params<P: Uniform>(&self, gpu: &Gpu, params: &P) -> Result<(), GpuError> {
        if P::WGSL != self.uniform {
            return Err(GpuError::Uniform {
                rust: std::any::type_name::<P>().to_string(),
                wgsl: format!("{}: struct {}", self.label, self.uniform),
                what: format!("written over a block of `{}`", P::WGSL),
            });
        }
        let bytes = bytemuck::bytes_of(params);
        if bytes.len() as u64 != self.params.size() {
            return Err(GpuError::Shape {
                tensor: format!("params of {}", self.label),
                expected: format!("{} bytes", self.params.size()),
                got: format!("{} bytes", bytes.len()),
            });
        }
        gpu.queue.write_buffer(&self.params, 0, bytes);
        Ok(())
    }
}

/// Records dispatches and copies into one command encoder; consecutive dispatches share
/// one compute pass (wgpu inserts the barriers between them). Nothing runs until
/// [`Recorder::submit`].
pub struct Recorder<'g> {
    gpu: &'g Gpu,
    encoder: wgpu::CommandEncoder,
    pass: Option<wgpu::ComputePass<'static>>,
    dispatches: usize,
    /// The first dispatch's label, for errors.
    first: Option<String>,
    /// Where a timed recorder writes each launch's start and end ([`Recorder::timed`]).
    stamps: Option<&'g Timestamps>,
    /// Launches recorded with timestamps so far.
    timed: u32,
}

impl<'g> Recorder<'g> {
    /// An empty recorder on `gpu`'s device.
    pub fn new(gpu: &'g Gpu) -> Recorder<'g> {
        let encoder = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("recorder"),
            });
        Recorder {
            gpu,
            encoder,
            pass: None,
            dispatches: 0,
            first: None,
            stamps: None,
            timed: 0,
        }
    }

    /// A recorder that times every launch: each runs in its own compute pass with a
    /// timestamp at its start and end, still in one submit and in order. After the
    /// submit, [`Timestamps::read`] gives the intervals, [`Recorder::timed_launches`]
    /// how many. More launches than `stamps` holds make the submit fail.
    pub fn timed(gpu: &'g Gpu, stamps: &'g Timestamps) -> Recorder<'g> {
        Recorder {
            stamps: Some(stamps),
            ..Recorder::new(gpu)
        }
    }

    /// Launches recorded so far by a timed recorder, in the order [`Timestamps::read`]
    /// returns their intervals (0 for an untimed one).
    pub fn timed_launches(&self) -> usize {
        self.timed as usize
    }

    /// Records one dispatch (with the launches chained to it).
    pub fn dispatch(&mut self, d: &Dispatch) {
        if self.stamps.is_some() {
            self.end_pass();
        }
        let launch = self.timed;
        let writes = self
            .stamps
            .and_then(|s| ((launch as usize) < s.capacity()).then(|| s.writes(launch)));
        let pass = self.pass.get_or_insert_with(|| {
            self.encoder
                .begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("ops"),
                    timestamp_writes: writes,
                })
                .forget_lifetime()
        });
        pass.set_pipeline(&d.pipeline.pipeline);
        pass.set_bind_group(0, &d.bind_group, &[]);
        let [x, y, z] = d.workgroups;
        pass.dispatch_workgroups(x, y, z);
        self.dispatches += 1;
        if self.stamps.is_some() {
            self.timed += 1;
            self.end_pass();
        }
        if self.first.is_none() {
            self.first = Some(d.label.clone());
        }
        if let Some(next) = &d.next {
            self.dispatch(next);
        }
    }

    /// Records every dispatch of `ds` in order.
    pub fn dispatch_all<'d>(&mut self, ds: impl IntoIterator<Item = &'d Dispatch>) {
        for d in ds {
            self.dispatch(d);
        }
    }

    fn end_pass(&mut self) {
        self.pass = None;
    }

    /// Records a full copy of `src` into `dst` (same byte length).
    pub fn copy(&mut self, src: &Tensor, dst: &Tensor) -> Result<(), GpuError> {
        if src.byte_len() != dst.byte_len() {
            return Err(GpuError::Shape {
                tensor: dst.name().to_string(),
                expected: format!("{} bytes like {}", src.byte_len(), src.name()),
                got: format!("{} bytes", dst.byte_len()),
            });
        }
        self.end_pass();
        if src.byte_len() > 0 {
            self.encoder
                .copy_buffer_to_buffer(&src.buffer, 0, &dst.buffer, 0, src.byte_len());
        }
        Ok(())
    }

    /// Records a copy of `count` f32 elements from `src[src_at..]` to `dst[dst_at..]`
    /// (e.g. one step's loss into a per-epoch log, one chunk's outputs into a table).
    pub fn copy_f32(
        &mut self,
        src: &Tensor,
        src_at: usize,
        dst: &Tensor,
        dst_at: usize,
        count: usize,
    ) -> Result<(), GpuError> {
        for (t, at) in [(src, src_at), (dst, dst_at)] {
            if at + count > t.numel() {
                return Err(GpuError::Shape {
                    tensor: t.name().to_string(),
                    expected: format!("at least {} elements", at + count),
                    got: format!("{} elements", t.numel()),
                });
            }
        }
        self.end_pass();
        if count > 0 {
            self.encoder.copy_buffer_to_buffer(
                &src.buffer,
                (src_at * 4) as u64,
                &dst.buffer,
                (dst_at * 4) as u64,
                (count * 4) as u64,
            );
        }
        Ok(())
    }

    /// Records zero-filling of `t`.
    pub fn zero(&mut self, t: &Tensor) {
        self.end_pass();
        self.encoder.clear_buffer(&t.buffer, 0, None);
    }

    /// Records a copy of `t` into the staging buffer `rb`; read it after [`Self::submit`].
    pub fn read_into(&mut self, t: &Tensor, rb: &Readback) -> Result<(), GpuError> {
        self.end_pass();
        rb.copy_from(&mut self.encoder, t)
    }

    /// Number of dispatches recorded so far.
    pub fn len(&self) -> usize {
        self.dispatches
    }

    /// True when nothing has been recorded.
    pub fn is_empty(&self) -> bool {
        self.dispatches == 0
    }

    /// Submits everything recorded as one command buffer. Does not wait. Fails when
    /// the device is lost or wgpu rejects the commands (the error names the first
    /// dispatch's kernel and the count).
    pub fn submit(mut self) -> Result<wgpu::SubmissionIndex, GpuError> {
        self.gpu.check()?;
        self.end_pass();
        let gpu = self.gpu;
        let (dispatches, first) = (self.dispatches, self.first.take());
        if let Some(stamps) = self.stamps {
            if self.timed as usize > stamps.capacity() {
                return Err(GpuError::Device(format!(
                    "{} launches recorded to be timed, timestamps for {}",
                    self.timed,
                    stamps.capacity()
                )));
            }
            stamps.resolve(&mut self.encoder, self.timed);
        }
        let encoder = self.encoder;
        let (index, error) = gpu.scoped(wgpu::ErrorFilter::Validation, || {
            gpu.queue.submit([encoder.finish()])
        });
        match error {
            None => Ok(index),
            Some(message) => Err(gpu.scope_error(
                format!(
                    "submit of {dispatches} dispatches starting with {}",
                    first.as_deref().unwrap_or("a copy")
                ),
                message,
            )),
        }
    }
}
