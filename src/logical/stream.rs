//! Streaming: a batch traced with its rays queued at the blocks they need (Pharr et al. 1997,
//! "Rendering complex scenes with memory-coherent ray tracing"; Navrátil et al. 2007; Eisenacher
//! et al. 2013), so that under a budget smaller than the file each block is read about once for
//! all the rays that need it, and the disk is read ahead of the tracing.
//!
//! **Parked walks.** A ray's top-down walk ([`Tree::run_held`]) is, between two blocks, exactly
//! its context (recomputed from the ray), its best hit so far ([`Best`]) and its stack of nodes
//! still to visit, whose top is the next block's node. When the walk reaches a node of another
//! block than the one held, it is *parked*: its ray index, best hit and stack are appended to
//! that block's queue. A block is *served* by taking its whole queue and resuming each walk
//! with the block's bytes; a walk ends with its answer, or parks at its next block. A resumed
//! walk does what it would have done had it waited for the block, so the answers are the direct
//! walk's, bit for bit (and a closest hit is the smallest `(t, primitive id)` over the
//! triangles tested in any order).
//!
//! **Wide first.** A walk is started as the wide walk (format 6's, [`Tree::wide_if_resident`]),
//! which answers the ray if every block it needs is resident and otherwise stops before reading
//! any; only then is the ray walked top-down from its start and parked. Under a budget that
//! holds most of the file, most rays are answered so, at the direct walk's cost (the answers
//! are the same: both walks give the direct walk's). A walk resumed in a served block, or a
//! shadow walk begun there, goes top-down at once (a thread holds one block at a time).
//!
//! **Scheduling.** All the rays are started first (as many as the parked walks' memory holds;
//! more as walks end), in Morton order of their entry point and direction
//! ([`super::RayKeys`]), each walking the top tree to its first block. Blocks with parked walks
//! are then served in two ways. A block that was resident when its first walk was parked is
//! *hot*: served first, at no cost if it still is. The others are served in a *sweep* in file
//! order (the next block with parked walks at or after the last one, wrapping to the start for
//! the next pass): neighbouring blocks are neighbouring regions and neighbouring bytes, a walk
//! that moves on to a later block is served in the same pass, and one that moves back finds
//! its block resident if the sweep passed it recently (else the next pass reads it once for
//! every walk parked there meanwhile). *Readers* (the threads beyond the workers, which mostly
//! sleep on the disk) claim the sweep's next blocks, admit them through the pager (read,
//! checksum, decode: the pager's admission, so a bad block is the same error as in a direct
//! walk) and hand them to the workers, at most `read_ahead` of them ahead; walks that park at a
//! claimed block join its queue and are served with it. *Workers* (one per core) serve blocks
//! the readers made ready, then hot ones, then start rays; with no reader, a worker claims and
//! reads the sweep's next block itself. A frame's shadow walk begins where its primary walk
//! ends, in the block being served ([`Job::light`]).
//!
//! **Memory.** The parked walks (their queues' capacity: 80 bytes a walk and 32 a stack entry)
//! are kept under `parked_bytes` (or one start chunk's walks, if that is larger: a limit too
//! small for one walk still traces, one ray at a time), which the caller takes out of the pager's budget for the
//! stream's duration; a worker's outbox (walks it parked, flushed every
//! [`FLUSH`] walks) and the answers (`(index, answer)` pairs, scattered at the end) are the
//! batch's own, as in a direct batch.
//!
//! **No deadlock.** One mutex guards the whole schedule; nobody holds it while reading a block
//! or tracing. Each thread holds at most one block at a time (a worker its served block, a
//! reader the block it admits, dropped at once), as the pager requires. Every wait is on the
//! condition variable of its kind (readers, workers), and whoever changes the schedule (a
//! block claimed or made ready, walks parked, a task taken or finished, a failure) wakes one
//! reader and one worker if each has something to do, all of them once the stream is done (a
//! thread woken for nothing waits again; one that takes work wakes the next); the stream ends when every ray has been
//! started and nothing is parked, claimed, ready or being traced.

use std::collections::{BTreeSet, VecDeque};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Condvar, Mutex, MutexGuard};

