//! Online compensation in the twin: the controller loop that streams sensor values into a
//! [`crate::model::Predictor`] and corrects the commanded pose (`online`), held-out runs
//! and sessions (`held_out`), and the error budget of a run by source (`budget`). The
//! experiments that train models and score them this way live in [`crate::experiment`].

pub mod budget;
pub mod held_out;
pub mod online;
