//! An opened file, ready to trace: the memory budget and the threads it allows, the pager, and
//! the batch calls (closest hit, any hit, in an order).

use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use rayon::prelude::*;
use serde::Serialize;

use super::batch::{CHUNK, in_order};
use super::held::ReadyMap;
use super::order::{Order, RayKeys};
use super::pager::chunks::ChunkCache;
use super::pager::{BlockBytes, BlockSource, PageCounters, PageError, Pager, PagerOptions};
use super::stream::{Job, Stream, StreamOptions, Streamed, every_hit};
use super::top_bounds::{LatticeBox, top_bounds};
use super::trace::{BlockFetch, ChunkCtx, Counters, Direct, HitInfo, TraceError, Tree, Walk};
use super::verify::VerifyReport;
use crate::error::{Error, FormatError};
use crate::geom::{Hit, HitAttributes, Ray};
use crate::mapping::{Corruption, LevelInfos, TreeMap};
use crate::os::MappedFile;
use crate::physical::format::{
    BlockEntry, CODEC_LEAN, CODEC_RAW, FLAG_CLUSTERS, FLAG_COMPRESSED, FLAG_ROPES, SectionKind,
    TriGroup,
};
use crate::physical::{BlockReader, OavmFile};
use crate::progress::Progress;
use crate::rays::Bounds;

/// How an opened file is traced.
#[derive(Clone, Copy, Debug)]
pub struct SceneOptions {
    /// Bytes of decoded blocks the pager may keep resident (the top tree and block directory
    /// are not counted: they are small and always resident). `None`: [`default_mem_budget`].
    /// Never raised: a budget that cannot hold two of the file's largest blocks per tracing
    /// thread and one more lowers the threads ([`Scene::threads`]), and one that cannot hold
    /// three blocks is an error ([`Error::Budget`]).
    pub mem_budget: Option<u64>,
    /// Threads that will trace at once; 0: rayon's current pool size.
    pub threads: usize,
    /// Check each raw block's checksum when it is paged in (reading it whole); off, only the
    /// pages a walk touches are read (see [`PagerOptions::check_raw`]).
    pub check_blocks: bool,
    /// How blocks are read under a budget smaller than the file (see [`BlockReads`]).
    pub block_reads: BlockReads,
    /// Which walk traces the rays (see [`Walk`]).
    pub walk: Walk,
    /// Under a budget smaller than the file's blocks, and where the file stores its groups in
    /// chunks (format-spec §8.3), let the pager hold blocks' heads and the walks read only the
    /// chunks of groups they reach ([`Scene::chunked`]): in [`Order::Stream`] the chunks rays
    /// wait for are read together (`logical::chunked`), in another order each when a ray
    /// reaches it. Off by default: it reads a half to a quarter of the bytes of whole blocks
    /// but, on the disks measured, takes as long (docs/out-of-core.md).
    pub chunks: bool,
}

/// How the pager reads blocks when the budget is smaller than the file's blocks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BlockReads {
    /// [`BlockReads::Read`] when the file is larger than the memory available (the page
    /// cache cannot keep it for the next run anyway), else [`BlockReads::Map`].
    #[default]
    Auto,
    /// Through the file's memory map: pages faulted in, and dropped on eviction; the page
    /// cache keeps what it can for the next run.
    Map,
    /// Into the pager's own memory, one direct read a block past the page cache
    /// ([`PagerOptions::read_blocks`]): far less time in the kernel (on the 130M-triangle
    /// file in a 1.5 GiB cgroup, about 3 s of system time against 7.6 s in a 6-8 s run), but
    /// nothing left in the page cache.
    Read,
}

impl Default for SceneOptions {
    fn default() -> Self {
        SceneOptions {
            mem_budget: None,
            threads: 0,
            check_blocks: true,
            block_reads: BlockReads::Auto,
            walk: Walk::Auto,
            chunks: false,
        }
    }
}

/// The memory budget when none is given: half of the memory available when it is asked
/// ([`crate::os::available_memory`]: the kernel's `MemAvailable`, lowered to what the memory
/// cgroup has left), or [`FALLBACK_MEM_BUDGET`] where that cannot be read.
pub fn default_mem_budget() -> u64 {
    crate::os::available_memory().map_or(FALLBACK_MEM_BUDGET, |a| a / 2)
}

/// [`Scene::decoded_bytes`] of an opened file.
fn decoded_bytes_of<D: AsRef<[u8]>>(file: &OavmFile<D>) -> u64 {
    let h = file.header();
    if h.flags & FLAG_COMPRESSED == 0 {
        return file.section(SectionKind::Blocks).length;
    }
    file.directory()
        .iter()
        .map(|e| e.raw_len.min(h.max_block_raw_len))
        .fold(0u64, u64::saturating_add)
}

/// The memory a block of `raw_len` bytes takes when held: whole pages (at least one).
fn held_bytes(raw_len: u64) -> u64 {
    raw_len
        .max(1)
        .next_multiple_of(crate::os::page_size() as u64)
}

/// The budget where the available memory cannot be read: 1 GiB.
pub const FALLBACK_MEM_BUDGET: u64 = 1 << 30;

