//! The logical layer: the octree with merged empty volumes as the tracer sees it, and tracing
//! batches of rays through it on rayon.

pub mod trace;

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use crate::error::{Error, FormatError};
use crate::geom::{Hit, Ray};
use crate::mapping::TreeMap;
use crate::physical::format::SectionKind;
use crate::physical::pager::{
    BlockBytes, BlockSource, PageCounters, PageError, Pager, PagerOptions,
};
use crate::physical::verify::VerifyReport;
use crate::physical::{MappedFile, OavmFile};
pub use trace::{BlockFetch, Counters, HitInfo, TraceError, Tree};

/// How an opened file is traced.
#[derive(Clone, Copy, Debug)]
pub struct SceneOptions {
    /// Bytes of decoded blocks the pager may keep resident (`u64::MAX`: no limit). The top tree
    /// and block directory are not counted (they are small and always resident).
    pub mem_budget: u64,
    /// Threads that will trace at once (the pager keeps at least one cache slot per thread, plus
    /// one); 0: rayon's current pool size.
    pub threads: usize,
}

impl Default for SceneOptions {
    fn default() -> Self {
        SceneOptions {
            mem_budget: u64::MAX,
            threads: 0,
        }
    }
}

/// An opened `.oavm` file, ready to trace. Opening reads the header, section table and top
/// tree's level table only, and sets up the pager: its cost does not grow with the file.
pub struct Scene<D = MappedFile> {
    file: OavmFile<D>,
    path: PathBuf,
    pager: Pager,
}

impl Scene<MappedFile> {
    /// Maps and opens the file at `path`, with no memory budget.
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
        let threads = if opts.threads == 0 {
            rayon::current_num_threads()
        } else {
            opts.threads
        };
        let pager = Pager::new(
            file.directory(),
            PagerOptions {
                budget: opts.mem_budget,
                threads,
                max_raw_len: file.header().max_block_raw_len,
            },
        );
        Ok(Scene { file, path, pager })
    }

    pub fn file(&self) -> &OavmFile<D> {
        &self.file
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The pager (for its resident-bytes figures).
    pub fn pager(&self) -> &Pager {
        &self.pager
    }

    pub fn tree(&self) -> Tree<'_> {
        let h = self.file.header();
        let top = TreeMap::new(
            self.file.levels(),
            self.file.records(SectionKind::Nodes),
            self.file.records(SectionKind::Ranks),
        );
        Tree::new(top, self.file.directory(), self, h.root_min, h.root_size)
    }

    /// Checks every section and checksum (see [`crate::physical::verify`]).
    pub fn verify(&self) -> VerifyReport {
        crate::physical::verify::verify(&self.file)
    }

    pub fn corrupt(&self, e: impl Into<FormatError>) -> Error {
        Error::format(&self.path, e.into())
    }

    /// Closest hits of `rays` into `out` (same length), in parallel on the current rayon pool.
    pub fn intersect_batch(&self, rays: &[Ray], out: &mut [Hit]) -> Result<Counters, Error> {
        let tree = self.tree();
        self.batch(rays, out, |ray, c| {
            Ok(tree.intersect(ray, c)?.map_or(Hit::MISS, |h| Hit {
                t: h.t,
                prim: h.prim,
            }))
        })
    }

    /// Any-hit answers of `rays` into `out` (1: occluded, 0: not), in parallel.
    pub fn occluded_batch(&self, rays: &[Ray], out: &mut [u8]) -> Result<Counters, Error> {
        let tree = self.tree();
        self.batch(rays, out, |ray, c| Ok(tree.occluded(ray, c)? as u8))
    }

    /// Answers `rays` into `out` with `answer`, in chunks on rayon, summing the counters.
    fn batch<T: Send>(
        &self,
        rays: &[Ray],
        out: &mut [T],
        answer: impl Fn(&Ray, &mut Counters) -> Result<T, TraceError> + Sync,
    ) -> Result<Counters, Error> {
        if rays.len() != out.len() {
            return Err(Error::Invalid(format!(
                "{} rays but room for {} answers",
                rays.len(),
                out.len()
            )));
        }
        rays.par_chunks(CHUNK)
            .zip(out.par_chunks_mut(CHUNK))
            .try_fold(Counters::default, |mut c, (rays, out)| {
                for (ray, o) in rays.iter().zip(out) {
                    *o = answer(ray, &mut c)?;
                }
                Ok(c)
            })
            .try_reduce(Counters::default, |a, b| Ok(a + b))
            .map_err(|e: TraceError| self.corrupt(e))
    }
}

impl<D: AsRef<[u8]> + BlockSource> BlockFetch for Scene<D> {
    fn fetch(&self, block: u32, c: &mut PageCounters) -> Result<BlockBytes<'_>, PageError> {
        self.pager
            .get(self.file.data(), self.file.directory(), block, c)
    }
}

/// Rays per rayon task: large enough to amortise scheduling, small enough to balance.
const CHUNK: usize = 256;
