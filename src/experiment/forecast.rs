//! What the demo will do and about how long it will take on this machine, said before it
//! starts: a second of IASTGCN training steps on the native CPU path (training is most
//! of the demo's time there) against the same steps on the machine whose demo time is
//! known ([`REFERENCE`]), and the demo's stages at that ratio.

use std::time::{Duration, Instant};

use crate::error::Result;
use crate::graph::Graph;
use crate::model::{NativeAdam, NativeStepShape, NativeTraining, Parameters};
use crate::train::RunConfig;

/// The machine the forecast is scaled from: the 2-core development machine (lavapipe,
/// nothing beside it) running `iastgcn demo` with its defaults (docs/results.md "How long
/// it takes"); its figures are remeasured when the demo changes.
pub struct Reference {
    /// Milliseconds per native training step of [`probe`] there.
    pub step_ms: f64,
    /// Seconds from the start of `iastgcn demo` to the first seed's result.
    pub first_result_s: f64,
    /// Seconds of the whole `iastgcn demo`.
    pub demo_s: f64,
    /// The training seeds it ran.
    pub seeds: usize,
    /// When and where it was measured.
    pub measured: &'static str,
}

/// The reference run ([`Reference`]).
pub const REFERENCE: Reference = Reference {
    step_ms: 6.1,
    first_result_s: 108.0,
    demo_s: 244.0,
    seeds: 2,
    measured: "2026-11-30, the 2-core development machine, the demo looking ahead",
};

/// How long a probe runs its steps.
const PROBE_TIME: Duration = Duration::from_millis(800);

/// Milliseconds per native training step (forward, loss and every gradient, no update)
/// of a freshly initialised model of `config` on a batch of its size of made-up windows,
/// on the threads training uses: the mean over the steps that fit in under a second,
/// after one warm-up step.
pub fn probe(config: &RunConfig) -> Result<f64> {
    let (model, t, batch) = (&config.model, &config.train, config.train.batch);
    let graph = Graph::default_for(model.look_ahead);
    let shape = NativeStepShape {
        batch,
        group: 1,
        seed: 1,
        penalty: t.attitude_penalty,
        threads: t.native_threads(),
    };
    let adam = NativeAdam {
        beta1: t.beta1,
        beta2: t.beta2,
        eps: t.adam_eps,
        weight_decay: t.weight_decay,
    };
    let mut train = NativeTraining::new(model, &graph, shape, adam)?;
    train.load_parameters(&Parameters::init(model, 1))?;
    let len = model.nodes * model.features * model.window;
    // Deterministic, varied inputs: the step's time does not depend on the values.
    let x: Vec<f32> = (0..batch * len)
        .map(|i| ((i * 7919) % 2003) as f32 / 1001.5 - 1.0)
        .collect();
    let y: Vec<f32> = (0..batch * model.outputs)
        .map(|i| ((i * 104_729) % 1009) as f32 / 504.5 - 1.0)
        .collect();
    train.gradients(&x, &y, 0)?;
    let began = Instant::now();
    let mut steps = 0u32;
    while steps < 3 || began.elapsed() < PROBE_TIME {
        train.gradients(&x, &y, steps + 1)?;
        steps += 1;
    }
    Ok(began.elapsed().as_secs_f64() * 1e3 / f64::from(steps))
}

/// The forecast for a machine whose probe took `step_ms`: seconds to the first seed's
/// result and to the end, at the reference's times scaled by the ratio of the steps.
pub fn forecast(step_ms: f64) -> (f64, f64) {
    let ratio = step_ms / REFERENCE.step_ms;
    (REFERENCE.first_result_s * ratio, REFERENCE.demo_s * ratio)
}

/// Minutes as a reader wants them: `about 7 min`, `under a minute`.
pub fn minutes(seconds: f64) -> String {
    if seconds < 60.0 {
        "under a minute".into()
    } else {
        format!("about {:.0} min", seconds / 60.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_forecast_scales_the_reference_by_the_steps() {
        let (first, all) = forecast(2.0 * REFERENCE.step_ms);
        assert_eq!(first, 2.0 * REFERENCE.first_result_s);
        assert_eq!(all, 2.0 * REFERENCE.demo_s);
        const { assert!(REFERENCE.first_result_s < REFERENCE.demo_s) };
        assert_eq!(minutes(30.0), "under a minute");
        assert_eq!(minutes(450.0), "about 8 min");
    }

    #[test]
    fn a_probe_times_real_steps_of_the_demos_network() {
        let mut config = RunConfig::demo();
        config.train.batch = 8;
        let ms = probe(&config).unwrap();
        assert!(ms.is_finite() && ms > 0.0, "{ms} ms per step");
    }
}
