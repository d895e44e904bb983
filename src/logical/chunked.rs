//! Batches traced out of core chunk by chunk (format-spec §8.3): the pager holds the blocks'
//! heads, and the chunks of groups that rays wait for are read together.
//!
//! A batch is taken in Morton order, [`BATCH`] rays at a time. First every ray is walked
//! through the heads, testing the groups whose chunks are resident and leaving the others for
//! later (`trace::deferred`), nearest first. Then, in rounds, each ray that still has groups
//! to test names the chunk of its nearest one; the chunks named are read in file order, as
//! many at once as the threads (the reads of a round overlap each other, not yet the tracing),
//! a cache's worth at a time, and the rays waiting for them test their groups while the chunks
//! are resident, passing over those past the closest hit found so far, until each names the
//! next chunk it waits for or is done. A ray reads only the chunks holding groups that it
//! enters before its closest hit; a chunk many rays wait for is read once a round.
//!
//! The answers are the direct walk's (see `trace::deferred`); the work counters are not (a
//! walk that has not found the hits in groups left for later culls less).

use std::sync::Mutex;

use super::batch::{CHUNK, in_order};
use super::pager::chunks::ChunkCache;
use super::trace::{Counters, Deferred, HitInfo, TraceError, Tree};
use crate::geom::Ray;

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
    let per = cache.chunk_groups().max(1);
    let key = |d: &Deferred| (d.block as u64) << 32 | (d.group / per) as u64;
    // Chunks read at once: what the cache holds beside a chunk a thread.
    let wave = cache.slots().saturating_sub(threads + 1).max(1);
    let mut total = Counters::default();
    for batch in order.chunks(BATCH) {
        let mut walked: Vec<Walked> = (0..batch.len()).map(|_| Walked::default()).collect();
        total += in_order(batch, &mut walked, CHUNK, threads, |idx, out, c| {
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
                        r.done +=
                            tree.resolve::<ANY>(ray, &mut r.best, left, read_first, &mut w.c)?;
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
            let mut next = Vec::new();
            let mut rest = &wants[..];
            while !rest.is_empty() {
                // The rays waiting for the next `wave` chunks.
                let mut keys: Vec<u64> = Vec::new();
                let end = rest
                    .iter()
                    .position(|&(k, _)| {
                        if keys.last() != Some(&k) {
                            keys.push(k);
                        }
                        keys.len() > wave
                    })
                    .unwrap_or(rest.len());
                keys.truncate(wave);
                let (now, later) = rest.split_at(end);
                rest = later;
                let mut unit = vec![(); keys.len()];
                total += in_order(&keys, &mut unit, 1, threads, |k, _, c: &mut Counters| {
                    let (block, chunk) = ((k[0] >> 32) as u32, k[0] as u32);
                    tree.read_group(block, chunk * per, &mut c.page).map(drop)
                })?;
                let places: Vec<u32> = now.iter().map(|&(_, p)| p).collect();
                let w = resolve(&places, true)?;
                total += w.c;
                next.extend(w.wants);
            }
            wants = next;
        }
        for (&i, r) in batch.iter().zip(walked) {
            answer(i, r.into_inner().unwrap_or_else(|e| e.into_inner()).best);
        }
    }
    Ok(total)
}
