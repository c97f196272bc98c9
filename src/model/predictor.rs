//! The embeddable forward pass: load a checkpoint, create a predictor on any adapter,
//! feed windows (one, many, or one step at a time through a ring buffer) and get the
//! 6-D pose residual in µm and mdeg.
//!
//! Inputs are the model's per-node features *before* standardisation (docs/model.md
//! "Features and labels": filtered signal, difference, scaled entropy per node and
//! step); the predictor standardises them with the checkpoint's statistics and
//! de-standardises the output. After [`Predictor::new`] no call allocates host
//! memory, buffers or pipelines.
//!
//! Every window runs on the native CPU forward ([`NativeForward`], one at a time) when
//! the adapter is a CPU implementation and the variant is one it covers: on lavapipe it
//! is about 10× faster than the WGSL path, at B = 1 and per window at B = 64 alike
//! (docs/performance.md "The native CPU forward"). [`Predictor::native`] needs no device
//! at all.

use std::sync::Arc;

use super::checkpoint::{Checkpoint, Normalization};
use super::config::ModelConfig;
use super::error::ModelError;
use super::native::NativeForward;
use super::network::Network;
use crate::gpu::{Device, Gpu, Readback, Recorder};

/// A residual prediction: dx, dy, dz in µm, rx, ry, rz in mdeg (base frame).
pub type Residual = [f64; 6];

/// What the windows given to [`Predictor::predict_batch`] hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Features {
    /// The per-node features as computed from the signals; the predictor standardises
    /// them with the checkpoint's statistics.
    Raw,
    /// Features already standardised with the checkpoint's statistics (a dataset built
    /// with them, as the evaluation does).
    Standardised,
}

/// Where a predictor runs its windows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backend {
    /// The WGSL forward on the device.
    Device,
    /// The native CPU forward ([`NativeForward`]), one window at a time; no device
    /// network is built.
    Native,
}

/// Where a predictor's windows run.
enum Path {
    // Both boxed: the two differ in size by a kilobyte.
    Device(Box<DevicePath>),
    Native(Box<NativeForward>),
}

/// The device side of a predictor.
struct DevicePath {
    gpu: Arc<Gpu>,
    /// The weights, to rebuild on a new device after the old one is lost.
    checkpoint: Box<Checkpoint>,
    /// `capacity` windows per submit, for batches.
    net: Network,
    /// One window per submit, when the capacity is larger than one.
    single: Option<Network>,
    readback: Readback,
}

/// The forward pass of one checkpoint: on a device, up to `capacity` windows per
/// submit, or on the CPU, one window at a time.
pub struct Predictor {
    path: Path,
    capacity: usize,
    config: ModelConfig,
    normalization: Normalization,
    /// `[capacity, N, F, T]` standardised input, reused.
    staging: Vec<f32>,
    /// `[capacity, O]` output, reused.
    output: Vec<f32>,
    /// The last T steps `[T][N·F]` (raw), oldest at `head`.
    ring: Vec<f32>,
    head: usize,
    filled: usize,
}

impl Predictor {
    /// Builds the inference schedule for `capacity` windows per submit and uploads
    /// the weights. Compiles every pipeline (the warm-up). When the adapter is a CPU and
    /// the variant is covered, builds the native CPU forward instead
    /// ([`Predictor::backend`]).
    pub fn new(
        gpu: Arc<Gpu>,
        checkpoint: &Checkpoint,
        capacity: usize,
    ) -> Result<Predictor, ModelError> {
        let backend = if gpu.is_software() {
            Backend::Native
        } else {
            Backend::Device
        };
        Predictor::with_backend(gpu, checkpoint, capacity, backend)
    }

    /// [`Predictor::new`] on an adapter, [`Predictor::native`] on the native device (a
    /// machine without a GPU driver).
    pub fn on(
        device: &Device,
        checkpoint: &Checkpoint,
        capacity: usize,
    ) -> Result<Predictor, ModelError> {
        match device {
            Device::Adapter(gpu) => Predictor::new(gpu.clone(), checkpoint, capacity),
            Device::Native => Predictor::native(checkpoint),
        }
    }

