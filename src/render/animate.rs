//! Animations: frames `A..B` of a moving scene, each brought into one `.oavm` file by a local
//! update ([`crate::pack::update`], the OAVM paper's §3) or, to compare, by a full pack, then
//! ray traced in Whitted's way ([`super::render_shaded`]) and written as numbered PNGs. What
//! `oavm-trace --frames` runs, and what the paper's Table 3 measures (frames a second, split
//! into the update and the render).
//!
//! # Frames
//!
//! An [`Animation`] takes each frame's geometry from one of two places:
//!
//! - a BART scene posed at the frame's time: frame `f` of the scene's `a start end frames` is
//!   at `start + f * (end - start) / frames` ([`frame_time`]), for `f` in `0..frames` (the
//!   scene's triangles in file order are its primitive ids, the same in every frame of the
//!   BART scenes);
//! - a mesh file per frame ([`Animation::with_meshes`]): a pattern whose `{}` is replaced by
//!   the frame number padded to [`FRAME_DIGITS`] digits, e.g. Rain's `DIR/rain_{}.ply`
//!   (`tools/rain.rs`); triangle `i` of each file is primitive `i`. The view scene then gives
//!   only the camera, the lights, the background and the materials (its own triangles take the
//!   first primitive ids' materials, every primitive past them the default material, as
//!   [`Look::material`] says); it is posed at each frame's time if it has an `a` statement
//!   (and the frames must lie in it), else at its default time.
//!
//! The camera is the view scene's `v` block ([`CameraChoice::View`], as `oavm-trace --view`),
//! BART's animated camera path ([`CameraChoice::Path`], `--camera-path`), or the path where the
//! scene has one and the `v` block otherwise ([`CameraChoice::Auto`]); the lights, materials,
//! background and ambient light are the frame's ([`Look::from_aff`]).
//!
//! # Modes
//!
//! - [`Mode::Update`]: the file must be updatable (packed with the primitive table,
//!   `oavm-pack --updatable`, and a root cube that holds every frame: an update refuses
//!   geometry outside it). Each frame opens an [`Updater`], sets the frame's mesh
//!   ([`Updater::set_mesh`]) and commits a new generation, rebuilding only the subtrees whose
//!   triangles changed; a frame whose triangles are those of the file writes nothing.
//!   [`Animation::pack_first`] makes such a file from the first frame, its root cube fitted to
//!   the bounds of every frame of the range ([`Animation::bounds`]).
//! - [`Mode::Rebuild`]: each frame is packed whole into the file ([`pack_mesh`]) with the
//!   options [`Animation::pack_first`] uses (updatable, the same root cube), replacing it; the
//!   full rebuild per frame that the paper compares updates with. A frame file too large to
//!   build in memory, or any when the pack options give a memory budget, is packed streaming
//!   from its path, as `oavm-pack` would ([`Animation::streamed`]; its pack time then
//!   includes reading the file).
//!
//! Both modes give the same images, byte for byte: a ray's answer depends only on the
//! triangles, not on the tree that finds them (`tests/integration/animate.rs` holds this).
//!
//! # Timing
//!
//! Per frame: `pose_seconds` (reading or posing the frame's geometry, not counted in a frame's
//! time: a renderer would have it in memory), `update_seconds` (the update, from opening the
//! updater to the synced new generation, or the full pack with its write), `open_seconds`
//! (opening the file for tracing), `render_seconds` (the render) and `write_seconds` (encoding
//! and writing the PNG, not counted). A frame's time is `update + open + render`; frames a
//! second are frames over the sum of those ([`AnimationReport::fps`]).
//!
//! # Reports
//!
//! A frame range is parsed from text by [`parse_frames`] (`A..B`, `A..=B` or `A`). The reports
//! print as the lines `oavm-trace --frames` writes ([`FirstPack`], [`FrameReport`] and
//! [`AnimationReport`] implement [`Display`](fmt::Display)), and serialize as its `--json`
//! object ([`AnimationRun`]: the first pack, if any, and the animation).

