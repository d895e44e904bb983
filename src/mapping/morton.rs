//! Morton (Z-order) codes and the arithmetic on them (OAVM paper §2.4).
//!
//! A node at level `L` covers a cube of the lattice of `2^LATTICE_BITS` cells per axis; its
//! Morton code interleaves the `L` high bits of its integer coordinates, x lowest:
//!
//! ```text
//!   coordinates (L = 3):  x = x2 x1 x0    y = y2 y1 y0    z = z2 z1 z0
//!   code:                 z2 y2 x2 | z1 y1 x1 | z0 y0 x0      (3 bits per level, root first)
//! ```
//!
//! The low three bits of a code are the node's *octant* within its parent
//! (`x | y << 1 | z << 2`), the parent's code is `code >> 3` and child `o` of `code` is
//! `code << 3 | o`.
//!
//! **Neighbours.** The paper steps to a face neighbour with `N' = N + 4α + 2β + γ`
//! (α, β, γ ∈ {-1, 0, 1}). That is only right while the step stays inside one parent: adding
//! to the interleaved code lets a carry from one axis' bit ripple into another axis' bit
//! ([`paper_neighbour`] exists to show it, in the tests). We instead add on *dilated integers*
//! (Tocher 1954; Wise & Franco 1990): with every bit not belonging to the axis set to one, a
//! carry skips over the other axes' bits and lands on the next bit of the same axis:
//!
//! ```text
//!   x + 1:  ((code | !XMASK) + 1) & XMASK  |  code & !XMASK
//!   x - 1:  ((code & XMASK) - 1) & XMASK   |  code & !XMASK
//! ```

pub use crate::physical::format::{LATTICE_BITS, LATTICE_SIZE, MAX_LEVEL};

/// The x bits of a code: bit 0, 3, 6, ... (`001` repeated; 21 times for 63 bits).
const XMASK: u64 = 0x1249_2492_4924_9249;

/// Spreads the low 21 bits of `v` so that bit `i` moves to bit `3 i`.
///
/// Each step halves the run length, moving runs apart by shifting copies into the gaps:
///
/// ```text
///   ............................................ ....... ....ddddd cccccccc bbbbbbbb aaaaaaaa  (21 bits)
///   after << 32, mask 0x1f00000000ffff:  ddddd (bits 32..36) | ccccccccbbbbbbbbaaaaaaaa low 16 (+c)
///   after << 16, mask 0x1f0000ff0000ff:  runs of 8 bits, 24 apart
///   after <<  8, mask 0x100f00f00f00f00f: runs of 4 bits, 12 apart
///   after <<  4, mask 0x10c30c30c30c30c3: runs of 2 bits, 6 apart
///   after <<  2, mask 0x1249249249249249: single bits, 3 apart
/// ```
#[inline]
pub fn spread(v: u32) -> u64 {
    let mut x = (v & (LATTICE_SIZE - 1)) as u64;
    x = (x | x << 32) & 0x001f_0000_0000_ffff;
    x = (x | x << 16) & 0x001f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    x = (x | x << 2) & XMASK;
    x
}

/// Inverse of [`spread`]: gathers bits `0, 3, 6, ...` of `x` into the low 21 bits.
#[inline]
pub fn compact(x: u64) -> u32 {
    let mut x = x & XMASK;
    x = (x | x >> 2) & 0x10c3_0c30_c30c_30c3;
    x = (x | x >> 4) & 0x100f_00f0_0f00_f00f;
    x = (x | x >> 8) & 0x001f_0000_ff00_00ff;
    x = (x | x >> 16) & 0x001f_0000_0000_ffff;
    x = (x | x >> 32) & 0x1f_ffff;
    x as u32
}

/// The code of the point with coordinates `c` (each `< 2^21`) on the full lattice.
#[inline]
pub fn encode(c: [u32; 3]) -> u64 {
    spread(c[0]) | spread(c[1]) << 1 | spread(c[2]) << 2
}

/// Inverse of [`encode`].
#[inline]
pub fn decode(code: u64) -> [u32; 3] {
    [compact(code), compact(code >> 1), compact(code >> 2)]
}

/// The code at `level` of the node containing lattice point `q`.
#[inline]
pub fn code_at_level(q: [u32; 3], level: u32) -> u64 {
    debug_assert!(level <= MAX_LEVEL);
    encode(q) >> (3 * (MAX_LEVEL - level))
}

/// The octant (child slot, `x | y << 1 | z << 2`) that lattice point `q` falls into when a node
/// of level `level - 1` is split into its children of level `level` (`1 <= level <= 21`).
#[inline]
pub fn octant_of_point(q: [u32; 3], level: u32) -> u32 {
    let p = MAX_LEVEL - level;
    ((q[0] >> p) & 1) | ((q[1] >> p) & 1) << 1 | ((q[2] >> p) & 1) << 2
}

/// Lowest lattice corner of node `code` at `level`.
#[inline]
pub fn cell_origin(code: u64, level: u32) -> [u32; 3] {
    let c = decode(code);
    let s = MAX_LEVEL - level;
    [c[0] << s, c[1] << s, c[2] << s]
}

/// Edge length, in lattice cells, of a node at `level`.
#[inline]
pub fn cell_size(level: u32) -> u32 {
    1 << (MAX_LEVEL - level)
}

/// The deepest level whose node containing `a` also contains `b`: the level of their lowest
/// common ancestor, from the highest bit in which their coordinates differ.
#[inline]
pub fn common_level(a: [u32; 3], b: [u32; 3]) -> u32 {
    let diff = (a[0] ^ b[0]) | (a[1] ^ b[1]) | (a[2] ^ b[2]);
    if diff == 0 {
        MAX_LEVEL
    } else {
        // Highest differing bit h: nodes of level l share bits h' >= 21 - l, so l <= 20 - h.
        let h = 31 - diff.leading_zeros();
        MAX_LEVEL - 1 - h
    }
}

