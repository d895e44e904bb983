//! Exact triangle–box overlap by the separating axis theorem.
//!
//! Akenine-Möller, "Fast 3D Triangle-Box Overlap Testing", JGT 6(1), 2001. A triangle and an
//! axis-aligned box are disjoint if and only if one of 13 axes separates them: the box's 3 face
//! normals, the triangle's normal and the 9 cross products of box edges with triangle edges. The
//! test runs in f64 on f32 inputs, so for the coordinates we feed it (f32 vertices mapped into the
//! octree's lattice) its rounding is far below the margin the builder adds to every box.
//!
//! The builder uses this to put a triangle only into the cells it really overlaps, not every cell
//! its bounding box touches (issue 2, item 3).
//!
//! Public for the comparison structures of `oavm-compare` (`crates/oavm-compare`): its uniform
//! grid bins triangles by [`triangle_overlaps_box`] and its KD-tree clips them at its splits by
//! [`clipped_bounds`], the same exact tests as OAVM's builder, so that no structure of the
//! comparison wins or loses by a different overlap test.

/// Whether triangle `tri` overlaps the closed box with centre `c` and half-extents `h`.
pub fn triangle_overlaps_box(tri: &[[f64; 3]; 3], c: [f64; 3], h: [f64; 3]) -> bool {
    // Move the box to the origin.
    let v: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|k| tri[i][k] - c[k]));

    // Box face normals: the triangle's bounding box against the box.
    for k in 0..3 {
        let lo = v[0][k].min(v[1][k]).min(v[2][k]);
        let hi = v[0][k].max(v[1][k]).max(v[2][k]);
        if lo > h[k] || hi < -h[k] {
            return false;
        }
    }

    let e = [sub(v[1], v[0]), sub(v[2], v[1]), sub(v[0], v[2])];

    // Nine edge cross products: axis = unit_k x e_j. Projecting the three vertices onto it, two
    // coincide (the edge's endpoints), so the min/max over all three is exact.
    for ej in &e {
        for k in 0..3 {
            let axis = cross(unit(k), *ej);
            if axis == [0.0; 3] {
                continue; // edge parallel to a box axis: covered by the face normals
            }
            if separated(&v, axis, h) {
                return false;
            }
        }
    }

    // Triangle normal: the plane against the box. From the two shorter edges: the cross
    // product's rounding grows with the lengths of its factors, and for a needle (two corners
    // 1.5e-11 apart at coordinates of 1e6, found by fuzzing) the two long edges' rounding is
    // larger than the short one, so their product points anywhere and the plane "separates"
    // a box the needle passes through.
    let len2 = e.map(|x| dot(x, x));
    let longest = if len2[0] >= len2[1] && len2[0] >= len2[2] {
        0
    } else if len2[1] >= len2[2] {
        1
    } else {
        2
    };
    let n = cross(e[(longest + 1) % 3], e[(longest + 2) % 3]);
    if n != [0.0; 3] {
        let d = dot(n, v[0]);
        let r = h[0] * n[0].abs() + h[1] * n[1].abs() + h[2] * n[2].abs();
        if d > r || d < -r {
            return false;
        }
    }
    true
}

/// Bounding box of the part of triangle `tri` inside the closed box `[lo, hi]`, each
/// coordinate clamped to the box: the triangle is clipped against the box's six planes
/// (Sutherland–Hodgman, f64) and the box of what remains is returned; `None` if nothing
/// remains. Used for the tight bounds of solid leaves, the boxes of a cluster's triangles and
/// the KD-tree's split clipping. A plane that cuts nothing is skipped (most triangles of a
/// leaf cross one or two faces of its cell, if any): clipping a polygon against a plane it lies
/// inside of returns it unchanged, so skipping is exact, bit for bit (a test clips with every
/// plane to check it).
pub fn clipped_bounds(
    tri: &[[f64; 3]; 3],
    lo: [f64; 3],
    hi: [f64; 3],
) -> Option<([f64; 3], [f64; 3])> {
    clip(tri, lo, hi, true)
}

