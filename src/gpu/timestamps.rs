//! GPU timestamps around each launch of a command buffer: where a whole pass's time goes
//! on the device, launch by launch, without submitting each one alone.
//!
//! A [`Recorder::timed`](super::Recorder::timed) recorder gives every launch its own
//! compute pass with a timestamp written at its start and at its end (WebGPU's
//! `timestamp_writes`, the portable form: only `Features::TIMESTAMP_QUERY`). The
//! launches still run in one submit, in order, with the barriers wgpu puts between
//! them; what lies between one launch's end and the next one's start (barriers, copies,
//! the front end's gaps) is what a profile calls the time between launches.

use super::{Gpu, GpuError, Readback};

/// Queries in one query set (wgpu's cap).
const PER_SET: u32 = wgpu::QUERY_SET_MAX_QUERIES;
/// Launches whose two timestamps fit in one query set.
const LAUNCHES_PER_SET: u32 = PER_SET / 2;

/// Query sets and buffers for the start and end timestamps of up to `capacity` launches.
pub struct Timestamps {
    sets: Vec<wgpu::QuerySet>,
    resolved: wgpu::Buffer,
    staging: Readback,
    capacity: u32,
    /// Nanoseconds per tick of the device's timestamp counter.
    period_ns: f64,
}

/// One launch's interval on the device's clock, in nanoseconds from an arbitrary origin.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Interval {
    /// When the launch's pass started.
    pub start_ns: f64,
    /// When it ended.
    pub end_ns: f64,
}

impl Interval {
    /// The launch's time (never negative: a counter that runs backwards reads 0).
    pub fn duration_ns(&self) -> f64 {
        (self.end_ns - self.start_ns).max(0.0)
    }
}

impl Timestamps {
    /// Room for the timestamps of `launches` launches. Fails with
    /// [`GpuError::Device`] when the device was opened without timestamp queries
    /// ([`Gpu::has_timestamps`]).
    pub fn new(gpu: &Gpu, launches: usize) -> Result<Timestamps, GpuError> {
        if !gpu.has_timestamps() {
            return Err(GpuError::Device(format!(
                "{} offers no timestamp queries, so launches cannot be timed in one submit",
                gpu.info().name
            )));
        }
        let capacity = u32::try_from(launches.max(1))
            .map_err(|_| GpuError::Device(format!("{launches} launches to time")))?;
        let sets = (0..capacity.div_ceil(LAUNCHES_PER_SET))
            .map(|i| {
                gpu.device.create_query_set(&wgpu::QuerySetDescriptor {
                    label: Some(&format!("timestamps {i}")),
                    ty: wgpu::QueryType::Timestamp,
                    count: PER_SET,
                })
            })
            .collect::<Vec<_>>();
        let bytes = sets.len() as u64 * u64::from(PER_SET) * wgpu::QUERY_SIZE as u64;
        Ok(Timestamps {
            resolved: gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamps resolved"),
                size: bytes,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            }),
            staging: Readback::new(gpu, "timestamps", bytes)?,
            sets,
            capacity,
            period_ns: f64::from(gpu.queue.get_timestamp_period()),
        })
    }

    /// Launches this can time.
    pub fn capacity(&self) -> usize {
        self.capacity as usize
    }

    /// The pass descriptor's timestamp writes for launch `launch` (< capacity).
    pub(crate) fn writes(&self, launch: u32) -> wgpu::ComputePassTimestampWrites<'_> {
        let at = 2 * (launch % LAUNCHES_PER_SET);
        wgpu::ComputePassTimestampWrites {
            query_set: &self.sets[(launch / LAUNCHES_PER_SET) as usize],
            beginning_of_pass_write_index: Some(at),
            end_of_pass_write_index: Some(at + 1),
        }
    }

    /// Records the resolve of the first `launches` launches' timestamps and their copy
    /// into the staging buffer (after the launches, before the submit).
    pub(crate) fn resolve(&self, encoder: &mut wgpu::CommandEncoder, launches: u32) {
        let set_bytes = u64::from(PER_SET) * wgpu::QUERY_SIZE as u64;
        for (i, set) in self.sets.iter().enumerate() {
            let first = i as u32 * LAUNCHES_PER_SET;
            if first >= launches {
                break;
            }
            let queries = 2 * (launches - first).min(LAUNCHES_PER_SET);
            let offset = i as u64 * set_bytes;
            encoder.resolve_query_set(set, 0..queries, &self.resolved, offset);
            encoder.copy_buffer_to_buffer(
                &self.resolved,
                offset,
                self.staging.buffer(),
                offset,
                u64::from(queries) * wgpu::QUERY_SIZE as u64,
            );
        }
    }

    /// Waits for the submitted work and reads the intervals of the first `launches`
    /// launches of the last timed submit, in recording order.
    pub fn read(&self, gpu: &Gpu, launches: usize) -> Result<Vec<Interval>, GpuError> {
        if launches > self.capacity() {
            return Err(GpuError::Device(format!(
                "{launches} launches read from timestamps for {}",
                self.capacity
            )));
        }
        let intervals = self.staging.map_read(gpu, |bytes| {
            let ticks: &[u64] = bytemuck::cast_slice(bytes);
            (0..launches)
                .map(|launch| {
                    let set = launch / LAUNCHES_PER_SET as usize;
                    let at = set * PER_SET as usize + 2 * (launch % LAUNCHES_PER_SET as usize);
                    Interval {
                        start_ns: ticks[at] as f64 * self.period_ns,
                        end_ns: ticks[at + 1] as f64 * self.period_ns,
                    }
                })
                .collect()
        })?;
        Ok(intervals)
    }
}
