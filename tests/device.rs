//! Adapter choice (pure logic, no driver needed) and the device layer on the real adapter:
//! tensors, the pipeline cache, the recorder and explicit readback; the smoke check of a
//! device, from the library and from the command line.

use iastgcn::gpu::{
    choose_adapter, DType, GpuError, Readback, Recorder, Timestamps, SUBGROUPS_ENV,
};
use iastgcn::ops::elementwise::{self, Unary};
use iastgcn::ops::matmul;
use iastgcn::ops::Accumulate;
use iastgcn::smoke::{smoke, SmokeOptions};
use iastgcn::testing::gpu;

fn info(name: &str, device_type: wgpu::DeviceType) -> wgpu::AdapterInfo {
    wgpu::AdapterInfo {
        name: name.to_string(),
        vendor: 0,
        device: 0,
        device_type,
        device_pci_bus_id: String::new(),
        driver: "test".to_string(),
        driver_info: String::new(),
        backend: wgpu::Backend::Vulkan,
        subgroup_min_size: 8,
        subgroup_max_size: 8,
        transient_saves_memory: None,
        limit_bucket: None,
    }
}

#[test]
fn prefers_a_real_gpu_over_lavapipe() {
    let list = [
        info("llvmpipe (LLVM 15.0.6, 256 bits)", wgpu::DeviceType::Cpu),
        info("Intel(R) UHD Graphics", wgpu::DeviceType::IntegratedGpu),
        info("NVIDIA H100", wgpu::DeviceType::DiscreteGpu),
    ];
    assert_eq!(choose_adapter(&list, None).unwrap(), 2);
    assert_eq!(choose_adapter(&list[..2], None).unwrap(), 1);
    assert_eq!(
        choose_adapter(&list[..1], None).unwrap(),
        0,
        "falls back to the CPU adapter"
    );
}

#[test]
fn name_override_is_a_case_insensitive_substring() {
    let list = [
        info("llvmpipe (LLVM 15.0.6, 256 bits)", wgpu::DeviceType::Cpu),
        info("NVIDIA H100", wgpu::DeviceType::DiscreteGpu),
    ];
    assert_eq!(choose_adapter(&list, Some("LLVMPIPE")).unwrap(), 0);
    assert_eq!(choose_adapter(&list, Some("h100")).unwrap(), 1);
    let err = choose_adapter(&list, Some("radeon"))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("\"radeon\"") && err.contains("llvmpipe") && err.contains("NVIDIA H100"),
        "{err}"
    );
}

#[test]
fn no_adapter_says_how_to_install_one() {
    let err = choose_adapter(&[], None).unwrap_err();
    assert!(matches!(err, GpuError::NoAdapter { .. }));
    assert!(
        err.to_string()
            .contains("apt-get install -y mesa-vulkan-drivers libvulkan1"),
        "{err}"
    );
}

#[test]
fn upload_and_read_back_round_trip() {
    let g = gpu();
    let data: Vec<f32> = (0..1001).map(|i| i as f32 * 0.5 - 3.0).collect();
    let t = g.upload("ramp", &[7, 143], &data).unwrap();
    assert_eq!(t.shape(), &[7, 143]);
    assert_eq!(g.read_f32(&t).unwrap(), data);
    let wrong = g
        .upload("short", &[10], &data[..9])
        .unwrap_err()
        .to_string();
    assert!(wrong.contains("tensor short"), "{wrong}");
}

#[test]
fn recorder_batches_copy_zero_and_dispatch_in_one_submit() {
    let g = gpu();
    let n = 700;
    let x: Vec<f32> = (0..n).map(|i| (i as f32 - 350.0) / 100.0).collect();
    let a = g.upload("a", &[n], &x).unwrap();
    let b = g.zeros("b", &[n], DType::F32).unwrap();
    let y = g.upload("y", &[n], &vec![5.0; n]).unwrap();
    let relu = elementwise::unary_forward(&g, Unary::Relu, &b, &y, Accumulate::Add).unwrap();
    let rb = Readback::new(&g, "y", y.byte_len()).unwrap();
    let mut rec = Recorder::new(&g);
    rec.copy(&a, &b).unwrap();
    rec.zero(&y);
    rec.dispatch(&relu); // y = 0 + relu(copy of a)
    rec.dispatch(&relu); // y += relu(a) again: accumulate mode
    rec.read_into(&y, &rb).unwrap();
    assert_eq!(rec.len(), 2);
    rec.submit().unwrap();
    let got = rb.read_f32(&g).unwrap();
    let want: Vec<f32> = x.iter().map(|v| 2.0 * v.max(0.0)).collect();
    assert_eq!(got, want);
    // The staging buffer is reusable.
    let mut rec = Recorder::new(&g);
    rec.zero(&y);
    rec.read_into(&y, &rb).unwrap();
    rec.submit().unwrap();
    assert!(rb.read_f32(&g).unwrap().iter().all(|&v| v == 0.0));
}