/// Threads per core when a budget makes the tracer read blocks again: on the 130M-triangle
/// file in a 1.5 GiB cgroup, 16 threads on 2 cores traced 1.7 to 2.2 times as fast as 2
/// (README, out of core), and no slower without a limit.
pub const IO_THREADS_PER_CORE: usize = 8;

/// Memory a batch call needs per ray, beyond the rays themselves: the answer, the sort key and
/// index of an ordered batch, and the answers in sorted order (with room to spare).
pub const BYTES_PER_RAY: u64 = 64;

/// The most rays a batch can hold in `budget` bytes (at most `2^32 - 1`, the ordered batches'
/// index): callers refuse larger batches with a clear error rather than fail to allocate.
pub fn max_rays(budget: u64) -> u64 {
    (budget / BYTES_PER_RAY).min(u32::MAX as u64)
}

/// The most rays a run may hold: [`max_rays`] of half of the memory available
/// ([`crate::os::available_memory`], or [`FALLBACK_MEM_BUDGET`] where that cannot be read), the
/// other half left to the pager's default budget ([`default_mem_budget`]).
pub fn max_rays_in_memory() -> u64 {
    max_rays(crate::os::available_memory().unwrap_or(FALLBACK_MEM_BUDGET) / 2)
}

/// An opened `.oavm` file, ready to trace. Opening reads the header, section table and top
/// tree's level table only, and sets up the pager: its cost does not grow with the file.
pub struct Scene<D = MappedFile> {
    file: OavmFile<D>,
    path: PathBuf,
    pager: Pager,
    /// The top tree's per-level constants (made at open).
    top_infos: LevelInfos,
    /// The memory budget (the user's, or the default).
    budget: u64,
    /// Threads that may trace at once (what the budget holds).
    threads: usize,
    /// The boxes of the top tree's nodes, made on first use (`top_bounds`).
    top_boxes: OnceLock<Vec<LatticeBox>>,
    /// Where streamed batches report the rays done and the blocks read.
    progress: Option<Arc<dyn Progress + Send + Sync>>,
    /// The walk asked for ([`SceneOptions::walk`]), checked against the file at open.
    walk: Walk,
    /// Chunked reading ([`Self::chunked`]): the heads' directory the pager is given, and the
    /// cache of chunks of groups.
    chunked: Option<(Vec<BlockEntry>, ChunkCache)>,
    /// The geometry table (format-spec §8.8), read and checked at open; empty: one mesh.
    geometries: Vec<crate::mesh::Geometry>,
}

/// What an opened scene is and holds, for reports.
#[derive(Clone, Debug, Serialize)]
pub struct SceneInfo {
    pub file_bytes: u64,
    pub blocks: u64,
    pub max_block_raw_len: u64,
    /// The budget the pager keeps to (the one asked for, or the default).
    pub pager_budget: u64,
    pub pager_peak_resident_bytes: u64,
    pub pager_slots: usize,
    /// Blocks are read into the pager's memory with direct reads ([`BlockReads::Read`]), not
    /// through the map.
    pub reads_blocks: bool,
}

impl Scene<MappedFile> {
    /// Maps and opens the file at `path`, with the default options. Opening checks the header,
    /// the section table and the top tree (O(1) in the file's size) and reads no block: blocks
    /// are paged in when a ray first needs them.
    ///
    /// ```
    /// # fn main() -> Result<(), Box<dyn std::error::Error>> {
    /// # let dir = tempfile::tempdir()?;
    /// # let path = dir.path().join("bunny.oavm");
    /// # let opts = oavm::pack::PackOptions::default();
    /// # oavm::pack::pack("data/bunny.ply".as_ref(), &path, &opts, &oavm::pack::Quiet)?;
    /// let scene = oavm::Scene::open(&path)?; // packed from data/bunny.ply
    /// assert_eq!(scene.file().header().input_triangles, 69_451);
    /// // A file that is not one is an error naming it, never a panic.
    /// let err = oavm::Scene::open("data/bunny.ply").err().unwrap();
    /// assert!(err.to_string().contains("data/bunny.ply"), "{err}");
    /// # Ok(()) }
    /// ```
    pub fn open(path: impl AsRef<Path>) -> Result<Scene<MappedFile>, Error> {
        Self::open_with(path, &SceneOptions::default())
    }

    /// Maps and opens the file at `path`.
    pub fn open_with(
        path: impl AsRef<Path>,
        opts: &SceneOptions,
    ) -> Result<Scene<MappedFile>, Error> {
        let path = path.as_ref();
        let map = MappedFile::open(path).map_err(|e| Error::io(path, e))?;
        map.advise(memmap2::Advice::Random);
        Scene::from_bytes_with(map, path, opts)
    }
}

impl<D: AsRef<[u8]> + BlockSource> Scene<D> {
    /// Opens `data` as an `.oavm` file; `path` names it in errors.
    pub fn from_bytes(data: D, path: impl Into<PathBuf>) -> Result<Scene<D>, Error> {
        Self::from_bytes_with(data, path, &SceneOptions::default())
    }

