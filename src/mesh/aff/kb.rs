//! Kochanek–Bartels splines for BART keyframes: positions (and scales) as cubic Hermite
//! segments, rotations as quaternion `squad` segments.
//!
//! The maths is that of D. Kochanek and R. Bartels, "Interpolating Splines with Local Tension,
//! Continuity, and Bias Control", SIGGRAPH 1984, in the form BART's reference code uses
//! (`kbsplpos.c` and `kbsplrot.c`, which the BART authors took from Dave Eberly's Magic Software
//! library; Lext, Assarsson, Möller, "BART: A Benchmark for Animated Ray Tracing", 2000/2001).
//! We follow that code step by step, so that a scene is posed as its authors saw it:
//!
//! - `n >= 4` keys give `n - 3` segments; segment `i` runs from key `i + 1` to key `i + 2`, and
//!   keys `0` and `n - 1` only shape the end tangents. Times before key 1 clamp to key 1, times
//!   after key `n - 2` clamp to key `n - 2`.
//! - With `DP = P2 - P1` and tension/continuity/bias `(T, C, B)` of the key concerned, the
//!   outgoing tangent at `P1` is `out0 (P1 - P0) + out1 DP` with
//!   `out0 = adj0 (1-T)(1+C)(1+B)/2`, `out1 = adj0 (1-T)(1-C)(1-B)/2`, and the incoming tangent
//!   at `P2` is `in0 DP + in1 (P3 - P2)` with `in0 = adj1 (1-T)(1-C)(1+B)/2`,
//!   `in1 = adj1 (1-T)(1+C)(1-B)/2`. The factors `adj0 = 2 (t2 - t1) / (t2 - t0)` and
//!   `adj1 = 2 (t2 - t1) / (t3 - t1)` correct for unevenly spaced keys (Kochanek–Bartels §5).
//!   The segment is the cubic Hermite curve through `P1`, `P2` with those tangents, in the local
//!   parameter `u = (t - t1) / (t2 - t1)`.
//! - Rotations: each key's axis and angle (degrees in the file) become a unit quaternion. Walking
//!   the segments in order, key `i + 2` is negated when its dot product with key `i + 1` is
//!   negative (the shorter arc), exactly when the reference code does it, so the fourth control
//!   point of a segment is the key as it was before its own alignment. With
//!   `L = log(q1⁻¹ q2)`, the tangents are `Tout = out1 L + out0 log(q0⁻¹ q1)` and
//!   `Tin = in0 L + in1 log(q2⁻¹ q3)` (same factors as above), the inner control points are
//!   `a = q1 exp((Tout - L)/2)` and `b = q2 exp((L - Tin)/2)`, and the segment is
//!   `squad(u; q1, a, b, q2) = slerp(2u(1-u), slerp(u; q1, q2), slerp(u; a, b))`
//!   (Shoemake 1987). `slerp` is Eberly's: no shortest-arc flip, plain `p` when the angle is
//!   below 1e-6.
//!
//! Where the reference code would divide by zero (two keys at the same time) we use the
//! even-spacing value instead: `adj = 1`, and `u = 0` on a segment of zero length. A rotation
//! key with a zero axis is the identity. Axes are normalised (the reference code assumes unit
//! axes; the files give them to five digits).
//!
//! Evaluation differs from the reference code in its cost only, never in its results (a test
//! compares the two bit for bit): a spline is prepared once ([`VecSpline::new`],
//! [`RotSpline::new`]: the key times, each rotation key as a quaternion, the reference code's
//! alignment walk done once over all segments), and the segment of a time is found by binary
//! search ([`Reach`]) instead of the reference code's walk from the first segment. Evaluating
//! at one time then costs `O(log n)` for `n` keys, not `O(n)`.

/// One translation or scaling key: time, value, tension, continuity, bias.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct VecKey {
    pub t: f64,
    pub v: [f64; 3],
    pub tcb: [f64; 3],
}

/// One rotation key: time, axis, angle in degrees, tension, continuity, bias.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct RotKey {
    pub t: f64,
    pub axis: [f64; 3],
    pub angle_deg: f64,
    pub tcb: [f64; 3],
}

