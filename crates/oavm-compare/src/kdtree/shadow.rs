//! Shadow-ray walks of the KD-tree: the multi-index tree of Liang and Huang (2019) and the
//! SATO order it is compared with (Nah and Manocha 2014). All answer any-hit queries only, and
//! all give the stack walk's answers: they change which nodes and triangles a ray tests, and in
//! what order, never which triangles can stop it.
//!
//! - **SATO** ([`SatoOrder`]): where a ray crosses both children of a node, the child of larger
//!   surface area is visited first, whatever the ray's direction. A BVH node's surface area is
//!   that of the box of its triangles; the KD-tree's cells tile space, and the larger cell is
//!   often the empty one the build cut off, so a child's area here is that of its triangles' box
//!   clipped to its cell (what a BVH node over those triangles would have), zero if it has none.
//! - **Primitive index** ([`PrimitiveIndex`]): large triangles are also tested at an inner node
//!   above their leaves, so that an occluded ray can stop there. Candidates are the triangles
//!   whose box's surface area is more than `candidate_ratio` times the mean. For each, and each
//!   inner node from the lowest node holding all its leaves (their common ancestor) up to the
//!   root, the subtree's cost with the triangle tested first is estimated as
//!   `C' = C_tri + (1 - P) (C_below + C_above)`, `P` the area of the triangle's box (clipped to
//!   the node's cell) over the cell's, the subtree costs by the SAH with the build's constants;
//!   the saving `C / C'` is weighted by `exp(-k d)`, `d` the levels above the common ancestor
//!   (our reading of the source's depth: it keeps a large triangle near its natural home), and
//!   the node of greatest weighted saving keeps the triangle if that exceeds `min_benefit`
//!   (1: the estimate says it pays). A node keeps at most `per_node`, those of greatest saving.
//!   The walk is the stack walk testing a node's triangles (over the whole ray) when it enters
//!   it; a ray remembers up to [`REMEMBER`] triangles it tested so and skips them in the leaves.
//! - **Adjacency index** ([`Adjacency`]): links from leaf to leaf across their faces (Popov's
//!   ropes: the smallest node holding everything across the face), built only where shadow rays
//!   go. The primary hits are mapped into a virtual grid of `grid`³ cells over the scene, and
//!   the grid cells on the segments from the cells holding them to each light marked too; links are then built breadth-first from the leaves holding the light, through
//!   neighbours whose cells meet a marked grid cell. The walk goes from the light's end of the
//!   segment back to its start (an any-hit answer does not depend on the order): it starts in
//!   the light's leaf with no descent, and from each leaf takes the link of the face it leaves
//!   by, walking down from the node linked to. A leaf reached that has no links sends the walk
//!   down again from the root (counted in `restarts`), which also tells it where the leaf
//!   ends; links followed count in `ropes_followed`. Where the walk meets a split plane at its
//!   point (a cell of no thickness may lie there), or leaves a leaf through an edge or a corner
//!   (two of its faces within the tolerance: the stack walk visits the leaves around it, and a
//!   triangle there may be hit by the watertight test: three of 37.7 million kitchen shadow
//!   rays were answered otherwise before this), it finishes the rest of the segment with the
//!   stack walk.

use std::cell::RefCell;
use std::time::Instant;

use super::KdTree;
use super::build::{ISECT_COST, TRAVERSAL_COST};
use super::ropes::{NONE, push_down};
use super::traverse::{KdRay, Plain, StackHooks};
use crate::Counters;
use crate::leaf::{NO_HIT, Query, STOP};
use oavm::geom::Ray;

/// How many promoted triangles a ray remembers having tested (more are tested again in their
/// leaves, which costs tests but not answers).
pub const REMEMBER: usize = 32;

/// The knobs of the multi-index tree (module docs), shared with OAVM's occluders.
pub use oavm::pack::occluders::ShadowParams;

type Cell = [[f32; 3]; 2];

fn area(c: &Cell) -> f64 {
    let e = |k: usize| (c[1][k] as f64 - c[0][k] as f64).max(0.0);
    2.0 * (e(0) * e(1) + e(1) * e(2) + e(2) * e(0))
}

