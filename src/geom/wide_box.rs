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
//!
//! [`FmaRay`] is a second test of the same meaning, faster: one multiply-add per plane per
//! lane (`q a + b`, with `a` and `b` per node and axis), made conservative by a slack on `b`
//! whose bound its doc derives, for the rays it calls eligible. Its multiply-add is fused on
//! AVX2 and not elsewhere, so its answers may differ between instruction sets (each
//! conservative).

#[cfg(not(all(target_arch = "x86_64", target_feature = "sse4.1")))]
use crate::os::Portable;
#[cfg(all(target_arch = "x86_64", target_feature = "sse4.1"))]
use crate::os::Sse41;
use crate::os::{Avx2, FmaNodeFields, FmaNodeRay, Simd8, WithAvx2};

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

/// The grid exponents the FMA node test is exact for, `-64..=63`: a node's `exp` is clamped
/// into this range before it builds the step, so that any bytes give a finite, normal step.
const FMA_EXP_MIN: i8 = -64;
const FMA_EXP_MAX: i8 = 63;
/// `2^-22` (`4 u`): the slack's factor of `|b|`.
const FMA_REL_B: f32 = 1.0 / (1u32 << 22) as f32;
/// `2^-14` (`1024 u`): the slack's factor of `|a|`.
const FMA_REL_A: f32 = 1.0 / (1u32 << 14) as f32;
/// `2^-120`: the slack's absolute term, for the products and sums that underflow.
const FMA_ABS: f32 = f32::from_bits((127 - 120) << 23);
/// The largest `|1 / d|` of an eligible ray, `2^55`.
const FMA_MAX_INV: f32 = f32::from_bits((127 + 55) << 23);
/// The largest `(|o| + coord_bound) |1 / d|` of an eligible ray, `2^100`.
const FMA_MAX_REACH: f32 = f32::from_bits((127 + 100) << 23);

/// A ray's constants for the FMA node test: the box test on a cluster node's eight children in
/// one multiply-add per plane per lane (fused on AVX2), conservative by the bound derived
/// below. Same
/// answers' meaning as [`BoxRay::node_hits`] (bit `i` for a live child whose box the segment
/// may meet, its entry `>= tmin`, `+inf` for the others), for eligible rays only
/// ([`FmaRay::eligible`]): a tracer sends the others to a walk that uses [`BoxRay`].
///
/// Along an axis the ray moves along, a plane of a node is `p + q 2^e` (the grid's origin `p`,
/// the face byte `q`, the step `2^e`); its `t` is `(p - o) / d + q (2^e / d)`, so per node and
/// axis two scalars, `a = r 2^e` and `b = (p - o) r` with `r = 1 / d`, make each lane's `t`
/// one multiply-add `q a + b`. That sum cancels (the grid's origin may be far from the box,
/// `q a` and `b` large and of opposite signs), so the relative growth of [`BoxRay`] does not
/// bound its error: `b` is moved by a slack `s` that does, down for the near planes and up for
/// the far ones, once per node and axis. An axis the ray does not move along (`d = ±0`) is
/// tested exactly, as [`BoxRay`] does: the origin within the slab, faces included.
///
/// With [`Avx2`] the multiply-add is fused (one rounding); with SSE and the portable kernel it
/// is a multiply and an add (two roundings). The bound covers both, but the answers (the mask
/// and the entries) may differ between instruction sets, by a hair: each one is conservative.
///
/// # The computation
///
/// `u = 2^-24`, `RN` rounds to nearest. Per ray: `o` its origin, `d` its direction; per axis
/// `k` with `d[k] != 0`, `r = RN(1 / d)` and the near row (`lo` if `d > 0`, else `hi`; the far
/// row the other). Per node and axis, `e` the node's exponent clamped into `-64..=63`, `p` its
/// origin (scalars, computed once per node, in this order):
///
/// - `a = r 2^e` (exact, but for an underflow),
/// - `b = RN(RN(p - o) r)`,
/// - `s = RN(RN(RN(|b| 2^-22) + RN(|a| 2^-14)) + 2^-120)`,
/// - `bn = RN(b - s)`, `bf = RN(b + s)`;
///
/// then per lane (child), for a near plane `t = RN(q a + bn)` fused, `RN(RN(q a) + bn)` not
/// fused, for a far plane the same with `bf`. The entry is `x' = max(tmin, near t's)`, the
/// exit `y' = min(tmax, far t's)`, and a child is reported hit when every flat axis has the
/// origin within its slab and `x' <= RN(y' (1 + 8u))`, with entry `x'`.
///
/// # The bound
///
/// Along a moving axis the exact `t` of a plane is `T = (p + q 2^e - o) / d = B + q 2^e / d`
/// with `B = (p - o) / d`. Every `|δi| <= u`:
///
/// - `r = (1 + δ0) / d`, so `a = 2^e r = (1 + δ0) 2^e / d` (an `a` below `2^-126` is off by
///   at most `2^-150`, so `q a` by at most `255 · 2^-150`);
/// - `RN(p - o) = (1 + δ1)(p - o)` (a difference that is subnormal is exact), and
///   `b = (1 + δ2) RN(p - o) r = (1 + δ0)(1 + δ1)(1 + δ2) B` (or off by at most `2^-150` if it
///   underflows);
/// - hence `q a + b = (1 + δ0)(T + B θ)` with `θ = (1 + δ1)(1 + δ2) - 1`, `|θ| <= 2u + u²`;
/// - `bn = b - s + ε_b` with `|ε_b| <= u |b - s|` (the same for `bf` with `+ s`);
/// - unfused, `RN(q a) = q a + ε4` with `|ε4| <= 255 u |a|` (255 the largest byte; `ε4 = 0`
///   fused).
///
/// The sum the last rounding sees is `(1 + δ0) T + [(1 + δ0) B θ + ε_b + ε4] - s` for a near
/// plane (`+ s` for a far one). Since `|(1 + δ0) B| = |b| / |(1 + δ1)(1 + δ2)| <= |b| / (1 -
/// u)²` and `s <= (1 + u)² (4u |b| + 1024u |a| + 2^-120)`, the bracket is at most
/// `3u (1 + 5u) |b| + 256u |a| + 2^-140` (the last term the underflows of `a`, `b` and `u s`);
/// and `s >= (1 - u)² (4u |b| + 1024u |a| + 2^-120 - 2^-149)` (each product of `s` exact but
/// for an underflow of at most `2^-150`, each sum rounded relatively), which exceeds the bracket
/// by at least `2^-121`. So the sum before the last rounding is at most `(1 + δ0) T - 2^-121`
/// for a near plane and at least `(1 + δ0) T + 2^-121` for a far one, and as `RN` is monotone
/// (relative error `u` at `2^-126` and above, absolute `2^-150` below, which the `2^-121`
/// absorbs):
///
/// - near: `t <= (1 + u)² T` when `T >= 0`, and `t <= 0` when `T < 0`;
/// - far: `t >= (1 - u)² T` when `T >= 0` (then `t > 0`), so `t < 0` only if `T < 0`.
///
/// With `tmin >= 0`, let `X = max(tmin, near T's)` and `Y = min(tmax, far T's)` be the exact
/// entry and exit (an exact hit is `X <= Y` and every flat axis's origin in its slab, the
/// latter tested exactly). Then `x' <= (1 + u)² X` (each near `t` is at most `(1 + u)² X`,
/// or at most `0 <= X`). If `Y >= 0`, every far `T` is, and `tmax`, so `y' >= (1 - u)² Y`.
/// An exact hit has `0 <= X <= Y`, so `x' <= ((1 + u) / (1 - u))² y' <= (1 + 4.1u) y' <=
/// y' (1 + 8u)`, and as `x'` is a float, `x' <= RN(y' (1 + 8u))`: never a false miss. A
/// negative `y'` needs a negative far `t` or `tmax`, so `Y < 0 <= X`, an exact miss: the exit
/// needs no growth that depends on its sign.
///
/// Eligibility keeps every value finite: `|r| <= 2^55` and `e <= 63` give `|q a| < 2^126`;
/// `|p| <= coord_bound` gives `|b| <= (1 + u)² (|o| + coord_bound) |r| <= (1 + u)² 2^100`,
/// and `s` is below `2^105`. A normal `r` and `e >= -64` leave `a` and `b` normal or off by at
/// most `2^-150`, which the `2^-120` of the slack covers, as above.
///
/// A traversal that culls a child popped from its stack once a hit at `t` (`>= 0`) has been
/// found must cull it only if its reported entry exceeds `RN(t (1 + 8u))`: the entry is at most
/// `(1 + u)²` times the exact one. [`grown_exit`] grows `t` by at least that, so the
/// traversal's test against `grown_exit(t)` serves both node tests.
#[derive(Clone, Copy, Debug)]
pub struct FmaRay {
    origin: [f32; 3],
    /// `RN(1 / d)` per axis (used where the ray moves along it).
    inv: [f32; 3],
    /// Per axis, the row of the face the ray enters a slab by: 0 (`lo`) for `d > 0`, 1 (`hi`)
    /// otherwise.
    near: [usize; 3],
    /// Per axis: `d == ±0`, the ray stays in the plane `o[k]`.
    flat: [bool; 3],
    eligible: bool,
    /// Some axis is flat (`d = 0`): the kernel tests it exactly, the AVX2 path does not.
    any_flat: bool,
    /// The constants as the AVX2 path reads them.
    avx: FmaNodeRay,
}