/// [`clipped_bounds`], skipping the planes that cut nothing or not.
fn clip(
    tri: &[[f64; 3]; 3],
    lo: [f64; 3],
    hi: [f64; 3],
    skip_uncut: bool,
) -> Option<([f64; 3], [f64; 3])> {
    // A triangle clipped by 6 planes has at most 9 corners; two buffers, used in turn.
    let mut buf = [[[0.0f64; 3]; 9]; 2];
    buf[0][..3].copy_from_slice(tri);
    let mut cur = 0;
    let mut n = 3;
    for k in 0..3 {
        for (bound, below) in [(lo[k], false), (hi[k], true)] {
            let inside = |p: &[f64; 3]| if below { p[k] <= bound } else { p[k] >= bound };
            if skip_uncut && buf[cur][..n].iter().all(inside) {
                continue;
            }
            let [b0, b1] = &mut buf;
            let (poly, next) = if cur == 0 { (&*b0, b1) } else { (&*b1, b0) };
            let mut m = 0;
            for i in 0..n {
                let (a, b) = (poly[i], poly[if i + 1 == n { 0 } else { i + 1 }]);
                let (ia, ib) = (inside(&a), inside(&b));
                if ia && m < 9 {
                    next[m] = a;
                    m += 1;
                }
                if ia != ib && m < 9 {
                    let t = (bound - a[k]) / (b[k] - a[k]);
                    let mut p: [f64; 3] = std::array::from_fn(|j| a[j] + t * (b[j] - a[j]));
                    p[k] = bound;
                    next[m] = p;
                    m += 1;
                }
            }
            if m == 0 {
                return None;
            }
            cur = 1 - cur;
            n = m;
        }
    }
    let mut blo = [f64::INFINITY; 3];
    let mut bhi = [f64::NEG_INFINITY; 3];
    for p in &buf[cur][..n] {
        for k in 0..3 {
            blo[k] = blo[k].min(p[k].max(lo[k]));
            bhi[k] = bhi[k].max(p[k].min(hi[k]));
        }
    }
    Some((blo, bhi))
}

/// Whether `axis` separates the triangle `v` from the origin-centred box with half-extents `h`.
#[inline]
fn separated(v: &[[f64; 3]; 3], axis: [f64; 3], h: [f64; 3]) -> bool {
    let p = [dot(axis, v[0]), dot(axis, v[1]), dot(axis, v[2])];
    let lo = p[0].min(p[1]).min(p[2]);
    let hi = p[0].max(p[1]).max(p[2]);
    let r = h[0] * axis[0].abs() + h[1] * axis[1].abs() + h[2] * axis[2].abs();
    lo > r || hi < -r
}

fn unit(k: usize) -> [f64; 3] {
    let mut u = [0.0; 3];
    u[k] = 1.0;
    u
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// The box every box on the way to triangle `v` must contain, in f32: the bounds of the part of
/// the triangle inside the closed box `clip`, rounded outward to f32 and cut to the triangle's
/// own bounds. The part is found by Sutherland–Hodgman clipping in f64
/// (`geom::tribox::clipped_bounds`). A
/// triangle that only touches `clip` (clipping leaves nothing, or rounding leaves an empty box)
/// gets its bounds cut to `clip`, possibly flat; `None` if even those miss `clip` (nothing of it
/// is inside).
///
/// The builder and the cluster checker ([`crate::physical::check_cluster`]) both call this, so the checker sees exactly the builder's
/// boxes; `clip` must be bit for bit the builder's.
pub fn triangle_box(
    v: &[[f32; 3]; 3],
    clip: &([f64; 3], [f64; 3]),
) -> Option<([f32; 3], [f32; 3])> {
    let (tlo, thi) = corner_bounds(v);
    let (lo, hi) = clip;
    // Wholly inside: clipping would give the triangle's own bounds.
    if (0..3).all(|k| tlo[k] as f64 >= lo[k] && thi[k] as f64 <= hi[k]) {
        return Some((tlo, thi));
    }
    let w: [[f64; 3]; 3] = v.map(|p| p.map(f64::from));
    if let Some((a, b)) = clipped_bounds(&w, *lo, *hi) {
        let blo: [f32; 3] = std::array::from_fn(|k| down(a[k]).max(tlo[k]));
        let bhi: [f32; 3] = std::array::from_fn(|k| up(b[k]).min(thi[k]));
        if (0..3).all(|k| blo[k] <= bhi[k]) {
            return Some((blo, bhi));
        }
    }
    let blo: [f32; 3] = std::array::from_fn(|k| tlo[k].max(down(lo[k])));
    let bhi: [f32; 3] = std::array::from_fn(|k| thi[k].min(up(hi[k])));
    (0..3).all(|k| blo[k] <= bhi[k]).then_some((blo, bhi))
}

/// The bounds of a triangle's corners.
pub(crate) fn corner_bounds(v: &[[f32; 3]; 3]) -> ([f32; 3], [f32; 3]) {
    (
        std::array::from_fn(|k| v[0][k].min(v[1][k]).min(v[2][k])),
        std::array::from_fn(|k| v[0][k].max(v[1][k]).max(v[2][k])),
    )
}

/// The largest f32 `<= x`.
pub(crate) fn down(x: f64) -> f32 {
    let f = x as f32;
    if f as f64 > x { f.next_down() } else { f }
}

/// The smallest f32 `>= x`.
pub(crate) fn up(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) < x { f.next_up() } else { f }
}