    /// As [`Predictor::new`], with the path chosen by the caller ([`Backend::Native`]
    /// fails for a variant the native forward does not cover, and ignores `gpu` and
    /// `capacity`).
    pub fn with_backend(
        gpu: Arc<Gpu>,
        checkpoint: &Checkpoint,
        capacity: usize,
        backend: Backend,
    ) -> Result<Predictor, ModelError> {
        if backend == Backend::Native {
            return Predictor::native(checkpoint);
        }
        let device = DevicePath::new(gpu, checkpoint, capacity)?;
        Predictor::build(checkpoint, Path::Device(Box::new(device)), capacity)
    }

    /// True once the device under this predictor is lost (a native predictor never
    /// is); [`Predictor::rebuild`] recovers.
    pub fn is_lost(&self) -> bool {
        matches!(&self.path, Path::Device(d) if d.gpu.is_lost())
    }

    /// After a [`crate::gpu::GpuError::DeviceLost`] (driver reset, GPU removed): opens
    /// a new device on the same adapter and rebuilds the network and weights on it. The
    /// pushed steps are kept, so a controller loop goes on with its next tick. A native
    /// predictor has nothing to rebuild.
    pub fn rebuild(&mut self) -> Result<(), ModelError> {
        let Path::Device(d) = &self.path else {
            return Ok(());
        };
        let gpu = Gpu::with_adapter(Some(&d.gpu.info().name))?;
        self.rebuild_on(Arc::new(gpu))
    }

    /// As [`Predictor::rebuild`], on a device the caller opened.
    pub fn rebuild_on(&mut self, gpu: Arc<Gpu>) -> Result<(), ModelError> {
        if let Path::Device(d) = &mut self.path {
            **d = DevicePath::new(gpu, &d.checkpoint, self.capacity)?;
        }
        Ok(())
    }

    /// A predictor without a device: every window on the CPU, one at a time (the four
    /// IASTGCN variants only); its capacity is 1. For controllers with no Vulkan, Metal
    /// or DX12 driver, and what [`Predictor::new`] builds on a CPU adapter. A window runs
    /// on the calling thread unless [`Predictor::set_threads`] says otherwise.
    pub fn native(checkpoint: &Checkpoint) -> Result<Predictor, ModelError> {
        let native = native_forward(checkpoint)?;
        Predictor::build(checkpoint, Path::Native(Box::new(native)), 1)
    }

    /// The tasks the native forward splits one window into (default 1: the calling
    /// thread alone; `NativeForward::set_threads` says what is split, on rayon's global
    /// pool). For a controller with idle cores and a large network: on the 2-core
    /// development machine the paper's shape ran 1.1× faster on both cores than on one;
    /// many-core machines were not measured (docs/performance.md "The native CPU
    /// forward"). The outputs do not depend on it. The device path ignores it.
    pub fn set_threads(&mut self, threads: usize) {
        if let Path::Native(native) = &mut self.path {
            native.set_threads(threads);
        }
    }

    /// The tasks the native forward splits one window into; 1 on the device path.
    pub fn threads(&self) -> usize {
        match &self.path {
            Path::Native(native) => native.threads(),
            Path::Device(_) => 1,
        }
    }

    fn build(
        checkpoint: &Checkpoint,
        path: Path,
        capacity: usize,
    ) -> Result<Predictor, ModelError> {
        let config = checkpoint.config.clone();
        if config.outputs != 6 {
            return Err(ModelError::Config(format!(
                "the predictor returns 6-D residuals; this model has {} outputs",
                config.outputs
            )));
        }
        let window = config.nodes * config.features * config.window;
        Ok(Predictor {
            staging: vec![0.0; capacity * window],
            output: vec![0.0; capacity * config.outputs],
            ring: vec![0.0; window],
            head: 0,
            filled: 0,
            path,
            capacity,
            normalization: checkpoint.normalization.clone(),
            config,
        })
    }

