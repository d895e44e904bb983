//! The chunk cache: a block's triangle groups, chunk by chunk (format-spec §8.3), for a tracer
//! that keeps the blocks' heads in the pager and reads only the chunks rays reach.
//!
//! A file of format 7 stores each block as its head (the octree, the wide nodes, the chunk
//! table) and its groups in chunks of `chunk_groups` groups, each with its own checksum. Out of
//! core, the pager holds heads ([`super::Pager::set_heads`]) and the walk asks this cache for
//! the chunk a group is in ([`ChunkCache::get`]): a whole block is never read for the few
//! groups a ray tests in it.
//!
//! **Slots.** Every chunk of a file decodes to at most `chunk_groups * 160` bytes, so the cache
//! is a fixed set of equal slots (the budget over that size, at least one per thread and one
//! more), each an `RwLock` over a page-aligned buffer. A get looks the chunk up in a map (key:
//! block and chunk) under one mutex, takes the slot's read lock and checks the slot still holds
//! it (a hit: one mutex, one read lock, no allocation). A miss, under the mutex, takes a slot by
//! CLOCK (Corbató 1968) among those nobody reads (`try_write`), maps the chunk to it, releases
//! the mutex, and then, under the slot's write lock only, reads the chunk's stored bytes (a
//! direct read past the page cache, or a copy from the map), checks them against the head's
//! chunk table and decodes them, and downgrades to the read lock it returns. Gets of the same
//! chunk meanwhile wait on that read lock and count a hit. A chunk that fails is reported as an
//! error naming its block and chunk, and stays failed.
//!
//! **No deadlock.** The mutex is never held while waiting on a slot (only `try_write`), and a
//! slot's lock is never held while waiting on the mutex by the thread filling it. A caller holds
//! at most one [`ChunkGuard`] at a time (the walk drops it after the group's test), so with
//! `threads + 1` slots a sweep always finds one free soon; one that finds none yields and tries
//! again.
//!
//! **Direct reads.** Under [`super::PagerOptions::read_blocks`] a chunk's stored bytes are read
//! past the page cache in one read rounded out to the device's block
//! ([`BlockSource::read_align`], 512 bytes here), not to pages: a 5 KiB chunk costs the disk
//! 5 KiB, not the 8-12 KiB of the pages it touches. A raw chunk is read into its slot; a zstd
//! chunk into its thread's read buffer, then decoded into the slot.
//!
//! **Many at once.** [`ChunkCache::read_many`] takes slots for a list of chunks, reads them all
//! from the calling thread with [`BlockSource::read_many`] (an io_uring over the direct file,
//! many reads in flight, where the kernel has one), and checks and decodes each into its slot;
//! it holds those slots' write locks meanwhile (gets of the same chunks wait, as for one read)
//! and never waits for a slot: where none is free it reads what it has. A compressed chunk's
//! stored bytes go to a buffer of the thread's own, [`MANY_PIECE`] of them at most.
//!
//! **Memory bound.** `slots * slot_bytes`, fixed when the cache is made, and one slot's size
//! a reading thread for a zstd chunk's stored bytes ([`MANY_PIECE`] of them for a thread that
//! reads many at once, and its io_uring's buffers, one a read in flight, `crate::os`): nothing
//! grows. (At 128 reads in flight of 5 KiB chunks, about 1.5 MB a thread that has read so, a
//! few threads of a pool: outside the budget, under 3 % of the 1.2 GB one measured.)

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Mutex, RwLock, RwLockReadGuard, RwLockWriteGuard, TryLockError};

use super::{BlockSource, PageCounters, PageError, lock};
use crate::os::PageBuf;
use crate::physical::BlockReader;
use crate::physical::format::{BlockEntry, CODEC_LEAN, CODEC_RAW, CODEC_ZSTD, TriGroup, checksum};

/// A chunk's key: its block (high 32 bits) and its index in the block (low).
fn key(block: u32, chunk: u32) -> u64 {
    (block as u64) << 32 | chunk as u64
}

/// No chunk.
const EMPTY: u64 = u64::MAX;

