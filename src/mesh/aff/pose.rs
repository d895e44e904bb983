//! Posing: the scene at one time, from what the parser gathered. Transforms are composed down
//! the node tree, animated ones from their keyframes at that time; animated triangles are
//! interpolated between their keys; invisible subtrees are left out.
//!
//! The work is linear in what the parser gathered: each animation (a name's `k` block) is
//! evaluated once, however many transforms use it, its splines in `O(log n)` for `n` keys (see
//! [`super::kb`]); an animated triangle's keys are searched by bisection too.

use glam::DVec3;

use super::kb::Quat;
use super::keyframes::Animation;
use super::parser::{AnimTri, NodeKind, Parser};
use super::transform::{Affine, IDENTITY, apply, compose, trs};
use crate::mesh::{Mesh, MeshError, Place};

impl Animation {
    /// The transform `T R S` at time `t` (the identity for a motion the block does not have).
    fn matrix(&self, t: f64) -> Affine {
        super::work::evaluation();
        let tr = self.transl.as_ref().map_or([0.0; 3], |s| s.at(t));
        let rot = self.rot.as_ref().map_or(Quat::IDENTITY, |s| s.at(t));
        let sc = self.scale.as_ref().map_or([1.0; 3], |s| s.at(t));
        trs(DVec3::from_array(tr), rot.matrix(), DVec3::from_array(sc))
    }

    /// Visible until the first visibility key, then as the latest key at or before `t` says
    /// (the last in file order, should the times not be in order). A walk over the keys, which
    /// posing does once per animation.
    fn visible(&self, t: f64) -> bool {
        super::work::keys(self.visibility.len());
        let mut v = true;
        for &(time, flag) in &self.visibility {
            if time <= t {
                v = flag;
            }
        }
        v
    }
}

/// The scene at one time.
pub(super) struct Pose {
    pub(super) mesh: Mesh,
    /// The material of each triangle of `mesh`.
    pub(super) material_of: Vec<u32>,
    /// The point lights, placed.
    pub(super) lights: Vec<[f64; 3]>,
    /// The transform of the animation named `camera`, when there is one.
    pub(super) camera: Option<Affine>,
}

impl Parser<'_> {
    /// Poses the scene at `time`.
    pub(super) fn pose(&self, time: f64) -> Result<Pose, MeshError> {
        // Each animation once, whatever the number of transforms that use it.
        let animations: Vec<Option<(Affine, bool)>> = self
            .animations
            .iter()
            .map(|a| a.as_ref().map(|a| (a.matrix(time), a.visible(time))))
            .collect();
        let mut world = Vec::with_capacity(self.nodes.len());
        let mut visible = Vec::with_capacity(self.nodes.len());
        for (i, node) in self.nodes.iter().enumerate() {
            let (parent, pvis) = if i == 0 {
                (IDENTITY, true)
            } else {
                (world[node.parent], visible[node.parent])
            };
            let (local, vis) = match node.kind {
                NodeKind::Root => (IDENTITY, true),
                NodeKind::Static(m) => (m, true),
                NodeKind::Animated(id) => animations[id].unwrap_or((IDENTITY, true)),
            };
            world.push(compose(&parent, &local));
            visible.push(pvis && vis);
        }
        let positions = self.positions_at(time, &world)?;
        // Each triangle's material travels with it (the parser synced them to the triangles).
        let of_triangle = &self.materials.of_triangle;
        debug_assert_eq!(of_triangle.len(), self.triangles.len());
        let (triangles, material_of) = if self.runs.iter().all(|r| visible[r.node]) {
            (self.triangles.clone(), of_triangle.clone())
        } else {
            let firsts: Vec<u32> = self.runs.iter().map(|r| r.first).collect();
            self.triangles
                .iter()
                .zip(of_triangle)
                .filter(|(t, _)| {
                    let r = firsts.partition_point(|&f| f <= t[0]).saturating_sub(1);
                    visible[self.runs[r].node]
                })
                .map(|(t, &m)| (*t, m))
                .unzip()
        };
        let lights = self
            .lights
            .iter()
            .map(|&(node, p, _)| apply(&world[node], p).to_array())
            .collect();
        let camera = self
            .animation_ids
            .get(&b"camera"[..])
            .and_then(|&id| animations[id])
            .map(|(m, _)| m);
        Ok(Pose {
            mesh: Mesh {
                geometries: Vec::new(),
                positions,
                triangles,
            },
            material_of,
            lights,
            camera,
        })
    }

    /// Every vertex placed by the world transform of its statement's node (`world`, by node),
    /// animated triangles' corners first interpolated at `time`; rounded to `f32`, which must
    /// keep them finite.
    fn positions_at(&self, time: f64, world: &[Affine]) -> Result<Vec<[f32; 3]>, MeshError> {
        let mut local = self.positions.clone();
        for a in &self.anim_tris {
            let corners = animated_corners(a, time);
            for (k, c) in corners.into_iter().enumerate() {
                local[a.slot as usize + k] = c;
            }
        }
        let mut positions = Vec::with_capacity(local.len());
        for (r, run) in self.runs.iter().enumerate() {
            let end = self
                .runs
                .get(r + 1)
                .map_or(local.len(), |n| n.first as usize);
            let m = &world[run.node];
            for (i, p) in local[run.first as usize..end].iter().enumerate() {
                let q = apply(m, *p).as_vec3();
                if !q.is_finite() {
                    return Err(MeshError::NonFinite {
                        file: self.files[run.file].clone(),
                        at: Place::Line(run.line),
                        vertex: (run.first as usize + i) as u64,
                    });
                }
                positions.push(q.to_array());
            }
        }
        debug_assert_eq!(positions.len(), local.len());
        Ok(positions)
    }
}

