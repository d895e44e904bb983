//! The statements that give triangles straight from the file: polygons (`p`, `pp`), textured
//! triangles (`tt`, `ttp`), meshes (`m`) and animated triangles (`tpa`); see the [module
//! documentation](super) for their operands.

use glam::DVec3;

use super::kb::Reach;
use super::parser::{AnimTri, Parser};
use super::tokens::{Src, show};
use crate::mesh::{Fan, MeshError};

impl Parser<'_> {
    pub(super) fn polygon(
        &mut self,
        src: &mut Src,
        fid: usize,
        line: u64,
        patch: bool,
    ) -> Result<(), MeshError> {
        let kw = if patch { "pp" } else { "p" };
        let n = src.count(&|| format!("the vertex count of `{kw}`"))?;
        self.begin(fid, line);
        let mut fan = Fan::default();
        for i in 0..n {
            let p = src.vec3(&|| format!("vertex {i} of the `{kw}` at line {line}"))?;
            if patch {
                src.vec3(&|| format!("normal {i} of the `pp` at line {line}"))?;
            }
            let v = self.vertex(src, line, p)?;
            fan.push(v, &mut self.triangles);
        }
        self.counts.polygons += 1;
        Ok(())
    }

    pub(super) fn textured_triangle(
        &mut self,
        src: &mut Src,
        fid: usize,
        line: u64,
        patch: bool,
    ) -> Result<(), MeshError> {
        let kw = if patch { "ttp" } else { "tt" };
        src.token(&|| format!("the texture name of `{kw}`"))?;
        self.begin(fid, line);
        let mut corners = [0u32; 3];
        for (i, c) in corners.iter_mut().enumerate() {
            let what = |w: &'static str| move || format!("{w} {i} of the `{kw}` at line {line}");
            let p = src.vec3(&what("vertex"))?;
            if patch {
                src.vec3(&what("normal"))?;
            }
            src.number(&what("the u coordinate of corner"))?;
            src.number(&what("the v coordinate of corner"))?;
            *c = self.vertex(src, line, p)?;
        }
        self.triangles.push(corners);
        self.counts.polygons += 1;
        Ok(())
    }

    pub(super) fn animated_triangle(
        &mut self,
        src: &mut Src,
        fid: usize,
        line: u64,
    ) -> Result<(), MeshError> {
        let n = src.count(&|| "the number of keys of `tpa`".into())?;
        if n == 0 {
            return Err(src.aff(line, "`tpa` with no keys".into()));
        }
        let mut keys = Vec::new();
        for k in 0..n {
            let t = src.number(&|| format!("the time of key {k} of the `tpa` at line {line}"))?;
            let mut corners = [DVec3::ZERO; 3];
            for (i, c) in corners.iter_mut().enumerate() {
                *c = src.vec3(&|| format!("vertex {i} of key {k} of the `tpa` at line {line}"))?;
                src.vec3(&|| format!("normal {i} of key {k} of the `tpa` at line {line}"))?;
            }
            keys.push((t, corners));
        }
        self.begin(fid, line);
        let a = self.vertex(src, line, DVec3::ZERO)?;
        let b = self.vertex(src, line, DVec3::ZERO)?;
        let c = self.vertex(src, line, DVec3::ZERO)?;
        self.triangles.push([a, b, c]);
        let reach = Reach::new(keys[1..].iter().map(|k| k.0));
        self.anim_tris.push(AnimTri {
            slot: a,
            keys,
            reach,
        });
        self.counts.animated_triangles += 1;
        Ok(())
    }

    pub(super) fn mesh(&mut self, src: &mut Src, fid: usize, line: u64) -> Result<(), MeshError> {
        let at = format!("of the mesh `m` at line {line}");
        let at = at.as_str();
        src.expect(b"vertices", &|| {
            format!("to begin the mesh `m` at line {line}")
        })?;
        let nv = src.count(&|| format!("the vertex count {at}"))?;
        self.begin(fid, line);
        let base = self.positions.len() as u64;
        for i in 0..nv {
            let p = src.vec3(&|| format!("vertex {i} {at}"))?;
            self.vertex(src, line, p)?;
        }
        let (mut next, mut next_line) = src.token(&|| format!("`triangles` {at}"))?;
        let mut nn = 0;
        if next == b"normals" {
            nn = src.count(&|| format!("the normal count {at}"))?;
            for i in 0..nn {
                src.vec3(&|| format!("normal {i} {at}"))?;
            }
            (next, next_line) = src.token(&|| format!("`triangles` {at}"))?;
        }
        let mut nt = 0;
        if next == b"texturecoords" {
            nt = src.count(&|| format!("the texture coordinate count {at}"))?;
            src.token(&|| format!("the texture name {at}"))?;
            for i in 0..nt {
                src.number(&|| format!("u of texture coordinate {i} {at}"))?;
                src.number(&|| format!("v of texture coordinate {i} {at}"))?;
            }
            (next, next_line) = src.token(&|| format!("`triangles` {at}"))?;
        }
        if next != b"triangles" {
            return Err(src.aff(
                next_line,
                format!(
                    "expected `normals`, `texturecoords` or `triangles` {at}, found `{}`",
                    show(next)
                ),
            ));
        }
        let ntri = src.count(&|| format!("the triangle count {at}"))?;
        for q in 0..ntri {
            let mut tri = [0u32; 3];
            for (w, c) in tri.iter_mut().enumerate() {
                let v = src.index(nv, &|| format!("vertex index {w} of triangle {q} {at}"))?;
                *c = (base + v) as u32;
            }
            if nn > 0 {
                for w in 0..3 {
                    src.index(nn, &|| format!("normal index {w} of triangle {q} {at}"))?;
                }
            }
            if nt > 0 {
                for w in 0..3 {
                    src.index(nt, &|| {
                        format!("texture coordinate index {w} of triangle {q} {at}")
                    })?;
                }
            }
            self.triangles.push(tri);
            self.counts.polygons += 1;
        }
        Ok(())
    }
}