/// A slot: the chunk it holds (or [`EMPTY`]) and its decoded groups.
struct Slot {
    key: u64,
    buf: PageBuf,
    /// Where the groups start in `buf` (a direct read starts on the page before them).
    start: usize,
    len: usize,
}

/// The cache (see the module docs).
pub struct ChunkCache {
    reader: BlockReader,
    /// Decoded bytes of a whole chunk.
    chunk_bytes: usize,
    /// Read chunks into the slots with direct reads (a mapped file, past the page cache) rather
    /// than copy them from the map.
    read_direct: bool,
    slots: Vec<RwLock<Slot>>,
    referenced: Vec<AtomicBool>,
    /// Key to slot, and the CLOCK hand.
    map: Mutex<(HashMap<u64, u32>, usize)>,
    /// Why each bad chunk is bad.
    bad: Mutex<HashMap<u64, String>>,
    /// Chunks read (every miss), for [`Self::chunks_read`].
    reads: AtomicU64,
}

/// A chunk's groups, locked for reading while this lives.
pub struct ChunkGuard<'c> {
    slot: RwLockReadGuard<'c, Slot>,
}

impl ChunkGuard<'_> {
    /// The chunk's groups.
    #[inline]
    pub fn groups(&self) -> &[TriGroup] {
        let s = &*self.slot;
        bytemuck::try_cast_slice(&s.buf[s.start..s.start + s.len]).unwrap_or(&[])
    }
}

impl ChunkCache {
    /// A cache of `budget` bytes for a file read by `reader`, for `threads` callers at once
    /// (at least `threads + 1` slots whatever the budget: the caller counts them in its own).
    /// `read_direct`: read chunks with direct reads ([`BlockSource::read_at`]).
    pub fn new(reader: BlockReader, budget: u64, threads: usize, read_direct: bool) -> ChunkCache {
        let chunk_bytes = reader.chunk_groups() as usize * std::mem::size_of::<TriGroup>();
        let slot_bytes = Self::slot_bytes_for(chunk_bytes) as u64;
        let count = (budget / slot_bytes.max(1)).max(threads as u64 + 1);
        let count = usize::try_from(count).unwrap_or(usize::MAX).min(1 << 24);
        ChunkCache {
            reader,
            chunk_bytes,
            read_direct,
            slots: (0..count)
                .map(|_| {
                    RwLock::new(Slot {
                        key: EMPTY,
                        buf: PageBuf::default(),
                        start: 0,
                        len: 0,
                    })
                })
                .collect(),
            referenced: (0..count).map(|_| AtomicBool::new(false)).collect(),
            map: Mutex::new((HashMap::new(), 0)),
            bad: Mutex::new(HashMap::new()),
            reads: AtomicU64::new(0),
        }
    }

    /// The memory one slot takes: a chunk's whole pages and one more (a direct read of a chunk
    /// that does not start on a page starts on the page before it, less than a page before,
    /// and ends on the page its last byte is in).
    pub fn slot_bytes_for(chunk_bytes: usize) -> usize {
        let page = crate::os::page_size();
        chunk_bytes.next_multiple_of(page) + page
    }

    /// Groups per chunk.
    pub fn chunk_groups(&self) -> u32 {
        self.reader.chunk_groups()
    }

    /// The most chunks resident at once.
    pub fn slots(&self) -> usize {
        self.slots.len()
    }

