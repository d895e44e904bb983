//! Keyframes (`k name { motion n rows... }`): the [`Animation`] of a name, read from its block.
//! Its evaluation is in [`super::pose`]; the splines are [`super::kb`]'s.

use super::kb::{MIN_KEYS, RotKey, VecKey};
use super::parser::Parser;
use super::tokens::{Src, show};
use crate::mesh::MeshError;

#[derive(Default)]
pub(super) struct Animation {
    pub(super) transl: Option<Vec<VecKey>>,
    pub(super) rot: Option<Vec<RotKey>>,
    pub(super) scale: Option<Vec<VecKey>>,
    pub(super) visibility: Vec<(f64, bool)>,
}

impl Parser<'_> {
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
            let few = |src: &Src| {
                src.aff(
                    mline,
                    format!(
                        "`{}` {at} has {n} keys; splines need at least {MIN_KEYS}",
                        show(motion)
                    ),
                )
            };
            match motion {
                b"transl" | b"scale" => {
                    if n < MIN_KEYS as u64 {
                        return Err(few(src));
                    }
                    let mut keys = Vec::new();
                    for i in 0..n {
                        let what = |w: &'static str| move || format!("{w} of key {i} {at}");
                        let t = src.number(&what("the time"))?;
                        let v = src.vec3(&what("the value"))?;
                        let tcb = src.vec3(&what("tension/continuity/bias"))?;
                        keys.push(VecKey { t, v, tcb });
                    }
                    if motion == b"transl" {
                        anim.transl = Some(keys);
                    } else {
                        anim.scale = Some(keys);
                    }
                }
                b"rot" => {
                    if n < MIN_KEYS as u64 {
                        return Err(few(src));
                    }
                    let mut keys = Vec::new();
                    for i in 0..n {
                        let what = |w: &'static str| move || format!("{w} of key {i} {at}");
                        let t = src.number(&what("the time"))?;
                        let axis = src.vec3(&what("the axis"))?;
                        let angle_deg = src.number(&what("the angle"))?;
                        let tcb = src.vec3(&what("tension/continuity/bias"))?;
                        keys.push(RotKey {
                            t,
                            axis,
                            angle_deg,
                            tcb,
                        });
                    }
                    anim.rot = Some(keys);
                }
                b"visibility" => {
                    let mut keys = Vec::new();
                    for i in 0..n {
                        let t = src.number(&|| format!("the time of visibility key {i} {at}"))?;
                        let (flag, _) =
                            src.integer(&|| format!("the flag of visibility key {i} {at}"))?;
                        keys.push((t, flag != 0));
                    }
                    anim.visibility = keys;
                }
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
        self.animations.insert(name, anim);
        Ok(())
    }
}
