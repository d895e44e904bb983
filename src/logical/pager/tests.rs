//! The pager on synthetic block files: every block reads back as
//! written (raw and zstd, any budget, 1 to 8 threads), the counters add up get by get, resident
//! memory stays within the effective budget plus one block per thread, damaged blocks and
//! directory entries give an error naming the block (every time, never a panic) while the other
//! blocks still read, many threads on the fewest slots finish, and a real mapped file pages in
//! and out.
//!
//! The files are built here, not by the writer: `N` blocks of seeded pseudo-random bytes (some
//! random, some compressible), raw ones at multiples of 4096, zstd ones at multiples of 64 (some
//! frames recording their content size, some not), after a 256-byte stand-in for the header,
//! and a directory of `BlockEntry` describing them.

use std::sync::Mutex;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use super::{
    BlockBytes, BlockSource, MIN_SLOT_BYTES, PageCounters, PageError, Pager, PagerOptions,
};
use crate::os::MappedFile;
use crate::physical::format::{BlockEntry, CODEC_RAW, CODEC_ZSTD, RAW_BLOCK_ALIGN, checksum};
use crate::physical::{AlignedBytes, BlockReader};

/// Bytes before the first block (a stand-in for the header) and after the last one: outside
/// the blocks section.
const HEAD: usize = 256;
const TAIL: usize = 100;

/// splitmix64: a small seeded generator (the tests need repeatable bytes, not good randomness).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Mix {
    Raw,
    Zstd,
    Mixed,
}

/// A synthetic file: its bytes, its block directory and each block's decoded bytes.
#[derive(Clone)]
struct Synth {
    file: Vec<u8>,
    dir: Vec<BlockEntry>,
    blocks: Vec<Vec<u8>>,
    max_raw_len: u64,
    /// Pagers made by [`Self::opts`] read blocks into slots ([`PagerOptions::read_blocks`]).
    read_blocks: bool,
}

impl Synth {
    fn build(n: usize, mix: Mix, max_len: usize, seed: u64) -> Synth {
        let mut rng = Rng(seed);
        let mut file = vec![0x5a; HEAD];
        let (mut dir, mut blocks) = (Vec::new(), Vec::new());
        for i in 0..n {
            let len = 1 + rng.below(max_len as u64) as usize;
            let data: Vec<u8> = if rng.below(3) == 0 {
                (0..len).map(|_| rng.next() as u8).collect()
            } else {
                // Runs over a small alphabet: compresses well.
                let mut v = Vec::with_capacity(len);
                while v.len() < len {
                    let (b, run) = (b"oavm"[rng.below(4) as usize], 1 + rng.below(40));
                    v.extend(std::iter::repeat_n(b, run as usize));
                }
                v.truncate(len);
                v
            };
            let zstd = match mix {
                Mix::Raw => false,
                Mix::Zstd => true,
                Mix::Mixed => i % 2 == 1 || rng.below(4) == 0,
            };
            let (codec, stored, align) = if zstd {
                let mut c = zstd::bulk::Compressor::new(3).unwrap();
                if rng.below(4) == 0 {
                    c.set_parameter(zstd::zstd_safe::CParameter::ContentSizeFlag(false))
                        .unwrap();
                }
                (CODEC_ZSTD, c.compress(&data).unwrap(), 64)
            } else {
                (CODEC_RAW, data.clone(), RAW_BLOCK_ALIGN as usize)
            };
            file.resize(file.len().next_multiple_of(align), 0xee);
            dir.push(BlockEntry {
                offset: file.len() as u64,
                stored_len: stored.len() as u64,
                raw_len: data.len() as u64,
                codec,
                root_level: 3,
                root_count: 1,
                triangles: 0,
                checksum: checksum(&stored),
                head_stored_len: stored.len() as u64,
                head_raw_len: data.len() as u64,
            });
            file.extend_from_slice(&stored);
            blocks.push(data);
        }
        file.extend_from_slice(&[0xee; TAIL]);
        let max_raw_len = blocks.iter().map(|b| b.len() as u64).max().unwrap_or(1);
        Synth {
            file,
            dir,
            blocks,
            max_raw_len,
            read_blocks: false,
        }
    }