/// The corners of an animated triangle at `t`: linear between the keys around `t`, clamped to
/// the first and last key.
fn animated_corners(tri: &AnimTri, t: f64) -> [DVec3; 3] {
    let keys = &tri.keys;
    let (first, last) = (keys[0], keys[keys.len() - 1]);
    if t <= first.0 {
        return first.1;
    }
    if t >= last.0 {
        return last.1;
    }
    // BART's `viGetAnimatedTriangle` takes the first pair of keys with `ta <= t <= tb`, walking
    // from the first. With `first < t < last`, that pair ends at the first key from the second
    // on with `t <= tb` (every key before it, but the first, is before `t`).
    let i = tri.reach.first_after(t, false);
    let ((ta, a), (tb, b)) = (keys[i], keys[i + 1]);
    let s = if tb > ta { (t - ta) / (tb - ta) } else { 0.0 };
    std::array::from_fn(|i| a[i] + (b[i] - a[i]) * s)
}

#[cfg(test)]
mod tests {
    use super::super::kb::Reach;
    use super::*;

    fn tri(keys: &[(f64, f64)]) -> AnimTri {
        let keys: Vec<_> = keys.iter().map(|&(t, z)| (t, [DVec3::Z * z; 3])).collect();
        AnimTri {
            slot: 0,
            reach: Reach::new(keys[1..].iter().map(|k| k.0)),
            keys,
        }
    }

    #[test]
    fn animated_corners_interpolate_and_clamp() {
        let keys = tri(&[(0.0, 0.0), (1.0, 2.0), (1.0, 5.0), (3.0, 9.0)]);
        let z = |t: f64| animated_corners(&keys, t)[0].z;
        assert_eq!(z(-1.0), 0.0);
        assert_eq!(z(0.5), 1.0);
        // At a repeated key time, the first pair of keys around it.
        assert_eq!(z(1.0), 2.0);
        assert_eq!(z(2.0), 7.0);
        assert_eq!(z(4.0), 9.0);
    }

    /// Keys out of time order are read as BART's walk reads them: the first pair of keys
    /// `ta <= t <= tb` in file order.
    #[test]
    fn animated_corners_take_the_first_pair_around_t_in_file_order() {
        let keys = tri(&[
            (0.0, 0.0),
            (4.0, 4.0),
            (1.0, 10.0),
            (2.0, 20.0),
            (6.0, 60.0),
        ]);
        let z = |t: f64| animated_corners(&keys, t)[0].z;
        // 0 <= 3 <= 4: the first pair.
        assert_eq!(z(3.0), 3.0);
        // 4 <= 5 <= ... no pair until (2, 6).
        assert_eq!(z(5.0), 20.0 + 0.75 * 40.0);
        assert_eq!(z(1.5), 1.5);
    }
}
