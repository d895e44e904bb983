//! SIMD for the tracer's kernels: the instruction sets, as tokens, and the only `unsafe` the
//! kernels need.
//!
//! A kernel (the watertight test on a triangle group, the box test on a cluster node; see
//! `geom::group` and `geom::wide_box`) is written once, generic over [`Simd8`]: eight `f32`
//! lanes and the few operations the kernels use, each a correctly rounded IEEE operation or a
//! bit-exact move. It is instantiated for three implementations of the trait:
//!
//! - [`Avx2`], one 256-bit register per eight lanes. A token that exists only if the CPU has
//!   AVX2 and FMA ([`Avx2::detect`]); a computation runs compiled for those features through
//!   [`Avx2::vectorize`]. The design is pulp's (Sarah Quiñones, `pulp::Simd`): the computation
//!   is a value implementing [`WithAvx2`], whose `run` (and everything below it) is
//!   `#[inline(always)]`, so that it is inlined into a private `#[target_feature(enable =
//!   "avx2,fma")]` trampoline and compiled whole with AVX2: the wrappers below inline into it
//!   as single instructions, with no call per operation.
//! - [`Sse41`], two 128-bit registers per eight lanes, on the low and high four. It exists
//!   only where the crate is compiled with SSE4.1 enabled (`.cargo/config.toml` builds for
//!   x86-64-v2), so it needs no check at run time; builds without it (the fuzzers', whose
//!   `RUSTFLAGS` replace the config's) use [`Portable`].
//! - [`Portable`], eight scalars: for any architecture, and the reference the others match.
//!
//! The same operations in the same order give bit-identical lanes in all three, with one
//! exception: every arithmetic operation but [`Simd8::mul_add`] is one correctly rounded IEEE
//! operation (LLVM never contracts a multiply and an add into a fused multiply-add without
//! fast-math flags), and `min`/`max` follow the x86 rule, NaN-aware in a way the box test
//! relies on. `mul_add` is a fused multiply-add on [`Avx2`] (one rounding) and a multiply then
//! an add elsewhere (two roundings). Only the FMA node test (`geom::wide_box::FmaRay`) uses it:
//! its answers (a culling mask and entries) may differ between instruction sets, and every one
//! of them stays conservative, by a bound that covers both roundings.
//!
//! Loads take references to arrays (`&[f32; 8]`, `&[u8; 8]`), never raw pointers, so callers
//! stay safe code: the crate root denies `unsafe` everywhere but here.

/// Eight `f32` lanes and the operations the kernels use. Masks are lanes of all ones (true)
/// or all zeros (false), as the comparisons return them.
///
/// Every method is `#[inline(always)]`: inside [`Avx2::vectorize`] it must become an
/// instruction of the AVX2-compiled computation, not a call.
pub trait Simd8: Copy {
    /// Eight `f32` lanes (or masks).
    type F: Copy;
    /// Eight lane indices, prepared by [`Simd8::slots`] for [`Simd8::permute`].
    type Idx: Copy;

    fn splat(self, x: f32) -> Self::F;
    fn load(self, x: &[f32; 8]) -> Self::F;
    fn store(self, v: Self::F) -> [f32; 8];
    /// Lane `l` is `q[l]` as an `f32` (exact).
    fn bytes(self, q: &[u8; 8]) -> Self::F;

    fn add(self, a: Self::F, b: Self::F) -> Self::F;
    fn sub(self, a: Self::F, b: Self::F) -> Self::F;
    fn mul(self, a: Self::F, b: Self::F) -> Self::F;
    fn div(self, a: Self::F, b: Self::F) -> Self::F;
    /// `a * b + c` per lane, rounded once or twice depending on the instruction set: a fused
    /// multiply-add on [`Avx2`] (`vfmadd`, one rounding), `add(mul(a, b), c)` on `Sse41` and
    /// [`Portable`] (two roundings). The one operation whose lanes differ between tokens: a
    /// caller must be correct under either rounding (the FMA node test's error bound covers
    /// both), and must not expect the tokens to agree bit for bit.
    fn mul_add(self, a: Self::F, b: Self::F, c: Self::F) -> Self::F;
    /// `a < b ? a : b` per lane (x86 `minps`): `b` where either is NaN.
    fn min(self, a: Self::F, b: Self::F) -> Self::F;
    /// `a > b ? a : b` per lane (x86 `maxps`): `b` where either is NaN.
    fn max(self, a: Self::F, b: Self::F) -> Self::F;

    /// `a == b` (false where either is NaN).
    fn eq(self, a: Self::F, b: Self::F) -> Self::F;
    /// `a != b` (true where either is NaN), Rust's `!=`.
    fn ne(self, a: Self::F, b: Self::F) -> Self::F;
    fn lt(self, a: Self::F, b: Self::F) -> Self::F;
    fn le(self, a: Self::F, b: Self::F) -> Self::F;
    fn ge(self, a: Self::F, b: Self::F) -> Self::F;
    fn and(self, a: Self::F, b: Self::F) -> Self::F;
    fn or(self, a: Self::F, b: Self::F) -> Self::F;
    /// Per lane, `yes` where the sign bit of `m` is set, else `no`. For a mask, `m ? yes : no`;
    /// for a value, `m < 0 ? yes : no` with `-0.0` and negative NaNs counting as negative.
    fn select(self, m: Self::F, yes: Self::F, no: Self::F) -> Self::F;
    /// The sign bits of the eight lanes, lane `l` as bit `l` (for masks: which lanes are true).
    fn bits(self, m: Self::F) -> u32;