fn clip(a: &Cell, b: &Cell) -> Option<Cell> {
    let lo: [f32; 3] = std::array::from_fn(|k| a[0][k].max(b[0][k]));
    let hi: [f32; 3] = std::array::from_fn(|k| a[1][k].min(b[1][k]));
    (0..3).all(|k| lo[k] <= hi[k]).then_some([lo, hi])
}

fn union(a: Option<Cell>, b: Option<Cell>) -> Option<Cell> {
    match (a, b) {
        (Some(a), Some(b)) => Some([
            std::array::from_fn(|k| a[0][k].min(b[0][k])),
            std::array::from_fn(|k| a[1][k].max(b[1][k])),
        ]),
        (a, None) => a,
        (None, b) => b,
    }
}

fn tri_box(t: &[[f32; 3]; 3]) -> Cell {
    [
        std::array::from_fn(|k| t[0][k].min(t[1][k]).min(t[2][k])),
        std::array::from_fn(|k| t[0][k].max(t[1][k]).max(t[2][k])),
    ]
}

/// Every node's cell, parent and depth.
struct Shape {
    cell: Vec<Cell>,
    parent: Vec<u32>,
    depth: Vec<u32>,
}

impl KdTree {
    fn shape(&self) -> Shape {
        let n = self.nodes.len();
        let mut s = Shape {
            cell: vec![[[0.0; 3]; 2]; n],
            parent: vec![NONE; n],
            depth: vec![0; n],
        };
        if n == 0 {
            return s;
        }
        s.cell[0] = [self.lo.map(|x| x as f32), self.hi.map(|x| x as f32)];
        // Depth-first: a node's children follow it, so one pass in index order sees every
        // parent before its children.
        for i in 0..n {
            let nd = self.nodes[i];
            if nd.is_leaf() {
                continue;
            }
            let (a, sp) = (nd.axis(), nd.split());
            let (below, above) = (i + 1, nd.upper() as usize);
            let cell = s.cell[i];
            for (ch, side) in [(below, 1), (above, 0)] {
                let Some(c) = s.cell.get_mut(ch) else {
                    continue;
                };
                *c = cell;
                c[side][a] = sp;
                s.parent[ch] = i as u32;
                s.depth[ch] = s.depth[i] + 1;
            }
        }
        s
    }

    /// Per node, the box of its triangles clipped to its cell (`None`: no triangles).
    fn tight_boxes(&self, shape: &Shape) -> Vec<Option<Cell>> {
        let n = self.nodes.len();
        let mut tight: Vec<Option<Cell>> = vec![None; n];
        for i in (0..n).rev() {
            let nd = self.nodes[i];
            tight[i] = if nd.is_leaf() {
                self.leaf_list(&nd)
                    .iter()
                    .filter_map(|&t| self.soup.v.get(t as usize))
                    .map(|t| clip(&tri_box(t), &shape.cell[i]))
                    .fold(None, union)
            } else {
                let (below, above) = (i + 1, nd.upper() as usize);
                union(
                    tight.get(below).copied().flatten(),
                    tight.get(above).copied().flatten(),
                )
            };
        }
        tight
    }

    /// The point location of `p`: the leaf whose cell holds it (on a plane, the above side).
    fn leaf_at(&self, p: [f32; 3]) -> u32 {
        let mut node = 0u32;
        while let Some(n) = self.nodes.get(node as usize) {
            if n.is_leaf() {
                return node;
            }
            node = if p[n.axis()] < n.split() {
                node + 1
            } else {
                n.upper()
            };
        }
        NONE
    }
}

/// What a variant's precomputation cost.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Precompute {
    pub seconds: f64,
    pub bytes: u64,
}

/// The SATO order: per inner node, whether its above child is visited first.
pub struct SatoOrder {
    above_first: Vec<u64>,
    pub cost: Precompute,
}

impl SatoOrder {
    pub fn build(kd: &KdTree) -> SatoOrder {
        let start = Instant::now();
        let shape = kd.shape();
        let tight = kd.tight_boxes(&shape);
        let n = kd.nodes.len();
        let mut above_first = vec![0u64; n.div_ceil(64)];
        let sa = |i: usize| tight.get(i).copied().flatten().map_or(0.0, |c| area(&c));
        for (i, nd) in kd.nodes.iter().enumerate() {
            if !nd.is_leaf() && sa(nd.upper() as usize) > sa(i + 1) {
                above_first[i / 64] |= 1 << (i % 64);
            }
        }
        let bytes = 8 * above_first.len() as u64;
        SatoOrder {
            above_first,
            cost: Precompute {
                seconds: start.elapsed().as_secs_f64(),
                bytes,
            },
        }
    }
}