/// The fewest keys a spline takes (the reference code asserts it).
pub(crate) const MIN_KEYS: usize = 4;

/// The running maximum of a list of times: `reach[i]` is the latest of `times[..=i]`.
///
/// It answers "the first `i` with `t < times[i]`" (or `t <= times[i]`) by bisection whether or
/// not the times are in order: an `i` with `t < times[i]` has `t < reach[i]`, and the first `i`
/// with `t < reach[i]` has `t < times[i]` (it is where the maximum last grew), so both firsts
/// are the same `i`, and `reach` is sorted. Key lists are in time order but for a few (a `rot`
/// list of the BART robots goes from time 48 back to 42), which the reference code reads as
/// any other: so must we, with the same result.
#[derive(Clone, Debug)]
pub(crate) struct Reach(Vec<f64>);

impl Reach {
    pub(crate) fn new(times: impl IntoIterator<Item = f64>) -> Reach {
        let mut latest = f64::NEG_INFINITY;
        Reach(
            times
                .into_iter()
                .map(|t| {
                    latest = latest.max(t);
                    latest
                })
                .collect(),
        )
    }

    /// The first `i` with `t < times[i]` (`strict`) or `t <= times[i]`, or the number of times
    /// when there is none.
    pub(crate) fn first_after(&self, t: f64, strict: bool) -> usize {
        self.0.partition_point(|&latest| {
            super::work::keys(1);
            if strict { latest <= t } else { latest < t }
        })
    }
}

/// Segment index and local parameter for time `t` over keys with times `times` (the reference
/// code's `ComputeIAndU`). `times.len() >= 4`; `ends` is the [`Reach`] of the segments' end
/// times `times[2..n - 1]`.
fn segment(times: &[f64], ends: &Reach, t: f64) -> (usize, f64) {
    let polys = times.len() - 3;
    let tmin = |i: usize| times[i + 1];
    let tmax = |i: usize| times[i + 2];
    if tmin(0) < t {
        if t < tmax(polys - 1) {
            // The reference code walks to the first segment `i` with `t < tmax(i)`; there is
            // one, the last segment at worst.
            let i = ends.first_after(t, true);
            let range = tmax(i) - tmin(i);
            let u = if range > 0.0 {
                ((t - tmin(i)) / range).clamp(0.0, 1.0)
            } else {
                0.0
            };
            (i, u)
        } else {
            (polys - 1, 1.0)
        }
    } else {
        (0, 0.0)
    }
}

/// The key times of a spline and the [`Reach`] of its segments' end times.
fn times_and_ends(times: Vec<f64>) -> (Vec<f64>, Reach) {
    let ends = Reach::new(times[2..times.len() - 1].iter().copied());
    (times, ends)
}

/// `2 (a - b) / (c - d)`, or 1 (even spacing) where that is not a finite number.
fn adjust(num: f64, den: f64) -> f64 {
    let a = 2.0 * num / den;
    if a.is_finite() { a } else { 1.0 }
}

/// The tangent multipliers of segment `i` (keys `i .. i + 3`): `(out0, out1, in0, in1)`.
fn multipliers(times: &[f64], tcb1: [f64; 3], tcb2: [f64; 3], i: usize) -> [f64; 4] {
    let (t0, t1, t2, t3) = (times[i], times[i + 1], times[i + 2], times[i + 3]);
    let [te, co, bi] = tcb1;
    let adj0 = adjust(t2 - t1, t2 - t0);
    let out0 = 0.5 * adj0 * (1.0 - te) * (1.0 + co) * (1.0 + bi);
    let out1 = 0.5 * adj0 * (1.0 - te) * (1.0 - co) * (1.0 - bi);
    let [te, co, bi] = tcb2;
    let adj1 = adjust(t2 - t1, t3 - t1);
    let in0 = 0.5 * adj1 * (1.0 - te) * (1.0 - co) * (1.0 + bi);
    let in1 = 0.5 * adj1 * (1.0 - te) * (1.0 + co) * (1.0 - bi);
    [out0, out1, in0, in1]
}

