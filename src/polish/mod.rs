//! The mirror: what compensation does to the glass (the paper's Table VI and
//! Figs. 12–14; docs/polishing.md). A simulated computer-controlled optical surfacing
//! stage on the twin: the starting surface error, the pad's influence function from its
//! true pose (Preston's law, a linear pressure under a tilted pad), the dwell-time solver,
//! and polishing iterations in which the twin's controller walks the planned feed while
//! the pad removes glass at every control tick and an interferometer measures the result.

mod dwell;
mod fft;
mod map;
mod pose_error;
mod process;
mod surface;
mod tif;

pub use dwell::{gaussian_average, Dwell, DwellSolver, PathRaster, GAMMAS};
pub use fft::{Convolver, Fft2};
pub use map::{Figure, Grid, HeightMap};
pub use pose_error::{
    walk, ErrorKind, Float, PoseError, Walked, SLOW_CORRELATION_S, SLOW_SMOOTHING_S, TICK_S,
};
pub use process::{Polisher, PoseSource, Setup, CLEAR_APERTURE, FORCE_RANGE};
pub use surface::{draw as draw_surface, StartingPoint};
pub use tif::{Contact, Pad};
