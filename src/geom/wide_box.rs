//! The ray–box test on a cluster node's eight children at once, conservative: it never misses
//! a child box that the segment `[tmin, tmax]` of the ray meets.
//!
//! A node (format 4's `ClusterNode` record) stores, per axis, a grid (an origin and a step
//! `2^exp`) and each child's lowest and highest face on it as 8-bit grid coordinates, in rows
//! of eight. A face is `origin + q * 2^exp`: the product scales a small integer by a power of
//! two and the sum is exact by the spec's construction (the origin is a multiple of the step,
//! less than `2^24` steps from 0), so a face is two IEEE operations that round nothing, and is
//! the same value in every lane layout.
//!
//! The test is the slab test (Kay and Kajiya 1986) with the direction's sign chosen once per
//! ray (Williams, Barrus, Morley and Shirley, "An Efficient and Robust Ray–Box Intersection
//! Algorithm", JGT 2005): along an axis the ray enters a slab at the face on its side and
//! leaves at the other, `t = (face - o) * inv` with `inv = 1 / d`, so which face is which is
//! known per ray and no lane needs a min/max per slab. A child is hit when
//! `max(tmin, entries) <= min(tmax, exits)`.
//!
//! Robustness follows pbrt-v4 (Pharr, Jakob and Humphreys, *Physically Based Rendering*, 4th
//! ed., §6.8.2 "Conservative Ray–Bounds Intersections"; `Bounds3::IntersectP`): each computed
//! `t` is the exact `(face - o) / d` up to three roundings (of `1 / d`, of the subtraction, of
//! the product), a relative error of at most `γ(3)` (`γ(n) = n ε / (1 - n ε)`, `ε = 2^-24`), so
//! growing the exit by `2 γ(3)` of itself makes it at least every computed entry that its exact
//! value is at least.
//!
//! Where we deviate from pbrt, and why:
//! - An axis the ray does not move along (`d = ±0`) is tested exactly, as the origin within the
//!   slab, faces included; pbrt lets `inv = ±inf` make the products `±inf`, or NaN where the
//!   origin is on a face plane, which its min/max skip. But an origin below the slab then
//!   gives an entry and an exit of `+inf`, which a range with `tmax = +inf` accepts: every child
//!   beside an axis-parallel ray would be hit (and the camera's axis-parallel rays would visit
//!   them). The branch is on the ray, the same for every node.
//! - The growth factor is `1 + 8 ε` (`1 + 2^-21`), not `1 + 2 γ(3)`: the latter is `1 + 6 ε` in
//!   f32, which does not cover the rounding of the product that grows the exit (a worst case
//!   needs `1 + 7 ε`).
//! - The exit is grown by its magnitude (times `1 - 8 ε` when negative; pbrt multiplies by
//!   `1 + 2 γ(3)` whatever the sign, which moves a negative exit the wrong way), and once, after
//!   the min over the three axes and `tmax`, which is the same for a monotone growth. Growing
//!   `tmax` too is what keeps a child whose entry is exactly `tmax` (rounded up by the
//!   computation) from being missed; pbrt compares against the ray's `tMax` ungrown.
//! - `2^-140` is added to the grown exit: a `t` that underflows into the subnormals has an
//!   absolute error (a few `2^-150`) that no relative growth covers.
//! - A ray along which some `1 / d` is not a normal number although `d` is not zero (a
//!   component below `2^-126` in magnitude, whose inverse overflows, or above `2^126`, whose
//!   inverse is subnormal and loses precision) breaks the error bound; for such a ray every
//!   child is hit, with entry `tmin` (rays that odd are rare enough that their speed does not
//!   matter).
//!
//! Written once over [`Simd8`] (`os::simd`) as [`super::group`] is: SSE, AVX2 and the portable
//! kernel compute the same operations in the same order and agree bit for bit.

#[cfg(not(all(target_arch = "x86_64", target_feature = "sse4.1")))]
use crate::os::Portable;
#[cfg(all(target_arch = "x86_64", target_feature = "sse4.1"))]
use crate::os::Sse41;
use crate::os::{Avx2, Simd8, WithAvx2};

use super::Ray;

