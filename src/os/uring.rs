//! Many direct reads at once from one thread: an io_uring (Linux 5.1 and later) keeps up to a
//! queue's depth of them in flight, so that the disk sees a deep queue without a thread for
//! each read (threads blocked in `pread` and woken one by one cost more of the CPU than the
//! reads, issue 32's profile: the kernel at 56 %, task switches and wake-ups the most of it).
//!
//! Written over the `io-uring` crate (tokio-rs's: the kernel's rings and opcodes, nothing
//! more). What must be ours is when a buffer may be freed: the kernel writes into it until its
//! completion is reaped, so each read goes into a buffer the thread's ring owns, taken back only
//! at its completion and copied into the caller's then; if the ring ever fails with reads in
//! flight, the ring and its buffers are leaked, never freed under the kernel.

use std::cell::RefCell;
use std::fs::File;
use std::os::fd::AsRawFd;
use std::sync::atomic::{AtomicBool, Ordering};

use io_uring::{IoUring, opcode, types};

use super::PageBuf;

/// The kernel refused a ring once (too old, or a seccomp policy): reads are made one by one
/// from then on.
static UNAVAILABLE: AtomicBool = AtomicBool::new(false);

/// A thread's ring and the buffers its reads land in (one per read in flight).
struct Ring {
    ring: IoUring,
    bufs: Vec<PageBuf>,
}

thread_local! {
    static RING: RefCell<Option<Ring>> = const { RefCell::new(None) };
}

/// Reads each `(offset, buf)` of `reads` from `file` (opened for direct reads, each offset and
/// length a multiple of what it asks), at most `depth` in flight; each read's bytes, which may
/// be fewer than asked at the file's end (the rest of its buffer untouched), or its error.
/// `None` where io_uring cannot be used: then nothing was read.
pub(super) fn read_many(
    file: &File,
    reads: &mut [(u64, &mut [u8])],
    depth: usize,
) -> Option<Vec<std::io::Result<usize>>> {
    if UNAVAILABLE.load(Ordering::Relaxed) || reads.is_empty() {
        return None;
    }
    let depth = depth.clamp(1, 4096);
    let longest = reads.iter().map(|(_, b)| b.len()).max().unwrap_or(0);
    if u32::try_from(longest).is_err() {
        return None;
    }
    let mut ring = match RING.take() {
        Some(r) if r.bufs.len() >= depth && r.bufs.iter().all(|b| b.len() >= longest) => r,
        other => {
            let ring = match other {
                Some(r) if r.bufs.len() >= depth => r.ring,
                _ => match IoUring::new(depth.next_power_of_two() as u32) {
                    Ok(ring) => ring,
                    Err(_) => {
                        UNAVAILABLE.store(true, Ordering::Relaxed);
                        return None;
                    }
                },
            };
            let bufs: Option<Vec<PageBuf>> =
                (0..depth).map(|_| PageBuf::new(longest.max(1))).collect();
            Ring { ring, bufs: bufs? }
        }
    };
    let results = run(&mut ring, file, reads, depth);
    match results {
        Some(_) => RING.set(Some(ring)),
        None => {
            // Reads may still be in flight into the ring's buffers: never freed.
            UNAVAILABLE.store(true, Ordering::Relaxed);
            std::mem::forget(ring);
        }
    }
    results
}

/// The reads of [`read_many`] on `r`; `None` if the ring failed (reads may be in flight).
fn run(
    r: &mut Ring,
    file: &File,
    reads: &mut [(u64, &mut [u8])],
    depth: usize,
) -> Option<Vec<std::io::Result<usize>>> {
    // (In flight at most what the submission queue holds: the completion queue holds twice.)
    let depth = depth
        .min(r.ring.params().sq_entries() as usize)
        .min(r.bufs.len());
    let n = reads.len();
    let mut results: Vec<std::io::Result<usize>> = (0..n).map(|_| Ok(0)).collect();
    let mut free: Vec<usize> = (0..depth).rev().collect();
    let (mut next, mut in_flight) = (0, 0);
    let fd = types::Fd(file.as_raw_fd());
    while next < n || in_flight > 0 {
        while next < n {
            let Some(&b) = free.last() else { break };
            let (offset, ref buf) = reads[next];
            let buf_ptr = r.bufs[b].as_mut_ptr();
            let entry = opcode::Read::new(fd, buf_ptr, buf.len() as u32)
                .offset(offset)
                .build()
                .user_data((next as u64) << 32 | b as u64);
            // SAFETY: the entry reads into `r.bufs[b]`, a buffer the ring owns and at least
            // `buf.len()` long; it is not read, moved, reused or freed until this entry's
            // completion is reaped below (`b` leaves `free` now and returns only then), and if
            // the ring fails with reads in flight the ring and its buffers are leaked
            // (`read_many`). `fd` stays open for the call (borrowed), and the kernel holds its
            // own reference to the file once the entry is submitted.
            if unsafe { r.ring.submission().push(&entry) }.is_err() {
                break;
            }
            free.pop();
            next += 1;
            in_flight += 1;
        }
        match r.ring.submit_and_wait(1) {
            Ok(_) => {}
            Err(e)
                if matches!(
                    e.raw_os_error(),
                    Some(libc::EINTR | libc::EAGAIN | libc::EBUSY)
                ) => {}
            Err(_) => return None,
        }
        for cqe in r.ring.completion() {
            let (i, b) = (
                (cqe.user_data() >> 32) as usize,
                cqe.user_data() as u32 as usize,
            );
            let (Some(read), Some(buf)) = (reads.get_mut(i), r.bufs.get(b)) else {
                return None;
            };
            results[i] = match cqe.result() {
                k if k >= 0 => {
                    let k = (k as usize).min(read.1.len());
                    read.1[..k].copy_from_slice(&buf[..k]);
                    Ok(k)
                }
                e => Err(std::io::Error::from_raw_os_error(-e)),
            };
            free.push(b);
            in_flight -= 1;
        }
    }
    Some(results)
}
