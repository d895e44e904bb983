//! Steps 4 and 5 of the cluster build: the groups' binary tree collapsed to 8-wide nodes,
//! sibling groups merged where they fit one, and the nodes written breadth-first with
//! quantised boxes. See the parent module.

use super::binary::{BinNode, PrimRef};
use super::group::Draft;
use super::{ClusterError, ClusterTri, Mode, Params, fits_group, make_group};
use crate::physical::format::{CLUSTER_WIDTH, ClusterNode, GROUP_LANES, TriGroup};

/// What the emission reads.
pub(super) struct Input<'a> {
    /// The groups' binary tree: each leaf holds one of `refs`, whose `id` is a draft.
    pub bin: &'a [BinNode],
    pub refs: &'a [PrimRef],
    pub drafts: &'a [Draft],
    pub tris: &'a [ClusterTri],
    /// The triangles' corner numbers.
    pub vid: &'a [[u32; 3]],
    pub params: &'a Params,
    pub mode: Mode,
    pub node_base: u32,
    pub group_base: u32,
}

/// A child of the wide node being assembled: a binary inner node (to become a wide node, or to
/// be opened), or a group.
#[derive(Clone, Copy)]
enum Entry {
    Inner(u32),
    Leaf(Draft),
}

impl Input<'_> {
    fn entry(&self, b: u32) -> Entry {
        let node = &self.bin[b as usize];
        if !node.leaf {
            return Entry::Inner(b);
        }
        debug_assert_eq!(node.b, 1);
        Entry::Leaf(self.drafts[self.refs[node.a as usize].id as usize])
    }

    fn bounds(&self, e: &Entry) -> ([f32; 3], [f32; 3]) {
        match e {
            Entry::Inner(b) => (self.bin[*b as usize].lo, self.bin[*b as usize].hi),
            Entry::Leaf(d) => (d.lo, d.hi),
        }
    }

    /// The inner entry to open next: the largest, ties to the tallest (SAH mode: equal boxes,
    /// as of identical triangles, would otherwise open a chain), or the tallest, ties to the
    /// largest (shallow mode); the first of equals.
    fn pick(&self, f: &[Entry]) -> Option<usize> {
        let mut best: Option<(usize, (f64, u32))> = None;
        for (i, e) in f.iter().enumerate() {
            let Entry::Inner(b) = *e else { continue };
            let node = &self.bin[b as usize];
            let (a, h) = (node.area, node.height);
            let better = |(ba, bh): (f64, u32)| match self.mode {
                Mode::Sah => a > ba || (a == ba && h > bh),
                Mode::Shallow => h > bh || (h == bh && a > ba),
            };
            if best.is_none_or(|(_, b)| better(b)) {
                best = Some((i, (a, h)));
            }
        }
        best.map(|(i, _)| i)
    }

    /// Fills `f` (one entry to start with) up to 8 children: opens inner entries, merges groups
    /// that fit one, and opens more into the slots merging freed.
    fn assemble(&self, f: &mut Vec<Entry>) {
        loop {
            while f.len() < CLUSTER_WIDTH {
                let Some(i) = self.pick(f) else { break };
                let Entry::Inner(b) = f[i] else { break };
                let node = &self.bin[b as usize];
                f[i] = self.entry(node.a);
                f.push(self.entry(node.b));
            }
            if !self.params.merge || !self.merge_one(f) {
                break;
            }
        }
    }

    /// Merges the pair of groups that fit one with the smallest joint box, if any.
    fn merge_one(&self, f: &mut Vec<Entry>) -> bool {
        let mut best: Option<(usize, usize, f64)> = None;
        for (i, a) in f.iter().enumerate() {
            let Entry::Leaf(a) = a else { continue };
            for (j, b) in f.iter().enumerate().skip(i + 1) {
                let Entry::Leaf(b) = b else { continue };
                if (a.n + b.n) as usize > GROUP_LANES {
                    continue;
                }
                let area = super::binary::half_area(&min3(&a.lo, &b.lo), &max3(&a.hi, &b.hi));
                if best.is_some_and(|(_, _, ba)| area >= ba) {
                    continue;
                }
                if fits_group(self.vid, a.ids().iter().chain(b.ids()).copied()) {
                    best = Some((i, j, area));
                }
            }
        }
        let Some((i, j, _)) = best else { return false };
        let Entry::Leaf(b) = f.remove(j) else {
            return false;
        };
        if let Entry::Leaf(a) = &mut f[i] {
            a.absorb(b.ids(), &b.lo, &b.hi);
        }
        true
    }
}