/// A cluster node's children as the box test reads them: the fields of format 4's
/// `ClusterNode` record (`physical::format`, spec §7.1), borrowed. (All by reference: a view
/// that copied `origin` and `exp` made an AVX2 call from ordinary code three times slower,
/// reloading them from the call's stack frame with loads that store forwarding cannot serve.)
#[derive(Clone, Copy, Debug)]
pub struct ClusterNodeView<'a> {
    /// The grid's origin per axis.
    pub origin: &'a [f32; 3],
    /// The grid's step per axis is `2^exp` (see [`grid_step`] for bytes outside the spec).
    pub exp: &'a [i8; 3],
    /// `lo[k][i]`: the lowest face of child `i` along axis `k`, in steps from the origin.
    pub lo: &'a [[u8; 8]; 3],
    /// `hi[k][i]`: the highest face.
    pub hi: &'a [[u8; 8]; 3],
    /// Children in use; slots `child_count..8` are never hit (above 8 counts as 8).
    pub child_count: u8,
}

impl ClusterNodeView<'_> {
    /// The box of child slot `i` (`< 8`), as `ClusterNode::child_box` gives it (for any
    /// exponent in the spec's range).
    pub fn child_box(&self, i: usize) -> ([f32; 3], [f32; 3]) {
        let i = i & 7;
        let face = |k: usize, q: u8| self.origin[k] + q as f32 * grid_step(self.exp[k]);
        (
            std::array::from_fn(|k| face(k, self.lo[k][i])),
            std::array::from_fn(|k| face(k, self.hi[k][i])),
        )
    }

    /// The children in use, bit `i` for slot `i`.
    #[inline(always)]
    pub fn live(&self) -> u32 {
        (1u32 << self.child_count.min(8)) - 1
    }
}

/// `2^e`, a grid's step: exact for every `e` in `-126..=127` (the spec's `-100..=100` among
/// them); an exponent below is taken as `-126`, so any bytes give a finite, normal step.
#[inline(always)]
pub fn grid_step(e: i8) -> f32 {
    f32::from_bits((((e as i32).max(-126) + 127) as u32) << 23)
}

/// The unit roundoff of f32, `2^-24` (pbrt's `MachineEpsilon`).
const EPS: f32 = 1.0 / (1u32 << 24) as f32;
/// A non-negative exit is grown by this factor, `1 + 8 ε` (exact in f32).
const GROW: f32 = 1.0 + 8.0 * EPS;
/// A negative exit by this one, `1 - 8 ε` (exact in f32).
const GROW_NEG: f32 = 1.0 - 8.0 * EPS;
/// Then `2^-140` is added, for exits that underflowed.
const SLACK: f32 = f32::from_bits(1 << 9);
/// The entry reported for a child that is not hit.
const MISS_T: f32 = f32::INFINITY;

/// `t` grown as the box test grows a child's exit before it compares the child's entry with
/// it: an entry the test reported is at most `grown_exit(t)` for every `t` at or past the
/// child's exact entry. A traversal that culls a child later (popped from its stack when a
/// hit at `t` has been found) must compare its reported entry with `grown_exit(t)`, not `t`:
/// the reported entry may exceed the exact one by about `2^-21` of itself, and a triangle
/// lying in the child's face is hit at the exact entry.
#[inline(always)]
pub fn grown_exit(t: f32) -> f32 {
    t * if t.is_sign_negative() { GROW_NEG } else { GROW } + SLACK
}

/// A ray's constants for the box test (the per-ray precomputation of Williams et al.).
#[derive(Clone, Copy, Debug)]
pub struct BoxRay {
    origin: [f32; 3],
    /// `1 / d` per axis (used where the ray moves along it).
    inv: [f32; 3],
    /// Per axis, the face the ray enters a slab by: 0 for the low face (`d > 0`), 1 for the
    /// high one (`d < 0`). An index rather than a flag, so that picking a row is a load, not a
    /// branch.
    near: [usize; 3],
    /// Per axis: `d != 0`.
    moves: [bool; 3],
    /// Some `1 / d` of a non-zero `d` is infinite or subnormal: the error bound does not hold,
    /// and every child counts as hit.
    odd: bool,
}

impl BoxRay {
    /// The constants for `ray` (its range is given to each test: it shrinks as hits are found).
    pub fn new(ray: &Ray) -> BoxRay {
        let d = ray.dir;
        let inv = d.map(|d| 1.0 / d);
        let odd = (0..3).any(|k| d[k] != 0.0 && !inv[k].is_normal());
        BoxRay {
            origin: ray.origin,
            inv,
            near: d.map(|d| (d < 0.0) as usize),
            moves: d.map(|d| d != 0.0),
            odd,
        }
    }

