//! Device-resident tensors: a storage buffer with a shape and an element type.

use super::{Allocation, Gpu, GpuError};

/// Element type of a tensor.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DType {
    /// 32-bit float.
    F32,
    /// 32-bit unsigned integer.
    U32,
}

impl DType {
    /// Bytes per element (4 for both).
    pub fn size(self) -> usize {
        4
    }
}

/// A buffer on the device with a row-major shape. Cloning shares the buffer.
///
/// Data only moves between host and device through explicit calls
/// ([`Gpu::upload`], [`Gpu::write`], [`Gpu::read_f32`], [`Readback`]).
#[derive(Clone, Debug)]
pub struct Tensor {
    pub(crate) buffer: wgpu::Buffer,
    shape: Vec<usize>,
    dtype: DType,
    name: String,
}

impl Tensor {
    /// The row-major shape, e.g. `[B, N, C, T]`.
    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    /// The element type.
    pub fn dtype(&self) -> DType {
        self.dtype
    }

    /// The name errors and profiles give it.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Number of elements: the product of the shape.
    pub fn numel(&self) -> usize {
        self.shape.iter().product()
    }

    /// Size of the data in bytes.
    pub fn byte_len(&self) -> u64 {
        (self.numel() * self.dtype.size()) as u64
    }

    /// The wgpu storage buffer.
    pub fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }

    /// The same buffer seen with another shape of the same element count.
    pub fn reshaped(&self, shape: &[usize]) -> Result<Tensor, GpuError> {
        if shape.iter().product::<usize>() != self.numel() {
            return Err(GpuError::Shape {
                tensor: self.name.clone(),
                expected: format!("{} elements", self.numel()),
                got: format!("{shape:?}"),
            });
        }
        Ok(Tensor {
            shape: shape.to_vec(),
            ..self.clone()
        })
    }

    /// The first `shape.product()` elements of the buffer seen as a tensor of `shape`
    /// (scratch buffers sized for the largest user are shared by smaller ones).
    pub fn prefix(&self, name: &str, shape: &[usize]) -> Result<Tensor, GpuError> {
        let numel: usize = shape.iter().product();
        if (numel * self.dtype.size()) as u64 > self.buffer.size() {
            return Err(GpuError::Shape {
                tensor: format!("{name} (view of {})", self.name),
                expected: format!("at most {} bytes", self.buffer.size()),
                got: format!("{shape:?}"),
            });
        }
        Ok(Tensor {
            shape: shape.to_vec(),
            name: name.to_string(),
            ..self.clone()
        })
    }

    /// Fails with a message naming the tensor unless it holds exactly `numel` elements.
    pub fn expect_len(&self, numel: usize) -> Result<(), GpuError> {
        if self.numel() == numel {
            Ok(())
        } else {
            Err(GpuError::Shape {
                tensor: self.name.clone(),
                expected: format!("{numel} elements"),
                got: format!("{:?} = {} elements", self.shape, self.numel()),
            })
        }
    }

    /// An output must not share its buffer with any input of the same dispatch (wgpu
    /// forbids a buffer bound both read-only and read-write); the error names both.
    pub fn expect_distinct<'t>(
        &self,
        inputs: impl IntoIterator<Item = &'t Tensor>,
    ) -> Result<(), GpuError> {
        match inputs.into_iter().find(|t| t.buffer() == self.buffer()) {
            None => Ok(()),
            Some(t) => Err(GpuError::Shape {
                tensor: self.name.clone(),
                expected: format!("a buffer distinct from input {}", t.name()),
                got: "the same buffer".to_string(),
            }),
        }
    }
}