impl FmaRay {
    /// The constants for `ray`. `coord_bound` bounds the magnitude of the grid origin of every
    /// node the ray will be tested against, per axis (a bound on the scene's coordinates, such
    /// as the largest magnitude of its bounding box's corners, serves). The ray is eligible
    /// ([`FmaRay::eligible`]) iff `ray.tmin >= 0` and along every axis with `d != 0`, `1 / d`
    /// (rounded) is finite and normal, `|1 / d| <= 2^55` and `(|o| + coord_bound) |1 / d| <=
    /// 2^100` (computed in f32, within two roundings of that: the bound's margin to overflow,
    /// `2^127`, is vast).
    #[inline(always)]
    pub fn new(ray: &Ray, coord_bound: f32) -> FmaRay {
        let (o, d) = (ray.origin, ray.dir);
        let inv = d.map(|d| 1.0 / d);
        let flat = d.map(|d| d == 0.0);
        let eligible = ray.tmin >= 0.0
            && (0..3).all(|k| {
                let r = inv[k].abs();
                flat[k]
                    || r.is_normal()
                        && r <= FMA_MAX_INV
                        && (o[k].abs() + coord_bound) * r <= FMA_MAX_REACH
            });
        let near = d.map(|d| if d > 0.0 { 0 } else { 1 });
        FmaRay {
            origin: o,
            inv,
            near,
            flat,
            eligible,
            any_flat: flat.iter().any(|&f| f),
            avx: FmaNodeRay {
                origin: [o[0], o[1], o[2], 0.0],
                inv: [inv[0], inv[1], inv[2], 0.0],
                near,
            },
        }
    }

    /// Whether the test's guarantee holds for this ray (see [`FmaRay::new`]): for nodes whose
    /// grid origins are within the `coord_bound` given and whose exponents are in `-64..=63`,
    /// with a `tmin >= 0`. A tracer sends the rays that are not to another walk.
    #[inline(always)]
    pub fn eligible(&self) -> bool {
        self.eligible
    }