    /// The live children of node `n` that the segment `[tmin, tmax]` of the ray may meet: bit
    /// `i` for child `i`, and the `t` at which the ray enters each (`>= tmin`; `+inf` for the
    /// children not hit). Never misses a child the exact segment meets; a child it reports
    /// may be missed by up to about `2^-21` of the entry (see the module's doc).
    ///
    /// SSE in builds for SSE4.1, such as the portable build; elsewhere the same kernel on
    /// eight scalars.
    #[inline(always)]
    pub fn node_hits(&self, n: ClusterNodeView<'_>, tmin: f32, tmax: f32) -> (u32, [f32; 8]) {
        #[cfg(all(target_arch = "x86_64", target_feature = "sse4.1"))]
        let isa = Sse41::new();
        #[cfg(not(all(target_arch = "x86_64", target_feature = "sse4.1")))]
        let isa = Portable;
        self.node_kernel(isa, n, tmin, tmax)
    }

    /// [`BoxRay::node_hits`] on any instruction set: for code that runs inside
    /// [`Avx2::vectorize`] (a tracer's traversal), where it inlines whole.
    #[inline(always)]
    pub fn node_hits_with<S: Simd8>(
        &self,
        isa: S,
        n: ClusterNodeView<'_>,
        tmin: f32,
        tmax: f32,
    ) -> (u32, [f32; 8]) {
        self.node_kernel(isa, n, tmin, tmax)
    }