    /// Prepares slot indices: lane `l` of [`Simd8::permute`] reads slot `s[l] & 7`.
    fn slots(self, s: &[u8; 8]) -> Self::Idx;
    /// Lane `l` is lane `s[l] & 7` of `v`, for the `s` that `i` was prepared from.
    fn permute(self, v: Self::F, i: Self::Idx) -> Self::F;

    /// This token as [`Avx2`], if it is one: lets a kernel take a path written for AVX2 (a
    /// constant per instantiation, so the other path is compiled out).
    #[inline(always)]
    fn as_avx2(self) -> Option<Avx2> {
        None
    }

    /// A mask of the lanes below `n` (all eight for `n >= 8`).
    #[inline(always)]
    fn lanes_below(self, n: u32) -> Self::F {
        const IOTA: [f32; 8] = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0];
        self.lt(self.load(&IOTA), self.splat(n.min(8) as f32))
    }

    /// The eight children of an octree cell, in `f64`: child `o` (bit 0 its half along x, bit
    /// 1 along y, bit 2 along z) is entered at `max(tmin, enter[0][x], enter[1][y],
    /// enter[2][z])` and left at the `min` of `tmax` and the matching `exit`s; bit `o` of the
    /// mask is set when it is entered no later than it is left, and `t[o]` is where it is
    /// entered. `max(a, b)` is `a > b ? a : b` (and `min` likewise), the x86 rule: a NaN in
    /// `a` gives `b`; a NaN entry or exit fails the comparison (a miss).
    ///
    /// Eight scalars by default (SSE has no gain to offer over them here); AVX2 does it in two
    /// registers of four.
    #[inline(always)]
    fn cell_hits(
        self,
        enter: &[[f64; 2]; 3],
        exit: &[[f64; 2]; 3],
        tmin: f64,
        tmax: f64,
    ) -> (u32, [f64; 8]) {
        cell_hits_scalar(enter, exit, tmin, tmax)
    }
}

/// [`Simd8::cell_hits`] one child at a time: the reference the vector versions equal.
#[inline(always)]
pub fn cell_hits_scalar(
    enter: &[[f64; 2]; 3],
    exit: &[[f64; 2]; 3],
    tmin: f64,
    tmax: f64,
) -> (u32, [f64; 8]) {
    let fmax = |a: f64, b: f64| if a > b { a } else { b };
    let fmin = |a: f64, b: f64| if a < b { a } else { b };
    let mut t = [0f64; 8];
    let mut mask = 0u32;
    for (o, t) in t.iter_mut().enumerate() {
        let (x, y, z) = (o & 1, (o >> 1) & 1, o >> 2);
        let ent = fmax(fmax(enter[0][x], enter[1][y]), fmax(tmin, enter[2][z]));
        let ext = fmin(fmin(exit[0][x], exit[1][y]), fmin(tmax, exit[2][z]));
        *t = ent;
        mask |= ((ent <= ext) as u32) << o;
    }
    (mask, t)
}

/// The computation [`Avx2::vectorize`] runs compiled for AVX2 and FMA. `run` and everything it
/// calls must be `#[inline(always)]` (or plain `#[inline]` functions the trampoline can
/// inline): a function that is not inlined is compiled without AVX2, and each wrapper it calls
/// becomes a call.
pub trait WithAvx2 {
    type Output;
    fn run(self, isa: Avx2) -> Self::Output;
}

/// Proof that the CPU has AVX2 and FMA: the only constructor is [`Avx2::detect`], which asks
/// the CPU. Zero-sized; copy it freely.
#[derive(Clone, Copy, Debug)]
pub struct Avx2 {
    /// Private: no token but `detect`'s. On other architectures, uninhabited.
    #[cfg(target_arch = "x86_64")]
    _private: (),
    #[cfg(not(target_arch = "x86_64"))]
    never: std::convert::Infallible,
}

impl Avx2 {
    /// The token, if this CPU has AVX2 and FMA. Cheap to call repeatedly: std caches what the
    /// CPU said (one atomic load per feature after the first call).
    #[inline]
    pub fn detect() -> Option<Avx2> {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            return Some(Avx2 { _private: () });
        }
        None
    }

    /// Runs `t` compiled for AVX2 and FMA (see [`WithAvx2`]). From code that is itself inside
    /// a `vectorize`, the trampoline inlines too: nesting costs nothing.
    #[inline(always)]
    pub fn vectorize<T: WithAvx2>(self, t: T) -> T::Output {
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx2,fma")]
            #[inline]
            fn trampoline<T: WithAvx2>(isa: Avx2, t: T) -> T::Output {
                t.run(isa)
            }
            // SAFETY: a token exists only if the CPU has AVX2 and FMA (`detect`), the features
            // the trampoline is compiled for.
            unsafe { trampoline(self, t) }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = t;
            match self.never {}
        }
    }
}

/// The per-ray constants of the FMA node test (`geom::wide_box::FmaRay`) as its AVX2 kernel
/// reads them: the origin and the reciprocal direction in the low three lanes (the fourth 0),
/// and per axis which face row the ray enters by (0: `lo`, 1: `hi`).
#[derive(Clone, Copy, Debug, Default)]
pub struct FmaNodeRay {
    pub origin: [f32; 4],
    pub inv: [f32; 4],
    pub near: [usize; 3],
}

