//! The pager: the only way the tracer reaches a block's bytes (format-spec.md §8: the
//! block directory and the blocks region; [`BlockEntry`]). A cache policy, so it lives with the
//! tracer; it reads blocks the one way the physical layer defines ([`BlockReader`]).
//!
//! A file's tree is split into *blocks*, self-contained subtrees whose bytes are stored either
//! raw or as one zstd frame. [`Pager::get`] turns a block id into the block's decoded bytes, and
//! keeps the memory those bytes take within a budget: zstd blocks are decompressed into a fixed
//! set of cache slots; raw blocks are read into slots too ([`PagerOptions::read_blocks`], the
//! scene's default under a budget), or are pages of the map, given back to the kernel when
//! evicted.
//!
//! **Admission.** The directory is cast from the file, so it is untrusted. The first `get` of a
//! block since it was last evicted (a *miss*) checks its entry as format-spec §11 ("Paging")
//! says ([`BlockReader::check_entry`]: inside the blocks section, a known codec, `raw_len`
//! within the header's largest block and, for zstd, within
//! [`MAX_ZSTD_RATIO`](crate::physical::format::MAX_ZSTD_RATIO) of what it
//! stores, a raw block page-aligned with `raw_len == stored_len`, so its bytes are 8-aligned and
//! its pages are its own). It then hints the kernel to read the range
//! ([`BlockSource::prefetch`]) and checks the xxh3 of the stored bytes, which reads the block
//! from the disk. A zstd frame is decoded by [`BlockReader::decode`] into a buffer of exactly
//! `raw_len` bytes: a frame claiming more cannot make the pager allocate or write more. Any
//! failure is a [`PageError`] naming the block, and the block is remembered as bad: later gets
//! fail at once with the same error. No bytes of the file can make the pager panic or allocate
//! more than `max_raw_len` per slot.
//!
//! **Raw blocks read from the map** (without [`PagerOptions::read_blocks`], or when nothing is
//! ever evicted) are returned as slices of the source, without a copy. Each block has an
//! atomic state: cold, busy (being admitted or evicted), resident, resident and referenced, or
//! bad. One thread admits a cold block (cold -> busy -> referenced); others asking for it wait
//! (spin, then yield) and count a hit. Admitted blocks are queued, referenced, in a ring that
//! CLOCK (Corbató 1968, the second-chance approximation of LRU) sweeps when the resident bytes
//! exceed the budget: a referenced block loses its bit and goes round again, an unreferenced
//! one is released ([`BlockSource::release`]: its pages are dropped from the process and the
//! page cache) and made cold. A hit sets the bit of a block that lost it. One eviction clears
//! bits for at most one pass over the ring, then evicts referenced blocks too, so hits racing
//! the hand cannot keep it going round. **Eviction of a raw block is memory-safe while another
//! thread reads it**: releasing drops pages, not the mapping, and a later access faults the
//! same bytes back in from the file (see [`crate::os::MappedFile::release`]). So a raw hit
//! takes no pin, and writes nothing unless it sets the bit: one atomic load in the common case.
//! The price is paid by budgets of a few blocks: a block evicted while its caller still walks
//! it is read from the disk again.
//!
//! **Blocks in slots** (zstd blocks, and raw blocks read into memory) live in slots, each an
//! `RwLock` over a page-aligned buffer ([`PageBuf`]: whole pages, of the block's size; a
//! slot's buffer is replaced on a miss when it is too small or more than about twice too
//! large, never past `max_raw_len` rounded to pages). A raw block is read straight into its
//! slot ([`BlockSource::read_at`]: one direct read past the page cache, for a mapped file),
//! then checked; a zstd block's stored bytes are read into a per-thread buffer (or taken from
//! the map) and decoded into the slot, with a zstd context per thread (not per slot). A miss
//! takes a slot holding a block before a free one once the budget is full, preferring one
//! whose buffer the block fits ([`VICTIMS`] looked at), so that buffers are reused rather
//! than mapped, faulted in and unmapped for every block. A
//! hit reads the block's slot index (an atomic), takes that slot's read lock and checks that it
//! holds the block: no global lock, no allocation. The guard is returned inside [`BlockBytes`],
//! so a slot cannot be reused while a caller reads it. A miss takes the clock mutex, looks
//! again (another thread may have just admitted the block), and takes a slot that holds no
//! block (never used, or freed by a failed decode) or else picks a victim by CLOCK among the
//! slots whose `try_write` succeeds (slots that nobody is reading). It assigns the slot to the
//! block, releases the mutex, then verifies and decompresses into the slot under the write
//! lock, and downgrades the write lock to the read lock it returns (so no other miss can take
//! the slot in between). Callers asking for the same block meanwhile find the slot assigned
//! and wait on its read lock, then count a hit.
//!
//! After a miss, with only the read lock of the slot it filled, the thread frees other slots'
//! buffers by CLOCK (among slots nobody reads) until the resident bytes are within the budget:
//! the cache is bounded by bytes, so small blocks fill it by the many.
//!
//! **No deadlock.** The clock mutex is never held while waiting on a slot (only `try_write`),
//! and a slot's write lock is never held while waiting on the mutex (a read lock may be: the
//! mutex's holder waits on nothing). A caller holds at most one
//! [`BlockBytes`] at a time (the tracer drops a block before asking for the next), so a caller
//! inside `get` holds no slot, and every slot's readers are callers outside `get` that will
//! drop theirs: a sweep that finds no slot free drops the mutex, yields and tries again, and
//! eventually finds one. With `threads + 1` slots and at most `threads` callers, one slot is
//! always free of long-term readers, so that wait is short. (A caller holding two blocks while
//! it asks for a third could wait for ever if every slot were held: do not.) A raw block is busy
//! only while one thread admits or evicts it, which waits on nothing. The raw eviction mutex is
//! held only while evicting, which waits on nothing but the ring's mutex (held for one push or
//! pop).
//!
//! **Memory bound.** The slots number `max(budget / S, threads + 1)` (no more than there are
//! blocks), `S` the blocks' average size in whole pages, at most [`MIN_SLOT_BYTES`]: at least
//! `threads + 1`, so that a free slot exists, and few enough that the slots themselves cost
//! little (blocks' heads, a few KiB each, get a slot each). Resident bytes count each resident raw block's
//! `stored_len` and each slot's buffer capacity. A thread that raises them past the budget
//! (admitting a raw block, filling a slot) evicts raw blocks and frees slot buffers until they
//! are back under it before its `get` returns (one thread evicts raw blocks at a time; the
//! others wait for it, then evict what is still over; slots held by readers, at most one per
//! other thread, are skipped), and a block is queued for eviction only once its bytes are
//! counted. A slot's buffer is never larger than `M`, `max_raw_len` rounded up to whole pages
//! (a new one is the size of its block in whole pages; a reused one was made so). Blocks held
//! by readers cannot be evicted, so with `B = max(budget, (threads + 1) * M)`: at any time
//! `resident <= B + one block (M) per thread inside get`, and once the gets return,
//! `resident <= B`. A budget of `u64::MAX` means unlimited: nothing is ever evicted, and each
//! zstd block gets a slot of its own.
//!
//! The pager is given a budget that makes this bound the user's: `crate::logical::Scene`
//! passes it the user's budget less one block (`M`) per thread, and lowers the threads until
//! that is at least `(threads + 1) * M` (or refuses a budget smaller than three blocks), so the
//! resident bytes never exceed the budget the user gave. Nothing is raised.
//!
//! **Counters.** [`PageCounters`] belong to the caller (one per thread, summed at the end), so a
//! hit touches no shared counter; resident bytes and their peak are shared atomics, changed on
//! admission and eviction only. They count the gets that succeeded: `requested = hits +
//! misses`, a miss adds its block's `stored_len` to `bytes_read` and (zstd) its `raw_len` to
//! `bytes_decompressed`; a get that returns an error counts nothing.
//!
//! **Cost.** A raw eviction pops the ring, O(1) per block looked at; a slot sweep looks at each
//! slot at most twice, and so does a slot eviction. `Pager::new` allocates a few bytes of state per block and reads the
//! directory's codecs, never the blocks.