    /// Opens `data` as an `.oavm` file with `opts`; `path` names it in errors.
    pub fn from_bytes_with(
        data: D,
        path: impl Into<PathBuf>,
        opts: &SceneOptions,
    ) -> Result<Scene<D>, Error> {
        let path = path.into();
        let file = OavmFile::open(data).map_err(|e| Error::format(&path, e))?;
        let geometries =
            crate::physical::read_geometries(&file).map_err(|e| Error::format(&path, e))?;
        let flags = file.header().flags;
        match opts.walk {
            Walk::Ropes if flags & FLAG_ROPES == 0 => {
                return Err(Error::Invalid(format!(
                    "{} has no ropes to walk by: add them with `oavm-pack {} OUT.oavm --ropes`",
                    path.display(),
                    path.display()
                )));
            }
            Walk::TopDown | Walk::Wide if flags & FLAG_CLUSTERS == 0 => {
                return Err(Error::Invalid(format!(
                    "{}: the wide and top-down walks need a file of clusters (`oavm-pack --leaf cluster`); \
                     this one holds leaf lists",
                    path.display()
                )));
            }
            _ => {}
        }
        let budget = opts.mem_budget.unwrap_or_else(default_mem_budget);
        let wanted = match opts.threads {
            0 => rayon::current_num_threads(),
            n => n,
        };
        // Each thread holds at most one block at a time, and a block is admitted before
        // another is evicted: the pager keeps its resident bytes within its own budget plus one
        // block per thread inside a get, once its budget holds a block per thread and one more
        // (pager module docs). So it gets the user's budget less one block per thread, and the
        // threads are lowered until that holds `threads + 1` blocks: the resident bytes then
        // never exceed the user's budget. A block takes whole pages of memory (in the page
        // cache, or in a slot the pager reads it into).
        // Chunked (format-spec §8.3): the pager holds blocks' heads, a cache the chunks of
        // groups, where the budget is smaller than the blocks and the walk reads clusters.
        let chunked = file.header().chunk_groups > 0
            && opts.chunks
            && budget < decoded_bytes_of(&file)
            && matches!(opts.walk, Walk::Auto | Walk::Wide | Walk::TopDown);
        let heads: Option<Vec<BlockEntry>> = chunked.then(|| {
            file.directory()
                .iter()
                .map(|e| match e.is_free() {
                    true => *e,
                    // A lean block's head is stored raw, on a page: a raw block of its own.
                    false => BlockEntry {
                        stored_len: e.head_stored_len,
                        raw_len: e.head_raw_len,
                        codec: match e.codec {
                            CODEC_LEAN => CODEC_RAW,
                            codec => codec,
                        },
                        ..*e
                    },
                })
                .collect()
        });
        let largest = match &heads {
            Some(h) => h.iter().map(|e| e.raw_len).max().unwrap_or(0),
            None => file.header().max_block_raw_len,
        };
        let held = held_bytes(largest);
        // Chunked, a thread holds a chunk's slot beside a head, and the cache keeps a slot a
        // thread and one more ([`ChunkCache::new`]).
        let slot = match &heads {
            Some(_) => {
                let chunk = file.header().chunk_groups as usize * std::mem::size_of::<TriGroup>();
                ChunkCache::slot_bytes_for(chunk) as u64
            }
            None => 0,
        };
        let fits = budget.checked_div(held + slot).unwrap_or(u64::MAX);
        if fits < 3 {
            return Err(Error::Budget {
                path,
                budget,
                needed: (held + slot).saturating_mul(3),
                largest,
            });
        }
        let threads = wanted
            .min(usize::try_from((fits - 1) / 2).unwrap_or(usize::MAX))
            .max(1);
        let mut pager_budget = match budget {
            u64::MAX => u64::MAX,
            b => b - threads as u64 * held,
        };
        // The chunks get what the heads do not need, and at least a quarter of the pager's
        // budget and a slot a thread and one more; the heads keep room for `threads + 1` of
        // the largest (the budget holds both: `fits` above).
        let chunk_budget = match &heads {
            Some(h) => {
                let need: u64 = h.iter().map(|e| held_bytes(e.raw_len)).sum();
                let floor = (threads as u64 + 1) * held;
                let chunks = pager_budget
                    .saturating_sub(need)
                    .max(pager_budget / 4)
                    .max((threads as u64 + 1) * slot)
                    .min(pager_budget.saturating_sub(floor));
                pager_budget -= chunks;
                chunks
            }
            None => 0,
        };
        let read_blocks = match opts.block_reads {
            BlockReads::Map => false,
            BlockReads::Read => true,
            BlockReads::Auto => {
                budget < decoded_bytes_of(&file)
                    && crate::os::available_memory().is_some_and(|a| file.header().file_size > a)
            }
        };
        let mut pager = Pager::new(
            heads.as_deref().unwrap_or(file.directory()),
            BlockReader::new(&file),
            PagerOptions {
                budget: pager_budget,
                threads,
                check_raw: opts.check_blocks,
                read_blocks,
            },
        );
        pager.set_heads(heads.is_some());
        let chunked = heads.map(|h| {
            let cache =
                ChunkCache::new(BlockReader::new(&file), chunk_budget, threads, read_blocks);
            (h, cache)
        });
        Ok(Scene {
            chunked,
            top_infos: LevelInfos::new(file.levels(), 0),
            file,
            path,
            pager,
            budget,
            threads,
            top_boxes: OnceLock::new(),
            progress: None,
            walk: opts.walk,
            geometries,
        })
    }