impl Gpu {
    /// A zero-filled tensor. Fails with [`GpuError::TooLarge`] before allocating when
    /// the tensor exceeds what one buffer or one storage binding of this adapter may
    /// hold, and with [`GpuError::OutOfMemory`] when the device has no room for it.
    pub fn zeros(&self, name: &str, shape: &[usize], dtype: DType) -> Result<Tensor, GpuError> {
        // Bindings may not be empty, and kernels may view the buffer as vec4s: round up to
        // whole 16-byte vectors (the tail is never read as data).
        let size = shape
            .iter()
            .try_fold(dtype.size() as u64, |n, &d| n.checked_mul(d as u64))
            .and_then(|bytes| bytes.max(1).checked_next_multiple_of(16))
            .unwrap_or(u64::MAX);
        let limits = self.limits();
        for (limit, limit_name) in [
            (limits.max_buffer_size, "max_buffer_size"),
            (
                limits.max_storage_buffer_binding_size,
                "max_storage_buffer_binding_size",
            ),
        ] {
            if size > limit {
                return Err(GpuError::TooLarge {
                    tensor: name.to_string(),
                    bytes: size,
                    limit,
                    limit_name,
                });
            }
        }
        let (buffer, error) = self.scoped(wgpu::ErrorFilter::OutOfMemory, || {
            self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(name),
                size,
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_SRC
                    | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        });
        if let Some(message) = error {
            return Err(GpuError::OutOfMemory {
                tensor: name.to_string(),
                bytes: size,
                message,
            });
        }
        if let Ok(mut log) = self.allocations.lock() {
            if let Some(log) = log.as_mut() {
                log.push(Allocation {
                    name: name.to_string(),
                    bytes: size,
                });
            }
        }
        Ok(Tensor {
            buffer,
            shape: shape.to_vec(),
            dtype,
            name: name.to_string(),
        })
    }

    /// Runs `f` and returns what it returned with every tensor it created on this device
    /// (by [`Gpu::zeros`] or [`Gpu::upload`]), in creation order: how much device memory
    /// a network takes. Not reentrant: a nested call sees nothing.
    pub fn allocations_during<T>(&self, f: impl FnOnce() -> T) -> (T, Vec<Allocation>) {
        let set = |log: Option<Vec<Allocation>>| match self.allocations.lock() {
            Ok(mut slot) => std::mem::replace(&mut *slot, log),
            Err(poisoned) => std::mem::replace(&mut *poisoned.into_inner(), log),
        };
        set(Some(Vec::new()));
        let out = f();
        (out, set(None).unwrap_or_default())
    }

    /// A new f32 tensor holding `data`.
    pub fn upload(&self, name: &str, shape: &[usize], data: &[f32]) -> Result<Tensor, GpuError> {
        let t = self.zeros(name, shape, DType::F32)?;
        self.write(&t, data)?;
        Ok(t)
    }

    /// Overwrites the whole tensor with `data` (queued; ordered before the next submit).
    pub fn write<T: bytemuck::Pod>(&self, tensor: &Tensor, data: &[T]) -> Result<(), GpuError> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        if bytes.len() as u64 != tensor.byte_len() {
            return Err(GpuError::Shape {
                tensor: tensor.name.clone(),
                expected: format!("{} bytes ({:?})", tensor.byte_len(), tensor.shape),
                got: format!("{} bytes", bytes.len()),
            });
        }
        if !bytes.is_empty() {
            self.queue.write_buffer(&tensor.buffer, 0, bytes);
        }
        Ok(())
    }

    /// Copies a tensor back to the host and waits for it. Allocates a staging buffer each
    /// call: for repeated reads of the same tensor use a [`Readback`].
    pub fn read_f32(&self, tensor: &Tensor) -> Result<Vec<f32>, GpuError> {
        let rb = Readback::new(self, tensor.name(), tensor.byte_len())?;
        let mut enc = self.device.create_command_encoder(&Default::default());
        rb.copy_from(&mut enc, tensor)?;
        self.queue.submit([enc.finish()]);
        rb.read_f32(self)
    }
}

