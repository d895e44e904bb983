//! `oavm-trace FILE.oavm`: traces rays through a packed file, memory-mapped, with no rebuild.
//! Renders an image by default; traces ray files in batch mode, or rays it makes itself in
//! benchmark mode; verifies files. Glue: the arguments become a typed [`Mode`], the library
//! does the work, this prints what it reports.

mod cli;

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use clap::Parser;
use cli::Pool;
use oavm::logical::{Answered, FrameOptions, Order, SceneInfo, SetReport, VerifyReport};
use oavm::mesh::AffScene;
use oavm::output::Output;
use oavm::rays::{self, Bounds, Camera};
use oavm::render::animate::{
    self, AnimateOptions, Animation, AnimationReport, CameraChoice, FirstPack, FrameReport,
};
use oavm::render::{
    self, Look, PointLight, RenderOptions, RenderStats, ShadedOptions, ShadedStats,
};
use oavm::{Error, Hit, Scene};
use serde::Serialize;

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
struct Args {
    /// The .oavm file.
    file: PathBuf,
    /// Batch mode: a RAYS file to trace.
    #[arg(long, value_name = "RAYS", conflicts_with_all = ["random", "primary", "verify"])]
    rays: Option<PathBuf>,
    /// Batch mode: write closest hits to this HITS file.
    #[arg(
        long,
        value_name = "HITS",
        requires = "rays",
        conflicts_with = "occluded"
    )]
    hits: Option<PathBuf>,
    /// Batch mode: write any-hit answers to this OCCL file.
    #[arg(long, value_name = "OCCL", requires = "rays")]
    occluded: Option<PathBuf>,
    /// Benchmark mode: trace N random rays (origins around the model, directions uniform; the
    /// ray sets of `cargo run --example rays`), closest hit; nothing is written. At most what
    /// half of the available memory holds (64 bytes a ray).
    #[arg(long, value_name = "N", conflicts_with_all = ["primary", "verify"])]
    random: Option<u64>,
    /// Benchmark mode: trace the WxH primary rays of the camera (as for rendering: --eye,
    /// --target, --fov, --view...), closest hit; nothing is written.
    #[arg(long, value_name = "WxH", value_parser = cli::parse_size, conflicts_with = "verify")]
    primary: Option<(u32, u32)>,
    /// Benchmark mode: then trace a shadow ray (any hit) from every hit to the light.
    #[arg(long)]
    shadow: bool,
    /// Benchmark mode with --shadow: trace in waves of N rays, taken in the tracing order
    /// (--order), each wave's shadow rays right after its primary ones, while the blocks they
    /// start in are still in memory, as a renderer would (0: all primary rays, then all shadow
    /// rays; default 65536). The answers are the same.
    #[arg(long, value_name = "N", requires = "shadow")]
    wave: Option<usize>,
    /// Seed of --random (default 1).
    #[arg(long, requires = "random")]
    seed: Option<u64>,
    /// Check every section, checksum and invariant; exit non-zero on any defect.
    #[arg(long)]
    verify: bool,
    /// Render mode: the image to write (default: the file's name with .png). With --frames:
    /// the directory the frames go to (`frame_00012.png`; created if missing).
    #[arg(short, long, value_name = "PNG", conflicts_with_all = ["rays", "random", "primary", "verify"])]
    output: Option<PathBuf>,
    /// Render mode: image width (default 1024, or the --view scene's resolution).
    #[arg(long, conflicts_with_all = ["rays", "random", "primary", "verify"])]
    width: Option<u32>,
    /// Render mode: image height (default 768, or the --view scene's resolution).
    #[arg(long, conflicts_with_all = ["rays", "random", "primary", "verify"])]
    height: Option<u32>,
    /// Render mode: ray trace in Whitted's way with the materials and lights of the --view
    /// scene (a white diffuse material and one light for another mesh): shadows from every
    /// light, Phong highlights, reflection and refraction (see `oavm::render::render_shaded`).
    /// --light replaces the scene's lights by one white light.
    #[arg(long, conflicts_with_all = ["rays", "random", "primary", "verify"])]
    shade: bool,
    /// Render mode with --shade or --frames: the most bounces of reflection and refraction
    /// (default 5, at most 16; 0: none).
    #[arg(long, value_name = "N")]
    depth: Option<u32>,
    /// With --view: pose the scene at this time (default: its animation start, as oavm-pack
    /// does) for its camera, lights and materials. Give the time the file was packed at.
    #[arg(long, value_name = "T", requires = "view", conflicts_with = "frames")]
    time: Option<f64>,
    /// Animation mode: render frames A..B (A to B-1; A..=B; or one frame A) of the --view
    /// scene's animation (`a start end frames`: frame f at start + f (end - start) / frames):
    /// for each frame, bring FILE to its triangles by a local update (FILE must be packed with
    /// `oavm-pack --updatable`, its root cube holding every frame: see --pack), ray trace it as
    /// --shade does (the frame's lights and materials, shadows, reflection and refraction to
    /// --depth) and write OUT_DIR/frame_NNNNN.png (-o, required). The camera is the --view
    /// scene's `v` block, or its camera path with --camera-path.
    #[arg(long, value_name = "A..B", value_parser = parse_frames, requires = "view",
          conflicts_with_all = ["rays", "random", "primary", "verify"])]
    frames: Option<std::ops::Range<u64>>,
    /// With --frames: read frame f's triangles from PATTERN, its {} replaced by f padded to
    /// five digits (e.g. DIR/rain_{}.ply of `cargo run --example rain`), triangle i being
    /// primitive i, instead of posing the --view scene, which gives the camera, lights and
    /// materials.
    #[arg(long, value_name = "PATTERN", requires = "frames")]
    frame_meshes: Option<String>,
    /// With --frames: pack each frame whole into FILE (replacing it) instead of updating it:
    /// the full rebuild per frame, to compare with. The images are the same, byte for byte.
    #[arg(long, requires = "frames")]
    rebuild: bool,
    /// With --frames: first pack FILE (replacing it) from frame A, updatable, with a root cube
    /// that holds every frame of the range (each frame posed to find its bounds).
    #[arg(long, requires = "frames", conflicts_with = "rebuild")]
    pack: bool,
    #[command(flatten)]
    camera: cli::CameraArgs,
    #[command(flatten)]
    trace: cli::TraceArgs,
    /// Print one JSON object with the figures of the run.
    #[arg(long)]
    json: bool,
}