#[cfg(test)]
mod tests {
    use super::*;

    const C: [f64; 3] = [0.0; 3];
    const H: [f64; 3] = [1.0; 3];

    #[test]
    fn inside_and_outside() {
        let inside = [[0.1, 0.1, 0.1], [0.2, 0.1, 0.1], [0.1, 0.2, 0.1]];
        assert!(triangle_overlaps_box(&inside, C, H));
        let far = [[5.0, 5.0, 5.0], [6.0, 5.0, 5.0], [5.0, 6.0, 5.0]];
        assert!(!triangle_overlaps_box(&far, C, H));
    }

    /// A needle from `pack` fuzzing (two corners 1.5e-11 apart at 1e6): its long edge passes
    /// through the box (the point at s = 0.58 along it is inside), so no axis separates them.
    #[test]
    fn a_needle_through_the_box_overlaps_it() {
        let v = [
            [1005977.1059603341, 1023.0009756097712, 1102925.5704544245],
            [1074556.1996379578, 129331.44318158942, 1000514.644136103],
            [1005977.1059603341, 1023.0009756097561, 1102925.5704544245],
        ];
        let (c, h) = ([917504.0, 131072.0, 917504.0], [131074.0; 3]);
        let p: [f64; 3] = std::array::from_fn(|k| v[0][k] + 0.58 * (v[1][k] - v[0][k]));
        assert!(
            (0..3).all(|k| (p[k] - c[k]).abs() <= h[k]),
            "the witness is inside"
        );
        assert!(triangle_overlaps_box(&v, c, h));
        // The same needle moved clear of the box is still separated.
        let away = v.map(|p| [p[0] + 4e5, p[1], p[2]]);
        assert!(!triangle_overlaps_box(&away, c, h));
    }

    #[test]
    fn bounding_box_overlaps_but_triangle_does_not() {
        // A triangle cutting past the box corner: its bounding box contains the whole box, but
        // its plane x + y + z = 3.5 stays clear of the corner (1, 1, 1) (sum 3).
        let t = [[3.5, 0.0, 0.0], [0.0, 3.5, 0.0], [0.0, 0.0, 3.5]];
        assert!(!triangle_overlaps_box(&t, C, H));
        let t = [[2.9, 0.0, 0.0], [0.0, 2.9, 0.0], [0.0, 0.0, 2.9]];
        assert!(triangle_overlaps_box(&t, C, H));
        // A sliver on the plane x + y = 2.1, passing the box edge at x = y = 1 (sum 2).
        let t = [[-3.0, 5.1, 0.0], [5.1, -3.0, 0.0], [5.1, -3.0, 0.01]];
        assert!(!triangle_overlaps_box(&t, C, H));
        let t = [[-3.0, 4.9, 0.0], [4.9, -3.0, 0.0], [4.9, -3.0, 0.01]];
        assert!(triangle_overlaps_box(&t, C, H));
    }

    #[test]
    fn big_triangle_through_box_and_touching_faces() {
        let t = [[-10.0, -10.0, 0.0], [10.0, -10.0, 0.0], [0.0, 10.0, 0.0]];
        assert!(triangle_overlaps_box(&t, C, H));
        // Touching the face x = 1 counts as overlap (closed boxes).
        let t = [[1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 1.0, 0.0]];
        assert!(triangle_overlaps_box(&t, C, H));
    }

