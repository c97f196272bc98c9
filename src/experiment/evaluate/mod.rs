//! The paper's tables on the twin: Table III (prediction accuracy on the held-out split
//! per trajectory and model) and Table V (pose error of held-out polishing runs: initial,
//! calibrated, compensated per model), the held-out sessions they are scored on, and the
//! models they score, and the report of `iastgcn evaluate`.

mod held_out;
mod models;
mod paper_tables;
mod report;

pub use held_out::{
    held_out_session, held_out_session_from, more_models, oracle_name, runs_at_a_time,
    session_start, table_v, HeldOutConfig, HeldOutResult, HeldOutSession, OpenLoopScore, Session,
    SessionOptions, MAX_HELD_OUT_SESSIONS,
};
pub use models::{ensemble, predictors, runs_on, LoopModel, NamedModel};
pub(crate) use paper_tables::{add_graph_mixing, tables};
pub use paper_tables::{
    evaluate, evaluate_models, predict_windows, report_evaluation, table_iii, Evaluated,
};
pub use report::evaluation_report;