/// What a run does, from the arguments.
#[derive(Debug)]
enum Mode {
    Render {
        image: PathBuf,
    },
    Batch {
        rays: PathBuf,
        query: Query,
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

#[derive(Debug)]
enum Query {
    /// Closest hits, to a HITS file.
    Closest(PathBuf),
    /// Any hit, to an OCCL file.
    Any(PathBuf),
}

/// A camera, its light and its image size.
type Shot = (Camera, [f32; 3], (u32, u32));

#[derive(Clone, Copy, Debug)]
enum RaySet {
    Random { count: u64, seed: u64 },
    Primary { width: u32, height: u32 },
}

/// Rays per wave by default (`--wave`).
const DEFAULT_WAVE: usize = 65536;

impl Args {
    /// An option given where its mode is not (clap's `requires` does not fire when the mode's
    /// own option is refused by a conflict of its own): a usage error, never ignored.
    fn misplaced(&self) -> Option<String> {
        let given = |o: bool, name: &str, needs: &str| {
            o.then(|| format!("{name} needs {needs}; it was given without"))
        };
        let bench = self.random.is_some() || self.primary.is_some();
        given(
            (self.hits.is_some() || self.occluded.is_some()) && self.rays.is_none(),
            "--hits/--occluded",
            "--rays (batch mode)",
        )
        .or_else(|| {
            given(
                self.seed.is_some() && self.random.is_none(),
                "--seed",
                "--random N",
            )
        })
        .or_else(|| {
            given(
                (self.shadow || self.wave.is_some()) && !bench,
                "--shadow/--wave",
                "--random N or --primary WxH",
            )
        })
        .or_else(|| {
            given(
                self.depth.is_some() && !self.shade && self.frames.is_none(),
                "--depth",
                "--shade or --frames",
            )
        })
        .or_else(|| {
            given(
                self.frames.is_some() && self.output.is_none(),
                "--frames",
                "-o OUT_DIR (the directory of the frames' images)",
            )
        })
        .or_else(|| {
            given(
                (self.frame_meshes.is_some() || self.rebuild || self.pack) && self.frames.is_none(),
                "--frame-meshes/--rebuild/--pack",
                "--frames A..B",
            )
        })
        .or_else(|| {
            given(
                self.time.is_some() && self.camera.view.is_none(),
                "--time",
                "--view SCENE.aff",
            )
        })
    }

    /// The mode the arguments ask for (clap has already refused the combinations that ask for
    /// two).
    fn mode(&self) -> Result<Mode, Error> {
        if self.verify {
            return Ok(Mode::Verify);
        }
        if let Some(range) = &self.frames {
            let out_dir = self.output.clone().ok_or_else(|| {
                Error::Invalid(
                    "--frames needs -o OUT_DIR, the directory the frames' images go to".into(),
                )
            })?;
            return Ok(Mode::Frames {
                out_dir,
                range: range.clone(),
            });
        }
        if let Some(rays) = &self.rays {
            let query = match (&self.hits, &self.occluded) {
                (Some(h), None) => Query::Closest(h.clone()),
                (None, Some(o)) => Query::Any(o.clone()),
                _ => {
                    return Err(Error::Invalid(
                        "--rays needs --hits (closest hit) or --occluded (any hit)".into(),
                    ));
                }
            };
            return Ok(Mode::Batch {
                rays: rays.clone(),
                query,
            });
        }
        let set = match (self.random, self.primary) {
            (Some(count), _) => Some(RaySet::Random {
                count,
                seed: self.seed.unwrap_or(1),
            }),
            (None, Some((width, height))) => Some(RaySet::Primary { width, height }),
            (None, None) => None,
        };
        match set {
            Some(set) => Ok(Mode::Bench {
                set,
                shadow: self.shadow,
                wave: self.wave.unwrap_or(DEFAULT_WAVE),
            }),
            None if self.shadow => Err(Error::Invalid(
                "--shadow needs --random N or --primary WxH".into(),
            )),
            None => Ok(Mode::Render {
                image: self
                    .output
                    .clone()
                    .unwrap_or_else(|| self.file.with_extension("png")),
            }),
        }
    }
}

fn main() -> ExitCode {
    let start = Instant::now();
    let args = Args::parse();
    if let Some(msg) = args.misplaced() {
        use clap::CommandFactory;
        Args::command()
            .error(clap::error::ErrorKind::ArgumentConflict, msg)
            .exit();
    }
    cli::main_with("oavm-trace", || run(&args, start))
}

fn run(args: &Args, start: Instant) -> Result<(), Error> {
    let mode = args.mode()?;
    match mode {
        Mode::Verify => return verify(args),
        Mode::Frames { out_dir, range } => return frames(args, &out_dir, range),
        _ => {}
    }
    let t = Instant::now();
    let mut scene = Scene::open_with(&args.file, &args.trace.scene_options(Pool::AfterOpen))?;
    let open_ms = t.elapsed().as_secs_f64() * 1e3;
    // Streamed batches draw their rays done and blocks read (on a terminal, after a second).
    let bar = std::sync::Arc::new(oavm::progress::Bar::new(std::io::IsTerminal::is_terminal(
        &std::io::stderr(),
    )));
    scene.set_progress(Some(bar.clone()));
    let threads = args.trace.threads_after_open(&scene, "oavm-trace");
    let order = args.trace.order.unwrap_or_else(|| scene.default_order());
    let mut ctx = Run {
        args,
        scene: &scene,
        start,
        open_ms,
        threads,
        order,
        first_ray_ms: 0.0,
        io_before: None,
    };
    cli::with_threads(threads, || match mode {
        Mode::Render { image } => ctx.render(&image),
        Mode::Batch { rays, query } => ctx.batch(&rays, &query),
        Mode::Bench { set, shadow, wave } => ctx.bench(set, shadow, wave),
        Mode::Verify | Mode::Frames { .. } => Ok(()),
    })
}

/// `--verify`: every byte, checksum and invariant.
fn verify(args: &Args) -> Result<(), Error> {
    let t = Instant::now();
    let scene = Scene::open(&args.file)?;
    let report = scene.verify()?;
    let seconds = t.elapsed().as_secs_f64();
    if args.json {
        #[derive(Serialize)]
        struct Verified<'a> {
            file: &'a Path,
            ok: bool,
            seconds: f64,
            report: &'a VerifyReport,
        }
        cli::print_json(&Verified {
            file: &args.file,
            ok: report.is_ok(),
            seconds,
            report: &report,
        })?;
    } else if report.is_ok() {
        cli::print_text(&format!(
            "{}: ok ({} bytes, {} sections, every checksum and invariant holds; {seconds:.3} s)\n",
            args.file.display(),
            report.bytes_checked,
            report.sections_checked,
        ))?;
    }
    if !report.is_ok() {
        for d in &report.defects {
            eprintln!("oavm-trace: {}: {d}", args.file.display());
        }
        return Err(Error::Invalid(format!(
            "{}: verification failed ({} defects)",
            args.file.display(),
            report.defects.len()
        )));
    }
    Ok(())
}

/// `--frames A..B`: an animation, each frame updated into the file (or packed whole, with
/// --rebuild) and rendered (`oavm::render::animate`).
fn frames(args: &Args, out_dir: &Path, range: std::ops::Range<u64>) -> Result<(), Error> {
    let view = args
        .camera
        .view
        .as_deref()
        .ok_or_else(|| Error::Invalid("--frames needs --view SCENE.aff".into()))?;
    let anim = match &args.frame_meshes {
        Some(pattern) => Animation::with_meshes(view, pattern, range)?,
        None => Animation::new(view, range)?,
    };
    let opts = AnimateOptions {
        mode: if args.rebuild {
            animate::Mode::Rebuild
        } else {
            animate::Mode::Update
        },
        out_dir: Some(out_dir.to_owned()),
        width: args.width,
        height: args.height,
        max_depth: args.depth.unwrap_or(render::DEFAULT_MAX_DEPTH),
        camera: if args.camera.camera_path {
            CameraChoice::Path
        } else {
            CameraChoice::View
        },
        light: args.camera.light,
        scene: args.trace.scene_options(Pool::BeforeOpen),
        order: args.trace.order,
        ..AnimateOptions::default()
    };
    cli::with_threads(opts.scene.threads, || {
        let first = match args.pack {
            true => {
                let p = anim.pack_first(&args.file, &opts.pack)?;
                if !args.json {
                    cli::print_text(&format!(
                        "packed {} from frame {} ({} triangles, {} bytes, {:.3} s), root cube \
                         around {:?}..{:?}\n",
                        args.file.display(),
                        p.frame,
                        p.pack.stats.input_triangles,
                        p.pack.file_bytes,
                        p.pack.total_seconds,
                        p.bounds.0,
                        p.bounds.1
                    ))?;
                }
                Some(p)
            }
            false => None,
        };
        let mut printed = Ok(());
        let report = animate::animate(&anim, &args.file, &opts, &mut |r| {
            if !args.json && printed.is_ok() {
                printed = cli::print_text(&frame_line(r));
            }
        })?;
        printed?;
        if args.json {
            #[derive(Serialize)]
            struct Frames<'a> {
                #[serde(skip_serializing_if = "Option::is_none")]
                packed: Option<FirstPack>,
                #[serde(flatten)]
                animation: &'a AnimationReport,
            }
            return cli::print_json(&Frames {
                packed: first,
                animation: &report,
            });
        }
        cli::print_text(&format!(
            "{} frames ({}x{}, {}, depth {}) on {} threads: {:.2} frames/s ({:.3} s a frame: \
             {} {:.3} s, open {:.3} s, render {:.3} s); {:.2} Mrays/s; {} bytes written, file \
             {} bytes\n",
            report.frames,
            report.width,
            report.height,
            match report.mode {
                animate::Mode::Update => "updated",
                animate::Mode::Rebuild => "rebuilt",
            },
            report.max_depth,
            report.threads,
            report.fps,
            report.frame_seconds / report.frames.max(1) as f64,
            match report.mode {
                animate::Mode::Update => "update",
                animate::Mode::Rebuild => "pack",
            },
            report.update_seconds / report.frames.max(1) as f64,
            report.open_seconds / report.frames.max(1) as f64,
            report.render_seconds / report.frames.max(1) as f64,
            report.mrays_per_s,
            report.bytes_written,
            report.file_bytes,
        ))
    })
}