    /// The same file, its pagers reading blocks into slots or not.
    fn reading(&self, read_blocks: bool) -> Synth {
        Synth {
            read_blocks,
            ..self.clone()
        }
    }

    fn source(&self) -> AlignedBytes {
        AlignedBytes::from_slice(&self.file)
    }

    fn opts(&self, budget: u64, threads: usize) -> PagerOptions {
        PagerOptions {
            budget,
            threads,
            check_raw: true,
            read_blocks: self.read_blocks,
        }
    }

    /// The reader of the file's blocks: its blocks section runs from the end of the header's
    /// stand-in to the start of the tail.
    fn reader(&self) -> BlockReader {
        BlockReader::for_section(
            (HEAD as u64, (self.file.len() - TAIL) as u64),
            self.max_raw_len,
            self.dir.iter().any(|e| e.codec == CODEC_ZSTD),
            0,
        )
    }

    /// Changes a block's entry and its stored bytes, and rewrites the checksum so that only
    /// the change made is wrong (as a writer with a bug would).
    fn rechecksum(&mut self, b: usize) {
        let e = &mut self.dir[b];
        let end = (e.offset + e.stored_len).min(self.file.len() as u64);
        e.checksum = checksum(&self.file[e.offset as usize..end as usize]);
    }

    fn first(&self, codec: u32) -> usize {
        self.dir.iter().position(|e| e.codec == codec).unwrap()
    }
}

/// A pager with the file it reads (the pager itself keeps no reference to it).
struct Bound<'a, S: BlockSource> {
    pager: Pager,
    src: &'a S,
    dir: &'a [BlockEntry],
}

impl<'a, S: BlockSource> Bound<'a, S> {
    fn new(src: &'a S, s: &'a Synth, opts: PagerOptions) -> Self {
        Bound {
            pager: Pager::new(&s.dir, s.reader(), opts),
            src,
            dir: &s.dir,
        }
    }

    fn get(&self, block: u32, c: &mut PageCounters) -> Result<BlockBytes<'_>, PageError> {
        self.pager.get(self.src, self.dir, block, c)
    }
}

impl<S: BlockSource> std::ops::Deref for Bound<'_, S> {
    type Target = Pager;
    fn deref(&self) -> &Pager {
        &self.pager
    }
}

/// One get, checked: the bytes are the block's and 8-aligned, and the counters moved by
/// exactly one hit, or one miss that read (and decompressed) exactly this block.
fn checked_get<S: BlockSource>(p: &Bound<S>, s: &Synth, b: u32, c: &mut PageCounters) {
    let before = *c;
    let bytes = p.get(b, c).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        bytes[..] == s.blocks[b as usize][..],
        "block {b}: wrong bytes"
    );
    assert_eq!(bytes.as_ptr() as usize % 8, 0, "block {b}: not 8-aligned");
    let e = &s.dir[b as usize];
    match &bytes {
        BlockBytes::Raw(_) => assert_eq!(e.codec, CODEC_RAW),
        // A raw block is read into a slot if the pager reads blocks (and may evict).
        BlockBytes::Decoded(_) => assert!(e.codec == CODEC_ZSTD || s.read_blocks),
    }
    drop(bytes);
    let (hits, misses) = (c.hits - before.hits, c.misses - before.misses);
    let (read, decompressed) = (
        c.bytes_read - before.bytes_read,
        c.bytes_decompressed - before.bytes_decompressed,
    );
    assert_eq!(c.requested - before.requested, 1);
    assert_eq!(hits + misses, 1, "block {b}: one get, one hit or miss");
    if misses == 1 {
        assert_eq!(
            read, e.stored_len,
            "block {b}: a miss reads the stored bytes"
        );
        let raw = if e.codec == CODEC_ZSTD { e.raw_len } else { 0 };
        assert_eq!(decompressed, raw, "block {b}: a miss decodes a zstd block");
    } else {
        assert_eq!(
            (read, decompressed),
            (0, 0),
            "block {b}: a hit reads nothing"
        );
    }
}

