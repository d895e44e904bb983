//! Batches traced out of core chunk by chunk (format-spec §8.3): the pager holds the blocks'
//! heads, and the chunks of groups that rays wait for are read together.
//!
//! A batch is taken in Morton order, [`BATCH`] rays at a time. First every ray is walked
//! through the heads, testing the groups whose chunks are resident and leaving the others for
//! later (`trace::deferred`), nearest first. Then, in rounds, each ray that still has groups
//! to test names the chunk of its nearest one; the chunks named are read in file order, in
//! waves of at most [`WAVE`], each wave's from one thread at [`READ_DEPTH`] reads in flight
//! (an io_uring: `ChunkCache::read_many`), and the rays waiting for them test their groups
//! while the chunks are resident, passing over those past the closest hit found so far, until
//! each names the next chunk it waits for or is done. A ray reads only the chunks holding
//! groups that it enters before its closest hit; a chunk many rays wait for is read once a
//! round.
//!
//! **Overlap.** A wave's chunks are read while the rays of the wave before test their groups,
//! and the next batch is walked through the heads (reading them, testing what is resident)
//! while this batch's rounds read its chunks: the disk is kept busy by one thread's ring while
//! the cores trace.
//!
//! The answers are the direct walk's (see `trace::deferred`); the work counters are not (a
//! walk that has not found the hits in groups left for later culls less).

use std::sync::Mutex;

use super::batch::{CHUNK, in_order};
use super::pager::chunks::ChunkCache;
use super::trace::{Counters, Deferred, HitInfo, TraceError, Tree};
use crate::geom::Ray;

/// Reads in flight at once: on this machine's disk `fio --readonly` gives 73,000 random 4 KiB
/// reads a second at depth 16, 84,300 at 32 and 91,700 at 64 (`tools/fio_disk.sh`); the lean
/// 130.7M-triangle file's 10^6 random rays ran at 0.203-0.204 Mrays/s with 128 in flight and
/// 0.184-0.199 with 64 (3 cold runs each, 1.5 GiB cgroup, budget 1200M, the reading thread
/// competing with the heads' faults).
const READ_DEPTH: usize = 128;

/// Chunks read in one wave at most, so that reading the next overlaps the tests of this one.
const WAVE: usize = 4096;

/// Rays walked before the chunks they wait for are read: their lists of groups are kept
/// meanwhile (12 bytes a group left for later).
const BATCH: usize = 1 << 16;

/// A ray of a batch: its closest hit (any hit with `ANY`) so far, and the groups it has left,
/// nearest first, of which the first `done` are done.
#[derive(Default)]
struct Walked {
    best: Option<HitInfo>,
    pending: Vec<Deferred>,
    done: usize,
}

/// What the threads of a pass bring back: their counters and the chunks rays wait for (the
/// chunk's key, and the ray's place in the batch).
#[derive(Default)]
struct Waits {
    c: Counters,
    wants: Vec<(u64, u32)>,
}

impl std::ops::Add for Waits {
    type Output = Waits;
    fn add(mut self, o: Waits) -> Waits {
        self.c += o.c;
        self.wants.extend(o.wants);
        self
    }
}

/// The closest hit (any hit with `ANY`) of each ray of `rays` at the places `order` gives (a
/// permutation: the order in which they are traced), given to `answer` with the ray's index,
/// on at most `threads` threads of the current pool, by `tree` whose groups are read through
/// `cache` (a tree whose pager holds the blocks' heads).
pub(super) fn answer<const ANY: bool>(
    tree: &Tree<'_>,
    cache: &ChunkCache,
    rays: &[Ray],
    order: &[u32],
    threads: usize,
    mut answer: impl FnMut(u32, Option<HitInfo>),
) -> Result<Counters, TraceError> {
    let batches: Vec<&[u32]> = order.chunks(BATCH).collect();
    let mut total = Counters::default();
    let mut next = match batches.first() {
        Some(first) => Some(walk::<ANY>(tree, rays, first, threads)?),
        None => None,
    };
    for (b, batch) in batches.iter().enumerate() {
        let Some((walked, c)) = next.take() else {
            break;
        };
        total += c;
        // The next batch is walked (its heads read, its resident groups tested) while this
        // one's chunks are read and its rays test their groups.
        let ahead = batches.get(b + 1);
        let (done, walked_next) = rayon::join(
            || rounds::<ANY>(tree, cache, rays, batch, walked, threads),
            || {
                ahead
                    .map(|a| walk::<ANY>(tree, rays, a, threads))
                    .transpose()
            },
        );
        let (bests, c) = done?;
        total += c;
        next = walked_next?;
        for (&i, best) in batch.iter().zip(bests) {
            answer(i, best);
        }
    }
    Ok(total)
}

