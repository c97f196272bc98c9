//! The IASTGCN network: configuration, parameter table, GPU schedule, f64 reference.

pub mod config;
pub mod flops;
pub mod params;
pub mod reference;

pub use config::{ModelConfig, Variant};
pub use params::{graph_basis, param_specs, Init, ParamSpec, Parameters};

mod block;
pub mod network;
pub mod schedule;

pub use network::{ModelError, Network};