    /// The live children of node `n` that the segment `[tmin, tmax]` of the ray may meet: bit
    /// `i` for child `i`, and the `t` at which the ray enters each (`>= tmin`; `+inf` for the
    /// children not hit), as [`BoxRay::node_hits`]. Never misses a child the exact segment
    /// meets if the ray is eligible, `tmin >= 0` and the node is within the bounds (see the
    /// type's doc); otherwise some mask of live children, without a panic.
    ///
    /// SSE in builds for SSE4.1, such as the portable build; elsewhere the same kernel on
    /// eight scalars. Two roundings per multiply-add: see [`FmaRay::node_hits_with`] for the
    /// fused one.
    #[inline(always)]
    pub fn node_hits(&self, n: ClusterNodeView<'_>, tmin: f32, tmax: f32) -> (u32, [f32; 8]) {
        #[cfg(all(target_arch = "x86_64", target_feature = "sse4.1"))]
        let isa = Sse41::new();
        #[cfg(not(all(target_arch = "x86_64", target_feature = "sse4.1")))]
        let isa = Portable;
        self.kernel::<_, true>(isa, n, tmin, tmax)
    }

    /// [`FmaRay::node_hits`] on any instruction set: for code that runs inside
    /// [`Avx2::vectorize`] (a tracer's traversal), where it inlines whole and the multiply-adds
    /// are fused.
    #[inline(always)]
    pub fn node_hits_with<S: Simd8>(
        &self,
        isa: S,
        n: ClusterNodeView<'_>,
        tmin: f32,
        tmax: f32,
    ) -> (u32, [f32; 8]) {
        self.kernel::<S, true>(isa, n, tmin, tmax)
    }

    /// The kernel. `SLACK` is false only in the tests, which show that without the slack the
    /// test misses children.
    #[inline(always)]
    fn kernel<S: Simd8, const SLACK: bool>(
        &self,
        s: S,
        n: ClusterNodeView<'_>,
        tmin: f32,
        tmax: f32,
    ) -> (u32, [f32; 8]) {
        self.kernel_with::<S, SLACK, true>(s, n, tmin, tmax)
    }

    /// The kernel; with `FAST`, on AVX2 for a ray with no flat axis, by
    /// [`Avx2::fma_node`] (the same operations, the three axes' scalar terms at once; a test
    /// compares the two paths bit for bit).
    #[inline(always)]
    fn kernel_with<S: Simd8, const SLACK: bool, const FAST: bool>(
        &self,
        s: S,
        n: ClusterNodeView<'_>,
        tmin: f32,
        tmax: f32,
    ) -> (u32, [f32; 8]) {
        if SLACK
            && FAST
            && !self.any_flat
            && let Some(avx) = s.as_avx2()
        {
            let fields = FmaNodeFields {
                origin: n.origin,
                exp: n.exp,
                rows: [n.lo, n.hi],
                child_count: n.child_count,
            };
            return avx.fma_node(&self.avx, fields, tmin, tmax);
        }
        let mut inside = s.lanes_below(n.child_count as u32);
        let mut enter = s.splat(tmin);
        let mut leave = s.splat(tmax);
        for k in 0..3 {
            let step = grid_step(n.exp[k].clamp(FMA_EXP_MIN, FMA_EXP_MAX));
            let (p, o) = (n.origin[k], self.origin[k]);
            if self.flat[k] {
                // The ray stays in the plane `o[k]`: inside the slab, faces included, or never.
                // Faces as `ClusterNode::child_box` computes them: `origin + q * step`, exact.
                let (pv, stepv, ov) = (s.splat(p), s.splat(step), s.splat(o));
                let face = |q: &[u8; 8]| s.add(pv, s.mul(s.bytes(q), stepv));
                let slab = s.and(s.le(face(&n.lo[k]), ov), s.le(ov, face(&n.hi[k])));
                inside = s.and(inside, slab);
                continue;
            }
            let (a, bn, bf) = fma_terms::<SLACK>(self.inv[k], p, o, step);
            let rows = [n.lo, n.hi];
            let near = self.near[k] & 1;
            let (near, far) = (&rows[near][k], &rows[near ^ 1][k]);
            let av = s.splat(a);
            enter = s.max(s.mul_add(s.bytes(near), av, s.splat(bn)), enter);
            leave = s.min(s.mul_add(s.bytes(far), av, s.splat(bf)), leave);
        }
        let hit = s.and(inside, s.le(enter, s.mul(leave, s.splat(GROW))));
        (s.bits(hit), s.store(s.select(hit, enter, s.splat(MISS_T))))
    }
}

