//! Online compensation in the twin and the report of the paper's Tables III and V; the
//! residual models of a serial arm (`arm`).

pub mod arm;
pub mod budget;
pub mod demo;
pub mod evaluate;
pub mod held_out;
pub mod machines;
pub mod online;
pub mod protocol;
pub mod report;
pub mod reproduce;
