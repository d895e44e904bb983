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
//! **Scheduling.** Parked walks are counted per block, and blocks are bucketed by
//! `floor(log2(count))`. The block served next is one of the fullest bucket, the first at or
//! after the last one chosen in file order (a sweep: neighbouring blocks are neighbouring
//! regions and neighbouring bytes). *Readers* (the threads beyond the workers, which sleep on
//! the disk) claim blocks that way, admit them through the pager (read, checksum, decode: the
//! pager's admission, so a bad block is the same error as in a direct walk), and hand them to
//! the workers in a ready queue, at most `read_ahead` of them ahead; walks that park at a
//! claimed block join its queue and are served with it. *Workers* (one per core) serve ready
//! blocks first; otherwise they start new rays (in Morton order of their entry point and
//! direction, [`super::RayKeys`]: rays started together need the same blocks) while the
//! parked walks' memory is under its limit; with no reader, a worker claims and reads the next
//! block itself.
//!
//! **Memory.** The parked walks (their queues' capacity: 72 bytes a walk and 32 a stack entry)
//! are kept under `parked_bytes` (or one start chunk's walks, if that is larger: a limit too
//! small for one walk still traces, one ray at a time), which the caller takes out of the pager's budget for the
//! stream's duration; a worker's outbox (walks it parked, flushed every
//! [`FLUSH`] walks) and the answers (`(index, answer)` pairs, scattered at the end) are the
//! batch's own, as in a direct batch.
//!
//! **No deadlock.** One mutex guards the whole schedule; nobody holds it while reading a block
//! or tracing. Each thread holds at most one block at a time (a worker its served block, a
//! reader the block it admits, dropped at once), as the pager requires. Every wait is on the
//! condition variable, and whoever changes what others wait for (a block made ready, walks
//! parked, a task finished, a failure) notifies all; the stream ends when every ray has been
//! started and nothing is parked, claimed, ready or being traced.

use std::collections::{BTreeSet, VecDeque};
use std::sync::{Condvar, Mutex, MutexGuard};

use super::held::Held;
use super::pager::PageCounters;
use super::trace::{Best, Counters, Entry, HitInfo, TraceError, Tree};
use crate::geom::Ray;

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

/// What a stream did, beyond the walks' counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct StreamStats {
    /// Walks parked at a block (each resumed once).
    pub walks_parked: u64,
    /// Times a block's queue was served.
    pub blocks_served: u64,
    /// The most bytes the parked walks took at once.
    pub peak_parked_bytes: u64,
    /// The limit they were kept under.
    pub parked_bytes_limit: u64,
}

/// A parked walk: its ray, its best hit so far and the length of its stack (whose entries
/// follow those of the walks before it in the queue's `entries`).
#[derive(Clone, Copy)]
struct Head {
    ray: u32,
    len: u32,
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

/// The schedule: every queue, the buckets of blocks by queue length, what is claimed, read
/// and being traced.
struct Sched {
    queues: Vec<Queue>,
    /// Per block: claimed by a reader or a worker (being read, or ready): walks parked there
    /// join its queue, and it is in no bucket.
    claimed: Vec<bool>,
    /// Blocks with parked walks and not claimed, by `floor(log2(walks))`.
    buckets: Vec<BTreeSet<u32>>,
    /// The last block chosen (the sweep's position).
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

fn bucket(walks: usize) -> usize {
    (usize::BITS - 1 - walks.leading_zeros()) as usize
}

impl Sched {
    /// Parks the walks of `out` (a worker's outbox) at their blocks.
    fn park(&mut self, out: &mut Outbox) {
        let mut at = 0;
        for &(block, head) in &out.heads {
            let b = block as usize;
            let q = &mut self.queues[b];
            let (before, walks) = (q.bytes(), q.heads.len());
            q.heads.push(head);
            q.entries
                .extend_from_slice(&out.entries[at..at + head.len as usize]);
            at += head.len as usize;
            let after = q.bytes();
            self.parked = self.parked + after - before;
            if !self.claimed[b] {
                if walks > 0 {
                    self.buckets[bucket(walks)].remove(&block);
                }
                self.buckets[bucket(walks + 1)].insert(block);
            }
        }
        self.stats.walks_parked += out.heads.len() as u64;
        self.stats.peak_parked_bytes = self.stats.peak_parked_bytes.max(self.parked);
        out.heads.clear();
        out.entries.clear();
    }