use std::collections::{HashMap, VecDeque};
use std::ops::Deref;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU32, AtomicU64, Ordering};
use std::sync::{
    Mutex, MutexGuard, OnceLock, RwLock, RwLockReadGuard, RwLockWriteGuard, TryLockError,
};

use super::held::ReadyMap;
use crate::os::{Changed, MappedFile, PageBuf};
use crate::physical::format::{BlockEntry, CODEC_LEAN, CODEC_RAW, CODEC_ZSTD, Header};
use crate::physical::{AlignedBytes, BlockError, BlockReader};

/// Where the pager reads blocks from: the whole file's bytes, with hints for the kernel.
///
/// Production uses a [`MappedFile`] (a prefetch is `madvise(WILLNEED)`, a release gives the
/// pages back); tests use an [`AlignedBytes`] buffer, whose hints do nothing.
pub trait BlockSource: Sync {
    /// The whole file.
    fn bytes(&self) -> &[u8];
    /// The bytes `off .. off + len` are about to be read.
    fn prefetch(&self, _off: usize, _len: usize) {}
    /// The bytes `off .. off + len` will not be needed for a while: their memory may be given
    /// back. They must stay readable (a later read may be slower, never wrong).
    fn release(&self, _off: usize, _len: usize) {}
    /// What [`Self::read_at`]'s offset and length should be multiples of to read directly
    /// (1: any read is as good as any other).
    fn read_align(&self) -> usize {
        1
    }
    /// Copies the bytes `off .. off + buf.len()` into `buf` (zeros past the end). A mapped
    /// file reads them from the disk into `buf` directly, past the page cache, when `off` and
    /// `buf`'s length are multiples of [`Self::read_align`] and `buf` is page-aligned
    /// ([`crate::os::PageBuf`]).
    fn read_at(&self, off: u64, buf: &mut [u8]) -> std::io::Result<()> {
        let bytes = self.bytes();
        let start = usize::try_from(off).unwrap_or(usize::MAX).min(bytes.len());
        let n = buf.len().min(bytes.len() - start);
        buf[..n].copy_from_slice(&bytes[start..start + n]);
        buf[n..].fill(0);
        Ok(())
    }
    /// Each `(off, buf)` of `reads` as [`Self::read_at`] reads it; a mapped file reads them
    /// all at once, at most `depth` in flight, where it can read them directly
    /// ([`MappedFile::read_many`]). Each read's result, in order.
    fn read_many(&self, reads: &mut [(u64, &mut [u8])], depth: usize) -> Vec<std::io::Result<()>> {
        let _ = depth;
        reads
            .iter_mut()
            .map(|(off, buf)| self.read_at(*off, buf))
            .collect()
    }
    /// `Err` if the bytes changed since the source was opened (a mapped file truncated or
    /// written in place by another program): what was read from them cannot be trusted.
    fn check_unchanged(&self) -> Result<(), Changed> {
        Ok(())
    }
    /// [`Self::check_unchanged`] for a reader of the generation whose header it read from
    /// slot `slot` (format-spec §2.1): an update, which only appends and writes a header slot,
    /// changed none of the bytes it reads.
    fn check_unchanged_at(&self, slot: usize, header: &Header) -> Result<(), Changed> {
        let _ = (slot, header);
        self.check_unchanged()
    }
}

/// Bytes held in memory (tests, files built in memory): the hints do nothing.
impl BlockSource for &[u8] {
    fn bytes(&self) -> &[u8] {
        self
    }
}