use std::fmt;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use super::look::{Look, PointLight};
use super::whitted::{DEFAULT_MAX_DEPTH, MAX_DEPTH_LIMIT, ShadedOptions, ShadedStats};
use super::{check_size, render_shaded, write_png};
use crate::error::Error;
use crate::logical::{Order, Scene, SceneOptions};
use crate::mesh::aff::AffView;
use crate::mesh::{AffScene, Mesh, load, load_aff};
use crate::output::Output;
use crate::pack::update::{UpdateOptions, UpdateReport, Updater};
use crate::pack::{PackOptions, PackReport, Quiet, pack, pack_mesh, streaming_budget};
use crate::rays::Camera;

/// Digits of a frame number in file names (`frame_00012.png`, Rain's `rain_00012.ply`).
pub const FRAME_DIGITS: usize = 5;

/// What a mesh pattern's frame number replaces.
pub const FRAME_PLACEHOLDER: &str = "{}";

/// The time of frame `frame` of a scene's animation `a start end frames`:
/// `start + frame * (end - start) / frames`.
pub fn frame_time((start, end, frames): (f64, f64, u64), frame: u64) -> f64 {
    start + frame as f64 * (end - start) / frames as f64
}

/// The name of frame `frame`'s image in the output directory: `frame_00012.png`.
pub fn frame_image_name(frame: u64) -> String {
    format!("frame_{frame:0FRAME_DIGITS$}.png")
}

/// `pattern` with every `{}` replaced by `frame`, padded to [`FRAME_DIGITS`] digits.
pub fn frame_mesh_path(pattern: &str, frame: u64) -> PathBuf {
    PathBuf::from(pattern.replace(FRAME_PLACEHOLDER, &format!("{frame:0FRAME_DIGITS$}")))
}

/// Parses a range of frames: `A..B` (frames A to B-1), `A..=B` (A to B) or `A` (frame A alone).
/// An error for an empty range.
pub fn parse_frames(text: &str) -> Result<Range<u64>, Error> {
    let number = |s: &str| {
        s.trim()
            .parse::<u64>()
            .map_err(|e| Error::Invalid(format!("{s:?} is not a frame number: {e}")))
    };
    let too_large = |what: &str| Error::Invalid(format!("the {what} is too large"));
    let (a, b) = if let Some((a, b)) = text.split_once("..=") {
        let b = number(b)?;
        (
            number(a)?,
            b.checked_add(1).ok_or_else(|| too_large("range"))?,
        )
    } else if let Some((a, b)) = text.split_once("..") {
        (number(a)?, number(b)?)
    } else {
        let a = number(text)?;
        (a, a.checked_add(1).ok_or_else(|| too_large("frame"))?)
    };
    if a >= b {
        return Err(Error::Invalid(format!(
            "{text:?}: the range is empty (A..B renders frames A to B-1; A..=B, or one frame A)"
        )));
    }
    Ok(a..b)
}

/// Where the camera comes from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum CameraChoice {
    /// The view scene's `v` block (as `oavm-trace --view`).
    #[default]
    View,
    /// BART's animated camera path, `k camera` (as `oavm-trace --view --camera-path`); an
    /// error for a scene without one.
    Path,
    /// The camera path where the scene has one, else the `v` block.
    Auto,
}

/// How each frame's geometry gets into the file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// A local update, written as a new generation ([`Updater`]).
    #[default]
    Update,
    /// A full pack of the frame, replacing the file ([`pack_mesh`]).
    Rebuild,
}

impl Mode {
    /// What brings the file to a frame, as a noun: `update` or `pack`.
    pub fn step(self) -> &'static str {
        match self {
            Mode::Update => "update",
            Mode::Rebuild => "pack",
        }
    }

    /// What was done to the frames, as a participle: `updated` or `rebuilt`.
    pub fn done(self) -> &'static str {
        match self {
            Mode::Update => "updated",
            Mode::Rebuild => "rebuilt",
        }
    }
}

/// An animation: the view scene, where each frame's geometry comes from, and the frames to
/// render. Made by [`Animation::new`] or [`Animation::with_meshes`], which check the range.
#[derive(Clone, Debug)]
pub struct Animation {
    view: PathBuf,
    meshes: Option<String>,
    frames: Range<u64>,
    /// The view scene's `a start end frames`.
    timing: Option<(f64, f64, u64)>,
}

