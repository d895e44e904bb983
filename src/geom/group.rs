//! The watertight ray–triangle test on a triangle group: up to eight triangles at once.
//!
//! A group (format 4's `TriGroup` record) stores up to eight distinct corners as three rows of
//! eight coordinates, and for each of its up to eight lanes the slots of its triangle's three
//! corners. The per-ray work of the watertight test (Woop, Benthin and Wald, JCGT 2013, §3:
//! the corners relative to the origin, sheared so that the ray runs along +z) depends on a
//! corner only, not on the triangle, so it is done once per distinct corner, eight at once,
//! instead of three times per triangle. The sheared corners are then permuted into lanes (one
//! `vpermps` per value and corner under AVX2; two `pshufb` and a blend per half under SSE),
//! and the edge functions, their signs and `t` are computed for the eight lanes.
//!
//! Every lane's answer is bit for bit that of [`RayShear::intersect`] on the lane's triangle:
//! each value goes through the same IEEE operations in the same order as there (a corner's
//! sheared coordinates are the same values whichever lane reads them; no fused multiply-add),
//! and the two rare rules are the scalar test's own code, out of line: the f64 recompute of
//! edge functions that are exactly 0 (paper §4.2), for the lanes that have one, and the
//! origin-on-triangle rule of `RAYS.md` for lanes inside with `t` just below 0. Lanes at or
//! past the group's `count` never hit and never reach either rule. When no lane is inside (the
//! common case), the test returns before it computes `t`, so the division is only paid for
//! groups the ray passes through.
//!
//! The kernel is written once, over [`Simd8`] (`os::simd`), and runs as SSE (two halves, the
//! portable build's x86-64-v2), as AVX2 through a token ([`Avx2`]), or on eight scalars
//! ([`Portable`], builds without SSE4.1). [`RayShear::intersect_group_scalar`] is the
//! reference they all equal: the scalar test lane by lane.
//!
//! The kernel takes a [`TriGroupView`], the record's fields borrowed, rather than the record:
//! `geom` is below `physical` in the module stack (`docs/architecture.md`).

#[cfg(not(all(target_arch = "x86_64", target_feature = "sse4.1")))]
use crate::os::Portable;
#[cfg(all(target_arch = "x86_64", target_feature = "sse4.1"))]
use crate::os::Sse41;
use crate::os::{Avx2, Simd8, WithAvx2};

use super::triangle::{RayShear, narrow, origin_on_triangle};

/// A triangle group as the kernels read it: the fields of format 4's `TriGroup` record
/// (`physical::format`, spec §7.2), borrowed: `TriGroupView { corner: &g.corner, tri: &g.tri,
/// count: g.count }`.
#[derive(Clone, Copy, Debug)]
pub struct TriGroupView<'a> {
    /// `corner[k][j]`: coordinate `k` of distinct corner `j`.
    pub corner: &'a [[f32; 8]; 3],
    /// `tri[c][l]`: the slot of corner `c` of lane `l`'s triangle; read as `& 7`.
    pub tri: &'a [[u8; 8]; 3],
    /// Lanes in use; lanes `count..8` never hit (any value: above 8 counts as 8).
    pub count: u32,
}

impl TriGroupView<'_> {
    /// The corners of lane `l`'s triangle (`l < 8`), as `TriGroup::triangle` gives them.
    #[inline(always)]
    pub fn triangle(&self, l: usize) -> [[f32; 3]; 3] {
        std::array::from_fn(|c| {
            let j = (self.tri[c][l & 7] & 7) as usize;
            [self.corner[0][j], self.corner[1][j], self.corner[2][j]]
        })
    }

    /// The lanes in use, bit `l` for lane `l`.
    #[inline(always)]
    pub fn live(&self) -> u32 {
        (1u32 << self.count.min(8)) - 1
    }
}

/// The `t` the group tests report for a lane that does not hit.
const MISS_T: f32 = f32::INFINITY;