#[test]
fn a_timed_recorder_times_each_launch_in_one_submit_and_computes_the_same() {
    let g = gpu();
    assert!(
        g.has_timestamps(),
        "{} offers timestamp queries, so the device opens with them",
        g.info().name
    );
    // A product of 2·384³ FLOPs and a ReLU of 700 floats, twice each, alternating.
    let mm = matmul::Matmul::new(384, 384, 384);
    let ramp =
        |len: usize| -> Vec<f32> { (0..len).map(|i| ((i % 97) as f32 - 48.0) / 50.0).collect() };
    let a = g.upload("a", &[mm.a_len()], &ramp(mm.a_len())).unwrap();
    let b = g.upload("b", &[mm.b_len()], &ramp(mm.b_len())).unwrap();
    let c = g.zeros("c", &[mm.c_len()], DType::F32).unwrap();
    let product = mm.forward(&g, &a, &b, &c, Accumulate::Overwrite).unwrap();
    let x = g.upload("x", &[700], &ramp(700)).unwrap();
    let y = g.zeros("y", &[700], DType::F32).unwrap();
    let relu = elementwise::unary_forward(&g, Unary::Relu, &x, &y, Accumulate::Add).unwrap();
    let run = |timed: Option<&Timestamps>| {
        g.write(&y, &[0.0f32; 700]).unwrap();
        let mut rec = match timed {
            Some(stamps) => Recorder::timed(&g, stamps),
            None => Recorder::new(&g),
        };
        for d in [&relu, &product, &relu, &product] {
            rec.dispatch(d);
        }
        let launches = rec.timed_launches();
        rec.submit().unwrap();
        g.wait().unwrap();
        (launches, g.read_f32(&c).unwrap(), g.read_f32(&y).unwrap())
    };
    let (untimed, c_plain, y_plain) = run(None);
    assert_eq!(untimed, 0);
    let stamps = Timestamps::new(&g, 4).unwrap();
    let (launches, c_timed, y_timed) = run(Some(&stamps));
    assert_eq!(launches, 4);
    assert_eq!(
        c_timed, c_plain,
        "timing a launch changes nothing it computes"
    );
    assert_eq!(y_timed, y_plain);
    let t = stamps.read(&g, 4).unwrap();
    for (i, w) in t.windows(2).enumerate() {
        assert!(
            w[1].start_ns >= w[0].end_ns,
            "launch {} starts before launch {i} ends: {t:?}",
            i + 1
        );
    }
    let (relus, products) = (
        t[0].duration_ns() + t[2].duration_ns(),
        t[1].duration_ns() + t[3].duration_ns(),
    );
    assert!(
        products > 5.0 * relus && relus > 0.0,
        "the 113-MFLOP products ({products} ns) take far longer than the 700-float ReLUs \
         ({relus} ns; lavapipe: ~0.4 ms a launch against ~10 ms): {t:?}"
    );
    // More launches than the timestamps hold: refused at the submit, saying so.
    let one = Timestamps::new(&g, 1).unwrap();
    let mut rec = Recorder::timed(&g, &one);
    rec.dispatch(&relu);
    rec.dispatch(&relu);
    let err = rec.submit().unwrap_err().to_string();
    assert!(err.contains("2 launches") && err.contains("for 1"), "{err}");
    assert!(
        stamps.read(&g, 5).is_err(),
        "reading past the capacity is refused"
    );
}

