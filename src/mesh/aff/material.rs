//! The shading statements: materials (`f`, `fm`), the background (`b`), the ambient light
//! (`am`) and the colours of lights (`l`); see the [module documentation](super) for what each
//! holds and how a material reaches the triangles after it.

use std::collections::HashMap;

use super::AffMaterial;
use super::parser::Parser;
use super::tokens::{Src, looks_like_number};
use crate::mesh::{MeshError, Place};

/// The bits of a material's twelve numbers: equal materials share one id.
pub(super) type MaterialKey = [u32; 12];

fn key(m: &AffMaterial) -> MaterialKey {
    let mut k = [0u32; 12];
    let scalars = [m.shine, m.transmittance, m.ior];
    let values = m
        .ambient
        .iter()
        .chain(&m.diffuse)
        .chain(&m.specular)
        .chain(&scalars);
    for (slot, v) in k.iter_mut().zip(values) {
        *slot = v.to_bits();
    }
    k
}

/// The materials read so far, each distinct one once, and the one the next triangles take.
pub(super) struct Materials {
    pub(super) list: Vec<AffMaterial>,
    ids: HashMap<MaterialKey, u32>,
    pub(super) current: u32,
    /// The material of each triangle pushed so far, filled up to the triangles' count each
    /// time the current material changes and when the parse ends ([`Parser::sync_materials`]):
    /// a statement's triangles all take the material current when it was read.
    pub(super) of_triangle: Vec<u32>,
}

impl Materials {
    pub(super) fn new() -> Materials {
        let default = AffMaterial::DEFAULT;
        Materials {
            ids: HashMap::from([(key(&default), 0)]),
            list: vec![default],
            current: 0,
            of_triangle: Vec::new(),
        }
    }
}

impl Src<'_> {
    /// A number that is finite as an `f32` (the precision colours and materials are kept in).
    fn number_f32(&mut self, what: &dyn Fn() -> String) -> Result<f32, MeshError> {
        let x = self.number(what)?;
        let y = x as f32;
        if !y.is_finite() {
            return Err(MeshError::BadValue {
                file: self.file.to_owned(),
                // The line of the number just read.
                at: Place::Line(self.tok.last),
                detail: format!(
                    "{x} for {}: beyond the range of a 32-bit float ({:e})",
                    what(),
                    f32::MAX
                ),
            });
        }
        Ok(y)
    }

    /// Three numbers `r g b`.
    pub(super) fn colour(&mut self, what: &dyn Fn() -> String) -> Result<[f32; 3], MeshError> {
        Ok([
            self.number_f32(&|| format!("the red of {}", what()))?,
            self.number_f32(&|| format!("the green of {}", what()))?,
            self.number_f32(&|| format!("the blue of {}", what()))?,
        ])
    }
}

impl Parser<'_> {
    /// Gives every triangle pushed since the last call the current material.
    pub(super) fn sync_materials(&mut self) {
        let m = &mut self.materials;
        m.of_triangle.resize(self.triangles.len(), m.current);
    }

    /// Makes `mat` the current material (an id already given to an equal one, or a new id).
    fn set_material(&mut self, src: &Src, line: u64, mat: AffMaterial) -> Result<(), MeshError> {
        self.sync_materials();
        let m = &mut self.materials;
        let id = match m.ids.get(&key(&mat)) {
            Some(&id) => id,
            None => {
                let id = u32::try_from(m.list.len())
                    .map_err(|_| src.aff(line, "more than 2^32 distinct materials".into()))?;
                m.list.push(mat);
                m.ids.insert(key(&mat), id);
                id
            }
        };
        m.current = id;
        Ok(())
    }

    /// `f r g b Kd Ks shine T ior` (NFF): ambient and diffuse `Kd` times the colour, specular
    /// `Ks` in every channel.
    pub(super) fn nff_material(&mut self, src: &mut Src, line: u64) -> Result<(), MeshError> {
        let colour = src.colour(&|| "the colour of the material `f`".into())?;
        let mut scalar =
            |w: &'static str| src.number_f32(&move || format!("{w} of the material `f`"));
        let kd = scalar("the diffuse coefficient Kd")?;
        let ks = scalar("the specular coefficient Ks")?;
        let shine = scalar("the Phong exponent")?;
        let transmittance = scalar("the transmittance T")?;
        let ior = scalar("the index of refraction")?;
        let diffuse = colour.map(|c| c * kd);
        let mat = AffMaterial {
            ambient: diffuse,
            diffuse,
            specular: [ks; 3],
            shine,
            transmittance,
            ior,
        };
        self.set_material(src, line, mat)
    }

    /// `fm` (BART): ambient, diffuse and specular colours, then shine, T and ior.
    pub(super) fn bart_material(&mut self, src: &mut Src, line: u64) -> Result<(), MeshError> {
        let ambient = src.colour(&|| "the ambient colour of the material `fm`".into())?;
        let diffuse = src.colour(&|| "the diffuse colour of the material `fm`".into())?;
        let specular = src.colour(&|| "the specular colour of the material `fm`".into())?;
        let mut scalar =
            |w: &'static str| src.number_f32(&move || format!("{w} of the material `fm`"));
        let shine = scalar("the Phong exponent")?;
        let transmittance = scalar("the transmittance T")?;
        let ior = scalar("the index of refraction")?;
        let mat = AffMaterial {
            ambient,
            diffuse,
            specular,
            shine,
            transmittance,
            ior,
        };
        self.set_material(src, line, mat)
    }

    /// `l x y z [r g b]`: a point light under the current transform, white without a colour.
    pub(super) fn light(&mut self, src: &mut Src) -> Result<(), MeshError> {
        let p = src.vec3(&|| "the position of the light `l`".into())?;
        let colour = if src.tok.peek().is_some_and(looks_like_number) {
            src.colour(&|| "the colour of the light `l`".into())?
        } else {
            [1.0; 3]
        };
        self.lights.push((self.current, p, colour));
        Ok(())
    }
}