impl BlockSource for MappedFile {
    fn bytes(&self) -> &[u8] {
        self.as_ref()
    }
    fn prefetch(&self, off: usize, len: usize) {
        self.advise_range(memmap2::Advice::WillNeed, off, len);
    }
    fn release(&self, off: usize, len: usize) {
        MappedFile::release(self, off, len);
    }
    fn read_align(&self) -> usize {
        self.direct_align()
    }
    fn read_at(&self, off: u64, buf: &mut [u8]) -> std::io::Result<()> {
        MappedFile::read_at(self, off, buf)
    }
    fn read_many(&self, reads: &mut [(u64, &mut [u8])], depth: usize) -> Vec<std::io::Result<()>> {
        MappedFile::read_many(self, reads, depth)
    }
    fn check_unchanged(&self) -> Result<(), Changed> {
        MappedFile::check_unchanged(self)
    }
    fn check_unchanged_at(&self, slot: usize, header: &Header) -> Result<(), Changed> {
        self.check_unchanged_unless(|f| crate::physical::generation_intact(f, slot, header))
    }
}

impl BlockSource for AlignedBytes {
    fn bytes(&self) -> &[u8] {
        self.as_ref()
    }
}

/// How much memory the pager may keep, and for how many threads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PagerOptions {
    /// Bytes of decoded blocks kept resident; `u64::MAX` for no limit. Never raised (see the
    /// module docs).
    pub budget: u64,
    /// The number of threads that call [`Pager::get`] at the same time (at least 1).
    pub threads: usize,
    /// Check a raw block's checksum when it is admitted, which reads it whole (with a hint to
    /// read it in one request). Off, a raw block's entry is still checked but only the pages a
    /// walk touches are read: far fewer bytes from the disk for rays that only pass through a
    /// block, and bytes that are never checked (every read is still bounds-checked, so a
    /// damaged block can give wrong answers, never a crash). Zstd blocks are always checked
    /// (they are decoded whole anyway).
    pub check_raw: bool,
    /// Read blocks into the pager's own memory ([`BlockSource::read_at`]: for a mapped file,
    /// direct reads past the page cache) instead of through the map: raw blocks then live in
    /// cache slots as decoded zstd blocks do, and zstd blocks' stored bytes are read into a
    /// buffer. Used under a budget with checks on, where each block is read whole anyway:
    /// faulting a block's pages in and dropping them on eviction cost the kernel more time
    /// than the tracing (format 4, 130M triangles in 1.5 GiB: 7.6 s of system time in 7.7 s),
    /// and reader threads each waiting on a direct read keep the disk at its bandwidth. Ignored
    /// when nothing is ever evicted (a raw file the budget holds whole is read from the map),
    /// and for raw blocks without `check_raw` (which read only the pages a walk touches).
    pub read_blocks: bool,
}

/// What the caller's gets cost (summed over them). See the module docs for what counts.
#[derive(Clone, Copy, Default, Debug, PartialEq, Eq, serde::Serialize)]
pub struct PageCounters {
    /// Successful gets.
    pub requested: u64,
    /// Gets answered from a resident block (including waiting for another thread's admission).
    pub hits: u64,
    /// Gets that admitted the block: read (and for zstd, decompressed) it.
    pub misses: u64,
    /// Stored bytes read and checksummed by misses.
    pub bytes_read: u64,
    /// Bytes produced by decompressing zstd blocks on misses.
    pub bytes_decompressed: u64,
    /// Chunks of groups asked for ([`chunks::ChunkCache`]), found resident, and read (their
    /// stored bytes are counted in `bytes_read`).
    pub chunk_requests: u64,
    pub chunk_hits: u64,
    pub chunk_misses: u64,
}

impl PageCounters {
    /// A get answered from a block that is already resident (read from the map, or kept by the
    /// caller from an earlier such get): one request, one hit.
    #[inline(always)]
    pub(crate) fn resident_hit(&mut self) {
        self.requested += 1;
        self.hits += 1;
    }
}

impl std::ops::AddAssign for PageCounters {
    fn add_assign(&mut self, o: PageCounters) {
        self.requested += o.requested;
        self.hits += o.hits;
        self.misses += o.misses;
        self.bytes_read += o.bytes_read;
        self.bytes_decompressed += o.bytes_decompressed;
        self.chunk_requests += o.chunk_requests;
        self.chunk_hits += o.chunk_hits;
        self.chunk_misses += o.chunk_misses;
    }
}

impl std::ops::Add for PageCounters {
    type Output = PageCounters;
    fn add(mut self, o: PageCounters) -> PageCounters {
        self += o;
        self
    }
}

/// A block that cannot be read: a bad directory entry, a checksum mismatch, a frame that does
/// not decode to its block.
pub type PageError = BlockError;

/// A block's decoded bytes (8-aligned), borrowed from the pager. Drop it before asking for the
/// next block (see the module docs: a caller holds at most one).
pub enum BlockBytes<'p> {
    /// A raw block: a slice of the source.
    Raw(&'p [u8]),
    /// A zstd block, decompressed into a slot that stays locked for reading while this lives.
    Decoded(SlotGuard<'p>),
}

impl Deref for BlockBytes<'_> {
    type Target = [u8];
    #[inline]
    fn deref(&self) -> &[u8] {
        match self {
            BlockBytes::Raw(bytes) => bytes,
            BlockBytes::Decoded(guard) => guard,
        }
    }
}

/// The read lock on a slot holding a decoded zstd block.
pub struct SlotGuard<'p>(RwLockReadGuard<'p, Slot>);

impl Deref for SlotGuard<'_> {
    type Target = [u8];
    #[inline]
    fn deref(&self) -> &[u8] {
        self.0.bytes()
    }
}

/// A cache slot for one block: a decoded zstd block, or a raw block read into it
/// ([`PagerOptions::read_blocks`]).
pub struct Slot {
    /// The block it holds, or [`NO_BLOCK`].
    block: u32,
    /// Whether `words` holds the block's decoded bytes (false while decoding, after a failure).
    valid: bool,
    /// The block's bytes, `len` of them, page-aligned (for direct reads, and so 8-aligned for
    /// the records).
    buf: PageBuf,
    len: usize,
    /// Bytes counted in the pager's resident bytes for this slot (its buffer's capacity).
    accounted: u64,
}

