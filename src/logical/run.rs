//! What a run of `oavm-trace` (or any program tracing a file) does and reports around its sets
//! of rays: a batch asking one [`Query`] of each ray, its [`Answers`] and figures
//! ([`Scene::answer`]); a traced frame's sets, each with a digest of its answers, and their
//! total ([`FrameFigures`], the benchmark mode); the figures of the whole run ([`TraceRun`],
//! [`RunReport`]); and a file's timed verification ([`Verification`]).

use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use super::frame::Frame;
use super::order::Order;
use super::pager::BlockSource;
use super::report::{Answered, SetReport};
use super::scene::{Scene, SceneInfo, SceneOptions};
use super::verify::VerifyReport;
use crate::error::Error;
use crate::geom::{AllHits, Hit, Ray};
use crate::output::Output;
use crate::rays::{write_hit_lists, write_into};

/// What a batch asks of each ray.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Query {
    /// Its closest hit ([`Scene::intersect_batch_ordered`]).
    Closest,
    /// Whether anything occludes it ([`Scene::occluded_batch_ordered`]).
    Any,
    /// Every hit along it ([`Scene::list_intersections`]).
    All,
    /// How many hits it has ([`Scene::count_intersections`]).
    Count,
}

/// A batch's answers, in the order of its rays.
#[derive(Clone, Debug)]
pub enum Answers {
    /// Closest hits ([`Query::Closest`]).
    Hits(Vec<Hit>),
    /// Every hit of each ray ([`Query::All`]).
    Lists(AllHits),
    /// Hits per ray ([`Query::Count`]).
    Counts(Vec<u32>),
    /// 1: occluded, 0: not ([`Query::Any`]).
    Occluded(Vec<u8>),
}

impl Answers {
    /// Writes them to `out`: a HITS file, or an OCCL file (`RAYS.md`).
    pub fn write(&self, out: Output) -> Result<(), Error> {
        match self {
            Answers::Hits(hits) => write_into(out, hits),
            Answers::Occluded(occ) => write_into(out, occ),
            Answers::Lists(all) => write_hit_lists(out, all),
            Answers::Counts(counts) => write_into(out, counts),
        }
    }
}

impl<D: AsRef<[u8]> + BlockSource> Scene<D> {
    /// Answers `query` for every ray of `rays`, traced in `order`: the answers, and the set's
    /// figures (how many hit, or were occluded; the time is the trace's).
    pub fn answer(
        &self,
        rays: &[Ray],
        query: Query,
        order: Order,
    ) -> Result<(Answers, SetReport), Error> {
        let t = Instant::now();
        match query {
            Query::Closest => {
                let mut hits = vec![Hit::MISS; rays.len()];
                let c = self.intersect_batch_ordered(rays, &mut hits, order)?;
                let seconds = t.elapsed().as_secs_f64();
                let n = hits.iter().filter(|h| h.is_hit()).count() as u64;
                let set = SetReport::new(&c, seconds, Answered::Hits(n));
                Ok((Answers::Hits(hits), set))
            }
            Query::Any => {
                let mut occ = vec![0u8; rays.len()];
                let c = self.occluded_batch_ordered(rays, &mut occ, order)?;
                let seconds = t.elapsed().as_secs_f64();
                let n = occ.iter().filter(|&&o| o == 1).count() as u64;
                let set = SetReport::new(&c, seconds, Answered::Occluded(n));
                Ok((Answers::Occluded(occ), set))
            }
            Query::All => {
                let (all, c) = self.list_intersections(rays)?;
                let seconds = t.elapsed().as_secs_f64();
                let n = (0..all.rays()).filter(|&i| !all.of(i).is_empty()).count() as u64;
                let set = SetReport::new(&c, seconds, Answered::Listed(n, all.hits.len() as u64));
                Ok((Answers::Lists(all), set))
            }
            Query::Count => {
                let mut counts = vec![0u32; rays.len()];
                let c = self.count_intersections(rays, &mut counts)?;
                let seconds = t.elapsed().as_secs_f64();
                let n = counts.iter().filter(|&&k| k > 0).count() as u64;
                let all = counts.iter().map(|&k| k as u64).sum();
                let set = SetReport::new(&c, seconds, Answered::Listed(n, all));
                Ok((Answers::Counts(counts), set))
            }
        }
    }
}