/// The Kochanek–Bartels curve through some translation or scaling keys, ready to evaluate.
#[derive(Clone, Debug)]
pub(crate) struct VecSpline {
    keys: Vec<VecKey>,
    times: Vec<f64>,
    ends: Reach,
}

impl VecSpline {
    /// The spline through `keys` (at least [`MIN_KEYS`]).
    pub(crate) fn new(keys: Vec<VecKey>) -> VecSpline {
        debug_assert!(keys.len() >= MIN_KEYS);
        super::work::keys(keys.len());
        let (times, ends) = times_and_ends(keys.iter().map(|k| k.t).collect());
        VecSpline { keys, times, ends }
    }

    /// The curve at time `t`.
    pub(crate) fn at(&self, t: f64) -> [f64; 3] {
        let (keys, times) = (&self.keys, &self.times[..]);
        let (i, u) = segment(times, &self.ends, t);
        super::work::keys(4);
        let (p0, p1, p2, p3) = (keys[i].v, keys[i + 1].v, keys[i + 2].v, keys[i + 3].v);
        let [out0, out1, in0, in1] = multipliers(times, keys[i + 1].tcb, keys[i + 2].tcb, i);
        std::array::from_fn(|k| {
            let dp = p2[k] - p1[k];
            let tout = out1 * dp + out0 * (p1[k] - p0[k]);
            let tin = in1 * (p3[k] - p2[k]) + in0 * dp;
            let c2 = 3.0 * dp - 2.0 * tout - tin;
            let c3 = -2.0 * dp + tout + tin;
            p1[k] + u * (tout + u * (c2 + u * c3))
        })
    }
}

/// A quaternion `w + xi + yj + zk`, with the reference code's operations.
///
/// Not glam's `DQuat`, which cannot give the reference code's bits: its product sums the terms
/// of each component in another order (`w0 y1 - x0 z1 + y0 w1 + z0 x1` against
/// `w0 y1 + y0 w1 + z0 x1 - x0 z1`), its `slerp` turns to the shorter arc and lerps near
/// `dot = 1` where Eberly's does neither, and `from_axis_angle` wants a unit axis. The
/// positions and scales stay `[f64; 3]` for the same reason: the code below is the reference
/// code's, term for term.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Quat {
    pub w: f64,
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

const EPSILON: f64 = 1e-6;

impl Quat {
    /// The rotation by `angle` radians about `axis` (normalised here; a zero axis gives the
    /// identity).
    pub(crate) fn from_angle_axis(angle: f64, axis: [f64; 3]) -> Quat {
        let len = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
        if !(len.is_finite() && len > 0.0) {
            return Quat::IDENTITY;
        }
        let (s, c) = (0.5 * angle).sin_cos();
        Quat {
            w: c,
            x: s * axis[0] / len,
            y: s * axis[1] / len,
            z: s * axis[2] / len,
        }
    }

    pub(crate) const IDENTITY: Quat = Quat {
        w: 1.0,
        x: 0.0,
        y: 0.0,
        z: 0.0,
    };

    fn dot(self, o: Quat) -> f64 {
        self.w * o.w + self.x * o.x + self.y * o.y + self.z * o.z
    }

    fn neg(self) -> Quat {
        self.scale(-1.0)
    }

    fn scale(self, s: f64) -> Quat {
        Quat {
            w: self.w * s,
            x: self.x * s,
            y: self.y * s,
            z: self.z * s,
        }
    }

    fn add(self, o: Quat) -> Quat {
        Quat {
            w: self.w + o.w,
            x: self.x + o.x,
            y: self.y + o.y,
            z: self.z + o.z,
        }
    }

    fn sub(self, o: Quat) -> Quat {
        self.add(o.neg())
    }

    fn mul(self, o: Quat) -> Quat {
        Quat {
            w: self.w * o.w - self.x * o.x - self.y * o.y - self.z * o.z,
            x: self.w * o.x + self.x * o.w + self.y * o.z - self.z * o.y,
            y: self.w * o.y + self.y * o.w + self.z * o.x - self.x * o.z,
            z: self.w * o.z + self.z * o.w + self.x * o.y - self.y * o.x,
        }
    }

