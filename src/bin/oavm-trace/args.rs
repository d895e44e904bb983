//! `oavm-trace`'s arguments: their declarations (clap; their doc comments are `--help`), the
//! checks clap cannot express, and the [`Mode`] a run takes from them.

use std::path::PathBuf;

use clap::Parser;
use oavm::Error;
use oavm::logical::{Query, RaySet};
use oavm::render::animate;

use crate::cli;

/// Traces rays through an .oavm file made by oavm-pack.
///
/// With no mode option, renders the model from a camera that frames it (or from the viewpoint of
/// a BART scene, --view), shaded by a point light with shadows, and writes a PNG (with --shade,
/// ray traced with the scene's materials and lights, reflections and refractions). With --rays and
/// --hits (closest hit) or --occluded (any hit), traces a ray file in the formats of RAYS.md.
/// With --random N or --primary WxH (and --shadow), traces rays it makes and reports the figures
/// only. With --verify, checks every byte of the file. With --frames A..B, renders frames of an
/// animation (--view), bringing the file to each frame by a local update (or, with --rebuild, a
/// full pack), ray traced as with --shade, to numbered PNGs in the -o directory. Outputs are written atomically, through
/// symlinks, never over a directory, device or FIFO, nor over an input.
#[derive(Parser, Debug)]
#[command(name = "oavm-trace", version)]
pub(crate) struct Args {
    /// The .oavm file.
    pub(crate) file: PathBuf,
    /// Batch mode: a RAYS file to trace.
    #[arg(long, value_name = "RAYS", conflicts_with_all = ["random", "primary", "verify"])]
    pub(crate) rays: Option<PathBuf>,
    /// Batch mode: write closest hits to this HITS file.
    #[arg(
        long,
        value_name = "HITS",
        requires = "rays",
        conflicts_with = "occluded"
    )]
    pub(crate) hits: Option<PathBuf>,
    /// Batch mode: write any-hit answers to this OCCL file.
    #[arg(long, value_name = "OCCL", requires = "rays", conflicts_with_all = ["all_hits", "count_hits"])]
    pub(crate) occluded: Option<PathBuf>,
    /// Batch mode: write every hit along each ray (t, primitive, u, v, in order of t) to this
    /// HITL file (docs/cli.md, "Every hit").
    #[arg(long, value_name = "HITL", requires = "rays", conflicts_with_all = ["hits", "count_hits"])]
    pub(crate) all_hits: Option<PathBuf>,
    /// Batch mode: write how many triangles each ray hits to this HITC file (a u32 per ray).
    #[arg(long, value_name = "HITC", requires = "rays", conflicts_with = "hits")]
    pub(crate) count_hits: Option<PathBuf>,
    /// Benchmark mode: trace N random rays (origins around the model, directions uniform; the
    /// ray sets of `cargo run --features tools --example rays`), closest hit; nothing is written. At most what
    /// half of the available memory holds (64 bytes a ray).
    #[arg(long, value_name = "N", conflicts_with_all = ["primary", "verify"])]
    pub(crate) random: Option<u64>,
    /// Benchmark mode: trace the WxH primary rays of the camera (as for rendering: --eye,
    /// --target, --fov, --view...), closest hit; nothing is written.
    #[arg(long, value_name = "WxH", value_parser = cli::parse_size, conflicts_with = "verify")]
    pub(crate) primary: Option<(u32, u32)>,
    /// Benchmark mode: then trace a shadow ray (any hit) from every hit to the light.
    #[arg(long)]
    pub(crate) shadow: bool,
    /// Benchmark mode with --shadow: trace in waves of N rays, taken in the tracing order
    /// (--order), each wave's shadow rays right after its primary ones, while the blocks they
    /// start in are still in memory, as a renderer would (0: all primary rays, then all shadow
    /// rays; default 65536). The answers are the same.
    #[arg(long, value_name = "N", requires = "shadow")]
    pub(crate) wave: Option<usize>,
    /// Seed of --random (default 1).
    #[arg(long, requires = "random")]
    pub(crate) seed: Option<u64>,
    /// Check every section, checksum and invariant; exit non-zero on any defect.
    #[arg(long)]
    pub(crate) verify: bool,
    /// Render mode: the image to write (default: the file's name with .png). With --frames:
    /// the directory the frames go to (`frame_00012.png`; created if missing).
    #[arg(short, long, value_name = "PNG", conflicts_with_all = ["rays", "random", "primary", "verify"])]
    pub(crate) output: Option<PathBuf>,
    /// Render mode: image width (default 1024, or the --view scene's resolution).
    #[arg(long, conflicts_with_all = ["rays", "random", "primary", "verify"])]
    pub(crate) width: Option<u32>,
    /// Render mode: image height (default 768, or the --view scene's resolution).
    #[arg(long, conflicts_with_all = ["rays", "random", "primary", "verify"])]
    pub(crate) height: Option<u32>,
    /// Render mode: ray trace in Whitted's way with the materials and lights of the --view
    /// scene (a white diffuse material and one light for another mesh): shadows from every
    /// light, Phong highlights, reflection and refraction (see `oavm::render::render_shaded`).
    /// --light replaces the scene's lights by one white light.
    #[arg(long, conflicts_with_all = ["rays", "random", "primary", "verify"])]
    pub(crate) shade: bool,
    /// Render mode with --shade or --frames: the most bounces of reflection and refraction
    /// (default 5, at most 16; 0: none).
    #[arg(long, value_name = "N")]
    pub(crate) depth: Option<u32>,
    /// With --view: pose the scene at this time (default: its animation start, as oavm-pack
    /// does) for its camera, lights and materials. Give the time the file was packed at.
    #[arg(long, value_name = "T", requires = "view", conflicts_with = "frames")]
    pub(crate) time: Option<f64>,
    /// Animation mode: render frames A..B (A to B-1; A..=B; or one frame A) of the --view
    /// scene's animation (`a start end frames`: frame f at start + f (end - start) / frames):
    /// for each frame, bring FILE to its triangles by a local update (FILE must be packed with
    /// `oavm-pack --updatable`, its root cube holding every frame: see --pack), ray trace it as
    /// --shade does (the frame's lights and materials, shadows, reflection and refraction to
    /// --depth) and write OUT_DIR/frame_NNNNN.png (-o, required). The camera is the --view
    /// scene's `v` block, or its camera path with --camera-path.
    #[arg(long, value_name = "A..B", value_parser = animate::parse_frames, requires = "view",
          conflicts_with_all = ["rays", "random", "primary", "verify"])]
    pub(crate) frames: Option<std::ops::Range<u64>>,
    /// With --frames: read frame f's triangles from PATTERN, its {} replaced by f padded to
    /// five digits (e.g. DIR/rain_{}.ply of `cargo run --features tools --example rain`), triangle i being
    /// primitive i, instead of posing the --view scene, which gives the camera, lights and
    /// materials.
    #[arg(long, value_name = "PATTERN", requires = "frames")]
    pub(crate) frame_meshes: Option<String>,
    /// With --frames: pack each frame whole into FILE (replacing it) instead of updating it:
    /// the full rebuild per frame, to compare with. The images are the same, byte for byte.
    #[arg(long, requires = "frames")]
    pub(crate) rebuild: bool,
    /// With --frames: first pack FILE (replacing it) from frame A, updatable, with a root cube
    /// that holds every frame of the range (each frame posed to find its bounds).
    #[arg(long, requires = "frames", conflicts_with = "rebuild")]
    pub(crate) pack: bool,
    #[command(flatten)]
    pub(crate) camera: cli::CameraArgs,
    #[command(flatten)]
    pub(crate) trace: cli::TraceArgs,
    /// Print one JSON object with the figures of the run.
    #[arg(long)]
    pub(crate) json: bool,
}

