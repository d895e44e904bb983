//! NFF's cones and cylinders (`c`) and spheres (`s`), tessellated into triangles: see the
//! [module documentation](super) for the tessellation.

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
        let axis = crate::rays::sub(apex, base);
        let len = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
        if !(len > 0.0 && len.is_finite()) {
            return Err(src.aff(
                line,
                "the cone `c` has its base and apex at the same point".into(),
            ));
        }
        let d = axis.map(|c| c / len);
        let (u, v) = basis(d);
        self.begin(fid, line);
        let first = self.positions.len() as u32;
        let n = CONE_SEGMENTS;
        for i in 0..n {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            let (s, c) = a.sin_cos();
            let radial: [f64; 3] = std::array::from_fn(|k| c * u[k] + s * v[k]);
            self.vertex(src, line, std::array::from_fn(|k| base[k] + r0 * radial[k]))?;
            self.vertex(src, line, std::array::from_fn(|k| apex[k] + r1 * radial[k]))?;
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
        let north = self.vertex(src, line, [c[0], c[1] + r, c[2]])?;
        for i in 1..stacks {
            let theta = std::f64::consts::PI * i as f64 / stacks as f64;
            let (st, ct) = theta.sin_cos();
            for j in 0..slices {
                let phi = std::f64::consts::TAU * j as f64 / slices as f64;
                let (sp, cp) = phi.sin_cos();
                self.vertex(
                    src,
                    line,
                    [c[0] + r * st * cp, c[1] + r * ct, c[2] - r * st * sp],
                )?;
            }
        }
        let south = self.vertex(src, line, [c[0], c[1] - r, c[2]])?;
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

/// Two unit vectors `u`, `v` with `u × v = d` for a unit `d`.
fn basis(d: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let helper = if d[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let u = crate::rays::normalize(crate::rays::cross(helper, d));
    let v = crate::rays::cross(d, u);
    (u, v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    pub(super) fn basis_is_right_handed_and_orthonormal() {
        for d in [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.6, -0.8]] {
            let (u, v) = basis(d);
            let w = crate::rays::cross(u, v);
            assert!(w.iter().zip(d).all(|(a, b)| (a - b).abs() < 1e-12));
            assert!(crate::rays::dot(u, d).abs() < 1e-12 && crate::rays::dot(v, d).abs() < 1e-12);
        }
    }
}