use super::held::Held;
use super::pager::PageCounters;
use super::trace::{Best, Counters, Entry, HitInfo, RayCtx, TraceError, Tree, WideEnd};
use crate::geom::Ray;
use crate::progress::Progress;
use crate::rays::shadow_ray;
use std::time::Instant;

/// Walks a worker parks before it hands them to the schedule (and so to the readers).
pub(crate) const FLUSH: usize = 1024;

/// Rays a worker starts at a time.
const START_CHUNK: usize = 256;

/// Bytes of a parked walk beyond its stack.
pub(crate) const HEAD_BYTES: u64 = std::mem::size_of::<Head>() as u64;
/// Bytes of a parked stack entry.
pub(crate) const ENTRY_BYTES: u64 = std::mem::size_of::<Entry>() as u64;

/// How a stream runs.
#[derive(Clone, Copy, Debug)]
pub(crate) struct StreamOptions {
    /// Threads that trace (at least 1).
    pub workers: usize,
    /// Threads that read blocks ahead (0: the workers read what they serve).
    pub readers: usize,
    /// Blocks admitted ahead of the workers, at most.
    pub read_ahead: usize,
    /// Memory for parked walks.
    pub parked_bytes: u64,
}

/// What a stream did, beyond the walks' counters (added to the batch's [`Counters`]).
#[derive(Clone, Copy, Debug, Default)]
struct StreamStats {
    /// Walks parked at a block (each resumed once).
    pub walks_parked: u64,
    /// Times a block's queue was served.
    pub blocks_served: u64,
    /// The most bytes the parked walks took at once.
    pub peak_parked_bytes: u64,
}

/// What a walk answers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    /// The closest hit of a ray of the batch.
    Closest,
    /// Whether a ray of the batch hits anything.
    Any,
    /// Whether the shadow ray of a ray of the batch (from its closest hit toward the light)
    /// hits anything.
    Shadow,
}

/// A parked walk: its ray (a shadow walk's is made again from its primary ray and `aux`, the
/// primary hit's `t`), its best hit so far and the length of its stack (whose entries follow
/// those of the walks before it in the queue's `entries`).
#[derive(Clone, Copy)]
struct Head {
    ray: u32,
    len: u32,
    kind: Kind,
    aux: f32,
    w: Best,
}

/// The walks parked at one block.
#[derive(Default)]
struct Queue {
    heads: Vec<Head>,
    entries: Vec<Entry>,
}

impl Queue {
    fn bytes(&self) -> u64 {
        self.heads.capacity() as u64 * HEAD_BYTES + self.entries.capacity() as u64 * ENTRY_BYTES
    }
}

/// The schedule: every queue, which blocks have walks parked and whether they are believed
/// resident, what is claimed, read and being traced.
struct Sched {
    queues: Vec<Queue>,
    /// Per block: claimed by a reader or a worker (being read, ready, or being served): walks
    /// parked there join its queue, and it is in neither `hot` nor `sweep`.
    claimed: Vec<bool>,
    /// Per block: in `hot`.
    is_hot: Vec<bool>,
    /// Blocks with parked walks that were resident when their first walk was parked: served
    /// first, at no cost if still resident.
    hot: Vec<u32>,
    /// The other blocks with parked walks, read in file order from `pos`.
    sweep: BTreeSet<u32>,
    /// The sweep's position: the last block claimed from it.
    pos: u32,
    /// Blocks admitted by readers, waiting for a worker.
    ready: VecDeque<u32>,
    /// Blocks readers are admitting now.
    reading: usize,
    /// Workers with a task.
    busy: usize,
    /// Rays started so far (in the start order).
    started: usize,
    parked: u64,
    stats: StreamStats,
    failed: Option<TraceError>,
}

impl Sched {
    /// Parks the walks of `out` (a worker's outbox) at their blocks; `resident` says whether
    /// a block is resident now.
    fn park(&mut self, out: &mut Outbox, resident: impl Fn(u32) -> bool) {
        let mut at = 0;
        for &(block, head) in &out.heads {
            let b = block as usize;
            let q = &mut self.queues[b];
            let (before, first) = (q.bytes(), q.heads.is_empty());
            q.heads.push(head);
            q.entries
                .extend_from_slice(&out.entries[at..at + head.len as usize]);
            at += head.len as usize;
            let after = q.bytes();
            self.parked = self.parked + after - before;
            if first && !self.claimed[b] {
                if resident(block) {
                    self.is_hot[b] = true;
                    self.hot.push(block);
                } else {
                    self.sweep.insert(block);
                }
            }
        }
        self.stats.walks_parked += out.heads.len() as u64;
        self.stats.peak_parked_bytes = self.stats.peak_parked_bytes.max(self.parked);
        out.heads.clear();
        out.entries.clear();
    }