/// One frame of `--frames`, as a line of text.
fn frame_line(r: &FrameReport) -> String {
    let how = match (&r.update, &r.pack) {
        (Some(u), _) => format!(
            "update {:.3} s ({} moved, {} inserted, {} removed; {} of {} blocks rebuilt; {} \
             bytes written)",
            r.update_seconds,
            u.moved,
            u.inserted,
            u.removed,
            u.blocks_rebuilt,
            u.blocks_before,
            u.bytes_written
        ),
        (_, Some(p)) => format!(
            "pack {:.3} s ({} blocks, {} bytes)",
            r.update_seconds, p.block_count, p.file_bytes
        ),
        _ => format!("no change ({:.3} s)", r.update_seconds),
    };
    let image = r
        .image
        .as_ref()
        .map_or(String::new(), |p| format!(" -> {}", p.display()));
    format!(
        "frame {} (time {}): {how}; render {:.3} s ({} rays, {:.2} Mrays/s){image}\n",
        r.frame, r.time, r.render_seconds, r.render.rays, r.render.mrays_per_s
    )
}

/// Parses `--frames`: `A..B` (A to B-1), `A..=B` (A to B) or `A` (one frame).
fn parse_frames(text: &str) -> Result<std::ops::Range<u64>, String> {
    let number = |s: &str| {
        s.trim()
            .parse::<u64>()
            .map_err(|e| format!("{s:?} is not a frame number: {e}"))
    };
    let (a, b) = if let Some((a, b)) = text.split_once("..=") {
        let b = number(b)?;
        (
            number(a)?,
            b.checked_add(1).ok_or("the range is too large")?,
        )
    } else if let Some((a, b)) = text.split_once("..") {
        (number(a)?, number(b)?)
    } else {
        let a = number(text)?;
        (a, a.checked_add(1).ok_or("the frame is too large")?)
    };
    if a >= b {
        return Err(format!(
            "{text:?}: the range is empty (A..B renders frames A to B-1; A..=B, or one frame A)"
        ));
    }
    Ok(a..b)
}

