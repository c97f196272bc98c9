//! `iastgcn scale`: the scaling study (docs/results.md "Scaling study"). How much does
//! each model gain from more training data, and where does that stop? One training
//! session of three recordings is recorded at the largest size M; a job trains one model
//! with one seed (core stage, to early stopping) on the first `m / M` of each
//! recording's training block and stops early on the first `m / M` of its validation
//! block, so it sees what an `m`-minute session would have given it, while the test
//! blocks stay those of the M-minute recordings: every size is scored on the same test
//! windows (`0.1·M` minutes per path) and on the same held-out session in the twin,
//! against hidden truth. Jobs are resumable and shardable
//! as `reproduce`'s; the summary (`scale.csv`, `scale_summary.csv`, `scale.md`,
//! `scale.png`) is rewritten from every finished job after each one, so a study stopped
//! early still reports what it has. With a validation session (`Study::validation`)
//! every job is scored on one more held-out session, kept out of those tables, on which
//! `experiment::recommend`'s rule names the model to use at each size (`scale.md`
//! "Recommended model", `scale_validation.csv`).

mod markdown;
mod points;
mod records;
mod run;
mod study;
mod summary;

pub use crate::experiment::runner::Progress;
pub use records::{PathScore, ScaleRecord};
pub use run::scale;
pub use study::{ScaleJob, Study, PAPER_HILBERT_REMOVED};
pub use summary::write_summary;