/// Face neighbour of node `code` at `level` along `axis` (0 = x, 1 = y, 2 = z), in direction
/// `+1` (`positive`) or `-1`, or `None` where it would leave the root. Correct across parent
/// boundaries (dilated-integer arithmetic, see the module documentation).
#[inline]
pub fn neighbour(code: u64, level: u32, axis: u32, positive: bool) -> Option<u64> {
    debug_assert!(level <= MAX_LEVEL && axis < 3);
    let bits = 3 * level;
    let level_mask = if bits == 64 {
        u64::MAX
    } else {
        (1u64 << bits) - 1
    };
    let axis_mask = (XMASK << axis) & level_mask;
    let coord = code & axis_mask;
    let rest = code & !axis_mask;
    if positive {
        if coord == axis_mask {
            return None; // at the far face of the root
        }
        Some((((code | !axis_mask).wrapping_add(1)) & axis_mask) | rest)
    } else {
        if coord == 0 {
            return None; // at the near face of the root
        }
        Some((coord.wrapping_sub(1) & axis_mask) | rest)
    }
}

/// The paper's neighbour formula `N' = N + 4α + 2β + γ` with α, β, γ the steps along x, y, z,
/// translated to our bit order (x lowest, so x weighs 1, y 2, z 4). Only correct inside one
/// parent; kept to show, in tests, where it fails. Not used by the tracer.
pub fn paper_neighbour(code: u64, step: [i64; 3]) -> u64 {
    (code as i64 + step[0] + 2 * step[1] + 4 * step[2]) as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encode_decode_round_trip_and_bit_order() {
        assert_eq!(encode([1, 0, 0]), 0b001);
        assert_eq!(encode([0, 1, 0]), 0b010);
        assert_eq!(encode([0, 0, 1]), 0b100);
        assert_eq!(encode([2, 0, 0]), 0b001_000);
        let max = LATTICE_SIZE - 1;
        assert_eq!(encode([max, max, max]), (1u64 << 63) - 1);
        let mut s = 12345u64;
        for _ in 0..10_000 {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let c = [
                (s >> 1) as u32 & max,
                (s >> 22) as u32 & max,
                (s >> 43) as u32 & max,
            ];
            assert_eq!(decode(encode(c)), c);
        }
    }

    /// Every node of levels 1..=4 (4,680 nodes), every face direction, against the answer
    /// computed on plain coordinates.
    #[test]
    fn neighbours_exhaustive_on_small_grids() {
        for level in 1..=4u32 {
            let n = 1u32 << level;
            for x in 0..n {
                for y in 0..n {
                    for z in 0..n {
                        let c = [x, y, z];
                        let code = code_at_level(c.map(|v| v << (MAX_LEVEL - level)), level);
                        for axis in 0..3 {
                            for positive in [false, true] {
                                let mut d = c.map(|v| v as i64);
                                d[axis] += if positive { 1 } else { -1 };
                                let expected = (d[axis] >= 0 && d[axis] < n as i64).then(|| {
                                    let q = d.map(|v| (v as u32) << (MAX_LEVEL - level));
                                    code_at_level(q, level)
                                });
                                assert_eq!(
                                    neighbour(code, level, axis as u32, positive),
                                    expected,
                                    "level {level} cell {c:?} axis {axis} positive {positive}"
                                );
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn neighbours_at_the_deepest_level() {
        let max = LATTICE_SIZE - 1;
        let code = encode([max, 5, 0]);
        assert_eq!(neighbour(code, MAX_LEVEL, 0, true), None);
        assert_eq!(neighbour(code, MAX_LEVEL, 2, false), None);
        assert_eq!(
            neighbour(code, MAX_LEVEL, 1, true),
            Some(encode([max, 6, 0]))
        );
        assert_eq!(
            neighbour(code, MAX_LEVEL, 0, false),
            Some(encode([max - 1, 5, 0]))
        );
    }

    /// The paper's formula agrees inside a parent and disagrees across a parent boundary.
    #[test]
    fn paper_formula_fails_across_parents() {
        let level = 2;
        let at = |c: [u32; 3]| code_at_level(c.map(|v| v << (MAX_LEVEL - level)), level);
        // Inside one parent: (0,0,0) -> (1,0,0).
        assert_eq!(paper_neighbour(at([0, 0, 0]), [1, 0, 0]), at([1, 0, 0]));
        // Across a parent boundary: (1,0,0) -> (2,0,0). The formula gives code 2, which is
        // (0,1,0): a cell on the other side of the parent.
        let wrong = paper_neighbour(at([1, 0, 0]), [1, 0, 0]);
        assert_ne!(wrong, at([2, 0, 0]));
        assert_eq!(wrong, at([0, 1, 0]));
        assert_eq!(
            neighbour(at([1, 0, 0]), level, 0, true),
            Some(at([2, 0, 0]))
        );
    }

    #[test]
    fn common_level_of_points() {
        assert_eq!(common_level([0, 0, 0], [0, 0, 0]), MAX_LEVEL);
        // Differ in the top bit: only the root contains both.
        assert_eq!(common_level([0, 0, 0], [1 << 20, 0, 0]), 0);
        // Differ in bit 0 only: they share every level above the deepest.
        assert_eq!(common_level([4, 4, 4], [5, 4, 4]), MAX_LEVEL - 1);
        assert_eq!(octant_of_point([1 << 20, 0, 1 << 20], 1), 0b101);
    }
}
