//! `train::predict_recordings` windows the recordings itself (`Prepared::window`): its
//! test-block windows are the dataset's test windows, their labels the dataset's, and its
//! predictions those of the same `Predictor` on the dataset's standardised windows.

mod common;

use iastgcn::data::DataSources;
use iastgcn::model::{Checkpoint, Features, Parameters, Predictor};
use iastgcn::train::{
    build_dataset, normalization, predict_recordings, PredictOptions, RunConfig, Subset,
};

#[test]
fn predict_recordings_sees_the_datasets_test_windows() {
    let dir = std::env::temp_dir().join(format!("iastgcn-predict-windows-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let (calibration, recordings) = common::twin_session(&dir, &["grid", "hilbert"], 30.0);
    let sources = DataSources {
        recordings,
        calibration,
        graph: None,
        robot: None,
    };
    let mut config = RunConfig::demo();
    config.model.window = 16;
    config.model.channels = 4;
    config.data.stride = 5;
    let (graph, data) = build_dataset(&sources, &config, None).unwrap();
    let ck = Checkpoint {
        parameters: Parameters::init(&config.model, 3),
        graph,
        normalization: normalization(&data.normalization),
        config: config.model.clone(),
    };
    let device = iastgcn::gpu::Device::from(iastgcn::testing::gpu());
    let options = PredictOptions {
        stride: config.data.stride,
        subset: Subset::Test,
        batch: 8,
    };
    let predicted = predict_recordings(&device, &ck, &sources, &options).unwrap();
    let mut native = Predictor::native(&ck).unwrap();
    let len = data.window_len();
    for (r, rec) in predicted.iter().enumerate() {
        let test: Vec<usize> = data.split_ranges()[2]
            .clone()
            .filter(|&i| data.windows[i].recording == r)
            .collect();
        // Each prediction is reported at the row it is for: the window's end, or (the
        // demo's models look ahead) the row after it.
        let ahead = config.model.look_ahead;
        let ends: Vec<usize> = test.iter().map(|&i| data.windows[i].end + ahead).collect();
        let rows: Vec<usize> = rec.windows.iter().map(|w| w.row).collect();
        assert_eq!(rows, ends, "{}: the test block's label rows", rec.recording);
        assert!(!ends.is_empty());
        for (w, &i) in rec.windows.iter().zip(&test) {
            assert_eq!(
                w.truth,
                Some(data.labels[i]),
                "{} row {}",
                rec.recording,
                w.row
            );
            let mut want = Vec::new();
            native
                .predict_batch(&data.x[i * len..][..len], Features::Standardised, &mut want)
                .unwrap();
            // The device's and the native forward's f32 sums agree to 1e-4 on the
            // network's own (standardised) scale; the outputs are de-standardised (µm,
            // mdeg, label SDs up to about 90), so the tolerance is 1e-4 of the label SD
            // plus 1e-4 of the output (an output near 0 µm still carries the SD's error).
            let label_std = &ck.normalization.label_std;
            for ((a, b), s) in w.predicted.iter().zip(want[0]).zip(label_std) {
                assert!(
                    (a - b).abs() <= 1e-4 * (s + b.abs()),
                    "{a} vs {b} at row {}",
                    w.row
                );
            }
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_batch_too_large_for_the_adapter_names_the_setting_and_what_fits() {
    let too_large = iastgcn::gpu::GpuError::TooLarge {
        tensor: "x".into(),
        bytes: 4096 * 1000,
        limit: 600 * 1000,
        limit_name: "max_buffer_size",
    };
    let err = iastgcn::train::batch_error(too_large, 4096);
    match err.root() {
        iastgcn::error::Error::Setting {
            setting: "predict.batch",
            message,
        } => assert!(
            message.starts_with("4096 windows: ") && message.ends_with("; 512 fit"),
            "{message}"
        ),
        other => panic!("{other}"),
    }
}