/// One set of a traced frame: its name, a digest of its answers and its figures.
#[derive(Clone, Debug, Serialize)]
pub struct AnsweredSet {
    /// The set's name: the primary rays' (`random`, `primary`...) or `shadow`.
    pub set: String,
    /// xxh3-64 of the set's answers (closest hits as their HITS records, or the OCCL bytes),
    /// in hex: runs that agree ray for ray have the same digest.
    pub answers_xxh3: String,
    /// The set's figures.
    #[serde(flatten)]
    pub report: SetReport,
}

/// `NAME: N rays, ANSWERED, S s, M Mrays/s` (the pager's figures left to
/// [`PageReport::clause`]).
impl fmt::Display for AnsweredSet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let r = &self.report;
        write!(
            f,
            "{}: {} rays, {}, {:.3} s, {:.2} Mrays/s",
            self.set,
            r.rays,
            r.answered(),
            r.seconds,
            r.mrays_per_s
        )
    }
}

/// What a traced frame ([`Frame`]) reports: the total over its sets, and each set (its primary
/// rays, then its shadow rays if it has them).
#[derive(Clone, Debug, Serialize)]
pub struct FrameFigures {
    /// The total over every set (its hits and occluded rays not counted).
    #[serde(flatten)]
    pub total: SetReport,
    pub sets: Vec<AnsweredSet>,
}

impl Frame {
    /// The figures of the frame, its primary rays named `name`, with its shadow rays' set if
    /// `shadow` (it was traced with a light, [`super::FrameOptions::light`]).
    pub fn figures(&self, name: &str, shadow: bool) -> FrameFigures {
        let digest = |bytes: &[u8]| format!("{:016x}", xxhash_rust::xxh3::xxh3_64(bytes));
        let hits = self.hits.iter().filter(|h| h.is_hit()).count() as u64;
        let mut sets = vec![AnsweredSet {
            set: name.to_owned(),
            answers_xxh3: digest(bytemuck::cast_slice(&self.hits)),
            report: SetReport::new(
                &self.primary.counters,
                self.primary.seconds,
                Answered::Hits(hits),
            ),
        }];
        if shadow {
            let n = self.occluded.iter().filter(|&&o| o == 1).count() as u64;
            sets.push(AnsweredSet {
                set: "shadow".to_owned(),
                answers_xxh3: digest(&self.occluded),
                report: SetReport::new(
                    &self.shadow.counters,
                    self.shadow.seconds,
                    Answered::Occluded(n),
                ),
            });
        }
        let total = SetReport::new(
            &(self.primary.counters + self.shadow.counters),
            self.primary.seconds + self.shadow.seconds,
            Answered::Mixed,
        );
        FrameFigures { total, sets }
    }
}

/// A tracing run, for its report: when it began, the threads and order it traces on, the
/// options it opened the file with, and what it had done when its first ray was ready
/// ([`TraceRun::first_ray`]). [`TraceRun::report`] wraps a run's own figures in what every
/// run reports ([`RunReport`]).
#[derive(Clone, Copy, Debug)]
pub struct TraceRun {
    /// When the run began (a program's entry: the time before it, exec and loading, is not
    /// counted).
    pub start: Instant,
    /// Milliseconds opening the file.
    pub open_ms: f64,
    /// The threads it traces on, and the order of its rays.
    pub threads: usize,
    pub order: Order,
    /// The memory budget asked for ([`SceneOptions::mem_budget`]; `None`: the default).
    pub mem_budget: Option<u64>,
    /// Whether blocks' checksums are checked ([`SceneOptions::check_blocks`]).
    pub block_checks: bool,
    /// Milliseconds from `start` to the first ray (0 until [`TraceRun::first_ray`]).
    pub first_ray_ms: f64,
    /// What the process had read from the disk at the first ray ([`crate::os::read_bytes`]).
    pub read_bytes_before: Option<u64>,
}

/// What every tracing run reports (`oavm-trace --json`), around its own figures (`body`,
/// flattened into the same object).
#[derive(Clone, Debug, Serialize)]
pub struct RunReport<T> {
    /// The file traced.
    pub file: PathBuf,
    /// What the scene is and holds ([`Scene::info`]).
    #[serde(flatten)]
    pub scene: SceneInfo,
    /// [`TraceRun::threads`], [`TraceRun::order`], [`TraceRun::open_ms`] and
    /// [`TraceRun::first_ray_ms`].
    pub threads: usize,
    pub order: Order,
    pub open_ms: f64,
    pub start_to_first_ray_ms: f64,
    /// The budget asked for (`None`: the default, see `pager_budget`).
    pub mem_budget: Option<u64>,
    pub block_checks: bool,
    /// The process's peak resident memory when the report was made.
    pub peak_rss_bytes: Option<u64>,
    /// Bytes the process had read from the disk before the first ray, and since.
    pub disk_read_bytes_before_trace: Option<u64>,
    pub disk_read_bytes_trace: Option<u64>,
    /// The run's own figures.
    #[serde(flatten)]
    pub body: T,
}

