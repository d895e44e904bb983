//! What a traced set of rays reports: its work counters, per ray, and the pager's figures, in
//! the shape `oavm-trace --json` prints them ([`SetReport`]); a traced frame's sets, each with a
//! digest of its answers, and their total ([`FrameFigures`], `oavm-trace`'s benchmark mode);
//! what a whole run reports around them ([`TraceRun`], [`RunReport`]); and a file's timed
//! verification ([`Verification`]).

use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use super::frame::Frame;
use super::order::Order;
use super::pager::{BlockSource, PageCounters};
use super::scene::{Scene, SceneInfo, SceneOptions};
use super::trace::Counters;
use super::verify::VerifyReport;
use crate::error::Error;

/// The pager's counters with the hit rate and the bytes read per ray.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct PageReport {
    #[serde(flatten)]
    pub counters: PageCounters,
    pub hit_rate: f64,
    pub bytes_read_per_ray: f64,
}

impl PageReport {
    pub fn new(c: &Counters) -> PageReport {
        PageReport {
            counters: c.page,
            hit_rate: c.page.hits as f64 / c.page.requested.max(1) as f64,
            bytes_read_per_ray: c.page.bytes_read as f64 / c.rays.max(1) as f64,
        }
    }

    /// The figures as a clause of a line of text, `"; pager: 120 blocks asked, 3 misses (97.5
    /// % hits), 1.2 MB read (10 B/ray), peak 5.0 MB resident of 512.0 MB"`, with the scene's
    /// peak resident bytes and budget ([`super::Scene::peak_resident_bytes`],
    /// [`super::Scene::budget`]).
    pub fn clause(&self, peak_resident_bytes: u64, budget: u64) -> String {
        format!(
            "; pager: {} blocks asked, {} misses ({:.1} % hits), {:.1} MB read ({:.0} B/ray), \
             peak {:.1} MB resident of {:.1} MB",
            self.counters.requested,
            self.counters.misses,
            100.0 * self.hit_rate,
            self.counters.bytes_read as f64 / 1e6,
            self.bytes_read_per_ray,
            peak_resident_bytes as f64 / 1e6,
            budget as f64 / 1e6,
        )
    }
}

/// The figures of one set of rays traced in `seconds`.
#[derive(Clone, Debug, Serialize)]
pub struct SetReport {
    pub rays: u64,
    /// Rays that hit something (closest-hit sets).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hits: Option<u64>,
    /// Rays occluded (any-hit sets).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub occluded: Option<u64>,
    pub seconds: f64,
    pub mrays_per_s: f64,
    pub nodes_visited: u64,
    pub leaves_visited: u64,
    pub volumes_crossed: u64,
    pub leaves_culled: u64,
    pub links_culled: u64,
    pub top_nodes_culled: u64,
    pub triangles_tested: u64,
    pub clusters_entered: u64,
    pub cluster_nodes_visited: u64,
    pub boxes_tested: u64,
    pub groups_tested: u64,
    /// Ropes followed (`--walk ropes`, spec §8.4; 0 elsewhere).
    pub ropes_followed: u64,
    pub nodes_visited_per_ray: f64,
    pub leaves_visited_per_ray: f64,
    pub volumes_crossed_per_ray: f64,
    pub triangles_tested_per_ray: f64,
    pub clusters_entered_per_ray: f64,
    pub cluster_nodes_visited_per_ray: f64,
    pub boxes_tested_per_ray: f64,
    pub groups_tested_per_ray: f64,
    pub ropes_followed_per_ray: f64,
    /// Streamed sets ([`super::Order::Stream`]): walks parked at a block and resumed, times a
    /// block's queue was served, and the most bytes the parked walks took at once.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stream: Option<StreamReport>,
    pub page: PageReport,
}

/// What a stream did (see [`SetReport::stream`]).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct StreamReport {
    pub walks_parked: u64,
    pub walks_parked_per_ray: f64,
    pub blocks_served: u64,
    pub peak_parked_bytes: u64,
}

/// What a set's rays answered: how many hit (closest hit) or were occluded (any hit).
#[derive(Clone, Copy, Debug)]
pub enum Answered {
    Hits(u64),
    Occluded(u64),
    /// A total over sets of both kinds.
    Mixed,
}

impl SetReport {
    pub fn new(c: &Counters, seconds: f64, answered: Answered) -> SetReport {
        let per_ray = |x: u64| x as f64 / c.rays.max(1) as f64;
        let (hits, occluded) = match answered {
            Answered::Hits(n) => (Some(n), None),
            Answered::Occluded(n) => (None, Some(n)),
            Answered::Mixed => (None, None),
        };
        SetReport {
            rays: c.rays,
            hits,
            occluded,
            seconds,
            mrays_per_s: c.rays as f64 / seconds.max(1e-12) / 1e6,
            nodes_visited: c.nodes_visited,
            leaves_visited: c.leaves_visited,
            volumes_crossed: c.volumes_crossed,
            leaves_culled: c.leaves_culled,
            links_culled: c.links_culled,
            top_nodes_culled: c.top_nodes_culled,
            triangles_tested: c.triangles_tested,
            clusters_entered: c.clusters_entered,
            cluster_nodes_visited: c.cluster_nodes_visited,
            boxes_tested: c.boxes_tested,
            groups_tested: c.groups_tested,
            ropes_followed: c.ropes_followed,
            nodes_visited_per_ray: per_ray(c.nodes_visited),
            leaves_visited_per_ray: per_ray(c.leaves_visited),
            volumes_crossed_per_ray: per_ray(c.volumes_crossed),
            triangles_tested_per_ray: per_ray(c.triangles_tested),
            clusters_entered_per_ray: per_ray(c.clusters_entered),
            cluster_nodes_visited_per_ray: per_ray(c.cluster_nodes_visited),
            boxes_tested_per_ray: per_ray(c.boxes_tested),
            groups_tested_per_ray: per_ray(c.groups_tested),
            ropes_followed_per_ray: per_ray(c.ropes_followed),
            stream: (c.blocks_served > 0).then(|| StreamReport {
                walks_parked: c.walks_parked,
                walks_parked_per_ray: per_ray(c.walks_parked),
                blocks_served: c.blocks_served,
                peak_parked_bytes: c.peak_parked_bytes,
            }),
            page: PageReport::new(c),
        }
    }

    /// What the set's rays answered (as given to [`SetReport::new`]).
    pub fn answered(&self) -> Answered {
        match (self.hits, self.occluded) {
            (Some(n), _) => Answered::Hits(n),
            (_, Some(n)) => Answered::Occluded(n),
            _ => Answered::Mixed,
        }
    }
}

/// `12 hits`, `3 occluded`, or `hits and occluded` for a total over both kinds.
impl fmt::Display for Answered {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Answered::Hits(n) => write!(f, "{n} hits"),
            Answered::Occluded(n) => write!(f, "{n} occluded"),
            Answered::Mixed => f.write_str("hits and occluded"),
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
