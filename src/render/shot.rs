//! A render's shot: the camera, the point light and the image size, chosen from what a user
//! gives ([`ShotSpec`]: a BART scene's viewpoint, or a camera framing the model adjusted by an
//! eye, a target, an up vector and a field of view) and the model's bounds. It is how
//! `oavm-trace` renders (its `--view`, `--eye`, `--light`... options) and makes the primary
//! rays of its benchmark mode. [`ShadedShot`] adds what a Whitted render of the shot needs: the
//! materials and lights of the view scene, matched to the file's triangles.

use std::path::{Path, PathBuf};

use super::look::{Look, PointLight};
use super::whitted::{ShadedOptions, ShadedStats, render_shaded};
use super::{Image, RenderOptions};
use crate::error::Error;
use crate::logical::{BlockSource, Order, Scene};
use crate::mesh::{AffScene, load_aff};
use crate::rays::{Bounds, Camera, default_light};

/// The image size of a shot without a view scene (nor a size given).
pub const DEFAULT_SIZE: (u32, u32) = (1024, 768);

/// The vertical field of view of a camera framing the model, in degrees, unless one is given.
pub const DEFAULT_FOV: f64 = 40.0;

/// Where a shot's camera, light and size come from. The default frames the model from in front,
/// the light above, right and in front of it ([`default_light`]), in a
/// [`DEFAULT_SIZE`] image.
#[derive(Clone, Debug, Default)]
pub struct ShotSpec {
    /// A BART scene (`.aff`) whose viewpoint (`v`: from, at, up, and its angle as the vertical
    /// field of view) is the camera, whose first light (`l`), or the viewpoint without one, is
    /// the light, and whose resolution is the image size. `None`: a camera framing the model,
    /// adjusted by `eye`, `target`, `up` and `fov`.
    pub view: Option<PathBuf>,
    /// The time the view scene is posed at; `None`: its animation's start, as `oavm-pack`
    /// poses it.
    pub time: Option<f64>,
    /// With `view`: the scene's animated camera path (`k camera`) at that time instead of its
    /// `v` block.
    pub camera_path: bool,
    /// Without `view`: the camera's position (default: in front of the model, framing it).
    pub eye: Option<[f64; 3]>,
    /// Without `view`: the point the camera looks at (default: the model's centre).
    pub target: Option<[f64; 3]>,
    /// Without `view`: the camera's up vector (default `0,1,0`).
    pub up: Option<[f64; 3]>,
    /// Without `view`: the vertical field of view in degrees (default [`DEFAULT_FOV`]).
    pub fov: Option<f64>,
    /// The point light, instead of the view scene's or the default one. A shaded render
    /// ([`ShadedShot`]) then has this one white light instead of the scene's lights.
    pub light: Option<[f64; 3]>,
    /// The image width, instead of the view scene's resolution or [`DEFAULT_SIZE`].
    pub width: Option<u32>,
    /// The image height, likewise.
    pub height: Option<u32>,
}

/// A camera, the point light of a plain render ([`super::render`]) or of shadow rays, and the
/// image size: what a [`ShotSpec`] gives for a model.
#[derive(Clone, Copy, Debug)]
pub struct Shot {
    pub camera: Camera,
    /// The point light's position, in the model's coordinates.
    pub light: [f32; 3],
    /// The image's size, in pixels.
    pub width: u32,
    pub height: u32,
}

impl ShotSpec {
    /// The view scene posed at [`Self::time`], if there is one.
    pub fn load_view(&self) -> Result<Option<AffScene>, Error> {
        match &self.view {
            Some(path) => Ok(Some(load_aff(path, self.time)?)),
            None => Ok(None),
        }
    }
}

impl Shot {
    /// The shot `spec` gives of a model within `bounds`, its view scene read and posed.
    pub fn new(spec: &ShotSpec, bounds: &Bounds) -> Result<Shot, Error> {
        Shot::with_view(spec, spec.load_view()?.as_ref(), bounds)
    }

    /// [`Shot::new`] with the view scene already read ([`ShotSpec::load_view`]); `view` is
    /// used only with [`ShotSpec::view`], which names it in errors.
    pub fn with_view(
        spec: &ShotSpec,
        view: Option<&AffScene>,
        bounds: &Bounds,
    ) -> Result<Shot, Error> {
        let mut shot = match spec.view.as_deref().zip(view) {
            Some((path, aff)) => viewpoint(spec, path, aff)?,
            None => Shot {
                camera: framing(spec, bounds)?,
                light: default_light(bounds),
                width: DEFAULT_SIZE.0,
                height: DEFAULT_SIZE.1,
            },
        };
        if let Some(light) = spec.light {
            shot.light = light.map(|x| x as f32);
        }
        shot.width = spec.width.unwrap_or(shot.width);
        shot.height = spec.height.unwrap_or(shot.height);
        Ok(shot)
    }

    /// The options of a plain render ([`super::render`]) of the shot, its tiles traced in
    /// `order`.
    pub fn render_options(&self, order: Order) -> RenderOptions {
        RenderOptions {
            width: self.width,
            height: self.height,
            camera: self.camera,
            light: self.light,
            order,
        }
    }
}