/// A wide node's fields as the FMA node test reads them (the record of format-spec §7.1).
#[derive(Clone, Copy, Debug)]
pub struct FmaNodeFields<'a> {
    pub origin: &'a [f32; 3],
    pub exp: &'a [i8; 3],
    pub rows: [&'a [[u8; 8]; 3]; 2],
    pub child_count: u8,
}

impl Avx2 {
    /// The FMA node test of `geom::wide_box::FmaRay` for a ray that moves along every axis,
    /// the three axes' scalar terms computed at once in one 128-bit register: the same
    /// operations in the same order as the generic kernel (so the same answers, bit for bit:
    /// `FmaRay`'s tests compare them), about half its instructions. The constants are the
    /// kernel's: `exp` clamped to `-64..=63`, slack `|b| 2^-22 + |a| 2^-14 + 2^-120`, exit
    /// grown by `1 + 2^-21`.
    #[inline(always)]
    pub fn fma_node(
        self,
        ray: &FmaNodeRay,
        n: FmaNodeFields<'_>,
        tmin: f32,
        tmax: f32,
    ) -> (u32, [f32; 8]) {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::*;
            // SAFETY: the token exists only if the CPU has AVX2 and FMA (`Avx2::detect`); the
            // loads read only the arrays they are given (`_mm_loadl_epi64` the eight bytes of
            // a row), the rest are register operations.
            unsafe {
                let p = _mm_set_ps(0.0, n.origin[2], n.origin[1], n.origin[0]);
                let e = _mm_set_epi32(0, n.exp[2] as i32, n.exp[1] as i32, n.exp[0] as i32);
                let e = _mm_min_epi32(_mm_max_epi32(e, _mm_set1_epi32(-64)), _mm_set1_epi32(63));
                let step =
                    _mm_castsi128_ps(_mm_slli_epi32::<23>(_mm_add_epi32(e, _mm_set1_epi32(127))));
                let r = _mm_loadu_ps(ray.inv.as_ptr());
                let o = _mm_loadu_ps(ray.origin.as_ptr());
                let a = _mm_mul_ps(r, step);
                let b = _mm_mul_ps(_mm_sub_ps(p, o), r);
                let abs = _mm_castsi128_ps(_mm_set1_epi32(0x7fff_ffff));
                let s = _mm_add_ps(
                    _mm_add_ps(
                        _mm_mul_ps(_mm_and_ps(b, abs), _mm_set1_ps(1.0 / (1u32 << 22) as f32)),
                        _mm_mul_ps(_mm_and_ps(a, abs), _mm_set1_ps(1.0 / (1u32 << 14) as f32)),
                    ),
                    _mm_set1_ps(f32::from_bits((127 - 120) << 23)),
                );
                let bn = _mm_sub_ps(b, s);
                let bf = _mm_add_ps(b, s);
                let (a, bn, bf): ([f32; 4], [f32; 4], [f32; 4]) = (
                    std::mem::transmute::<__m128, [f32; 4]>(a),
                    std::mem::transmute::<__m128, [f32; 4]>(bn),
                    std::mem::transmute::<__m128, [f32; 4]>(bf),
                );
                let row = |q: &[u8; 8]| {
                    _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_loadl_epi64(
                        q.as_ptr().cast::<__m128i>(),
                    )))
                };
                let mut enter = _mm256_set1_ps(tmin);
                let mut leave = _mm256_set1_ps(tmax);
                for k in 0..3 {
                    let near = ray.near[k] & 1;
                    let av = _mm256_set1_ps(a[k]);
                    let tn = _mm256_fmadd_ps(row(&n.rows[near][k]), av, _mm256_set1_ps(bn[k]));
                    let tf = _mm256_fmadd_ps(row(&n.rows[near ^ 1][k]), av, _mm256_set1_ps(bf[k]));
                    enter = _mm256_max_ps(tn, enter);
                    leave = _mm256_min_ps(tf, leave);
                }
                const IOTA: [f32; 8] = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0];
                let live = _mm256_cmp_ps::<_CMP_LT_OQ>(
                    _mm256_loadu_ps(IOTA.as_ptr()),
                    _mm256_set1_ps(n.child_count.min(8) as f32),
                );
                let grown = _mm256_mul_ps(leave, _mm256_set1_ps(1.0 + 8.0 / (1u32 << 24) as f32));
                let hit = _mm256_and_ps(live, _mm256_cmp_ps::<_CMP_LE_OQ>(enter, grown));
                let t = _mm256_blendv_ps(_mm256_set1_ps(f32::INFINITY), enter, hit);
                (
                    _mm256_movemask_ps(hit) as u32,
                    std::mem::transmute::<__m256, [f32; 8]>(t),
                )
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = (ray, n, tmin, tmax);
            match self.never {}
        }
    }
}

/// Proof that the CPU has SSE4.1 (and SSSE3): the crate is compiled for it, so every CPU the
/// code runs on has it. Exists only in such builds; zero-sized.
#[cfg(all(target_arch = "x86_64", target_feature = "sse4.1"))]
#[derive(Clone, Copy, Debug, Default)]
pub struct Sse41 {
    _private: (),
}

#[cfg(all(target_arch = "x86_64", target_feature = "sse4.1"))]
impl Sse41 {
    /// The token (the build enables SSE4.1, which implies SSSE3).
    #[inline(always)]
    pub const fn new() -> Sse41 {
        Sse41 { _private: () }
    }
}