    /// The meshes the file was made of (format-spec §8.8), each a run of primitive ids; empty
    /// for a file of one mesh.
    pub fn geometries(&self) -> &[crate::mesh::Geometry] {
        &self.geometries
    }

    /// Which geometry holds primitive `prim`, and its index within that geometry: `(0, prim)`
    /// in a file of one mesh; `None` for a primitive id past the file's.
    pub fn locate(&self, prim: u32) -> Option<(u32, u64)> {
        match self.geometries.is_empty() {
            true => (u64::from(prim) < self.file.header().input_triangles)
                .then_some((0, u64::from(prim))),
            false => crate::mesh::locate_primitive(&self.geometries, u64::from(prim)),
        }
    }

    /// Reports streamed batches' progress (rays answered, blocks read) to `progress`
    /// (`None`: to nobody, the default).
    pub fn set_progress(&mut self, progress: Option<Arc<dyn Progress + Send + Sync>>) {
        self.progress = progress;
    }

    pub fn file(&self) -> &OavmFile<D> {
        &self.file
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The memory one of the file's largest blocks takes when held, in whole pages (a raw
    /// block's pages in the page cache, or the pager's buffer it is read or decoded into):
    /// budgets are counted in these (a budget holds three at least, two a thread and one
    /// more).
    pub fn held_block_bytes(&self) -> u64 {
        held_bytes(self.file.header().max_block_raw_len)
    }

    /// Threads that may trace at once: the threads asked for, lowered to what the budget
    /// holds. Every batch call traces on at most this many threads of the current rayon pool.
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// The memory budget: the decoded blocks resident never exceed it.
    pub fn budget(&self) -> u64 {
        self.budget
    }

    /// The most bytes of decoded blocks resident at any time so far.
    pub fn peak_resident_bytes(&self) -> u64 {
        self.pager.peak_resident_bytes()
    }

    /// The sum of the blocks' decoded sizes: the blocks section's length for a file of raw
    /// blocks; for a compressed file, read from the block directory (`O(blocks)`).
    pub fn decoded_bytes(&self) -> u64 {
        decoded_bytes_of(&self.file)
    }

    /// Whether the budget holds every decoded block: then nothing is ever evicted, and the
    /// file is traced as if in memory.
    pub fn fits_in_budget(&self) -> bool {
        self.decoded_bytes() <= self.budget()
    }

    /// The order to trace in when none is asked for: [`Order::Stream`] when the budget is
    /// smaller than the file's decoded blocks (walks parked at the blocks they need, each
    /// block read about once for all of them: on the 130M-triangle file in a 1.5 GiB cgroup
    /// with a 1 GiB budget, raw, warm, 1.17x the speed of [`Order::Blocks`] on a 1024x768
    /// frame with its shadow rays and 1.08x on 10^6 random rays; zstd, 1.04x and 0.97x: README
    /// "Out of core"), else
    /// [`Order::None`]: in memory, a stream costs more than the coherence it buys (the dragon,
    /// 0.46x to 0.72x of the direct walk), and so does sorting (format 4, 2 threads,
    /// `tools/ab_speed.sh`: the dragon's primary / random / shadow rays ran 1.17x / 1.23x /
    /// 1.07x faster as given than sorted by Morton key, Sibenik's 1.08x / 1.33x / 1.28x).
    pub fn default_order(&self) -> Order {
        if self.fits_in_budget() {
            Order::None
        } else {
            Order::Stream
        }
    }

    /// The order `order` traces in here: [`Order::Stream`] is [`Order::None`] when the budget
    /// holds every decoded block. A stream is for reading each block once for all the walks
    /// that need it; a pager that never evicts reads each block once anyway, and the stream's
    /// sort and scheduling would only cost (format 7, the dragon in memory: streamed at
    /// 0.24-0.41x of the direct walk before, 1.0x now; docs/out-of-core.md "A cheaper
    /// stream").
    pub fn streamed(&self, order: Order) -> Order {
        match order {
            Order::Stream if self.fits_in_budget() => Order::None,
            o => o,
        }
    }

    /// The threads to trace on when none are asked for, out of `cores`: one per core, or
    /// [`IO_THREADS_PER_CORE`] per core when the budget is smaller than the file's decoded
    /// blocks (some trace while others wait for the disk), but then no more than leave three
    /// quarters of the budget to the cache (each thread keeps one block's room of the budget
    /// for the block it reads; with large blocks, eight threads per core would leave the
    /// cache too little and every block would be read again and again); at most
    /// [`Self::threads`].
    pub fn default_threads(&self, cores: usize) -> usize {
        let cores = cores.max(1);
        if self.fits_in_budget() {
            return cores.min(self.threads);
        }
        let largest = held_bytes(self.file.header().max_block_raw_len);
        let quarter = usize::try_from(self.budget / largest / 4).unwrap_or(usize::MAX);
        cores
            .saturating_mul(IO_THREADS_PER_CORE)
            .min(quarter.max(cores))
            .min(self.threads)
    }

    /// The model's bounds: the box of its triangles, as the header records it.
    pub fn bounds(&self) -> Bounds {
        let h = self.file.header();
        Bounds {
            min: h.mesh_min,
            max: h.mesh_max,
        }
    }

    /// What the scene is and holds.
    pub fn info(&self) -> SceneInfo {
        SceneInfo {
            file_bytes: self.file.bytes().len() as u64,
            blocks: self.file.header().block_count,
            max_block_raw_len: self.file.header().max_block_raw_len,
            pager_budget: self.budget,
            pager_peak_resident_bytes: self.pager.peak_resident_bytes(),
            pager_slots: self.pager.slot_count(),
            reads_blocks: self.pager.reads_blocks(),
        }
    }

    /// The tree, for walks one ray at a time ([`Tree::intersect`], [`Tree::occluded`]). A
    /// caller that walks on several threads must use at most [`Self::threads`] of them, and
    /// call [`Self::check_unchanged`] before trusting the answers.
    pub fn tree(&self) -> Tree<'_> {
        let h = self.file.header();
        let top = TreeMap::new(
            &self.top_infos,
            self.file.levels(),
            self.file.records(SectionKind::Nodes),
            self.file.records(SectionKind::Ranks),
        );
        let link_bounds = self.file.records(SectionKind::LinkBounds);
        let top_boxes = self.top_boxes.get_or_init(|| top_bounds(&top, link_bounds));
        Tree::new(
            top,
            top_boxes,
            self.directory(),
            self,
            self.pager.resident_forever().map(|ready| Direct {
                file: self.file.data().as_ref(),
                ready,
            }),
            h,
        )
        .with_wide(
            self.file.records(SectionKind::WideNodes),
            self.file.records(SectionKind::WideLinks),
        )
        .walking(self.walk, self.file.records(SectionKind::Ropes))
        .with_chunks(self.chunked.as_ref().map(|(_, cache)| ChunkCtx {
            cache,
            src: self.file.data() as &dyn BlockSource,
            directory: self.file.directory(),
        }))
    }