    /// Where single windows run.
    pub fn backend(&self) -> Backend {
        match self.path {
            Path::Device(_) => Backend::Device,
            Path::Native(_) => Backend::Native,
        }
    }

    /// The network's shapes and variant, as in the checkpoint.
    pub fn config(&self) -> &ModelConfig {
        &self.config
    }

    /// Windows per submit (1 without a device).
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Floats in one window `[N, F, T]`.
    pub fn window_len(&self) -> usize {
        self.config.nodes * self.config.features * self.config.window
    }

    /// `(v − mean)/std` of feature `k` of node `node`.
    fn standardise(&self, node: usize, k: usize, v: f32) -> f32 {
        standardise(&self.normalization, node, k, v)
    }

    /// Puts one window `[N, F, T]` into staging slot `slot`, standardised.
    fn stage(&mut self, slot: usize, window: &[f32], features: Features) {
        let (f, t) = (self.config.features, self.config.window);
        let len = self.window_len();
        let staged = &mut self.staging[slot * len..][..len];
        if features == Features::Standardised {
            staged.copy_from_slice(window);
            return;
        }
        for (i, &v) in window.iter().enumerate() {
            let row = i / t;
            staged[i] = standardise(&self.normalization, row / f, row % f, v);
        }
    }

    /// Runs the forward pass on the first `windows` staged windows: natively one by one,
    /// or on the device in one submit.
    fn run(&mut self, windows: usize) -> Result<(), ModelError> {
        let (len, o) = (self.window_len(), self.config.outputs);
        match &mut self.path {
            Path::Native(native) => {
                for w in 0..windows {
                    native.forward(
                        &self.staging[w * len..][..len],
                        &mut self.output[w * o..][..o],
                    )?;
                }
                Ok(())
            }
            Path::Device(d) => {
                let net = match &d.single {
                    Some(single) if windows == 1 => single,
                    _ => &d.net,
                };
                let len = net.input.numel();
                d.gpu.write(&net.input, &self.staging[..len])?;
                let mut rec = Recorder::new(&d.gpu);
                net.record_forward(&mut rec)?;
                rec.read_into(&net.output, &d.readback)?;
                rec.submit()?;
                let outputs = net.output.numel();
                d.readback.read_into(&d.gpu, &mut self.output[..outputs])?;
                Ok(())
            }
        }
    }

    fn residual(&self, slot: usize) -> Residual {
        let o = &self.output[slot * 6..][..6];
        std::array::from_fn(|m| {
            o[m] as f64 * self.normalization.label_std[m] + self.normalization.label_mean[m]
        })
    }

    /// The residual of one window `[N, F, T]` (raw features, oldest step first).
    pub fn predict(&mut self, window: &[f32]) -> Result<Residual, ModelError> {
        if window.len() != self.window_len() {
            return Err(ModelError::Config(format!(
                "window: expected N·F·T = {} floats, got {}",
                self.window_len(),
                window.len()
            )));
        }
        self.stage(0, window, Features::Raw);
        self.run(1)?;
        Ok(self.residual(0))
    }

    /// The residuals of many windows `[W, N, F, T]`, `capacity` per submit, written to
    /// `out` (cleared first). This is the one batched path: prediction on recordings,
    /// Table III and any caller with many windows use it.
    pub fn predict_batch(
        &mut self,
        windows: &[f32],
        features: Features,
        out: &mut Vec<Residual>,
    ) -> Result<(), ModelError> {
        let len = self.window_len();
        if !windows.len().is_multiple_of(len) {
            return Err(ModelError::Config(format!(
                "windows: {} floats is not a whole number of windows of N·F·T = {len}",
                windows.len()
            )));
        }
        out.clear();
        for chunk in windows.chunks(self.capacity() * len) {
            let n = chunk.len() / len;
            for (slot, w) in chunk.chunks(len).enumerate() {
                self.stage(slot, w, features);
            }
            // A partial last chunk still runs the full-capacity network (stale slots
            // are ignored) unless it is a single window.
            self.run(if n == 1 { 1 } else { self.capacity() })?;
            out.extend((0..n).map(|slot| self.residual(slot)));
        }
        Ok(())
    }