    /// Claims a block with parked walks that was resident when they came.
    fn claim_hot(&mut self) -> Option<u32> {
        let b = self.hot.pop()?;
        self.is_hot[b as usize] = false;
        self.claimed[b as usize] = true;
        Some(b)
    }

    /// Claims the next block of the sweep: the first at or after its position, in file order
    /// (wrapping to the start: the next pass).
    fn claim_next(&mut self) -> Option<u32> {
        let b = match self.sweep.range(self.pos..).next() {
            Some(&b) => b,
            None => *self.sweep.iter().next()?,
        };
        self.sweep.remove(&b);
        self.claimed[b as usize] = true;
        self.pos = b;
        Some(b)
    }

    /// Takes a claimed block's queue to serve it, and unclaims the block.
    fn take(&mut self, b: u32) -> Queue {
        self.claimed[b as usize] = false;
        let q = std::mem::take(&mut self.queues[b as usize]);
        self.parked -= q.bytes();
        self.stats.blocks_served += 1;
        q
    }

    /// Whether no walk is parked at a block that is not claimed.
    fn nothing_parked(&self) -> bool {
        self.hot.is_empty() && self.sweep.is_empty()
    }

    fn done(&self, n: usize) -> bool {
        self.failed.is_some()
            || (self.started == n
                && self.busy == 0
                && self.reading == 0
                && self.ready.is_empty()
                && self.nothing_parked())
    }
}

/// Walks a worker parked, not yet handed to the schedule.
#[derive(Default)]
struct Outbox {
    heads: Vec<(u32, Head)>,
    entries: Vec<Entry>,
}

/// What a worker does next.
enum Task {
    /// Serve a block (already admitted by a reader, or to be read by the worker).
    Serve(u32),
    /// Start the rays `start_order[from..to]`.
    Start(usize, usize),
    Exit,
}

/// What a stream traces: the batch's rays, closest or any hit, and for a frame the light its
/// closest hits cast shadow rays toward.
pub(crate) struct Job<'j, M> {
    pub rays: &'j [Ray],
    /// Any hit (else closest hit).
    pub any: bool,
    /// With closest hits: the shadow ray of each hit, toward this light, is traced in the
    /// same stream ([`crate::rays::shadow_ray`]).
    pub light: Option<[f32; 3]>,
    /// Which hits cast their shadow ray (all of a frame's; a renderer's lit side only).
    pub casts: fn(&Ray, &HitInfo, [f32; 3]) -> bool,
    /// The answer of ray `i` from its hit.
    pub map: M,
}

/// [`Job::casts`] for a frame: every hit casts its shadow ray.
pub(crate) fn every_hit(_: &Ray, _: &HitInfo, _: [f32; 3]) -> bool {
    true
}

/// What one thread found: its walks' counters (the batch's rays, and the shadow rays), the
/// batch's answers and the shadow answers (by primary ray), and the time it spent walking
/// each kind (for a frame's split of its time).
struct Found<T> {
    k: [Counters; 2],
    answers: Vec<(u32, T)>,
    shadows: Vec<(u32, u8)>,
    nanos: [u64; 2],
}

impl<T> Default for Found<T> {
    fn default() -> Self {
        Found {
            k: [Counters::default(); 2],
            answers: Vec::new(),
            shadows: Vec::new(),
            nanos: [0; 2],
        }
    }
}

/// What a stream answered (see [`Stream::run`]).
pub(crate) struct Streamed {
    /// The walks' counters: the batch's rays, and the shadow rays.
    pub counters: [Counters; 2],
    /// The share of the time spent walking shadow rays (0 without a light).
    pub shadow_share: f64,
}

/// A worker's scratch: the stacks of the walk being resumed.
#[derive(Default)]
struct Scratch {
    stack: Vec<Entry>,
    cluster: Vec<(u32, f32, u8)>,
}