thread_local! {
    /// Per thread, the buffer a zstd block's stored bytes are read into (with
    /// [`PagerOptions::read_blocks`]), kept and grown to the largest read so far.
    static STORED: std::cell::RefCell<PageBuf> = std::cell::RefCell::new(PageBuf::default());
    /// One zstd decompression context per thread, made on its first miss and kept: a miss
    /// allocates no context, and slots (of which there may be tens of thousands) hold none.
    static DCTX: std::cell::RefCell<Option<zstd::bulk::Decompressor<'static>>> =
        const { std::cell::RefCell::new(None) };
}

/// The smallest average block the slot count plans for: a budget of `B` bytes gets at most
/// `B / MIN_SLOT_BYTES` slots (so slots, about 64 bytes each, cost at most 1/1024 of the
/// budget, and little time to set up at open), and the budget, not the slot count, bounds the
/// cache unless blocks average less than this (the default 256 KiB target gives about 90 KiB).
pub const MIN_SLOT_BYTES: u64 = 64 * 1024;

impl Slot {
    fn bytes(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&[])
    }
}

const NO_BLOCK: u32 = u32::MAX;
const NO_SLOT: u32 = u32::MAX;

// Raw block states (`Pager::state`). Zstd blocks use only COLD and BAD.
const COLD: u8 = 0;
/// Being admitted or evicted by one thread; others wait.
const BUSY: u8 = 1;
const RESIDENT: u8 = 2;
const REFERENCED: u8 = 3;
const BAD: u8 = 4;

/// Spins before a waiting thread starts yielding.
const SPINS: u32 = 64;

/// Reads blocks for the tracer within a memory budget. See the module docs.
pub struct Pager {
    /// [`PagerOptions::check_raw`].
    check_raw: bool,
    /// Blocks are read into memory of the pager's ([`PagerOptions::read_blocks`]); raw
    /// blocks too, in slots.
    read_blocks: bool,
    read_raw: bool,
    /// How blocks are checked and decoded.
    reader: BlockReader,
    /// The budget ([`Self::set_budget`] lowers it while a stream's parked walks take part of
    /// it).
    budget: AtomicU64,
    /// Per block: COLD, BUSY, RESIDENT, REFERENCED or BAD.
    state: Vec<AtomicU8>,
    /// Why each bad block is bad (filled on the error path only).
    bad: Mutex<HashMap<u32, String>>,
    resident: AtomicU64,
    peak: AtomicU64,
    /// Raw blocks that are resident, in CLOCK order; each at most once.
    ring: Mutex<VecDeque<u32>>,
    /// Held by the one thread evicting raw blocks.
    evicting: Mutex<()>,
    /// Per block: the slot holding (or being filled with) it, or NO_SLOT.
    block_slot: Vec<AtomicU32>,
    slots: Vec<RwLock<Slot>>,
    slot_referenced: Vec<AtomicBool>,
    /// Held to assign a slot to a block.
    hand: Mutex<Hand>,
    /// Per block: its map, made when it is first admitted and kept (see [`ReadyMap`]).
    ready: Vec<OnceLock<Box<ReadyMap>>>,
    /// No block is ever evicted: every block is raw and the budget holds them all.
    keeps_everything: bool,
    /// The directory given to each get is of blocks' heads (spec §8.2: every entry's
    /// `raw_len` its `head_raw_len`), whose groups a [`chunks::ChunkCache`] reads.
    heads: bool,
}

/// The slots' CLOCK state.
struct Hand {
    /// The next slot the hand looks at.
    at: usize,
    /// Slots holding no block (never used, or freed by a failed decode), used before any slot
    /// is taken from a block: an unlimited budget never evicts. Hints: checked when taken.
    free: Vec<usize>,
}

/// What one call reads: the file's bytes and its block directory. The pager keeps no reference
/// to them, so that whoever owns the file can own its pager too; every call must pass the same
/// file.
struct Src<'s, S> {
    source: &'s S,
    directory: &'s [BlockEntry],
}

impl<S> Clone for Src<'_, S> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<S> Copy for Src<'_, S> {}

impl Pager {
    /// A pager over `directory` (cast from the file, untrusted: each entry is checked when its
    /// block is first admitted). Reads the directory's codecs to size the slot set, never the
    /// blocks; allocates a few bytes per block, and no slot buffer until a zstd miss needs it.
    pub fn new(directory: &[BlockEntry], reader: BlockReader, opts: PagerOptions) -> Pager {
        let threads = opts.threads.max(1) as u64;
        let keeps_everything = !reader.compressed()
            && opts.budget >= (directory.len() as u64).saturating_mul(reader.max_raw_len());
        let read_raw = opts.read_blocks && opts.check_raw && !keeps_everything;
        // (Slot indices are stored as u32s, NO_SLOT excluded.)
        // Blocks' heads (a few KiB each) are smaller on average than MIN_SLOT_BYTES: the slots
        // are planned for the blocks' average size in whole pages, when smaller.
        let pages: u64 = directory.iter().fold(0u64, |a, e| {
            a.saturating_add(e.raw_len.checked_next_multiple_of(4096).unwrap_or(u64::MAX))
        });
        let per_slot = (pages / (directory.len() as u64).max(1)).clamp(4096, MIN_SLOT_BYTES);
        let slot_count = if reader.compressed() || read_raw {
            (opts.budget / per_slot)
                .max(threads + 1)
                .min(directory.len() as u64)
                .min(u64::from(NO_SLOT) - 1)
        } else {
            0
        };
        Pager {
            check_raw: opts.check_raw,
            read_blocks: opts.read_blocks,
            read_raw,
            reader,
            budget: AtomicU64::new(opts.budget),
            state: directory.iter().map(|_| AtomicU8::new(COLD)).collect(),
            bad: Mutex::new(HashMap::new()),
            resident: AtomicU64::new(0),
            peak: AtomicU64::new(0),
            ring: Mutex::new(VecDeque::new()),
            evicting: Mutex::new(()),
            block_slot: directory.iter().map(|_| AtomicU32::new(NO_SLOT)).collect(),
            slots: (0..slot_count)
                .map(|_| {
                    RwLock::new(Slot {
                        block: NO_BLOCK,
                        valid: false,
                        buf: PageBuf::default(),
                        len: 0,
                        accounted: 0,
                    })
                })
                .collect(),
            slot_referenced: (0..slot_count).map(|_| AtomicBool::new(false)).collect(),
            hand: Mutex::new(Hand {
                at: 0,
                free: (0..slot_count as usize).rev().collect(),
            }),
            ready: directory.iter().map(|_| OnceLock::new()).collect(),
            keeps_everything,
            heads: false,
        }
    }