/// Eight lanes as eight scalars, on any architecture: the same operations one lane at a time.
#[derive(Clone, Copy, Debug, Default)]
pub struct Portable;

/// A method of a token's [`Simd8`] implementation that is one expression of intrinsics.
#[cfg(target_arch = "x86_64")]
macro_rules! intrinsics {
    ($($name:ident($($a:ident: $t:ty),*) -> $r:ty = $e:expr;)*) => {$(
        #[inline(always)]
        fn $name(self, $($a: $t),*) -> $r {
            // SAFETY: the token exists only if the CPU has the instructions: `Avx2` only if it
            // has AVX2 and FMA (`Avx2::detect`), `Sse41` only in builds for SSE4.1 (its cfg).
            // The intrinsics read and write no memory but their arguments and results.
            unsafe { $e }
        }
    )*};
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    use super::{Avx2, Simd8};

    impl Simd8 for Avx2 {
        type F = __m256;
        type Idx = __m256i;

        #[inline(always)]
        fn as_avx2(self) -> Option<Avx2> {
            Some(self)
        }

        #[inline(always)]
        fn load(self, x: &[f32; 8]) -> __m256 {
            bytemuck::cast(*x)
        }
        #[inline(always)]
        fn store(self, v: __m256) -> [f32; 8] {
            bytemuck::cast(v)
        }
        intrinsics! {
            splat(x: f32) -> __m256 = _mm256_set1_ps(x);
            bytes(q: &[u8; 8]) -> __m256 = _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(
                _mm_cvtsi64_si128(i64::from_le_bytes(*q)),
            ));
            add(a: __m256, b: __m256) -> __m256 = _mm256_add_ps(a, b);
            sub(a: __m256, b: __m256) -> __m256 = _mm256_sub_ps(a, b);
            mul(a: __m256, b: __m256) -> __m256 = _mm256_mul_ps(a, b);
            div(a: __m256, b: __m256) -> __m256 = _mm256_div_ps(a, b);
            // One rounding: the token exists only if the CPU has FMA.
            mul_add(a: __m256, b: __m256, c: __m256) -> __m256 = _mm256_fmadd_ps(a, b, c);
            min(a: __m256, b: __m256) -> __m256 = _mm256_min_ps(a, b);
            max(a: __m256, b: __m256) -> __m256 = _mm256_max_ps(a, b);
            eq(a: __m256, b: __m256) -> __m256 = _mm256_cmp_ps::<_CMP_EQ_OQ>(a, b);
            ne(a: __m256, b: __m256) -> __m256 = _mm256_cmp_ps::<_CMP_NEQ_UQ>(a, b);
            lt(a: __m256, b: __m256) -> __m256 = _mm256_cmp_ps::<_CMP_LT_OQ>(a, b);
            le(a: __m256, b: __m256) -> __m256 = _mm256_cmp_ps::<_CMP_LE_OQ>(a, b);
            ge(a: __m256, b: __m256) -> __m256 = _mm256_cmp_ps::<_CMP_GE_OQ>(a, b);
            and(a: __m256, b: __m256) -> __m256 = _mm256_and_ps(a, b);
            or(a: __m256, b: __m256) -> __m256 = _mm256_or_ps(a, b);
            select(m: __m256, yes: __m256, no: __m256) -> __m256 = _mm256_blendv_ps(no, yes, m);
            bits(m: __m256) -> u32 = _mm256_movemask_ps(m) as u32;
            // `vpermps` reads the low three bits of each index: the `& 7` of the slots.
            slots(s: &[u8; 8]) -> __m256i = _mm256_cvtepu8_epi32(
                _mm_cvtsi64_si128(i64::from_le_bytes(*s)),
            );
            permute(v: __m256, i: __m256i) -> __m256 = _mm256_permutevar8x32_ps(v, i);
        }

        #[inline(always)]
        fn cell_hits(
            self,
            enter: &[[f64; 2]; 3],
            exit: &[[f64; 2]; 3],
            tmin: f64,
            tmax: f64,
        ) -> (u32, [f64; 8]) {
            // SAFETY: the token exists only if the CPU has AVX2 (`Avx2::detect`). The
            // intrinsics read and write no memory but their arguments and results.
            unsafe {
                // Children 0..4 (low z) in one register, 4..8 in the other; lane `i` is child
                // `i` (x = bit 0, y = bit 1). `_mm256_set_pd` lists lanes from the highest.
                let per_x = |v: &[f64; 2]| _mm256_set_pd(v[1], v[0], v[1], v[0]);
                let per_y = |v: &[f64; 2]| _mm256_set_pd(v[1], v[1], v[0], v[0]);
                // `maxpd(a, b)` is `a > b ? a : b`, as the scalar reference's `fmax`.
                let exy = _mm256_max_pd(per_x(&enter[0]), per_y(&enter[1]));
                let xxy = _mm256_min_pd(per_x(&exit[0]), per_y(&exit[1]));
                let tmin = _mm256_set1_pd(tmin);
                let tmax = _mm256_set1_pd(tmax);
                let e_lo = _mm256_max_pd(exy, _mm256_max_pd(tmin, _mm256_set1_pd(enter[2][0])));
                let e_hi = _mm256_max_pd(exy, _mm256_max_pd(tmin, _mm256_set1_pd(enter[2][1])));
                let x_lo = _mm256_min_pd(xxy, _mm256_min_pd(tmax, _mm256_set1_pd(exit[2][0])));
                let x_hi = _mm256_min_pd(xxy, _mm256_min_pd(tmax, _mm256_set1_pd(exit[2][1])));
                let m_lo = _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_LE_OQ>(e_lo, x_lo)) as u32;
                let m_hi = _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_LE_OQ>(e_hi, x_hi)) as u32;
                let t: [[f64; 4]; 2] = [bytemuck::cast(e_lo), bytemuck::cast(e_hi)];
                (m_lo | (m_hi << 4), bytemuck::cast(t))
            }
        }
    }

    #[cfg(target_feature = "sse4.1")]
    mod sse {
        use std::arch::x86_64::*;

        use super::super::{Simd8, Sse41};

        /// One half of a prepared permutation: the `pshufb` control that moves slot `s & 3`'s
        /// four bytes into each lane, and a mask of the lanes whose slot is in the high half.
        #[derive(Clone, Copy, Debug)]
        pub struct HalfIdx {
            ctrl: __m128i,
            high: __m128,
        }

        impl Sse41 {
            /// [`HalfIdx`] for lanes `4 h .. 4 h + 4` of the slot bytes in `raw`'s low eight
            /// bytes (`spread` repeats each of those four bytes four times).
            #[inline(always)]
            fn half(self, raw: __m128i, spread: __m128i) -> HalfIdx {
                // SAFETY: `Sse41` exists only in builds for SSE4.1, which implies SSSE3. No
                // memory is touched.
                unsafe {
                    let s = _mm_shuffle_epi8(raw, spread);
                    // Byte `4 l + b` of the control is `4 (s & 3) + b`: the shift moves bytes of
                    // at most 3 by two bits, so nothing crosses into the next byte.
                    let within = _mm_slli_epi32::<2>(_mm_and_si128(s, _mm_set1_epi8(3)));
                    let ctrl = _mm_or_si128(
                        within,
                        _mm_setr_epi8(0, 1, 2, 3, 0, 1, 2, 3, 0, 1, 2, 3, 0, 1, 2, 3),
                    );
                    let four = _mm_set1_epi8(4);
                    let high = _mm_castsi128_ps(_mm_cmpeq_epi8(_mm_and_si128(s, four), four));
                    HalfIdx { ctrl, high }
                }
            }

            #[inline(always)]
            fn pick(self, v: [__m128; 2], h: HalfIdx) -> __m128 {
                // SAFETY: `Sse41` exists only in builds for SSE4.1, which implies SSSE3. No
                // memory is touched.
                unsafe {
                    let lo = _mm_shuffle_epi8(_mm_castps_si128(v[0]), h.ctrl);
                    let hi = _mm_shuffle_epi8(_mm_castps_si128(v[1]), h.ctrl);
                    _mm_blendv_ps(_mm_castsi128_ps(lo), _mm_castsi128_ps(hi), h.high)
                }
            }
        }

        impl Simd8 for Sse41 {
            type F = [__m128; 2];
            type Idx = [HalfIdx; 2];

            #[inline(always)]
            fn load(self, x: &[f32; 8]) -> [__m128; 2] {
                bytemuck::cast(*x)
            }
            #[inline(always)]
            fn store(self, v: [__m128; 2]) -> [f32; 8] {
                bytemuck::cast(v)
            }
            #[inline(always)]
            fn slots(self, s: &[u8; 8]) -> [HalfIdx; 2] {
                // SAFETY: `Sse41` exists only in builds for SSE4.1. No memory is touched.
                let (raw, spread) = unsafe {
                    (
                        _mm_cvtsi64_si128(i64::from_le_bytes(*s)),
                        [
                            _mm_setr_epi8(0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3),
                            _mm_setr_epi8(4, 4, 4, 4, 5, 5, 5, 5, 6, 6, 6, 6, 7, 7, 7, 7),
                        ],
                    )
                };
                [self.half(raw, spread[0]), self.half(raw, spread[1])]
            }
            #[inline(always)]
            fn permute(self, v: [__m128; 2], i: [HalfIdx; 2]) -> [__m128; 2] {
                [self.pick(v, i[0]), self.pick(v, i[1])]
            }
            intrinsics! {
                splat(x: f32) -> [__m128; 2] = [_mm_set1_ps(x); 2];
                bytes(q: &[u8; 8]) -> [__m128; 2] = {
                    let raw = _mm_cvtsi64_si128(i64::from_le_bytes(*q));
                    [
                        _mm_cvtepi32_ps(_mm_cvtepu8_epi32(raw)),
                        _mm_cvtepi32_ps(_mm_cvtepu8_epi32(_mm_srli_si128::<4>(raw))),
                    ]
                };
                add(a: [__m128; 2], b: [__m128; 2]) -> [__m128; 2] =
                    [_mm_add_ps(a[0], b[0]), _mm_add_ps(a[1], b[1])];
                sub(a: [__m128; 2], b: [__m128; 2]) -> [__m128; 2] =
                    [_mm_sub_ps(a[0], b[0]), _mm_sub_ps(a[1], b[1])];
                mul(a: [__m128; 2], b: [__m128; 2]) -> [__m128; 2] =
                    [_mm_mul_ps(a[0], b[0]), _mm_mul_ps(a[1], b[1])];
                div(a: [__m128; 2], b: [__m128; 2]) -> [__m128; 2] =
                    [_mm_div_ps(a[0], b[0]), _mm_div_ps(a[1], b[1])];
                // Two roundings (SSE4.1 has no FMA): `add(mul(a, b), c)`, as `Portable`.
                mul_add(a: [__m128; 2], b: [__m128; 2], c: [__m128; 2]) -> [__m128; 2] = [
                    _mm_add_ps(_mm_mul_ps(a[0], b[0]), c[0]),
                    _mm_add_ps(_mm_mul_ps(a[1], b[1]), c[1]),
                ];
                min(a: [__m128; 2], b: [__m128; 2]) -> [__m128; 2] =
                    [_mm_min_ps(a[0], b[0]), _mm_min_ps(a[1], b[1])];
                max(a: [__m128; 2], b: [__m128; 2]) -> [__m128; 2] =
                    [_mm_max_ps(a[0], b[0]), _mm_max_ps(a[1], b[1])];
                eq(a: [__m128; 2], b: [__m128; 2]) -> [__m128; 2] =
                    [_mm_cmpeq_ps(a[0], b[0]), _mm_cmpeq_ps(a[1], b[1])];
                ne(a: [__m128; 2], b: [__m128; 2]) -> [__m128; 2] =
                    [_mm_cmpneq_ps(a[0], b[0]), _mm_cmpneq_ps(a[1], b[1])];
                lt(a: [__m128; 2], b: [__m128; 2]) -> [__m128; 2] =
                    [_mm_cmplt_ps(a[0], b[0]), _mm_cmplt_ps(a[1], b[1])];
                le(a: [__m128; 2], b: [__m128; 2]) -> [__m128; 2] =
                    [_mm_cmple_ps(a[0], b[0]), _mm_cmple_ps(a[1], b[1])];
                ge(a: [__m128; 2], b: [__m128; 2]) -> [__m128; 2] =
                    [_mm_cmpge_ps(a[0], b[0]), _mm_cmpge_ps(a[1], b[1])];
                and(a: [__m128; 2], b: [__m128; 2]) -> [__m128; 2] =
                    [_mm_and_ps(a[0], b[0]), _mm_and_ps(a[1], b[1])];
                or(a: [__m128; 2], b: [__m128; 2]) -> [__m128; 2] =
                    [_mm_or_ps(a[0], b[0]), _mm_or_ps(a[1], b[1])];
                select(m: [__m128; 2], yes: [__m128; 2], no: [__m128; 2]) -> [__m128; 2] = [
                    _mm_blendv_ps(no[0], yes[0], m[0]),
                    _mm_blendv_ps(no[1], yes[1], m[1]),
                ];
                bits(m: [__m128; 2]) -> u32 =
                    (_mm_movemask_ps(m[0]) | _mm_movemask_ps(m[1]) << 4) as u32;
            }
        }
    }
}

