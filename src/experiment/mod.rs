//! The experiments on the twin and on serial arms, built on the pipeline: the protocol's
//! data and the fitting of one model (`protocol`), Tables III and V and the report folder
//! they go into (`evaluate`, `report/`), the demo over training seeds (`demo`), the
//! protocol over seeds in resumable, shardable jobs (`reproduce`), the merge of reproduce
//! folders of several twin machines (`machines`), the one runner of the resumable jobs of
//! `reproduce`, `scale` and `demo` (`runner`), what their jobs share (shards, pinned
//! setups, job records, TOML files: `jobs`), the scaling study of error against
//! training data (`scale`), the model recommended on a validation session
//! (`recommend`), the named recipes of the training data and the loop (`recipe`), a serial arm's residual models on held-out poses (`arm`), how a
//! calibration holds on a held-out stretch of a pose file (`block_study`), and the
//! independent runs of an evaluation on every core (`parallel`), models fitted one per
//! core with the bits of fitting them in turn (`side_by_side`), how long the demo
//! will take on this machine (`forecast`), the morning minute's adaptation measured on
//! held-out sessions (`morning`), how far a seed ensemble's spread tells how far to
//! trust its prediction (`confidence`), and the floor of a look-ahead oracle (`floor`).

pub mod arm;
pub mod block_study;
pub mod calibration;
pub mod campaign;
pub mod confidence;
pub mod demo;
pub mod evaluate;
pub mod floor;
pub mod forecast;
pub mod jobs;
pub mod machines;
pub mod morning;
mod parallel;
pub mod polish;
pub mod polish_sweep;
pub mod protocol;
pub mod recipe;
pub mod recommend;
pub mod report;
pub mod reproduce;
pub mod runner;
pub mod scale;
pub mod side_by_side;