impl TraceRun {
    /// A run that began at `start`, opened its file with `opts` in `open_ms` milliseconds, and
    /// traces on `threads` threads in `order`.
    pub fn new(
        start: Instant,
        open_ms: f64,
        threads: usize,
        order: Order,
        opts: &SceneOptions,
    ) -> TraceRun {
        TraceRun {
            start,
            open_ms,
            threads,
            order,
            mem_budget: opts.mem_budget,
            block_checks: opts.check_blocks,
            first_ray_ms: 0.0,
            read_bytes_before: None,
        }
    }

    /// Marks the moment the first ray is ready to be traced: its time since
    /// [`TraceRun::start`], and the bytes the process had read from the disk.
    pub fn first_ray(&mut self) {
        self.first_ray_ms = self.start.elapsed().as_secs_f64() * 1e3;
        self.read_bytes_before = crate::os::read_bytes();
    }

    /// The run's report on `scene`, around `body`, with the process's figures now (peak
    /// memory, bytes read since the first ray).
    pub fn report<T, D: AsRef<[u8]> + BlockSource>(
        &self,
        scene: &Scene<D>,
        body: T,
    ) -> RunReport<T> {
        let read_now = crate::os::read_bytes();
        RunReport {
            file: scene.path().to_owned(),
            scene: scene.info(),
            threads: self.threads,
            order: self.order,
            open_ms: self.open_ms,
            start_to_first_ray_ms: self.first_ray_ms,
            mem_budget: self.mem_budget,
            block_checks: self.block_checks,
            peak_rss_bytes: crate::os::peak_rss_bytes(),
            disk_read_bytes_before_trace: self.read_bytes_before,
            disk_read_bytes_trace: read_now
                .zip(self.read_bytes_before)
                .map(|(a, b)| a.saturating_sub(b)),
            body,
        }
    }

    /// `N Mrays/s on T threads (open M ms)`, a rate of `mrays_per_s` as a run's text says it.
    pub fn rate(&self, mrays_per_s: f64) -> String {
        format!(
            "{mrays_per_s:.2} Mrays/s on {} threads (open {:.3} ms)",
            self.threads, self.open_ms
        )
    }
}

/// A file's full verification ([`Scene::verify`]), timed, as `oavm-trace --verify` reports it:
/// with `--json` these fields, as text ([`Display`](fmt::Display)) the line `FILE: ok (...)`
/// or `FILE: verification failed (N defects)`.
#[derive(Clone, Debug, Serialize)]
pub struct Verification {
    /// The file verified.
    pub file: PathBuf,
    /// No defect found.
    pub ok: bool,
    /// Seconds opening and verifying the file.
    pub seconds: f64,
    /// What the checks found.
    pub report: VerifyReport,
}

impl Verification {
    /// Opens the file at `path` and checks every section, checksum and invariant. An error
    /// only if it cannot be opened (or changes while read); defects are in the report.
    pub fn run(path: &Path) -> Result<Verification, Error> {
        let t = Instant::now();
        let report = Scene::open(path)?.verify()?;
        Ok(Verification {
            file: path.to_owned(),
            ok: report.is_ok(),
            seconds: t.elapsed().as_secs_f64(),
            report,
        })
    }

    /// `Err` saying that verification failed and how many defects it found, if it did.
    pub fn result(&self) -> Result<(), Error> {
        match self.ok {
            true => Ok(()),
            false => Err(Error::Invalid(self.to_string())),
        }
    }
}

impl fmt::Display for Verification {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (file, r) = (self.file.display(), &self.report);
        match self.ok {
            true => write!(
                f,
                "{file}: ok ({} bytes, {} sections, every checksum and invariant holds; {:.3} s)",
                r.bytes_checked, r.sections_checked, self.seconds
            ),
            false => write!(
                f,
                "{file}: verification failed ({} defects)",
                r.defects.len()
            ),
        }
    }
}