    #[test]
    fn degenerate_triangles() {
        let seg_in = [[0.0, 0.0, 0.0], [0.5, 0.5, 0.5], [0.5, 0.5, 0.5]];
        assert!(triangle_overlaps_box(&seg_in, C, H));
        let point_out = [[1.5, 0.0, 0.0]; 3];
        assert!(!triangle_overlaps_box(&point_out, C, H));
    }

    #[test]
    fn clipping_gives_the_box_of_the_inside_part() {
        // A big triangle in the plane z = 0.5 covering the unit box's cross-section.
        let t = [[-5.0, -5.0, 0.5], [5.0, -5.0, 0.5], [0.0, 5.0, 0.5]];
        let (lo, hi) = clipped_bounds(&t, [0.0; 3], [1.0; 3]).unwrap();
        assert_eq!((lo, hi), ([0.0, 0.0, 0.5], [1.0, 1.0, 0.5]));
        // A diagonal sliver through one corner region only.
        let t = [[0.0, 0.0, 0.1], [0.2, 0.0, 0.1], [0.0, 0.2, 0.1]];
        let (lo, hi) = clipped_bounds(&t, [0.0; 3], [1.0; 3]).unwrap();
        assert_eq!((lo, hi), ([0.0, 0.0, 0.1], [0.2, 0.2, 0.1]));
        let far = [[5.0, 5.0, 5.0], [6.0, 5.0, 5.0], [5.0, 6.0, 5.0]];
        assert!(clipped_bounds(&far, [0.0; 3], [1.0; 3]).is_none());
    }

    /// Skipping the planes that cut nothing gives the bounds of clipping by all six, bit for
    /// bit, on random triangles around a box (most cut by some planes, some by none).
    #[test]
    fn skipping_uncut_planes_is_exact() {
        let mut s = 0x2545_f491_4f6c_dd1d_u64;
        let mut rnd = |lo: f64, hi: f64| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            lo + (s >> 11) as f64 / (1u64 << 53) as f64 * (hi - lo)
        };
        let (lo, hi) = ([0.0, -1.0, 2.0], [1.0, 0.5, 2.25]);
        let mut clipped = 0;
        for _ in 0..20_000 {
            let t: [[f64; 3]; 3] =
                std::array::from_fn(|_| std::array::from_fn(|k| rnd(lo[k] - 1.0, hi[k] + 1.0)));
            let fast = clip(&t, lo, hi, true);
            assert_eq!(fast, clip(&t, lo, hi, false), "{t:?}");
            clipped += fast.is_some() as u32;
        }
        assert!(clipped > 1000);
    }

    /// Sampled check against a dense point-sampling of the triangle: a sample inside the box
    /// implies overlap (the converse is only approximate, so it is checked with a margin).
    #[test]
    fn agrees_with_sampling() {
        let mut s = 0x9e37_79b9_7f4a_7c15_u64;
        let mut rnd = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 * 6.0 - 3.0
        };
        for _ in 0..2000 {
            let t: [[f64; 3]; 3] = std::array::from_fn(|_| std::array::from_fn(|_| rnd()));
            let mut any_inside = false;
            let mut any_near = false;
            let n = 60;
            for i in 0..=n {
                for j in 0..=(n - i) {
                    let (a, b) = (i as f64 / n as f64, j as f64 / n as f64);
                    let p: [f64; 3] = std::array::from_fn(|k| {
                        t[0][k] + a * (t[1][k] - t[0][k]) + b * (t[2][k] - t[0][k])
                    });
                    let m = p.iter().map(|x| x.abs()).fold(0.0, f64::max);
                    any_inside |= m <= 1.0;
                    any_near |= m <= 1.2;
                }
            }
            let o = triangle_overlaps_box(&t, C, H);
            if any_inside {
                assert!(o, "sampled point inside but no overlap: {t:?}");
            }
            if o {
                assert!(
                    any_near,
                    "overlap claimed but no sample near the box: {t:?}"
                );
            }
        }
    }
}