/// One tracing run: the scene and what every mode reports besides its rays.
struct Run<'a> {
    args: &'a Args,
    scene: &'a Scene,
    /// `main`'s entry (the time before it, exec and loading, is not counted).
    start: Instant,
    open_ms: f64,
    threads: usize,
    order: Order,
    first_ray_ms: f64,
    /// The process's `read_bytes` just before the first ray.
    io_before: Option<u64>,
}

/// The figures every tracing mode reports with `--json`, around the mode's own (`body`).
#[derive(Serialize)]
struct Report<'a, T: Serialize> {
    file: &'a Path,
    #[serde(flatten)]
    scene: SceneInfo,
    threads: usize,
    order: Order,
    open_ms: f64,
    start_to_first_ray_ms: f64,
    /// The budget asked for (`None`: the default, see `pager_budget`).
    mem_budget: Option<u64>,
    block_checks: bool,
    peak_rss_bytes: Option<u64>,
    disk_read_bytes_before_trace: Option<u64>,
    disk_read_bytes_trace: Option<u64>,
    #[serde(flatten)]
    body: T,
}

impl Run<'_> {
    /// Marks the moment the first ray is ready to be traced.
    fn first_ray(&mut self) {
        self.first_ray_ms = self.start.elapsed().as_secs_f64() * 1e3;
        self.io_before = oavm::os::read_bytes();
    }

    fn report<T: Serialize>(&self, body: T) -> Report<'_, T> {
        let io_after = oavm::os::read_bytes();
        Report {
            file: &self.args.file,
            scene: self.scene.info(),
            threads: self.threads,
            order: self.order,
            open_ms: self.open_ms,
            start_to_first_ray_ms: self.first_ray_ms,
            mem_budget: self.args.trace.mem_budget,
            block_checks: !self.args.trace.no_block_checks,
            peak_rss_bytes: oavm::os::peak_rss_bytes(),
            disk_read_bytes_before_trace: self.io_before,
            disk_read_bytes_trace: io_after
                .zip(self.io_before)
                .map(|(a, b)| a.saturating_sub(b)),
            body,
        }
    }

    /// The pager's figures for a set, as a clause of the text report.
    fn paging_text(&self, s: &SetReport) -> String {
        let p = &s.page;
        format!(
            "; pager: {} blocks asked, {} misses ({:.1} % hits), {:.1} MB read ({:.0} B/ray), \
             peak {:.1} MB resident of {:.1} MB",
            p.counters.requested,
            p.counters.misses,
            100.0 * p.hit_rate,
            p.counters.bytes_read as f64 / 1e6,
            p.bytes_read_per_ray,
            self.scene.peak_resident_bytes() as f64 / 1e6,
            self.scene.budget() as f64 / 1e6,
        )
    }

    /// The most rays a run may hold: what half of the available memory holds.
    fn max_rays(&self) -> u64 {
        let avail = oavm::os::available_memory().unwrap_or(oavm::logical::FALLBACK_MEM_BUDGET);
        oavm::logical::max_rays(avail / 2)
    }

    /// Render mode: the image, written only once every pixel is traced.
    fn render(&mut self, image: &Path) -> Result<(), Error> {
        if self.args.shade {
            return self.render_shaded(image);
        }
        let out = Output::create(image, &[&self.args.file])?;
        let (camera, light, (width, height)) = self.shot()?;
        let opts = RenderOptions {
            width: self.args.width.unwrap_or(width),
            height: self.args.height.unwrap_or(height),
            camera,
            light,
            order: self.order,
        };
        self.first_ray();
        let (img, stats) = render::render(self.scene, &opts)?;
        render::write_png(out, &img)?;
        let all = stats.primary + stats.shadow;
        let total = SetReport::new(&all, stats.seconds, Answered::Mixed);
        if self.args.json {
            #[derive(Serialize)]
            struct Rendered<'a> {
                image: &'a Path,
                rays: u64,
                seconds: f64,
                mrays_per_s: f64,
                page: oavm::logical::PageReport,
                render: RenderStats,
            }
            return cli::print_json(&self.report(Rendered {
                image,
                rays: total.rays,
                seconds: total.seconds,
                mrays_per_s: total.mrays_per_s,
                page: total.page,
                render: stats,
            }));
        }
        cli::print_text(&format!(
            "wrote {} ({}x{}): {} primary rays ({} hit), {} shadow rays ({} shadowed), {:.3} s, \
             {:.2} Mrays/s on {} threads (open {:.3} ms){}\n",
            image.display(),
            stats.width,
            stats.height,
            stats.primary.rays,
            stats.hits,
            stats.shadow.rays,
            stats.shadowed,
            stats.seconds,
            total.mrays_per_s,
            self.threads,
            self.open_ms,
            self.paging_text(&total),
        ))
    }

    /// Render mode with --shade: the scene's materials and lights (the --view scene's, posed
    /// at --time, which must be the scene the file was packed from), Whitted-style.
    fn render_shaded(&mut self, image: &Path) -> Result<(), Error> {
        let out = Output::create(image, &[&self.args.file])?;
        let aff = self.view_scene()?;
        let (camera, light, (width, height)) = self.shot_of(aff.as_ref())?;
        let mut look = match &aff {
            Some(aff) => {
                let packed = self.scene.file().header().input_triangles;
                if aff.mesh.triangles.len() as u64 != packed {
                    return Err(Error::Invalid(format!(
                        "{}: posed at time {}, the scene has {} triangles, but {} was packed \
                         from {packed}: its materials cannot be matched to the file's triangles \
                         (give --time the time given to oavm-pack, or pack this scene)",
                        self.args
                            .camera
                            .view
                            .as_deref()
                            .unwrap_or(Path::new(""))
                            .display(),
                        aff.time,
                        aff.mesh.triangles.len(),
                        self.args.file.display(),
                    )));
                }
                Look::from_aff(aff)
            }
            None => Look::plain(&self.bounds()),
        };
        if aff.is_none() || self.args.camera.light.is_some() {
            look.lights = vec![PointLight {
                position: light.map(f64::from),
                colour: [1.0; 3],
            }];
        }
        let mut opts = ShadedOptions::new(
            self.args.width.unwrap_or(width),
            self.args.height.unwrap_or(height),
            camera,
        );
        opts.order = self.order;
        if let Some(depth) = self.args.depth {
            opts.max_depth = depth;
        }
        self.first_ray();
        let (img, stats) = render::render_shaded(self.scene, &opts, &look)?;
        render::write_png(out, &img)?;
        let all = stats.primary + stats.shadow + stats.reflection + stats.refraction;
        let total = SetReport::new(&all, stats.seconds, Answered::Mixed);
        if self.args.json {
            #[derive(Serialize)]
            struct Shaded<'a> {
                image: &'a Path,
                shading: &'static str,
                max_depth: u32,
                lights: usize,
                materials: usize,
                rays: u64,
                seconds: f64,
                mrays_per_s: f64,
                page: oavm::logical::PageReport,
                render: ShadedStats,
            }
            return cli::print_json(&self.report(Shaded {
                image,
                shading: "whitted",
                max_depth: opts.max_depth,
                lights: look.lights.len(),
                materials: look.materials.len(),
                rays: total.rays,
                seconds: total.seconds,
                mrays_per_s: total.mrays_per_s,
                page: total.page,
                render: stats,
            }));
        }
        cli::print_text(&format!(
            "wrote {} ({}x{}, Whitted, depth {}, {} lights, {} materials): {} primary rays ({} \
             hit), {} shadow rays ({} shadowed), {} reflection rays, {} refraction rays, {:.3} s, \
             {:.2} Mrays/s on {} threads (open {:.3} ms){}\n",
            image.display(),
            stats.width,
            stats.height,
            opts.max_depth,
            look.lights.len(),
            look.materials.len(),
            stats.primary.rays,
            stats.hits,
            stats.shadow.rays,
            stats.shadowed,
            stats.reflection.rays,
            stats.refraction.rays,
            stats.seconds,
            total.mrays_per_s,
            self.threads,
            self.open_ms,
            self.paging_text(&total),
        ))
    }

    /// Batch mode: traces a RAYS file and writes the answers (only once every ray is answered;
    /// the output's place is checked before the trace).
    fn batch(&mut self, rays_path: &Path, query: &Query) -> Result<(), Error> {
        let (out_path, closest) = match query {
            Query::Closest(p) => (p, true),
            Query::Any(p) => (p, false),
        };
        let out = Output::create(out_path, &[&self.args.file, rays_path])?;
        let rays = rays::read_rays(rays_path, self.max_rays())?;
        self.first_ray();
        let t = Instant::now();
        let set = if closest {
            let mut hits = vec![Hit::MISS; rays.len()];
            let c = self
                .scene
                .intersect_batch_ordered(&rays, &mut hits, self.order)?;
            let seconds = t.elapsed().as_secs_f64();
            rays::write_into(out, &hits)?;
            let n = hits.iter().filter(|h| h.is_hit()).count() as u64;
            SetReport::new(&c, seconds, Answered::Hits(n))
        } else {
            let mut occ = vec![0u8; rays.len()];
            let c = self
                .scene
                .occluded_batch_ordered(&rays, &mut occ, self.order)?;
            let seconds = t.elapsed().as_secs_f64();
            rays::write_into(out, &occ)?;
            let n = occ.iter().filter(|&&o| o == 1).count() as u64;
            SetReport::new(&c, seconds, Answered::Occluded(n))
        };
        if self.args.json {
            return cli::print_json(&self.report(&set));
        }
        let (n, label) = match (set.hits, set.occluded) {
            (Some(n), _) => (n, "hits"),
            (_, n) => (n.unwrap_or(0), "occluded"),
        };
        cli::print_text(&format!(
            "{} rays, {n} {label}, {:.3} s, {:.2} Mrays/s on {} threads (open {:.3} ms); per \
             ray: {:.1} nodes, {:.1} volumes, {:.1} triangles{}; wrote {}\n",
            set.rays,
            set.seconds,
            set.mrays_per_s,
            self.threads,
            self.open_ms,
            set.nodes_visited_per_ray,
            set.volumes_crossed_per_ray,
            set.triangles_tested_per_ray,
            self.paging_text(&set),
            out_path.display()
        ))
    }

    /// Benchmark mode: traces --random or --primary rays (closest hit), then with --shadow a
    /// shadow ray from every hit (in waves, --wave); reports each set and the total, writes
    /// nothing.
    fn bench(&mut self, set: RaySet, shadow: bool, wave: usize) -> Result<(), Error> {
        let (camera, light, _) = self.shot()?;
        let count = match set {
            RaySet::Random { count, .. } => count,
            RaySet::Primary { width, height } => width as u64 * height as u64,
        };
        let max = self.max_rays();
        if count > max {
            return Err(Error::Invalid(format!(
                "{count} rays: at most {max} fit in half of the available memory \
                 ({} bytes a ray); trace them in several runs",
                oavm::logical::BYTES_PER_RAY
            )));
        }
        let (name, rays) = match set {
            RaySet::Random { count, seed } => (
                "random",
                rays::random_rays(&self.bounds(), count as usize, seed),
            ),
            RaySet::Primary { width, height } => ("primary", camera.primary_rays(width, height)),
        };
        self.first_ray();
        let frame = self.scene.trace_frame(
            &rays,
            &FrameOptions {
                light: shadow.then_some(light),
                wave,
                order: self.order,
            },
        )?;

        /// One set's figures, with a digest of its answers.
        #[derive(Serialize)]
        struct Set {
            set: &'static str,
            /// xxh3-64 of the set's answers (closest hits as their HITS records, or the OCCL
            /// bytes): runs that agree ray for ray have the same digest.
            answers_xxh3: String,
            #[serde(flatten)]
            report: SetReport,
        }
        let digest = |bytes: &[u8]| format!("{:016x}", xxhash_rust::xxh3::xxh3_64(bytes));
        let hits = frame.hits.iter().filter(|h| h.is_hit()).count() as u64;
        let mut sets = vec![Set {
            set: name,
            answers_xxh3: digest(bytemuck::cast_slice(&frame.hits)),
            report: SetReport::new(
                &frame.primary.counters,
                frame.primary.seconds,
                Answered::Hits(hits),
            ),
        }];
        if shadow {
            let n = frame.occluded.iter().filter(|&&o| o == 1).count() as u64;
            sets.push(Set {
                set: "shadow",
                answers_xxh3: digest(&frame.occluded),
                report: SetReport::new(
                    &frame.shadow.counters,
                    frame.shadow.seconds,
                    Answered::Occluded(n),
                ),
            });
        }
        let total = SetReport::new(
            &(frame.primary.counters + frame.shadow.counters),
            frame.primary.seconds + frame.shadow.seconds,
            Answered::Mixed,
        );
        if self.args.json {
            #[derive(Serialize)]
            struct Bench {
                #[serde(flatten)]
                total: SetReport,
                sets: Vec<Set>,
            }
            return cli::print_json(&self.report(Bench { total, sets }));
        }
        let mut text = String::new();
        for s in &sets {
            let (n, label) = match (s.report.hits, s.report.occluded) {
                (Some(n), _) => (n, "hits"),
                (_, n) => (n.unwrap_or(0), "occluded"),
            };
            text += &format!(
                "{}: {} rays, {n} {label}, {:.3} s, {:.2} Mrays/s{}\n",
                s.set,
                s.report.rays,
                s.report.seconds,
                s.report.mrays_per_s,
                self.paging_text(&s.report)
            );
        }
        text += &format!(
            "{} threads, order {}, open {:.3} ms, first ray {:.3} ms after start\n",
            self.threads, self.order, self.open_ms, self.first_ray_ms
        );
        cli::print_text(&text)
    }

    /// The model's bounds, from the header.
    fn bounds(&self) -> Bounds {
        let h = self.scene.file().header();
        Bounds {
            min: h.mesh_min,
            max: h.mesh_max,
        }
    }

    /// The camera, light and image size of the render and of --primary: from --view, or
    /// framing the model and adjusted by --eye, --target, --up, --fov; the light from --light,
    /// else the scene's, else the default.
    fn shot(&self) -> Result<Shot, Error> {
        self.shot_of(self.view_scene()?.as_ref())
    }

    /// The --view scene posed at --time, if there is one.
    fn view_scene(&self) -> Result<Option<AffScene>, Error> {
        match &self.args.camera.view {
            Some(path) => Ok(Some(oavm::mesh::load_aff(path, self.args.time)?)),
            None => Ok(None),
        }
    }

    /// [`Self::shot`] with the --view scene `aff` already read.
    fn shot_of(&self, aff: Option<&AffScene>) -> Result<Shot, Error> {
        let c = &self.args.camera;
        let bounds = self.bounds();
        let view = c.view.as_ref().zip(aff);
        let (camera, scene_light, size) = if let Some((view_path, aff)) = view {
            let v = if c.camera_path {
                aff.camera_path.ok_or_else(|| {
                    Error::Invalid(format!(
                        "{}: the scene has no camera path (`k camera` and a `v` block) for \
                         --camera-path",
                        view_path.display()
                    ))
                })?
            } else {
                aff.view.ok_or_else(|| {
                    Error::Invalid(format!(
                        "{}: the scene has no viewpoint (`v` block) for --view",
                        view_path.display()
                    ))
                })?
            };
            let camera = Camera::look_at(v.from, v.at, v.up, v.angle_deg)
                .map_err(|e| Error::Invalid(format!("{}: viewpoint: {e}", view_path.display())))?;
            let light = aff.lights.first().copied().unwrap_or(v.from);
            (camera, Some(light), v.resolution)
        } else {
            let mut camera = Camera::framing(&bounds);
            if let Some(target) = c.target {
                camera.target = target;
            }
            if let Some(eye) = c.eye {
                camera.eye = eye;
            }
            camera.up = c.up.unwrap_or([0.0, 1.0, 0.0]);
            camera.fov_y = c.fov.unwrap_or(40.0);
            if !(camera.fov_y > 0.0 && camera.fov_y < 180.0) || camera.eye == camera.target {
                return Err(Error::Invalid(
                    "the camera needs 0 < --fov < 180 and --eye apart from --target".into(),
                ));
            }
            (camera, None, (1024, 768))
        };
        let light = c
            .light
            .or(scene_light)
            .map(|l| l.map(|x| x as f32))
            .unwrap_or_else(|| rays::default_light(&bounds));
        Ok((camera, light, size))
    }
}
