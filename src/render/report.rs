//! What a render reports: the image written, the total over its rays of every kind (their
//! number, time, rate and the pager's figures) and the renderer's own figures, in the shape
//! `oavm-trace --json` prints them; as text ([`Display`](fmt::Display)), the start of the line
//! `oavm-trace` prints, up to the render's time.

use std::fmt;
use std::path::{Path, PathBuf};

use serde::Serialize;

use super::RenderStats;
use super::shot::ShadedShot;
use super::whitted::ShadedStats;
use crate::logical::{Answered, Counters, PageReport, SetReport};

/// The total over a render's rays of every kind.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct RenderTotal {
    pub rays: u64,
    /// The render's seconds, and its rays' rate over them (millions a second).
    pub seconds: f64,
    pub mrays_per_s: f64,
    /// The pager's figures over every ray.
    pub page: PageReport,
}

impl RenderTotal {
    /// The total of rays whose work is `counters`, traced in `seconds`.
    pub fn new(counters: &Counters, seconds: f64) -> RenderTotal {
        let s = SetReport::new(counters, seconds, Answered::Mixed);
        RenderTotal {
            rays: s.rays,
            seconds: s.seconds,
            mrays_per_s: s.mrays_per_s,
            page: s.page,
        }
    }
}

/// What a plain render ([`super::render`]) reports.
#[derive(Clone, Debug, Serialize)]
pub struct RenderReport {
    /// Where the image was written.
    pub image: PathBuf,
    /// Its primary and shadow rays.
    #[serde(flatten)]
    pub total: RenderTotal,
    /// The renderer's own figures.
    pub render: RenderStats,
}

impl RenderReport {
    /// The report of a render written to `image`.
    pub fn new(image: &Path, render: RenderStats) -> RenderReport {
        RenderReport {
            image: image.to_owned(),
            total: RenderTotal::new(&(render.primary + render.shadow), render.seconds),
            render,
        }
    }
}

/// `wrote IMAGE (WxH): N primary rays (N hit), N shadow rays (N shadowed), S s`.
impl fmt::Display for RenderReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let r = &self.render;
        write!(
            f,
            "wrote {} ({}x{}): {} primary rays ({} hit), {} shadow rays ({} shadowed), {:.3} s",
            self.image.display(),
            r.width,
            r.height,
            r.primary.rays,
            r.hits,
            r.shadow.rays,
            r.shadowed,
            r.seconds,
        )
    }
}

/// What a shaded render ([`super::render_shaded`], through a [`ShadedShot`]) reports.
#[derive(Clone, Debug, Serialize)]
pub struct ShadedReport {
    /// Where the image was written.
    pub image: PathBuf,
    /// The shading model: `whitted`.
    pub shading: &'static str,
    /// The most bounces of reflection and refraction.
    pub max_depth: u32,
    /// The look's lights and materials.
    pub lights: usize,
    pub materials: usize,
    /// Its rays of every kind: primary, shadow, reflection and refraction.
    #[serde(flatten)]
    pub total: RenderTotal,
    /// The renderer's own figures.
    pub render: ShadedStats,
}

impl ShadedReport {
    /// The report of `shot`'s render written to `image`.
    pub fn new(image: &Path, shot: &ShadedShot, render: ShadedStats) -> ShadedReport {
        let all = render.primary + render.shadow + render.reflection + render.refraction;
        ShadedReport {
            image: image.to_owned(),
            shading: "whitted",
            max_depth: shot.options.max_depth,
            lights: shot.look.lights.len(),
            materials: shot.look.materials.len(),
            total: RenderTotal::new(&all, render.seconds),
            render,
        }
    }
}

/// `wrote IMAGE (WxH, Whitted, depth D, L lights, M materials): N primary rays (N hit), N
/// shadow rays (N shadowed), N reflection rays, N refraction rays, S s`.
impl fmt::Display for ShadedReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let r = &self.render;
        write!(
            f,
            "wrote {} ({}x{}, Whitted, depth {}, {} lights, {} materials): {} primary rays ({} \
             hit), {} shadow rays ({} shadowed), {} reflection rays, {} refraction rays, {:.3} s",
            self.image.display(),
            r.width,
            r.height,
            self.max_depth,
            self.lights,
            self.materials,
            r.primary.rays,
            r.hits,
            r.shadow.rays,
            r.shadowed,
            r.reflection.rays,
            r.refraction.rays,
            r.seconds,
        )
    }
}