#[test]
fn each_pipeline_is_compiled_once_per_device() {
    let g = gpu();
    let x = g.zeros("x", &[10], DType::F32).unwrap();
    let y = g.zeros("y", &[10], DType::F32).unwrap();
    let z = g.zeros("z", &[10], DType::F32).unwrap();
    assert_eq!(g.pipeline_count(), 0);
    for _ in 0..3 {
        elementwise::unary_forward(&g, Unary::Tanh, &x, &y, Accumulate::Overwrite).unwrap();
        elementwise::unary_forward(&g, Unary::Tanh, &y, &z, Accumulate::Overwrite).unwrap();
    }
    assert_eq!(g.pipeline_count(), 1);
    elementwise::unary_forward(&g, Unary::Sigmoid, &x, &y, Accumulate::Overwrite).unwrap();
    assert_eq!(g.pipeline_count(), 2);
}

#[test]
fn mismatched_or_aliased_tensors_are_rejected_by_name() {
    let g = gpu();
    let x = g.zeros("x", &[10], DType::F32).unwrap();
    let y = g.zeros("y", &[11], DType::F32).unwrap();
    let err = elementwise::unary_forward(&g, Unary::Relu, &x, &y, Accumulate::Overwrite)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("tensor x") && err.contains("11 elements"),
        "{err}"
    );
    let err = elementwise::unary_forward(&g, Unary::Relu, &x, &x, Accumulate::Overwrite)
        .unwrap_err()
        .to_string();
    assert!(err.contains("distinct"), "{err}");
    let view = x.reshaped(&[2, 5]).unwrap();
    assert_eq!(view.shape(), &[2, 5]);
    assert!(x.reshaped(&[3, 3]).is_err());
}

#[test]
fn subgroup_matmul_follows_the_device_and_can_be_switched_off() {
    let g = gpu();
    let info = |subgroups: Option<&str>| {
        let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_iastgcn"));
        cmd.arg("info").env_remove(SUBGROUPS_ENV);
        if let Some(v) = subgroups {
            cmd.env(SUBGROUPS_ENV, v);
        }
        let out = cmd.output().unwrap();
        assert!(out.status.success(), "{out:?}");
        String::from_utf8(out.stdout).unwrap()
    };
    let default = info(None);
    let expected = if matmul::subgroup_kernel_available(&g) {
        "matmul_subgroup"
    } else {
        "(matmul)"
    };
    assert!(default.contains(expected), "{default}");
    // Lavapipe on 256-bit vectors (CI) has 8-lane subgroups: the kernel must be in use.
    if g.info().name.contains("llvmpipe") && g.info().name.contains("256 bits") {
        assert_eq!(g.subgroup_size(), Some(8));
        assert!(default.contains("matmul_subgroup"), "{default}");
    }
    let off = info(Some("0"));
    assert!(off.contains("8x8 blocks per invocation (matmul)"), "{off}");
}

#[test]
fn smoke_check_compares_every_kernel_output_with_the_reference() {
    let g = gpu();
    let options = SmokeOptions {
        seed: 3,
        rows: 28,
        channels: 8,
    };
    let rows = smoke(&g, &options).unwrap();
    let names: Vec<&str> = rows.iter().map(|r| r.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "matmul forward",
            "matmul backward dX",
            "matmul backward dW",
            "batch-summed dW",
            "batch-summed row",
            "layernorm y",
            "layernorm dX",
            "layernorm dgamma",
            "layernorm dbeta",
            "gate H",
            "gate dF",
            "gate dG",
            "removal",
            "fft 2-D forward"
        ]
    );
    for r in &rows {
        assert!(r.pass, "{}: {}", r.name, r.worst);
        assert!(r.worst.ratio <= 1.0 && r.worst.abs_err.is_finite(), "{r:?}");
        assert!(r.seconds > 0.0, "{r:?}");
    }
    assert_eq!(rows[0].group, "matmul [28,8]x[8,8] fwd+bwd");
    assert_eq!(
        rows[0].flops,
        Some(3.0 * matmul::Matmul::new(28, 8, 8).flops())
    );
    assert!(!rows[0].includes_compile && rows[11].includes_compile);
    assert_eq!(SmokeOptions::default().rows, 1400);
}

#[test]
fn smoke_command_prints_the_rows_and_succeeds() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_iastgcn"))
        .args(["smoke", "--rows", "28", "--channels", "8"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("matmul backward dW"), "{text}");
    assert!(
        text.contains("all kernels match the CPU reference"),
        "{text}"
    );
}