impl RayShear {
    /// The watertight test on the live lanes of group `g`: bit `l` of the mask is set when lane
    /// `l`'s triangle is hit with `tmin <= t <= tmax`, and `t[l]` is that `t` (`+inf` for lanes
    /// that miss). Bit for bit [`RayShear::intersect`] on each lane.
    ///
    /// SSE (two halves of four lanes) in builds for SSE4.1, such as the portable build;
    /// elsewhere the same kernel on eight scalars.
    #[inline(always)]
    pub fn intersect_group(&self, g: TriGroupView<'_>, tmin: f32, tmax: f32) -> (u32, [f32; 8]) {
        #[cfg(all(target_arch = "x86_64", target_feature = "sse4.1"))]
        let isa = Sse41::new();
        #[cfg(not(all(target_arch = "x86_64", target_feature = "sse4.1")))]
        let isa = Portable;
        self.group_kernel(isa, g, tmin, tmax)
    }

    /// [`RayShear::intersect_group`] on any instruction set: for code that runs inside
    /// [`Avx2::vectorize`] (a tracer's traversal), where it inlines whole.
    #[inline(always)]
    pub fn intersect_group_with<S: Simd8>(
        &self,
        isa: S,
        g: TriGroupView<'_>,
        tmin: f32,
        tmax: f32,
    ) -> (u32, [f32; 8]) {
        self.group_kernel(isa, g, tmin, tmax)
    }