fn min3(a: &[f32; 3], b: &[f32; 3]) -> [f32; 3] {
    std::array::from_fn(|k| a[k].min(b[k]))
}

fn max3(a: &[f32; 3], b: &[f32; 3]) -> [f32; 3] {
    std::array::from_fn(|k| a[k].max(b[k]))
}

/// Collapses the binary tree of `inp` and appends its wide nodes and groups to `nodes` and
/// `groups`. `queue` is scratch. [`ClusterError::TooDeep`] if a node would be deeper than
/// `params.max_depth` (the caller then retries in shallow mode); on any error the caller
/// truncates what was appended.
pub(super) fn emit(
    inp: &Input,
    queue: &mut Vec<(u32, u32)>,
    nodes: &mut Vec<ClusterNode>,
    groups: &mut Vec<TriGroup>,
) -> Result<(), ClusterError> {
    let g0 = groups.len();
    let index = |base: u32, local: usize| -> Result<u32, ClusterError> {
        u32::try_from(local)
            .ok()
            .and_then(|l| base.checked_add(l))
            .ok_or(ClusterError::IndexOverflow)
    };
    queue.clear();
    queue.push((0, 0));
    let mut f: Vec<Entry> = Vec::with_capacity(CLUSTER_WIDTH);
    let mut i = 0;
    while i < queue.len() {
        let (b, depth) = queue[i];
        i += 1;
        f.clear();
        f.push(inp.entry(b));
        inp.assemble(&mut f);
        // Inner children first (slots 0..inner_count), then leaves, each in assembly order.
        let mut inner = 0;
        for j in 0..f.len() {
            if let Entry::Inner(_) = f[j] {
                f[inner..=j].rotate_right(1);
                inner += 1;
            }
        }
        let mut node: ClusterNode = bytemuck::Zeroable::zeroed();
        node.child_count = f.len() as u8;
        node.inner_count = inner as u8;
        if inner > 0 {
            if depth as usize + 1 > inp.params.max_depth {
                return Err(ClusterError::TooDeep {
                    cap: inp.params.max_depth,
                });
            }
            node.node_base = index(inp.node_base, queue.len())?;
            index(inp.node_base, queue.len() + inner)?;
        }
        if inner < f.len() {
            node.group_base = index(inp.group_base, groups.len() - g0)?;
            index(inp.group_base, groups.len() - g0 + f.len() - inner)?;
        }
        for e in &f {
            match e {
                Entry::Inner(c) => queue.push((*c, depth + 1)),
                Entry::Leaf(d) => groups.push(make_group(inp.tris, inp.vid, d.ids())),
            }
        }
        quantise(&mut node, f.iter().map(|e| inp.bounds(e)))?;
        nodes.push(node);
    }
    Ok(())
}

/// Sets the grid and the child boxes of `node` (spec §7.1; the one rule of
/// [`crate::physical::wide::quantise`], which the octree's wide nodes use too).
fn quantise(
    node: &mut ClusterNode,
    boxes: impl Iterator<Item = ([f32; 3], [f32; 3])> + Clone,
) -> Result<(), ClusterError> {
    crate::physical::wide::quantise(node, boxes).map_err(|e| ClusterError::Range {
        axis: e.axis,
        lo: e.lo,
        hi: e.hi,
    })
}
