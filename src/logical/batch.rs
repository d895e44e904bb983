//! Handing a batch's work to the threads; a batch of rays asking one [`Query`] of each, its
//! [`Answers`] and figures ([`Scene::answer`]).

use std::time::Instant;

use rayon::prelude::*;

use super::order::Order;
use super::pager::BlockSource;
use super::report::{Answered, SetReport};
use super::scene::Scene;
use crate::error::Error;
use crate::geom::{Hit, Ray};
use crate::output::Output;
use crate::rays::write_into;

/// What a batch asks of each ray.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Query {
    /// Its closest hit ([`Scene::intersect_batch_ordered`]).
    Closest,
    /// Whether anything occludes it ([`Scene::occluded_batch_ordered`]).
    Any,
}

/// A batch's answers, in the order of its rays.
#[derive(Clone, Debug)]
pub enum Answers {
    /// Closest hits ([`Query::Closest`]).
    Hits(Vec<Hit>),
    /// 1: occluded, 0: not ([`Query::Any`]).
    Occluded(Vec<u8>),
}

impl Answers {
    /// Writes them to `out`: a HITS file, or an OCCL file (`RAYS.md`).
    pub fn write(&self, out: Output) -> Result<(), Error> {
        match self {
            Answers::Hits(hits) => write_into(out, hits),
            Answers::Occluded(occ) => write_into(out, occ),
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
        }
    }
}

/// Rays per chunk handed to a thread: large enough to amortise the hand-out, small enough to
/// balance.
pub(crate) const CHUNK: usize = 256;

/// Runs `work` on the chunks of `chunk` items of `items` (and the matching chunks of `out`)
/// on at most `workers` threads of the current rayon pool, handing the chunks out *in order*:
/// each thread takes the next chunk not yet taken. So at any time the threads work on
/// neighbouring chunks (with rayon's splitting, each thread would work through its own half of
/// the batch: for sorted rays, two distant regions of space, which split the pager's budget
/// between them), and no more threads trace at once than the pager was sized for. Stops at the
/// first error; the threads' accumulators (counters, statistics) are summed.
pub(crate) fn in_order<I: Sync, T: Send, A, E: Send>(
    items: &[I],
    out: &mut [T],
    chunk: usize,
    workers: usize,
    work: impl Fn(&[I], &mut [T], &mut A) -> Result<(), E> + Sync,
) -> Result<A, E>
where
    A: Default + std::ops::Add<Output = A> + Send,
{
    let chunk = chunk.max(1);
    use std::sync::Mutex;
    use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
    // One lock per chunk, each taken once, by the thread whose turn it is: never contended.
    let chunks: Vec<Mutex<&mut [T]>> = out.chunks_mut(chunk).map(Mutex::new).collect();
    let next = AtomicUsize::new(0);
    let failed = AtomicBool::new(false);
    let threads = rayon::current_num_threads()
        .min(workers)
        .min(chunks.len())
        .max(1);
    (0..threads)
        .into_par_iter()
        .with_max_len(1)
        .map(|_| {
            let mut c = A::default();
            while !failed.load(Ordering::Relaxed) {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(slot) = chunks.get(i) else { break };
                let mut out = slot.lock().unwrap_or_else(|e| e.into_inner());
                let from = i * chunk;
                let items = &items[from..(from + chunk).min(items.len())];
                if let Err(e) = work(items, &mut out, &mut c) {
                    failed.store(true, Ordering::Relaxed);
                    return Err(e);
                }
            }
            Ok(c)
        })
        .try_reduce(A::default, |a, b| Ok(a + b))
}