    /// The directory the pager is given: the file's, or its blocks' heads' when chunked.
    fn directory(&self) -> &[BlockEntry] {
        match &self.chunked {
            Some((heads, _)) => heads,
            None => self.file.directory(),
        }
    }

    /// Whether the pager holds blocks' heads and the walks read groups chunk by chunk
    /// (format-spec §8.3): a file that stores its groups in chunks, a budget smaller than its
    /// blocks, a walk of clusters, and [`SceneOptions::chunks`] asked for. Such a scene traces
    /// a batch in [`Order::Stream`] chunk by chunk (`logical::chunked`), in Morton order, and
    /// in any other order ray by ray.
    pub fn chunked(&self) -> bool {
        self.chunked.is_some()
    }

    /// Chunks of groups read so far (0 unless [`Self::chunked`]).
    pub fn chunks_read(&self) -> u64 {
        self.chunked.as_ref().map_or(0, |(_, c)| c.chunks_read())
    }

    /// Checks every byte, checksum and invariant ([`super::verify`]).
    pub fn verify(&self) -> Result<VerifyReport, Error> {
        let report = super::verify::verify(&self.file);
        self.check_unchanged()?;
        Ok(report)
    }

    /// `Err(Error::Changed)` if the file changed since it was opened (truncated or written in
    /// place by another program): what was read from it since cannot be trusted.
    pub fn check_unchanged(&self) -> Result<(), Error> {
        self.file
            .data()
            .check_unchanged_at(self.file.slot(), self.file.header())
            .map_err(|source| Error::Changed {
                path: self.path.clone(),
                source,
            })
    }

    /// The error for bytes that break the format (or a change of the file, which explains
    /// them better).
    pub fn corrupt(&self, e: impl Into<FormatError>) -> Error {
        match self.check_unchanged() {
            Err(changed) => changed,
            Ok(()) => Error::format(&self.path, e.into()),
        }
    }

    /// Closest hits of `rays` into `out` (same length), in parallel, traced in
    /// [`Self::default_order`]: as given when the budget holds the file, streamed when it does
    /// not (see [`Self::intersect_batch_ordered`]; the answers are the same).
    ///
    /// ```
    /// # fn main() -> Result<(), Box<dyn std::error::Error>> {
    /// # let dir = tempfile::tempdir()?;
    /// # let path = dir.path().join("bunny.oavm");
    /// # let opts = oavm::pack::PackOptions::default();
    /// # oavm::pack::pack("data/bunny.ply".as_ref(), &path, &opts, &oavm::pack::Quiet)?;
    /// use oavm::{Hit, Ray, Scene};
    /// let scene = Scene::open(&path)?; // the bunny
    /// let h = scene.file().header();
    /// let centre: [f32; 3] = std::array::from_fn(|k| (h.mesh_min[k] + h.mesh_max[k]) / 2.0);
    /// // Two rays from outside the bunny's box toward its centre, and one away from it.
    /// let rays = [
    ///     Ray::new([centre[0], centre[1], 10.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY),
    ///     Ray::new([centre[0], 10.0, centre[2]], [0.0, -1.0, 0.0], 0.0, f32::INFINITY),
    ///     Ray::new([centre[0], centre[1], 10.0], [0.0, 0.0, 1.0], 0.0, f32::INFINITY),
    /// ];
    /// let mut hits = [Hit::MISS; 3];
    /// let counters = scene.intersect_batch(&rays, &mut hits)?;
    /// assert!(hits[0].is_hit() && hits[1].is_hit() && !hits[2].is_hit());
    /// // The same answers as an f64 brute force over the mesh's triangles.
    /// let mesh = oavm::mesh::load("data/bunny.ply".as_ref())?;
    /// let diagonal = 0.3; // about the bunny's
    /// for (ray, hit) in rays.iter().zip(&hits) {
    ///     let want = oavm::geom::reference::closest(&mesh.corners(), ray);
    ///     assert!(want.agrees(hit, diagonal), "{want:?} against {hit:?}");
    /// }
    /// assert_eq!(counters.rays, 3);
    /// # Ok(()) }
    /// ```
    pub fn intersect_batch(&self, rays: &[Ray], out: &mut [Hit]) -> Result<Counters, Error> {
        self.intersect_batch_ordered(rays, out, self.default_order())
    }

