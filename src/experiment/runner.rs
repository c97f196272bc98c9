//! The one runner of the experiments' resumable jobs (`reproduce`, `scale`, `demo`): a
//! list of jobs, each leaving a record file when it finishes; a job with a record is
//! done and is not run again, so a run interrupted at any point continues where it
//! stopped; a shard runs its share of the list (several processes, or machines writing
//! into copies of one folder merged afterwards); the records, read back, make the report.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use super::jobs::{clock, write_toml, Shard};
use crate::error::{Error, Result};
use crate::progress::Reporter;

/// One job of a list: where its record goes, and what it is in words.
pub trait Job {
    /// What a finished job leaves, written as TOML.
    type Record: Serialize;
    /// The record's file under the run's folder `out`.
    fn record_path(&self, out: &Path) -> PathBuf;
    /// The job in a few words for the progress lines ("iastgcn seed 2").
    fn describe(&self) -> String;
    /// The job's wall time, set on its record by the runner (s).
    fn set_wall_seconds(record: &mut Self::Record, seconds: f64);
}

/// How far a call got: jobs with a record, of all.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Progress {
    /// Jobs with a record.
    pub done: usize,
    /// Jobs in the list.
    pub total: usize,
}

/// The jobs of one run into the folder `out`, this process's shard of them.
pub struct Runner<'a, J> {
    jobs: &'a [J],
    shard: Option<Shard>,
    out: &'a Path,
    began: Instant,
}

impl<'a, J: Job> Runner<'a, J> {
    /// The runner of `jobs` into `out`; with `shard`, only that shard's jobs run. The
    /// progress lines count elapsed time from `began`.
    pub fn new(jobs: &'a [J], shard: Option<Shard>, out: &'a Path, began: Instant) -> Self {
        Runner {
            jobs,
            shard,
            out,
            began,
        }
    }

    /// Whether `job` has its record.
    pub fn is_done(&self, job: &J) -> bool {
        job.record_path(self.out).exists()
    }

    /// Jobs of the whole list (every shard's) with a record, of all.
    pub fn progress(&self) -> Progress {
        Progress {
            done: self.jobs.iter().filter(|j| self.is_done(j)).count(),
            total: self.jobs.len(),
        }
    }

    /// This process's jobs (its shard's, or all): their places in the list and them.
    pub fn mine(&self) -> Vec<(usize, &'a J)> {
        self.jobs
            .iter()
            .enumerate()
            .filter(|(i, _)| self.shard.is_none_or(|s| s.owns(*i)))
            .collect()
    }

    /// This process's jobs without a record, in the list's order.
    pub fn pending(&self) -> Vec<(usize, &'a J)> {
        self.mine()
            .into_iter()
            .filter(|(_, j)| !self.is_done(j))
            .collect()
    }

    /// Runs each pending job in turn: a line with its place, elapsed time and ETA (the
    /// mean of the jobs finished in this call), then `work`, whose record (with the job's
    /// wall time) is written before `after` is called. Returns the progress at the end.
    pub fn run_each(
        &self,
        reporter: &mut dyn Reporter,
        mut work: impl FnMut(&J, &mut dyn Reporter) -> Result<J::Record>,
        mut after: impl FnMut(&mut dyn Reporter) -> Result<()>,
    ) -> Result<Progress> {
        let todo = self.pending();
        let mut spent: Vec<f64> = Vec::new();
        for (n, (i, job)) in todo.iter().enumerate() {
            let eta = match spent.len() {
                0 => "unknown until a job finishes".to_string(),
                k => clock(spent.iter().sum::<f64>() / k as f64 * (todo.len() - n) as f64),
            };
            reporter.note(&format!(
                "== job {}/{} ({} of this run): {}; elapsed {}, ETA {eta}",
                i + 1,
                self.jobs.len(),
                n + 1,
                job.describe(),
                clock(self.began.elapsed().as_secs_f64())
            ));
            let started = Instant::now();
            let mut record = work(job, reporter)?;
            let wall = started.elapsed().as_secs_f64();
            J::set_wall_seconds(&mut record, wall);
            write_toml(&record, &job.record_path(self.out))?;
            spent.push(wall);
            after(reporter)?;
        }
        Ok(self.progress())
    }

