//! NFF's cones and cylinders (`c`) and spheres (`s`), tessellated into triangles: see the
//! [module documentation](super) for the tessellation.

use glam::DVec3;

use super::parser::Parser;
use super::tokens::Src;
use super::{CONE_SEGMENTS, SPHERE_SLICES, SPHERE_STACKS};
use crate::mesh::MeshError;

impl Parser<'_> {
    pub(super) fn cone(&mut self, src: &mut Src, fid: usize, line: u64) -> Result<(), MeshError> {
        let base = src.vec3(&|| "the base of the cone `c`".into())?;
        let r0 = src.number(&|| "the base radius of the cone `c`".into())?;
        let apex = src.vec3(&|| "the apex of the cone `c`".into())?;
        let r1 = src.number(&|| "the apex radius of the cone `c`".into())?;
        let axis = apex - base;
        let len = axis.length();
        if !(len > 0.0 && len.is_finite()) {
            return Err(src.aff(
                line,
                "the cone `c` has its base and apex at the same point".into(),
            ));
        }
        let (u, v) = basis(divided(axis, len));
        self.begin(fid, line);
        let first = self.positions.len() as u32;
        let n = CONE_SEGMENTS;
        for i in 0..n {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            let (s, c) = a.sin_cos();
            let radial = u * c + v * s;
            self.vertex(src, line, base + radial * r0)?;
            self.vertex(src, line, apex + radial * r1)?;
        }
        for i in 0..n {
            let j = (i + 1) % n;
            let (b0, a0, b1, a1) = (
                first + 2 * i,
                first + 2 * i + 1,
                first + 2 * j,
                first + 2 * j + 1,
            );
            // Outward, counterclockwise seen from outside.
            self.triangles.push([b0, b1, a1]);
            self.triangles.push([b0, a1, a0]);
        }
        self.counts.cones += 1;
        Ok(())
    }

    pub(super) fn sphere(&mut self, src: &mut Src, fid: usize, line: u64) -> Result<(), MeshError> {
        let c = src.vec3(&|| "the centre of the sphere `s`".into())?;
        let r = src.number(&|| "the radius of the sphere `s`".into())?.abs();
        self.begin(fid, line);
        let (slices, stacks) = (SPHERE_SLICES, SPHERE_STACKS);
        let north = self.vertex(src, line, DVec3::new(c.x, c.y + r, c.z))?;
        for i in 1..stacks {
            let theta = std::f64::consts::PI * i as f64 / stacks as f64;
            let (st, ct) = theta.sin_cos();
            for j in 0..slices {
                let phi = std::f64::consts::TAU * j as f64 / slices as f64;
                let (sp, cp) = phi.sin_cos();
                let p = DVec3::new(c.x + r * st * cp, c.y + r * ct, c.z - r * st * sp);
                self.vertex(src, line, p)?;
            }
        }
        let south = self.vertex(src, line, DVec3::new(c.x, c.y - r, c.z))?;
        let ring = |i: u32, j: u32| north + 1 + (i - 1) * slices + j % slices;
        for j in 0..slices {
            self.triangles.push([north, ring(1, j), ring(1, j + 1)]);
        }
        for i in 1..stacks - 1 {
            for j in 0..slices {
                let (a, b, c2, d) = (
                    ring(i, j),
                    ring(i + 1, j),
                    ring(i + 1, j + 1),
                    ring(i, j + 1),
                );
                self.triangles.push([a, b, c2]);
                self.triangles.push([a, c2, d]);
            }
        }
        for j in 0..slices {
            self.triangles
                .push([south, ring(stacks - 1, j + 1), ring(stacks - 1, j)]);
        }
        self.counts.spheres += 1;
        Ok(())
    }
}

/// `v / len`, dividing each coordinate. glam's `normalize` multiplies by the reciprocal of the
/// length instead, which rounds differently and would move the tessellated vertices by a bit.
fn divided(v: DVec3, len: f64) -> DVec3 {
    v / len
}

/// Two unit vectors `u`, `v` with `u × v = d` for a unit `d`.
fn basis(d: DVec3) -> (DVec3, DVec3) {
    let helper = if d.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    let w = helper.cross(d);
    let len = w.length();
    // `d` is a unit vector and the helper far from parallel to it, so `len > 0`; the test
    // keeps the vector as it is otherwise, as the code before glam did.
    let u = if len > 0.0 { divided(w, len) } else { w };
    (u, d.cross(u))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn basis_is_right_handed_and_orthonormal() {
        for d in [DVec3::Y, DVec3::X, DVec3::new(0.0, 0.6, -0.8)] {
            let (u, v) = basis(d);
            assert!(u.cross(v).abs_diff_eq(d, 1e-12));
            assert!(u.dot(d).abs() < 1e-12 && v.dot(d).abs() < 1e-12);
            assert!((u.length() - 1.0).abs() < 1e-12 && (v.length() - 1.0).abs() < 1e-12);
        }
    }

    /// Why [`divided`]: glam's `normalize` multiplies by the reciprocal of the length, which
    /// rounds differently for many vectors, so it would move tessellated vertices (the BART
    /// scenes' cones happen to be axis-aligned, where both agree).
    #[test]
    fn dividing_by_the_length_is_not_glams_normalize() {
        let differ = (1..100)
            .map(|i| DVec3::new(1.0, i as f64, 3.0))
            .filter(|&v| divided(v, v.length()) != v.normalize())
            .count();
        assert!(differ > 0);
    }
}