    /// Any-hit answers of `rays` into `out` (1: occluded, 0: not), in parallel, traced in
    /// [`Self::default_order`].
    pub fn occluded_batch(&self, rays: &[Ray], out: &mut [u8]) -> Result<Counters, Error> {
        self.occluded_batch_ordered(rays, out, self.default_order())
    }

    /// Closest hits of `rays` into `out`, traced in `order`. The answers do not depend on the
    /// order (each ray's walk is independent of the others'); only the pager's work does: see
    /// [`Order`].
    pub fn intersect_batch_ordered(
        &self,
        rays: &[Ray],
        out: &mut [Hit],
        order: Order,
    ) -> Result<Counters, Error> {
        self.answers::<false, _>(rays, out, order, |_, h| {
            h.map_or(Hit::MISS, |h| Hit {
                t: h.t,
                prim: h.prim,
            })
        })
    }

    /// Closest hits of `rays` with their barycentric coordinates and geometric normals into
    /// `out`, traced in `order`: the same `t` and primitive ids as
    /// [`Self::intersect_batch_ordered`].
    pub fn intersect_attributes_ordered(
        &self,
        rays: &[Ray],
        out: &mut [HitAttributes],
        order: Order,
    ) -> Result<Counters, Error> {
        self.answers::<false, _>(rays, out, order, |ray, h| {
            h.map_or(HitAttributes::MISS, |h| {
                HitAttributes::new(ray, h.t, h.prim, &h.v)
            })
        })
    }

    /// Any-hit answers of `rays` into `out` (1: occluded, 0: not), traced in `order`.
    pub fn occluded_batch_ordered(
        &self,
        rays: &[Ray],
        out: &mut [u8],
        order: Order,
    ) -> Result<Counters, Error> {
        self.answers::<true, _>(rays, out, order, |_, h| h.is_some() as u8)
    }

    /// The closest (`ANY`: any) hit of each of `rays`, as `map` makes it an answer, into `out`,
    /// traced in `order`: streamed ([`Order::Stream`], for a file of clusters), or ray by ray.
    fn answers<const ANY: bool, T: Send + Sync + Copy>(
        &self,
        rays: &[Ray],
        out: &mut [T],
        order: Order,
        map: impl Fn(&Ray, Option<HitInfo>) -> T + Sync,
    ) -> Result<Counters, Error> {
        let tree = self.tree();
        let order = self.streamed(order);
        if order == Order::Stream
            && let Some((_, cache)) = &self.chunked
        {
            return self.by_chunks::<ANY, T>(&tree, cache, rays, out, map);
        }
        if order == Order::Stream && tree.walks_top_down() {
            return self.stream::<ANY, T>(&tree, rays, out, map);
        }
        let order = match order {
            Order::Stream => Order::Blocks,
            o => o,
        };
        self.batch(rays, out, order, |chunk, out, c| {
            tree.answer_each::<ANY>(chunk, c, |i, ray, h| out[i] = map(ray, h))
        })
    }

    /// [`Self::answers`] chunk by chunk ([`super::chunked`]), in Morton order.
    fn by_chunks<const ANY: bool, T: Send + Sync + Copy>(
        &self,
        tree: &Tree<'_>,
        cache: &ChunkCache,
        rays: &[Ray],
        out: &mut [T],
        map: impl Fn(&Ray, Option<HitInfo>) -> T + Sync,
    ) -> Result<Counters, Error> {
        check_room(rays.len(), out.len())?;
        let order = self
            .permutation(rays, Order::Morton)?
            .unwrap_or_else(|| (0..rays.len() as u32).collect());
        let c = super::chunked::answer::<ANY>(tree, cache, rays, &order, self.threads, |i, h| {
            out[i as usize] = map(&rays[i as usize], h)
        })
        .map_err(|e| self.corrupt(e))?;
        self.check_unchanged()?;
        Ok(c)
    }