/// One frame's geometry and look.
pub struct Frame {
    pub frame: u64,
    /// The time the view scene was posed at.
    pub time: f64,
    /// The frame's triangles, by primitive id.
    pub mesh: Mesh,
    /// The view scene posed at `time`, without its triangles when they are `mesh`.
    pub view: AffScene,
}

impl Animation {
    /// Frames `frames` of the BART scene `view`, posed at each frame's time. The scene must
    /// have an animation (`a start end frames`) holding the range.
    pub fn new(view: &Path, frames: Range<u64>) -> Result<Animation, Error> {
        Animation::make(view, None, frames)
    }

    /// Frames `frames` read from the mesh files `pattern` names (`{}`: the frame number, padded
    /// to [`FRAME_DIGITS`] digits), seen through the scene `view`. Every frame's file must
    /// exist.
    pub fn with_meshes(view: &Path, pattern: &str, frames: Range<u64>) -> Result<Animation, Error> {
        Animation::make(view, Some(pattern), frames)
    }

    fn make(view: &Path, meshes: Option<&str>, frames: Range<u64>) -> Result<Animation, Error> {
        let range = format!("frames {}..{}", frames.start, frames.end);
        if frames.is_empty() {
            return Err(Error::Invalid(format!(
                "{range}: the range is empty (A..B renders frames A to B-1)"
            )));
        }
        let timing = load_aff(view, None)?.animation;
        match timing {
            Some((_, _, 0)) => {
                return Err(Error::Invalid(format!(
                    "{}: its animation (`a`) has no frames, so it has no {range}",
                    view.display()
                )));
            }
            Some((start, end, n)) if frames.end > n => {
                return Err(Error::Invalid(format!(
                    "{range}: {} animates {n} frames (0..{n}, `a {start} {end} {n}`), so frame \
                     {} is past its end",
                    view.display(),
                    frames.end - 1
                )));
            }
            None if meshes.is_none() => {
                return Err(Error::Invalid(format!(
                    "{range}: {} has no animation (`a start end frames`) to pose frames at; \
                     give a mesh per frame (a pattern with {FRAME_PLACEHOLDER})",
                    view.display()
                )));
            }
            _ => {}
        }
        if let Some(pattern) = meshes {
            if !pattern.contains(FRAME_PLACEHOLDER) {
                return Err(Error::Invalid(format!(
                    "frame meshes {pattern:?}: the pattern has no {FRAME_PLACEHOLDER} for the \
                     frame number"
                )));
            }
            for f in frames.clone() {
                let path = frame_mesh_path(pattern, f);
                if !path.is_file() {
                    return Err(Error::Invalid(format!(
                        "{range}: frame {f}'s mesh {} is missing (or not a file)",
                        path.display()
                    )));
                }
            }
        }
        Ok(Animation {
            view: view.to_owned(),
            meshes: meshes.map(str::to_owned),
            frames,
            timing,
        })
    }

    /// The view scene.
    pub fn view(&self) -> &Path {
        &self.view
    }

    /// The mesh pattern, for frames read from files.
    pub fn meshes(&self) -> Option<&str> {
        self.meshes.as_deref()
    }

    /// The frames to render.
    pub fn frames(&self) -> Range<u64> {
        self.frames.clone()
    }

    /// The view scene's animation, `a start end frames`.
    pub fn timing(&self) -> Option<(f64, f64, u64)> {
        self.timing
    }

    /// The time the view scene is posed at for frame `frame` (`None`: its default time).
    pub fn time(&self, frame: u64) -> Option<f64> {
        self.timing.map(|a| frame_time(a, frame))
    }

    /// Frame `frame`'s geometry and look.
    pub fn frame(&self, frame: u64) -> Result<Frame, Error> {
        self.pose(frame, true)
    }

    /// Frame `frame`, its mesh file read when `mesh` (else its `mesh` is empty: the file is
    /// packed from its path, [`Animation::streamed`]).
    fn pose(&self, frame: u64, mesh: bool) -> Result<Frame, Error> {
        let mut view = load_aff(&self.view, self.time(frame))?;
        let mesh = match &self.meshes {
            None => std::mem::take(&mut view.mesh),
            Some(pattern) if mesh => load(&frame_mesh_path(pattern, frame))?,
            Some(_) => Mesh::default(),
        };
        Ok(Frame {
            frame,
            time: view.time,
            mesh,
            view,
        })
    }