    /// Pushes one step of raw features `[N, F]`; once T steps have been pushed, returns
    /// the residual of the window ending at this step.
    pub fn push(&mut self, step: &[f32]) -> Result<Option<Residual>, ModelError> {
        self.push_step(step)?;
        self.predict_latest()
    }

    /// Pushes one step of raw features `[N, F]` into the ring without predicting (for a
    /// controller that predicts every k-th tick); true once T steps are in.
    pub fn push_step(&mut self, step: &[f32]) -> Result<bool, ModelError> {
        let (n, f, t) = (self.config.nodes, self.config.features, self.config.window);
        if step.len() != n * f {
            return Err(ModelError::Config(format!(
                "step: expected N·F = {} floats, got {}",
                n * f,
                step.len()
            )));
        }
        self.ring[self.head * n * f..][..n * f].copy_from_slice(step);
        self.head = (self.head + 1) % t;
        self.filled = (self.filled + 1).min(t);
        Ok(self.filled == t)
    }

    /// The residual of the window ending at the last pushed step; `None` until T steps
    /// have been pushed.
    pub fn predict_latest(&mut self) -> Result<Option<Residual>, ModelError> {
        let (n, f, t) = (self.config.nodes, self.config.features, self.config.window);
        if self.filled < t {
            return Ok(None);
        }
        // Unroll the ring (oldest at `head`) into window layout [N, F, T], standardised.
        for age in 0..t {
            let at = ((self.head + age) % t) * n * f;
            for row in 0..n * f {
                let v = self.standardise(row / f, row % f, self.ring[at + row]);
                self.staging[row * t + age] = v;
            }
        }
        self.run(1)?;
        Ok(Some(self.residual(0)))
    }

    /// Forgets the pushed steps (e.g. after a pause in the trajectory).
    pub fn reset(&mut self) {
        self.head = 0;
        self.filled = 0;
    }
}

impl DevicePath {
    /// The inference networks for `capacity` windows (and for one) with the
    /// checkpoint's weights, and the output's staging buffer.
    fn new(gpu: Arc<Gpu>, checkpoint: &Checkpoint, capacity: usize) -> Result<Self, ModelError> {
        let config = &checkpoint.config;
        let net = Network::for_inference(&gpu, config, &checkpoint.graph, capacity)?;
        net.load_parameters(&gpu, &checkpoint.parameters)?;
        let single = if capacity > 1 {
            let single = Network::for_inference(&gpu, config, &checkpoint.graph, 1)?;
            single.load_parameters(&gpu, &checkpoint.parameters)?;
            Some(single)
        } else {
            None
        };
        let readback = Readback::new(&gpu, "y_hat", net.output.byte_len())?;
        Ok(DevicePath {
            gpu,
            checkpoint: Box::new(checkpoint.clone()),
            net,
            single,
            readback,
        })
    }
}

/// The native forward of a checkpoint's weights.
fn native_forward(checkpoint: &Checkpoint) -> Result<NativeForward, ModelError> {
    NativeForward::new(
        &checkpoint.config,
        &checkpoint.graph,
        &checkpoint.parameters,
    )
}

/// `(v − mean)/std` of feature `k` of node `node` under the statistics `nz`.
fn standardise(nz: &Normalization, node: usize, k: usize, v: f32) -> f32 {
    ((v as f64 - nz.feature_mean[node][k]) / nz.feature_std[node][k]) as f32
}