    /// [`RayShear::intersect_group`] with the eight lanes in one AVX2 register. A call from
    /// ordinary code goes through the trampoline of [`Avx2::vectorize`] (one call, which LLVM
    /// does not inline even from inside another `vectorize`: there, use
    /// [`RayShear::intersect_group_with`]).
    #[inline(always)]
    pub fn intersect_group_avx2(
        &self,
        isa: Avx2,
        g: TriGroupView<'_>,
        tmin: f32,
        tmax: f32,
    ) -> (u32, [f32; 8]) {
        struct Job<'a> {
            shear: &'a RayShear,
            g: TriGroupView<'a>,
            tmin: f32,
            tmax: f32,
        }
        impl WithAvx2 for Job<'_> {
            type Output = (u32, [f32; 8]);
            #[inline(always)]
            fn run(self, isa: Avx2) -> Self::Output {
                #[cfg(target_arch = "x86_64")]
                return self.shear.group_kernel(isa, self.g, self.tmin, self.tmax);
                // No token exists on other architectures: never reached.
                #[cfg(not(target_arch = "x86_64"))]
                return {
                    let _ = isa;
                    self.shear
                        .intersect_group_scalar(self.g, self.tmin, self.tmax)
                };
            }
        }
        isa.vectorize(Job {
            shear: self,
            g,
            tmin,
            tmax,
        })
    }

    /// The reference: [`RayShear::intersect`] on each live lane's triangle, with the answers
    /// of [`RayShear::intersect_group`].
    pub fn intersect_group_scalar(
        &self,
        g: TriGroupView<'_>,
        tmin: f32,
        tmax: f32,
    ) -> (u32, [f32; 8]) {
        let (mut mask, mut ts) = (0, [MISS_T; 8]);
        for l in (0..8).filter(|l| g.live() >> l & 1 == 1) {
            if let Some(t) = self.intersect(&g.triangle(l), tmin, tmax) {
                mask |= 1 << l;
                ts[l] = t;
            }
        }
        (mask, ts)
    }

    /// The kernel, for any [`Simd8`]. Each value is computed as in [`RayShear::intersect`],
    /// whose lines are quoted at each step.
    #[inline(always)]
    fn group_kernel<S: Simd8>(
        &self,
        s: S,
        g: TriGroupView<'_>,
        tmin: f32,
        tmax: f32,
    ) -> (u32, [f32; 8]) {
        let (kx, ky, kz) = (self.kx, self.ky, self.kz);
        if kx > 2 || ky > 2 || kz > 2 {
            return (0, [MISS_T; 8]); // never: lets the compiler drop the bounds checks below
        }
        let o = self.origin;
        // Each distinct corner relative to the origin (`rel`), then sheared:
        // `ax = a[0] - sx * a[2]`, `ay = a[1] - sy * a[2]`, `az = sz * a[2]`.
        let rel = |k: usize| s.sub(s.load(&g.corner[k]), s.splat(o[k]));
        let z = rel(kz);
        let x = s.sub(rel(kx), s.mul(s.splat(self.sx), z));
        let y = s.sub(rel(ky), s.mul(s.splat(self.sy), z));
        let z = s.mul(s.splat(self.sz), z);
        // Into lanes: corner `c` of lane `l` is slot `tri[c][l]`.
        let corner = |c: usize| {
            let i = s.slots(&g.tri[c]);
            (s.permute(x, i), s.permute(y, i), s.permute(z, i))
        };
        let ((ax, ay, az), (bx, by, bz), (cx, cy, cz)) = (corner(0), corner(1), corner(2));

        // `u = cx * by - cy * bx`, `v = ax * cy - ay * cx`, `w = bx * ay - by * ax`.
        let mut u = s.sub(s.mul(cx, by), s.mul(cy, bx));
        let mut v = s.sub(s.mul(ax, cy), s.mul(ay, cx));
        let mut w = s.sub(s.mul(bx, ay), s.mul(by, ax));
        let zero = s.splat(0.0);
        let live = s.lanes_below(g.count);
        // Paper §4.2: lanes with an edge function exactly 0 recompute all three in f64.
        let on_edge = s.or(s.or(s.eq(u, zero), s.eq(v, zero)), s.eq(w, zero));
        let on_edge = s.bits(s.and(live, on_edge));
        if on_edge != 0 {
            let mut uvw = [s.store(u), s.store(v), s.store(w)];
            let edges = [ax, ay, bx, by, cx, cy].map(|e| s.store(e));
            recompute_edges(on_edge, &edges, &mut uvw);
            (u, v, w) = (s.load(&uvw[0]), s.load(&uvw[1]), s.load(&uvw[2]));
        }
        // `all_pos | all_neg`: the edge functions agree in sign. No live lane where they do:
        // no hit, and no need for `t`.
        let all_pos = s.and(s.and(s.ge(u, zero), s.ge(v, zero)), s.ge(w, zero));
        let all_neg = s.and(s.and(s.le(u, zero), s.le(v, zero)), s.le(w, zero));
        let agree = s.and(live, s.or(all_pos, all_neg));
        if s.bits(agree) == 0 {
            return (0, [MISS_T; 8]);
        }
        // `det = u + v + w`, `t_scaled = u * az + v * bz + w * cz`, `t = t_scaled / det`.
        let det = s.add(s.add(u, v), w);
        let t_scaled = s.add(s.add(s.mul(u, az), s.mul(v, bz)), s.mul(w, cz));
        let t = s.div(t_scaled, det);
        // `inside = (all_pos | all_neg) & (det != 0)`; a hit when `lo <= t <= hi` for the
        // range clamped to finite values.
        let inside = s.and(agree, s.ne(det, zero));
        let (lo, hi) = (tmin.max(-f32::MAX), tmax.min(f32::MAX));
        let in_range = s.and(s.ge(t, s.splat(lo)), s.le(t, s.splat(hi)));
        let hit = s.and(inside, in_range);
        let mut mask = s.bits(hit);
        let mut ts = s.store(s.select(hit, t, s.splat(MISS_T)));
        // The origin rule: inside, `t < 0`, `tmin <= 0 <= tmax`, origin on the triangle.
        if tmin <= 0.0 {
            let behind = s.bits(s.and(inside, s.lt(t, zero))) & !mask;
            if behind != 0 {
                origin_rule(g, o, behind, tmax, &mut mask, &mut ts);
            }
        }
        (mask, ts)
    }
}

