//! Independent runs of an evaluation on every core: the jobs go to worker threads, their
//! results come back in the jobs' order (so a table is the same whichever thread ran
//! which run), and the caller's tick callback sees every tick on the calling thread,
//! which keeps the progress bar. A worker's native passes borrow the cores that no
//! worker uses (`model::native::cores`), so the last jobs run on every core.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Duration;

use crate::model::native::cores::{with_cores, Cores};

/// How often the calling thread passes the workers' ticks on.
const POLL: Duration = Duration::from_millis(50);

/// Runs `work` on every job, on `workers` threads (on the calling thread alone when
/// `workers` ≤ 1), and returns the results in the jobs' order. `work` counts its ticks
/// through the function it is given; `on_tick` is called once per tick, on the calling
/// thread. The first error (in the jobs' order) is returned after every job has ended.
pub(crate) fn run_all<J, R, E>(
    jobs: Vec<J>,
    workers: usize,
    work: impl Fn(J, &dyn Fn()) -> Result<R, E> + Sync,
    mut on_tick: impl FnMut(),
) -> Result<Vec<R>, E>
where
    J: Send,
    R: Send,
    E: Send,
{
    let count = jobs.len();
    let workers = workers.min(count);
    if workers <= 1 {
        let on_tick = std::cell::RefCell::new(on_tick);
        let tick = || (on_tick.borrow_mut())();
        return jobs.into_iter().map(|j| work(j, &tick)).collect();
    }
    // The cores beyond the workers', and each worker's once it has no job left: a
    // native training step or prediction borrows them (the last jobs of a batch then
    // run on every core, with the same bits).
    let cores = Cores::new(
        std::thread::available_parallelism()
            .map_or(1, |n| n.get())
            .saturating_sub(workers),
    );
    let queue = Mutex::new(jobs.into_iter().enumerate().collect::<VecDeque<_>>());
    let results: Mutex<Vec<Option<Result<R, E>>>> = Mutex::new((0..count).map(|_| None).collect());
    let ticks = AtomicUsize::new(0);
    let running = AtomicUsize::new(workers);
    std::thread::scope(|scope| {
        for _ in 0..workers {
            scope.spawn(|| {
                let tick = || {
                    ticks.fetch_add(1, Ordering::Relaxed);
                };
                with_cores(&cores, || loop {
                    // invariant: no thread panics while holding the queue's lock.
                    let next = queue.lock().expect("the job queue").pop_front();
                    let Some((i, job)) = next else { break };
                    let r = work(job, &tick);
                    // invariant: no thread panics while holding the results' lock.
                    results.lock().expect("the results")[i] = Some(r);
                });
                cores.give_back();
                running.fetch_sub(1, Ordering::Release);
            });
        }
        let mut passed = 0;
        loop {
            let finished = running.load(Ordering::Acquire) == 0;
            let now = ticks.load(Ordering::Relaxed);
            for _ in passed..now {
                on_tick();
            }
            passed = now;
            if finished {
                break;
            }
            std::thread::sleep(POLL);
        }
    });
    // invariant: every worker has ended (the scope joined them) and filled its slots.
    let results = results.into_inner().expect("the results");
    results
        .into_iter()
        .map(|r| r.expect("every job ran"))
        .collect()
}

/// [`run_all`] with the jobs queued costliest first (by `cost`, ties in the jobs' order),
/// so that the last job to end is a short one; `work` is given each job's index in
/// `jobs`, and the results come back in the jobs' order. An error is the first in the
/// queue's order.
pub(crate) fn run_all_costliest_first<J, R, E>(
    jobs: Vec<J>,
    cost: impl Fn(&J) -> f64,
    workers: usize,
    work: impl Fn(usize, J, &dyn Fn()) -> Result<R, E> + Sync,
    on_tick: impl FnMut(),
) -> Result<Vec<R>, E>
where
    J: Send,
    R: Send,
    E: Send,
{
    let costs: Vec<f64> = jobs.iter().map(cost).collect();
    let mut queued: Vec<(usize, J)> = jobs.into_iter().enumerate().collect();
    queued.sort_by(|(a, _), (b, _)| costs[*b].total_cmp(&costs[*a]));
    let mut done = run_all(
        queued,
        workers,
        |(i, job), tick| work(i, job, tick).map(|r| (i, r)),
        on_tick,
    )?;
    done.sort_by_key(|(i, _)| *i);
    Ok(done.into_iter().map(|(_, r)| r).collect())
}

/// The worker threads for runs that may share the machine: every core, or one where a
/// run uses the GPU (`all_native` false: the device's queue stays with one thread).
pub(crate) fn workers(all_native: bool) -> usize {
    if all_native {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    } else {
        1
    }
}

#[cfg(test)]
mod tests {
    use super::{run_all, run_all_costliest_first};
    use std::cell::Cell;

    #[test]
    fn results_come_back_in_the_jobs_order_with_every_tick() {
        for workers in [1, 2, 4] {
            let ticks = Cell::new(0);
            let out: Result<Vec<u64>, String> = run_all(
                (0..20u64).collect(),
                workers,
                |j, tick| {
                    for _ in 0..j {
                        tick();
                    }
                    Ok(j * j)
                },
                || ticks.set(ticks.get() + 1),
            );
            assert_eq!(out.unwrap(), (0..20u64).map(|j| j * j).collect::<Vec<_>>());
            assert_eq!(ticks.get(), (0..20).sum::<usize>(), "{workers} workers");
        }
    }

    #[test]
    fn the_costliest_run_first_and_come_back_in_the_jobs_order() {
        for workers in [1, 2] {
            let started = std::sync::Mutex::new(Vec::new());
            let out: Result<Vec<u64>, String> = run_all_costliest_first(
                vec![3u64, 9, 1, 9, 5],
                |&j| j as f64,
                workers,
                |i, j, _| {
                    started.lock().unwrap().push(i);
                    Ok(10 * j + i as u64)
                },
                || {},
            );
            assert_eq!(out.unwrap(), vec![30, 91, 12, 93, 54]);
            if workers == 1 {
                assert_eq!(started.into_inner().unwrap(), vec![1, 3, 4, 0, 2]);
            }
        }
    }

    #[test]
    fn the_first_error_in_the_jobs_order_is_returned() {
        let out: Result<Vec<u64>, String> = run_all(
            (0..10u64).collect(),
            3,
            |j, _| {
                if j % 4 == 3 {
                    Err(format!("job {j}"))
                } else {
                    Ok(j)
                }
            },
            || {},
        );
        assert_eq!(out.unwrap_err(), "job 3");
    }
}