/// `gets` random gets on each of `threads` threads of a local pool; the counters of each.
fn run_threads<S: BlockSource>(
    p: &Bound<S>,
    s: &Synth,
    threads: usize,
    gets: usize,
    seed: u64,
) -> Vec<PageCounters> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.broadcast(|ctx| {
        let mut rng = Rng(seed ^ ((ctx.index() as u64 + 1) * 0x1234_5678));
        let mut c = PageCounters::default();
        for _ in 0..gets {
            // Mostly a few hot blocks (hits), sometimes any block (misses).
            let n = s.blocks.len() as u64;
            let b = if rng.below(2) == 0 {
                rng.below(n.min(4))
            } else {
                rng.below(n)
            };
            checked_get(p, s, b as u32, &mut c);
        }
        c
    })
}

fn sum(cs: &[PageCounters]) -> PageCounters {
    cs.iter().fold(PageCounters::default(), |a, &c| a + c)
}

/// The bound of the module docs: the budget (or, below what a block per thread and one more
/// need, that) plus one block per thread in `get`.
fn check_bound<S: BlockSource>(p: &Bound<S>, s: &Synth, threads: usize, what: &str) {
    let floor = (threads as u64 + 1) * s.max_raw_len;
    let bound = p
        .budget()
        .max(floor)
        .saturating_add(threads as u64 * s.max_raw_len);
    assert!(
        p.peak_resident_bytes() <= bound,
        "{what}: peak {} > budget {} + {threads} x {}",
        p.peak_resident_bytes(),
        p.budget(),
        s.max_raw_len
    );
    // Once every get has returned, each thread has evicted its own excess.
    assert!(
        p.resident_bytes() <= p.budget().max(floor),
        "{what}: {} resident after the gets, budget {}",
        p.resident_bytes(),
        p.budget()
    );
}

#[test]
fn every_block_reads_back_under_any_budget_and_threads() {
    for (mix, seed, read) in [
        (Mix::Raw, 1, false),
        (Mix::Zstd, 2, false),
        (Mix::Mixed, 3, false),
        (Mix::Raw, 1, true),
        (Mix::Zstd, 2, true),
        (Mix::Mixed, 3, true),
    ] {
        let s = Synth::build(40, mix, 20_000, seed).reading(read);
        let src = s.source();
        let total: u64 = s.dir.iter().map(|e| e.raw_len).sum();
        for budget in [u64::MAX, total / 4, 1, 0] {
            for threads in [1, 2, 4, 8] {
                let what = format!("{mix:?}, read {read}, budget {budget}, {threads} threads");
                let p = Bound::new(&src, &s, s.opts(budget, threads));
                // Every block once, in order, then random gets on all the threads.
                let mut first = PageCounters::default();
                for b in 0..s.blocks.len() as u32 {
                    checked_get(&p, &s, b, &mut first);
                }
                let per_thread = run_threads(&p, &s, threads, 4000 / threads, seed * 77);
                let c = sum(&per_thread) + first;
                assert_eq!(
                    c.requested,
                    40 + (4000 / threads * threads) as u64,
                    "{what}"
                );
                assert_eq!(c.requested, c.hits + c.misses, "{what}");
                if budget == u64::MAX {
                    // Nothing is ever evicted: each block is read once.
                    assert_eq!(c.misses, 40, "{what}");
                    assert_eq!(
                        c.bytes_read,
                        s.dir.iter().map(|e| e.stored_len).sum::<u64>(),
                        "{what}"
                    );
                    assert_eq!(p.budget(), u64::MAX);
                } else if budget <= 1 {
                    // A budget below one block: blocks are evicted and read again.
                    assert!(c.misses > 40, "{what}: {c:?}");
                }
                check_bound(&p, &s, threads, &what);
            }
        }
    }
}

/// A source that records the pager's hints, to check what it releases.
struct Recording {
    bytes: AlignedBytes,
    prefetched: Mutex<Vec<(usize, usize)>>,
    released: Mutex<Vec<(usize, usize)>>,
}

impl BlockSource for Recording {
    fn bytes(&self) -> &[u8] {
        self.bytes.as_ref()
    }
    fn prefetch(&self, off: usize, len: usize) {
        self.prefetched.lock().unwrap().push((off, len));
    }
    fn release(&self, off: usize, len: usize) {
        self.released.lock().unwrap().push((off, len));
    }
}