    /// The bounds (lowest and highest corner) of every triangle of every frame of the range:
    /// what the root cube of a file updated through them must hold. Reads or poses every frame.
    pub fn bounds(&self) -> Result<([f32; 3], [f32; 3]), Error> {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for f in self.frames.clone() {
            let frame = self.frame(f)?;
            for t in &frame.mesh.triangles {
                for &v in t {
                    if let Some(p) = frame.mesh.positions.get(v as usize) {
                        for k in 0..3 {
                            lo[k] = lo[k].min(p[k]);
                            hi[k] = hi[k].max(p[k]);
                        }
                    }
                }
            }
        }
        if lo[0] > hi[0] {
            return Err(Error::Invalid(format!(
                "frames {}..{}: no frame holds a triangle",
                self.frames.start, self.frames.end
            )));
        }
        Ok((lo, hi))
    }

    /// `pack` as the frames are packed: updatable, and with `pack.bounds`, or else the bounds
    /// of the range ([`Animation::bounds`]), as the box the root cube must hold.
    pub fn pack_options(&self, pack: &PackOptions) -> Result<PackOptions, Error> {
        let bounds = match pack.bounds {
            Some(b) => b,
            None => self.bounds()?,
        };
        Ok(PackOptions {
            updatable: true,
            bounds: Some(bounds),
            ..*pack
        })
    }

    /// Packs the first frame of the range into `file` (replacing it, atomically) so that it can
    /// be updated through every frame of the range: updatable, its root cube holding
    /// `pack.bounds` or else the bounds of every frame ([`Animation::pack_options`]).
    pub fn pack_first(&self, file: &Path, pack: &PackOptions) -> Result<FirstPack, Error> {
        let t = Instant::now();
        let opts = self.pack_options(pack)?;
        let bounds_seconds = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let start = self.frames.start;
        let streamed = self.streamed(start, &opts);
        let frame = self.pose(start, streamed.is_none())?;
        let pose_seconds = t.elapsed().as_secs_f64();
        let report = self
            .pack_frame(
                start,
                streamed.as_ref().map(|s| s.0.as_path()),
                frame.mesh,
                file,
                &opts,
            )
            .map_err(|e| at_frame(start, e))?;
        Ok(FirstPack {
            file: file.to_owned(),
            frame: self.frames.start,
            bounds: opts.bounds.unwrap_or_default(),
            bounds_seconds,
            pose_seconds,
            pack: report,
        })
    }

    /// Frame `frame`'s mesh file and its triangle count, when a pack of it with `opts`
    /// streams: a binary PLY, and `opts.mem_budget` is given or its triangles would take more
    /// than the memory available to build in memory (as `oavm-pack` decides,
    /// [`streaming_budget`]). Such a frame is packed from its path ([`crate::pack::pack`])
    /// without being read into memory first, and its pack time includes reading the file (the
    /// streaming pack's passes over it).
    pub fn streamed(&self, frame: u64, opts: &PackOptions) -> Option<(PathBuf, u64)> {
        let path = frame_mesh_path(self.meshes.as_ref()?, frame);
        let faces = crate::mesh::stream::PlyStream::open(&path)
            .ok()?
            .face_count();
        if opts.mem_budget.is_none() {
            streaming_budget(faces, crate::os::available_memory()?)?;
        }
        Some((path, faces))
    }

    /// Packs frame `frame` into `file` with `opts`: from `streamed`, its file, where
    /// [`Animation::streamed`] said so (then `mesh` was not read), else from `mesh`. The
    /// caller decides once: asked again, the memory available may say otherwise.
    fn pack_frame(
        &self,
        frame: u64,
        streamed: Option<&Path>,
        mesh: Mesh,
        file: &Path,
        opts: &PackOptions,
    ) -> Result<PackReport, Error> {
        match streamed {
            Some(path) => pack(path, file, opts, &Quiet),
            None => pack_mesh(mesh, &self.frame_name(frame), file, opts, &Quiet),
        }
    }

    /// What names frame `frame`'s geometry in reports.
    fn frame_name(&self, frame: u64) -> String {
        match &self.meshes {
            Some(pattern) => frame_mesh_path(pattern, frame).display().to_string(),
            None => format!(
                "{} at time {}",
                self.view.display(),
                self.time(frame).unwrap_or(0.0)
            ),
        }
    }
}