    /// Claims the next block to read: in the fullest bucket, the first at or after the last
    /// one chosen (wrapping).
    fn claim(&mut self) -> Option<u32> {
        let set = self.buckets.iter_mut().rev().find(|s| !s.is_empty())?;
        let b = match set.range(self.pos..).next() {
            Some(&b) => b,
            None => *set.iter().next()?,
        };
        set.remove(&b);
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

    fn done(&self, n: usize) -> bool {
        self.failed.is_some()
            || (self.started == n
                && self.busy == 0
                && self.reading == 0
                && self.ready.is_empty()
                && self.buckets.iter().all(BTreeSet::is_empty))
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

/// Where a stream gets blocks and how it answers.
pub(crate) struct Stream<'t, 'a> {
    pub tree: &'t Tree<'a>,
    pub opts: StreamOptions,
}

impl Stream<'_, '_> {
    /// Traces `rays` (closest hit, or with `ANY` any hit), starting them in `start_order`;
    /// returns each ray's answer (`None`: no hit) as `map(ray, answer)` in `out`, the walks'
    /// counters and the stream's statistics.
    pub fn run<const ANY: bool, T: Send + Copy>(
        &self,
        rays: &[Ray],
        start_order: &[u32],
        out: &mut [T],
        map: impl Fn(&Ray, Option<HitInfo>) -> T + Sync,
    ) -> Result<(Counters, StreamStats), TraceError> {
        let n = start_order.len();
        let blocks = self.tree.block_count();
        let sched = Mutex::new(Sched {
            queues: (0..blocks).map(|_| Queue::default()).collect(),
            claimed: vec![false; blocks],
            buckets: (0..usize::BITS).map(|_| BTreeSet::new()).collect(),
            pos: 0,
            ready: VecDeque::new(),
            reading: 0,
            busy: 0,
            started: 0,
            parked: 0,
            stats: StreamStats {
                parked_bytes_limit: self.opts.parked_bytes,
                ..StreamStats::default()
            },
            failed: None,
        });
        let wake = Condvar::new();
        let workers = self.opts.workers.max(1);
        let readers = self.opts.readers;
        let results: Vec<Result<(Counters, Vec<(u32, T)>), TraceError>> =
            std::thread::scope(|s| {
                let mut handles = Vec::new();
                for _ in 0..readers {
                    handles.push(s.spawn(|| {
                        self.reader(&sched, &wake, n)
                            .map(|page| (Counters { page, ..Counters::default() }, Vec::new()))
                    }));
                }
                for _ in 0..workers {
                    handles.push(s.spawn(|| {
                        self.worker::<ANY, T>(&sched, &wake, n, rays, start_order, &map)
                    }));
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
        let mut total = Counters::default();
        for r in results {
            let (c, answers) = r?;
            total += c;
            for (i, a) in answers {
                out[i as usize] = a;
            }
        }
        Ok((total, sched.stats))
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

    fn lock<'s>(&self, m: &'s Mutex<Sched>) -> MutexGuard<'s, Sched> {
        m.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// A reader: claims blocks, admits them, hands them to the workers.
    fn reader(&self, m: &Mutex<Sched>, wake: &Condvar, n: usize) -> Result<PageCounters, TraceError> {
        let mut page = PageCounters::default();
        let mut s = self.lock(m);
        loop {
            if s.done(n) {
                return Ok(page);
            }
            // Blocks are read once the walks fill their memory (or every ray is started): a
            // block claimed earlier would be served with the few walks parked there so far.
            let filling = s.started < n && s.parked + self.start_reserve() <= self.opts.parked_bytes;
            let room = !filling && s.ready.len() + s.reading < self.opts.read_ahead;
            let Some(b) = room.then(|| s.claim()).flatten() else {
                s = wake.wait(s).unwrap_or_else(|p| p.into_inner());
                continue;
            };
            s.reading += 1;
            drop(s);
            let got = self.tree.admit(b, &mut page);
            s = self.lock(m);
            s.reading -= 1;
            match got {
                Ok(()) => s.ready.push_back(b),
                Err(e) => {
                    s.failed.get_or_insert(e);
                }
            }
            wake.notify_all();
        }
    }

    /// A worker: serves ready blocks, starts rays, and (without readers) reads blocks.
    #[allow(clippy::too_many_arguments)]
    fn worker<const ANY: bool, T: Send + Copy>(
        &self,
        m: &Mutex<Sched>,
        wake: &Condvar,
        n: usize,
        rays: &[Ray],
        start_order: &[u32],
        map: &(impl Fn(&Ray, Option<HitInfo>) -> T + Sync),
    ) -> Result<(Counters, Vec<(u32, T)>), TraceError> {
        let mut k = Counters::default();
        let mut answers: Vec<(u32, T)> = Vec::new();
        let mut out = Outbox::default();
        let mut stack: Vec<Entry> = Vec::new();
        let mut cluster_stack = Vec::new();
        let start_reserve = self.start_reserve();
        let chunk = self.start_chunk();
        loop {
            let task = {
                let mut s = self.lock(m);
                loop {
                    if s.done(n) {
                        wake.notify_all();
                        break Task::Exit;
                    }
                    if let Some(b) = s.ready.pop_front() {
                        break Task::Serve(b);
                    }
                    if s.started < n && s.parked + start_reserve <= self.opts.parked_bytes {
                        let from = s.started;
                        s.started = (from + chunk).min(n);
                        break Task::Start(from, s.started);
                    }
                    if self.opts.readers == 0
                        && let Some(b) = s.claim()
                    {
                        break Task::Serve(b);
                    }
                    if s.started < n
                        && s.busy == 0
                        && s.reading == 0
                        && s.ready.is_empty()
                        && s.buckets.iter().all(BTreeSet::is_empty)
                    {
                        // Nothing parked and the limit too small for a chunk (a chunk of one
                        // walk whose stack is deeper than most): start it anyway.
                        let from = s.started;
                        s.started = (from + chunk).min(n);
                        break Task::Start(from, s.started);
                    }
                    s = wake.wait(s).unwrap_or_else(|p| p.into_inner());
                }
            };
            let queue = match task {
                Task::Exit => return Ok((k, answers)),
                Task::Serve(b) => {
                    let mut s = self.lock(m);
                    s.busy += 1;
                    Some((b, s.take(b)))
                }
                Task::Start(..) => {
                    self.lock(m).busy += 1;
                    None
                }
            };
            let result = match (&task, queue) {
                (Task::Serve(b), Some((_, q))) => self.serve::<ANY, T>(
                    *b,
                    q,
                    rays,
                    map,
                    &mut k,
                    &mut answers,
                    &mut out,
                    &mut stack,
                    &mut cluster_stack,
                    m,
                    wake,
                ),
                (Task::Start(from, to), _) => {
                    let mut r = Ok(());
                    for &i in &start_order[*from..*to] {
                        r = self.start::<ANY, T>(
                            i,
                            rays,
                            map,
                            &mut k,
                            &mut answers,
                            &mut out,
                            &mut stack,
                            &mut cluster_stack,
                        );
                        if r.is_err() {
                            break;
                        }
                    }
                    r
                }
                _ => Ok(()),
            };
            let mut s = self.lock(m);
            s.park(&mut out);
            s.busy -= 1;
            if let Err(e) = result {
                s.failed.get_or_insert(e);
            }
            wake.notify_all();
        }
    }

    /// Starts ray `i`: walks the top tree until it is answered or parks.
    #[allow(clippy::too_many_arguments)]
    fn start<const ANY: bool, T: Copy>(
        &self,
        i: u32,
        rays: &[Ray],
        map: &impl Fn(&Ray, Option<HitInfo>) -> T,
        k: &mut Counters,
        answers: &mut Vec<(u32, T)>,
        out: &mut Outbox,
        stack: &mut Vec<Entry>,
        cluster_stack: &mut Vec<(u32, f32, u8)>,
    ) -> Result<(), TraceError> {
        let ray = &rays[i as usize];
        let Some((r, mut w)) = self.tree.begin(ray, stack, k)? else {
            answers.push((i, map(ray, None)));
            return Ok(());
        };
        match self
            .tree
            .resume::<ANY>(&r, &mut w, k, stack, cluster_stack, None)?
        {
            None => answers.push((i, map(ray, w.best))),
            Some(b) => park(out, b, i, w, stack),
        }
        Ok(())
    }

    /// Serves block `b`: resumes every walk of its queue with the block's bytes.
    #[allow(clippy::too_many_arguments)]
    fn serve<const ANY: bool, T: Copy>(
        &self,
        b: u32,
        q: Queue,
        rays: &[Ray],
        map: &impl Fn(&Ray, Option<HitInfo>) -> T,
        k: &mut Counters,
        answers: &mut Vec<(u32, T)>,
        out: &mut Outbox,
        stack: &mut Vec<Entry>,
        cluster_stack: &mut Vec<(u32, f32, u8)>,
        m: &Mutex<Sched>,
        wake: &Condvar,
    ) -> Result<(), TraceError> {
        let (_, bytes, ready) = self.tree.fetch(b, &mut k.page)?;
        let held = Held::new(b, ready, &bytes);
        let mut at = 0;
        for head in &q.heads {
            let ray = &rays[head.ray as usize];
            let len = head.len as usize;
            stack.clear();
            stack.extend_from_slice(&q.entries[at..at + len]);
            at += len;
            let mut w = head.w;
            let Some(r) = self.tree.context(ray) else {
                // Not reached: a walk was parked only for a ray with a context.
                answers.push((head.ray, map(ray, w.best)));
                continue;
            };
            match self
                .tree
                .resume::<ANY>(&r, &mut w, k, stack, cluster_stack, Some(&held))?
            {
                None => answers.push((head.ray, map(ray, w.best))),
                Some(next) => park(out, next, head.ray, w, stack),
            }
            if out.heads.len() >= FLUSH {
                self.lock(m).park(out);
                wake.notify_all();
            }
        }
        Ok(())
    }
}

/// Parks a walk at block `b` in the outbox.
fn park(out: &mut Outbox, b: u32, ray: u32, w: Best, stack: &[Entry]) {
    out.heads.push((
        b,
        Head {
            ray,
            len: stack.len() as u32,
            w,
        },
    ));
    out.entries.extend_from_slice(stack);
}