#[test]
fn evicted_raw_blocks_are_released_whole_and_accounted() {
    for threads in [1, 4] {
        let s = Synth::build(30, Mix::Raw, 10_000, 11);
        let src = Recording {
            bytes: s.source(),
            prefetched: Mutex::new(Vec::new()),
            released: Mutex::new(Vec::new()),
        };
        let budget = 3 * s.max_raw_len;
        let p = Bound::new(&src, &s, s.opts(budget, threads));
        assert_eq!(
            p.budget(),
            budget,
            "no zstd blocks, no slots: the budget as asked"
        );
        let c = sum(&run_threads(&p, &s, threads, 3000 / threads, 5));
        let released = src.released.lock().unwrap().clone();
        assert!(
            !released.is_empty(),
            "a budget of 3 blocks out of 30 evicts"
        );
        for &(off, len) in &released {
            assert!(
                s.dir
                    .iter()
                    .any(|e| (e.offset, e.stored_len) == (off as u64, len as u64)),
                "released {off}+{len}, not a block"
            );
        }
        // Every byte admitted is resident or was released.
        let released_bytes: u64 = released.iter().map(|&(_, len)| len as u64).sum();
        assert_eq!(c.bytes_read - released_bytes, p.resident_bytes());
        // One prefetch per miss, of the block read.
        assert_eq!(src.prefetched.lock().unwrap().len() as u64, c.misses);
        check_bound(&p, &s, threads, "raw, 3 blocks");
    }
}

#[test]
fn clock_gives_a_block_got_again_a_second_chance() {
    // Ten raw blocks of 1000 bytes, a budget of three: blocks are admitted with their bit
    // set; the hand clears bits on its first pass over the blocks queued and evicts the first
    // block found clear, so a block got again since the hand passed it survives.
    let mut s = Synth::build(10, Mix::Raw, 1000, 21);
    for (b, data) in s.blocks.iter_mut().enumerate() {
        data.resize(1000, b as u8);
    }
    let s = rebuild(&s);
    let src = Recording {
        bytes: s.source(),
        prefetched: Mutex::new(Vec::new()),
        released: Mutex::new(Vec::new()),
    };
    let p = Bound::new(&src, &s, s.opts(3000, 1));
    let mut c = PageCounters::default();
    let mut trace = String::new();
    for b in [0, 1, 2, 3, 1, 4, 1, 3, 4, 2] {
        let before = c.misses;
        checked_get(&p, &s, b, &mut c);
        trace.push(if c.misses > before { 'M' } else { 'h' });
    }
    // 3 evicts 0 (all bits were set: the hand clears them, then takes the oldest); 1 is got
    // again, so 4 evicts 2, not 1; 2 comes back and evicts 3.
    assert_eq!(trace, "MMMMhMhhhM");
    let released: Vec<u64> = src
        .released
        .lock()
        .unwrap()
        .iter()
        .map(|&(off, _)| off as u64)
        .collect();
    let offsets: Vec<u64> = [0, 2, 3].iter().map(|&b| s.dir[b].offset).collect();
    assert_eq!(released, offsets);
    assert_eq!(p.resident_bytes(), 3000);
    assert_eq!(p.peak_resident_bytes(), 4000);

    let p = Bound::new(&src, &s, s.opts(u64::MAX, 1));
    let mut c = PageCounters::default();
    for _ in 0..3 {
        for b in 0..10 {
            checked_get(&p, &s, b, &mut c);
        }
    }
    assert_eq!((c.misses, c.hits), (10, 20));
    assert_eq!(p.resident_bytes(), 10_000);
}