    /// The inverse of a unit quaternion: its conjugate.
    fn unit_inverse(self) -> Quat {
        Quat {
            w: self.w,
            x: -self.x,
            y: -self.y,
            z: -self.z,
        }
    }

    /// Logarithm of a unit quaternion (Eberly): `(0, angle * axis)`.
    fn log(self) -> Quat {
        let mut out = Quat { w: 0.0, ..self };
        if self.w.abs() < 1.0 {
            let angle = self.w.acos();
            let sn = angle.sin();
            if sn.abs() >= EPSILON {
                let c = angle / sn;
                out.x *= c;
                out.y *= c;
                out.z *= c;
            }
        }
        out
    }

    /// Exponential of a pure quaternion (Eberly).
    fn exp(self) -> Quat {
        let angle = (self.x * self.x + self.y * self.y + self.z * self.z).sqrt();
        let (sn, cs) = angle.sin_cos();
        let c = if sn.abs() >= EPSILON { sn / angle } else { 1.0 };
        Quat {
            w: cs,
            x: self.x * c,
            y: self.y * c,
            z: self.z * c,
        }
    }

    /// Eberly's slerp: no shortest-arc flip; `p` when the angle between them is tiny.
    fn slerp(t: f64, p: Quat, q: Quat) -> Quat {
        let angle = p.dot(q).clamp(-1.0, 1.0).acos();
        if angle.abs() < EPSILON {
            return p;
        }
        let sn = angle.sin();
        if sn.abs() < EPSILON {
            // Opposite quaternions: the same rotation, any path is as good.
            return p;
        }
        let c0 = (angle - t * angle).sin() / sn;
        let c1 = (t * angle).sin() / sn;
        p.scale(c0).add(q.scale(c1))
    }

    fn squad(t: f64, p: Quat, a: Quat, b: Quat, q: Quat) -> Quat {
        Quat::slerp(
            2.0 * t * (1.0 - t),
            Quat::slerp(t, p, q),
            Quat::slerp(t, a, b),
        )
    }

    /// The rotation matrix (rows) of this quaternion after normalisation; the identity for a
    /// zero or non-finite quaternion.
    pub(crate) fn matrix(self) -> [[f64; 3]; 3] {
        let n = self.dot(self).sqrt();
        if !(n.is_finite() && n > 0.0) {
            return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        }
        let Quat { w, x, y, z } = self.scale(1.0 / n);
        [
            [
                1.0 - 2.0 * (y * y + z * z),
                2.0 * (x * y - w * z),
                2.0 * (x * z + w * y),
            ],
            [
                2.0 * (x * y + w * z),
                1.0 - 2.0 * (x * x + z * z),
                2.0 * (y * z - w * x),
            ],
            [
                2.0 * (x * z - w * y),
                2.0 * (y * z + w * x),
                1.0 - 2.0 * (x * x + y * y),
            ],
        ]
    }
}

/// The Kochanek–Bartels quaternion spline through some rotation keys, ready to evaluate.
#[derive(Clone, Debug)]
pub(crate) struct RotSpline {
    times: Vec<f64>,
    ends: Reach,
    tcb: Vec<[f64; 3]>,
    /// Each key as a unit quaternion, as read.
    keys: Vec<Quat>,
    /// The keys after the reference code's alignment walk over every segment (see
    /// [`RotSpline::new`]).
    aligned: Vec<Quat>,
}