/// A reusable host-visible staging buffer for explicit readback.
pub struct Readback {
    buffer: wgpu::Buffer,
    size: u64,
    name: String,
}

impl Readback {
    /// A staging buffer of at least `bytes` bytes (rounded up to a multiple of 4), named
    /// `name` in errors; refused like [`Gpu::zeros`] when the adapter cannot hold it.
    pub fn new(gpu: &Gpu, name: &str, bytes: u64) -> Result<Readback, GpuError> {
        let size = bytes.max(4).next_multiple_of(4);
        let label = format!("readback {name}");
        let limit = gpu.limits().max_buffer_size;
        if size > limit {
            return Err(GpuError::TooLarge {
                tensor: label,
                bytes: size,
                limit,
                limit_name: "max_buffer_size",
            });
        }
        let (buffer, error) = gpu.scoped(wgpu::ErrorFilter::OutOfMemory, || {
            gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(&label),
                size,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        });
        if let Some(message) = error {
            return Err(GpuError::OutOfMemory {
                tensor: label,
                bytes: size,
                message,
            });
        }
        Ok(Readback {
            buffer,
            size,
            name: name.to_string(),
        })
    }

    /// Records a copy of `tensor` into this staging buffer.
    pub(crate) fn copy_from(
        &self,
        enc: &mut wgpu::CommandEncoder,
        tensor: &Tensor,
    ) -> Result<(), GpuError> {
        if tensor.byte_len() > self.size {
            return Err(GpuError::Shape {
                tensor: tensor.name.clone(),
                expected: format!("at most {} bytes (readback {})", self.size, self.name),
                got: format!("{} bytes", tensor.byte_len()),
            });
        }
        if tensor.byte_len() > 0 {
            enc.copy_buffer_to_buffer(&tensor.buffer, 0, &self.buffer, 0, tensor.byte_len());
        }
        Ok(())
    }

    /// Waits for submitted work and copies the first `out.len()` floats of the staging
    /// buffer into `out` (no allocation).
    pub fn read_into(&self, gpu: &Gpu, out: &mut [f32]) -> Result<(), GpuError> {
        if (out.len() * 4) as u64 > self.size {
            return Err(GpuError::Shape {
                tensor: format!("readback {}", self.name),
                expected: format!("at most {} floats", self.size / 4),
                got: format!("{}", out.len()),
            });
        }
        self.map_read(gpu, |bytes| {
            out.copy_from_slice(&bytemuck::cast_slice::<u8, f32>(bytes)[..out.len()]);
        })
    }

    /// Waits for submitted work, maps the whole staging buffer and hands its bytes to
    /// `read` (any element type: [`super::Timestamps`] reads its u64 ticks this way).
    pub(crate) fn map_read<T>(
        &self,
        gpu: &Gpu,
        read: impl FnOnce(&[u8]) -> T,
    ) -> Result<T, GpuError> {
        let (tx, rx) = std::sync::mpsc::channel();
        self.buffer.map_async(wgpu::MapMode::Read, .., move |r| {
            let _ = tx.send(r);
        });
        gpu.wait()?;
        rx.recv()
            .map_err(|e| GpuError::Readback(format!("{}: {e}", self.name)))?
            .map_err(|e| GpuError::Readback(format!("{}: {e}", self.name)))?;
        let value = {
            let view = self
                .buffer
                .get_mapped_range(..)
                .map_err(|e| GpuError::Readback(format!("{}: {e}", self.name)))?;
            read(&view)
        };
        self.buffer.unmap();
        Ok(value)
    }

    /// The staging buffer, for a copy into it that is not a tensor's.
    pub(crate) fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }

    /// Waits for submitted work and returns the whole staging buffer as f32.
    pub fn read_f32(&self, gpu: &Gpu) -> Result<Vec<f32>, GpuError> {
        let mut out = vec![0.0; (self.size / 4) as usize];
        self.read_into(gpu, &mut out)?;
        Ok(out)
    }
}