#[test]
fn a_slot_freed_by_a_failed_decode_is_used_before_any_blocks() {
    // Zstd blocks A B C D X (X bad), three slots (two threads), a budget of three blocks.
    let mut s = Synth::build(5, Mix::Zstd, 3000, 23);
    let x = 4;
    let off = s.dir[x].offset as usize;
    s.file[off + 5] ^= 0xff;
    let src = s.source();
    // (Slots hold whole pages.)
    let p = Bound::new(
        &src,
        &s,
        s.opts(3 * s.max_raw_len.next_multiple_of(4096), 2),
    );
    assert_eq!(p.slot_count(), 3);
    let mut c = PageCounters::default();
    let mut trace = String::new();
    for b in [0, 1, 2, 3, x, 1, 2, 3] {
        let before = c.misses;
        if b == x {
            assert!(p.get(b as u32, &mut c).is_err());
            trace.push('E');
            continue;
        }
        checked_get(&p, &s, b as u32, &mut c);
        trace.push(if c.misses > before { 'M' } else { 'h' });
    }
    // D's sweep clears every bit and takes A's slot; X takes B's (unreferenced) and fails,
    // freeing it; B comes back into that free slot, not C's (unreferenced too).
    assert_eq!(trace, "MMMMEMhh");
}

/// The same blocks laid out again (after their bytes were changed).
fn rebuild(s: &Synth) -> Synth {
    let mut file = vec![0x5a; HEAD];
    let mut dir = Vec::new();
    for (e, data) in s.dir.iter().zip(&s.blocks) {
        assert_eq!(e.codec, CODEC_RAW);
        file.resize(file.len().next_multiple_of(RAW_BLOCK_ALIGN as usize), 0xee);
        dir.push(BlockEntry {
            offset: file.len() as u64,
            stored_len: data.len() as u64,
            raw_len: data.len() as u64,
            checksum: checksum(data),
            head_stored_len: data.len() as u64,
            head_raw_len: data.len() as u64,
            ..*e
        });
        file.extend_from_slice(data);
    }
    file.extend_from_slice(&[0xee; TAIL]);
    let max_raw_len = s.blocks.iter().map(|b| b.len() as u64).max().unwrap();
    Synth {
        file,
        dir,
        blocks: s.blocks.clone(),
        max_raw_len,
        read_blocks: s.read_blocks,
    }
}

#[test]
fn zstd_slots_hold_at_most_their_share() {
    let s = Synth::build(40, Mix::Zstd, 20_000, 31);
    let src = s.source();
    for (budget, threads) in [(0, 1), (0, 8), (5 * s.max_raw_len, 2), (u64::MAX, 4)] {
        let p = Bound::new(&src, &s, s.opts(budget, threads));
        // Slots for blocks of their average size in whole pages, at most MIN_SLOT_BYTES (at
        // least threads + 1, at most one per block); the budget, never raised, bounds their
        // bytes (plus a block per thread in a get).
        let pages: u64 = s.dir.iter().map(|e| e.raw_len.next_multiple_of(4096)).sum();
        let per_slot = (pages / 40).clamp(4096, MIN_SLOT_BYTES);
        assert!(
            per_slot < MIN_SLOT_BYTES,
            "blocks of {per_slot} bytes on average"
        );
        let slots = (budget / per_slot).max(threads as u64 + 1).min(40);
        assert_eq!(p.slot_count() as u64, slots);
        assert_eq!(p.budget(), budget);
        let c = sum(&run_threads(&p, &s, threads, 2000, 7));
        // Each slot's buffer is at most its block's size rounded to 8, and about twice that.
        assert!(p.resident_bytes() <= slots * (2 * s.max_raw_len + 8 * 64));
        if budget == u64::MAX {
            // A slot per block: each is decoded once.
            assert_eq!(c.misses, 40, "{c:?}");
        } else {
            assert!(c.misses > 40, "{c:?}");
        }
        check_bound(&p, &s, threads, &format!("zstd, budget {budget}"));
    }
}