/// The FMA node test's scalars for one node and axis, in f32 as [`FmaRay`]'s doc states
/// them: `a = r step`, and `b = (p - o) r` moved down and up by the slack `s`, `(bn, bf)`. The
/// slack is 0 if `SLACK` is false (only in the tests, which show it is needed).
#[inline(always)]
fn fma_terms<const SLACK: bool>(r: f32, p: f32, o: f32, step: f32) -> (f32, f32, f32) {
    let a = r * step;
    let b = (p - o) * r;
    let s = if SLACK {
        (b.abs() * FMA_REL_B + a.abs() * FMA_REL_A) + FMA_ABS
    } else {
        0.0
    };
    (a, b - s, b + s)
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

    // The FMA node test (`FmaRay`).

    /// A `coord_bound` for node `n`, as a tracer would take its scene's: the largest magnitude
    /// among the grid origins and the live children's faces.
    fn coord_bound(n: &Node) -> f32 {
        let v = n.view();
        let mut m = n.origin.iter().fold(0f32, |m, x| m.max(x.abs()));
        for i in 0..n.child_count.min(8) as usize {
            let (lo, hi) = v.child_box(i);
            for k in 0..3 {
                m = m.max(lo[k].abs()).max(hi[k].abs());
            }
        }
        m
    }

    /// The FMA kernel's answers (with the slack, or without it) on every instruction set this
    /// machine has, named: portable (a multiply and an add), SSE (the same roundings: checked
    /// equal to portable bit for bit, and not listed) and AVX2 (fused: may differ).
    fn fma_answers<const SLACK: bool>(
        fr: &FmaRay,
        n: &Node,
        tmin: f32,
        tmax: f32,
    ) -> Vec<(&'static str, (u32, [f32; 8]))> {
        let portable = fr.kernel::<_, SLACK>(Portable, n.view(), tmin, tmax);
        if SLACK {
            assert!(same(
                fr.node_hits_with(Portable, n.view(), tmin, tmax),
                portable
            ));
        }
        #[cfg(all(target_arch = "x86_64", target_feature = "sse4.1"))]
        {
            let sse = fr.kernel::<_, SLACK>(Sse41::new(), n.view(), tmin, tmax);
            assert!(
                same(sse, portable),
                "sse vs portable: {sse:?} {portable:?}\n{n:?}\n{fr:?}"
            );
            if SLACK {
                assert!(same(fr.node_hits(n.view(), tmin, tmax), sse));
            }
        }
        #[allow(unused_mut)]
        let mut out = vec![("portable", portable)];
        #[cfg(target_arch = "x86_64")]
        if let Some(isa) = Avx2::detect() {
            struct Job<'a, const SLACK: bool>(&'a FmaRay, ClusterNodeView<'a>, f32, f32);
            impl<const SLACK: bool> WithAvx2 for Job<'_, SLACK> {
                type Output = (u32, [f32; 8]);
                #[inline(always)]
                fn run(self, isa: Avx2) -> Self::Output {
                    self.0.kernel::<_, SLACK>(isa, self.1, self.2, self.3)
                }
            }
            let avx2 = isa.vectorize(Job::<SLACK>(fr, n.view(), tmin, tmax));
            out.push(("avx2", avx2));
        }
        out
    }

    /// Counts per instruction set, over the live children of the cases checked.
    #[derive(Clone, Copy, Debug, Default)]
    struct Tally {
        hits: u64,
        false_hits: u64,
        false_misses: u64,
        /// Children the exact segment only touches (`Equal`), hit or not.
        touching: u64,
        /// Answers whose mask or entries differ from the portable kernel's.
        differ: u64,
    }

    /// One tally per instruction set, in the order of [`fma_answers`].
    #[derive(Debug, Default)]
    struct Tallies(Vec<(&'static str, Tally)>);

    impl Tallies {
        fn get(&mut self, isa: &'static str) -> &mut Tally {
            if let Some(i) = self.0.iter().position(|(n, _)| *n == isa) {
                return &mut self.0[i].1;
            }
            self.0.push((isa, Tally::default()));
            &mut self.0.last_mut().unwrap().1
        }
        fn print(&self, what: &str) {
            for (isa, t) in &self.0 {
                eprintln!("{what}, {isa}: {t:?}");
            }
            if !self.0.iter().any(|(isa, _)| *isa == "avx2") {
                eprintln!("{what}: AVX2 (the fused kernel) skipped: this CPU has no AVX2 and FMA");
            }
        }
    }

    /// Checks the FMA kernel on one case against the exact test on case `exact` (the same
    /// case, or the one it was scaled from), on every instruction set: with the slack a false
    /// miss fails the test; without it (`SLACK` false) false misses are only counted.
    fn check_fma<const SLACK: bool>(n: &Node, ray: &Ray, exact: (&Node, &Ray), t: &mut Tallies) {
        let fr = FmaRay::new(ray, coord_bound(n));
        let live = n.child_count.min(8) as usize;
        let orders: Vec<Ordering> = (0..live)
            .map(|i| {
                let (lo, hi) = exact.0.view().child_box(i);
                let r = exact.1;
                exact_test(r.origin, r.dir, r.tmin, r.tmax, lo, hi)
            })
            .collect();
        let answers = fma_answers::<SLACK>(&fr, n, ray.tmin, ray.tmax);
        let portable = answers[0].1;
        for (isa, (mask, ts)) in answers {
            let tally = t.get(isa);
            tally.differ += !same((mask, ts), portable) as u64;
            for (i, &t) in ts.iter().enumerate() {
                let got = mask >> i & 1 == 1;
                if i >= live {
                    assert!(!got && t == MISS_T, "slot {i} past the count: {n:?}");
                    continue;
                }
                tally.touching += (orders[i] == Ordering::Equal) as u64;
                let exact = orders[i] != Ordering::Greater;
                if !got && exact {
                    assert!(
                        !SLACK,
                        "{isa}: false miss of child {i}\n{n:?}\n{ray:?}\n{fr:?}"
                    );
                    tally.false_misses += 1;
                }
                if got {
                    assert!(t >= ray.tmin, "{isa}: entry {t} below tmin");
                    tally.hits += 1;
                    tally.false_hits += !exact as u64;
                }
                if !got {
                    assert_eq!(t, MISS_T);
                }
            }
        }
    }

    /// `ray` with its range started at 0 or later, as an eligible ray's is.
    fn from_zero(ray: &Ray) -> Ray {
        Ray::new(ray.origin, ray.dir, ray.tmin.max(0.0), ray.tmax)
    }

    /// No false miss of the FMA test, against the exact test, on the random nodes and rays
    /// (ranges started at 0 or later; every such ray is eligible), with grazing and touching
    /// cases, on every instruction set (AVX2's fused multiply-add among them where the CPU has
    /// it); false hits under 1%.
    #[test]
    fn fma_never_misses_a_child_the_exact_test_hits() {
        let mut r = Rng(0xf3a0_0000_2468_ace1);
        let mut t = Tallies::default();
        let mut grazing = 0u64;
        for _ in 0..150_000 {
            let n = random_node(&mut r);
            let ray = from_zero(&random_ray(&mut r, &n));
            assert!(FmaRay::new(&ray, coord_bound(&n)).eligible(), "{ray:?}");
            check_fma::<true>(&n, &ray, (&n, &ray), &mut t);
            grazing += (0..3).any(|k| {
                ray.dir[k] == 0.0 && {
                    let (lo, hi) = n.view().child_box(0);
                    ray.origin[k] == lo[k] || ray.origin[k] == hi[k]
                }
            }) as u64;
        }
        t.print("random cases");
        eprintln!("{grazing} grazing rays");
        assert!(grazing > 1000, "too few grazing rays: {grazing}");
        for (isa, c) in &t.0 {
            assert!(
                c.hits > 50_000 && c.touching > 1000,
                "{isa}: the cases cover too little: {c:?}"
            );
            assert!(
                c.false_hits * 100 < c.hits,
                "{isa}: too many false hits: {c:?}"
            );
        }
    }

    /// The AVX2 path of the kernel ([`Avx2::fma_node`]) gives what the generic kernel gives on
    /// AVX2, bit for bit, masks and entries, on the random cases and their extreme scalings.
    #[test]
    fn fma_avx2_path_equals_the_generic_kernel() {
        let Some(avx) = Avx2::detect() else {
            eprintln!("AVX2 path not tested: this CPU has no AVX2 and FMA");
            return;
        };
        let mut r = Rng(0x0a5c_2000_1357_9bdf);
        let (mut compared, mut hits) = (0u64, 0u64);
        for i in 0..200_000 {
            let n = random_node(&mut r);
            let mut ray = from_zero(&random_ray(&mut r, &n));
            let mut node = n;
            if i % 2 == 1 {
                let (s, e) = (r.range(-40, 40) as i32, r.range(-40, 60) as i32);
                let Some((m, scaled)) = scaled(&n, &ray, s, e) else {
                    continue;
                };
                (node, ray) = (m, scaled);
            }
            let fr = FmaRay::new(&ray, coord_bound(&node));
            if fr.any_flat {
                continue;
            }
            struct Both<'a>(&'a FmaRay, &'a Node, f32, f32);
            impl WithAvx2 for Both<'_> {
                type Output = ((u32, [f32; 8]), (u32, [f32; 8]));
                #[inline(always)]
                fn run(self, isa: Avx2) -> Self::Output {
                    let Both(fr, n, lo, hi) = self;
                    (
                        fr.kernel_with::<_, true, true>(isa, n.view(), lo, hi),
                        fr.kernel_with::<_, true, false>(isa, n.view(), lo, hi),
                    )
                }
            }
            let (fast, generic) = avx.vectorize(Both(&fr, &node, ray.tmin, ray.tmax));
            assert!(
                same(fast, generic),
                "{node:?} {ray:?}: {fast:?} {generic:?}"
            );
            compared += 1;
            hits += fast.0.count_ones() as u64;
        }
        eprintln!("{compared} nodes compared, {hits} children hit");
        assert!(compared > 50_000 && hits > 20_000, "{compared} {hits}");
    }

    /// The same cases scaled by powers of two (`scaled`), positions by `2^-58..2^61` (grid
    /// exponents within `-64..=63`) and directions by `2^-50..2^126`, so that `t` is scaled by
    /// `2^-176..2^111` (far below the subnormals, where every `t` rounds to 0, to about
    /// `2^100`); those whose ray is eligible are checked against the unscaled exact answers: no
    /// false miss. False hits are counted apart where `t` is scaled below `2^-100`, as there the
    /// slack's `2^-120` is no longer small beside the `t`s (about `2^-90` and below): they are
    /// rare above.
    #[test]
    fn fma_never_misses_at_extreme_scales() {
        let mut r = Rng(0x05ca_1ab1_ef3a);
        let (mut above, mut below) = (Tallies::default(), Tallies::default());
        let (mut tried, mut ineligible, mut tiny, mut huge) = (0u64, 0u64, 0u64, 0u64);
        for _ in 0..150_000 {
            let n = random_node(&mut r);
            let ray = from_zero(&random_ray(&mut r, &n));
            let s = r.range(-58, 61) as i32;
            let e = r.range(-50, 126) as i32;
            let Some((m, sr)) = scaled(&n, &ray, s, e) else {
                continue;
            };
            assert!(
                m.exp
                    .iter()
                    .all(|e| (FMA_EXP_MIN..=FMA_EXP_MAX).contains(e))
            );
            if !FmaRay::new(&sr, coord_bound(&m)).eligible() {
                ineligible += 1;
                continue;
            }
            let t = if s - e < -100 { &mut below } else { &mut above };
            check_fma::<true>(&m, &sr, (&n, &ray), t);
            tried += 1;
            tiny += (s - e < -126) as u64;
            huge += (s - e > 60) as u64;
        }
        above.print("scaled cases, t scaled by 2^-100 or more");
        below.print("scaled cases, t scaled below 2^-100");
        eprintln!(
            "{tried} eligible scaled cases checked ({tiny} with t scaled below 2^-126, {huge} \
             above 2^60), {ineligible} ineligible skipped"
        );
        assert!(
            tried > 70_000 && tiny > 3_000 && huge > 3_000,
            "{tried} scaled cases, {tiny} tiny, {huge} huge"
        );
        for (isa, c) in &above.0 {
            assert!(c.hits > 30_000 && c.touching > 10_000, "{isa}: {c:?}");
            assert!(
                c.false_hits * 100 < c.hits,
                "{isa}: too many false hits: {c:?}"
            );
        }
        for (isa, c) in &below.0 {
            assert!(c.hits > 5_000 && c.touching > 2_000, "{isa}: {c:?}");
        }
    }

    /// How a cancellation case meets child 0.
    #[derive(Clone, Copy, Debug, PartialEq)]
    enum Meet {
        /// Through a point of its boundary at `t = 1`, mostly an edge or a corner (touching).
        Edge,
        /// From a point of one of its faces, at `t = 0`.
        OnFace,
        /// Through its boundary as `Edge`, lying in one of its face planes (`d = 0` there).
        InFacePlane,
    }

    /// A case where the FMA test's multiply-add cancels: the node's grid origin is far from
    /// child 0 (steps of `2^4..2^12`, child 0's faces 128 to 255 steps from the origin), and the
    /// ray meets child 0 exactly at its boundary, from an origin at most 300 away along each
    /// axis (or on a face), so `|q a|` and `|b|` are up to about `2^22 / |d|` with opposite
    /// signs while the `t` that matters is 0 or 1. Half the cases are coarse: the grid's origin
    /// up to 1024 steps from 0 on either side, and every point and direction an integer (so
    /// `p - o` is exact); the other half fine: child 0 at most 8 steps wide and within 12 steps
    /// of 0, so the grid's origin is 128 or more of its widths away, and points and directions
    /// with fractional parts (multiples of `2^-12` rounded to f32), so `RN(p - o)` rounds too.
    /// The directions are rarely powers of two, so `1 / d` rounds.
    fn cancellation_case(r: &mut Rng) -> (Node, Ray, Meet) {
        let fine = r.chance(50);
        let mut n = Node {
            origin: [0.0; 3],
            exp: [0; 3],
            lo: [[0; 8]; 3],
            hi: [[0; 8]; 3],
            child_count: 1 + r.below(8) as u8,
        };
        for k in 0..3 {
            n.exp[k] = r.range(4, 12) as i8;
            let step = grid_step(n.exp[k]);
            for i in 0..n.child_count as usize {
                let low = if i == 0 { 128 } else { 0 };
                let (a, b) = (r.range(low, 255) as u8, r.range(low, 255) as u8);
                (n.lo[k][i], n.hi[k][i]) = (a.min(b), a.max(b));
            }
            n.origin[k] = if fine {
                let (q, w) = (r.range(128, 247), r.range(0, 8));
                (n.lo[k][0], n.hi[k][0]) = (q as u8, (q + w) as u8);
                -((q + r.range(-4, 12)) as f32) * step
            } else {
                r.range(-1024, 1024) as f32 * step
            };
        }
        let (lo, hi) = n.view().child_box(0);
        let meet = match r.below(3) {
            0 => Meet::Edge,
            1 => Meet::OnFace,
            _ => Meet::InFacePlane,
        };
        // Faces are multiples of 16 below 2^23, and the other points are rounded to f32 from
        // multiples of 2^-12: all on the unit grid.
        let unit = if fine { 4096 } else { 1 };
        let off = |r: &mut Rng, a: i64, b: i64| r.range(a * unit, b * unit) as f64 / unit as f64;
        let at = |x: f32, off: f64| (x as f64 + off) as f32;
        let between = |r: &mut Rng, k: usize| at(lo[k], off(r, 0, (hi[k] - lo[k]) as i64));
        let face = |r: &mut Rng, k: usize| if r.chance(50) { lo[k] } else { hi[k] };
        let k0 = r.below(3) as usize;
        let (o, d, (tmin, tmax)) = if meet == Meet::OnFace {
            // On a face of axis k0, within or on the other slabs (or beyond them, sometimes).
            let o: [f32; 3] = std::array::from_fn(|k| match (k == k0, r.below(10)) {
                (true, _) => face(r, k),
                (false, 0..=2) => face(r, k),
                (false, 3) => {
                    let f = face(r, k);
                    at(f, off(r, -300, 300))
                }
                _ => between(r, k),
            });
            let mut d: [f32; 3] = std::array::from_fn(|_| {
                let m = off(r, 1, 999) as f32;
                if r.chance(50) { m } else { -m }
            });
            if r.chance(20) {
                d[(k0 + 1 + r.below(2) as usize) % 3] = 0.0;
            }
            let tmax = if r.chance(50) {
                f32::INFINITY
            } else {
                r.range(0, 1 << 16) as f32 / 256.0
            };
            (o, d, (0.0, tmax))
        } else {
            // A point of the boundary: on a face along at least two axes (all but `free`), or
            // one.
            let free = r.below(3) as usize;
            let on_faces = if r.chance(80) { 2 } else { 1 };
            let e: [f32; 3] = std::array::from_fn(|k| {
                if k == free || (on_faces == 1 && k == (free + 1) % 3) {
                    between(r, k)
                } else {
                    face(r, k)
                }
            });
            // From outside the faces it is on, mostly.
            let mut o: [f32; 3] = std::array::from_fn(|k| {
                let out = off(r, 0, 300);
                let outward = if e[k] == lo[k] { -out } else { out };
                if (e[k] == lo[k] || e[k] == hi[k]) && r.chance(70) {
                    at(e[k], outward)
                } else {
                    at(e[k], off(r, -300, 300))
                }
            });
            if meet == Meet::InFacePlane {
                // Along an axis where the point is on a face.
                let k = (free + 2) % 3;
                o[k] = e[k];
            }
            // `e - o`, exactly: the ray is at `e` at t = 1.
            let mut d: [f32; 3] = std::array::from_fn(|k| {
                let d = e[k] as f64 - o[k] as f64;
                assert_eq!(d as f32 as f64, d, "{e:?} {o:?}");
                d as f32
            });
            if d == [0.0; 3] {
                d = [3.0, -7.0, 5.0];
                o = std::array::from_fn(|k| e[k] - d[k]);
            }
            let range = match r.below(5) {
                0 | 1 => (0.0, f32::INFINITY),
                2 => (0.0, 1.0),
                3 => (1.0, f32::INFINITY),
                _ => (1.0, 1.0),
            };
            (o, d, range)
        };
        (n, Ray::new(o, d, tmin, tmax), meet)
    }

    /// What the cancellation cases cover, for child 0: exact hits, touching ones, hits whose
    /// ray starts on a face plane of it or lies in one, and hits with `|B| = |p - o| / |d|`
    /// above `2^10` along some axis while the `t` that matters is 0 or 1.
    #[derive(Debug, Default)]
    struct Cover {
        cases: u64,
        child0_hits: u64,
        child0_touching: u64,
        from_face: u64,
        in_face_plane: u64,
        cancelling: u64,
    }

    fn cover(c: &mut Cover, n: &Node, ray: &Ray) {
        c.cases += 1;
        let (lo, hi) = n.view().child_box(0);
        let (o, d) = (ray.origin, ray.dir);
        let order = exact_test(o, d, ray.tmin, ray.tmax, lo, hi);
        if order == Ordering::Greater {
            return;
        }
        c.child0_hits += 1;
        c.child0_touching += (order == Ordering::Equal) as u64;
        let on = |k: usize| o[k] == lo[k] || o[k] == hi[k];
        c.from_face += (0..3).any(|k| d[k] != 0.0 && on(k)) as u64;
        c.in_face_plane += (0..3).any(|k| d[k] == 0.0 && on(k)) as u64;
        c.cancelling += (0..3).any(|k| {
            d[k] != 0.0 && ((n.origin[k] as f64 - o[k] as f64) / d[k] as f64).abs() > 1024.0
        }) as u64;
    }

    /// No false miss of the FMA test where its multiply-add cancels (see
    /// [`cancellation_case`]): rays through a child's edges and corners, from its faces, in its
    /// face planes, with the grid's origin far away. The robust [`BoxRay`] test, whose faces
    /// are exact, misses none either.
    #[test]
    fn fma_never_misses_where_the_sum_cancels() {
        let mut r = Rng(0xca9c_e11a_7105);
        let mut t = Tallies::default();
        let mut c = Cover::default();
        for _ in 0..100_000 {
            let (n, ray, _) = cancellation_case(&mut r);
            assert!(FmaRay::new(&ray, coord_bound(&n)).eligible(), "{ray:?}");
            check_fma::<true>(&n, &ray, (&n, &ray), &mut t);
            check(&n, &ray, (&n, &ray));
            cover(&mut c, &n, &ray);
        }
        t.print("cancellation cases");
        eprintln!("{c:?}");
        assert!(
            c.child0_hits > 80_000
                && c.child0_touching > 30_000
                && c.from_face > 20_000
                && c.in_face_plane > 10_000
                && c.cancelling > 40_000,
            "the cases cover too little: {c:?}"
        );
        for (isa, c) in &t.0 {
            assert!(
                c.false_hits * 20 < c.hits,
                "{isa}: too many false hits: {c:?}"
            );
        }
    }

    /// The slack is needed: the FMA kernel without it (`b` unmoved, only the exit's relative
    /// growth) misses children the exact test hits on the cancellation cases, on every
    /// instruction set (fused or not).
    #[test]
    fn without_the_slack_the_fma_test_misses() {
        let mut r = Rng(0xca9c_e11a_7105);
        let mut by_meet: [Tallies; 3] = Default::default();
        for _ in 0..100_000 {
            let (n, ray, meet) = cancellation_case(&mut r);
            check_fma::<false>(&n, &ray, (&n, &ray), &mut by_meet[meet as usize]);
        }
        let mut total = Tallies::default();
        for (t, meet) in by_meet
            .iter()
            .zip(["through an edge", "from a face", "in a face plane"])
        {
            t.print(&format!("cancellation cases {meet}, without the slack"));
            for (isa, c) in &t.0 {
                total.get(isa).false_misses += c.false_misses;
            }
        }
        for (isa, c) in &total.0 {
            eprintln!("{isa}: {} false misses without the slack", c.false_misses);
            assert!(
                c.false_misses > 100,
                "{isa}: the slack was not needed? {c:?}"
            );
        }
    }

    /// The doc's bound plane by plane: the sum the last rounding sees, `q a + bn` (fused) or
    /// `RN(q a) + bn` (not), is below `r (p + q 2^e - o)` (`(1 + δ0) T`, exactly), and the far
    /// plane's sum with `bf` above it, on planes that cancel and planes that do not (the ray's
    /// origin on the plane, near it, or anywhere; `q` from 0 to 255; fractional points and
    /// directions). Exact, in integers of `2^-68` (every value here is a multiple of it: the
    /// test asserts so). Without the slack, the sums land on the wrong side of it on some
    /// planes, fused or not, and by at most the bound's `3u |b| + 256u |a|`: the largest
    /// misses seen are printed, in units of `u |b|` (fused) and `u (|b| + 255 |a|)` (not).
    #[test]
    fn fma_plane_sums_bracket_the_exact_plane() {
        /// `x` in units of `2^-bits`, exactly.
        fn units_of(x: f64, bits: i32) -> i128 {
            let v = x * 2f64.powi(bits);
            assert!(
                v.fract() == 0.0 && v.abs() < 2f64.powi(100),
                "{x} off the grid"
            );
            v as i128
        }
        let units = |x: f64| units_of(x, 68);
        let mut r = Rng(0x91a7e);
        let fine =
            |r: &mut Rng, a: i64, b: i64| (r.range(a * 4096, b * 4096) as f64 / 4096.0) as f32;
        let (mut wrong_fused, mut wrong_twice) = (0u64, 0u64);
        let (mut worst_fused, mut worst_twice) = (0f64, 0f64);
        for i in 0..400_000 {
            let e = r.range(4, 12) as i8;
            let step = grid_step(e);
            let p = r.range(-1024, 1024) as f32 * step;
            let q = r.below(256) as u8;
            let face = p + q as f32 * step;
            let o = match r.below(5) {
                0 => face,
                1 | 2 => (face as f64 + fine(&mut r, -300, 300) as f64) as f32,
                _ => fine(&mut r, -(1 << 22), 1 << 22),
            };
            let d = fine(&mut r, 1, 1000).max(0.25) * if r.chance(50) { 1.0 } else { -1.0 };
            // The kernel's scalars.
            let inv = FmaRay::new(&Ray::new([o; 3], [d; 3], 0.0, 1.0), 0.0).inv[0];
            let (a, bn, bf) = fma_terms::<true>(inv, p, o, step);
            let b = fma_terms::<false>(inv, p, o, step).1;
            // r (face - o) = (1 + δ0) T, exactly: r on 2^-34, face - o on 2^-12.
            let exact = units_of(inv as f64, 34) * units_of(face as f64 - o as f64, 12) * (1 << 22);
            let fused = |c: f32| q as i128 * units(a as f64) + units(c as f64);
            let twice = |c: f32| units((q as f32 * a) as f64) + units(c as f64);
            for (sum, wrong, worst, scale) in [
                (
                    &fused as &dyn Fn(f32) -> i128,
                    &mut wrong_fused,
                    &mut worst_fused,
                    b.abs(),
                ),
                (
                    &twice,
                    &mut wrong_twice,
                    &mut worst_twice,
                    b.abs() + 255.0 * a.abs(),
                ),
            ] {
                assert!(sum(bn) < exact, "near plane {i}: {p} {q} {e} {o} {d}");
                assert!(sum(bf) > exact, "far plane {i}: {p} {q} {e} {o} {d}");
                // Without the slack: on the wrong side sometimes, by at most the bound.
                let miss = sum(b) - exact;
                *wrong += (miss != 0) as u64;
                let bound = 3 * units(b.abs() as f64) + 256 * units(a.abs() as f64);
                assert!(miss.abs() << 24 <= bound, "plane {i}: {miss} {bound}");
                if scale > 0.0 {
                    let ratio = miss.abs() as f64 / (scale as f64 * 2f64.powi(68 - 24));
                    *worst = worst.max(ratio);
                }
            }
        }
        eprintln!(
            "without the slack: fused sums off (1 + δ0) T on {wrong_fused} planes, by up to \
             {worst_fused:.3} u |b|; unfused on {wrong_twice}, by up to {worst_twice:.3} u \
             (|b| + 255 |a|)"
        );
        assert!(wrong_fused > 10_000 && wrong_twice > 10_000);
        assert!(
            worst_fused > 1.5 && worst_twice > 1.0,
            "the bound is far from tight"
        );
    }

    /// Which rays are eligible: a range from below 0, a direction component whose inverse is
    /// above `2^55` or not normal, an origin or a `coord_bound` so far out that
    /// `(|o| + bound) / |d|` exceeds `2^100` make a ray ineligible; ordinary rays, and
    /// axes the ray does not move along whatever the origin, do not.
    #[test]
    fn fma_eligibility() {
        let inf = f32::INFINITY;
        let ok = |o: [f32; 3], d: [f32; 3], tmin: f32, bound: f32| {
            FmaRay::new(&Ray::new(o, d, tmin, inf), bound).eligible()
        };
        let (o, d) = ([1.0, -2.0, 3.5], [0.3, -0.5, 0.7]);
        assert!(ok(o, d, 0.0, 1e4));
        assert!(ok(o, d, -0.0, 1e4));
        assert!(ok(o, d, 17.0, 1e4));
        assert!(ok(o, [1.0, 0.0, -0.0], 0.0, 1e4));
        // Ranges from below 0 (or NaN).
        assert!(!ok(o, d, -1e-3, 1e4));
        assert!(!ok(o, d, -inf, 1e4));
        assert!(!ok(o, d, f32::NAN, 1e4));
        // Tiny components: 1 / d above 2^55; 2^-55 itself is eligible.
        assert!(!ok(o, [1e-30, 1.0, 1.0], 0.0, 1e4));
        assert!(!ok(o, [1.0, 2f32.powi(-56), 1.0], 0.0, 1e4));
        assert!(ok(o, [1.0, 2f32.powi(-55), 1.0], 0.0, 1e4));
        assert!(!ok(o, [1.0, f32::from_bits(1), 1.0], 0.0, 1e4));
        // Huge components: 1 / d subnormal or 0; and NaN.
        assert!(!ok(o, [1e38, 1.0, 1.0], 0.0, 1e4));
        assert!(!ok(o, [inf, 1.0, 1.0], 0.0, 1e4));
        assert!(!ok(o, [f32::NAN, 1.0, 1.0], 0.0, 1e4));
        // Huge origins: (|o| + bound) / |d| above 2^100 (about 1.27e30).
        assert!(!ok([1e30, 0.0, 0.0], [0.5, 1.0, 1.0], 0.0, 1e4));
        assert!(!ok([2e30, 0.0, 0.0], [1.0, 1.0, 1.0], 0.0, 1e4));
        assert!(!ok([0.0, 0.0, 1e20], [1.0, 1.0, 1e-12], 0.0, 1e4));
        assert!(!ok([0.0, inf, 0.0], d, 0.0, 1e4));
        // 1e30 with |d| = 1 is just within it; along an axis it does not move along, any.
        assert!(ok([1e30, 0.0, 0.0], [1.0, 1.0, 1.0], 0.0, 1e4));
        assert!(ok([0.0, 1e38, 0.0], [1.0, 0.0, 1.0], 0.0, 1e4));
        // The bound counts as the origin does.
        assert!(!ok(o, d, 0.0, 1e30));
        assert!(!ok(o, d, 0.0, f32::MAX));
        assert!(!ok(o, d, 0.0, f32::NAN));
        // Ordinary rays of the random cases.
        let mut r = Rng(12);
        for _ in 0..10_000 {
            let n = random_node(&mut r);
            let ray = random_ray(&mut r, &n);
            let fr = FmaRay::new(&ray, coord_bound(&n));
            assert_eq!(fr.eligible(), ray.tmin >= 0.0, "{ray:?}");
        }
    }

    /// Any bytes (exponents outside `-64..=63` among them, clamped): no panic, only live
    /// slots reported, misses at `+inf`.
    #[test]
    fn fma_garbage_nodes_give_some_mask() {
        let mut r = Rng(199);
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
            let fr = FmaRay::new(&ray, coord_bound(&near));
            for (isa, (mask, ts)) in fma_answers::<true>(&fr, &n, ray.tmin, ray.tmax) {
                assert_eq!(mask & !n.view().live(), 0, "{isa}");
                for (i, t) in ts.iter().enumerate() {
                    assert!(mask >> i & 1 == 1 || *t == MISS_T, "{isa}");
                }
            }
        }
    }
}
