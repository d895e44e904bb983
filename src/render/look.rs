//! What a shaded render needs beside the geometry: the material of each primitive, the lights,
//! the background and the ambient light ([`Look`]), from a BART scene ([`Look::from_aff`]) or a
//! default for a plain mesh ([`Look::plain`]).

use crate::mesh::AffScene;
use crate::mesh::aff::AffMaterial;
use crate::rays::{Bounds, default_light};

/// A point light: no fall-off with distance (NFF's lights).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointLight {
    pub position: [f64; 3],
    pub colour: [f32; 3],
}

/// The materials, lights, background and ambient light of a scene.
///
/// Any values are accepted: [`super::render_shaded`] clamps what makes no sense (see its
/// module), and finds a primitive's material as [`Look::material`] does, so that no look makes
/// a NaN or a panic.
#[derive(Clone, Debug, PartialEq)]
pub struct Look {
    /// The materials (BART's `f` and `fm`, see [`crate::mesh::aff`]).
    pub materials: Vec<AffMaterial>,
    /// The index in `materials` of each primitive, by primitive id (the mesh's triangle order).
    pub material_of: Vec<u32>,
    pub lights: Vec<PointLight>,
    /// The colour of rays that hit nothing.
    pub background: [f32; 3],
    /// The ambient light, scaled by each material's ambient colour.
    pub ambient: [f32; 3],
}

/// The default look's ambient light.
pub const PLAIN_AMBIENT: [f32; 3] = [0.15; 3];
/// The default look's background.
pub const PLAIN_BACKGROUND: [f32; 3] = [0.08, 0.09, 0.11];

impl Look {
    /// The look of a BART scene as posed: its materials, the material of each triangle, its
    /// lights with their colours, its background and ambient light.
    pub fn from_aff(scene: &AffScene) -> Look {
        Look {
            materials: scene.materials.clone(),
            material_of: scene.material_of.clone(),
            lights: scene
                .lights
                .iter()
                .zip(&scene.light_colours)
                .map(|(&position, &colour)| PointLight { position, colour })
                .collect(),
            background: scene.background,
            ambient: scene.ambient,
        }
    }

    /// The look of a plain mesh: one white diffuse material ([`AffMaterial::DEFAULT`]) for
    /// every primitive, one white light at [`default_light`] of `bounds` (above, right and in
    /// front of the mesh), a dim ambient light ([`PLAIN_AMBIENT`]) and a dark background
    /// ([`PLAIN_BACKGROUND`]).
    pub fn plain(bounds: &Bounds) -> Look {
        Look {
            materials: vec![AffMaterial::DEFAULT],
            material_of: Vec::new(),
            lights: vec![PointLight {
                position: default_light(bounds).map(f64::from),
                colour: [1.0; 3],
            }],
            background: PLAIN_BACKGROUND,
            ambient: PLAIN_AMBIENT,
        }
    }

    /// The material of primitive `prim`: `materials[material_of[prim]]`; the first material
    /// for a primitive beyond `material_of` (all of them in a plain look); the default
    /// ([`AffMaterial::DEFAULT`]) for an index beyond `materials`.
    pub fn material(&self, prim: u32) -> &AffMaterial {
        let index = self
            .material_of
            .get(prim as usize)
            .map_or(0, |&m| m as usize);
        self.materials.get(index).unwrap_or(&AffMaterial::DEFAULT)
    }
}