    /// Runs `batch` (jobs of this list, without a record) together with `work`, which
    /// hands each job's record to its second argument as the job ends, with the job's
    /// place in the batch and its wall time: the record is written at once (the wall time
    /// set on it), so that a batch cut short keeps the jobs it finished. For jobs that run
    /// side by side. A job left without a record is an error.
    pub fn run_batch(
        &self,
        batch: &[&J],
        work: impl FnOnce(&[&J], &RecordFn<'_, J::Record>) -> Result<()>,
    ) -> Result<()>
    where
        J: Sync,
    {
        if batch.is_empty() {
            return Ok(());
        }
        let out = self.out;
        let record = |i: usize, mut record: J::Record, wall: f64| -> Result<()> {
            J::set_wall_seconds(&mut record, wall);
            let job = batch.get(i).ok_or_else(|| {
                Error::Invalid(format!(
                    "a record for job {i} of a batch of {}",
                    batch.len()
                ))
            })?;
            write_toml(&record, &job.record_path(out))
        };
        work(batch, &record)?;
        match batch.iter().find(|j| !self.is_done(j)) {
            Some(job) => Err(Error::Invalid(format!(
                "{} ended without a record",
                job.describe()
            ))),
            None => Ok(()),
        }
    }
}

/// What a batch's work hands each finished job's record to: its place in the batch, the
/// record and the job's wall time (s).
pub type RecordFn<'a, R> = dyn Fn(usize, R, f64) -> Result<()> + Sync + 'a;

/// The last value built, kept while the next jobs ask for the same key: the dataset of
/// a share or size of the training data, which consecutive jobs of a list share.
pub struct Cached<K, V> {
    kept: Option<(K, V)>,
}

impl<K: PartialEq, V> Default for Cached<K, V> {
    fn default() -> Self {
        Cached { kept: None }
    }
}

impl<K: PartialEq, V> Cached<K, V> {
    /// The value of `key`: the kept one, or (the kept one dropped first, to free its
    /// memory) what `build` makes.
    pub fn get(&mut self, key: K, build: impl FnOnce() -> Result<V>) -> Result<&V> {
        if self.kept.as_ref().is_none_or(|(k, _)| *k != key) {
            self.kept = None;
            self.kept = Some((key, build()?));
        }
        // invariant: kept was set just above unless it already held `key`.
        Ok(&self.kept.as_ref().expect("a kept value").1)
    }

    /// Forgets the kept value.
    pub fn clear(&mut self) {
        self.kept = None;
    }
}

#[cfg(test)]
mod tests {
    use super::{Cached, Job, Progress, Runner};
    use crate::error::Error;
    use crate::experiment::jobs::Shard;
    use crate::progress::Reporter;
    use serde::Serialize;
    use std::path::{Path, PathBuf};
    use std::time::Instant;

    struct Count(usize);

    #[derive(Serialize)]
    struct Record {
        n: usize,
        wall: f64,
    }

    impl Job for Count {
        type Record = Record;
        fn record_path(&self, out: &Path) -> PathBuf {
            out.join(format!("{}.job.toml", self.0))
        }
        fn describe(&self) -> String {
            format!("count {}", self.0)
        }
        fn set_wall_seconds(record: &mut Record, seconds: f64) {
            record.wall = seconds;
        }
    }

    #[derive(Default)]
    struct Lines(Vec<String>);

    impl Reporter for Lines {
        fn note(&mut self, line: &str) {
            self.0.push(line.to_string());
        }
    }