/// Where a stream gets blocks and how it answers.
pub(crate) struct Stream<'t, 'a> {
    pub tree: &'t Tree<'a>,
    pub opts: StreamOptions,
    /// Told the rays answered and the blocks read as they go.
    pub progress: Option<&'t dyn Progress>,
}

/// Where readers and workers wait for something to do.
#[derive(Default)]
struct Wake {
    readers: Condvar,
    workers: Condvar,
}

/// Rays answered and blocks read so far, for the progress report.
#[derive(Default)]
struct Tally {
    answered: AtomicU64,
    read: AtomicU64,
    /// `answered` when the report was last updated.
    reported: AtomicU64,
}

impl Stream<'_, '_> {
    /// Traces `job`'s rays, starting them in `start_order`: each ray's answer `map(ray, hit)`
    /// goes to `out` (at its index), and with a light each hit's shadow answer (1: occluded)
    /// to `shadows` (at its primary ray's index; rays without a hit keep what `shadows`
    /// held).
    pub fn run<T: Send + Copy, M: Fn(&Ray, Option<HitInfo>) -> T + Sync>(
        &self,
        job: &Job<'_, M>,
        start_order: &[u32],
        out: &mut [T],
        shadows: &mut [u8],
    ) -> Result<Streamed, TraceError> {
        let n = start_order.len();
        let blocks = self.tree.block_count();
        let sched = Mutex::new(Sched {
            queues: (0..blocks).map(|_| Queue::default()).collect(),
            claimed: vec![false; blocks],
            is_hot: vec![false; blocks],
            hot: Vec::new(),
            sweep: BTreeSet::new(),
            pos: 0,
            ready: VecDeque::new(),
            reading: 0,
            busy: 0,
            started: 0,
            parked: 0,
            stats: StreamStats::default(),
            failed: None,
        });
        let wake = Wake::default();
        let tally = Tally::default();
        if let Some(p) = self.progress {
            p.phase("tracing", Some(n as u64), false);
        }
        let workers = self.opts.workers.max(1);
        let readers = self.opts.readers;
        let results: Vec<Result<Found<T>, TraceError>> = std::thread::scope(|s| {
            let mut handles = Vec::new();
            for _ in 0..readers {
                handles.push(s.spawn(|| {
                    self.reader(&sched, &wake, n, &tally).map(|page| {
                        let mut f = Found::default();
                        f.k[0].page = page;
                        f
                    })
                }));
            }
            for _ in 0..workers {
                handles.push(s.spawn(|| self.worker(&sched, &wake, job, start_order, &tally)));
            }
            handles
                .into_iter()
                .map(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p)))
                .collect()
        });
        let sched = sched.into_inner().unwrap_or_else(|p| p.into_inner());
        if let Some(e) = sched.failed {
            return Err(e);
        }
        let mut counters = [Counters::default(); 2];
        let mut nanos = [0u64; 2];
        for r in results {
            let f = r?;
            for j in 0..2 {
                counters[j] += f.k[j];
                nanos[j] += f.nanos[j];
            }
            for (i, a) in f.answers {
                out[i as usize] = a;
            }
            for (i, o) in f.shadows {
                shadows[i as usize] = o;
            }
        }
        let c = &mut counters[0];
        c.walks_parked = sched.stats.walks_parked;
        c.blocks_served = sched.stats.blocks_served;
        c.peak_parked_bytes = sched.stats.peak_parked_bytes;
        let total = (nanos[0] + nanos[1]).max(1);
        Ok(Streamed {
            counters,
            shadow_share: nanos[1] as f64 / total as f64,
        })
    }

    fn lock<'s>(&self, m: &'s Mutex<Sched>) -> MutexGuard<'s, Sched> {
        m.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Rays started at a time: [`START_CHUNK`], fewer if the parked walks' limit is small
    /// (at least one).
    fn start_chunk(&self) -> usize {
        let per_walk = HEAD_BYTES + 16 * ENTRY_BYTES;
        usize::try_from(self.opts.parked_bytes / 4 / per_walk)
            .unwrap_or(usize::MAX)
            .clamp(1, START_CHUNK)
    }

    /// Room a start chunk may take: every walk parked with a deep stack.
    fn start_reserve(&self) -> u64 {
        self.start_chunk() as u64 * (HEAD_BYTES + 16 * ENTRY_BYTES)
    }

    /// A reader: claims blocks in the sweep's order, admits them, hands them to the workers.
    fn reader(
        &self,
        m: &Mutex<Sched>,
        wake: &Wake,
        n: usize,
        tally: &Tally,
    ) -> Result<PageCounters, TraceError> {
        let mut page = PageCounters::default();
        let mut s = self.lock(m);
        loop {
            if s.done(n) {
                return Ok(page);
            }
            let Some(b) = self.reader_can(&s, n).then(|| s.claim_next()).flatten() else {
                s = wake.readers.wait(s).unwrap_or_else(|p| p.into_inner());
                continue;
            };
            s.reading += 1;
            self.kick(&s, n, wake);
            drop(s);
            let misses = page.misses;
            let got = self.tree.admit(b, &mut page);
            tally
                .read
                .fetch_add(page.misses - misses, Ordering::Relaxed);
            s = self.lock(m);
            s.reading -= 1;
            match got {
                Ok(()) => s.ready.push_back(b),
                Err(e) => {
                    s.failed.get_or_insert(e);
                }
            }
            self.kick(&s, n, wake);
        }
    }

    /// Whether the rays still to start fit in the parked walks' memory: then workers start
    /// them, and readers wait (a block claimed earlier would be served with the few walks
    /// parked there so far).
    fn filling(&self, s: &Sched, n: usize) -> bool {
        s.started < n && s.parked + self.start_reserve() <= self.opts.parked_bytes
    }

    /// Whether a reader has a block to claim.
    fn reader_can(&self, s: &Sched, n: usize) -> bool {
        !self.filling(s, n)
            && s.ready.len() + s.reading < self.opts.read_ahead
            && !s.sweep.is_empty()
    }

    /// Whether a worker has something to do (see [`Self::worker`]).
    fn worker_can(&self, s: &Sched, n: usize) -> bool {
        !s.ready.is_empty()
            || !s.hot.is_empty()
            || self.filling(s, n)
            || (self.opts.readers == 0 && !s.sweep.is_empty())
            || self.stalled(s, n)
    }

    /// Nothing is parked, read or traced, and rays are left that the parked walks' limit
    /// holds no chunk of (a chunk of one walk whose stack is deeper than most): one is
    /// started anyway.
    fn stalled(&self, s: &Sched, n: usize) -> bool {
        s.started < n && s.busy == 0 && s.reading == 0 && s.ready.is_empty() && s.nothing_parked()
    }

    /// Wakes a reader and a worker if each has something to do (all of them when the
    /// stream is done). Called, holding the schedule's lock, after every change to it: a
    /// thread woken for nothing waits again, and one that takes work kicks the next.
    fn kick(&self, s: &Sched, n: usize, wake: &Wake) {
        if s.done(n) {
            wake.readers.notify_all();
            wake.workers.notify_all();
            return;
        }
        if self.opts.readers > 0 && self.reader_can(s, n) {
            wake.readers.notify_one();
        }
        if self.worker_can(s, n) {
            wake.workers.notify_one();
        }
    }

    /// A worker: serves ready blocks (then those believed resident), starts rays, and
    /// (without readers) reads blocks in the sweep's order.
    fn worker<T: Send + Copy, M: Fn(&Ray, Option<HitInfo>) -> T + Sync>(
        &self,
        m: &Mutex<Sched>,
        wake: &Wake,
        job: &Job<'_, M>,
        start_order: &[u32],
        tally: &Tally,
    ) -> Result<Found<T>, TraceError> {
        let n = start_order.len();
        let mut f = Found::default();
        let mut out = Outbox::default();
        let mut x = Scratch::default();
        let chunk = self.start_chunk();
        loop {
            let task = {
                let mut s = self.lock(m);
                loop {
                    if s.done(n) {
                        self.kick(&s, n, wake);
                        break Task::Exit;
                    }
                    let task = if let Some(b) = s.ready.pop_front().or_else(|| s.claim_hot()) {
                        Some(Task::Serve(b))
                    } else if self.filling(&s, n) || self.stalled(&s, n) {
                        let from = s.started;
                        s.started = (from + chunk).min(n);
                        Some(Task::Start(from, s.started))
                    } else if self.opts.readers == 0 {
                        s.claim_next().map(Task::Serve)
                    } else {
                        None
                    };
                    if let Some(t) = task {
                        s.busy += 1;
                        self.kick(&s, n, wake);
                        break t;
                    }
                    s = wake.workers.wait(s).unwrap_or_else(|p| p.into_inner());
                }
            };
            let (answers, misses) = (f.answers.len(), f.k[0].page.misses);
            let result = match task {
                Task::Exit => return Ok(f),
                Task::Serve(b) => {
                    let q = self.lock(m).take(b);
                    self.serve(b, q, job, &mut f, &mut out, &mut x, m, wake, n)
                }
                Task::Start(from, to) => start_order[from..to].iter().try_for_each(|&i| {
                    let kind = if job.any { Kind::Any } else { Kind::Closest };
                    self.begin(kind, i, 0.0, job, &mut f, &mut out, &mut x, None)
                }),
            };
            tally
                .answered
                .fetch_add((f.answers.len() - answers) as u64, Ordering::Relaxed);
            tally
                .read
                .fetch_add(f.k[0].page.misses - misses, Ordering::Relaxed);
            self.report(tally, n);
            let mut s = self.lock(m);
            s.park(&mut out, |b| self.tree.resident(b));
            s.busy -= 1;
            if let Err(e) = result {
                s.failed.get_or_insert(e);
            }
            self.kick(&s, n, wake);
        }
    }

    /// Updates the progress report every 1/1000 of the rays (or at the end).
    fn report(&self, tally: &Tally, n: usize) {
        let Some(p) = self.progress else { return };
        let done = tally.answered.load(Ordering::Relaxed);
        let last = tally.reported.load(Ordering::Relaxed);
        if (done - last.min(done)) * 1000 >= n as u64 || done == n as u64 {
            tally.reported.store(done, Ordering::Relaxed);
            p.at(done);
            p.note(&format!(
                "{} blocks read",
                tally.read.load(Ordering::Relaxed)
            ));
        }
    }

    /// Serves block `b`: resumes every walk of its queue with the block's bytes.
    #[allow(clippy::too_many_arguments)]
    fn serve<T: Copy, M: Fn(&Ray, Option<HitInfo>) -> T>(
        &self,
        b: u32,
        q: Queue,
        job: &Job<'_, M>,
        f: &mut Found<T>,
        out: &mut Outbox,
        x: &mut Scratch,
        m: &Mutex<Sched>,
        wake: &Wake,
        n: usize,
    ) -> Result<(), TraceError> {
        let (_, bytes, ready) = self.tree.fetch(b, &mut f.k[0].page)?;
        let held = Held::new(b, ready, &bytes);
        let mut at = 0;
        for head in &q.heads {
            let len = head.len as usize;
            x.stack.clear();
            x.stack.extend_from_slice(&q.entries[at..at + len]);
            at += len;
            let ray = self.ray_of(head.kind, head.ray, head.aux, job);
            let Some(r) = self.tree.context(&ray) else {
                // Not reached: a walk is parked only for a ray with a context.
                self.finish(
                    head.kind,
                    head.ray,
                    head.w.best,
                    job,
                    f,
                    out,
                    x,
                    Some(&held),
                )?;
                continue;
            };
            let (kind, i, aux) = (head.kind, head.ray, head.aux);
            self.advance(kind, i, aux, &r, head.w, job, f, out, x, Some(&held))?;
            if out.heads.len() >= FLUSH {
                let mut s = self.lock(m);
                s.park(out, |b| self.tree.resident(b));
                self.kick(&s, n, wake);
            }
        }
        Ok(())
    }

    /// The ray a walk of `kind` for ray `i` traces.
    fn ray_of<M>(&self, kind: Kind, i: u32, aux: f32, job: &Job<'_, M>) -> Ray {
        let ray = &job.rays[i as usize];
        match (kind, job.light) {
            (Kind::Shadow, Some(light)) => shadow_ray(ray, aux, light),
            _ => *ray,
        }
    }

    /// Starts a walk of `kind` for ray `i` (with `held`, the block being served, if any): it
    /// walks the top tree and that block until it is answered or parks.
    #[allow(clippy::too_many_arguments)]
    fn begin<T: Copy, M: Fn(&Ray, Option<HitInfo>) -> T>(
        &self,
        kind: Kind,
        i: u32,
        aux: f32,
        job: &Job<'_, M>,
        f: &mut Found<T>,
        out: &mut Outbox,
        x: &mut Scratch,
        held: Option<&Held<'_>>,
    ) -> Result<(), TraceError> {
        let ray = self.ray_of(kind, i, aux, job);
        let set = (kind == Kind::Shadow) as usize;
        // Walked wide while every block it needs is resident (no block held: the pager gives
        // a thread one block at a time); parked only where a block must be read.
        if held.is_none() {
            let timed = job.light.map(|_| Instant::now());
            let k = &mut f.k[set];
            let end = match kind {
                Kind::Closest => self.tree.wide_if_resident::<false>(&ray, k)?,
                Kind::Any | Kind::Shadow => self.tree.wide_if_resident::<true>(&ray, k)?,
            };
            if let Some(t) = timed {
                f.nanos[set] += t.elapsed().as_nanos() as u64;
            }
            if let WideEnd::Answered(best) = end {
                f.k[set].walks_unparked += 1;
                return self.finish(kind, i, best, job, f, out, x, held);
            }
        }
        match self.tree.begin(&ray, &mut x.stack, &mut f.k[set])? {
            None => self.finish(kind, i, None, job, f, out, x, held),
            Some((r, w)) => self.advance(kind, i, aux, &r, w, job, f, out, x, held),
        }
    }

    /// Resumes a walk (its ray's context `r`, its stack in `x.stack`) with `held`: answered,
    /// or parked at its next block.
    #[allow(clippy::too_many_arguments)]
    fn advance<T: Copy, M: Fn(&Ray, Option<HitInfo>) -> T>(
        &self,
        kind: Kind,
        i: u32,
        aux: f32,
        r: &RayCtx,
        mut w: Best,
        job: &Job<'_, M>,
        f: &mut Found<T>,
        out: &mut Outbox,
        x: &mut Scratch,
        held: Option<&Held<'_>>,
    ) -> Result<(), TraceError> {
        let set = (kind == Kind::Shadow) as usize;
        let timed = job.light.map(|_| Instant::now());
        let (k, stack, cluster) = (&mut f.k[set], &mut x.stack, &mut x.cluster);
        let next = match kind {
            Kind::Closest => self
                .tree
                .resume::<false>(r, &mut w, k, stack, cluster, held)?,
            Kind::Any | Kind::Shadow => self
                .tree
                .resume::<true>(r, &mut w, k, stack, cluster, held)?,
        };
        if let Some(t) = timed {
            f.nanos[set] += t.elapsed().as_nanos() as u64;
        }
        match next {
            Some(b) => {
                out.heads.push((
                    b,
                    Head {
                        ray: i,
                        len: x.stack.len() as u32,
                        kind,
                        aux,
                        w,
                    },
                ));
                out.entries.extend_from_slice(&x.stack);
                Ok(())
            }
            None => self.finish(kind, i, w.best, job, f, out, x, held),
        }
    }

    /// A walk's answer; a closest hit with a light begins its shadow walk at once (it starts
    /// where the hit is, most often in the block held).
    #[allow(clippy::too_many_arguments)]
    fn finish<T: Copy, M: Fn(&Ray, Option<HitInfo>) -> T>(
        &self,
        kind: Kind,
        i: u32,
        best: Option<HitInfo>,
        job: &Job<'_, M>,
        f: &mut Found<T>,
        out: &mut Outbox,
        x: &mut Scratch,
        held: Option<&Held<'_>>,
    ) -> Result<(), TraceError> {
        match kind {
            Kind::Shadow => f.shadows.push((i, best.is_some() as u8)),
            Kind::Closest | Kind::Any => {
                f.answers.push((i, (job.map)(&job.rays[i as usize], best)));
                if let (Kind::Closest, Some(light), Some(h)) = (kind, job.light, best)
                    && (job.casts)(&job.rays[i as usize], &h, light)
                {
                    return self.begin(Kind::Shadow, i, h.t, job, f, out, x, held);
                }
            }
        }
        Ok(())
    }
}
