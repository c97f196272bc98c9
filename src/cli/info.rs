//! `iastgcn info`: what the engine will run on.

use iastgcn::gpu::{describe, Device, Gpu, INSTALL_HINT, NATIVE_NAME};
use iastgcn::ops::matmul;

pub fn run(adapter: Option<&str>) -> anyhow::Result<()> {
    let all = Gpu::list_adapters();
    let gpu = match Device::open(adapter)? {
        Device::Adapter(gpu) => gpu,
        Device::Native => {
            println!("adapter      none: {NATIVE_NAME}");
            println!(
                "runs         train, refine, predict, evaluate, compensate, polish, demo, \
                 reproduce and scale on the native CPU path; smoke and forward (WGSL only) \
                 need an adapter"
            );
            println!("to get one   {INSTALL_HINT}");
            return Ok(());
        }
    };
    let i = gpu.info();
    println!("adapter      {}", i.name);
    println!("backend      {:?}", i.backend);
    println!(
        "device type  {:?}{}",
        i.device_type,
        if gpu.is_software() {
            " (software rasteriser: expect CPU speed)"
        } else {
            ""
        }
    );
    println!("driver       {} {}", i.driver, i.driver_info);
    println!("vendor:dev   {:#06x}:{:#06x}", i.vendor, i.device);
    println!(
        "subgroups    {}..{} lanes",
        i.subgroup_min_size, i.subgroup_max_size
    );
    println!(
        "matmul       {}",
        if matmul::subgroup_kernel_available(&gpu) {
            "operands shared across 8-lane subgroups (matmul_subgroup, matmul_subgroup_cols)"
        } else {
            "8x8 blocks per invocation (matmul)"
        }
    );
    let l = gpu.limits();
    println!("compute limits");
    println!(
        "  invocations per workgroup  {}",
        l.max_compute_invocations_per_workgroup
    );
    println!(
        "  workgroup size x/y/z       {}/{}/{}",
        l.max_compute_workgroup_size_x,
        l.max_compute_workgroup_size_y,
        l.max_compute_workgroup_size_z
    );
    println!(
        "  workgroups per dimension   {}",
        l.max_compute_workgroups_per_dimension
    );
    println!(
        "  workgroup memory           {} KiB",
        l.max_compute_workgroup_storage_size / 1024
    );
    println!(
        "  storage binding            {} MiB",
        l.max_storage_buffer_binding_size >> 20
    );
    println!(
        "  buffer size                {} MiB",
        l.max_buffer_size >> 20
    );
    println!(
        "  storage buffers per stage  {}",
        l.max_storage_buffers_per_shader_stage
    );
    println!(
        "  immediates                 {} bytes",
        l.max_immediate_size
    );
    let f = gpu.adapter_features();
    let flag = |x: wgpu::Features| if f.contains(x) { "yes" } else { "no" };
    println!("features");
    println!(
        "  timestamp queries          {} (inside passes: {})",
        flag(wgpu::Features::TIMESTAMP_QUERY),
        flag(wgpu::Features::TIMESTAMP_QUERY_INSIDE_PASSES)
    );
    println!(
        "  subgroups                  {}",
        flag(wgpu::Features::SUBGROUP)
    );
    println!(
        "  f16                        {}",
        flag(wgpu::Features::SHADER_F16)
    );
    println!(
        "  f64                        {}",
        flag(wgpu::Features::SHADER_F64)
    );
    println!(
        "  immediates                 {}",
        flag(wgpu::Features::IMMEDIATES)
    );
    println!("adapters seen ({})", all.len());
    for a in &all {
        let mark = if a.name == i.name && a.backend == i.backend {
            "*"
        } else {
            " "
        };
        println!("  {mark} {}", describe(a));
    }
    Ok(())
}
