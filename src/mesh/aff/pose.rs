//! Posing: the scene at one time, from what the parser gathered. Transforms are composed down
//! the node tree, animated ones from their keyframes at that time; animated triangles are
//! interpolated between their keys; invisible subtrees are left out.

use super::kb::{self, Quat};
use super::keyframes::Animation;
use super::parser::{NodeKind, Parser};
use super::transform::{Affine, IDENTITY, apply, compose, trs};
use crate::mesh::{Mesh, MeshError, Place};

impl Animation {
    pub(super) fn matrix(&self, t: f64) -> Affine {
        let tr = self
            .transl
            .as_deref()
            .map_or([0.0; 3], |k| kb::interpolate_vec(k, t));
        let rot = self
            .rot
            .as_deref()
            .map_or(Quat::IDENTITY, |k| kb::interpolate_rot(k, t));
        let sc = self
            .scale
            .as_deref()
            .map_or([1.0; 3], |k| kb::interpolate_vec(k, t));
        trs(tr, rot.matrix(), sc)
    }

    pub(super) fn visible(&self, t: f64) -> bool {
        let mut v = true;
        for &(time, flag) in &self.visibility {
            if time <= t {
                v = flag;
            }
        }
        v
    }
}

impl Parser<'_> {
    /// Poses the scene at `time`: the mesh and the light positions.
    pub(super) fn pose(&self, time: f64) -> Result<(Mesh, Vec<[f64; 3]>), MeshError> {
        let mut world = Vec::with_capacity(self.nodes.len());
        let mut visible = Vec::with_capacity(self.nodes.len());
        for (i, node) in self.nodes.iter().enumerate() {
            let (parent, pvis) = if i == 0 {
                (IDENTITY, true)
            } else {
                (world[node.parent], visible[node.parent])
            };
            let (local, vis) = match &node.kind {
                NodeKind::Root => (IDENTITY, true),
                NodeKind::Static(m) => (*m, true),
                NodeKind::Animated(name) => match self.animations.get(name) {
                    Some(a) => (a.matrix(time), a.visible(time)),
                    None => (IDENTITY, true),
                },
            };
            world.push(compose(&parent, &local));
            visible.push(pvis && vis);
        }

        let mut local = self.positions.clone();
        for a in &self.anim_tris {
            let corners = animated_corners(&a.keys, time);
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
                let q = apply(m, *p).map(|c| c as f32);
                if !q.iter().all(|c| c.is_finite()) {
                    return Err(MeshError::NonFinite {
                        file: self.files[run.file].clone(),
                        at: Place::Line(run.line),
                        vertex: (run.first as usize + i) as u64,
                    });
                }
                positions.push(q);
            }
        }
        debug_assert_eq!(positions.len(), local.len());

        let triangles = if self.runs.iter().all(|r| visible[r.node]) {
            self.triangles.clone()
        } else {
            let firsts: Vec<u32> = self.runs.iter().map(|r| r.first).collect();
            self.triangles
                .iter()
                .filter(|t| {
                    let r = firsts.partition_point(|&f| f <= t[0]).saturating_sub(1);
                    visible[self.runs[r].node]
                })
                .copied()
                .collect()
        };
        let lights = self
            .lights
            .iter()
            .map(|&(node, p)| apply(&world[node], p))
            .collect();
        Ok((
            Mesh {
                positions,
                triangles,
            },
            lights,
        ))
    }
}

/// The corners of an animated triangle at `t`: linear between the keys around `t`, clamped.
fn animated_corners(keys: &[(f64, [[f64; 3]; 3])], t: f64) -> [[f64; 3]; 3] {
    let (first, last) = (keys[0], keys[keys.len() - 1]);
    if t <= first.0 {
        return first.1;
    }
    if t >= last.0 {
        return last.1;
    }
    for w in keys.windows(2) {
        let ((ta, a), (tb, b)) = (w[0], w[1]);
        if ta <= t && t <= tb {
            let s = if tb > ta { (t - ta) / (tb - ta) } else { 0.0 };
            return std::array::from_fn(|i| {
                std::array::from_fn(|k| a[i][k] + s * (b[i][k] - a[i][k]))
            });
        }
    }
    last.1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn animated_corners_interpolate_and_clamp() {
        let k = |t: f64, z: f64| (t, [[0.0, 0.0, z]; 3]);
        let keys = [k(0.0, 0.0), k(1.0, 2.0), k(1.0, 5.0), k(3.0, 9.0)];
        assert_eq!(animated_corners(&keys, -1.0)[0][2], 0.0);
        assert_eq!(animated_corners(&keys, 0.5)[0][2], 1.0);
        assert_eq!(animated_corners(&keys, 2.0)[0][2], 7.0);
        assert_eq!(animated_corners(&keys, 4.0)[0][2], 9.0);
    }
}
