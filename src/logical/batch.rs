//! Handing a batch's work to the threads.

use rayon::prelude::*;

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