    fn folder(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("iastgcn-runner-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn a_job_with_a_record_runs_no_more_and_a_failed_one_runs_again() {
        let out = folder("resume");
        let jobs: Vec<Count> = (0..4).map(Count).collect();
        let runner = Runner::new(&jobs, None, &out, Instant::now());
        let mut lines = Lines::default();
        let mut ran = Vec::new();
        // Job 2 fails: jobs 0 and 1 keep their records, 2 and 3 have none.
        let failed = runner.run_each(
            &mut lines,
            |job, _| {
                ran.push(job.0);
                if job.0 == 2 {
                    return Err(Error::Invalid("interrupted".into()));
                }
                Ok(Record {
                    n: job.0,
                    wall: -1.0,
                })
            },
            |_| Ok(()),
        );
        assert!(failed.is_err());
        assert_eq!(ran, [0, 1, 2]);
        assert_eq!(runner.progress(), Progress { done: 2, total: 4 });
        let record = std::fs::read_to_string(out.join("1.job.toml")).unwrap();
        assert!(
            record.contains("n = 1") && !record.contains("wall = -1"),
            "{record}"
        );
        assert!(lines.0[0].starts_with("== job 1/4 (1 of this run): count 0; elapsed 0:00:0"));
        assert!(
            lines.0[0].ends_with("ETA unknown until a job finishes"),
            "{:?}",
            lines.0
        );
        // Run again: only the jobs without a record, each followed by `after`.
        ran.clear();
        let mut after = 0;
        let mut lines = Lines::default();
        let progress = runner
            .run_each(
                &mut lines,
                |job, _| {
                    ran.push(job.0);
                    Ok(Record {
                        n: job.0,
                        wall: 0.0,
                    })
                },
                |_| {
                    after += 1;
                    Ok(())
                },
            )
            .unwrap();
        assert_eq!((ran.as_slice(), after), ([2, 3].as_slice(), 2));
        assert_eq!(progress, Progress { done: 4, total: 4 });
        assert!(lines.0[0].starts_with("== job 3/4 (1 of this run): count 2"));
        assert!(lines.0[1].starts_with("== job 4/4 (2 of this run): count 3"));
        std::fs::remove_dir_all(&out).unwrap();
    }

    #[test]
    fn a_shard_runs_its_share_and_counts_every_shards_records() {
        let out = folder("shard");
        let jobs: Vec<Count> = (0..5).map(Count).collect();
        let shard = Some(Shard { index: 2, count: 2 });
        let runner = Runner::new(&jobs, shard, &out, Instant::now());
        let mine: Vec<usize> = runner.mine().iter().map(|(i, _)| *i).collect();
        assert_eq!(mine, [1, 3]);
        let mut ran = Vec::new();
        let progress = runner
            .run_each(
                &mut Lines::default(),
                |job, _| {
                    ran.push(job.0);
                    Ok(Record {
                        n: job.0,
                        wall: 0.0,
                    })
                },
                |_| Ok(()),
            )
            .unwrap();
        assert_eq!(ran, [1, 3]);
        assert_eq!(progress, Progress { done: 2, total: 5 });
        // The other shard's run sees them done, and runs its own.
        let other = Runner::new(
            &jobs,
            Some(Shard { index: 1, count: 2 }),
            &out,
            Instant::now(),
        );
        let pending: Vec<usize> = other.pending().iter().map(|(i, _)| *i).collect();
        assert_eq!(pending, [0, 2, 4]);
        std::fs::remove_dir_all(&out).unwrap();
    }

    #[test]
    fn a_batch_writes_each_record_as_its_job_ends() {
        let out = folder("batch");
        let jobs: Vec<Count> = (0..4).map(Count).collect();
        let runner = Runner::new(&jobs, None, &out, Instant::now());
        let batch: Vec<&Count> = jobs.iter().skip(1).collect();
        // Cut short after its first job: that one keeps its record.
        let cut = runner.run_batch(&batch, |b, record| {
            // The runner sets the wall time it is given.
            record(
                0,
                Record {
                    n: b[0].0,
                    wall: -1.0,
                },
                1.5,
            )?;
            Err(Error::Invalid("interrupted".into()))
        });
        assert!(cut.is_err());
        let pending: Vec<usize> = runner.pending().iter().map(|(i, _)| *i).collect();
        assert_eq!(pending, [0, 2, 3]);
        let record = std::fs::read_to_string(out.join("1.job.toml")).unwrap();
        assert!(
            record.contains("n = 1") && record.contains("wall = 1.5"),
            "{record}"
        );
        // A job the work leaves without a record, or a record for no job: errors.
        let batch: Vec<&Count> = jobs.iter().skip(2).collect();
        let short = runner.run_batch(&batch, |b, record| {
            record(
                0,
                Record {
                    n: b[0].0,
                    wall: 0.0,
                },
                0.0,
            )
        });
        assert!(short
            .unwrap_err()
            .to_string()
            .contains("count 3 ended without a record"));
        let beyond = runner.run_batch(&batch, |_, record| {
            record(2, Record { n: 9, wall: 0.0 }, 0.0)
        });
        assert!(beyond.is_err());
        runner
            .run_batch(&[&jobs[3]], |b, record| {
                record(
                    0,
                    Record {
                        n: b[0].0,
                        wall: 0.0,
                    },
                    0.0,
                )
            })
            .unwrap();
        let pending: Vec<usize> = runner.pending().iter().map(|(i, _)| *i).collect();
        assert_eq!(pending, [0]);
        std::fs::remove_dir_all(&out).unwrap();
    }

    #[test]
    fn the_cache_builds_once_per_key_in_a_row() {
        let mut cache: Cached<u32, String> = Cached::default();
        let mut built = 0;
        for key in [1, 1, 2, 2, 1] {
            let value = cache
                .get(key, || {
                    built += 1;
                    Ok(format!("value {key}"))
                })
                .unwrap();
            assert_eq!(value, &format!("value {key}"));
        }
        assert_eq!(built, 3);
        cache.clear();
        cache
            .get(1, || {
                built += 1;
                Ok(String::new())
            })
            .unwrap();
        assert_eq!(built, 4);
        assert!(cache.get(5, || Err(Error::Invalid("no".into()))).is_err());
    }
}
