//! The mirror's heavy parts (issue 52, docs/polishing.md "Compute"): the dwell solve and
//! one control tick's removal, on 512 × 512 and 1024 × 1024 maps of the twin's mirror
//! (the raster path at its held-out placement, a starting surface of seed 1 as the
//! interferometer measures it). The solve is timed as `Polisher::plan_at` at 100 N runs
//! it; a tick's removal as `Pad::remove` at the pad's pose with the nominal contact,
//! centres spread over the glass (criterion's "thrpt" column is ticks per second), on the
//! native f64 path (`removal_tick`) and, where a wgpu adapter is there, through the WGSL
//! kernel (`removal_tick_wgsl`: the ticks binned and sent in one batch of 1000, the kernel
//! waited for). Where an adapter is there the dwell solve runs again with its FFTs as
//! WGSL kernels (`dwell_solve_wgsl`, `ops::fft`; on a CPU adapter at 512² only).
//!
//! It also writes each size's dwell problem with the engine's solution to
//! `target/bench-polish/dwell_<n>.safetensors`: `make bench-polish` hands those to the
//! NumPy implementation of the same solver (benches/numpy/dwell.py), which checks that it
//! finds the same seconds and times itself on the same cores in the same call.

use std::sync::Arc;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use iastgcn::gpu::Gpu;
use iastgcn::ops::removal::{Accumulator, Tick};
use iastgcn::polish::{draw_surface, HeightMap, Pad, Polisher, Setup, StartingPoint};
use iastgcn::twin::PathKind;

/// The twin's raster polisher on an `n × n` map, and a measured starting surface.
fn problem(n: usize) -> (Polisher, HeightMap) {
    let pad = Pad::default();
    let radius = iastgcn::twin::Mirror::default().radius();
    let mut setup = Setup::new(PathKind::Grid);
    // `Grid::covering` takes the smallest even grid covering the mirror and the pad's
    // reach: a pitch a little coarser than the exact fit gives n.
    setup.pitch = 2.0 * (radius + pad.reach()) / (n as f64 - 0.5);
    let polisher = Polisher::new(setup).expect("the bench's set-up");
    assert_eq!(polisher.grid.n, n, "pitch {} mm", polisher.setup.pitch);
    let surface = draw_surface(
        polisher.grid,
        radius,
        &polisher.clear,
        &StartingPoint::default(),
        1,
    );
    let measured = polisher.measure(&surface, 7);
    (polisher, measured)
}

fn bench(c: &mut Criterion) {
    let out = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/bench-polish");
    std::fs::create_dir_all(&out).unwrap();
    let mut solve = c.benchmark_group("dwell_solve");
    solve.sample_size(10);
    solve.measurement_time(Duration::from_secs(20));
    let mut ticks = Vec::new();
    for n in [512, 1024] {
        let (mut polisher, measured) = problem(n);
        let file = out.join(format!("dwell_{n}.safetensors"));
        let dwell = polisher.write_dwell_problem(&measured, &file).unwrap();
        eprintln!(
            "dwell_solve/{n}: pitch {:.3} mm, {} segments, planned RMS {:.2} nm (from {:.2}), gamma {}; wrote {}",
            polisher.setup.pitch,
            dwell.seconds.len(),
            dwell.planned.rms,
            measured.figure(&polisher.clear).rms,
            dwell.gamma,
            file.display()
        );
        solve.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| polisher.plan_at(&measured, 100.0).unwrap())
        });
        ticks.push((n, polisher, measured));
    }
    solve.finish();

    let mut removal = c.benchmark_group("removal_tick");
    let per_iter = 1000;
    removal.throughput(Throughput::Elements(per_iter));
    for (n, polisher, measured) in &ticks {
        let pad = polisher.setup.pad;
        let radius = polisher.mirror.radius();
        let contact = pad.contact([0.0, 0.0], 100.0);
        // Centres on a golden-angle spiral over the glass, one per tick.
        let centres = spiral(radius, per_iter);
        let mut map = measured.clone();
        removal.bench_with_input(BenchmarkId::from_parameter(n), n, |b, _| {
            b.iter(|| {
                for &centre in &centres {
                    pad.remove(&mut map, &polisher.glass, radius, centre, &contact, 0.02);
                }
            })
        });
    }
    removal.finish();

    // The same ticks through the WGSL kernel, where an adapter is there: each iteration
    // sends its 1000 ticks (binned on the host) and waits for the kernel; the removed
    // depth stays on the device (a walk reads it back once at its end).
    let Ok(gpu) = Gpu::new() else {
        eprintln!("removal_tick_wgsl: no GPU adapter, skipped");
        return;
    };
    let gpu = Arc::new(gpu);
    eprintln!("removal_tick_wgsl on {}", gpu.info().name);
    let mut kernel = c.benchmark_group("removal_tick_wgsl");
    kernel.throughput(Throughput::Elements(per_iter));
    kernel.sample_size(10);
    for (n, polisher, _) in &ticks {
        let pad = polisher.setup.pad;
        let contact = pad.contact([0.0, 0.0], 100.0);
        let batch: Vec<Tick> = spiral(polisher.mirror.radius(), per_iter)
            .into_iter()
            .map(|centre| pad.tick(centre, &contact, 0.02))
            .collect();
        let mut acc = Accumulator::new(
            &gpu,
            *n,
            polisher.grid.pitch,
            &polisher.glass,
            pad.footprint(polisher.mirror.radius()),
            per_iter as usize,
        )
        .unwrap();
        kernel.bench_with_input(BenchmarkId::from_parameter(n), n, |b, _| {
            b.iter(|| {
                for t in &batch {
                    acc.push(t).unwrap();
                }
                gpu.wait().unwrap();
            })
        });
    }
    kernel.finish();

    // The dwell solve with its FFTs on the adapter (ops::fft). On a CPU adapter only the
    // 512 map: lavapipe takes tens of seconds per solve at 1024.
    let mut solve = c.benchmark_group("dwell_solve_wgsl");
    solve.sample_size(10);
    solve.measurement_time(Duration::from_secs(20));
    for (n, polisher, measured) in &mut ticks {
        if *n > 512 && gpu.is_software() {
            eprintln!("dwell_solve_wgsl/{n}: skipped on a CPU adapter");
            continue;
        }
        let cpu = polisher.plan_at(measured, 100.0).unwrap();
        polisher.solve_with_kernels(Some(gpu.clone())).unwrap();
        let on_gpu = polisher.plan_at(measured, 100.0).unwrap();
        eprintln!(
            "dwell_solve_wgsl/{n}: planned RMS {:.4} nm (CPU {:.4}), gamma {} (CPU {})",
            on_gpu.planned.rms, cpu.planned.rms, on_gpu.gamma, cpu.gamma
        );
        solve.bench_with_input(BenchmarkId::from_parameter(*n), n, |b, _| {
            b.iter(|| polisher.plan_at(measured, 100.0).unwrap())
        });
        polisher.solve_with_kernels(None).unwrap();
    }
    solve.finish();
}

/// `count` centres on a golden-angle spiral over a disc of radius `radius`, mm.
fn spiral(radius: f64, count: u64) -> Vec<[f64; 2]> {
    (0..count)
        .map(|k| {
            let r = radius * ((k as f64 + 0.5) / count as f64).sqrt();
            let a = k as f64 * 2.399_963_229_728_653;
            [r * a.cos(), r * a.sin()]
        })
        .collect()
}

criterion_group! {
    name = benches;
    config = Criterion::default().without_plots();
    targets = bench
}
criterion_main!(benches);
