//! The rank directory (format-spec §4.3): built here, by the builder's layout and block split,
//! and queried here, by [`super::TreeMap`]'s child steps and by the builder.
//!
//! One [`RankWord`] per 64 nodes of a level holds a bitmap of which nodes are internal and the
//! count of internal nodes before it:
//!
//! ```text
//!   rank(i) = word.rank + popcount(word.internal & ((1 << (i % 64)) - 1)),   word = ranks[i / 64]
//! ```

use crate::physical::format::RankWord;

/// The rank words of one level whose nodes are internal or not as `internal` says, in order;
/// and the number of internal nodes.
pub fn rank_words(internal: impl IntoIterator<Item = bool>) -> (Vec<RankWord>, u64) {
    let mut words = Vec::new();
    let (mut bits, mut n, mut rank) = (0u64, 0u32, 0u64);
    for is_internal in internal {
        bits |= (is_internal as u64) << n;
        n += 1;
        if n == 64 {
            words.push(RankWord {
                internal: bits,
                rank,
            });
            rank += bits.count_ones() as u64;
            (bits, n) = (0, 0);
        }
    }
    if n > 0 {
        words.push(RankWord {
            internal: bits,
            rank,
        });
        rank += bits.count_ones() as u64;
    }
    (words, rank)
}

/// Position of internal node `i` among its level's internal nodes, from the level's rank words
/// (which must cover `i`: a builder's own, or checked).
#[inline]
pub fn rank(ranks: &[RankWord], i: usize) -> usize {
    let w = &ranks[i / 64];
    w.rank as usize + (w.internal & ((1u64 << (i % 64)) - 1)).count_ones() as usize
}

/// `8 * rank + octant` for the internal node at bit `bit` of `word`: checked, since a corrupt
/// rank word can hold any value (`None` on overflow, which no valid file reaches).
#[inline(always)]
pub(super) fn child_index(word: &RankWord, bit: u64, octant: u32) -> Option<u64> {
    let rank = word
        .rank
        .checked_add((word.internal & ((1u64 << bit) - 1)).count_ones() as u64)?;
    rank.checked_mul(8)?.checked_add(octant as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn words_count_the_internal_nodes_before_them() {
        let kinds: Vec<bool> = (0..150).map(|i| i % 3 == 0).collect();
        let (words, internal) = rank_words(kinds.iter().copied());
        assert_eq!(words.len(), 3);
        assert_eq!(internal, 50);
        let mut seen = 0;
        for (i, &k) in kinds.iter().enumerate() {
            if k {
                assert_eq!(rank(&words, i), seen);
                seen += 1;
            }
        }
        assert_eq!(
            words[2].internal >> 22,
            0,
            "bits past the level's end are 0"
        );
        assert_eq!(rank_words(std::iter::empty()), (Vec::new(), 0));
    }
}