    /// The map of `block`, whose bytes `raw` a [`Self::get`] just gave: made (and the block's
    /// layout checked) the first time, kept after. A block whose layout is wrong gives its
    /// error every time.
    pub fn ready(
        &self,
        block: u32,
        entry: &BlockEntry,
        raw: &[u8],
    ) -> Result<&ReadyMap, PageError> {
        let Some(cell) = self.ready.get(block as usize) else {
            return Err(PageError {
                block,
                what: "no such block".into(),
            });
        };
        if let Some(r) = cell.get() {
            return Ok(r);
        }
        match ReadyMap::new(raw, block, entry, self.heads) {
            Ok(r) => Ok(cell.get_or_init(|| Box::new(r))),
            Err(what) => Err(PageError {
                block,
                what: what.to_string(),
            }),
        }
    }

    /// Makes the pager one of blocks' heads (see [`Pager::heads`]'s field): each get is given
    /// the heads' directory, and a block's map is made from its head.
    pub fn set_heads(&mut self, heads: bool) {
        self.heads = heads;
    }

    /// The maps of blocks admitted so far, if no block is ever evicted (every block raw, and
    /// the budget holding them all): then a walk may read an admitted block's bytes straight
    /// from the file, without asking the pager.
    pub fn resident_forever(&self) -> Option<&[OnceLock<Box<ReadyMap>>]> {
        self.keeps_everything.then_some(&self.ready[..])
    }