    /// Chunk `chunk` of block `block` if it is resident now (counted as a hit), without reading
    /// it: `None` if it is not, is being read, or failed (a [`Self::get`] then says why).
    pub fn peek(&self, block: u32, chunk: u32, c: &mut PageCounters) -> Option<ChunkGuard<'_>> {
        let k = key(block, chunk);
        let s = *lock(&self.map).0.get(&k)?;
        let slot = self.slots[s as usize].try_read().ok()?;
        if slot.key != k {
            return None;
        }
        self.referenced[s as usize].store(true, Ordering::Relaxed);
        c.chunk_requests += 1;
        c.chunk_hits += 1;
        Some(ChunkGuard { slot })
    }

    /// Chunks read so far.
    pub fn chunks_read(&self) -> u64 {
        self.reads.load(Ordering::Relaxed)
    }

    /// Chunk `chunk` of block `block` (entry `e`, decoded head `head`, both checked when the
    /// head was admitted) of the file `src`, read if it is not resident; counted in `c`.
    pub fn get<'c, S: BlockSource + ?Sized>(
        &'c self,
        src: &S,
        block: u32,
        e: &BlockEntry,
        head: &[u8],
        chunk: u32,
        c: &mut PageCounters,
    ) -> Result<ChunkGuard<'c>, PageError> {
        let k = key(block, chunk);
        loop {
            let mut m = lock(&self.map);
            if let Some(&s) = m.0.get(&k) {
                drop(m);
                let slot = self.slots[s as usize]
                    .read()
                    .unwrap_or_else(|p| p.into_inner());
                if slot.key == k {
                    self.referenced[s as usize].store(true, Ordering::Relaxed);
                    c.chunk_requests += 1;
                    c.chunk_hits += 1;
                    return Ok(ChunkGuard { slot });
                }
                // Evicted, or its read failed, since it was looked up: look again.
                continue;
            }
            if let Some(what) = lock(&self.bad).get(&k) {
                return Err(PageError {
                    block,
                    what: what.clone(),
                });
            }
            let Some((s, mut w)) = self.victim(&mut m) else {
                drop(m);
                std::thread::yield_now();
                continue;
            };
            self.assign(&mut m, s, &mut w, k);
            drop(m);
            match self.fill(src, e, head, chunk, &mut w) {
                Ok(read) => {
                    self.count(read, c);
                    let slot = RwLockWriteGuard::downgrade(w);
                    return Ok(ChunkGuard { slot });
                }
                Err(what) => return Err(self.fail(block, chunk, s, &mut w, what)),
            }
        }
    }

    /// Gives slot `s` (write-locked as `w`, found by [`Self::victim`] under the map's lock
    /// `m`) to chunk `k`.
    fn assign(&self, m: &mut (HashMap<u64, u32>, usize), s: usize, w: &mut Slot, k: u64) {
        if w.key != EMPTY {
            m.0.remove(&w.key);
        }
        m.0.insert(k, s as u32);
        w.key = k;
        self.referenced[s].store(true, Ordering::Relaxed);
    }

    /// Counts a chunk read (its stored bytes, and the bytes decompressed) in `c`.
    fn count(&self, (stored, decoded): (u64, u64), c: &mut PageCounters) {
        self.reads.fetch_add(1, Ordering::Relaxed);
        c.chunk_requests += 1;
        c.chunk_misses += 1;
        c.bytes_read += stored;
        c.bytes_decompressed += decoded;
    }

    /// Chunk `chunk` of block `block`, being read into slot `s` (`w`), failed with `what`: it
    /// stays failed (every later get gives the same error) and the slot is emptied.
    fn fail(&self, block: u32, chunk: u32, s: usize, w: &mut Slot, what: String) -> PageError {
        let what = format!("chunk {chunk}: {what}");
        let k = key(block, chunk);
        w.key = EMPTY;
        lock(&self.bad).insert(k, what.clone());
        let mut m = lock(&self.map);
        if m.0.get(&k) == Some(&(s as u32)) {
            m.0.remove(&k);
        }
        PageError { block, what }
    }

    /// A slot nobody reads, write-locked, by CLOCK: a referenced slot loses its bit and is
    /// passed over once; after two turns any free slot is taken. `None` if every slot is read.
    fn victim<'c>(
        &'c self,
        m: &mut (HashMap<u64, u32>, usize),
    ) -> Option<(usize, RwLockWriteGuard<'c, Slot>)> {
        let n = self.slots.len();
        for step in 0..3 * n {
            let s = m.1;
            m.1 = (m.1 + 1) % n;
            if step < 2 * n && self.referenced[s].swap(false, Ordering::Relaxed) {
                continue;
            }
            match self.slots[s].try_write() {
                Ok(w) => return Some((s, w)),
                Err(TryLockError::Poisoned(p)) => return Some((s, p.into_inner())),
                Err(TryLockError::WouldBlock) => {}
            }
        }
        None
    }

    /// Where chunk `chunk` of block `block` (entry `e`, decoded head `head`) is stored and what
    /// it decodes to, from the head's chunk table.
    pub fn plan(
        &self,
        block: u32,
        e: &BlockEntry,
        head: &[u8],
        chunk: u32,
    ) -> Result<ChunkRead, String> {
        let table = self.reader.chunk_table(e, head)?;
        let ce = table
            .get(chunk as usize)
            .ok_or_else(|| format!("no such chunk (the block has {})", table.len()))?;
        let groups = (e.raw_len - e.head_raw_len) as usize / std::mem::size_of::<TriGroup>();
        let first = chunk as usize * self.reader.chunk_groups() as usize;
        let raw_len = (groups - first).min(self.reader.chunk_groups() as usize)
            * std::mem::size_of::<TriGroup>();
        let len = ce.stored_len as usize;
        Ok(ChunkRead {
            block,
            chunk,
            at: e.offset + e.head_stored_len + ce.offset as u64,
            len,
            raw_len,
            checksum: ce.checksum,
            codec: e.codec,
            raw: e.codec == CODEC_RAW || (e.codec == CODEC_ZSTD && len == raw_len),
        })
    }

    /// Reads chunk `chunk` of the block `e` into `w`, checked and decoded; the stored bytes
    /// read, and the bytes decompressed (0 for a raw chunk).
    fn fill<S: BlockSource + ?Sized>(
        &self,
        src: &S,
        e: &BlockEntry,
        head: &[u8],
        chunk: u32,
        w: &mut Slot,
    ) -> Result<(u64, u64), String> {
        let r = self.plan(0, e, head, chunk)?;
        self.room(w)?;
        if !self.read_direct {
            let stored = mapped(src, r.at, r.len)?;
            if r.raw {
                w.buf[..r.len].copy_from_slice(stored);
                return self.settle(&r, w, None, 0);
            }
            return self.settle(&r, w, Some(stored), 0);
        }
        if r.raw {
            let skip = read_aligned(src, r.at, r.len, &mut w.buf)?;
            return self.settle(&r, w, None, skip);
        }
        STORED.with_borrow_mut(|stored_buf| {
            let slot_bytes = Self::slot_bytes_for(self.chunk_bytes);
            if stored_buf.len() < slot_bytes {
                *stored_buf = PageBuf::new(slot_bytes)
                    .ok_or_else(|| format!("cannot allocate {slot_bytes} bytes to read it"))?;
            }
            let skip = read_aligned(src, r.at, r.len, stored_buf)?;
            self.settle(&r, w, Some(&stored_buf[skip..skip + r.len]), 0)
        })
    }

    /// Gives `w` its buffer (a slot's size) if it has none yet.
    fn room(&self, w: &mut Slot) -> Result<(), String> {
        let slot_bytes = Self::slot_bytes_for(self.chunk_bytes);
        if w.buf.len() < slot_bytes {
            w.buf = PageBuf::default();
            w.buf = PageBuf::new(slot_bytes)
                .ok_or_else(|| format!("cannot allocate {slot_bytes} bytes to read it"))?;
        }
        Ok(())
    }

    /// Checks and decodes the chunk `r` just read: a raw chunk's stored bytes are in `w`'s
    /// buffer from `skip`, a compressed chunk's are `stored`. The stored bytes read, and the
    /// bytes decompressed (0 for a raw chunk).
    fn settle(
        &self,
        r: &ChunkRead,
        w: &mut Slot,
        stored: Option<&[u8]>,
        skip: usize,
    ) -> Result<(u64, u64), String> {
        let Some(stored) = stored else {
            // A raw chunk of a compressed block may start anywhere: moved to the buffer's
            // start, where the groups are aligned.
            let start = if skip.is_multiple_of(std::mem::align_of::<TriGroup>()) {
                skip
            } else {
                w.buf.copy_within(skip..skip + r.len, 0);
                0
            };
            check(r.checksum, &w.buf[start..start + r.len])?;
            w.start = start;
            w.len = r.len;
            return Ok((r.len as u64, 0));
        };
        check(r.checksum, stored)?;
        let out = &mut w.buf[..r.raw_len];
        if r.codec == CODEC_LEAN {
            crate::physical::lean::decode_chunk(stored, out)?;
        } else {
            ZSTD.with_borrow_mut(|d| {
                let d = match d {
                    Some(d) => d,
                    none => none.insert(
                        zstd::bulk::Decompressor::new()
                            .map_err(|err| format!("cannot create a zstd decompressor: {err}"))?,
                    ),
                };
                crate::physical::decode_frame(stored, out, d, "its groups take")
            })?;
        }
        w.start = 0;
        w.len = r.raw_len;
        Ok((r.len as u64, r.raw_len as u64))
    }

    /// Reads the chunks `reads` that are not resident, as many at once as slots are free (at
    /// most `depth` in flight: [`BlockSource::read_many`], from this thread), each checked and
    /// decoded into its slot; the others are left (read when next asked for). Counted in `c`
    /// as [`Self::get`] counts its misses. The first chunk that fails is the error (every
    /// failed chunk stays failed, as in [`Self::get`]).
    pub fn read_many<S: BlockSource + ?Sized>(
        &self,
        src: &S,
        reads: &[ChunkRead],
        depth: usize,
        c: &mut PageCounters,
    ) -> Result<(), PageError> {
        // In pieces: a compressed chunk is read into a buffer of the thread's own, beside the
        // cache, so at most a piece's worth of them.
        let mut failed = Ok(());
        for piece in reads.chunks(MANY_PIECE) {
            let r = self.read_piece(src, piece, depth, c);
            if failed.is_ok() {
                failed = r;
            }
        }
        failed
    }

    /// [`Self::read_many`] of at most [`MANY_PIECE`] chunks.
    fn read_piece<S: BlockSource + ?Sized>(
        &self,
        src: &S,
        reads: &[ChunkRead],
        depth: usize,
        c: &mut PageCounters,
    ) -> Result<(), PageError> {
        let mut taken = Vec::with_capacity(reads.len());
        for r in reads {
            let k = key(r.block, r.chunk);
            let mut m = lock(&self.map);
            if m.0.contains_key(&k) || lock(&self.bad).contains_key(&k) {
                continue;
            }
            let Some((s, mut w)) = self.victim(&mut m) else {
                break;
            };
            self.assign(&mut m, s, &mut w, k);
            drop(m);
            taken.push((r, s, w));
        }
        let mut failed = None;
        MANY.with_borrow_mut(|stored| {
            let slot_bytes = Self::slot_bytes_for(self.chunk_bytes);
            let align = src.read_align().max(1) as u64;
            let mut ios = Vec::with_capacity(taken.len());
            let mut skips = Vec::with_capacity(taken.len());
            let mut refused = vec![None; taken.len()];
            if stored.len() < taken.len() {
                stored.resize_with(taken.len(), PageBuf::default);
            }
            for (i, ((r, _, w), st)) in taken.iter_mut().zip(stored.iter_mut()).enumerate() {
                let from = r.at / align * align;
                let skip = (r.at - from) as usize;
                let whole = (skip + r.len).next_multiple_of(align as usize);
                skips.push(skip);
                // (The slot's buffer, where a raw chunk is read and a compressed one decoded.)
                let room = self.room(w);
                let buf = match room {
                    Err(what) => Err(what),
                    Ok(()) if r.raw => Ok(&mut w.buf[..]),
                    Ok(()) => {
                        if st.len() < slot_bytes {
                            *st = PageBuf::new(slot_bytes).unwrap_or_default();
                        }
                        Ok(&mut st[..])
                    }
                };
                match buf.and_then(|b| {
                    let have = b.len();
                    b.get_mut(..whole)
                        .ok_or_else(|| format!("{whole} bytes to read do not fit a slot of {have}"))
                }) {
                    Ok(b) => ios.push((from, b)),
                    Err(what) => refused[i] = Some(what),
                }
            }
            let mut done = src.read_many(&mut ios, depth).into_iter();
            drop(ios);
            for (i, (r, s, w)) in taken.iter_mut().enumerate() {
                let settled = match refused[i].take() {
                    Some(what) => Err(what),
                    None => match done.next() {
                        Some(Ok(())) if r.raw => self.settle(r, w, None, skips[i]),
                        Some(Ok(())) => {
                            let st = &stored[i][skips[i]..skips[i] + r.len];
                            self.settle(r, w, Some(st), 0)
                        }
                        Some(Err(err)) => Err(format!("cannot read it: {err}")),
                        None => Err("not read".to_string()),
                    },
                };
                match settled {
                    Ok(read) => self.count(read, c),
                    Err(what) => {
                        let e = self.fail(r.block, r.chunk, *s, w, what);
                        failed.get_or_insert(e);
                    }
                }
            }
        });
        drop(taken);
        failed.map_or(Ok(()), Err)
    }
}

