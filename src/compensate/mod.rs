//! Online compensation in the twin and the report of the paper's Tables III and V.

pub mod budget;
pub mod evaluate;
pub mod online;
pub mod report;
