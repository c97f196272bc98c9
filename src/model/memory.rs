//! How much device memory a network takes, and the largest batch the adapter allows.
//!
//! Every device buffer of a network is created when it is built and none during a pass,
//! so its memory is the sum of its buffers ([`crate::gpu::Gpu::allocations_during`]).
//! Building it at B = 1 and at the batch asked for gives the memory at that batch
//! exactly, and the cost of one more window as the average slope between the two (most
//! buffers are fixed or grow in proportion to B; the weight-gradient chunk buffers grow
//! in steps, so the slope is an average).

use super::config::ModelConfig;
use super::error::ModelError;
use super::network::{Network, Pass};
use crate::gpu::{Allocation, Gpu};
use crate::graph::Graph;

/// A network's device memory at one batch.
#[derive(Clone, Debug, PartialEq)]
pub struct Footprint {
    /// The schedules it was built for.
    pub pass: Pass,
    /// The batch B it was measured at.
    pub batch: usize,
    /// Bytes of all its buffers at B.
    pub bytes: u64,
    /// Bytes at B = 1.
    pub bytes_at_one: u64,
    /// Its largest buffer at B: name and bytes.
    pub largest: (String, u64),
    /// The largest batch for which that buffer, growing in proportion to B, stays within
    /// the adapter's limit on one buffer and one storage binding.
    pub max_batch: usize,
    /// That limit, bytes.
    pub limit_bytes: u64,
}

impl Footprint {
    /// Bytes per additional window: the average slope between B = 1 and B.
    pub fn per_window_bytes(&self) -> u64 {
        (self.bytes - self.bytes_at_one) / (self.batch as u64 - 1)
    }
}

/// The footprint of `config`'s network for `pass` at `batch` (≥ 2) windows:
/// [`Pass::Train`] is the network of a training stage (without the optimiser's two
/// moment tensors per parameter), [`Pass::Inference`] the predictor's. Measured by
/// building the network at B = 1 and at `batch` on `gpu`.
pub fn footprint(
    gpu: &Gpu,
    config: &ModelConfig,
    graph: &Graph,
    pass: Pass,
    batch: usize,
) -> Result<Footprint, ModelError> {
    if batch < 2 {
        return Err(ModelError::Config(format!(
            "memory footprint: the batch must be at least 2, got {batch}"
        )));
    }
    let build = |batch: usize| -> Result<Vec<Allocation>, ModelError> {
        let (net, log) = gpu.allocations_during(|| match pass {
            Pass::Train => Network::new(gpu, config, graph, batch, 0),
            Pass::Inference => Network::for_inference(gpu, config, graph, batch),
        });
        net?;
        Ok(log)
    };
    let total = |log: &[Allocation]| log.iter().map(|a| a.bytes).sum::<u64>();
    let one = build(1)?;
    let at = build(batch)?;
    let largest = at
        .iter()
        .max_by_key(|a| a.bytes)
        .map_or((String::new(), 0), |a| (a.name.clone(), a.bytes));
    let limits = gpu.limits();
    let limit = limits
        .max_buffer_size
        .min(limits.max_storage_buffer_binding_size);
    let per_window = largest.1.div_ceil(batch as u64).max(1);
    Ok(Footprint {
        pass,
        batch,
        bytes: total(&at),
        bytes_at_one: total(&one),
        largest,
        max_batch: (limit / per_window) as usize,
        limit_bytes: limit,
    })
}
