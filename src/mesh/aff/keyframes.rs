//! Keyframes (`k name { motion n rows... }`): the [`Animation`] of a name, read from its block,
//! its splines prepared once (see [`super::kb`]). Its evaluation is in [`super::pose`].

use super::kb::{MIN_KEYS, RotKey, RotSpline, VecKey, VecSpline};
use super::parser::Parser;
use super::tokens::{Src, show};
use crate::mesh::MeshError;

/// The motions of one `k` block.
#[derive(Default)]
pub(super) struct Animation {
    pub(super) transl: Option<VecSpline>,
    pub(super) rot: Option<RotSpline>,
    pub(super) scale: Option<VecSpline>,
    /// `(time, visible)`, as in the file.
    pub(super) visibility: Vec<(f64, bool)>,
}

impl Parser<'_> {
    /// `k name { motion n rows... }`; the last block of a name counts.
    pub(super) fn keyframes(&mut self, src: &mut Src, line: u64) -> Result<(), MeshError> {
        let (name, _) = src.token(&|| "the name of the keyframes `k`".into())?;
        let name = name.to_vec();
        let at = format!("in `k {}` at line {line}", show(&name));
        let at = at.as_str();
        src.expect(b"{", &|| format!("after `k {}`", show(&name)))?;
        let mut anim = Animation::default();
        loop {
            let (motion, mline) = src.token(&|| format!("a motion or `}}` {at}"))?;
            if motion == b"}" {
                break;
            }
            let n = src.count(&|| format!("the key count of `{}` {at}", show(motion)))?;
            let spline = matches!(motion, b"transl" | b"scale" | b"rot");
            if spline && n < MIN_KEYS as u64 {
                return Err(src.aff(
                    mline,
                    format!(
                        "`{}` {at} has {n} keys; splines need at least {MIN_KEYS}",
                        show(motion)
                    ),
                ));
            }
            match motion {
                b"transl" => anim.transl = Some(VecSpline::new(vec_keys(src, n, at)?)),
                b"scale" => anim.scale = Some(VecSpline::new(vec_keys(src, n, at)?)),
                b"rot" => anim.rot = Some(RotSpline::new(&rot_keys(src, n, at)?)),
                b"visibility" => anim.visibility = visibility_keys(src, n, at)?,
                _ => {
                    return Err(src.aff(
                        mline,
                        format!(
                            "unknown motion `{}` {at} (expected transl, rot, scale or visibility)",
                            show(motion)
                        ),
                    ));
                }
            }
        }
        let id = self.animation_id(&name);
        self.animations[id] = Some(anim);
        Ok(())
    }
}

/// `n` rows `t x y z T C B` (`transl`, `scale`).
fn vec_keys(src: &mut Src, n: u64, at: &str) -> Result<Vec<VecKey>, MeshError> {
    let mut keys = Vec::new();
    for i in 0..n {
        let what = |w: &'static str| move || format!("{w} of key {i} {at}");
        let t = src.number(&what("the time"))?;
        let v = src.vec3(&what("the value"))?.to_array();
        let tcb = src.vec3(&what("tension/continuity/bias"))?.to_array();
        keys.push(VecKey { t, v, tcb });
    }
    Ok(keys)
}

/// `n` rows `t ax ay az deg T C B` (`rot`).
fn rot_keys(src: &mut Src, n: u64, at: &str) -> Result<Vec<RotKey>, MeshError> {
    let mut keys = Vec::new();
    for i in 0..n {
        let what = |w: &'static str| move || format!("{w} of key {i} {at}");
        let t = src.number(&what("the time"))?;
        let axis = src.vec3(&what("the axis"))?.to_array();
        let angle_deg = src.number(&what("the angle"))?;
        let tcb = src.vec3(&what("tension/continuity/bias"))?.to_array();
        keys.push(RotKey {
            t,
            axis,
            angle_deg,
            tcb,
        });
    }
    Ok(keys)
}

/// `n` rows `t flag` (`visibility`).
fn visibility_keys(src: &mut Src, n: u64, at: &str) -> Result<Vec<(f64, bool)>, MeshError> {
    let mut keys = Vec::new();
    for i in 0..n {
        let t = src.number(&|| format!("the time of visibility key {i} {at}"))?;
        let (flag, _) = src.integer(&|| format!("the flag of visibility key {i} {at}"))?;
        keys.push((t, flag != 0));
    }
    Ok(keys)
}