    /// [`BoxRay::node_hits`] with the eight children in one AVX2 register: the same answers.
    /// A call from ordinary code goes through the trampoline of [`Avx2::vectorize`] (one call,
    /// which LLVM does not inline even from inside another `vectorize`: there, use
    /// [`BoxRay::node_hits_with`]).
    #[inline(always)]
    pub fn node_hits_avx2(
        &self,
        isa: Avx2,
        n: ClusterNodeView<'_>,
        tmin: f32,
        tmax: f32,
    ) -> (u32, [f32; 8]) {
        struct Job<'a> {
            ray: &'a BoxRay,
            n: ClusterNodeView<'a>,
            tmin: f32,
            tmax: f32,
        }
        impl WithAvx2 for Job<'_> {
            type Output = (u32, [f32; 8]);
            #[inline(always)]
            fn run(self, isa: Avx2) -> Self::Output {
                #[cfg(target_arch = "x86_64")]
                return self.ray.node_kernel(isa, self.n, self.tmin, self.tmax);
                // No token exists on other architectures: never reached.
                #[cfg(not(target_arch = "x86_64"))]
                return {
                    let _ = isa;
                    self.ray.node_hits(self.n, self.tmin, self.tmax)
                };
            }
        }
        isa.vectorize(Job {
            ray: self,
            n,
            tmin,
            tmax,
        })
    }

    /// The kernel.
    #[inline(always)]
    fn node_kernel<S: Simd8>(
        &self,
        s: S,
        n: ClusterNodeView<'_>,
        tmin: f32,
        tmax: f32,
    ) -> (u32, [f32; 8]) {
        let live = s.lanes_below(n.child_count as u32);
        if self.odd {
            return (
                s.bits(live),
                s.store(s.select(live, s.splat(tmin), s.splat(MISS_T))),
            );
        }
        let mut enter = s.splat(tmin);
        let mut leave = s.splat(tmax);
        let mut slabs = live;
        for k in 0..3 {
            let (origin, step) = (s.splat(n.origin[k]), s.splat(grid_step(n.exp[k])));
            // Faces as `ClusterNode::child_box` computes them: `origin + q * step`, exact.
            let face = |q: &[u8; 8]| s.add(origin, s.mul(s.bytes(q), step));
            let o = s.splat(self.origin[k]);
            if !self.moves[k] {
                // The ray stays in the plane `o[k]`: inside the slab, faces included, or never.
                let inside = s.and(s.le(face(&n.lo[k]), o), s.le(o, face(&n.hi[k])));
                slabs = s.and(slabs, inside);
                continue;
            }
            let rows = [n.lo, n.hi];
            let near = self.near[k] & 1;
            let (near, far) = (&rows[near][k], &rows[near ^ 1][k]);
            let inv = s.splat(self.inv[k]);
            enter = s.max(s.mul(s.sub(face(near), o), inv), enter);
            leave = s.min(s.mul(s.sub(face(far), o), inv), leave);
        }
        // Grown by its magnitude (the sign bit picks the factor), then the underflow slack.
        let grow = s.select(leave, s.splat(GROW_NEG), s.splat(GROW));
        let leave = s.add(s.mul(leave, grow), s.splat(SLACK));
        let hit = s.and(slabs, s.le(enter, leave));
        (s.bits(hit), s.store(s.select(hit, enter, s.splat(MISS_T))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::os::Portable;
    use std::cmp::Ordering;

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
        fn range(&mut self, lo: i64, hi: i64) -> i64 {
            lo + self.below((hi - lo + 1) as u64) as i64
        }
        fn chance(&mut self, percent: u64) -> bool {
            self.below(100) < percent
        }
    }

    /// A node with its own storage.
    #[derive(Clone, Copy, Debug)]
    struct Node {
        origin: [f32; 3],
        exp: [i8; 3],
        lo: [[u8; 8]; 3],
        hi: [[u8; 8]; 3],
        child_count: u8,
    }

    impl Node {
        fn view(&self) -> ClusterNodeView<'_> {
            ClusterNodeView {
                origin: &self.origin,
                exp: &self.exp,
                lo: &self.lo,
                hi: &self.hi,
                child_count: self.child_count,
            }
        }
    }

    /// Every f32 the generators make is a multiple of `2^-UNIT_BITS` below `2^31` of them, so
    /// the exact reference works on integers.
    const UNIT_BITS: i32 = 20;

    /// `x` in units of `2^-UNIT_BITS`, exactly (the generators keep to such values).
    fn units(x: f32) -> i128 {
        let v = x as f64 * 2f64.powi(UNIT_BITS);
        assert!(
            v.fract() == 0.0 && v.abs() < 2f64.powi(62),
            "{x} is not on the unit grid"
        );
        v as i128
    }

    /// A `t` for the exact test: `num / den` with `den > 0`, or an infinity.
    #[derive(Clone, Copy, Debug)]
    enum Q {
        NegInf,
        Fin(i128, i128),
        PosInf,
    }

    fn cmp(a: Q, b: Q) -> Ordering {
        match (a, b) {
            (Q::Fin(p, q), Q::Fin(r, s)) => (p * s).cmp(&(r * q)),
            (Q::NegInf, Q::NegInf) | (Q::PosInf, Q::PosInf) => Ordering::Equal,
            (Q::NegInf, _) | (_, Q::PosInf) => Ordering::Less,
            _ => Ordering::Greater,
        }
    }

    fn t_of(x: f32) -> Q {
        match x {
            f32::INFINITY => Q::PosInf,
            f32::NEG_INFINITY => Q::NegInf,
            x => Q::Fin(units(x), 1 << UNIT_BITS),
        }
    }

    /// The exact slab test: whether the segment `[tmin, tmax]` of `origin + t dir` meets the
    /// closed box `[lo, hi]` (an axis the ray does not move along: the origin within the slab),
    /// as the comparison of the last entry with the first exit (`Equal`: it touches).
    fn exact_test(
        o: [f32; 3],
        d: [f32; 3],
        tmin: f32,
        tmax: f32,
        lo: [f32; 3],
        hi: [f32; 3],
    ) -> Ordering {
        let (mut enter, mut leave) = (t_of(tmin), t_of(tmax));
        for k in 0..3 {
            let (o, d, lo, hi) = (units(o[k]), units(d[k]), units(lo[k]), units(hi[k]));
            if d == 0 {
                if o < lo || o > hi {
                    return Ordering::Greater;
                }
                continue;
            }
            // (face - o) / d with a positive denominator.
            let t = |face: i128| {
                if d > 0 {
                    Q::Fin(face - o, d)
                } else {
                    Q::Fin(o - face, -d)
                }
            };
            let (a, b) = if d > 0 {
                (t(lo), t(hi))
            } else {
                (t(hi), t(lo))
            };
            if cmp(a, enter) == Ordering::Greater {
                enter = a;
            }
            if cmp(b, leave) == Ordering::Less {
                leave = b;
            }
        }
        cmp(enter, leave)
    }

    /// A node on a grid of step `2^-6..2^2` (faces multiples of `2^-6`, within about 1000 of
    /// 0): children of every size down to flat, `child_count` in `1..=8`, unused slots 0.
    fn random_node(r: &mut Rng) -> Node {
        let mut n = Node {
            origin: [0.0; 3],
            exp: [0; 3],
            lo: [[0; 8]; 3],
            hi: [[0; 8]; 3],
            child_count: 1 + r.below(8) as u8,
        };
        for k in 0..3 {
            n.exp[k] = r.range(-6, 2) as i8;
            n.origin[k] = r.range(-150, 150) as f32 * grid_step(n.exp[k]);
            for i in 0..n.child_count as usize {
                let (a, b) = match r.below(4) {
                    0 => (0, 255),
                    1 => {
                        let a = r.below(256) as u8;
                        (a, a)
                    }
                    _ => {
                        let (a, b) = (r.below(256) as u8, r.below(256) as u8);
                        (a.min(b), a.max(b))
                    }
                };
                n.lo[k][i] = a;
                n.hi[k][i] = b;
            }
        }
        n
    }

    /// A ray for node `n`: from anywhere, from a face plane or a corner of a child, from inside
    /// a child; directions with zero components (along a face plane: grazing), powers of two
    /// (so that entry and exit `t` are on the unit grid and can be the range's ends, touching),
    /// or arbitrary; ranges from 0, from below 0, to a child's exact entry or exit.
    fn random_ray(r: &mut Rng, n: &Node) -> Ray {
        let v = n.view();
        let (lo, hi) = v.child_box(r.below(n.child_count as u64) as usize);
        let anywhere = |r: &mut Rng| r.range(-(1 << 20), 1 << 20) as f32 / 1024.0;
        let mut o: [f32; 3] = std::array::from_fn(|_| anywhere(r));
        for k in 0..3 {
            match r.below(5) {
                0 => o[k] = lo[k],
                1 => o[k] = hi[k],
                2 => o[k] = (lo[k] + hi[k]) * 0.5,
                _ => {}
            }
        }
        let pow2 = r.chance(50);
        let mut d: [f32; 3] = std::array::from_fn(|_| match r.below(4) {
            0 => 0.0,
            _ if pow2 => {
                let m = 2f32.powi(r.range(-3, 3) as i32);
                if r.chance(50) { m } else { -m }
            }
            1 => r.range(-9, 9) as f32,
            _ => r.range(-(1 << 20), 1 << 20) as f32 / 1024.0,
        });
        if !pow2 && r.chance(40) {
            // Towards the child's centre (reached at t = 1), along the axes that need it.
            d = std::array::from_fn(|k| {
                let c = (lo[k] + hi[k]) * 0.5 - o[k];
                if d[k] == 0.0 && r.chance(50) { 0.0 } else { c }
            });
        }
        if d == [0.0; 3] {
            d[r.below(3) as usize] = -0.5;
        }
        if r.chance(10) {
            let k = r.below(3) as usize;
            d[k] = -0.0;
        }
        let some_t = |r: &mut Rng| r.range(-(1 << 24), 1 << 24) as f32 / 4096.0;
        let (mut tmin, mut tmax) = match r.below(4) {
            0 => (0.0, f32::INFINITY),
            1 => (-f32::INFINITY, f32::INFINITY),
            _ => {
                let (a, b) = (some_t(r), some_t(r));
                (a.min(b), a.max(b))
            }
        };
        if pow2 && r.chance(50) {
            // A face's `t` along an axis the ray moves along: exact, on the unit grid.
            let k = r.below(3) as usize;
            if d[k] != 0.0 {
                let face = if r.chance(50) { lo[k] } else { hi[k] };
                let t = (face - o[k]) / d[k];
                if r.chance(50) {
                    tmax = t;
                    tmin = tmin.min(t);
                } else {
                    tmin = t;
                    tmax = tmax.max(t);
                }
            }
        }
        Ray::new(o, d, tmin, tmax)
    }

    fn same(a: (u32, [f32; 8]), b: (u32, [f32; 8])) -> bool {
        a.0 == b.0 && a.1.map(f32::to_bits) == b.1.map(f32::to_bits)
    }

    /// The answers of every kernel, checked equal to each other; the portable one returned.
    fn all_kernels(ray: &BoxRay, n: &Node, tmin: f32, tmax: f32) -> (u32, [f32; 8]) {
        let want = ray.node_kernel(Portable, n.view(), tmin, tmax);
        let sse = ray.node_hits(n.view(), tmin, tmax);
        assert!(
            same(sse, want),
            "default vs portable: {sse:?} {want:?}\n{n:?}\n{ray:?}"
        );
        if let Some(isa) = Avx2::detect() {
            let avx2 = ray.node_hits_avx2(isa, n.view(), tmin, tmax);
            assert!(
                same(avx2, want),
                "avx2 vs portable: {avx2:?} {want:?}\n{n:?}\n{ray:?}"
            );
        }
        want
    }

    /// Checks one case against the exact test on case `exact` (the same case, or the one it was
    /// scaled from); returns the false hits and the children the exact segment only touches.
    fn check(n: &Node, ray: &Ray, exact: (&Node, &Ray)) -> (u32, u32) {
        let br = BoxRay::new(ray);
        let (mask, ts) = all_kernels(&br, n, ray.tmin, ray.tmax);
        let (mut false_hits, mut touching) = (0, 0);
        for (i, &t) in ts.iter().enumerate() {
            let got = mask >> i & 1 == 1;
            if i >= n.child_count as usize {
                assert!(!got && t == MISS_T, "slot {i} past the count: {n:?}");
                continue;
            }
            let (lo, hi) = exact.0.view().child_box(i);
            let r = exact.1;
            let order = exact_test(r.origin, r.dir, r.tmin, r.tmax, lo, hi);
            touching += (order == Ordering::Equal) as u32;
            let exact = order != Ordering::Greater;
            assert!(got || !exact, "false miss of child {i}\n{n:?}\n{ray:?}");
            if got {
                assert!(t >= ray.tmin, "entry below tmin");
                false_hits += !exact as u32;
            }
        }
        (false_hits, touching)
    }

    /// Scales a case by powers of two, `2^s` for positions and `2^r` for the direction (so
    /// `t` by `2^(s - r)`): the exact answers do not change. `None` where a value would not be
    /// exact (or a grid exponent would leave the spec's range).
    fn scaled(n: &Node, ray: &Ray, s: i32, r: i32) -> Option<(Node, Ray)> {
        let by = |x: f32, e: i32| {
            let y = (x as f64 * 2f64.powi(e)) as f32;
            (y as f64 * 2f64.powi(-e) == x as f64 || x.is_infinite()).then_some(y)
        };
        let mut m = *n;
        for k in 0..3 {
            m.origin[k] = by(n.origin[k], s)?;
            let e = n.exp[k] as i32 + s;
            if !(-100..=100).contains(&e) {
                return None;
            }
            m.exp[k] = e as i8;
        }
        let o = [
            by(ray.origin[0], s)?,
            by(ray.origin[1], s)?,
            by(ray.origin[2], s)?,
        ];
        let d = [by(ray.dir[0], r)?, by(ray.dir[1], r)?, by(ray.dir[2], r)?];
        let ray2 = Ray::new(o, d, by(ray.tmin, s - r)?, by(ray.tmax, s - r)?);
        Some((m, ray2))
    }

    /// No false miss, against the exact test, on random nodes and rays with grazing and
    /// touching cases; false hits rare. The SSE, AVX2 and portable kernels agree bit for bit.
    #[test]
    fn never_misses_a_child_the_exact_test_hits() {
        if Avx2::detect().is_none() {
            eprintln!("AVX2 kernel skipped: this CPU has no AVX2 and FMA");
        }
        let mut r = Rng(0xb0c5_0000_1234_5679);
        let (mut hits, mut false_hits, mut grazing, mut touching) = (0u64, 0u64, 0u64, 0u64);
        for _ in 0..150_000 {
            let n = random_node(&mut r);
            let ray = random_ray(&mut r, &n);
            let (f, t) = check(&n, &ray, (&n, &ray));
            (false_hits, touching) = (false_hits + f as u64, touching + t as u64);
            let br = BoxRay::new(&ray);
            hits += br.node_hits(n.view(), ray.tmin, ray.tmax).0.count_ones() as u64;
            grazing += (0..3).any(|k| {
                ray.dir[k] == 0.0 && {
                    let (lo, hi) = n.view().child_box(0);
                    ray.origin[k] == lo[k] || ray.origin[k] == hi[k]
                }
            }) as u64;
        }
        eprintln!(
            "{hits} children hit, {false_hits} of them false, {touching} touching; \
             {grazing} grazing rays"
        );
        assert!(
            hits > 50_000 && grazing > 1000 && touching > 1000,
            "the cases cover too little"
        );
        assert!(false_hits * 1000 < hits, "too many false hits");
    }

    /// The same cases scaled by powers of two into the subnormals and towards overflow, where
    /// `t` underflows or overflows: still no false miss.
    #[test]
    fn never_misses_at_extreme_scales() {
        let mut r = Rng(0x5ca1_ab1e);
        let mut tried = 0;
        for _ in 0..150_000 {
            let n = random_node(&mut r);
            let ray = random_ray(&mut r, &n);
            let s = r.range(-95, 95) as i32;
            let e = r.range(-135, 135) as i32;
            if let Some((m, scaled_ray)) = scaled(&n, &ray, s, e) {
                check(&m, &scaled_ray, (&n, &ray));
                tried += 1;
            }
        }
        assert!(tried > 50_000, "{tried} scaled cases");
    }

    /// A ray through a child's edge (it leaves the slab of x where it enters that of y) along
    /// directions that are not powers of two, at scales where that `t` is subnormal: relative
    /// growth does nothing there, and each `t` may be a subnormal step off; the slack keeps the
    /// child hit.
    #[test]
    fn touching_in_the_subnormals() {
        for p in 1..64u8 {
            for q in 1..64u8 {
                // Child 0: x in [0, p], y in [q, 2q], z in [0, 1], in steps of 2^-100.
                let n = Node {
                    origin: [0.0; 3],
                    exp: [-100; 3],
                    lo: [[0; 8], [q, 0, 0, 0, 0, 0, 0, 0], [0; 8]],
                    hi: [
                        [p, 0, 0, 0, 0, 0, 0, 0],
                        [2 * q, 0, 0, 0, 0, 0, 0, 0],
                        [1; 8],
                    ],
                    child_count: 1,
                };
                for e in 0..60 {
                    // Touching at t = 2^(-100 - e): normal for small e, subnormal beyond 26.
                    let d = [p as f32 * 2f32.powi(e), q as f32 * 2f32.powi(e), 0.0];
                    let ray = Ray::new([0.0; 3], d, 0.0, f32::INFINITY);
                    let (mask, _) = all_kernels(&BoxRay::new(&ray), &n, 0.0, f32::INFINITY);
                    assert_eq!(mask, 1, "{p} {q} {e}");
                }
            }
        }
    }

    /// Directions whose inverse is not a normal number: every child counts as hit.
    #[test]
    fn odd_directions_hit_every_child() {
        let mut r = Rng(3);
        let n = random_node(&mut r);
        // The ray barely moves along z (1 / d overflows), yet enters the box at t = 1: the
        // plain slab test would give an infinite entry.
        for d in [[1.0, 0.0, f32::from_bits(1)], [1.0, 0.0, 1e38]] {
            let ray = Ray::new([0.0; 3], d, 0.0, f32::INFINITY);
            let (mask, ts) = all_kernels(&BoxRay::new(&ray), &n, 0.0, f32::INFINITY);
            assert_eq!(mask, n.view().live());
            assert!(ts[..n.child_count as usize].iter().all(|&t| t == 0.0));
        }
    }

    /// Any bytes: no panic, only live slots reported, every kernel the same answer.
    #[test]
    fn garbage_nodes_give_some_mask() {
        let mut r = Rng(99);
        for _ in 0..50_000 {
            let mut n = random_node(&mut r);
            let bytes: [u8; 48] = std::array::from_fn(|_| r.next() as u8);
            n.lo = bytemuck::cast(<[u8; 24]>::try_from(&bytes[..24]).unwrap());
            n.hi = bytemuck::cast(<[u8; 24]>::try_from(&bytes[24..]).unwrap());
            n.exp = std::array::from_fn(|_| r.next() as i8);
            n.origin = std::array::from_fn(|_| f32::from_bits(r.next() as u32));
            n.child_count = r.next() as u8;
            let near = random_node(&mut r);
            let ray = random_ray(&mut r, &near);
            let (mask, _) = all_kernels(&BoxRay::new(&ray), &n, ray.tmin, ray.tmax);
            assert_eq!(mask & !n.view().live(), 0);
        }
    }
}
