//! The IASTGCN network: configuration, parameter table, GPU schedule, f64 reference.

pub mod checkpoint;
pub mod config;
pub mod conv_lstm;
mod cpu;
pub mod dense;
pub mod error;
mod exact;
pub mod flops;
mod head;
pub mod memory;
pub mod native;
pub mod params;
pub mod predictor;
pub mod recurrent;
pub mod reference;

pub use checkpoint::{Checkpoint, CheckpointError, Normalization};
pub use config::{Family, ModelConfig, Variant};
pub use params::{
    check_parameter_count, graph_basis, graph_mixing, param_specs, Init, ParamSpec, Parameters,
    MAX_PARAMETERS,
};

pub mod block;
pub mod network;
pub mod schedule;

pub use cpu::product_for_bench;
pub use error::ModelError;
pub use native::{NativeAdam, NativeForward, NativeStepShape, NativeTraining};
pub use network::{Network, Pass};
pub use predictor::{Backend, Features, Predictor, Residual};
pub use schedule::{Profile, StepTime, Timing};
