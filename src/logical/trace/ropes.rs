//! Ropes (spec §8.4; the threaded KD-tree of Jiao, Chen and Zhang, on the octree): the
//! leaf-to-leaf walk of [`super::neighbours`] takes its next leaf from the node the rope of the
//! exit face names, instead of from the lowest common ancestor of the two cells
//! ([`super::Walk::Ropes`]). The answers are the same.

use super::neighbours::{Leaf, WalkState};
use super::ray::RayCtx;
use super::{Counters, Held, Tree};
use crate::physical::format::ROPE_TOP;

impl Tree<'_> {
    /// After a step out of `leaf` across a face perpendicular to `axis`: the
    /// walk descends next from the node the exit face's rope names, the smallest node holding
    /// every cell just across it (`w.q` among them); from the root where there is no rope (a
    /// block without them) or one that names no node.
    #[inline(always)]
    pub(super) fn rope_step(
        &self,
        r: &RayCtx,
        w: &mut WalkState,
        held: Option<&Held<'_>>,
        leaf: &Leaf,
        axis: usize,
        k: &mut Counters,
    ) {
        let (level, block) = (leaf.level, leaf.block);
        let face = 2 * axis + r.fwd[axis] as usize;
        let (map, ropes, at) = match (block, held) {
            (Some(_), Some(h)) => (&h.map, h.ropes, w.bpath[(level & 31) as usize]),
            _ => (&self.top, self.top_ropes, w.tpath[(level & 31) as usize]),
        };
        let rope = ropes
            .get((map.node_start(level) + at) as usize)
            .map(|r| r.across[face]);
        if let Some(rope) = rope
            && self.take_rope(rope, level, block.is_some(), held, w)
        {
            k.ropes_followed += 1;
            return;
        }
        w.level = 0;
        w.cur = None;
    }

    /// Moves the walk to the node `rope` names (spec §8.4), from a leaf at `level`
    /// (`in_block`: of the block `held`): its level is found from its record index, at or
    /// above `level`. `false` if the rope names no node of the unit it must be in (bytes that
    /// break the format: the walk then starts again from the root, and stays bounded either
    /// way, since every box is built around the walk's cell whatever node it starts from).
    #[inline(always)]
    fn take_rope(
        &self,
        rope: u32,
        level: u32,
        in_block: bool,
        held: Option<&Held<'_>>,
        w: &mut WalkState,
    ) -> bool {
        let (map, index) = if rope & ROPE_TOP != 0 {
            (&self.top, (rope & !ROPE_TOP) as u64)
        } else if in_block && let Some(h) = held {
            (&h.map, rope as u64)
        } else {
            return false;
        };
        let base = map.base();
        let mut l = level.min(base + map.level_count().saturating_sub(1));
        while l > base && map.node_start(l) > index {
            l -= 1;
        }
        let Some(e) = map.levels().get((l - base) as usize) else {
            return false;
        };
        let local = index.wrapping_sub(e.node_start);
        if index < e.node_start || local >= e.node_count {
            return false;
        }
        if rope & ROPE_TOP != 0 {
            w.cur = None;
            w.tpath[(l & 31) as usize] = local;
        } else {
            w.bpath[(l & 31) as usize] = local;
        }
        w.level = l;
        true
    }
}