/// The f64 recompute of [`RayShear::intersect`] for lanes `lanes`: `edges` are the lanes'
/// sheared `ax, ay, bx, by, cx, cy`, `uvw` their `u, v, w`, replaced.
#[cold]
#[inline(never)]
fn recompute_edges(lanes: u32, edges: &[[f32; 8]; 6], uvw: &mut [[f32; 8]; 3]) {
    for l in (0..8).filter(|l| lanes >> l & 1 == 1) {
        let [ax, ay, bx, by, cx, cy] = edges.map(|e| e[l] as f64);
        uvw[0][l] = narrow(cx * by - cy * bx);
        uvw[1][l] = narrow(ax * cy - ay * cx);
        uvw[2][l] = narrow(bx * ay - by * ax);
    }
}

/// The origin rule of [`RayShear::intersect`] for lanes `lanes` (inside, `t < 0`, `tmin <=
/// 0`): a hit at `t = 0` where `tmax >= 0` and origin `o` lies on the lane's triangle.
#[cold]
#[inline(never)]
fn origin_rule(
    g: TriGroupView<'_>,
    o: [f32; 3],
    lanes: u32,
    tmax: f32,
    mask: &mut u32,
    ts: &mut [f32; 8],
) {
    if tmax.is_nan() || tmax < 0.0 {
        return;
    }
    for l in (0..8).filter(|l| lanes >> l & 1 == 1) {
        if origin_on_triangle(&g.triangle(l), o) {
            *mask |= 1 << l;
            ts[l] = 0.0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Ray;
    use crate::os::Portable;

    /// xorshift64*: the tests' random numbers, seeded.
    struct Rng(u64);

    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
        }
        fn below(&mut self, n: u64) -> u64 {
            self.next() % n
        }
        fn chance(&mut self, percent: u64) -> bool {
            self.below(100) < percent
        }
        /// A small multiple of 1/2 in `[-2, 2]`: exact zeros and shared lines are common.
        fn small(&mut self) -> f32 {
            (self.below(9) as f32 - 4.0) * 0.5
        }
    }

    /// A group with its own storage.
    #[derive(Clone, Copy, Debug)]
    struct Group {
        corner: [[f32; 8]; 3],
        tri: [[u8; 8]; 3],
        count: u32,
    }

    impl Group {
        fn view(&self) -> TriGroupView<'_> {
            TriGroupView {
                corner: &self.corner,
                tri: &self.tri,
                count: self.count,
            }
        }
    }

    /// A random group: `distinct` corners of small coordinates (some repeated exactly, some
    /// sharing a line), lanes of three random slots among them (degenerate when two coincide),
    /// `count` in `1..=8`; lanes past `count`, and sometimes the unused slots, garbage. Then,
    /// sometimes, every coordinate scaled far into the subnormals or near overflow, or a few
    /// replaced by such values.
    fn random_group(r: &mut Rng) -> Group {
        let distinct = 1 + r.below(8) as usize;
        let mut corner = [[0.0f32; 8]; 3];
        for j in 0..distinct {
            for row in corner.iter_mut() {
                row[j] = r.small();
            }
            if j > 0 && r.chance(15) {
                let from = r.below(j as u64) as usize;
                let keep = if r.chance(50) { 3 } else { 2 };
                for row in corner.iter_mut().take(keep) {
                    row[j] = row[from];
                }
            }
        }
        if r.chance(20) {
            for row in corner.iter_mut() {
                for c in row.iter_mut().skip(distinct) {
                    *c = f32::from_bits(r.next() as u32);
                }
            }
        }
        let count = 1 + r.below(8) as u32;
        let mut tri = [[0u8; 8]; 3];
        for row in tri.iter_mut() {
            for (l, slot) in row.iter_mut().enumerate() {
                *slot = if l < count as usize {
                    r.below(distinct as u64) as u8 | if r.chance(5) { 0xf8 } else { 0 }
                } else if r.chance(50) {
                    r.next() as u8
                } else {
                    0
                };
            }
        }
        let mut g = Group { corner, tri, count };
        match r.below(10) {
            0 => scale(
                &mut g.corner,
                [-135, -100, -60, 40, 100, 120][r.below(6) as usize],
            ),
            1 => {
                let odd = [
                    f32::from_bits(1),
                    -f32::from_bits(7),
                    1e-38,
                    3e38,
                    -3e38,
                    1e30,
                ];
                for _ in 0..1 + r.below(3) {
                    let (k, j) = (r.below(3) as usize, r.below(8) as usize);
                    g.corner[k][j] = odd[r.below(odd.len() as u64) as usize];
                }
            }
            _ => {}
        }
        g
    }

    fn scale(rows: &mut [[f32; 8]; 3], e: i32) {
        for v in rows.iter_mut().flatten() {
            *v = (*v as f64 * 2f64.powi(e)) as f32;
        }
    }

    /// A ray for group `g`: through a point of one of its triangles (a corner, an edge's
    /// midpoint, a point inside: edges through the ray and exact zeros), starting there (the
    /// origin rule), two directions before it, or anywhere; a small direction, sometimes along
    /// an axis; ranges with `tmin` below, at and above 0.
    fn random_ray(r: &mut Rng, g: &Group) -> Ray {
        let tri = g.view().triangle(r.below(g.count as u64) as usize);
        let point: [f32; 3] = match r.below(3) {
            0 => tri[r.below(3) as usize],
            _ => {
                // Weights in quarters (exact for coordinates that are multiples of 1/2).
                let w = match r.below(3) {
                    0 => [2.0, 2.0, 0.0],
                    1 => [1.0, 1.0, 2.0],
                    _ => [1.0, 2.0, 1.0],
                };
                std::array::from_fn(|k| {
                    (w[0] * tri[0][k] + w[1] * tri[1][k] + w[2] * tri[2][k]) * 0.25
                })
            }
        };
        let mut dir = [r.small(), r.small(), r.small()];
        if r.chance(20) {
            dir = [0.0; 3];
            dir[r.below(3) as usize] = if r.chance(50) { 1.0 } else { -3.0 };
        }
        if dir == [0.0; 3] {
            dir[2] = -1.0;
        }
        if r.chance(10) {
            dir = dir.map(|d| d + (r.below(1000) as f32 - 500.0) * 1e-3);
        }
        let origin = match r.below(5) {
            0 | 1 => point,
            2 | 3 => std::array::from_fn(|k| point[k] - 2.0 * dir[k]),
            _ => [r.small(), r.small(), r.small() + 2.0],
        };
        let (tmin, tmax) = match r.below(6) {
            0 => (0.0, f32::INFINITY),
            1 => (-1.0, f32::INFINITY),
            2 => (-0.0, 0.0),
            3 => (0.5, 3.0),
            4 => (-f32::INFINITY, 2.0),
            _ => (r.small(), r.small() + 1.0),
        };
        Ray::new(origin, dir, tmin, tmax)
    }

    fn same(a: (u32, [f32; 8]), b: (u32, [f32; 8])) -> bool {
        a.0 == b.0 && a.1.map(f32::to_bits) == b.1.map(f32::to_bits)
    }

    /// The SSE, AVX2 and portable kernels give every lane bit for bit the scalar test's answer.
    #[test]
    fn kernels_equal_the_scalar_test_lane_by_lane() {
        let avx2 = Avx2::detect();
        if avx2.is_none() {
            eprintln!("AVX2 kernel skipped: this CPU has no AVX2 and FMA");
        }
        let mut r = Rng(0x5eed_1234_abcd_0001);
        let (mut hits, mut at_zero, mut empty) = (0u64, 0u64, 0u64);
        for case in 0..200_000 {
            let g = random_group(&mut r);
            let ray = random_ray(&mut r, &g);
            if !ray.is_valid() {
                continue;
            }
            let sh = RayShear::new(&ray);
            let want = sh.intersect_group_scalar(g.view(), ray.tmin, ray.tmax);
            let got = [
                ("default", sh.intersect_group(g.view(), ray.tmin, ray.tmax)),
                (
                    "portable",
                    sh.group_kernel(Portable, g.view(), ray.tmin, ray.tmax),
                ),
            ];
            for (name, got) in got {
                assert!(
                    same(got, want),
                    "{name}, case {case}: {got:?} vs {want:?}\n{g:?}\n{ray:?}"
                );
            }
            if let Some(isa) = avx2 {
                let got = sh.intersect_group_avx2(isa, g.view(), ray.tmin, ray.tmax);
                assert!(
                    same(got, want),
                    "avx2, case {case}: {got:?} vs {want:?}\n{g:?}\n{ray:?}"
                );
            }
            hits += want.0.count_ones() as u64;
            at_zero += (0..8)
                .filter(|&l| want.0 >> l & 1 == 1 && want.1[l] == 0.0)
                .count() as u64;
            empty += (want.0 == 0) as u64;
        }
        eprintln!("{hits} lane hits ({at_zero} at t = 0), {empty} groups missed");
        assert!(
            hits > 50_000 && at_zero > 10_000 && empty > 10_000,
            "the cases cover too little"
        );
    }

    /// Lanes at or past `count` never hit, whatever their slots and corners hold, even where
    /// the ray passes through their triangles or starts on them.
    #[test]
    fn lanes_past_count_never_hit() {
        let mut r = Rng(77);
        // Slot 0..3: a big triangle around the ray's path (z = 0) and one containing the
        // origin; slots 4..8 garbage.
        let mut corner = [[0.0f32; 8]; 3];
        let big = [[-4.0, -4.0, 0.0], [4.0, -4.0, 0.0], [0.0, 4.0, 0.0]];
        for (j, p) in big.iter().enumerate() {
            for k in 0..3 {
                corner[k][j] = p[k];
            }
        }
        let avx2 = Avx2::detect();
        for _ in 0..20_000 {
            for row in corner.iter_mut() {
                for c in row.iter_mut().skip(3) {
                    *c = match r.below(4) {
                        0 => f32::from_bits(r.next() as u32),
                        1 => 0.0,
                        _ => r.small(),
                    };
                }
            }
            let count = r.below(9) as u32;
            let mut tri = [[0u8; 8]; 3];
            for (c, row) in tri.iter_mut().enumerate() {
                for (l, s) in row.iter_mut().enumerate() {
                    *s = if l < count as usize || r.chance(50) {
                        c as u8
                    } else {
                        r.next() as u8
                    };
                }
            }
            let g = Group { corner, tri, count };
            let live = g.view().live();
            // From above, and from a point on the plane (origin rule) with tmin <= 0.
            for ray in [
                Ray::new([0.5, 0.25, 2.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY),
                Ray::new([0.5, 0.25, 0.0], [0.3, 0.1, 1.0], -1.0, 1.0),
            ] {
                let sh = RayShear::new(&ray);
                let mut answers = vec![sh.intersect_group(g.view(), ray.tmin, ray.tmax)];
                if let Some(isa) = avx2 {
                    answers.push(sh.intersect_group_avx2(isa, g.view(), ray.tmin, ray.tmax));
                }
                for (mask, ts) in answers {
                    assert_eq!(mask & !live, 0, "{g:?}");
                    assert_eq!(mask & live, live & 0xff, "the live lanes all hit: {g:?}");
                    assert!((0..8).all(|l| live >> l & 1 == 1 || ts[l] == MISS_T));
                }
            }
        }
        let g = Group {
            corner,
            tri: [[0, 0, 0, 0, 0, 0, 0, 0], [1; 8], [2; 8]],
            count: u32::MAX,
        };
        let sh = RayShear::new(&Ray::new([0.5, 0.25, 2.0], [0.0, 0.0, -1.0], 0.0, 9.0));
        assert_eq!(
            sh.intersect_group(g.view(), 0.0, 9.0).0,
            0xff,
            "a count above 8 is 8"
        );
    }
}