/// What a run does, from the arguments.
#[derive(Debug)]
pub(crate) enum Mode {
    Render {
        image: PathBuf,
    },
    Batch {
        rays: PathBuf,
        query: Query,
        out: PathBuf,
    },
    Bench {
        set: RaySet,
        shadow: bool,
        wave: usize,
    },
    Verify,
    Frames {
        out_dir: PathBuf,
        range: std::ops::Range<u64>,
    },
}

/// Rays per wave by default (`--wave`).
const DEFAULT_WAVE: usize = 65536;

impl Args {
    /// An option given where its mode is not (clap's `requires` does not fire when the mode's
    /// own option is refused by a conflict of its own): a usage error, never ignored.
    pub(crate) fn misplaced(&self) -> Option<String> {
        let bench = self.random.is_some() || self.primary.is_some();
        let frames = self.frames.is_some();
        // Each group of options, given without what it needs (in the order checked)...
        let given = [
            [&self.hits, &self.occluded, &self.all_hits, &self.count_hits]
                .iter()
                .any(|o| o.is_some())
                && self.rays.is_none(),
            self.seed.is_some() && self.random.is_none(),
            (self.shadow || self.wave.is_some()) && !bench,
            self.depth.is_some() && !self.shade && !frames,
            frames && self.output.is_none(),
            (self.frame_meshes.is_some() || self.rebuild || self.pack) && !frames,
            self.time.is_some() && self.camera.view.is_none(),
        ];
        // ...and what it needs.
        const NEEDS: [(&str, &str); 7] = [
            (
                "--hits/--occluded/--all-hits/--count-hits",
                "--rays (batch mode)",
            ),
            ("--seed", "--random N"),
            ("--shadow/--wave", "--random N or --primary WxH"),
            ("--depth", "--shade or --frames"),
            (
                "--frames",
                "-o OUT_DIR (the directory of the frames' images)",
            ),
            ("--frame-meshes/--rebuild/--pack", "--frames A..B"),
            ("--time", "--view SCENE.aff"),
        ];
        let (_, (name, needs)) = given.into_iter().zip(NEEDS).find(|g| g.0)?;
        Some(format!("{name} needs {needs}; it was given without"))
    }

