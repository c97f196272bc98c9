//! How a long library call reports as it goes. The library never prints: it tells a
//! [`Reporter`] what it is doing, and the caller decides. The command line draws
//! progress bars and prints the notes; an embedding program passes [`Silent`] or its own
//! logger.

/// Receives the progress of a long call: tasks with a length (epochs, control ticks,
/// simulation steps), and notes (a summary line, a table row) for the user to read.
pub trait Reporter {
    /// A task of `len` units named `what` begins; it replaces any unfinished one.
    fn begin(&mut self, what: &str, len: u64) {
        let _ = (what, len);
    }
    /// The current task has done `pos` units; `message` says how it stands (may be empty).
    fn update(&mut self, pos: u64, message: &str) {
        let _ = (pos, message);
    }
    /// The current task has ended.
    fn end(&mut self) {}
    /// A line for the user: a stage heading, a summary or a row of a table.
    fn note(&mut self, line: &str) {
        let _ = line;
    }
}

/// Ignores everything.
///
/// ```
/// use iastgcn::progress::{Reporter, Silent};
/// let mut p = Silent;
/// p.begin("epochs", 10);
/// p.update(1, "loss 0.5");
/// p.end();
/// ```
#[derive(Clone, Copy, Debug, Default)]
pub struct Silent;

impl Reporter for Silent {}

/// Collects the notes (for tests and for callers that print them later).
#[derive(Clone, Debug, Default)]
pub struct Notes(pub Vec<String>);

impl Reporter for Notes {
    fn note(&mut self, line: &str) {
        self.0.push(line.to_string());
    }
}