impl StackHooks for &SatoOrder {
    #[inline(always)]
    fn far_first(&self, node: u32, near_is_below: bool) -> bool {
        let i = node as usize;
        let above = self
            .above_first
            .get(i / 64)
            .is_some_and(|w| w >> (i % 64) & 1 == 1);
        above == near_is_below
    }
}

/// The primitive index: triangles also tested at inner nodes (module docs).
pub struct PrimitiveIndex {
    /// Per node `i`, its triangles are `tris[start[i]..start[i + 1]]` (indices into the soup).
    start: Vec<u32>,
    tris: Vec<u32>,
    pub candidates: usize,
    pub cost: Precompute,
}

impl PrimitiveIndex {
    pub fn promoted(&self) -> usize {
        self.tris.len()
    }

    #[inline(always)]
    fn at(&self, node: u32) -> &[u32] {
        let i = node as usize;
        match (self.start.get(i), self.start.get(i + 1)) {
            (Some(&a), Some(&b)) => self.tris.get(a as usize..b as usize).unwrap_or(&[]),
            _ => &[],
        }
    }

    pub fn build(kd: &KdTree, p: &ShadowParams) -> PrimitiveIndex {
        let start = Instant::now();
        let n = kd.nodes.len();
        let shape = kd.shape();
        // SAH cost of every subtree, bottom-up.
        let mut cost = vec![0f64; n];
        for i in (0..n).rev() {
            let nd = kd.nodes[i];
            cost[i] = if nd.is_leaf() {
                ISECT_COST * kd.leaf_list(&nd).len() as f64
            } else {
                let (b, a) = (i + 1, nd.upper() as usize);
                let whole = area(&shape.cell[i]).max(f64::MIN_POSITIVE);
                let part = |j: usize| area(&shape.cell[j]) / whole * cost[j];
                TRAVERSAL_COST + part(b) + part(a)
            };
        }
        // Each triangle's common ancestor of its leaves.
        let ntri = kd.soup.len();
        let mut lca = vec![NONE; ntri];
        let join = |mut a: u32, mut b: u32| {
            while a != b {
                if shape.depth[a as usize] >= shape.depth[b as usize] {
                    a = shape.parent[a as usize];
                } else {
                    b = shape.parent[b as usize];
                }
                if a == NONE || b == NONE {
                    return 0;
                }
            }
            a
        };
        for (i, nd) in kd.nodes.iter().enumerate() {
            if !nd.is_leaf() {
                continue;
            }
            for &t in kd.leaf_list(nd) {
                if let Some(l) = lca.get_mut(t as usize) {
                    *l = if *l == NONE {
                        i as u32
                    } else {
                        join(*l, i as u32)
                    };
                }
            }
        }
        let boxes: Vec<Cell> = kd.soup.v.iter().map(tri_box).collect();
        let mean = boxes.iter().map(area).sum::<f64>() / ntri.max(1) as f64;
        let mut chosen: Vec<(u32, f64, u32)> = Vec::new();
        let mut candidates = 0;
        for (t, b) in boxes.iter().enumerate() {
            if area(b) <= p.candidate_ratio * mean || lca[t] == NONE {
                continue;
            }
            candidates += 1;
            let home = lca[t];
            let mut node = if kd.nodes[home as usize].is_leaf() {
                shape.parent[home as usize]
            } else {
                home
            };
            let mut best = (0.0, NONE);
            while node != NONE {
                let i = node as usize;
                let nd = kd.nodes[i];
                let cell = &shape.cell[i];
                let hit =
                    clip(b, cell).map_or(0.0, |c| area(&c)) / area(cell).max(f64::MIN_POSITIVE);
                let kids = cost[i + 1] + cost[nd.upper() as usize];
                let with = ISECT_COST + (1.0 - hit.min(1.0)) * kids;
                let d = shape.depth[home as usize].saturating_sub(shape.depth[i]) as f64;
                let benefit = kids / with * (-p.depth_k * d).exp();
                if benefit > best.0 {
                    best = (benefit, node);
                }
                node = shape.parent[i];
            }
            if best.0 > p.min_benefit {
                chosen.push((best.1, best.0, t as u32));
            }
        }
        // Per node, the greatest savings first, at most `per_node`.
        chosen.sort_by(|a, b| a.0.cmp(&b.0).then(b.1.total_cmp(&a.1)).then(a.2.cmp(&b.2)));
        let mut starts = vec![0u32; n + 1];
        let mut tris = Vec::new();
        let mut k = 0;
        for (i, st) in starts.iter_mut().enumerate().take(n) {
            *st = tris.len() as u32;
            let mut m = 0;
            while k < chosen.len() && chosen[k].0 as usize == i {
                if m < p.per_node {
                    tris.push(chosen[k].2);
                    m += 1;
                }
                k += 1;
            }
        }
        starts[n] = tris.len() as u32;
        let bytes = 4 * (starts.len() + tris.len()) as u64;
        PrimitiveIndex {
            start: starts,
            tris,
            candidates,
            cost: Precompute {
                seconds: start.elapsed().as_secs_f64(),
                bytes,
            },
        }
    }
}