/// The zstd cache is bounded by bytes, not by a count of the largest block: a budget that
/// holds every block's decoded bytes (in whole pages, as slots hold them) keeps them all,
/// however much smaller than the largest the others are; half that budget keeps them within it
/// and still hits.
#[test]
fn zstd_cache_holds_blocks_by_their_size() {
    let s = Synth::build(24, Mix::Zstd, 400_000, 77);
    let src = s.source();
    let total: u64 = s.dir.iter().map(|e| e.raw_len.next_multiple_of(4096)).sum();
    assert!(total / s.max_raw_len < 24, "blocks of mixed sizes");
    let p = Bound::new(&src, &s, s.opts(total, 1));
    let mut c = PageCounters::default();
    for _ in 0..2 {
        for b in 0..24 {
            checked_get(&p, &s, b, &mut c);
        }
    }
    assert_eq!((c.misses, c.hits), (24, 24), "{c:?}");
    // Half the bytes: evictions, the budget held, some hits all the same (a block read twice
    // in a row is never evicted in between).
    let p = Bound::new(&src, &s, s.opts(total / 2, 1));
    let mut c = PageCounters::default();
    for b in (0..24).flat_map(|b| [b, b, (b + 23) % 24]) {
        checked_get(&p, &s, b, &mut c);
    }
    assert!(c.misses > 24 && c.hits >= 24, "{c:?}");
    assert!(
        p.resident_bytes() <= p.budget(),
        "{} > {}",
        p.resident_bytes(),
        p.budget()
    );
    check_bound(&p, &s, 1, "half the bytes");
}

/// Every get of `b` fails with the same error naming `b`, whose text contains `expect`; every
/// other block reads back.
fn expect_bad(s: &Synth, b: u32, expect: &str) {
    for read in [false, true] {
        expect_bad_in(&s.reading(read), b, expect);
    }
}

fn expect_bad_in(s: &Synth, b: u32, expect: &str) {
    let src = s.source();
    for budget in [u64::MAX, 0] {
        let p = Bound::new(&src, s, s.opts(budget, 2));
        let mut c = PageCounters::default();
        let first = p.get(b, &mut c).err().expect("a bad block gives an error");
        assert_eq!(first.block, b);
        assert!(
            first.what.contains(expect),
            "block {b}: {first} (wanted '{expect}')"
        );
        assert!(first.to_string().starts_with(&format!("block {b}: ")));
        assert_eq!(c, PageCounters::default(), "a failed get counts nothing");
        // Other blocks read, before and after the bad one is asked for again.
        for round in 0..2 {
            for o in 0..s.blocks.len() as u32 {
                if o != b {
                    checked_get(&p, s, o, &mut c);
                }
            }
            let again = p.get(b, &mut c).err().expect("still bad");
            assert_eq!(again, first, "round {round}");
        }
        // Many threads asking for it at once all get the error.
        let errors = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap()
            .broadcast(|_| {
                let mut c = PageCounters::default();
                p.get(b, &mut c).err()
            });
        assert!(errors.iter().all(|e| e.as_ref() == Some(&first)));
    }
    // And a fresh pager, on 4 threads at once: every thread gets the error.
    let p = Bound::new(&src, s, s.opts(0, 4));
    let errors: Vec<Option<PageError>> = rayon::ThreadPoolBuilder::new()
        .num_threads(4)
        .build()
        .unwrap()
        .broadcast(|_| {
            let mut c = PageCounters::default();
            p.get(b, &mut c).err()
        });
    assert!(errors.iter().all(|e| {
        e.as_ref()
            .is_some_and(|e| e.block == b && e.what.contains(expect))
    }));
}

#[test]
fn a_flipped_byte_in_a_block_is_a_checksum_error() {
    let s = Synth::build(12, Mix::Mixed, 8000, 41);
    for codec in [CODEC_RAW, CODEC_ZSTD] {
        let b = s.first(codec);
        for at in [0, s.dir[b].stored_len / 2, s.dir[b].stored_len - 1] {
            let mut bad = s.clone();
            bad.file[(s.dir[b].offset + at) as usize] ^= 0x10;
            expect_bad(&bad, b as u32, "checksum mismatch");
        }
    }
}

