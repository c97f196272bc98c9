//! A controller loop: load a checkpoint once, then each control tick push the raw sensor
//! values and read the residual to compensate. The same loop in C
//! (`examples/c/controller.c`) and Python (`examples/python/controller.py`) prints the
//! same lines, bit for bit; tests/c_abi.rs and the pytest suite check it.
//!
//! ```text
//! cargo run --release --example controller -- MODEL.safetensors [TICKS]
//! ```
//!
//! The sensor values are synthetic (a triangle wave per node, some nodes sampled only
//! every few ticks: NaN in between), computed with exact operations so that every
//! language gets the same doubles. Each line gives the residual in µm and mdeg and, after
//! the bar, the bits of its six doubles in hex.

use iastgcn::compensate::SensorPredictor;
use iastgcn::model::{Checkpoint, Residual};

/// The control period of the twin's recordings, s.
const DT: f64 = 0.02;

/// Node `node`'s sensor value at tick `tick`, or NaN when it has no new sample.
fn sensor(node: usize, tick: usize) -> f64 {
    if !tick.is_multiple_of(1 + node % 4) {
        return f64::NAN;
    }
    let phase = (tick * (node + 1) * 7 + node * 13) % 200;
    let triangle = (phase as f64 - 100.0).abs() / 100.0;
    20.0 + node as f64 + 0.5 * triangle
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let path = args
        .next()
        .ok_or("usage: controller MODEL.safetensors [TICKS]")?;
    let ticks: usize = match args.next() {
        Some(t) => t.parse()?,
        None => 60,
    };
    // Everything is allocated and warmed up here, once.
    let checkpoint = Checkpoint::load(path.as_ref())?;
    let mut predictor = SensorPredictor::native(&checkpoint, DT)?;
    let c = predictor.predictor().config().clone();
    println!(
        "nodes {} features {} window {}",
        c.nodes, c.features, c.window
    );
    let mut frame = vec![0.0; c.nodes];
    for tick in 0..ticks {
        for (node, v) in frame.iter_mut().enumerate() {
            *v = sensor(node, tick);
        }
        predictor.push(&frame)?;
        if let Some(r) = predictor.predict_latest()? {
            println!("{}", line(tick, &r));
        }
    }
    Ok(())
}

/// One output line: the residual, then its bits.
fn line(tick: usize, r: &Residual) -> String {
    let bits: Vec<String> = r.iter().map(|v| format!("{:016x}", v.to_bits())).collect();
    format!(
        "tick {tick:4}  {:9.3} {:9.3} {:9.3} um  {:9.3} {:9.3} {:9.3} mdeg | {}",
        r[0],
        r[1],
        r[2],
        r[3],
        r[4],
        r[5],
        bits.join(" ")
    )
}