    /// The mode the arguments ask for (clap has already refused the combinations that ask for
    /// two).
    pub(crate) fn mode(&self) -> Result<Mode, Error> {
        if self.verify {
            return Ok(Mode::Verify);
        }
        if let Some(range) = &self.frames {
            let out_dir = self.output.clone().ok_or_else(|| {
                Error::Invalid(
                    "--frames needs -o OUT_DIR, the directory the frames' images go to".into(),
                )
            })?;
            let range = range.clone();
            return Ok(Mode::Frames { out_dir, range });
        }
        if let Some(rays) = self.rays.clone() {
            let asked = [
                (&self.hits, Query::Closest),
                (&self.occluded, Query::Any),
                (&self.all_hits, Query::All),
                (&self.count_hits, Query::Count),
            ];
            let mut given = asked.iter().filter_map(|(o, q)| Some(((*o).clone()?, *q)));
            let (out, query) = match (given.next(), given.next()) {
                (Some(one), None) => one,
                _ => {
                    return Err(Error::Invalid(
                        "--rays needs one of --hits (closest hit), --occluded (any hit), \
                         --all-hits (every hit) or --count-hits"
                            .into(),
                    ));
                }
            };
            return Ok(Mode::Batch { rays, query, out });
        }
        let set = match (self.random, self.primary) {
            (Some(count), _) => RaySet::Random {
                count,
                seed: self.seed.unwrap_or(1),
            },
            (None, Some((width, height))) => RaySet::Primary { width, height },
            (None, None) if self.shadow => {
                return Err(Error::Invalid(
                    "--shadow needs --random N or --primary WxH".into(),
                ));
            }
            (None, None) => {
                let image = self.output.clone();
                let image = image.unwrap_or_else(|| self.file.with_extension("png"));
                return Ok(Mode::Render { image });
            }
        };
        let (shadow, wave) = (self.shadow, self.wave.unwrap_or(DEFAULT_WAVE));
        Ok(Mode::Bench { set, shadow, wave })
    }
}