/// Chunks read at once by [`ChunkCache::read_many`]: its buffers for compressed chunks take
/// this many slots' room beside the cache, per thread that reads.
const MANY_PIECE: usize = 128;

/// Where a chunk is stored and what it decodes to ([`ChunkCache::plan`]).
#[derive(Clone, Copy, Debug)]
pub struct ChunkRead {
    block: u32,
    chunk: u32,
    /// Its stored bytes' offset in the file, and length.
    at: u64,
    len: usize,
    /// Its decoded length.
    raw_len: usize,
    checksum: u64,
    codec: u32,
    /// Stored as it decodes (a raw block's, or a zstd block's chunk that did not compress).
    raw: bool,
}

thread_local! {
    /// Each thread's zstd context for chunks.
    static ZSTD: std::cell::RefCell<Option<zstd::bulk::Decompressor<'static>>> =
        const { std::cell::RefCell::new(None) };
    /// Each thread's buffer for a compressed chunk's stored bytes, read directly (a slot's
    /// size: a chunk's stored bytes are never more than its decoded ones).
    static STORED: std::cell::RefCell<PageBuf> = std::cell::RefCell::new(PageBuf::default());
    /// Each thread's buffers for the compressed chunks of a [`ChunkCache::read_many`].
    static MANY: std::cell::RefCell<Vec<PageBuf>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Reads the stored bytes `at .. at + len` into `buf` with one read rounded out to the source's
/// direct alignment (the device's block, [`BlockSource::read_align`]), so that it goes past the
/// page cache and reads at most one block more at each end; where they start in `buf`. `buf`
/// holds `len` and two alignments more (a slot: a chunk's pages and one more page).
fn read_aligned<S: BlockSource + ?Sized>(
    src: &S,
    at: u64,
    len: usize,
    buf: &mut [u8],
) -> Result<usize, String> {
    let align = src.read_align().max(1) as u64;
    let from = at / align * align;
    let skip = (at - from) as usize;
    let whole = (skip + len).next_multiple_of(align as usize);
    let have = buf.len();
    let into = buf
        .get_mut(..whole)
        .ok_or_else(|| format!("{whole} bytes to read do not fit a slot of {have}"))?;
    src.read_at(from, into)
        .map_err(|err| format!("cannot read it: {err}"))?;
    Ok(skip)
}

/// The stored bytes `at .. at + len` in the source's map.
fn mapped<S: BlockSource + ?Sized>(src: &S, at: u64, len: usize) -> Result<&[u8], String> {
    usize::try_from(at)
        .ok()
        .and_then(|a| src.bytes().get(a..a.checked_add(len)?))
        .ok_or_else(|| "stored bytes outside the file".to_string())
}

/// Checks a chunk's stored bytes against its checksum.
fn check(expected: u64, stored: &[u8]) -> Result<(), String> {
    let computed = checksum(stored);
    if computed != expected {
        return Err(format!(
            "checksum mismatch (stored {expected:#018x}, computed {computed:#018x}): the file \
             is corrupt"
        ));
    }
    Ok(())
}