impl RotSpline {
    /// The spline through `keys` (at least [`MIN_KEYS`]).
    ///
    /// The reference code aligns key `i + 2` with key `i + 1` (negating it when their dot
    /// product is negative) while it builds segment `i`, walking the segments in order, so
    /// segment `s` sees keys `0 ..= s + 2` as aligned by the walk so far and key `s + 3` as it
    /// was read. Each step depends only on the steps before it, so the walk done once over all
    /// segments gives every segment the same keys.
    pub(crate) fn new(keys: &[RotKey]) -> RotSpline {
        debug_assert!(keys.len() >= MIN_KEYS);
        super::work::keys(keys.len());
        let quats: Vec<Quat> = keys
            .iter()
            .map(|k| Quat::from_angle_axis(k.angle_deg.to_radians(), k.axis))
            .collect();
        let mut aligned = quats.clone();
        for i in 0..keys.len() - 3 {
            if aligned[i + 1].dot(aligned[i + 2]) < 0.0 {
                aligned[i + 2] = aligned[i + 2].neg();
            }
        }
        let (times, ends) = times_and_ends(keys.iter().map(|k| k.t).collect());
        RotSpline {
            times,
            ends,
            tcb: keys.iter().map(|k| k.tcb).collect(),
            keys: quats,
            aligned,
        }
    }

