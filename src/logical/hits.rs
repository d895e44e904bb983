//! Every hit along a ray ([`Scene::list_intersections`], [`Scene::count_intersections`]): what
//! a user counting crossings (inside tests, thickness, visibility through layers) asks for, in
//! Open3D's shape (a list per ray, the lists end to end with their splits).
//!
//! Each ray is walked by the wide walk with its closest hit never closing in
//! ([`Tree::all_hits`]), so it enters every node its segment meets; a triangle found in several
//! leaves is kept once, and a ray through an edge or a corner shared by several triangles meets
//! one of them ([`crate::geom::triangle::RayShear::owns`]): a closed surface is crossed an even
//! number of times by a ray from outside to outside, whatever edges and corners it passes
//! through.

use bytemuck::Zeroable;

use super::batch::{CHUNK, in_order};
use super::pager::BlockSource;
use super::trace::{Counters, HitInfo, TraceError, Tree};
use super::{Order, Scene};
use crate::error::Error;
use crate::geom::{AllHits, HitAttributes, ListedHit, Ray};

/// What one chunk of rays found: each ray's index and number of hits, and the hits end to end.
#[derive(Default)]
struct ChunkHits {
    rays: Vec<(u32, u32)>,
    hits: Vec<ListedHit>,
}

impl<D: AsRef<[u8]> + BlockSource> Scene<D> {
    /// Every hit of each of `rays` with `tmin <= t <= tmax` (see [`AllHits`]), in parallel,
    /// the rays taken in Morton order when the file is larger than the budget (so that
    /// neighbouring rays share the blocks read). A file of leaf lists, and a ray with
    /// `tmin < 0` or a direction with a component too small or too large for the walk's f32
    /// (spec §8.7: `|1 / d|` above 2^55), are refused with an error naming the ray; a ray that
    /// hits nothing by `RAYS.md` (a zero or non-finite direction, `tmin > tmax`) has no hit.
    pub fn list_intersections(&self, rays: &[Ray]) -> Result<(AllHits, Counters), Error> {
        let (found, c) = self.every_hit(rays, true)?;
        let mut splits = Vec::with_capacity(rays.len() + 1);
        splits.push(0u64);
        let mut count = vec![0u32; rays.len()];
        for ch in &found {
            for &(i, n) in &ch.rays {
                count[i as usize] = n;
            }
        }
        let mut at = 0u64;
        for n in &count {
            at += *n as u64;
            splits.push(at);
        }
        let mut hits = vec![ListedHit::zeroed(); at as usize];
        for ch in &found {
            let mut from = 0usize;
            for &(i, n) in &ch.rays {
                let to = splits[i as usize] as usize;
                hits[to..to + n as usize].copy_from_slice(&ch.hits[from..from + n as usize]);
                from += n as usize;
            }
        }
        Ok((AllHits { splits, hits }, c))
    }

    /// How many hits each of `rays` has ([`Self::list_intersections`]'s lists' lengths), into
    /// `out` (same length), without keeping the hits.
    pub fn count_intersections(&self, rays: &[Ray], out: &mut [u32]) -> Result<Counters, Error> {
        if rays.len() != out.len() {
            let what = format!("{} rays but room for {} answers", rays.len(), out.len());
            return Err(Error::Invalid(what));
        }
        let (found, c) = self.every_hit(rays, false)?;
        for ch in &found {
            for &(i, n) in &ch.rays {
                out[i as usize] = n;
            }
        }
        Ok(c)
    }

    /// Each chunk's rays and hits (the hits only with `keep`).
    fn every_hit(&self, rays: &[Ray], keep: bool) -> Result<(Vec<ChunkHits>, Counters), Error> {
        let tree = self.tree();
        if !tree.has_clusters() {
            let what = "every hit along a ray needs a file of clusters (the default leaf); \
                        this one holds leaf lists: pack it again without --leaf list";
            return Err(self.refuse(what));
        }
        let order = match self.fits_in_budget() {
            true => None,
            false => self.permutation(rays, Order::Morton)?,
        };
        let order = order.unwrap_or_else(|| (0..rays.len() as u32).collect());
        let chunks: Vec<&[u32]> = order.chunks(CHUNK).collect();
        let mut found: Vec<ChunkHits> = (0..chunks.len()).map(|_| ChunkHits::default()).collect();
        let walked = in_order(&chunks, &mut found, 1, self.threads(), |idx, out, c| {
            walk_chunk(&tree, rays, idx[0], &mut out[0], keep, c)
        });
        let c = walked.map_err(|e| match e {
            Walked::Trace(e) => self.corrupt(e),
            Walked::Refused(i) => self.refuse(&format!(
                "ray {i} cannot be walked for every hit: its tmin is below 0 or its direction \
                 has a component too small or too large for f32 (|1/d| above 2^55): {:?}",
                rays[i as usize]
            )),
        })?;
        self.check_unchanged()?;
        Ok((found, c))
    }

    fn refuse(&self, what: &str) -> Error {
        Error::Invalid(format!("{}: {what}", self.path().display()))
    }
}

enum Walked {
    Trace(TraceError),
    Refused(u32),
}

/// Walks the rays `idx` of `rays` for every hit into `out`.
fn walk_chunk(
    tree: &Tree<'_>,
    rays: &[Ray],
    idx: &[u32],
    out: &mut ChunkHits,
    keep: bool,
    c: &mut Counters,
) -> Result<(), Walked> {
    let mut found: Vec<HitInfo> = Vec::new();
    let mut refused = None;
    let mut ids = idx.iter().copied();
    let walk = idx.iter().map(|&i| &rays[i as usize]);
    tree.all_hits_each(walk, c, &mut found, |ray, hits| {
        // The walk hands back each ray of `walk`, in order: one id each.
        let Some(i) = ids.next() else { return };
        match hits {
            // An invalid ray (a NaN, a zero direction, tmin above tmax) hits nothing.
            None if !ray.is_valid() => out.rays.push((i, 0)),
            None => {
                refused.get_or_insert(i);
            }
            Some(hits) => {
                out.rays.push((i, hits.len() as u32));
                if keep {
                    out.hits.extend(hits.iter().map(|h| {
                        let a = HitAttributes::new(ray, h.t, h.prim, &h.v);
                        ListedHit {
                            t: h.t,
                            prim: h.prim,
                            u: a.u,
                            v: a.v,
                        }
                    }));
                }
            }
        }
    })
    .map_err(Walked::Trace)?;
    match refused {
        Some(i) => Err(Walked::Refused(i)),
        None => Ok(()),
    }
}