/// The shot of the view scene `aff` (read from `path`): its camera, its first light (else the
/// viewpoint) and its resolution.
fn viewpoint(spec: &ShotSpec, path: &Path, aff: &AffScene) -> Result<Shot, Error> {
    let v = if spec.camera_path {
        aff.camera_path.ok_or_else(|| {
            Error::Invalid(format!(
                "{}: the scene has no camera path (`k camera` and a `v` block) for \
                 --camera-path",
                path.display()
            ))
        })?
    } else {
        aff.view.ok_or_else(|| {
            Error::Invalid(format!(
                "{}: the scene has no viewpoint (`v` block) for --view",
                path.display()
            ))
        })?
    };
    let camera = Camera::look_at(v.from, v.at, v.up, v.angle_deg)
        .map_err(|e| Error::Invalid(format!("{}: viewpoint: {e}", path.display())))?;
    let light = aff.lights.first().copied().unwrap_or(v.from);
    Ok(Shot {
        camera,
        light: light.map(|x| x as f32),
        width: v.resolution.0,
        height: v.resolution.1,
    })
}

/// A camera framing the model within `bounds`, adjusted as `spec` asks.
fn framing(spec: &ShotSpec, bounds: &Bounds) -> Result<Camera, Error> {
    let mut camera = Camera::framing(bounds);
    if let Some(target) = spec.target {
        camera.target = target;
    }
    if let Some(eye) = spec.eye {
        camera.eye = eye;
    }
    camera.up = spec.up.unwrap_or([0.0, 1.0, 0.0]);
    camera.fov_y = spec.fov.unwrap_or(DEFAULT_FOV);
    if !(camera.fov_y > 0.0 && camera.fov_y < 180.0) || camera.eye == camera.target {
        return Err(Error::Invalid(
            "the camera needs 0 < --fov < 180 and --eye apart from --target".into(),
        ));
    }
    Ok(camera)
}

/// A Whitted render of a packed scene ([`render_shaded`]) set up from a [`ShotSpec`], as
/// `oavm-trace --shade` sets it up: the shot's camera and size; the materials and lights of
/// the view scene posed at its time, which must be the scene the file was packed from (its
/// triangles in file order are the file's primitives), or for a file without a view scene a
/// white diffuse material ([`Look::plain`]); and one white light at the shot's light instead
/// of the scene's lights when [`ShotSpec::light`] is given or there is no view scene.
#[derive(Clone, Debug)]
pub struct ShadedShot {
    /// The shot's camera and size, the bounces and the order of the tiles.
    pub options: ShadedOptions,
    /// The materials, lights, background and ambient light.
    pub look: Look,
}

impl ShadedShot {
    /// Sets up the render of `scene` that `spec` asks for, with at most `max_depth` bounces
    /// (`None`: [`super::DEFAULT_MAX_DEPTH`]) and its tiles traced in `order`. An error if the
    /// view scene posed at its time has not as many triangles as the file was packed from.
    pub fn new<D: AsRef<[u8]> + BlockSource>(
        scene: &Scene<D>,
        spec: &ShotSpec,
        max_depth: Option<u32>,
        order: Order,
    ) -> Result<ShadedShot, Error> {
        let aff = spec.load_view()?;
        let bounds = scene.bounds();
        let shot = Shot::with_view(spec, aff.as_ref(), &bounds)?;
        let mut look = match &aff {
            Some(aff) => {
                check_matches(scene, spec, aff)?;
                Look::from_aff(aff)
            }
            None => Look::plain(&bounds),
        };
        if aff.is_none() || spec.light.is_some() {
            look.lights = vec![PointLight {
                position: shot.light.map(f64::from),
                colour: [1.0; 3],
            }];
        }
        let mut options = ShadedOptions::new(shot.width, shot.height, shot.camera);
        options.order = order;
        if let Some(depth) = max_depth {
            options.max_depth = depth;
        }
        Ok(ShadedShot { options, look })
    }

    /// Renders it ([`render_shaded`]).
    pub fn render<D: AsRef<[u8]> + BlockSource>(
        &self,
        scene: &Scene<D>,
    ) -> Result<(Image, ShadedStats), Error> {
        render_shaded(scene, &self.options, &self.look)
    }
}

/// Checks that the view scene `aff` has the triangles `scene` was packed from, so that its
/// materials can be matched to the file's primitives.
fn check_matches<D: AsRef<[u8]> + BlockSource>(
    scene: &Scene<D>,
    spec: &ShotSpec,
    aff: &AffScene,
) -> Result<(), Error> {
    let packed = scene.file().header().input_triangles;
    if aff.mesh.triangles.len() as u64 == packed {
        return Ok(());
    }
    Err(Error::Invalid(format!(
        "{}: posed at time {}, the scene has {} triangles, but {} was packed from {packed}: its \
         materials cannot be matched to the file's triangles (give --time the time given to \
         oavm-pack, or pack this scene)",
        spec.view.as_deref().unwrap_or(Path::new("")).display(),
        aff.time,
        aff.mesh.triangles.len(),
        scene.path().display(),
    )))
}
