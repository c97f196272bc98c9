//! Train and evaluate from Rust (`cargo run --release --example train_and_evaluate`): the
//! twin records a calibration set and three polishing runs, the EKF calibrates, a small
//! IASTGCN trains on the residuals, and its test MAE is printed beside the training mean.

use iastgcn::calibrate::{calibrate, file, EkfConfig};
use iastgcn::data::{read_measurements, record_calibration_set, record_run, DataSources};
use iastgcn::error::{Error, Result};
use iastgcn::gpu::Device;
use iastgcn::progress::Silent;
use iastgcn::robot::{Geometry, Robot};
use iastgcn::train::{build_dataset, train, RunConfig};
use iastgcn::twin::{draw_machine, PathKind, PathParams, RunInfo};

fn main() -> Result<()> {
    let dir = std::env::temp_dir().join("iastgcn-example");
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    // The default adapter, or the native CPU on a machine without a GPU driver.
    let device = Device::open(None)?;
    let machine = draw_machine(Geometry::default_asset(), 1); // the hidden truth
    let nominal = Robot::nominal(Geometry::default_asset());

    // Geometric calibration from 80 poses measured by the tracker.
    let set = dir.join("calibration_set.csv");
    let info = RunInfo::calibration(101);
    record_calibration_set(&machine, &nominal, 80, &info, &set, &mut Silent)?;
    let measurements = read_measurements(&set)?;
    let cal = calibrate(&nominal, &measurements, &EkfConfig::default())?;
    let calibration = dir.join("calibration.toml");
    file::save(&calibration, &cal, measurements.len())?;
    let controller = nominal.with_errors(cal.errors);

    // One session of three 45-second polishing runs under the calibrated controller.
    let (mut state, mut recordings) = (machine.cold(), Vec::new());
    for (i, kind) in PathKind::TRAINING.into_iter().enumerate() {
        let csv = dir.join(format!("{}.csv", kind.name()));
        let run = RunInfo::polishing(kind, &PathParams::default(), 45.0, 201 + i as u64);
        state = record_run(&machine, &controller, run, state, &csv, None, &mut Silent)?.end;
        recordings.push(csv);
    }

    // The demo's small model, a few epochs; the best checkpoint lands in `dir`.
    let mut config = RunConfig::demo();
    config.train.max_epochs = 4;
    let sources = DataSources::new(recordings, calibration);
    let (graph, data) = build_dataset(&sources, &config, None)?;
    let out = dir.join("model.safetensors");
    let trained = train(&device, &data, &graph, &config, &out, None, &mut Silent)?;
    println!("best validation loss {:.4}", trained.best_val);
    for t in &trained.test {
        let (m, b) = (&t.model, &t.training_mean);
        println!(
            "{}: test MAE {:.1} µm / {:.1} mdeg (training mean {:.1} / {:.1})",
            t.recording, m.pos_mae, m.att_mae, b.pos_mae, b.att_mae
        );
    }
    Ok(())
}