/// A mask lane: all ones (true) or all zeros.
#[inline(always)]
fn mask(b: bool) -> f32 {
    f32::from_bits(if b { u32::MAX } else { 0 })
}

#[inline(always)]
fn lanes(f: impl FnMut(usize) -> f32) -> [f32; 8] {
    std::array::from_fn(f)
}

impl Simd8 for Portable {
    type F = [f32; 8];
    type Idx = [u8; 8];

    #[inline(always)]
    fn splat(self, x: f32) -> [f32; 8] {
        [x; 8]
    }
    #[inline(always)]
    fn load(self, x: &[f32; 8]) -> [f32; 8] {
        *x
    }
    #[inline(always)]
    fn store(self, v: [f32; 8]) -> [f32; 8] {
        v
    }
    #[inline(always)]
    fn bytes(self, q: &[u8; 8]) -> [f32; 8] {
        q.map(f32::from)
    }
    #[inline(always)]
    fn add(self, a: [f32; 8], b: [f32; 8]) -> [f32; 8] {
        lanes(|l| a[l] + b[l])
    }
    #[inline(always)]
    fn sub(self, a: [f32; 8], b: [f32; 8]) -> [f32; 8] {
        lanes(|l| a[l] - b[l])
    }
    #[inline(always)]
    fn mul(self, a: [f32; 8], b: [f32; 8]) -> [f32; 8] {
        lanes(|l| a[l] * b[l])
    }
    #[inline(always)]
    fn div(self, a: [f32; 8], b: [f32; 8]) -> [f32; 8] {
        lanes(|l| a[l] / b[l])
    }
    /// Two roundings, as `add(mul(a, b), c)` (not `f32::mul_add`, which fuses).
    #[inline(always)]
    fn mul_add(self, a: [f32; 8], b: [f32; 8], c: [f32; 8]) -> [f32; 8] {
        lanes(|l| a[l] * b[l] + c[l])
    }
    #[inline(always)]
    fn min(self, a: [f32; 8], b: [f32; 8]) -> [f32; 8] {
        lanes(|l| if a[l] < b[l] { a[l] } else { b[l] })
    }
    #[inline(always)]
    fn max(self, a: [f32; 8], b: [f32; 8]) -> [f32; 8] {
        lanes(|l| if a[l] > b[l] { a[l] } else { b[l] })
    }
    #[inline(always)]
    fn eq(self, a: [f32; 8], b: [f32; 8]) -> [f32; 8] {
        lanes(|l| mask(a[l] == b[l]))
    }
    #[inline(always)]
    fn ne(self, a: [f32; 8], b: [f32; 8]) -> [f32; 8] {
        lanes(|l| mask(a[l] != b[l]))
    }
    #[inline(always)]
    fn lt(self, a: [f32; 8], b: [f32; 8]) -> [f32; 8] {
        lanes(|l| mask(a[l] < b[l]))
    }
    #[inline(always)]
    fn le(self, a: [f32; 8], b: [f32; 8]) -> [f32; 8] {
        lanes(|l| mask(a[l] <= b[l]))
    }
    #[inline(always)]
    fn ge(self, a: [f32; 8], b: [f32; 8]) -> [f32; 8] {
        lanes(|l| mask(a[l] >= b[l]))
    }
    #[inline(always)]
    fn and(self, a: [f32; 8], b: [f32; 8]) -> [f32; 8] {
        lanes(|l| f32::from_bits(a[l].to_bits() & b[l].to_bits()))
    }
    #[inline(always)]
    fn or(self, a: [f32; 8], b: [f32; 8]) -> [f32; 8] {
        lanes(|l| f32::from_bits(a[l].to_bits() | b[l].to_bits()))
    }
    #[inline(always)]
    fn select(self, m: [f32; 8], yes: [f32; 8], no: [f32; 8]) -> [f32; 8] {
        lanes(|l| {
            if m[l].is_sign_negative() {
                yes[l]
            } else {
                no[l]
            }
        })
    }
    #[inline(always)]
    fn bits(self, m: [f32; 8]) -> u32 {
        (0..8).fold(0, |b, l| b | (m[l].is_sign_negative() as u32) << l)
    }
    #[inline(always)]
    fn slots(self, s: &[u8; 8]) -> [u8; 8] {
        s.map(|j| j & 7)
    }
    #[inline(always)]
    fn permute(self, v: [f32; 8], i: [u8; 8]) -> [f32; 8] {
        i.map(|j| v[j as usize])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every operation of the SIMD tokens equals the portable one, bit for bit, on values
    /// that include zeros of both signs, infinities, NaNs and subnormals.
    fn same_as_portable<S: Simd8>(s: S) {
        let p = Portable;
        let odd = [
            0.0,
            -0.0,
            1.0,
            -1.5,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            -f32::NAN,
            f32::from_bits(1),
            f32::MAX,
            3.25,
        ];
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        for _ in 0..2000 {
            let a: [f32; 8] = std::array::from_fn(|_| odd[(next() % odd.len() as u64) as usize]);
            let b: [f32; 8] = std::array::from_fn(|_| odd[(next() % odd.len() as u64) as usize]);
            let q: [u8; 8] = next().to_le_bytes();
            let bits = |v: [f32; 8]| v.map(f32::to_bits);
            let (va, vb) = (s.load(&a), s.load(&b));
            // NaN payloads of arithmetic may differ; everything else is exact.
            let same = |got: [f32; 8], want: [f32; 8]| {
                (0..8).all(|l| {
                    got[l].to_bits() == want[l].to_bits() || (got[l].is_nan() && want[l].is_nan())
                })
            };
            macro_rules! check {
                ($($op:ident)*) => {$(
                    let (got, want) = (s.store(s.$op(va, vb)), p.$op(a, b));
                    assert!(same(got, want), "{}: {a:?} {b:?}: {got:?} vs {want:?}", stringify!($op));
                )*};
            }
            check!(add sub mul div min max eq ne lt le ge and or);
            assert_eq!(bits(s.store(s.select(va, vb, va))), bits(p.select(a, b, a)));
            assert_eq!(s.bits(va), p.bits(a));
            assert_eq!(bits(s.store(s.bytes(&q))), bits(p.bytes(&q)));
            let perm = s.store(s.permute(va, s.slots(&q)));
            assert_eq!(bits(perm), bits(p.permute(a, p.slots(&q))), "slots {q:?}");
            let n = (next() % 12) as u32;
            assert_eq!(s.bits(s.lanes_below(n)), p.bits(p.lanes_below(n)));
        }
        assert_eq!(p.bits(p.lanes_below(3)), 0b111);
        assert_eq!(p.bits(p.lanes_below(u32::MAX)), 0xff);

        // The octree's eight cells: the same mask and the same entries as the scalar form,
        // with infinities, NaNs, ties and signed zeros among the planes.
        let planes = [
            0.0,
            -0.0,
            1.0,
            2.0,
            -3.0,
            7.5,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ];
        let mut hits = 0;
        for _ in 0..20000 {
            let mut pick = || planes[(next() % planes.len() as u64) as usize];
            let enter: [[f64; 2]; 3] = std::array::from_fn(|_| [pick(), pick()]);
            let exit: [[f64; 2]; 3] = std::array::from_fn(|_| [pick(), pick()]);
            let (tmin, tmax) = (pick(), pick());
            let (gm, gt) = s.cell_hits(&enter, &exit, tmin, tmax);
            let (wm, wt) = cell_hits_scalar(&enter, &exit, tmin, tmax);
            assert_eq!(gm, wm, "{enter:?} {exit:?} {tmin} {tmax}");
            for o in 0..8 {
                let (g, w) = (gt[o], wt[o]);
                assert!(
                    g.to_bits() == w.to_bits() || g.is_nan() && w.is_nan(),
                    "{g} {w}"
                );
            }
            hits += gm.count_ones();
        }
        assert!(hits > 2000, "{hits}");
    }

    /// [`Simd8::mul_add`] rounds once where `fused` (the AVX2 token: `f32::mul_add`, a
    /// correctly rounded fused multiply-add) and twice elsewhere (`a * b + c`), on special
    /// values, random bit patterns and random near-cancelling triples; and a case where the
    /// two differ shows which one ran.
    fn mul_add_rounding<S: Simd8>(s: S, fused: bool) {
        let odd = [
            0.0,
            -0.0,
            1.0,
            -1.5,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            f32::from_bits(1),
            f32::MAX,
            3.25,
        ];
        let mut x = 0x0123_4567_89ab_cdefu64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let mut differ = 0;
        for _ in 0..20_000 {
            let pick = |next: &mut dyn FnMut() -> u64| match next() % 3 {
                0 => odd[(next() % odd.len() as u64) as usize],
                1 => f32::from_bits(next() as u32),
                // Mantissas near 1 of either sign, scaled a little.
                _ => {
                    let v = f32::from_bits(0x3f80_0000 | (next() as u32 & 0x7f_ffff));
                    let v = v * (1 << (next() % 8)) as f32;
                    if next() & 1 == 0 { v } else { -v }
                }
            };
            let a: [f32; 8] = std::array::from_fn(|_| pick(&mut next));
            let b: [f32; 8] = std::array::from_fn(|_| pick(&mut next));
            let mut c: [f32; 8] = std::array::from_fn(|_| pick(&mut next));
            if next() & 1 == 0 {
                // `c` cancelling most of the product: where one rounding and two differ.
                c = std::array::from_fn(|l| -(a[l] * b[l]));
            }
            let got = s.store(s.mul_add(s.load(&a), s.load(&b), s.load(&c)));
            for l in 0..8 {
                let once = a[l].mul_add(b[l], c[l]);
                let twice = a[l] * b[l] + c[l];
                let want = if fused { once } else { twice };
                assert!(
                    got[l].to_bits() == want.to_bits() || got[l].is_nan() && want.is_nan(),
                    "mul_add({}, {}, {}) = {} (fused {fused}): {} vs {}",
                    a[l],
                    b[l],
                    c[l],
                    got[l],
                    once,
                    twice
                );
                differ += (once.to_bits() != twice.to_bits() && !once.is_nan()) as u32;
            }
        }
        assert!(
            differ > 10_000,
            "only {differ} lanes where the roundings differ"
        );
        // (1 + 2^-12)^2 - (1 + 2^-11) is 2^-24 exactly; the rounded product is 1 + 2^-11.
        let a = 1.0 + 2f32.powi(-12);
        let r = s.store(s.mul_add(s.splat(a), s.splat(a), s.splat(-(1.0 + 2f32.powi(-11)))));
        assert_eq!(r, [if fused { 2f32.powi(-24) } else { 0.0 }; 8]);
    }

    #[test]
    fn mul_add_rounds_once_with_avx2_twice_elsewhere() {
        mul_add_rounding(Portable, false);
        #[cfg(all(target_arch = "x86_64", target_feature = "sse4.1"))]
        mul_add_rounding(Sse41::new(), false);
        match Avx2::detect() {
            Some(isa) => {
                struct Check;
                impl WithAvx2 for Check {
                    type Output = ();
                    #[inline(always)]
                    fn run(self, isa: Avx2) {
                        mul_add_rounding(isa, true)
                    }
                }
                isa.vectorize(Check)
            }
            None => eprintln!("AVX2 skipped: this CPU has no AVX2 and FMA"),
        }
    }

    /// The scalar form of the octree cells' test, on cells whose answer is known: a ray along
    /// +x at low y and high z meets exactly the two children it passes through, entered where
    /// it crosses into them.
    #[test]
    fn cell_hits_finds_the_cells_a_ray_passes_through() {
        // The ray x = t, y = 0.25, z = 0.75 in the cell [0, 1]^3 halved at 0.5: along x it is
        // in the low half over [0, 0.5] and the high half over [0.5, 1]; along y always in the
        // low half, along z always in the high half.
        let inf = f64::INFINITY;
        let enter = [[0.0, 0.5], [-inf, inf], [inf, -inf]];
        let exit = [[0.5, 1.0], [inf, inf], [inf, inf]];
        let (m, t) = cell_hits_scalar(&enter, &exit, 0.0, 10.0);
        // Children 4 (x low, y low, z high) and 5 (x high).
        assert_eq!(m, 0b0011_0000);
        assert_eq!((t[4], t[5]), (0.0, 0.5));
        // A range that ends before x = 0.5 meets only the first.
        assert_eq!(cell_hits_scalar(&enter, &exit, 0.0, 0.4).0, 0b0001_0000);
    }

    #[test]
    fn avx2_operations_equal_portable() {
        match Avx2::detect() {
            Some(isa) => {
                struct Check;
                impl WithAvx2 for Check {
                    type Output = ();
                    #[inline(always)]
                    fn run(self, isa: Avx2) {
                        same_as_portable(isa)
                    }
                }
                isa.vectorize(Check)
            }
            None => eprintln!("skipped: this CPU has no AVX2 and FMA"),
        }
    }

    #[cfg(all(target_arch = "x86_64", target_feature = "sse4.1"))]
    #[test]
    fn sse_operations_equal_portable() {
        same_as_portable(Sse41::new());
    }
}
