//! `iastgcn reproduce`: the paper's protocol on the twin, at any size, over several
//! training seeds. The work splits into independent jobs, one per model and seed; each
//! job trains (resuming from its state file after an interruption) and refines one model
//! and then writes a job record. Jobs can be spread over processes or machines with
//! `--shard k/n`; a final run without a shard finds every job done and writes the
//! report (Tables III and V per seed, and over seeds with the paired comparisons).

mod protocol;
mod report;
mod run;

pub use protocol::{Job, Protocol};
pub use run::{reproduce, Outcome};