#[test]
fn directory_entries_outside_the_file_or_misaligned_are_errors() {
    let s = Synth::build(12, Mix::Mixed, 8000, 51);
    let len = s.file.len() as u64;
    for codec in [CODEC_RAW, CODEC_ZSTD] {
        let b = s.first(codec);
        // Past the end, straddling it, and an offset + length that overflows.
        for (offset, stored_len) in [(len + 4096, 10), (len - 8, 4096), (u64::MAX - 4095, 8192)] {
            let mut bad = s.clone();
            bad.dir[b].offset = offset;
            bad.dir[b].stored_len = stored_len;
            bad.dir[b].raw_len = stored_len.min(bad.max_raw_len);
            expect_bad(&bad, b as u32, "outside the blocks section");
        }
        // Inside the file but not the blocks section (spec §11): the header's bytes, with a
        // checksum that matches them.
        let mut bad = s.clone();
        bad.dir[b].offset = 0;
        bad.dir[b].stored_len = 64;
        bad.dir[b].raw_len = 64;
        bad.rechecksum(b);
        expect_bad(&bad, b as u32, "outside the blocks section");
    }
    // A raw block at an offset that is not a multiple of 4096 (checksum of its bytes there).
    let b = s.first(CODEC_RAW);
    let mut bad = s.clone();
    bad.dir[b].offset += 64;
    bad.rechecksum(b);
    expect_bad(&bad, b as u32, "not a multiple of 4096");
    // A raw block whose raw_len is not its stored_len.
    let mut bad = s.clone();
    bad.dir[b].raw_len -= 1;
    expect_bad(&bad, b as u32, "raw_len");
    // Longer than the largest block the header allows.
    let mut bad = s.clone();
    bad.dir[b].raw_len = bad.max_raw_len + 1;
    expect_bad(&bad, b as u32, "exceeds the header's largest block");
    // An unknown codec.
    let mut bad = s.clone();
    bad.dir[b].codec = 7;
    expect_bad(&bad, b as u32, "unknown codec 7");
    // Blocks the directory does not have.
    let src = s.source();
    let p = Bound::new(&src, &s, s.opts(0, 1));
    for b in [12, 1000, u32::MAX] {
        let e = p.get(b, &mut PageCounters::default()).err().unwrap();
        assert_eq!(e.block, b);
        assert!(e.to_string().contains("no such block"), "{e}");
    }
}

#[test]
fn zstd_frames_that_do_not_decode_to_their_block_are_errors() {
    let s = Synth::build(12, Mix::Zstd, 8000, 61);
    // raw_len one short, one long (frames that record their size, and frames that do not).
    for b in 0..4 {
        for delta in [-1i64, 1] {
            let mut bad = s.clone();
            // (A block without groups is all head.)
            bad.dir[b].raw_len = (bad.dir[b].raw_len as i64 + delta) as u64;
            bad.dir[b].head_raw_len = bad.dir[b].raw_len;
            bad.max_raw_len += 1;
            expect_bad(&bad, b as u32, "raw_len");
        }
    }
    // Not a zstd frame at all (the checksum matches the garbage).
    let mut bad = s.clone();
    let e = bad.dir[2];
    bad.file[e.offset as usize..(e.offset + e.stored_len) as usize].fill(0x33);
    bad.rechecksum(2);
    expect_bad(&bad, 2, "zstd frame");
    // A truncated frame.
    let mut bad = s.clone();
    bad.dir[3].stored_len /= 2;
    bad.dir[3].head_stored_len = bad.dir[3].stored_len;
    bad.rechecksum(3);
    expect_bad(&bad, 3, "zstd");
}

/// A zstd frame (RFC 8878 §3.1.1) claiming `content_size` bytes, holding one raw block of
/// `data`.
fn lying_frame(content_size: u64, data: &[u8]) -> Vec<u8> {
    let mut f = vec![0x28, 0xb5, 0x2f, 0xfd];
    // Frame header descriptor: 8-byte content size, single segment (no window descriptor).
    f.push(0b1110_0000);
    f.extend_from_slice(&content_size.to_le_bytes());
    // Block header: last block, raw, `data.len()` bytes.
    let h = 1 | (data.len() as u32) << 3;
    f.extend_from_slice(&h.to_le_bytes()[..3]);
    f.extend_from_slice(data);
    f
}

