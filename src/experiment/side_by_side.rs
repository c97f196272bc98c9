//! Fitting several models side by side: on the native CPU path, one model per core, the
//! costliest first, each training step's shares on the cores no other model uses
//! (`model::native::cores`), so the bits are those of fitting them one after another.
//! One progress bar follows them all; each model's notes are held until it ends and
//! shown in the models' order.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use super::parallel;
use super::protocol::{fit_model, Fitted, ModelFiles};
use crate::data::Dataset;
use crate::error::Result;
use crate::gpu::Device;
use crate::graph::Graph;
use crate::model::flops::training_flops;
use crate::progress::Reporter;
use crate::train::engine::runs_native;
use crate::train::RunConfig;

/// One model to fit: its run configuration (variant and seed set), name and files.
pub struct FitJob {
    /// The run configuration, its variant and seed set.
    pub config: RunConfig,
    /// The model's name (`iastgcn.seed1`).
    pub name: String,
    /// Where its weights and logs go.
    pub files: ModelFiles,
}

/// Progress units per model of the shared bar.
const PER_MODEL: u64 = 1000;

/// Fits every job as [`fit_model`] does; `fitted` is called with each job's place,
/// result and wall time (s) as soon as it ends, on the thread that fitted it (an error
/// from it is the job's). On the native
/// CPU path the models run one per core (`what` names the bar that follows them);
/// elsewhere one after another, with their own progress. Side by side, an error is
/// returned after every job has ended, with every model's notes shown.
pub fn fit_side_by_side(
    device: &Device,
    data: &Dataset,
    graph: &Graph,
    jobs: Vec<FitJob>,
    what: &str,
    fitted: &(dyn Fn(usize, &Fitted, f64) -> Result<()> + Sync),
    reporter: &mut dyn Reporter,
) -> Result<()> {
    let native = match jobs.first() {
        Some(j) => runs_native(&j.config.train.backend, device)?,
        None => return Ok(()),
    };
    let workers = parallel::workers(native).min(jobs.len());
    if workers <= 1 {
        return jobs.iter().enumerate().try_for_each(|(i, j)| {
            let started = Instant::now();
            let f = fit_model(device, data, graph, &j.config, &j.name, &j.files, reporter)?;
            fitted(i, &f, started.elapsed().as_secs_f64())
        });
    }
    let count = jobs.len();
    let progress: Vec<AtomicU64> = (0..count).map(|_| AtomicU64::new(0)).collect();
    let notes: Mutex<Vec<Option<Vec<String>>>> = Mutex::new((0..count).map(|_| None).collect());
    let names: Vec<String> = jobs.iter().map(|j| j.name.clone()).collect();
    reporter.begin(
        &format!("{what}: {count} models, {workers} at a time"),
        count as u64 * PER_MODEL,
    );
    let mut shown = 0;
    let mut show = |reporter: &mut dyn Reporter| {
        // invariant: no thread panics while holding the notes' lock.
        let mut held = notes.lock().expect("the held notes");
        while let Some(Some(lines)) = held.get_mut(shown).map(Option::take) {
            for line in &lines {
                reporter.note(line);
            }
            shown += 1;
        }
    };
    // The costliest first (training FLOPs per batch), so that the last to end is a
    // small one.
    let all = parallel::run_all_costliest_first(
        jobs,
        |j| training_flops(&j.config.model, j.config.train.batch),
        workers,
        |i, job, tick| {
            let mut held = Held {
                notes: Vec::new(),
                progress: &progress[i],
                tick,
                len: 0,
            };
            held.progress.fetch_max(1, Ordering::Relaxed);
            let started = Instant::now();
            let out = fit_model(
                device,
                data,
                graph,
                &job.config,
                &job.name,
                &job.files,
                &mut held,
            )
            .and_then(|f| fitted(i, &f, started.elapsed().as_secs_f64()));
            held.progress.store(PER_MODEL, Ordering::Relaxed);
            // invariant: no thread panics while holding the notes' lock.
            notes.lock().expect("the held notes")[i] = Some(held.notes);
            tick();
            out
        },
        || {
            let at: Vec<u64> = progress.iter().map(|p| p.load(Ordering::Relaxed)).collect();
            let running: Vec<&str> = at
                .iter()
                .zip(&names)
                .filter(|(&p, _)| 0 < p && p < PER_MODEL)
                .map(|(_, n)| n.as_str())
                .collect();
            reporter.update(at.iter().sum(), &running.join(", "));
            show(reporter);
        },
    );
    reporter.end();
    show(reporter);
    all.map(drop)
}

/// A model's reporter while it fits beside others: its notes are held, its progress is
/// the furthest any of its tasks has gone (the core stage is most of a model's time).
struct Held<'a> {
    notes: Vec<String>,
    progress: &'a AtomicU64,
    tick: &'a dyn Fn(),
    len: u64,
}

impl Reporter for Held<'_> {
    fn begin(&mut self, _what: &str, len: u64) {
        self.len = len;
    }

    fn update(&mut self, pos: u64, _message: &str) {
        if let Some(at) = (pos.min(self.len) * (PER_MODEL - 1)).checked_div(self.len) {
            self.progress.fetch_max(at.max(1), Ordering::Relaxed);
            (self.tick)();
        }
    }

    fn note(&mut self, line: &str) {
        self.notes.push(line.to_string());
    }
}