    /// [`Self::answers`] streamed ([`super::stream`]).
    fn stream<const ANY: bool, T: Send + Sync + Copy>(
        &self,
        tree: &Tree<'_>,
        rays: &[Ray],
        out: &mut [T],
        map: impl Fn(&Ray, Option<HitInfo>) -> T + Sync,
    ) -> Result<Counters, Error> {
        let job = Job {
            rays,
            any: ANY,
            light: None,
            casts: every_hit,
            map,
        };
        let s = self.stream_job(tree, &job, out, &mut [])?;
        Ok(s.counters[0])
    }

    /// Closest hits of `rays` into `hits` and, for each hit, whether its shadow ray toward
    /// `light` ([`crate::rays::shadow_ray`]) is occluded into `occluded` (at the primary ray's
    /// index; 0 for rays without a hit), in one stream ([`super::stream`]): a shadow walk
    /// begins where its primary walk ends, in the block held. The counters of the primary and
    /// of the shadow rays, and the share of the time spent on shadow rays. `None` for a file
    /// of leaf lists (which is not streamed).
    pub(crate) fn stream_frame(
        &self,
        rays: &[Ray],
        light: [f32; 3],
        hits: &mut [Hit],
        occluded: &mut [u8],
    ) -> Result<Option<([Counters; 2], f64)>, Error> {
        let map = |_: &Ray, h: Option<HitInfo>| {
            h.map_or(Hit::MISS, |h| Hit {
                t: h.t,
                prim: h.prim,
            })
        };
        self.stream_shaded(rays, light, every_hit, map, hits, occluded)
    }

    /// [`Self::stream_frame`] with the hits made answers by `map`, and only the hits `casts`
    /// picks casting their shadow rays (the others' `occluded` is 0): a renderer's.
    pub(crate) fn stream_shaded<T: Send + Sync + Copy>(
        &self,
        rays: &[Ray],
        light: [f32; 3],
        casts: fn(&Ray, &HitInfo, [f32; 3]) -> bool,
        map: impl Fn(&Ray, Option<HitInfo>) -> T + Sync,
        out: &mut [T],
        occluded: &mut [u8],
    ) -> Result<Option<([Counters; 2], f64)>, Error> {
        let tree = self.tree();
        // (Under a budget that holds the file, a stream is the direct walk: `Self::streamed`.)
        if !tree.walks_top_down() || self.fits_in_budget() {
            return Ok(None);
        }
        if occluded.len() != rays.len() {
            return Err(Error::Invalid(format!(
                "{} rays but room for {} shadow answers",
                rays.len(),
                occluded.len()
            )));
        }
        let job = Job {
            rays,
            any: false,
            light: Some(light),
            casts,
            map,
        };
        occluded.fill(0);
        let s = self.stream_job(&tree, &job, out, occluded)?;
        Ok(Some((s.counters, s.shadow_share)))
    }

    /// Runs a stream: one worker per core (at most [`Self::threads`]), the other threads
    /// read ahead; the parked walks get an eighth of the budget (taken from the pager's for
    /// the stream's duration, so that the blocks and the walks together stay within it). Rays
    /// start in [`Order::Morton`]'s order.
    fn stream_job<T: Send + Sync + Copy, M: Fn(&Ray, Option<HitInfo>) -> T + Sync>(
        &self,
        tree: &Tree<'_>,
        job: &Job<'_, M>,
        out: &mut [T],
        shadows: &mut [u8],
    ) -> Result<Streamed, Error> {
        let rays = job.rays;
        check_room(rays.len(), out.len())?;
        // (Also refuses a batch too long for 32-bit indices.)
        let start_order = self.permutation(rays, Order::Stream)?.unwrap_or_default();
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let workers = cores.min(self.threads).max(1);
        let readers = self.threads - workers;
        let largest = held_bytes(self.file.header().max_block_raw_len);
        let pager_budget = self.pager.budget();
        // The pager keeps `threads + 1` blocks at least; the walks get an eighth of the budget
        // or what is left above that.
        let floor = (self.threads as u64 + 1).saturating_mul(largest);
        let parked = match pager_budget {
            u64::MAX => u64::MAX,
            b => (self.budget / 8).min(b.saturating_sub(floor)),
        };
        let cache = pager_budget.saturating_sub(parked);
        // Blocks read ahead and not yet served must not be evicted before they are: a quarter
        // of the cache at most.
        let read_ahead = (2 * readers)
            .min(usize::try_from(cache / largest / 4).unwrap_or(usize::MAX))
            .max(1);
        if pager_budget != u64::MAX {
            self.pager.set_budget(cache);
        }
        let stream = Stream {
            tree,
            progress: self.progress.as_deref().map(|p| p as &dyn Progress),
            opts: StreamOptions {
                workers,
                readers,
                read_ahead,
                parked_bytes: parked,
            },
        };
        let ran = stream.run(job, &start_order, out, shadows);
        self.pager.set_budget(pager_budget);
        let s = ran.map_err(|e| self.corrupt(e))?;
        self.check_unchanged()?;
        Ok(s)
    }