/// Walks the rays of `batch` (places in `rays`) through the heads, testing the groups whose
/// chunks are resident and leaving the others, nearest first.
fn walk<const ANY: bool>(
    tree: &Tree<'_>,
    rays: &[Ray],
    batch: &[u32],
    threads: usize,
) -> Result<(Vec<Walked>, Counters), TraceError> {
    let mut walked: Vec<Walked> = (0..batch.len()).map(|_| Walked::default()).collect();
    let c = in_order(batch, &mut walked, CHUNK, threads, |idx, out, c| {
        let mut out = out.iter_mut();
        let rays = idx.iter().map(|&i| &rays[i as usize]);
        tree.answer_each_deferring::<ANY>(rays, c, |_, _, best, defer| {
            let Some(w) = out.next() else { return };
            w.best = best;
            if !(defer.is_empty() || ANY && best.is_some()) {
                defer.sort_unstable_by(|a, b| a.t.total_cmp(&b.t));
                w.pending = defer.clone();
            }
        })
    })?;
    Ok((walked, c))
}

/// The rounds of a walked batch: the chunks its rays wait for read and their groups tested,
/// until every ray is done; each ray's hit, in the batch's order.
fn rounds<const ANY: bool>(
    tree: &Tree<'_>,
    cache: &ChunkCache,
    rays: &[Ray],
    batch: &[u32],
    walked: Vec<Walked>,
    threads: usize,
) -> Result<(Vec<Option<HitInfo>>, Counters), TraceError> {
    let per = cache.chunk_groups().max(1);
    let key = |d: &Deferred| (d.block as u64) << 32 | (d.group / per) as u64;
    // Chunks read at once: a quarter of what the cache holds beside a chunk a thread (a
    // wave's chunks are read while the rays of the wave before test theirs, and the next
    // batch's walk keeps what it finds resident), and at most WAVE.
    let wave = (cache.slots().saturating_sub(threads + 1) / 4).clamp(1, WAVE);
    let mut total = Counters::default();
    let walked: Vec<Mutex<Walked>> = walked.into_iter().map(Mutex::new).collect();
    // Each waiting ray tests what is resident, and names the chunk it waits for next.
    let resolve = |places: &[u32], read_first: bool| {
        let mut unit = vec![(); places.len()];
        in_order(
            places,
            &mut unit,
            CHUNK,
            threads,
            |places, _, w: &mut Waits| {
                for &p in places {
                    let mut r = walked[p as usize].lock().unwrap_or_else(|e| e.into_inner());
                    let r = &mut *r;
                    let ray = &rays[batch[p as usize] as usize];
                    let left = &r.pending[r.done..];
                    r.done += tree.resolve::<ANY>(ray, &mut r.best, left, read_first, &mut w.c)?;
                    match r.pending.get(r.done) {
                        Some(d) => w.wants.push((key(d), p)),
                        None => r.pending = Vec::new(),
                    }
                }
                Ok::<(), TraceError>(())
            },
        )
    };
    let waiting: Vec<u32> = (0..batch.len() as u32)
        .filter(|&p| {
            !walked[p as usize]
                .lock()
                .is_ok_and(|r| r.pending.is_empty())
        })
        .collect();
    let w = resolve(&waiting, false)?;
    total += w.c;
    let mut wants = w.wants;
    while !wants.is_empty() {
        wants.sort_unstable();
        // The rays waiting for each `wave` chunks: their chunks, and the rays.
        let mut waves: Vec<(Vec<u64>, Vec<u32>)> = Vec::new();
        for &(k, p) in &wants {
            match waves.last_mut() {
                Some((keys, places)) if keys.last() == Some(&k) => places.push(p),
                Some((keys, places)) if keys.len() < wave => {
                    keys.push(k);
                    places.push(p);
                }
                _ => waves.push((vec![k], vec![p])),
            }
        }
        // Each wave's chunks are read (from one thread, many at once) while the rays of the
        // wave before test their groups.
        let read = |keys: &[u64]| {
            let mut c = Counters::default();
            tree.read_chunks(keys, READ_DEPTH, &mut c.page).map(|()| c)
        };
        total += read(&waves[0].0)?;
        let mut next = Vec::new();
        for (i, (_, places)) in waves.iter().enumerate() {
            let ahead = waves.get(i + 1).map(|(keys, _)| &keys[..]);
            let (r, w) = rayon::join(
                || ahead.map_or(Ok(Counters::default()), read),
                || resolve(places, true),
            );
            let w = w?;
            total += r? + w.c;
            next.extend(w.wants);
        }
        wants = next;
    }
    let bests = walked
        .into_iter()
        .map(|r| r.into_inner().unwrap_or_else(|e| e.into_inner()).best)
        .collect();
    Ok((bests, total))
}