/// What [`Animation::pack_first`] did.
#[derive(Clone, Debug, Serialize)]
pub struct FirstPack {
    /// The file packed (not serialized: the report around it names it).
    #[serde(skip)]
    pub file: PathBuf,
    pub frame: u64,
    /// The box the root cube holds.
    pub bounds: ([f32; 3], [f32; 3]),
    /// Seconds finding the bounds (0 when they were given).
    pub bounds_seconds: f64,
    pub pose_seconds: f64,
    pub pack: PackReport,
}

/// How [`animate`] renders.
#[derive(Clone, Debug)]
pub struct AnimateOptions {
    pub mode: Mode,
    /// Where the images go (`frame_00012.png`; created if missing); `None`: nothing written
    /// (the images' digests are still reported).
    pub out_dir: Option<PathBuf>,
    /// The image's width and height; `None`: the view's.
    pub width: Option<u32>,
    pub height: Option<u32>,
    /// Bounces of reflection and refraction ([`ShadedOptions::max_depth`]).
    pub max_depth: u32,
    pub camera: CameraChoice,
    /// One white light here instead of the scene's lights.
    pub light: Option<[f64; 3]>,
    /// How the file is opened for tracing (memory budget, threads).
    pub scene: SceneOptions,
    /// The order tiles are traced in; `None`: the file's default ([`Scene::default_order`]).
    /// The images are the same.
    pub order: Option<Order>,
    /// How updates store their blocks ([`Mode::Update`]).
    pub update: UpdateOptions,
    /// How frames are packed ([`Mode::Rebuild`]), made updatable with the range's bounds as
    /// [`Animation::pack_options`] says.
    pub pack: PackOptions,
}

impl Default for AnimateOptions {
    fn default() -> Self {
        AnimateOptions {
            mode: Mode::Update,
            out_dir: None,
            width: None,
            height: None,
            max_depth: DEFAULT_MAX_DEPTH,
            camera: CameraChoice::View,
            light: None,
            scene: SceneOptions::default(),
            order: None,
            update: UpdateOptions::default(),
            pack: PackOptions::default(),
        }
    }
}

/// One frame of [`animate`].
#[derive(Clone, Debug, Serialize)]
pub struct FrameReport {
    pub frame: u64,
    /// The time the view scene was posed at.
    pub time: f64,
    pub triangles: u64,
    /// Seconds reading or posing the frame's geometry (not in `frame_seconds`).
    pub pose_seconds: f64,
    /// [`Mode::Update`]: primitives that differ from the file before the frame (0: no update
    /// written); [`Mode::Rebuild`]: every primitive.
    pub changed: u64,
    /// Seconds bringing the file to the frame: the update (opening the updater, finding the
    /// changes, rebuilding, writing and syncing) or the full pack (build, write, sync).
    pub update_seconds: f64,
    /// The update's own report ([`Mode::Update`], when something changed).
    pub update: Option<UpdateReport>,
    /// The pack's report ([`Mode::Rebuild`]).
    pub pack: Option<PackReport>,
    /// Bytes the frame wrote to the file: the update's ([`UpdateReport::bytes_written`]) or the
    /// whole file packed.
    pub bytes_written: u64,
    /// The file's size after the frame.
    pub file_bytes: u64,
    /// Seconds opening the file for tracing.
    pub open_seconds: f64,
    /// Seconds rendering ([`ShadedStats::seconds`]).
    pub render_seconds: f64,
    /// `update_seconds + open_seconds + render_seconds`.
    pub frame_seconds: f64,
    /// Seconds encoding and writing the PNG (not in `frame_seconds`).
    pub write_seconds: f64,
    /// Threads the render traced on.
    pub threads: usize,
    pub image: Option<PathBuf>,
    /// xxh3-64 of the image's RGB8 pixels: frames rendered alike have the same digest.
    pub image_xxh3: String,
    pub render: ShadedStats,
}

