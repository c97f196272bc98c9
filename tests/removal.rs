//! The pad's removal (`ops::removal`): the WGSL kernel against the f64 reference on random
//! ticks (tilted pads, the map's edges, batches that split), and a polishing walk on the
//! twin with its removal laid by the kernel against the same walk on the native path.

use std::sync::Arc;

use iastgcn::compensate::online::Feedback;
use iastgcn::ops::removal::{Accumulator, Tick};
use iastgcn::polish::{draw_surface, HeightMap, Pad, Polisher, PoseSource, Setup, StartingPoint};
use iastgcn::robot::{Geometry, Robot};
use iastgcn::testing::{compare, gpu, Tolerance};
use iastgcn::twin::{draw_machine, PathKind};
use rand::{RngExt, SeedableRng};

/// Random ticks over (and a little beyond) a map of side `extent` mm: pressures and
/// gradients of the size the pad meets (a tilt of a few mrad on a 0.2 N/mm³ backing),
/// control ticks of 20 ms.
fn ticks(count: usize, extent: f64, seed: u64) -> Vec<Tick> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..count)
        .map(|_| Tick {
            centre: [
                rng.random_range(-0.6..0.6) * extent,
                rng.random_range(-0.6..0.6) * extent,
            ],
            force: rng.random_range(35.0..140.0),
            gradient: [rng.random_range(-1e-3..1e-3), rng.random_range(-1e-3..1e-3)],
            seconds: 0.02,
        })
        .collect()
}

/// The kernel's removed depth against the reference's, on maps that fill their tiles and
/// maps that do not, in one batch and in many.
#[test]
fn the_kernel_lays_what_the_reference_removes() {
    let g = Arc::new(gpu());
    for (n, pitch, capacity, count) in [(64, 1.0, 1000, 600), (75, 0.8, 7, 200), (40, 2.0, 1, 30)] {
        let extent = n as f64 * pitch;
        // The glass's rim within the pad's reach of most ticks: its pressure changes
        // along the orbit there.
        let footprint = Pad::default().footprint(0.45 * extent);
        // A disc of glass short of the map's edge, as the mirror's.
        let half = 0.5 * n as f64;
        let glass: Vec<bool> = (0..n * n)
            .map(|i| {
                let (r, c) = ((i / n) as f64 + 0.5 - half, (i % n) as f64 + 0.5 - half);
                r.hypot(c) <= 0.45 * n as f64
            })
            .collect();
        let ticks = ticks(count, extent, n as u64);
        let rim = ticks
            .iter()
            .filter(|t| footprint.touches_rim(t.centre))
            .count();
        assert!(rim > count / 4, "{rim} of {count} ticks reach the rim");
        let mut want = vec![0.0; n * n];
        for t in &ticks {
            footprint.remove_tick(n, pitch, &glass, t, &mut want);
        }
        let mut acc = Accumulator::new(&g, n, pitch, &glass, footprint, capacity).unwrap();
        // Twice from the same accumulator: `finish` starts again from zero.
        for round in 0..2 {
            for t in &ticks {
                acc.push(t).unwrap();
            }
            let mut got = vec![0.0; n * n];
            assert_eq!(acc.finish(&mut got).unwrap(), count);
            let peak = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(peak > 1.0, "the ticks remove something: {peak} nm");
            compare(
                &format!("removal n = {n}, batch {capacity}, round {round}"),
                &got,
                &want,
                Tolerance {
                    abs: 1e-4 * peak,
                    rel: 1e-4,
                },
            )
            .map(|w| eprintln!("{w}"))
            .unwrap_or_else(|e| panic!("{e}"));
            for (i, (w, m)) in want.iter().zip(&glass).enumerate() {
                if !m {
                    assert_eq!(got[i], 0.0, "pixel {i} is off the glass");
                    assert_eq!(*w, 0.0);
                }
            }
        }
    }
}

/// A walk on the twin (the nominal controller, a coarse map) with the removal laid by the
/// kernel leaves the glass the native path leaves, within f32's rounding.
#[test]
fn a_polishing_walk_on_the_kernel_matches_the_native_walk() {
    let geometry = Geometry::load_or_default(None).unwrap();
    let machine = draw_machine(geometry.clone(), 1);
    let nominal = Robot::nominal(geometry);
    let mut setup = Setup::new(PathKind::Grid);
    setup.pitch = 6.0;
    let mut polisher = Polisher::new(setup).unwrap();
    let start = draw_surface(
        polisher.grid,
        polisher.mirror.radius(),
        &polisher.clear,
        &StartingPoint::default(),
        3,
    );
    let dwell = polisher.plan(&polisher.measure(&start, 11)).unwrap();
    let walk = |polisher: &Polisher| -> HeightMap {
        let mut surface = start.clone();
        polisher
            .polish(
                &machine,
                &nominal,
                machine.cold(),
                Feedback::None,
                polisher.feed(&dwell).unwrap(),
                21,
                PoseSource::True,
                &mut surface,
                |_| {},
            )
            .unwrap();
        surface
    };
    let native = walk(&polisher);
    assert_eq!(polisher.removal_device(), "native CPU (f64)");
    polisher.remove_with_kernel(Some(Arc::new(gpu())));
    assert!(polisher.removal_device().ends_with("(WGSL, f32)"));
    let kernel = walk(&polisher);
    let removed: Vec<f64> = start
        .values
        .iter()
        .zip(&native.values)
        .map(|(a, b)| a - b)
        .collect();
    let peak = removed.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(peak > 50.0, "the walk removes glass: {peak} nm");
    compare(
        "the walk's glass, kernel against native",
        &kernel.values,
        &native.values,
        Tolerance {
            abs: 1e-4 * peak,
            rel: 1e-5,
        },
    )
    .map(|w| eprintln!("{w}"))
    .unwrap_or_else(|e| panic!("{e}"));
}