/// The walks of [`KdTree::occluded_by`].
#[derive(Clone, Copy)]
enum By<'a> {
    Standard,
    Sato(&'a SatoOrder),
    Adjacent(&'a Adjacency),
}

/// The promoted triangles a ray has tested (up to [`REMEMBER`]).
struct Tested {
    ids: [u32; REMEMBER],
    len: usize,
}

impl Tested {
    #[inline(always)]
    fn has(&self, t: u32) -> bool {
        self.ids[..self.len].contains(&t)
    }
}

/// The stack walk's hook that tests a node's promoted triangles, and remembers them.
struct Promoted<'a, 'q> {
    index: &'a PrimitiveIndex,
    q: &'a Query<'q>,
    tested: &'a RefCell<Tested>,
    found: bool,
}

impl StackHooks for Promoted<'_, '_> {
    #[inline(always)]
    fn inner(&mut self, node: u32, c: &mut Counters) -> bool {
        let tris = self.index.at(node);
        if tris.is_empty() {
            return false;
        }
        c.promoted_tested += tris.len() as u64;
        if self.q.any(tris, c) {
            self.found = true;
            return true;
        }
        let mut tested = self.tested.borrow_mut();
        for &t in tris {
            if tested.len < REMEMBER && !tested.has(t) {
                let at = tested.len;
                tested.ids[at] = t;
                tested.len += 1;
            }
        }
        false
    }
}

/// One leaf-to-leaf link record of the adjacency index: the leaf's cell and the node across
/// each of its faces (−x, +x, −y, +y, −z, +z; [`NONE`] at the scene's boundary).
#[derive(Clone, Copy, Debug)]
struct Links {
    cell: Cell,
    across: [u32; 6],
}

/// The adjacency index (module docs).
pub struct Adjacency {
    /// Per node, its record in `links`, or [`NONE`].
    slot: Vec<u32>,
    links: Vec<Links>,
    /// The leaves holding a light's points, where walks start.
    starts: Vec<u32>,
    pub linked_leaves: usize,
    pub leaves: usize,
    pub cost: Precompute,
}

impl Adjacency {
    /// Links for `kd` where shadow rays go from the points `visible` (the primary hits) to the
    /// points `lights` (module docs).
    pub fn build(
        kd: &KdTree,
        visible: &[[f32; 3]],
        lights: &[[f32; 3]],
        p: &ShadowParams,
    ) -> Adjacency {
        let start = Instant::now();
        let n = kd.nodes.len();
        let shape = kd.shape();
        let leaves = kd.nodes.iter().filter(|n| n.is_leaf()).count();
        let mut adj = Adjacency {
            slot: vec![NONE; n],
            links: Vec::new(),
            starts: Vec::new(),
            linked_leaves: 0,
            leaves,
            cost: Precompute::default(),
        };
        if n == 0 || kd.brute {
            return adj;
        }
        // The virtual grid over the root cell.
        let g = p.grid.clamp(1, 256) as usize;
        let root = shape.cell[0];
        let size: [f64; 3] =
            std::array::from_fn(|k| (root[1][k] as f64 - root[0][k] as f64).max(f64::MIN_POSITIVE));
        let cell_of = |x: [f64; 3]| -> [usize; 3] {
            std::array::from_fn(|k| {
                (((x[k] - root[0][k] as f64) / size[k] * g as f64)
                    .floor()
                    .max(0.0) as usize)
                    .min(g - 1)
            })
        };
        let mut marked = vec![false; g * g * g];
        let idx = |c: [usize; 3]| (c[2] * g + c[1]) * g + c[0];
        let range = |c: &Cell| -> [[usize; 3]; 2] {
            [
                cell_of(c[0].map(|x| x as f64)),
                cell_of(c[1].map(|x| x as f64)),
            ]
        };
        // The grid cells holding visible points.
        let mut visible_cells = Vec::new();
        for &v in visible {
            let c = cell_of(v.map(|x| x as f64));
            if !marked[idx(c)] {
                marked[idx(c)] = true;
                visible_cells.push(c);
            }
        }
        // The segments from them to the lights, at half a grid cell a step.
        for c in visible_cells {
            let from: [f64; 3] = std::array::from_fn(|k| {
                root[0][k] as f64 + (c[k] as f64 + 0.5) / g as f64 * size[k]
            });
            for l in lights {
                let to = l.map(|x| x as f64);
                let steps = (0..3)
                    .map(|k| ((to[k] - from[k]) / size[k] * g as f64).abs())
                    .fold(0.0, f64::max);
                let steps = (2.0 * steps).ceil().min(4.0 * g as f64) as usize + 1;
                for s in 0..=steps {
                    let f = s as f64 / steps as f64;
                    let x = std::array::from_fn(|k| from[k] + f * (to[k] - from[k]));
                    marked[idx(cell_of(x))] = true;
                }
            }
        }
        let meets_marked = |c: &Cell| {
            let [a, b] = range(c);
            (a[2]..=b[2])
                .any(|z| (a[1]..=b[1]).any(|y| (a[0]..=b[0]).any(|x| marked[idx([x, y, z])])))
        };
        // Nodebox clues, top-down (as the ropes are built).
        let mut clues = vec![[NONE; 6]; n];
        for i in 0..n {
            let nd = kd.nodes[i];
            if nd.is_leaf() {
                continue;
            }
            let (a, below, above) = (nd.axis(), i + 1, nd.upper() as usize);
            let (mut cb, mut ca) = (clues[i], clues[i]);
            (cb[2 * a + 1], ca[2 * a]) = (above as u32, below as u32);
            if let Some(c) = clues.get_mut(below) {
                *c = cb;
            }
            if let Some(c) = clues.get_mut(above) {
                *c = ca;
            }
        }
        // Breadth-first from the lights' leaves.
        let mut queue = std::collections::VecDeque::new();
        let mut queued = vec![false; n];
        for l in lights {
            let leaf = kd.leaf_at(*l);
            if leaf != NONE && !queued[leaf as usize] {
                queued[leaf as usize] = true;
                queue.push_back(leaf);
                adj.starts.push(leaf);
            }
        }
        let mut stack = Vec::new();
        while let Some(leaf) = queue.pop_front() {
            let li = leaf as usize;
            let cell = shape.cell[li];
            let mut across = [NONE; 6];
            for (f, a) in across.iter_mut().enumerate() {
                *a = push_down(kd, clues[li][f], f, &cell);
                if *a == NONE {
                    continue;
                }
                // The leaves under it that touch the face.
                let (fa, high) = (f / 2, f % 2 == 1);
                let plane = if high { cell[1][fa] } else { cell[0][fa] };
                stack.push(*a);
                while let Some(m) = stack.pop() {
                    let mi = m as usize;
                    let Some(nd) = kd.nodes.get(mi) else { continue };
                    let mc = &shape.cell[mi];
                    let touches = (0..3).all(|k| {
                        if k == fa {
                            mc[0][k] <= plane && plane <= mc[1][k]
                        } else {
                            mc[0][k] <= cell[1][k] && cell[0][k] <= mc[1][k]
                        }
                    });
                    if !touches {
                        continue;
                    }
                    if nd.is_leaf() {
                        if !queued[mi] && meets_marked(mc) {
                            queued[mi] = true;
                            queue.push_back(m);
                        }
                    } else {
                        stack.push(m + 1);
                        stack.push(nd.upper());
                    }
                }
            }
            adj.slot[li] = adj.links.len() as u32;
            adj.links.push(Links { cell, across });
        }
        adj.linked_leaves = adj.links.len();
        adj.cost = Precompute {
            seconds: start.elapsed().as_secs_f64(),
            bytes: (4 * adj.slot.len()
                + std::mem::size_of::<Links>() * adj.links.len()
                + 4 * adj.starts.len()) as u64,
        };
        adj
    }

    #[inline(always)]
    fn record(&self, node: u32) -> Option<&Links> {
        let s = *self.slot.get(node as usize)?;
        self.links.get(s as usize)
    }
}

impl KdTree {
    /// Any hit by the plain stack walk (the standard traversal).
    pub fn occluded_standard(&self, ray: &Ray, c: &mut Counters) -> bool {
        self.occluded_by(ray, c, By::Standard)
    }

    /// Any hit by the SATO order.
    pub fn occluded_sato(&self, ray: &Ray, order: &SatoOrder, c: &mut Counters) -> bool {
        self.occluded_by(ray, c, By::Sato(order))
    }

    /// Any hit by the stack walk testing the primitive index's triangles at inner nodes.
    pub fn occluded_promoted(&self, ray: &Ray, index: &PrimitiveIndex, c: &mut Counters) -> bool {
        let Some(q) = Query::new(&self.soup, ray) else {
            return false;
        };
        if self.brute {
            return q.any(&(0..self.soup.len()), c);
        }
        let Some(r) = self.kd_ray(ray) else {
            return false;
        };
        let tested = RefCell::new(Tested {
            ids: [0; REMEMBER],
            len: 0,
        });
        let mut hook = Promoted {
            index,
            q: &q,
            tested: &tested,
            found: false,
        };
        let mut found = false;
        let mut buf = [0u32; 64];
        let mut leaf = |ids: &[u32], c: &mut Counters| {
            let tested = tested.borrow();
            found = if tested.len == 0 {
                q.any(ids, c)
            } else {
                // The triangles not tested at inner nodes already.
                ids.chunks(buf.len()).any(|chunk| {
                    let mut m = 0;
                    for &t in chunk {
                        if !tested.has(t) {
                            buf[m] = t;
                            m += 1;
                        }
                    }
                    q.any(&buf[..m], c)
                })
            };
            if found { STOP } else { NO_HIT }
        };
        if self.stack_core(&r, r.t0, c, &mut leaf, &mut hook) {
            found || hook.found
        } else {
            q.any(&(0..self.soup.len()), c)
        }
    }

    /// Any hit by the adjacency index's walk, from the light's end of the segment.
    pub fn occluded_adjacent(&self, ray: &Ray, adj: &Adjacency, c: &mut Counters) -> bool {
        self.occluded_by(ray, c, By::Adjacent(adj))
    }

    /// The any-hit query by one of the walks that test leaves only (`false` from a walk: it
    /// could not answer, and every triangle is tested).
    #[inline(always)]
    fn occluded_by(&self, ray: &Ray, c: &mut Counters, by: By) -> bool {
        let Some(q) = Query::new(&self.soup, ray) else {
            return false;
        };
        if self.brute {
            return q.any(&(0..self.soup.len()), c);
        }
        let Some(r) = self.kd_ray(ray) else {
            return false;
        };
        let mut found = false;
        let mut leaf = |ids: &[u32], c: &mut Counters| {
            found = q.any(ids, c);
            if found { STOP } else { NO_HIT }
        };
        let complete = match by {
            By::Standard => self.stack_core(&r, r.t0, c, &mut leaf, &mut Plain),
            By::Sato(order) => self.stack_core(&r, r.t0, c, &mut leaf, &mut &*order),
            By::Adjacent(adj) => self.walk_adjacent(&r, adj, c, &mut leaf),
        };
        if complete {
            found
        } else {
            q.any(&(0..self.soup.len()), c)
        }
    }

    /// The adjacency walk (module docs) of the segment `f`, backwards.
    #[inline(always)]
    fn walk_adjacent(
        &self,
        f: &KdRay,
        adj: &Adjacency,
        c: &mut Counters,
        leaf: &mut impl FnMut(&[u32], &mut Counters) -> f32,
    ) -> bool {
        // The same line walked the other way: `t` becomes `-t`, every plane decision mirrored
        // exactly (negation is exact).
        let r = KdRay {
            t0: -f.t1,
            t1: -f.t0,
            o: f.o,
            d: f.d.map(|x| -x),
            inv: f.inv.map(|x| -x),
            eps: f.eps,
        };
        let mut s = r.t0;
        let p: [f64; 3] = std::array::from_fn(|k| r.o[k] + s * r.d[k]);
        let inside = |cell: &Cell| {
            (0..3).all(|k| {
                let m = r.eps * r.d[k].abs();
                p[k] > cell[0][k] as f64 + m && p[k] < cell[1][k] as f64 - m
            })
        };
        let mut node = adj
            .starts
            .iter()
            .copied()
            .find(|&l| adj.record(l).is_some_and(|rec| inside(&rec.cell)))
            .unwrap_or(0);
        let mut from_root = node == 0;
        let mut tested = NONE;
        loop {
            // Down to the leaf holding the point at `s`; from the root, `tmax` is where it ends.
            let mut tmax = r.t1;
            let n = loop {
                let Some(n) = self.nodes.get(node as usize) else {
                    return self.stack_core(&r, s, c, leaf, &mut Plain);
                };
                c.nodes_visited += 1;
                if n.is_leaf() {
                    break n;
                }
                let a = n.axis();
                let split = n.split() as f64;
                let (below, above) = (node + 1, n.upper());
                node = if r.d[a] == 0.0 {
                    if r.o[a] < split {
                        below
                    } else if r.o[a] > split {
                        above
                    } else {
                        return self.stack_core(&r, s, c, leaf, &mut Plain);
                    }
                } else {
                    let tp = (split - r.o[a]) * r.inv[a];
                    if (tp - s).abs() <= r.eps {
                        // At the plane: the other side may be a cell of no thickness.
                        return self.stack_core(&r, s, c, leaf, &mut Plain);
                    }
                    let (near, far) = if r.d[a] > 0.0 {
                        (below, above)
                    } else {
                        (above, below)
                    };
                    if tp < s {
                        far
                    } else {
                        tmax = tmax.min(tp);
                        near
                    }
                };
            };
            if node != tested {
                let Some(_) = self.visit_leaf(n, c, leaf) else {
                    return true;
                };
            }
            tested = node;
            let (exit, next) = if let Some(rec) = adj.record(node) {
                let (mut exit, mut face, mut second) = (f64::INFINITY, 0, f64::INFINITY);
                for k in 0..3 {
                    let (plane, fc) = if r.d[k] > 0.0 {
                        (rec.cell[1][k], 2 * k + 1)
                    } else if r.d[k] < 0.0 {
                        (rec.cell[0][k], 2 * k)
                    } else {
                        continue;
                    };
                    let t = (plane as f64 - r.o[k]) * r.inv[k];
                    if t < exit {
                        second = exit;
                        (exit, face) = (t, fc);
                    } else if t < second {
                        second = t;
                    }
                }
                if second - exit <= r.eps && exit < r.t1 {
                    // Out through an edge or a corner (within the tolerance): the leaves around
                    // it, which the stack walk visits, are not all across one face.
                    return self.stack_core(&r, exit, c, leaf, &mut Plain);
                }
                (exit, Some(rec.across[face]))
            } else if from_root {
                (tmax, None)
            } else {
                // No links here: down again from the root, to learn where this leaf ends.
                c.restarts += 1;
                (node, from_root) = (0, true);
                continue;
            };
            if exit >= r.t1 {
                return true;
            }
            if exit <= s {
                return self.stack_core(&r, s, c, leaf, &mut Plain);
            }
            s = exit;
            match next {
                Some(NONE) => return true,
                Some(t) => {
                    c.ropes_followed += 1;
                    (node, from_root) = (t, false);
                }
                None => {
                    c.restarts += 1;
                    (node, from_root) = (0, true);
                }
            }
        }
    }
}