/// What [`animate`] did: every frame, and the sums.
#[derive(Clone, Debug, Serialize)]
pub struct AnimationReport {
    pub file: PathBuf,
    pub view: PathBuf,
    pub meshes: Option<String>,
    pub mode: Mode,
    /// The range rendered, `first..end`.
    pub first: u64,
    pub end: u64,
    pub frames: u64,
    pub width: u32,
    pub height: u32,
    pub max_depth: u32,
    pub camera: CameraChoice,
    /// Threads the renders traced on.
    pub threads: usize,
    /// [`Mode::Rebuild`]: the box the root cube holds, and the seconds finding it (0 when
    /// given).
    pub bounds: Option<([f32; 3], [f32; 3])>,
    pub bounds_seconds: f64,
    /// Sums over the frames.
    pub pose_seconds: f64,
    pub update_seconds: f64,
    pub open_seconds: f64,
    pub render_seconds: f64,
    pub frame_seconds: f64,
    pub write_seconds: f64,
    pub bytes_written: u64,
    /// Frames a second: `frames / frame_seconds` (update, open and render).
    pub fps: f64,
    /// Frames a second of the renders alone: `frames / render_seconds`.
    pub render_fps: f64,
    /// Rays of every kind, and their rate over `render_seconds`.
    pub rays: u64,
    pub mrays_per_s: f64,
    /// The file's size after the last frame.
    pub file_bytes: u64,
    /// Wall seconds of the whole run.
    pub total_seconds: f64,
    pub per_frame: Vec<FrameReport>,
}

/// What `oavm-trace --frames` reports with `--json`: the first pack, when the file was packed
/// first ([`Animation::pack_first`]), and the animation's report.
#[derive(Clone, Debug, Serialize)]
pub struct AnimationRun {
    /// The first pack ([`Animation::pack_first`]), when the file was packed first.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub packed: Option<FirstPack>,
    /// The frames ([`animate`]), flattened into the same object.
    #[serde(flatten)]
    pub animation: AnimationReport,
}

/// `packed FILE from frame A (N triangles, B bytes, S s), root cube around LO..HI`.
impl fmt::Display for FirstPack {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "packed {} from frame {} ({} triangles, {} bytes, {:.3} s), root cube around \
             {:?}..{:?}",
            self.file.display(),
            self.frame,
            self.pack.stats.input_triangles,
            self.pack.file_bytes,
            self.pack.total_seconds,
            self.bounds.0,
            self.bounds.1
        )
    }
}

/// `frame F (time T): HOW; render S s (N rays, M Mrays/s) -> IMAGE`, where HOW is the update
/// (what moved and what it rebuilt and wrote), the pack, or `no change`.
impl fmt::Display for FrameReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "frame {} (time {}): ", self.frame, self.time)?;
        match (&self.update, &self.pack) {
            (Some(u), _) => write!(
                f,
                "update {:.3} s ({} moved, {} inserted, {} removed; {} of {} blocks rebuilt; \
                 {} bytes written)",
                self.update_seconds,
                u.moved,
                u.inserted,
                u.removed,
                u.blocks_rebuilt,
                u.blocks_before,
                u.bytes_written
            )?,
            (_, Some(p)) => write!(
                f,
                "pack {:.3} s ({} blocks, {} bytes)",
                self.update_seconds, p.block_count, p.file_bytes
            )?,
            _ => write!(f, "no change ({:.3} s)", self.update_seconds)?,
        }
        write!(
            f,
            "; render {:.3} s ({} rays, {:.2} Mrays/s)",
            self.render_seconds, self.render.rays, self.render.mrays_per_s
        )?;
        match &self.image {
            Some(p) => write!(f, " -> {}", p.display()),
            None => Ok(()),
        }
    }
}

/// `N frames (WxH, MODE, depth D) on T threads: F frames/s (S s a frame: ...); M Mrays/s; B
/// bytes written, file B bytes`, the times a frame's means.
impl fmt::Display for AnimationReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mean = |s: f64| s / self.frames.max(1) as f64;
        write!(
            f,
            "{} frames ({}x{}, {}, depth {}) on {} threads: {:.2} frames/s ({:.3} s a frame: {} \
             {:.3} s, open {:.3} s, render {:.3} s); {:.2} Mrays/s; {} bytes written, file {} \
             bytes",
            self.frames,
            self.width,
            self.height,
            self.mode.done(),
            self.max_depth,
            self.threads,
            self.fps,
            mean(self.frame_seconds),
            self.mode.step(),
            mean(self.update_seconds),
            mean(self.open_seconds),
            mean(self.render_seconds),
            self.mrays_per_s,
            self.bytes_written,
            self.file_bytes,
        )
    }
}