#[test]
fn a_zstd_frame_claiming_a_huge_size_is_an_error_without_allocating_it() {
    let data = b"a small block, claimed to be a terabyte".to_vec();
    // The frame is valid for its true size.
    let honest = lying_frame(data.len() as u64, &data);
    assert_eq!(zstd::bulk::decompress(&honest, 1000).unwrap(), data);
    for (claimed, raw_len) in [
        (1u64 << 40, data.len() as u64), // the directory has the true size
        (1 << 40, 1 << 40),              // the directory believes the frame
        (u64::MAX - 2, 4096),            // neither is right
    ] {
        let frame = lying_frame(claimed, &data);
        let mut s = Synth::build(6, Mix::Zstd, 4000, 71);
        // The frame goes where the tail was, and a new tail after it.
        s.file.truncate(s.file.len() - TAIL);
        s.file.resize(s.file.len().next_multiple_of(64), 0);
        s.dir[5] = BlockEntry {
            offset: s.file.len() as u64,
            stored_len: frame.len() as u64,
            raw_len,
            checksum: checksum(&frame),
            head_stored_len: frame.len() as u64,
            head_raw_len: raw_len,
            ..s.dir[5]
        };
        s.file.extend_from_slice(&frame);
        s.file.extend_from_slice(&[0xee; TAIL]);
        s.blocks[5] = data.clone();
        s.max_raw_len = s.max_raw_len.max(4096);
        let expect = if raw_len > s.max_raw_len {
            "exceeds the header's largest block"
        } else if !crate::physical::format::zstd_head_fits(raw_len, frame.len() as u64) {
            "times its size"
        } else {
            "content size"
        };
        expect_bad(&s, 5, expect);
    }
}

/// Runs `f` on a thread of its own; fails if it panics or takes longer than `limit` (a
/// deadlock then fails the test instead of hanging it).
fn with_deadline(limit: Duration, f: impl FnOnce() + Send + 'static) {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
        let _ = tx.send(r.is_ok());
    });
    match rx.recv_timeout(limit) {
        Ok(true) => {}
        Ok(false) => panic!("the run panicked (see above)"),
        Err(_) => panic!("not finished after {limit:?}: deadlock?"),
    }
}

#[test]
fn eight_threads_on_the_fewest_slots_finish() {
    with_deadline(Duration::from_secs(15), || {
        let start = Instant::now();
        let s = Synth::build(48, Mix::Mixed, 6000, 81);
        let src = s.source();
        // Budget 0: nine slots for eight threads, and raw blocks evicted after every use.
        let p = Bound::new(&src, &s, s.opts(0, 8));
        assert_eq!(p.slot_count(), 9);
        let c = sum(&run_threads(&p, &s, 8, 100_000 / 8, 91));
        assert_eq!(c.requested, 100_000);
        assert_eq!(c.requested, c.hits + c.misses);
        assert!(c.misses > 10_000, "{c:?}");
        check_bound(&p, &s, 8, "stress");
        eprintln!("10^5 gets on 8 threads: {c:?} in {:?}", start.elapsed());
    });
}

#[test]
fn a_mapped_file_pages_in_and_out() {
    for read in [false, true] {
        mapped_file_pages_in_and_out(read);
    }
}

fn mapped_file_pages_in_and_out(read: bool) {
    let s = Synth::build(40, Mix::Mixed, 30_000, 101).reading(read);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("blocks.bin");
    std::fs::write(&path, &s.file).unwrap();
    let map = MappedFile::open(&path).unwrap();
    assert_eq!(map.bytes(), &s.file[..]);
    for threads in [1, 4] {
        // A budget below one block (raised to the zstd slots'): raw blocks are released.
        let p = Bound::new(&map, &s, s.opts(1000, threads));
        let mut c = sum(&run_threads(&p, &s, threads, 1500, 103));
        for b in 0..40 {
            checked_get(&p, &s, b, &mut c);
        }
        let raw = s.dir.iter().filter(|e| e.codec == CODEC_RAW).count() as u64;
        assert!(raw > 5 && c.misses > 40, "{c:?}");
        check_bound(&p, &s, threads, "mapped");
    }
    // A block damaged on disk is an error there too.
    let mut bad = s.file.clone();
    let b = s.first(CODEC_RAW);
    bad[s.dir[b].offset as usize + 3] ^= 1;
    let path = dir.path().join("bad.bin");
    std::fs::write(&path, &bad).unwrap();
    let map = MappedFile::open(&path).unwrap();
    let p = Bound::new(&map, &s, s.opts(1000, 1));
    let e = p.get(b as u32, &mut PageCounters::default()).err().unwrap();
    assert!(e.to_string().contains("checksum mismatch"), "{e}");
    checked_get(&p, &s, (b + 1) as u32, &mut PageCounters::default());
}