    /// The permutation in which `order` traces `rays` (`None` for [`Order::None`]: as given,
    /// no permutation).
    pub fn permutation(&self, rays: &[Ray], order: Order) -> Result<Option<Vec<u32>>, Error> {
        if u32::try_from(rays.len()).is_err() {
            return Err(Error::Invalid(format!(
                "{} rays: a batch holds at most 2^32 - 1",
                rays.len()
            )));
        }
        Ok(match order {
            Order::None => None,
            Order::Given => Some((0..rays.len() as u32).collect()),
            Order::Morton | Order::Stream => Some(self.morton_order(rays)),
            Order::Blocks => Some(self.block_order(rays)?),
        })
    }

    /// The order in which [`Order::Morton`] traces `rays`: their indices sorted by
    /// [`RayKeys::key`] (ties by index, so the order is deterministic).
    pub fn morton_order(&self, rays: &[Ray]) -> Vec<u32> {
        let keys = RayKeys::new(self.file.header());
        let mut keyed: Vec<(u64, u32)> = rays
            .par_iter()
            .enumerate()
            .map(|(i, r)| (keys.key(r), i as u32))
            .collect();
        keyed.par_sort_unstable();
        keyed.into_iter().map(|(_, i)| i).collect()
    }

    /// The order in which [`Order::Blocks`] traces `rays`: their indices sorted by the first
    /// block each needs ([`Tree::first_block`], found in the top tree; rays that need none
    /// last), then by [`RayKeys::key`], then by index.
    pub fn block_order(&self, rays: &[Ray]) -> Result<Vec<u32>, Error> {
        let keys = RayKeys::new(self.file.header());
        let tree = self.tree();
        let mut keyed: Vec<(u32, u64, u32)> = rays
            .par_iter()
            .enumerate()
            .map(|(i, r)| {
                let first = tree.first_block(r)?.unwrap_or(u32::MAX);
                Ok((first, keys.key(r), i as u32))
            })
            .collect::<Result<_, Corruption>>()
            .map_err(|e| self.corrupt(e))?;
        keyed.par_sort_unstable();
        Ok(keyed.into_iter().map(|(.., i)| i).collect())
    }

    /// Answers `rays` into `out` with `answer`, in `order`, in chunks on at most
    /// [`Self::threads`] threads, summing the counters; then checks that the file did not
    /// change meanwhile. `answer` is given a chunk's rays and the room for their answers (as
    /// many), in order.
    fn batch<T: Send + Sync + Copy>(
        &self,
        rays: &[Ray],
        out: &mut [T],
        order: Order,
        answer: impl Fn(ChunkRays<'_>, &mut [T], &mut Counters) -> Result<(), TraceError> + Sync,
    ) -> Result<Counters, Error> {
        check_room(rays.len(), out.len())?;
        let traced: Result<Counters, TraceError> = match self.permutation(rays, order)? {
            _ if rays.is_empty() => Ok(Counters::default()),
            None => in_order(rays, out, CHUNK, self.threads, |rays, out, c| {
                answer(ChunkRays::Given(rays.iter()), out, c)
            }),
            Some(perm) => {
                // Trace in that order into `sorted`, then put each answer at its ray's place:
                // the same answers as unordered, written in the caller's order.
                let mut sorted = vec![out[0]; rays.len()];
                let c = in_order(&perm, &mut sorted, CHUNK, self.threads, |idx, out, c| {
                    answer(ChunkRays::Permuted(rays, idx.iter()), out, c)
                });
                for (&i, a) in perm.iter().zip(&sorted) {
                    out[i as usize] = *a;
                }
                c
            }
        };
        let c = traced.map_err(|e| self.corrupt(e))?;
        self.check_unchanged()?;
        Ok(c)
    }
}

/// The rays of one chunk of a batch ([`Scene::batch`]), in the order they are traced: a slice
/// of the batch's rays, or the batch's rays at a slice of its permutation.
enum ChunkRays<'r> {
    Given(std::slice::Iter<'r, Ray>),
    Permuted(&'r [Ray], std::slice::Iter<'r, u32>),
}

impl<'r> Iterator for ChunkRays<'r> {
    type Item = &'r Ray;
    #[inline(always)]
    fn next(&mut self) -> Option<&'r Ray> {
        match self {
            ChunkRays::Given(rays) => rays.next(),
            ChunkRays::Permuted(rays, idx) => idx.next().map(|&i| &rays[i as usize]),
        }
    }
}

/// A batch of `rays` rays must have room for as many answers.
fn check_room(rays: usize, answers: usize) -> Result<(), Error> {
    if rays == answers {
        return Ok(());
    }
    Err(Error::Invalid(format!(
        "{rays} rays but room for {answers} answers"
    )))
}

impl<D: AsRef<[u8]> + BlockSource> BlockFetch for Scene<D> {
    fn fetch(
        &self,
        block: u32,
        c: &mut PageCounters,
    ) -> Result<(BlockBytes<'_>, &ReadyMap), PageError> {
        let directory = self.directory();
        let bytes = self.pager.get(self.file.data(), directory, block, c)?;
        // `get` found the entry.
        let entry = directory.get(block as usize).ok_or_else(|| PageError {
            block,
            what: "no such block".into(),
        })?;
        let ready = self.pager.ready(block, entry, &bytes)?;
        Ok((bytes, ready))
    }

    fn resident(&self, block: u32) -> bool {
        self.pager.is_resident(block)
    }
}
