//! The viewpoint block `v` ([`AffView`]).

use super::AffView;
use super::tokens::Src;
use crate::mesh::MeshError;

pub(super) fn parse_view(src: &mut Src, line: u64) -> Result<AffView, MeshError> {
    let mut from = None;
    let mut at = None;
    let mut up = None;
    let mut angle = None;
    let mut hither = None;
    let mut resolution = None;
    while let Some(word) = src.tok.peek() {
        let what = |w: &'static str| move || format!("`{w}` of the viewpoint `v`");
        match word {
            b"from" => {
                src.tok.next();
                from = Some(src.vec3(&what("from"))?.to_array());
            }
            b"at" => {
                src.tok.next();
                at = Some(src.vec3(&what("at"))?.to_array());
            }
            b"up" => {
                src.tok.next();
                up = Some(src.vec3(&what("up"))?.to_array());
            }
            b"angle" => {
                src.tok.next();
                angle = Some(src.number(&what("angle"))?);
            }
            b"hither" => {
                src.tok.next();
                hither = Some(src.number(&what("hither"))?);
            }
            b"resolution" => {
                src.tok.next();
                let mut dim = |w: &'static str| -> Result<u32, MeshError> {
                    let (v, l) = src.integer(&what(w))?;
                    u32::try_from(v).ok().filter(|&v| v > 0).ok_or_else(|| {
                        src.aff(l, format!("the {w} is {v}; it must be a positive integer"))
                    })
                };
                let w = dim("resolution width")?;
                let h = dim("resolution height")?;
                resolution = Some((w, h));
            }
            _ => break,
        }
    }
    let missing = |w: &str| src.aff(line, format!("the viewpoint `v` has no `{w}`"));
    Ok(AffView {
        from: from.ok_or_else(|| missing("from"))?,
        at: at.ok_or_else(|| missing("at"))?,
        up: up.ok_or_else(|| missing("up"))?,
        angle_deg: angle.ok_or_else(|| missing("angle"))?,
        hither: hither.ok_or_else(|| missing("hither"))?,
        resolution: resolution.ok_or_else(|| missing("resolution"))?,
    })
}
