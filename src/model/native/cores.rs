//! How many OS threads a native pass may run on when several jobs share the machine.
//!
//! A native training step cuts its batch into a fixed number of shares (one per thread
//! the run was configured for, [`super::NativeStepShape::threads`]); each share's
//! gradient is summed in share order, so the bits depend on the shares, not on which
//! thread ran which. On its own a step runs each share on a thread of its own. When jobs
//! run side by side (the demo trains a seed's models two at a time), the job runner sets
//! a [`Cores`] budget on each worker thread: a job then owns the core it runs on and
//! borrows spare ones for a step (a worker that found no job left gives its core back),
//! so that the shares run on fewer threads while the machine is full and on every core
//! at the tail, with the same bits.

use std::cell::RefCell;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

/// The spare cores of a set of jobs that run side by side.
#[derive(Debug, Default)]
pub struct Cores {
    spare: AtomicUsize,
}

impl Cores {
    /// A budget with `spare` cores beyond those the jobs' own threads run on.
    pub fn new(spare: usize) -> Arc<Cores> {
        Arc::new(Cores {
            spare: AtomicUsize::new(spare),
        })
    }

    /// Gives one core back (a worker that has no job left).
    pub fn give_back(&self) {
        self.spare.fetch_add(1, Ordering::AcqRel);
    }

    /// Cores not lent now.
    pub fn spare(&self) -> usize {
        self.spare.load(Ordering::Acquire)
    }

    /// Takes up to `wanted` spare cores; returns how many were taken.
    fn take(&self, wanted: usize) -> usize {
        let mut now = self.spare.load(Ordering::Acquire);
        loop {
            let taken = now.min(wanted);
            if taken == 0 {
                return 0;
            }
            match self.spare.compare_exchange_weak(
                now,
                now - taken,
                Ordering::AcqRel,
                Ordering::Acquire,
            ) {
                Ok(_) => return taken,
                Err(seen) => now = seen,
            }
        }
    }
}

thread_local! {
    static BUDGET: RefCell<Option<Arc<Cores>>> = const { RefCell::new(None) };
}

/// Runs `f` with the calling thread's native passes drawing extra threads from `cores`
/// (the thread itself counts as the job's own core), then restores the thread's budget,
/// also when `f` panics.
pub fn with_cores<R>(cores: &Arc<Cores>, f: impl FnOnce() -> R) -> R {
    /// Puts the saved budget back when dropped.
    struct Restore(Option<Arc<Cores>>);
    impl Drop for Restore {
        fn drop(&mut self) {
            let saved = self.0.take();
            BUDGET.with(|b| *b.borrow_mut() = saved);
        }
    }
    let saved = BUDGET.with(|b| b.borrow_mut().replace(cores.clone()));
    let _restore = Restore(saved);
    f()
}

/// Whether the calling thread's passes share the machine with other jobs (a budget is
/// set on it).
pub(crate) fn shared() -> bool {
    BUDGET.with(|b| b.borrow().is_some())
}

/// The threads one pass may use now, returned to the budget when dropped.
pub(crate) struct Lease {
    threads: usize,
    borrowed: usize,
    cores: Option<Arc<Cores>>,
}

impl Lease {
    /// Threads to run on (at least 1).
    pub(crate) fn threads(&self) -> usize {
        self.threads
    }
}

impl Drop for Lease {
    fn drop(&mut self) {
        if let Some(cores) = &self.cores {
            cores.spare.fetch_add(self.borrowed, Ordering::AcqRel);
        }
    }
}

/// Threads for a pass that would use `wanted` (≥ 1) on its own: all of them when no
/// budget is set on this thread, else this thread plus what spare cores there are.
pub(crate) fn lease(wanted: usize) -> Lease {
    let wanted = wanted.max(1);
    let cores = BUDGET.with(|b| b.borrow().clone());
    match cores {
        None => Lease {
            threads: wanted,
            borrowed: 0,
            cores: None,
        },
        Some(cores) => {
            let borrowed = cores.take(wanted - 1);
            Lease {
                threads: 1 + borrowed,
                borrowed,
                cores: Some(cores),
            }
        }
    }
}

/// Splits `0..count` into `parts` (≥ 1) contiguous runs of nearly equal length, in order.
pub(crate) fn runs(count: usize, parts: usize) -> impl Iterator<Item = std::ops::Range<usize>> {
    let parts = parts.clamp(1, count.max(1));
    (0..parts).map(move |p| (p * count / parts)..((p + 1) * count / parts))
}

#[cfg(test)]
mod tests {
    use super::{lease, runs, with_cores, Cores};

    #[test]
    fn without_a_budget_a_pass_gets_what_it_wants() {
        assert_eq!(lease(3).threads(), 3);
        assert_eq!(lease(0).threads(), 1);
    }

    #[test]
    fn with_a_budget_a_pass_borrows_spare_cores_and_gives_them_back() {
        let cores = Cores::new(0);
        with_cores(&cores, || {
            assert_eq!(lease(2).threads(), 1, "no spare core");
            cores.give_back();
            {
                let l = lease(4);
                assert_eq!(l.threads(), 2, "its own core and the spare one");
                assert_eq!(cores.spare(), 0);
                assert_eq!(lease(2).threads(), 1, "the spare core is lent");
            }
            assert_eq!(cores.spare(), 1, "returned when the lease ends");
        });
        assert_eq!(lease(2).threads(), 2, "the budget ends with the scope");
    }

    #[test]
    fn runs_cover_the_range_in_order() {
        for count in 0..9 {
            for parts in 1..5 {
                let r: Vec<_> = runs(count, parts).collect();
                assert_eq!(r.first().map_or(0, |r| r.start), 0);
                assert_eq!(r.last().map_or(0, |r| r.end), count);
                assert!(r.windows(2).all(|w| w[0].end == w[1].start));
                assert!(r.len() <= parts.max(1));
            }
        }
    }
}