/// An error of frame `frame`, saying so.
fn at_frame(frame: u64, e: Error) -> Error {
    Error::Invalid(format!("frame {frame}: {e}"))
}

/// The camera of `view` as `choice` asks, and the view it came from.
fn pick_camera(view: &AffScene, path: &Path, choice: CameraChoice) -> Result<AffView, Error> {
    let v = match choice {
        CameraChoice::View => view.view.ok_or_else(|| {
            Error::Invalid(format!(
                "{}: the scene has no viewpoint (`v` block) for the camera",
                path.display()
            ))
        })?,
        CameraChoice::Path => view.camera_path.ok_or_else(|| {
            Error::Invalid(format!(
                "{}: the scene has no camera path (`k camera` and a `v` block) for the camera",
                path.display()
            ))
        })?,
        CameraChoice::Auto => {
            return pick_camera(
                view,
                path,
                if view.camera_path.is_some() {
                    CameraChoice::Path
                } else {
                    CameraChoice::View
                },
            );
        }
    };
    Ok(v)
}

/// Renders the frames of `anim` with the file at `file` brought to each in turn as
/// `opts.mode` says (see the [module documentation](self)); calls `each` with every frame's
/// report as it is done. In [`Mode::Update`] the file must be updatable (the error says so
/// before any frame is posed); in [`Mode::Rebuild`] it is written by the first frame.
pub fn animate(
    anim: &Animation,
    file: &Path,
    opts: &AnimateOptions,
    each: &mut dyn FnMut(&FrameReport),
) -> Result<AnimationReport, Error> {
    let start = Instant::now();
    opts.update.validate()?;
    if opts.max_depth > MAX_DEPTH_LIMIT {
        return Err(Error::Invalid(format!(
            "a depth of {} bounces: at most {MAX_DEPTH_LIMIT}",
            opts.max_depth
        )));
    }
    check_size(opts.width.unwrap_or(1), opts.height.unwrap_or(1))?;
    let (pack, bounds_seconds) = match opts.mode {
        Mode::Update => {
            // Refuses a file that cannot be updated, naming why, before any work.
            drop(Updater::open(file)?);
            (None, 0.0)
        }
        Mode::Rebuild => {
            let t = Instant::now();
            let pack = anim.pack_options(&opts.pack)?;
            pack.validate()?;
            let given = opts.pack.bounds.is_some();
            (
                Some(pack),
                if given {
                    0.0
                } else {
                    t.elapsed().as_secs_f64()
                },
            )
        }
    };
    if let Some(dir) = &opts.out_dir {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    let mut report = AnimationReport {
        file: file.to_owned(),
        view: anim.view.clone(),
        meshes: anim.meshes.clone(),
        mode: opts.mode,
        first: anim.frames.start,
        end: anim.frames.end,
        frames: 0,
        width: 0,
        height: 0,
        max_depth: opts.max_depth,
        camera: opts.camera,
        threads: 0,
        bounds: pack.and_then(|p| p.bounds),
        bounds_seconds,
        pose_seconds: 0.0,
        update_seconds: 0.0,
        open_seconds: 0.0,
        render_seconds: 0.0,
        frame_seconds: 0.0,
        write_seconds: 0.0,
        bytes_written: 0,
        fps: 0.0,
        render_fps: 0.0,
        rays: 0,
        mrays_per_s: 0.0,
        file_bytes: 0,
        total_seconds: 0.0,
        per_frame: Vec::new(),
    };
    for f in anim.frames.clone() {
        let r = one_frame(anim, file, opts, pack.as_ref(), f).map_err(|e| at_frame(f, e))?;
        report.width = r.render.width;
        report.height = r.render.height;
        report.frames += 1;
        report.pose_seconds += r.pose_seconds;
        report.update_seconds += r.update_seconds;
        report.open_seconds += r.open_seconds;
        report.render_seconds += r.render_seconds;
        report.frame_seconds += r.frame_seconds;
        report.write_seconds += r.write_seconds;
        report.bytes_written += r.bytes_written;
        report.rays += r.render.rays;
        report.file_bytes = r.file_bytes;
        report.threads = r.threads;
        each(&r);
        report.per_frame.push(r);
    }
    let rate = |n: f64, s: f64| if s > 0.0 { n / s } else { 0.0 };
    report.fps = rate(report.frames as f64, report.frame_seconds);
    report.render_fps = rate(report.frames as f64, report.render_seconds);
    report.mrays_per_s = rate(report.rays as f64 / 1e6, report.render_seconds);
    report.total_seconds = start.elapsed().as_secs_f64();
    Ok(report)
}

/// Frame `f`: pose it, bring the file to it, render it, write its image.
fn one_frame(
    anim: &Animation,
    file: &Path,
    opts: &AnimateOptions,
    pack: Option<&PackOptions>,
    f: u64,
) -> Result<FrameReport, Error> {
    // The image's place is checked before the work.
    let image = opts.out_dir.as_ref().map(|d| d.join(frame_image_name(f)));
    let out = match &image {
        Some(p) => Some(Output::create(p, &[file, &anim.view])?),
        None => None,
    };
    // A frame packed streaming is not read into memory first (the pack reads it).
    let t = Instant::now();
    let streamed = pack.and_then(|p| anim.streamed(f, p));
    let frame = anim.pose(f, streamed.is_none())?;
    let pose_seconds = t.elapsed().as_secs_f64();
    let v = pick_camera(&frame.view, &anim.view, opts.camera)?;
    let camera = Camera::look_at(v.from, v.at, v.up, v.angle_deg)
        .map_err(|e| Error::Invalid(format!("{}: viewpoint: {e}", anim.view.display())))?;
    let width = opts.width.unwrap_or(v.resolution.0);
    let height = opts.height.unwrap_or(v.resolution.1);
    let mut look = Look::from_aff(&frame.view);
    if let Some(l) = opts.light {
        look.lights = vec![PointLight {
            position: l,
            colour: [1.0; 3],
        }];
    }
    let triangles = match &streamed {
        Some((_, faces)) => *faces,
        None => frame.mesh.triangles.len() as u64,
    };

    let t = Instant::now();
    let (changed, update, packed) = match pack {
        None => {
            let mut u = Updater::open(file)?;
            let changed = u.set_mesh(&frame.mesh)?;
            drop(frame.mesh);
            let update = match changed {
                0 => None,
                _ => Some(u.commit(&opts.update)?),
            };
            (changed, update, None)
        }
        Some(p) => {
            let path = streamed.as_ref().map(|s| s.0.as_path());
            let r = anim.pack_frame(f, path, frame.mesh, file, p)?;
            (triangles, None, Some(r))
        }
    };
    let update_seconds = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let scene = Scene::open_with(file, &opts.scene)?;
    let open_seconds = t.elapsed().as_secs_f64();
    let threads = scene.threads().min(rayon::current_num_threads());
    let mut shaded = ShadedOptions::new(width, height, camera);
    shaded.max_depth = opts.max_depth;
    shaded.order = opts.order.unwrap_or_else(|| scene.default_order());
    let (img, stats) = render_shaded(&scene, &shaded, &look)?;
    drop(scene);
    let image_xxh3 = format!("{:016x}", xxhash_rust::xxh3::xxh3_64(&img.rgb));

    let t = Instant::now();
    if let Some(out) = out {
        write_png(out, &img)?;
    }
    let write_seconds = t.elapsed().as_secs_f64();
    let file_bytes = std::fs::metadata(file)
        .map_err(|e| Error::io(file, e))?
        .len();
    let bytes_written = match (&update, &packed) {
        (Some(u), _) => u.bytes_written,
        (_, Some(p)) => p.file_bytes,
        _ => 0,
    };
    Ok(FrameReport {
        frame: f,
        time: frame.time,
        triangles,
        pose_seconds,
        changed,
        update_seconds,
        update,
        pack: packed,
        bytes_written,
        file_bytes,
        open_seconds,
        render_seconds: stats.seconds,
        frame_seconds: update_seconds + open_seconds + stats.seconds,
        write_seconds,
        threads,
        image,
        image_xxh3,
        render: stats,
    })
}
