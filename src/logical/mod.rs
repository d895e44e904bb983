//! The logical layer: the octree with merged empty volumes as the tracer sees it, and tracing
//! batches of rays through it on rayon.

pub mod trace;

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use crate::error::{Error, FormatError};
use crate::geom::{Hit, Ray};
use crate::mapping::Corruption;
use crate::physical::verify::VerifyReport;
use crate::physical::{MappedFile, OavmFile};
pub use trace::{Counters, HitInfo, Tree};

/// An opened `.oavm` file, ready to trace. Opening reads the header, section table and level
/// table only: its cost does not grow with the file.
pub struct Scene<D = MappedFile> {
    file: OavmFile<D>,
    path: PathBuf,
}

impl Scene<MappedFile> {
    /// Maps and opens the file at `path`.
    pub fn open(path: impl AsRef<Path>) -> Result<Scene<MappedFile>, Error> {
        let path = path.as_ref();
        let map = MappedFile::open(path).map_err(|e| Error::io(path, e))?;
        map.advise(memmap2::Advice::Random);
        Scene::from_bytes(map, path)
    }
}

impl<D: AsRef<[u8]>> Scene<D> {
    /// Opens `data` as an `.oavm` file; `path` names it in errors.
    pub fn from_bytes(data: D, path: impl Into<PathBuf>) -> Result<Scene<D>, Error> {
        let path = path.into();
        let file = OavmFile::open(data).map_err(|e| Error::format(&path, e))?;
        Ok(Scene { file, path })
    }

    pub fn file(&self) -> &OavmFile<D> {
        &self.file
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn tree(&self) -> Tree<'_> {
        Tree::new(&self.file)
    }

    /// Checks every section and checksum (see [`crate::physical::verify`]).
    pub fn verify(&self) -> VerifyReport {
        crate::physical::verify::verify(&self.file)
    }

    fn corrupt(&self, e: impl Into<FormatError>) -> Error {
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
        answer: impl Fn(&Ray, &mut Counters) -> Result<T, Corruption> + Sync,
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
            .map_err(|e: Corruption| self.corrupt(e))
    }
}

/// Rays per rayon task: large enough to amortise scheduling, small enough to balance.
const CHUNK: usize = 256;
