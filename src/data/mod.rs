//! Recordings and datasets: the CSV formats of TWIN.md (and, in later slices,
//! resampling, filtering, features, windows and splits).

pub mod recording;

pub use recording::{
    read_calibration_set, write_calibration_set, CalibrationRow, DataError, Recording, Row,
    JOINT_COLUMNS, TRACKER_COLUMNS,
};