    /// The decoded bytes of `block`, admitting it if it is not resident; adds to `c`.
    pub fn get<'s, S: BlockSource>(
        &'s self,
        source: &'s S,
        directory: &'s [BlockEntry],
        block: u32,
        c: &mut PageCounters,
    ) -> Result<BlockBytes<'s>, PageError> {
        let src = Src { source, directory };
        if directory.len() != self.state.len() {
            return Err(PageError {
                block,
                what: "the pager was made for another file's directory".into(),
            });
        }
        let Some(entry) = directory.get(block as usize) else {
            return Err(PageError {
                block,
                what: format!(
                    "no such block (the directory has {} blocks)",
                    directory.len()
                ),
            });
        };
        let bytes = match entry.codec {
            CODEC_RAW if self.read_raw => self.get_slot(src, block, entry, c)?,
            CODEC_RAW => self.get_raw(src, block, entry, c)?,
            CODEC_ZSTD | CODEC_LEAN => self.get_slot(src, block, entry, c)?,
            codec => {
                let what = match self.check_entry(src, entry) {
                    Err(what) => what,
                    Ok(()) => format!("unknown codec {codec}"),
                };
                return Err(self.fail(block, what));
            }
        };
        c.requested += 1;
        Ok(bytes)
    }

    /// Whether `block` is resident now (a hint: it may be evicted the next moment): a raw
    /// block admitted and not evicted, a zstd block with a slot.
    pub fn is_resident(&self, block: u32) -> bool {
        let b = block as usize;
        if self.keeps_everything {
            return true;
        }
        match self.state.get(b).map(|s| s.load(Ordering::Relaxed)) {
            Some(RESIDENT | REFERENCED) => true,
            Some(COLD) if !self.slots.is_empty() => self
                .block_slot
                .get(b)
                .is_some_and(|s| s.load(Ordering::Relaxed) != NO_SLOT),
            _ => false,
        }
    }

    /// Bytes of decoded blocks resident now.
    #[cfg(test)]
    pub fn resident_bytes(&self) -> u64 {
        self.resident.load(Ordering::Relaxed)
    }

    /// The most bytes resident at any time so far.
    pub fn peak_resident_bytes(&self) -> u64 {
        self.peak.load(Ordering::Relaxed)
    }

    /// The budget (see the module docs for what it bounds).
    pub fn budget(&self) -> u64 {
        self.budget.load(Ordering::Relaxed)
    }

    /// Sets the budget (never above the one the pager was made with, which the
    /// scene sized for its threads): [`super::stream`] lowers it by the memory its parked
    /// walks may take, and gives it back after. Evicts at the next admission, not now.
    pub fn set_budget(&self, budget: u64) {
        self.budget.store(budget, Ordering::Relaxed);
    }

    /// Whether blocks are read into the pager's memory ([`PagerOptions::read_blocks`] in
    /// effect): raw blocks into slots, zstd blocks' stored bytes into a buffer.
    pub fn reads_blocks(&self) -> bool {
        self.read_raw || (self.read_blocks && self.reader.compressed())
    }

    /// The number of cache slots.
    pub fn slot_count(&self) -> usize {
        self.slots.len()
    }

    fn get_raw<'s, S: BlockSource>(
        &'s self,
        src: Src<'s, S>,
        block: u32,
        entry: &BlockEntry,
        c: &mut PageCounters,
    ) -> Result<BlockBytes<'s>, PageError> {
        let state = &self.state[block as usize];
        let mut spins = 0;
        loop {
            match state.load(Ordering::Acquire) {
                REFERENCED => break,
                RESIDENT => {
                    // Fails only if an evictor took it meanwhile: look again.
                    if state
                        .compare_exchange(
                            RESIDENT,
                            REFERENCED,
                            Ordering::Acquire,
                            Ordering::Relaxed,
                        )
                        .is_ok()
                    {
                        break;
                    }
                }
                COLD => {
                    if state
                        .compare_exchange(COLD, BUSY, Ordering::Acquire, Ordering::Relaxed)
                        .is_ok()
                    {
                        return self.admit_raw(src, block, entry, c);
                    }
                }
                BAD => return Err(self.remembered(block)),
                _ => wait(&mut spins),
            }
        }
        c.hits += 1;
        Ok(BlockBytes::Raw(self.raw_slice(src, block, entry)?))
    }

    /// Admits a raw block this thread has made BUSY.
    fn admit_raw<'s, S: BlockSource>(
        &'s self,
        src: Src<'s, S>,
        block: u32,
        entry: &BlockEntry,
        c: &mut PageCounters,
    ) -> Result<BlockBytes<'s>, PageError> {
        let state = &self.state[block as usize];
        let checked = self.check_entry(src, entry).and_then(|()| {
            if !self.check_raw {
                return Ok(());
            }
            let (off, len) = (entry.offset as usize, entry.stored_len as usize);
            src.source.prefetch(off, len);
            self.reader.check_sum(entry, self.stored(src, entry))
        });
        if let Err(what) = checked {
            return Err(self.fail(block, what));
        }
        self.add_resident(entry.stored_len);
        state.store(REFERENCED, Ordering::Release);
        lock(&self.ring).push_back(block);
        c.misses += 1;
        c.bytes_read += entry.stored_len;
        self.evict_raw(src);
        self.evict_slots();
        Ok(BlockBytes::Raw(self.raw_slice(src, block, entry)?))
    }

    /// A raw block's bytes (its entry was checked on admission; checked again for free).
    fn raw_slice<'s, S: BlockSource>(
        &self,
        src: Src<'s, S>,
        block: u32,
        entry: &BlockEntry,
    ) -> Result<&'s [u8], PageError> {
        let source: &'s S = src.source;
        let off = entry.offset as usize;
        source
            .bytes()
            .get(off..off.saturating_add(entry.stored_len as usize))
            .ok_or_else(|| PageError {
                block,
                what: "outside the file".into(),
            })
    }

    /// Evicts raw blocks by CLOCK until the resident bytes are within the budget or no raw
    /// block is left to evict. One thread evicts at a time; the others wait for it, then evict
    /// what is still over (so that no thread returns with the budget exceeded by more than the
    /// blocks other threads are admitting).
    fn evict_raw<S: BlockSource>(&self, src: Src<'_, S>) {
        if self.resident.load(Ordering::SeqCst) <= self.budget() {
            return;
        }
        let _evicting = lock(&self.evicting);
        // The first pass over the blocks queued now clears referenced bits; after it, a
        // referenced block is evicted too, so that hits racing the hand cannot keep it going
        // round for ever. Blocks queued meanwhile are evicted by their own threads, or here.
        let first_pass = lock(&self.ring).len();
        let mut step = 0;
        while self.resident.load(Ordering::SeqCst) > self.budget() {
            let Some(b) = lock(&self.ring).pop_front() else {
                break;
            };
            let second_chance = step < first_pass;
            step += 1;
            let state = &self.state[b as usize];
            loop {
                let s = state.load(Ordering::Relaxed);
                if s == REFERENCED && second_chance {
                    if state
                        .compare_exchange(s, RESIDENT, Ordering::Relaxed, Ordering::Relaxed)
                        .is_ok()
                    {
                        lock(&self.ring).push_back(b);
                        break;
                    }
                } else if s == REFERENCED || s == RESIDENT {
                    if state
                        .compare_exchange(s, BUSY, Ordering::Acquire, Ordering::Relaxed)
                        .is_ok()
                    {
                        let e = &src.directory[b as usize];
                        src.source.release(e.offset as usize, e.stored_len as usize);
                        self.resident.fetch_sub(e.stored_len, Ordering::SeqCst);
                        state.store(COLD, Ordering::Release);
                        break;
                    }
                } else {
                    // Not reached: a queued block is resident until popped and evicted.
                    break;
                }
                // A hit set the bit between the load and the exchange: look again.
            }
        }
    }

    /// A block kept in a slot: a zstd block, or a raw block read into one.
    fn get_slot<'s, S: BlockSource>(
        &'s self,
        src: Src<'s, S>,
        block: u32,
        entry: &BlockEntry,
        c: &mut PageCounters,
    ) -> Result<BlockBytes<'s>, PageError> {
        if self.slots.is_empty() {
            return Err(self.fail(
                block,
                "a zstd block in a file whose header says no block is compressed".into(),
            ));
        }
        let mut spins = 0;
        loop {
            if self.state[block as usize].load(Ordering::Acquire) == BAD {
                return Err(self.remembered(block));
            }
            if let Some(guard) = self.slot_hit(block) {
                c.hits += 1;
                return Ok(BlockBytes::Decoded(SlotGuard(guard)));
            }
            self.check_entry(src, entry)
                .map_err(|what| self.fail(block, what))?;
            let Some((slot, write)) = self.assign_slot(block, entry.raw_len) else {
                // Admitted by another thread meanwhile (look again), or no slot free of
                // readers yet (wait for one).
                wait(&mut spins);
                continue;
            };
            return self.admit_slot(src, block, entry, slot, write, c);
        }
    }

    /// The slot holding `block`, locked for reading, if it holds it (waits while it is being
    /// filled).
    fn slot_hit(&self, block: u32) -> Option<RwLockReadGuard<'_, Slot>> {
        let s = self.block_slot[block as usize].load(Ordering::Acquire);
        let slot = self.slots.get(s as usize)?;
        let guard = slot.read().unwrap_or_else(|p| p.into_inner());
        if guard.block != block || !guard.valid {
            return None;
        }
        let referenced = &self.slot_referenced[s as usize];
        if !referenced.load(Ordering::Relaxed) {
            referenced.store(true, Ordering::Relaxed);
        }
        Some(guard)
    }

    /// Under the clock mutex: a slot for `block` (of `raw_len` bytes), chosen by CLOCK among
    /// the slots nobody reads, locked for writing and assigned to the block. `None` if the
    /// block has a slot already, or if no slot is free of readers.
    ///
    /// A free slot (holding no block) is taken first if the budget has room for the block or
    /// the slot has a buffer the block can reuse; else a slot holding a block is taken first,
    /// so that its buffer is reused if the block fits it ([`Self::decode`]): mapping a new
    /// buffer and faulting its pages in for every block read, and unmapping another's, had
    /// cost more system time than the reads themselves.
    fn assign_slot(&self, block: u32, raw_len: u64) -> Option<(usize, RwLockWriteGuard<'_, Slot>)> {
        let mut hand = lock(&self.hand);
        // (`new` gives at least one slot when a slot block exists, so `n > 0` below.)
        if self.block_slot[block as usize].load(Ordering::Acquire) != NO_SLOT {
            return None;
        }
        let room = self.resident.load(Ordering::SeqCst).saturating_add(raw_len) <= self.budget();
        if let Some(t) = self.take_free(block, (!room).then_some(raw_len), &mut hand) {
            return Some(t);
        }
        if let Some(t) = self.take_clock(block, raw_len, &mut hand) {
            return Some(t);
        }
        self.take_free(block, None, &mut hand)
    }

    /// A free slot (holding no block), for `block`; with `fits`, only one whose buffer a block
    /// of that many bytes can reuse.
    fn take_free(
        &self,
        block: u32,
        fits: Option<u64>,
        hand: &mut Hand,
    ) -> Option<(usize, RwLockWriteGuard<'_, Slot>)> {
        while let Some(i) = hand.free.pop() {
            if let Some(write) = self.try_write(i)
                && write.block == NO_BLOCK
            {
                if fits.is_some_and(|n| !reusable(write.buf.len(), n as usize)) {
                    // Kept free for a block that has room or fits it.
                    hand.free.push(i);
                    return None;
                }
                return Some(self.assign(block, i, write));
            }
        }
        None
    }

    /// A slot chosen by CLOCK among those nobody reads, for `block` (of `raw_len` bytes): of
    /// the first [`VICTIMS`] the hand finds, the first whose buffer the block can reuse, else
    /// the first.
    fn take_clock(
        &self,
        block: u32,
        raw_len: u64,
        hand: &mut Hand,
    ) -> Option<(usize, RwLockWriteGuard<'_, Slot>)> {
        let n = self.slots.len();
        let mut first: Option<(usize, RwLockWriteGuard<'_, Slot>)> = None;
        let mut seen = 0;
        for _ in 0..2 * n {
            let i = hand.at;
            hand.at = (i + 1) % n;
            if self.slot_referenced[i].load(Ordering::Relaxed) {
                self.slot_referenced[i].store(false, Ordering::Relaxed);
                continue;
            }
            let Some(write) = self.try_write(i) else {
                continue;
            };
            if reusable(write.buf.len(), raw_len as usize) {
                drop(first);
                return Some(self.assign(block, i, write));
            }
            if first.is_none() {
                first = Some((i, write));
            }
            seen += 1;
            if seen >= VICTIMS {
                break;
            }
        }
        first.map(|(i, write)| self.assign(block, i, write))
    }

    /// Frees the buffers of slots nobody reads, chosen by CLOCK, until the resident bytes are
    /// within the budget or one sweep (two passes: the first clears referenced bits) finds
    /// nothing more to free. Freed slots hold no block and go to the free list. Called after
    /// an admission, holding at most the read lock of the slot just filled (which `try_write`
    /// then skips); under the clock mutex, which waits on nothing.
    fn evict_slots(&self) {
        if self.slots.is_empty() || self.resident.load(Ordering::SeqCst) <= self.budget() {
            return;
        }
        let mut hand = lock(&self.hand);
        let n = self.slots.len();
        for _ in 0..2 * n {
            if self.resident.load(Ordering::SeqCst) <= self.budget() {
                break;
            }
            let i = hand.at;
            hand.at = (i + 1) % n;
            if self.slot_referenced[i].load(Ordering::Relaxed) {
                self.slot_referenced[i].store(false, Ordering::Relaxed);
                continue;
            }
            let Some(mut w) = self.try_write(i) else {
                continue;
            };
            if w.accounted == 0 {
                continue;
            }
            if let Some(old) = self.block_slot.get(w.block as usize) {
                let _ =
                    old.compare_exchange(i as u32, NO_SLOT, Ordering::Release, Ordering::Relaxed);
            }
            w.block = NO_BLOCK;
            w.valid = false;
            w.len = 0;
            w.buf = PageBuf::default();
            self.resident.fetch_sub(w.accounted, Ordering::SeqCst);
            w.accounted = 0;
            drop(w);
            hand.free.push(i);
        }
    }

    /// Slot `i` locked for writing, if nobody holds it.
    fn try_write(&self, i: usize) -> Option<RwLockWriteGuard<'_, Slot>> {
        match self.slots[i].try_write() {
            Ok(w) => Some(w),
            Err(TryLockError::Poisoned(p)) => Some(p.into_inner()),
            Err(TryLockError::WouldBlock) => None,
        }
    }

    /// Takes slot `i` (locked for writing, under the clock mutex) from its block for `block`.
    fn assign<'p>(
        &self,
        block: u32,
        i: usize,
        mut write: RwLockWriteGuard<'p, Slot>,
    ) -> (usize, RwLockWriteGuard<'p, Slot>) {
        if let Some(old) = self.block_slot.get(write.block as usize) {
            let _ = old.compare_exchange(i as u32, NO_SLOT, Ordering::Release, Ordering::Relaxed);
        }
        write.block = block;
        write.valid = false;
        self.block_slot[block as usize].store(i as u32, Ordering::Release);
        self.slot_referenced[i].store(true, Ordering::Relaxed);
        (i, write)
    }

    /// Fills a slot assigned to `block` (outside the clock mutex) and returns it locked for
    /// reading.
    fn admit_slot<'p, S: BlockSource>(
        &'p self,
        src: Src<'_, S>,
        block: u32,
        entry: &BlockEntry,
        slot: usize,
        mut write: RwLockWriteGuard<'p, Slot>,
        c: &mut PageCounters,
    ) -> Result<BlockBytes<'p>, PageError> {
        match self.decode(src, entry, &mut write) {
            Ok(()) => {
                write.valid = true;
                let read = RwLockWriteGuard::downgrade(write);
                c.misses += 1;
                c.bytes_read += entry.stored_len;
                if entry.codec != CODEC_RAW {
                    c.bytes_decompressed += entry.raw_len;
                }
                self.evict_slots();
                self.evict_raw(src);
                Ok(BlockBytes::Decoded(SlotGuard(read)))
            }
            Err(what) => {
                let err = self.fail(block, what);
                write.block = NO_BLOCK;
                write.valid = false;
                write.len = 0;
                self.block_slot[block as usize].store(NO_SLOT, Ordering::Release);
                self.slot_referenced[slot].store(false, Ordering::Relaxed);
                drop(write);
                lock(&self.hand).free.push(slot);
                Err(err)
            }
        }
    }

    /// Fills `slot` with a block: a raw block's stored bytes read into it and verified, or a
    /// zstd block's verified and decompressed into it.
    fn decode<S: BlockSource>(
        &self,
        src: Src<'_, S>,
        entry: &BlockEntry,
        slot: &mut Slot,
    ) -> Result<(), String> {
        let raw_len = entry.raw_len as usize;
        // A buffer of the block's size: the one the slot has if it is large enough and not
        // more than about twice too large, else a new one (the old one is given back). Whole
        // pages, so that a raw block's last page is read whole too.
        slot.len = 0;
        if !reusable(slot.buf.len(), raw_len) {
            slot.buf = PageBuf::default();
            slot.buf = PageBuf::new(raw_len)
                .ok_or_else(|| format!("cannot allocate {raw_len} bytes to read it"))?;
        }
        let now = slot.buf.len() as u64;
        if now > slot.accounted {
            self.add_resident(now - slot.accounted);
        } else {
            self.resident
                .fetch_sub(slot.accounted - now, Ordering::SeqCst);
        }
        slot.accounted = now;
        if entry.codec == CODEC_RAW {
            // (check_entry: a raw block starts on a page and `raw_len == stored_len`.)
            let whole = raw_len.next_multiple_of(crate::os::page_size());
            src.source
                .read_at(entry.offset, &mut slot.buf[..whole])
                .map_err(|e| format!("cannot read it: {e}"))?;
            self.reader.check_sum(entry, &slot.buf[..raw_len])?;
            slot.len = raw_len;
            return Ok(());
        }
        let out = &mut slot.buf[..raw_len];
        let mut decoded = |stored: &[u8]| {
            self.reader.check_sum(entry, stored)?;
            DCTX.with_borrow_mut(|dctx| {
                let dctx = match dctx {
                    Some(d) => d,
                    none => none.insert(
                        zstd::bulk::Decompressor::new()
                            .map_err(|e| format!("cannot create a zstd decompressor: {e}"))?,
                    ),
                };
                self.reader.decode(entry, stored, out, dctx)
            })
        };
        if self.read_blocks {
            // The pages covering the stored bytes, read into this thread's buffer.
            let page = crate::os::page_size() as u64;
            let first = entry.offset / page * page;
            let skip = (entry.offset - first) as usize;
            let len = entry.stored_len as usize;
            let whole = (skip + len).next_multiple_of(page as usize);
            STORED.with_borrow_mut(|buf| {
                if buf.len() < whole {
                    *buf = PageBuf::default();
                    *buf = PageBuf::new(whole)
                        .ok_or_else(|| format!("cannot allocate {whole} bytes to read it"))?;
                }
                src.source
                    .read_at(first, &mut buf[..whole])
                    .map_err(|e| format!("cannot read it: {e}"))?;
                decoded(&buf[skip..skip + len])
            })?;
        } else {
            let stored = self.stored(src, entry);
            src.source.prefetch(entry.offset as usize, stored.len());
            decoded(stored)?;
        }
        slot.len = raw_len;
        Ok(())
    }

    /// Checks an entry without reading its block ([`BlockReader::check_entry`]), and that a
    /// raw block's bytes can be cast in place (the source is 8-aligned).
    fn check_entry<S: BlockSource>(&self, src: Src<'_, S>, e: &BlockEntry) -> Result<(), String> {
        self.reader.check_entry(e)?;
        let base = src.source.bytes().as_ptr() as usize;
        if e.codec == CODEC_RAW && !base.is_multiple_of(std::mem::align_of::<u64>()) {
            return Err("the file's buffer is not 8-aligned".into());
        }
        Ok(())
    }

    /// A block's stored bytes (its entry checked).
    fn stored<'s, S: BlockSource>(&self, src: Src<'s, S>, e: &BlockEntry) -> &'s [u8] {
        self.reader.stored(src.source.bytes(), e)
    }

    fn add_resident(&self, bytes: u64) {
        let now = self.resident.fetch_add(bytes, Ordering::SeqCst) + bytes;
        self.peak.fetch_max(now, Ordering::Relaxed);
    }

    /// Remembers `block` as bad, for `what`, and returns the error.
    fn fail(&self, block: u32, what: String) -> PageError {
        lock(&self.bad).entry(block).or_insert_with(|| what.clone());
        self.state[block as usize].store(BAD, Ordering::Release);
        PageError { block, what }
    }

    /// The error a bad block was remembered with.
    fn remembered(&self, block: u32) -> PageError {
        let what = lock(&self.bad)
            .get(&block)
            .cloned()
            .unwrap_or_else(|| "bad block".into());
        PageError { block, what }
    }
}

/// Slots the CLOCK hand looks at for one whose buffer a block can reuse.
const VICTIMS: usize = 8;

/// Whether a slot's buffer of `len` bytes may take a block of `raw_len`: large enough, and
/// not more than about twice too large.
fn reusable(len: usize, raw_len: usize) -> bool {
    len >= raw_len && len <= 2 * raw_len + 65536
}

/// Locks a mutex, ignoring poisoning (every structure it guards stays consistent at each
/// step).
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Waits a little for another thread: spins, then yields.
fn wait(spins: &mut u32) {
    if *spins < SPINS {
        *spins += 1;
        std::hint::spin_loop();
    } else {
        std::thread::yield_now();
    }
}

#[cfg(test)]
mod tests;

pub mod chunks;
