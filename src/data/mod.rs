//! Recordings and datasets: the CSV formats of docs/twin.md, causal preprocessing (hold,
//! low-pass, differences, entropy), windows and leakage-free splits.

pub mod arm_dataset;
pub mod arm_import;
pub mod arm_poses;
pub mod dataset;
pub mod features;
pub mod measurements;
pub mod recording;
pub mod simulated;
pub mod sources;
pub mod windows;

pub use dataset::{prepare, Dataset, DatasetError, Normalization, Prepared, FEATURES, OUTPUTS};
pub use features::FeatureConfig;
pub use measurements::{read_measurements, recording_measurements};
pub use recording::{
    calibration_set_csv, expected_channels, read_calibration_set, tracker_columns, tracker_pose,
    write_calibration_set, CalibrationRow, DataError, Recording, Row, JOINT_COLUMNS,
    TRACKER_COLUMNS,
};
pub use simulated::{
    record_calibration_set, record_corrected_run, record_run, Corrector, RecordedRun,
    MAX_CALIBRATION_POSES, MAX_RUN_SECONDS,
};
pub use sources::{DataSources, Inputs};
pub use windows::{split, window_ends, SplitMode, Splits, Window, WindowConfig};