    /// The rotation at time `t`.
    pub(crate) fn at(&self, t: f64) -> Quat {
        let times = &self.times[..];
        let (seg, u) = segment(times, &self.ends, t);
        super::work::keys(4);
        let q = &self.aligned;
        let (q0, q1, q2, q3) = (q[seg], q[seg + 1], q[seg + 2], self.keys[seg + 3]);
        let [out0, out1, in0, in1] = multipliers(times, self.tcb[seg + 1], self.tcb[seg + 2], seg);
        let logdq = q1.unit_inverse().mul(q2).log();
        let tout = logdq
            .scale(out1)
            .add(q0.unit_inverse().mul(q1).log().scale(out0));
        let tin = logdq
            .scale(in0)
            .add(q2.unit_inverse().mul(q3).log().scale(in1));
        let a = q1.mul(tout.sub(logdq).scale(0.5).exp());
        let b = q2.mul(logdq.sub(tin).scale(0.5).exp());
        Quat::squad(u, q1, a, b, q2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The evaluation as it was written first, transliterating the reference code step by
    /// step (a linear walk to the segment, the alignment walk at every evaluation): what the
    /// prepared splines must reproduce bit for bit.
    mod reference {
        use super::super::{Quat, RotKey, VecKey, multipliers};

        /// Segment index and local parameter for time `t` over keys with times `times` (the reference
        /// code's `ComputeIAndU`). `times.len() >= 4`.
        fn segment(times: &[f64], t: f64) -> (usize, f64) {
            let polys = times.len() - 3;
            let tmin = |i: usize| times[i + 1];
            let tmax = |i: usize| times[i + 2];
            if tmin(0) < t {
                if t < tmax(polys - 1) {
                    let i = (0..polys).find(|&i| t < tmax(i)).unwrap_or(polys - 1);
                    let range = tmax(i) - tmin(i);
                    let u = if range > 0.0 {
                        ((t - tmin(i)) / range).clamp(0.0, 1.0)
                    } else {
                        0.0
                    };
                    (i, u)
                } else {
                    (polys - 1, 1.0)
                }
            } else {
                (0, 0.0)
            }
        }

        /// The Kochanek–Bartels curve through `keys` (at least [`MIN_KEYS`]) at time `t`.
        pub(super) fn interpolate_vec(keys: &[VecKey], t: f64) -> [f64; 3] {
            debug_assert!(keys.len() >= 4);
            let times: Vec<f64> = keys.iter().map(|k| k.t).collect();
            let (i, u) = segment(&times, t);
            let (p0, p1, p2, p3) = (keys[i].v, keys[i + 1].v, keys[i + 2].v, keys[i + 3].v);
            let [out0, out1, in0, in1] = multipliers(&times, keys[i + 1].tcb, keys[i + 2].tcb, i);
            std::array::from_fn(|k| {
                let dp = p2[k] - p1[k];
                let tout = out1 * dp + out0 * (p1[k] - p0[k]);
                let tin = in1 * (p3[k] - p2[k]) + in0 * dp;
                let c2 = 3.0 * dp - 2.0 * tout - tin;
                let c3 = -2.0 * dp + tout + tin;
                p1[k] + u * (tout + u * (c2 + u * c3))
            })
        }

        /// The Kochanek–Bartels quaternion spline through `keys` (at least [`MIN_KEYS`]) at time `t`.
        pub(super) fn interpolate_rot(keys: &[RotKey], t: f64) -> Quat {
            debug_assert!(keys.len() >= 4);
            let times: Vec<f64> = keys.iter().map(|k| k.t).collect();
            let (seg, u) = segment(&times, t);
            let mut q: Vec<Quat> = keys
                .iter()
                .map(|k| Quat::from_angle_axis(k.angle_deg.to_radians(), k.axis))
                .collect();
            // The reference code aligns key i + 2 with key i + 1 while it builds segment i, walking the
            // segments in order; segment `seg` sees the keys as they are at that point of the walk.
            for i in 0..=seg {
                if q[i + 1].dot(q[i + 2]) < 0.0 {
                    q[i + 2] = q[i + 2].neg();
                }
            }
            let (q0, q1, q2, q3) = (q[seg], q[seg + 1], q[seg + 2], q[seg + 3]);
            let [out0, out1, in0, in1] =
                multipliers(&times, keys[seg + 1].tcb, keys[seg + 2].tcb, seg);
            let logdq = q1.unit_inverse().mul(q2).log();
            let tout = logdq
                .scale(out1)
                .add(q0.unit_inverse().mul(q1).log().scale(out0));
            let tin = logdq
                .scale(in0)
                .add(q2.unit_inverse().mul(q3).log().scale(in1));
            let a = q1.mul(tout.sub(logdq).scale(0.5).exp());
            let b = q2.mul(logdq.sub(tin).scale(0.5).exp());
            Quat::squad(u, q1, a, b, q2)
        }
    }

    fn interpolate_vec(keys: &[VecKey], t: f64) -> [f64; 3] {
        VecSpline::new(keys.to_vec()).at(t)
    }

    fn interpolate_rot(keys: &[RotKey], t: f64) -> Quat {
        RotSpline::new(keys).at(t)
    }

    /// A small deterministic generator (SplitMix64).
    fn random(state: &mut u64) -> f64 {
        *state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = *state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn prepared_splines_give_the_reference_codes_bits() {
        let mut state = 7;
        for n in [4usize, 5, 9, 40, 300] {
            let mut time = -3.0;
            let mut vec_keys = Vec::new();
            let mut rot_keys = Vec::new();
            for i in 0..n {
                // Uneven steps, some keys at the same time (a zero-length segment), and in
                // the longer lists some going back in time, as in a BART robot.
                if i % 7 != 3 {
                    time += 0.1 + 2.0 * random(&mut state);
                }
                if n >= 40 && i % 13 == 5 {
                    time -= 10.0 * random(&mut state);
                }
                let mut r = || 4.0 * random(&mut state) - 2.0;
                let tcb = [r() / 2.0, r() / 2.0, r() / 2.0];
                vec_keys.push(VecKey {
                    t: time,
                    v: [r(), r(), r()],
                    tcb,
                });
                rot_keys.push(RotKey {
                    t: time,
                    axis: [r(), r(), r()],
                    angle_deg: 200.0 * r(),
                    tcb,
                });
            }
            let (vs, rs) = (VecSpline::new(vec_keys.clone()), RotSpline::new(&rot_keys));
            let mut times: Vec<f64> = vec_keys.iter().map(|k| k.t).collect();
            times.extend((0..200).map(|_| -5.0 + (time + 10.0) * random(&mut state)));
            for t in times {
                let (a, b) = (vs.at(t), reference::interpolate_vec(&vec_keys, t));
                assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits), "n = {n}, t = {t}");
                let (a, b) = (rs.at(t), reference::interpolate_rot(&rot_keys, t));
                let bits = |q: Quat| [q.w, q.x, q.y, q.z].map(f64::to_bits);
                assert_eq!(bits(a), bits(b), "n = {n}, t = {t}");
            }
        }
    }

    fn vk(t: f64, v: [f64; 3]) -> VecKey {
        VecKey {
            t,
            v,
            tcb: [0.0; 3],
        }
    }

    #[test]
    fn positions_pass_through_the_inner_keys_and_clamp() {
        let keys = [
            vk(-1.0, [5.0, 0.0, 0.0]),
            vk(0.0, [0.0, 0.0, 0.0]),
            vk(1.0, [1.0, 2.0, 3.0]),
            vk(2.0, [4.0, 4.0, 4.0]),
            vk(3.0, [9.0, 9.0, 9.0]),
        ];
        assert_eq!(interpolate_vec(&keys, 0.0), [0.0, 0.0, 0.0]);
        assert_eq!(interpolate_vec(&keys, -5.0), [0.0, 0.0, 0.0]);
        let at1 = interpolate_vec(&keys, 1.0);
        for (a, b) in at1.iter().zip([1.0, 2.0, 3.0]) {
            assert!((a - b).abs() < 1e-12);
        }
        assert_eq!(interpolate_vec(&keys, 2.0), [4.0, 4.0, 4.0]);
        assert_eq!(interpolate_vec(&keys, 99.0), [4.0, 4.0, 4.0]);
    }

    #[test]
    fn evenly_spaced_collinear_keys_move_linearly() {
        // Catmull-Rom (T = C = B = 0) reproduces a straight line at constant speed.
        let keys: Vec<VecKey> = (0..6)
            .map(|i| vk(i as f64, [2.0 * i as f64, 0.0, -(i as f64)]))
            .collect();
        for k in 0..=30 {
            let t = 1.0 + k as f64 / 10.0;
            let p = interpolate_vec(&keys, t);
            assert!((p[0] - 2.0 * t).abs() < 1e-12 && (p[2] + t).abs() < 1e-12);
        }
    }

    #[test]
    fn duplicate_key_times_give_finite_values() {
        let keys = [
            vk(0.0, [0.0; 3]),
            vk(0.0, [0.0; 3]),
            vk(0.0, [1.0; 3]),
            vk(1.0, [2.0; 3]),
        ];
        for t in [-1.0, 0.0, 0.5, 1.0, 2.0] {
            assert!(interpolate_vec(&keys, t).iter().all(|c| c.is_finite()));
        }
    }

    fn rk(t: f64, axis: [f64; 3], angle_deg: f64) -> RotKey {
        RotKey {
            t,
            axis,
            angle_deg,
            tcb: [0.0; 3],
        }
    }

    fn angle_about_y(q: Quat) -> f64 {
        // For rotations about +y: q = (cos(a/2), 0, sin(a/2), 0).
        2.0 * q.y.atan2(q.w).to_degrees()
    }

    #[test]
    fn rotations_hit_the_keys_and_turn_past_180_degrees() {
        let keys: Vec<RotKey> = (0..8)
            .map(|i| rk(i as f64, [0.0, 1.0, 0.0], 90.0 * i as f64))
            .collect();
        for i in 1..=6 {
            let q = interpolate_rot(&keys, i as f64);
            let a = angle_about_y(q).rem_euclid(360.0);
            assert!(
                (a - (90.0 * i as f64).rem_euclid(360.0)).abs() < 1e-9,
                "{i}: {a}"
            );
        }
        // Evenly spaced keys about one axis: the spline turns at constant speed.
        let q = interpolate_rot(&keys, 2.5);
        assert!((angle_about_y(q).rem_euclid(360.0) - 225.0).abs() < 1e-6);
    }

    #[test]
    fn rotation_matrix_is_right_handed() {
        let q = Quat::from_angle_axis(90f64.to_radians(), [0.0, 0.0, 2.0]);
        let m = q.matrix();
        // +x goes to +y about +z.
        let x = [m[0][0], m[1][0], m[2][0]];
        assert!((x[0]).abs() < 1e-12 && (x[1] - 1.0).abs() < 1e-12 && x[2].abs() < 1e-12);
        assert_eq!(
            Quat::from_angle_axis(1.0, [0.0; 3]).matrix(),
            Quat::IDENTITY.matrix()
        );
    }
}
